"""Volume anchor sampling: N_A points filling an object's interior, seeded by the object's id.

The anchors carry the mass of the spring-mass system, so they must fill the volume, not only the
surface. Gaussian centres are voxelised into an occupancy grid, the grid is closed and its interior
filled, candidate points are drawn uniformly inside the occupied voxels, and farthest-point
sampling picks an evenly spread subset. The same object id always gives the same anchors.
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch
from scipy import ndimage
from torch import Tensor

from .._optional import numba_available

if numba_available():  # Numba is optional: farthest-point sampling falls back to the PyTorch loop
    import numba


def seed_from_id(object_id: str) -> int:
    """A stable 63-bit seed from an object identifier (independent of Python's hash salt)."""
    digest = hashlib.sha256(object_id.encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "little") & ((1 << 63) - 1)


def occupancy_grid(
    points: np.ndarray,  # [N, 3] metres
    resolution: int = 40,
    seal: int = 2,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Voxels (largest side split into ``resolution`` cells) holding a point, with the interior.

    Sparse surface samples leave gaps in the shell, so the occupancy is dilated by ``seal`` voxels,
    its enclosed cavities are filled, and it is eroded back: gaps up to ~2·seal voxels are sealed.
    Returns ``(occupied [X, Y, Z] bool, origin [3] metres, voxel_size metres)``.
    """
    low, high = points.min(0), points.max(0)
    voxel = float((high - low).max()) / resolution
    if voxel <= 0:
        raise ValueError("cannot sample anchors: all points coincide")
    margin = seal + 1  # empty border so that dilation never reaches the edge of the grid
    origin = low - margin * voxel
    shape = np.floor((high - origin) / voxel).astype(int) + margin + 1
    cells = np.floor((points - origin) / voxel).astype(int)
    surface = np.zeros(shape, dtype=bool)
    surface[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    ball = ndimage.generate_binary_structure(3, 1)
    grown = ndimage.binary_dilation(surface, ball, iterations=seal) if seal else surface
    filled = ndimage.binary_fill_holes(grown)
    solid = ndimage.binary_erosion(filled, ball, iterations=seal) if seal else filled
    return solid | surface, origin, voxel


def _fps_py(points, count, first, chosen, distance):
    """Compiled twin of :func:`farthest_point_sampling_reference` (same arithmetic, in float64:
    (dx² + dy²) + dz², running minimum, first index of the maximum)."""
    current = first
    for n in range(count):
        chosen[n] = current
        cx, cy, cz = points[current, 0], points[current, 1], points[current, 2]
        best, best_index = -1.0, 0
        for i in range(points.shape[0]):
            dx, dy, dz = points[i, 0] - cx, points[i, 1] - cy, points[i, 2] - cz
            d = dx * dx + dy * dy + dz * dz
            if d < distance[i]:
                distance[i] = d
            if distance[i] > best:
                best, best_index = distance[i], i
        current = best_index


_fps_compiled = numba.njit(cache=True)(_fps_py) if numba_available() else None


def farthest_point_sampling(
    points: Tensor,  # [M, 3] float64
    count: int,
    first: int = 0,
) -> Tensor:  # [count] int64 indices into points
    """Greedy farthest-point subset, starting from index ``first``: the compiled loop when Numba
    is there (~100× faster on 16k candidates), else :func:`farthest_point_sampling_reference`.
    Both return the same indices (tests/test_physics_topology.py)."""
    if _fps_compiled is None or points.dtype != torch.float64:
        return farthest_point_sampling_reference(points, count, first)
    count = min(count, points.shape[0])
    chosen = np.empty(count, dtype=np.int64)
    distance = np.full(points.shape[0], np.inf)
    _fps_compiled(np.ascontiguousarray(points.numpy()), count, first, chosen, distance)
    return torch.from_numpy(chosen)


def farthest_point_sampling_reference(
    points: Tensor,  # [M, 3]
    count: int,
    first: int = 0,
) -> Tensor:  # [count] int64 indices into points
    """Greedy farthest-point subset, starting from index ``first`` (plain PyTorch)."""
    count = min(count, points.shape[0])
    chosen = torch.empty(count, dtype=torch.int64)
    distance = torch.full((points.shape[0],), float("inf"), dtype=points.dtype)
    current = first
    for n in range(count):
        chosen[n] = current
        distance = torch.minimum(distance, ((points - points[current]) ** 2).sum(-1))
        current = int(torch.argmax(distance))
    return chosen


def sample_volume_anchors(
    points: Tensor | np.ndarray,  # [N, 3] Gaussian centres (or any points of the object), metres
    num_anchors: int = 2048,
    seed: int | str = 0,
    resolution: int = 40,
    candidates_per_anchor: int = 8,
) -> Tensor:  # [num_anchors, 3] float32, metres
    """``num_anchors`` points spread evenly through the filled volume of ``points``.

    ``seed`` may be an object id string (hashed with :func:`seed_from_id`). Objects too thin to
    fill any voxel interior still get anchors inside their occupied (surface) voxels.
    """
    if isinstance(seed, str):
        seed = seed_from_id(seed)
    pts = torch.as_tensor(points).detach().cpu().double().numpy()
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise ValueError(f"points must have shape [N, 3] with N > 0, got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN or inf")
    occupied, origin, voxel = occupancy_grid(pts, resolution)
    cells = np.argwhere(occupied)
    rng = np.random.default_rng(seed)
    num_candidates = max(num_anchors * candidates_per_anchor, len(cells))
    picked = rng.integers(0, len(cells), size=num_candidates)
    candidates = origin + (cells[picked] + rng.random((num_candidates, 3))) * voxel
    candidates = torch.from_numpy(candidates)
    index = farthest_point_sampling(
        candidates, num_anchors, first=int(rng.integers(num_candidates))
    )
    return candidates[index].float()
