"""Triangle meshes (.obj/.glb/.gltf/.ply/.stl, or a ``trimesh.Trimesh``) → 3D Gaussians.

The mesh is first normalised (bounding box centred on the origin, largest side ``size`` metres).
Surface Gaussians are area-uniform samples of the triangles; interior Gaussians are jittered
centres of the voxels that lie at least one voxel deep inside the filled voxelisation
(``mesh.voxelized(pitch).fill()``, then a one-voxel erosion so no sample pokes out). This needs no
ray-casting backend (rtree/embree). A mesh whose surface is not closed (open shells, large holes)
cannot be filled: it then gets surface Gaussians only, ``num_gaussians`` of them.

Colours come from the mesh (texture image sampled at the interpolated UV, vertex colours
interpolated barycentrically, or face colours) or from a procedural texture. Interior Gaussians
take the colour of the nearest surface sample (mesh colours) or the procedural texture at their
position. Every channel is raised to at least ``MIN_COLOR_VALUE`` so nothing reads as background.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from reconphys.assets.gaussians import Gaussians, check_sampling_args
from reconphys.assets.procedural import (
    MIN_COLOR_VALUE,
    OPACITY,
    TEXTURES,
    surface_and_interior_sigmas,
    texture_colors,
)
from reconphys.errors import InputError

MESH_TEXTURES = ("auto", "mesh", *TEXTURES)
MESH_SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")  # for scanning mesh folders
# Voxel resolutions (cells along the largest side) tried for the interior: the finer one only
# when the coarse eroded interior is empty (thin objects).
INTERIOR_RESOLUTIONS = (48, 96)
# Visual meshes shipped at the top of pybullet_data, besides random_urdfs/*/*.obj.
PYBULLET_NAMED_MESHES = ("bunny.obj", "duck.obj", "teddy2_VHACD_CHs.obj")


def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Load a mesh file as one ``trimesh.Trimesh`` (scenes are concatenated), validated.

    Raises ``InputError`` naming the path for a missing, unreadable or empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("mesh file not found", source=str(path))
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises many exception types for corrupt files
        detail = (str(e).splitlines() or [""])[0][:200]
        message = f"cannot read mesh ({type(e).__name__}: {detail})"
        raise InputError(message, source=str(path)) from e
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError("file holds no triangle mesh", source=str(path))
    _validate(mesh, str(path))
    return mesh


def _validate(mesh: trimesh.Trimesh, source: str) -> None:
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise InputError("mesh has no triangles", source=source, field="faces")
    if not np.isfinite(mesh.vertices).all():
        raise InputError("mesh has NaN or infinite vertex coordinates", source, "vertices")
    if not mesh.area > 0:
        raise InputError("mesh has zero surface area", source=source, field="faces")
    if not mesh.extents.max() > 0:
        raise InputError("all mesh vertices coincide", source=source, field="vertices")


# --- colours ---


def _uv_texture_colors(
    mesh: trimesh.Trimesh, face_index: np.ndarray, barycentric: np.ndarray
) -> np.ndarray | None:
    """Texture colours ``[S, 3]`` in [0, 1] at the samples, or None without UV or material."""
    visual = mesh.visual
    material = getattr(visual, "material", None)
    if material is None:
        return None
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        image = material.baseColorTexture
        factor = np.ones(3)  # glTF default when baseColorFactor is absent
        if material.baseColorFactor is not None:
            factor = trimesh.visual.color.to_rgba(material.baseColorFactor)[:3] / 255.0
    else:
        image, factor = getattr(material, "image", None), np.ones(3)
    uv = getattr(visual, "uv", None)
    if image is None or uv is None or len(uv) != len(mesh.vertices):
        return np.broadcast_to(material.main_color[:3] / 255.0, (len(face_index), 3)).copy()
    sample_uv = np.einsum("sk,skj->sj", barycentric, uv[mesh.faces[face_index]])
    rgba = trimesh.visual.color.uv_to_interpolated_color(sample_uv, image)
    return rgba[:, :3] / 255.0 * factor


def mesh_surface_colors(
    mesh: trimesh.Trimesh,
    face_index: np.ndarray,  # [S] triangle of each sample
    barycentric: np.ndarray,  # [S, 3] barycentric coordinates in that triangle
) -> np.ndarray | None:
    """Colours ``[S, 3]`` in [0, 1] the mesh defines at surface samples, or None if it has none."""
    visual = mesh.visual
    if visual is None or not visual.defined:
        return None
    if visual.kind == "texture":
        return _uv_texture_colors(mesh, face_index, barycentric)
    if visual.kind == "vertex":
        vertex_colors = np.asarray(visual.vertex_colors)[:, :3] / 255.0
        return np.einsum("sk,skj->sj", barycentric, vertex_colors[mesh.faces[face_index]])
    if visual.kind == "face":
        return np.asarray(visual.face_colors)[face_index, :3] / 255.0
    return None


def _gaussian_colors(
    mesh: trimesh.Trimesh,
    face_index: np.ndarray,  # [S] triangle of each surface sample
    barycentric: np.ndarray,  # [S, 3]
    surface: np.ndarray,  # [S, 3] normalised positions, metres
    interior: np.ndarray,  # [I, 3] normalised positions, metres
    texture: str,
    size: float,
    seed: int,
    source: str,
) -> np.ndarray:
    """RGB ``[S + I, 3]`` in [MIN_COLOR_VALUE, 1] for the surface then the interior samples."""
    surface_colors = None
    if texture in ("auto", "mesh"):
        surface_colors = mesh_surface_colors(mesh, face_index, barycentric)
        if texture == "mesh" and surface_colors is None:
            raise InputError("mesh defines no colours; use a procedural texture", source, "texture")
        uniform = surface_colors is not None and np.ptp(surface_colors, axis=0).max() < 1e-3
        if texture == "auto" and uniform:
            surface_colors = None  # one flat colour would hide rotation: use the checker instead
    if surface_colors is None:
        procedural = "checker" if texture in ("auto", "mesh") else texture
        points = torch.from_numpy(np.concatenate([surface, interior]))
        return texture_colors(points, procedural, size=size, seed=seed).numpy()
    if len(interior):
        _, nearest = cKDTree(surface).query(interior, k=1)
        surface_colors = np.concatenate([surface_colors, surface_colors[nearest]])
    return np.clip(surface_colors, MIN_COLOR_VALUE, 1.0)


# --- sampling ---


def _interior_samples(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` points ``[count, 3]`` uniformly inside the eroded filled voxelisation.

    Empty ``[0, 3]`` when ``count`` is 0 or the mesh cannot be filled (surface not closed).
    """
    if count == 0:
        return np.zeros((0, 3))
    for resolution in INTERIOR_RESOLUTIONS:
        pitch = float(mesh.extents.max()) / resolution
        voxels = mesh.voxelized(pitch)
        shell_count = voxels.filled_count
        voxels.fill()
        if voxels.filled_count == shell_count:
            return np.zeros((0, 3))  # nothing enclosed: the surface is not closed
        deep = ndimage.binary_erosion(voxels.matrix, structure=np.ones((3, 3, 3), dtype=bool))
        indices = np.argwhere(deep)
        if len(indices):
            break
    else:
        return np.zeros((0, 3))  # closed but thinner than about two voxels everywhere
    chosen = indices[rng.integers(len(indices), size=count)]
    jitter = rng.uniform(-0.5, 0.5, size=(count, 3)) * pitch
    return voxels.indices_to_points(chosen) + jitter


def mesh_to_gaussians(
    mesh_or_path: trimesh.Trimesh | str | os.PathLike,
    num_gaussians: int = 20000,
    seed: int = 0,
    size: float | None = 0.5,
    interior_fraction: float = 0.3,
    texture: str = "auto",
) -> Gaussians:
    """Gaussians ``[num_gaussians]`` (float32, CPU) sampled from a mesh, normalised to ``size``
    (or where the file puts them, ``size=None``).

    Args:
        mesh_or_path: a ``trimesh.Trimesh`` (left unchanged) or a mesh file path.
        num_gaussians: total count; ``round(interior_fraction × num_gaussians)`` fill the inside,
            the rest lie on the surface. If the mesh cannot be filled, all lie on the surface.
        seed: all randomness derives from it (samples, jitter, procedural colours).
        size: largest side of the mesh's bounding box after normalisation, metres; the box is
            centred on the origin (mesh frame kept: no rotation). None: the mesh's own
            coordinates, taken as metres (a mesh already in its pose and size, e.g. frame 0's).
        interior_fraction: in [0, 1).
        texture: "auto" (mesh colours when they vary over the surface, else "checker"), "mesh"
            (mesh colours, even uniform ones; error if it has none), or a procedural texture
            (``TEXTURES``) that ignores the mesh's colours.

    Surface Gaussians come first, then interior ones; scales are isotropic and follow the local
    sample spacing, as for the procedural shapes.
    """
    if texture not in MESH_TEXTURES:
        valid = ", ".join(MESH_TEXTURES)
        raise InputError(f"unknown texture {texture!r}; expected one of: {valid}", field="texture")
    check_sampling_args(num_gaussians, 1.0 if size is None else size, interior_fraction)
    if int(seed) != seed or seed < 0:
        raise InputError(f"must be a non-negative integer, got {seed}", field="seed")
    if isinstance(mesh_or_path, trimesh.Trimesh):
        mesh, source = mesh_or_path, "mesh"
    else:
        mesh, source = load_mesh(mesh_or_path), str(mesh_or_path)
    _validate(mesh, source)

    lower, upper = mesh.bounds
    if size is None:  # as given: no centring, no scaling
        size = float((upper - lower).max())
        center, factor = np.zeros(3), 1.0
    else:
        center, factor = 0.5 * (lower + upper), size / float((upper - lower).max())
    geometry = trimesh.Trimesh((mesh.vertices - center) * factor, mesh.faces, process=False)

    rng = np.random.default_rng(seed)
    interior_count = min(round(interior_fraction * num_gaussians), num_gaussians - 2)
    interior = _interior_samples(geometry, interior_count, rng)
    surface, face_index, barycentric = trimesh.sample.sample_surface(
        geometry, num_gaussians - len(interior), return_barycentric=True, seed=seed
    )

    colors = _gaussian_colors(
        mesh, face_index, barycentric, surface, interior, texture, size, seed, source
    )
    surface_sigma, interior_sigma = surface_and_interior_sigmas(surface, interior)
    sigma = torch.from_numpy(np.concatenate([surface_sigma, interior_sigma])).float()  # [N]
    return Gaussians.from_activated(
        means=torch.from_numpy(np.concatenate([surface, interior])).float(),
        scales=sigma.unsqueeze(-1).expand(-1, 3).contiguous(),
        opacities=torch.full((num_gaussians,), OPACITY),
        colors=torch.from_numpy(colors).float(),
    )


def pybullet_mesh_paths() -> list[Path]:
    """Visual meshes shipped in the ``pybullet`` wheel: ``random_urdfs/*/*.obj`` plus a few named.

    Sorted; collision-only ``*_coll.obj`` and ``*_vhacd*`` hulls are skipped. Raises
    ``InputError`` when pybullet is not installed (``pip install reconphys[meshes]``).
    """
    try:
        import pybullet_data
    except ImportError as e:
        raise InputError(
            "pybullet is not installed; run: pip install reconphys[meshes]", source="pybullet_data"
        ) from e
    root = Path(pybullet_data.getDataPath())
    paths = [
        p
        for p in sorted(root.glob("random_urdfs/*/*.obj"))
        if not p.stem.endswith("_coll") and "vhacd" not in p.stem.lower()
    ]
    paths += [root / name for name in PYBULLET_NAMED_MESHES if (root / name).is_file()]
    if not paths:
        raise InputError("no meshes found in the installed pybullet_data", source=str(root))
    return paths
