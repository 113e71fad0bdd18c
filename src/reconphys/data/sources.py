"""Where the dataset's objects come from: procedural shapes, a folder of meshes, pybullet's meshes,
or a local Objaverse mirror — each turned into normalised Gaussians
(docs/design.md#synthetic-dataset).

A source lists candidate objects (:class:`ObjectRef`, identified by a stable string id) and turns
one into Gaussians centred on the origin with their largest bounding-box side ``settings.size``
metres, in the object's own frame. All randomness of an object derives from its id, never from the
dataset seed, so an object looks the same in every dataset that draws it.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import torch

from ..assets.gaussians import Gaussians
from ..assets.mesh import MESH_SUFFIXES, load_mesh, pybullet_mesh_paths
from ..assets.normalize import normalize_gaussians
from ..assets.procedural import SHAPES, make_procedural_gaussians
from ..errors import InputError
from .settings import DataSettings
from .source_base import ObjectRef, load_file_object, object_seed

# Procedural objects vary by texture and by an anisotropic stretch of each axis in this range
# (then renormalised), so that two variants of one shape differ in proportions and look.
PROCEDURAL_TEXTURES = ("checker", "stripes")  # "solid" would hide rotation
PROCEDURAL_STRETCH = (0.65, 1.0)


class ProceduralSource:
    """Built-in shapes (``reconphys.assets.procedural.SHAPES``), variants ``<shape>-<nnnn>``."""

    name = "procedural"

    def candidates(self, count: int) -> list[ObjectRef]:
        variants = -(-count // len(SHAPES))
        return [ObjectRef(f"{shape}-{v:04d}") for v in range(variants) for shape in SHAPES]

    def describe(self, ref: ObjectRef) -> dict:
        rng = np.random.default_rng(object_seed(ref.id, "variant"))
        texture = PROCEDURAL_TEXTURES[int(rng.integers(len(PROCEDURAL_TEXTURES)))]
        stretch = rng.uniform(*PROCEDURAL_STRETCH, size=3)
        shape = ref.id.rsplit("-", 1)[0]
        return {"shape": shape, "texture": texture, "stretch": [float(s) for s in stretch]}

    def load(self, ref: ObjectRef, settings: DataSettings) -> Gaussians:
        variant = self.describe(ref)
        if variant["shape"] not in SHAPES:
            raise InputError(f"unknown procedural object {ref.id!r}", field="object")
        g = make_procedural_gaussians(
            variant["shape"],
            settings.num_gaussians,
            seed=object_seed(ref.id, "gaussians"),
            size=settings.size,
            texture=variant["texture"],
        )
        stretched = g.means * torch.tensor(variant["stretch"], dtype=g.means.dtype)
        return normalize_gaussians(g.with_means(stretched), settings.size)


class FolderSource:
    """Every mesh file under a folder (recursively), ids = paths relative to the folder."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.name = str(self.root.resolve())
        if not self.root.is_dir():
            expected = "a folder of meshes, or procedural, pybullet, objaverse"
            raise InputError(f"not found; expected {expected}", source=str(root))

    def candidates(self, count: int) -> list[ObjectRef]:
        paths = sorted(
            p for p in self.root.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES
        )
        if not paths:
            suffixes = ", ".join(MESH_SUFFIXES)
            raise InputError(f"no mesh files ({suffixes}) found", source=str(self.root))
        return [ObjectRef(p.relative_to(self.root).as_posix(), str(p)) for p in paths]

    def describe(self, ref: ObjectRef) -> dict:
        return {"file": ref.id}

    def load(self, ref: ObjectRef, settings: DataSettings) -> Gaussians:
        return load_file_object(Path(ref.path), ref.id, settings)


class PybulletSource(FolderSource):
    """The ~1000 visual meshes shipped in the ``pybullet`` wheel (optional extra ``meshes``)."""

    def __init__(self):
        paths = pybullet_mesh_paths()  # InputError with the install hint when missing
        import pybullet_data

        self.root = Path(pybullet_data.getDataPath())
        self.name = "pybullet"
        # The wheel holds broken files (random_urdfs/168/168.obj is one line, "v nan"): they are
        # left out of the candidates, so a plan never draws them (~4 s to check all ~1000).
        self.paths, broken = [], []
        for path in paths:
            try:
                load_mesh(path)
                self.paths.append(path)
            except InputError as e:
                broken.append(f"{path.relative_to(self.root).as_posix()} ({e})")
        if broken:
            listed = "; ".join(broken)
            warnings.warn(
                f"pybullet: left out {len(broken)} unusable meshes: {listed}", stacklevel=2
            )

    def candidates(self, count: int) -> list[ObjectRef]:
        return [ObjectRef(p.relative_to(self.root).as_posix(), str(p)) for p in self.paths]


def open_source(
    spec: str,
    settings: DataSettings | None = None,
    objaverse_root: str | os.PathLike | None = None,
    download: bool = False,
):
    """The source named by ``spec``: "procedural", "pybullet", "objaverse" or a folder path."""
    if spec == "procedural":
        if settings is not None and settings.stretched:
            raise InputError(
                "procedural shapes have their own proportions; --stretch applies to mesh files",
                field="--stretch",
            )
        return ProceduralSource()
    if spec == "pybullet":
        return PybulletSource()
    if spec == "objaverse":
        from .objaverse import ObjaverseSource

        uids = settings.objaverse_uids if settings is not None else ""
        return ObjaverseSource(objaverse_root, uids_file=uids or None, download=download)
    return FolderSource(spec)
