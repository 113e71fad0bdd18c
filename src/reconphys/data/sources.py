"""Where the dataset's objects come from: procedural shapes, a folder of meshes, pybullet's meshes,
or a local Objaverse mirror — each turned into normalised Gaussians (DESIGN §7).

A source lists candidate objects (:class:`ObjectRef`, identified by a stable string id) and turns
one into Gaussians centred on the origin with their largest bounding-box side ``settings.size``
metres, in the object's own frame. All randomness of an object derives from its id, never from the
dataset seed, so an object looks the same in every dataset that draws it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..assets.gaussians import Gaussians
from ..assets.mesh import MESH_SUFFIXES, mesh_to_gaussians, pybullet_mesh_paths
from ..assets.normalize import normalize_gaussians
from ..assets.ply import read_ply
from ..assets.procedural import SHAPES, make_procedural_gaussians
from ..errors import InputError
from ..physics import seed_from_id
from .settings import DataSettings

# Procedural objects vary by texture and by an anisotropic stretch of each axis in this range
# (then renormalised), so that two variants of one shape differ in proportions and look.
PROCEDURAL_TEXTURES = ("checker", "stripes")  # "solid" would hide rotation
PROCEDURAL_STRETCH = (0.65, 1.0)


@dataclass(frozen=True)
class ObjectRef:
    """One candidate object: ``id`` is stable and unique within its source."""

    id: str  # e.g. "bunny-0003", "random_urdfs/000/000.obj", "objaverse/<uid>"
    path: str = ""  # file the object is read from (empty for procedural shapes)


def object_seed(object_id: str, purpose: str) -> int:
    """A 31-bit seed for one purpose (``"gaussians"``, ...) of one object."""
    return seed_from_id(f"{purpose}:{object_id}") % (2**31)


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


def _is_gaussian_ply(path: Path) -> bool:
    """True when a .ply file holds 3DGS Gaussians (has f_dc_0 / opacity) rather than a mesh."""
    try:
        with open(path, "rb") as f:
            header = f.read(4096)
    except OSError as e:
        raise InputError(f"cannot read ({e.strerror})", source=str(path)) from None
    return b"f_dc_0" in header and b"opacity" in header


def load_file_object(path: Path, object_id: str, settings: DataSettings) -> Gaussians:
    """A mesh (.obj/.glb/.ply/...) or a 3DGS Gaussian PLY → normalised Gaussians.

    Gaussian PLYs keep their own Gaussians (a seeded random subset of ``settings.num_gaussians``
    when they hold more); meshes are sampled by ``mesh_to_gaussians`` (mesh colours when they vary,
    else a procedural checker).
    """
    seed = object_seed(object_id, "gaussians")
    if path.suffix.lower() == ".ply" and _is_gaussian_ply(path):
        g = read_ply(path)
        if g.num_gaussians > settings.num_gaussians:
            keep = np.random.default_rng(seed).permutation(g.num_gaussians)[
                : settings.num_gaussians
            ]
            g = g.select(torch.from_numpy(np.sort(keep)))
        return normalize_gaussians(g, settings.size)
    return mesh_to_gaussians(path, settings.num_gaussians, seed=seed, size=settings.size)


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
        self.paths = pybullet_mesh_paths()  # InputError with the install hint when missing
        import pybullet_data

        self.root = Path(pybullet_data.getDataPath())
        self.name = "pybullet"

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
        return ProceduralSource()
    if spec == "pybullet":
        return PybulletSource()
    if spec == "objaverse":
        from .objaverse import ObjaverseSource

        uids = settings.objaverse_uids if settings is not None else ""
        return ObjaverseSource(objaverse_root, uids_file=uids or None, download=download)
    return FolderSource(spec)
