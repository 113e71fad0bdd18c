"""What every object source shares: the object reference, per-object seeds, and the reader of an
object file (a mesh or a 3DGS Gaussian PLY) into normalised Gaussians.

Kept apart from :mod:`reconphys.data.sources` (which opens a source by name) so that the sources
in their own modules (:mod:`reconphys.data.objaverse`) import these without importing the factory.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..assets.gaussians import Gaussians
from ..assets.mesh import load_mesh, mesh_to_gaussians
from ..assets.normalize import normalize_gaussians
from ..assets.ply import read_ply
from ..errors import InputError
from ..physics import seed_from_id
from .settings import DataSettings


@dataclass(frozen=True)
class ObjectRef:
    """One candidate object: ``id`` is stable and unique within its source."""

    id: str  # e.g. "bunny-0003", "random_urdfs/000/000.obj", "objaverse/<uid>"
    path: str = ""  # file the object is read from (empty for procedural shapes)


def object_seed(object_id: str, purpose: str) -> int:
    """A 31-bit seed for one purpose (``"gaussians"``, ...) of one object."""
    return seed_from_id(f"{purpose}:{object_id}") % (2**31)


def _is_gaussian_ply(path: Path) -> bool:
    """True when a .ply file holds 3DGS Gaussians (has f_dc_0 / opacity) rather than a mesh."""
    try:
        with open(path, "rb") as f:
            header = f.read(4096)
    except OSError as e:
        raise InputError(f"cannot read ({e.strerror})", source=str(path)) from None
    return b"f_dc_0" in header and b"opacity" in header


def mesh_stretch(object_id: str, settings: DataSettings) -> np.ndarray | None:
    """The linear map ``[3, 3]`` that stretches one object's mesh, or None for no stretch.

    A stretch by ``s`` along a unit axis ``u``: ``I + (s - 1) u uᵀ``, with ``u`` uniform on the
    sphere and ``log s`` uniform in ``log settings.stretch_range``, both drawn from the object id
    and the dataset seed (another seed stretches the same mesh otherwise).
    """
    if not settings.stretched:
        return None
    low, high = settings.stretch_range
    rng = np.random.default_rng(object_seed(object_id, f"stretch:{settings.seed}"))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    factor = float(np.exp(rng.uniform(np.log(low), np.log(high))))
    return np.eye(3) + (factor - 1.0) * np.outer(axis, axis)


def load_file_object(path: Path, object_id: str, settings: DataSettings) -> Gaussians:
    """A mesh (.obj/.glb/.ply/...) or a 3DGS Gaussian PLY → normalised Gaussians.

    Gaussian PLYs keep their own Gaussians (a seeded random subset of ``settings.num_gaussians``
    when they hold more); meshes are sampled by ``mesh_to_gaussians`` (mesh colours when they vary,
    else a procedural checker), after the stretch of ``mesh_stretch`` when the settings ask for one.
    """
    seed = object_seed(object_id, "gaussians")
    stretch = mesh_stretch(object_id, settings)
    if path.suffix.lower() == ".ply" and _is_gaussian_ply(path):
        if stretch is not None:
            raise InputError(
                "a Gaussian PLY cannot be stretched (--stretch applies to mesh files)",
                source=str(path),
            )
        g = read_ply(path)
        if g.num_gaussians > settings.num_gaussians:
            keep = np.random.default_rng(seed).permutation(g.num_gaussians)[
                : settings.num_gaussians
            ]
            g = g.select(torch.from_numpy(np.sort(keep)))
        return normalize_gaussians(g, settings.size)
    if stretch is None:
        return mesh_to_gaussians(path, settings.num_gaussians, seed=seed, size=settings.size)
    mesh = load_mesh(path)  # a fresh mesh per call: transformed in place
    transform = np.eye(4)
    transform[:3, :3] = stretch
    mesh.apply_transform(transform)  # keeps the mesh's colours and texture coordinates
    return mesh_to_gaussians(mesh, settings.num_gaussians, seed=seed, size=settings.size)
