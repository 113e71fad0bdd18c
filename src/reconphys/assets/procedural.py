"""Built-in procedural shapes as 3D Gaussians: no mesh file, no download.

Every shape is a signed distance function (SDF: negative inside, metres after scaling) in a
canonical frame with a known bounding box. ``make_procedural_gaussians`` puts Gaussians on the
surface (uniform samples in a thin band around the zero level, projected onto it by Newton steps)
and inside (rejection sampling where the SDF is negative), scales the object so its largest
bounding-box side is ``size`` metres with the box centred on the origin, sizes each Gaussian from
the local sample spacing so the surface renders closed, and colours it with a procedural texture
that makes rotation and deformation visible.

Frames: the canonical frame of every shape is z up (cylinder, capsule and torus axes along z; the
bunny looks along +x). Ordering of the result: surface Gaussians first, then interior ones.
Dependencies: torch and numpy, plus SciPy's k-d tree for the sample spacing (a core dependency;
a torch nearest-neighbour search was 30× slower on CPU).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from reconphys.assets.gaussians import Gaussians, check_sampling_args
from reconphys.errors import InputError

TEXTURES = ("checker", "stripes", "solid")

# Every colour channel stays at or above this: the evaluation counts pixels darker than 0.0392 as
# background, so no part of an object may be that dark.
MIN_COLOR_VALUE = 0.1
OPACITY = 0.95
# Gaussian standard deviation per unit of local sample spacing (mean distance to the 6 nearest
# samples). Random surface samples leave gaps; at 1.0 a front-facing surface still accumulates an
# opacity above 0.95 almost everywhere (0.5 leaves half of it below 0.9, i.e. see-through).
SIGMA_PER_SPACING = 1.0
NEIGHBORS_FOR_SPACING = 6
CHECKER_CELLS_ACROSS = 7  # checker cells along the largest side
STRIPES_ACROSS = 8
STRIPE_DIRECTION = (0.80, 0.48, 0.36)  # tilted so that rotation about any axis moves the stripes
# Six saturated colours ordered by hue, every channel ≥ MIN_COLOR_VALUE. A texture uses three of
# them 120° apart in hue, chosen by the seed.
PALETTE = (
    (0.90, 0.15, 0.13),  # red
    (0.95, 0.78, 0.12),  # yellow
    (0.15, 0.75, 0.25),  # green
    (0.12, 0.72, 0.78),  # cyan
    (0.16, 0.32, 0.92),  # blue
    (0.78, 0.20, 0.80),  # magenta
)

SignedDistance = Callable[[Tensor], Tensor]  # points [..., 3] -> signed distance [...]


@dataclass(frozen=True)
class _Shape:
    sdf: SignedDistance  # canonical frame, canonical units
    lower: tuple[float, float, float]  # exact bounding box of the zero level set
    upper: tuple[float, float, float]


# --- signed distance primitives (Inigo Quilez's formulas; exact unless noted) ---


def _sphere(p: Tensor, center: tuple[float, float, float], radius: float) -> Tensor:
    return (p - p.new_tensor(center)).norm(dim=-1) - radius


def _box(p: Tensor, half_extents: tuple[float, float, float]) -> Tensor:
    q = p.abs() - p.new_tensor(half_extents)
    outside = q.clamp_min(0.0).norm(dim=-1)
    inside = q.amax(dim=-1).clamp_max(0.0)
    return outside + inside


def _cylinder(p: Tensor, radius: float, half_height: float) -> Tensor:  # axis z
    radial = p[..., :2].norm(dim=-1) - radius
    axial = p[..., 2].abs() - half_height
    q = torch.stack([radial, axial], dim=-1)
    return q.clamp_min(0.0).norm(dim=-1) + q.amax(dim=-1).clamp_max(0.0)


def _torus(p: Tensor, major_radius: float, minor_radius: float) -> Tensor:  # axis z
    q = torch.stack([p[..., :2].norm(dim=-1) - major_radius, p[..., 2]], dim=-1)
    return q.norm(dim=-1) - minor_radius


def _capsule(
    p: Tensor, a: tuple[float, float, float], b: tuple[float, float, float], radius: float
) -> Tensor:
    a_t, b_t = p.new_tensor(a), p.new_tensor(b)
    ab = b_t - a_t
    t = (((p - a_t) * ab).sum(dim=-1) / ab.dot(ab)).clamp(0.0, 1.0)
    return (p - a_t - t.unsqueeze(-1) * ab).norm(dim=-1) - radius


def _ellipsoid(p: Tensor, radii: tuple[float, float, float]) -> Tensor:
    """Bound, not exact, away from the surface; its zero level set is the exact ellipsoid."""
    r = p.new_tensor(radii)
    k0 = (p / r).norm(dim=-1)
    k1 = (p / (r * r)).norm(dim=-1).clamp_min(1e-12)
    return k0 * (k0 - 1.0) / k1


def _smooth_union(a: Tensor, b: Tensor, blend: float) -> Tensor:
    """Polynomial smooth minimum: equals ``min(a, b)`` wherever ``|a - b| >= blend``."""
    h = (0.5 + 0.5 * (b - a) / blend).clamp(0.0, 1.0)
    return b + (a - b) * h - blend * h * (1.0 - h)


# Bunny-like blob: two body spheres, a head, two ear capsules and a tail, smoothly joined. The blend
# never reaches the extreme points of the primitives, so its bounding box is theirs.
_BUNNY_BLEND = 0.1
_BUNNY_PARTS: tuple[tuple[str, tuple], ...] = (
    ("sphere", ((-0.2, 0.0, -0.15), 0.5)),  # rump
    ("sphere", ((0.2, 0.0, -0.05), 0.42)),  # chest
    ("sphere", ((0.55, 0.0, 0.3), 0.3)),  # head
    ("capsule", ((0.5, 0.1, 0.5), (0.38, 0.2, 1.0), 0.09)),  # left ear
    ("capsule", ((0.5, -0.1, 0.5), (0.38, -0.2, 1.0), 0.09)),  # right ear
    ("sphere", ((-0.75, 0.0, 0.0), 0.13)),  # tail
)


def _bunny(p: Tensor) -> Tensor:
    distance = None
    for kind, args in _BUNNY_PARTS:
        part = _sphere(p, *args) if kind == "sphere" else _capsule(p, *args)
        distance = part if distance is None else _smooth_union(distance, part, _BUNNY_BLEND)
    return distance


def _bunny_bounds() -> tuple[tuple[float, ...], tuple[float, ...]]:
    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    for kind, args in _BUNNY_PARTS:
        if kind == "sphere":
            center, radius = np.array(args[0]), args[1]
            lower, upper = np.minimum(lower, center - radius), np.maximum(upper, center + radius)
        else:
            ends, radius = np.array(args[:2]), args[2]
            lower = np.minimum(lower, ends.min(axis=0) - radius)
            upper = np.maximum(upper, ends.max(axis=0) + radius)
    return tuple(lower.tolist()), tuple(upper.tolist())


_SHAPE_TABLE: dict[str, _Shape] = {
    "sphere": _Shape(lambda p: _sphere(p, (0.0, 0.0, 0.0), 1.0), (-1.0,) * 3, (1.0,) * 3),
    "box": _Shape(lambda p: _box(p, (1.0, 0.75, 0.5)), (-1.0, -0.75, -0.5), (1.0, 0.75, 0.5)),
    "cylinder": _Shape(lambda p: _cylinder(p, 0.6, 1.0), (-0.6, -0.6, -1.0), (0.6, 0.6, 1.0)),
    "torus": _Shape(lambda p: _torus(p, 0.7, 0.3), (-1.0, -1.0, -0.3), (1.0, 1.0, 0.3)),
    "capsule": _Shape(
        lambda p: _capsule(p, (0.0, 0.0, -0.5), (0.0, 0.0, 0.5), 0.5),
        (-0.5, -0.5, -1.0),
        (0.5, 0.5, 1.0),
    ),
    "ellipsoid": _Shape(
        lambda p: _ellipsoid(p, (1.0, 0.7, 0.5)), (-1.0, -0.7, -0.5), (1.0, 0.7, 0.5)
    ),
    "bunny": _Shape(_bunny, *_bunny_bounds()),
}
SHAPES = tuple(_SHAPE_TABLE)  # names accepted by make_procedural_gaussians


# --- public helpers ---


def _check_choice(value: str, valid: tuple[str, ...], field: str) -> None:
    if value not in valid:
        raise InputError(
            f"unknown {field} {value!r}; expected one of: {', '.join(valid)}", field=field
        )


def _canonical_placement(shape: str, size: float) -> tuple[Tensor, float]:
    """Centre of the canonical bounding box ``[3]`` and the factor that maps it to ``size``."""
    spec = _SHAPE_TABLE[shape]
    lower = torch.tensor(spec.lower, dtype=torch.float64)
    upper = torch.tensor(spec.upper, dtype=torch.float64)
    return 0.5 * (lower + upper), size / float((upper - lower).max())


def procedural_sdf(
    shape: str,
    points: Tensor,  # [..., 3] metres, in the frame of make_procedural_gaussians(shape, size=size)
    size: float = 0.5,
) -> Tensor:
    """Signed distance of ``points`` to the normalised shape, ``[...]`` metres (negative inside).

    Exact for sphere, box, cylinder, torus and capsule; for the ellipsoid and the bunny the sign and
    the zero level set are exact and the magnitude is a close approximation.
    """
    _check_choice(shape, SHAPES, "shape")
    center, factor = _canonical_placement(shape, size)
    canonical = points.to(torch.float64) / factor + center
    return (_SHAPE_TABLE[shape].sdf(canonical) * factor).to(points.dtype)


def texture_colors(
    points: Tensor,  # [N, 3] metres, object centred on the origin
    texture: str = "checker",
    size: float = 0.5,
    seed: int = 0,
) -> Tensor:
    """Procedural RGB colours in [MIN_COLOR_VALUE, 1] at ``points``, ``[N, 3]`` float32.

    "checker": a 3D checkerboard of three saturated colours with ``CHECKER_CELLS_ACROSS`` cells
    along the largest side (``size`` metres); any two cells sharing a face or an edge differ.
    "stripes": planar bands across a tilted direction, three colours. "solid": one colour.
    The seed picks which three palette colours (120° apart in hue) are used.
    """
    _check_choice(texture, TEXTURES, "texture")
    palette = torch.tensor(PALETTE, dtype=torch.float32)
    generator = torch.Generator().manual_seed(int(seed))
    first = int(torch.randint(len(PALETTE), (1,), generator=generator))
    colors = palette[[(first + 2 * i) % len(PALETTE) for i in range(3)]]  # [3, 3]
    p = points.to(torch.float64)
    if texture == "solid":
        index = torch.zeros(p.shape[:-1], dtype=torch.long)
    elif texture == "checker":
        cell = torch.floor(p / (size / CHECKER_CELLS_ACROSS)).long()
        index = cell.sum(dim=-1).remainder(3)
    else:
        direction = p.new_tensor(STRIPE_DIRECTION)
        direction = direction / direction.norm()
        index = torch.floor(p @ direction / (size / STRIPES_ACROSS)).long().remainder(3)
    return colors[index].clamp_min(MIN_COLOR_VALUE)


def local_spacing(points: np.ndarray, neighbors: int = NEIGHBORS_FOR_SPACING) -> np.ndarray:
    """Mean distance from each point ``[N, 3]`` to its ``neighbors`` nearest others, ``[N]``.

    Same unit as the points. Needs at least two points.
    """
    k = min(neighbors, len(points) - 1)
    distances, _ = cKDTree(points).query(points, k=k + 1)
    return distances[:, 1:].mean(axis=1)


def spacing_sigmas(points: np.ndarray) -> np.ndarray:
    """Isotropic standard deviations ``[N]`` for Gaussians at ``points`` ``[N, 3]`` (same unit).

    ``SIGMA_PER_SPACING`` × local spacing, clipped to [0.5, 2] × the median so isolated samples
    neither vanish nor blow up. Needs at least two points.
    """
    spacing = local_spacing(points)
    median = float(np.median(spacing))
    return SIGMA_PER_SPACING * np.clip(spacing, 0.5 * median, 2.0 * median)


def surface_and_interior_sigmas(
    surface: np.ndarray,  # [S, 3] surface samples (S >= 2)
    interior: np.ndarray,  # [I, 3] samples inside
) -> tuple[np.ndarray, np.ndarray]:
    """Isotropic standard deviations ``([S], [I])`` for surface and interior Gaussians.

    Interior samples are sparser (a volume, not an area), so their spacing-based sigma is larger.
    It is capped at twice the surface median (interior Gaussians are hidden; big ones only cost
    render time) and at half the distance to the nearest surface sample, but not below the surface
    median, so that they do not bulge through the surface.
    """
    surface_sigma = spacing_sigmas(surface)
    if len(interior) == 0:
        return surface_sigma, np.zeros(0)
    floor = float(np.median(surface_sigma))
    depth, _ = cKDTree(surface).query(interior, k=1)
    cap = np.clip(0.5 * depth, floor, 2.0 * floor)
    spacing_sigma = spacing_sigmas(interior) if len(interior) >= 2 else np.full(1, floor)
    return surface_sigma, np.minimum(spacing_sigma, cap)


# --- sampling ---

_CHUNK = 1 << 16
_MAX_CHUNKS = 2000


def _uniform_in_box(lower: Tensor, upper: Tensor, count: int, generator: torch.Generator) -> Tensor:
    return lower + (upper - lower) * torch.rand(count, 3, generator=generator, dtype=torch.float64)


def _rejection_sample(
    accept: Callable[[Tensor], Tensor],
    lower: Tensor,
    upper: Tensor,
    count: int,
    generator: torch.Generator,
) -> Tensor:
    """``count`` uniform samples ``[count, 3]`` of the box where ``accept`` is true."""
    kept, total = [torch.empty(0, 3, dtype=torch.float64)], 0
    for _ in range(_MAX_CHUNKS):
        if total >= count:
            break
        candidates = _uniform_in_box(lower, upper, _CHUNK, generator)
        candidates = candidates[accept(candidates)]
        kept.append(candidates)
        total += len(candidates)
    else:
        raise RuntimeError("rejection sampling accepted too few points; is the shape empty?")
    return torch.cat(kept)[:count]


def _project_to_surface(sdf: SignedDistance, points: Tensor, max_steps: int = 8) -> Tensor:
    """Newton steps ``p ← p − f ∇f / |∇f|²`` onto the zero level set (gradient by differences).

    Exact SDFs converge in one or two steps; only points not yet within 1e-10 (canonical units,
    objects are ~2 across) keep iterating.
    """
    step = 1e-6
    offsets = torch.eye(3, dtype=points.dtype) * step
    points = points.clone()
    active = torch.arange(len(points))
    for _ in range(max_steps):
        p = points[active]
        distance = sdf(p)
        unconverged = distance.abs() > 1e-10
        if not bool(unconverged.any()):
            break
        active, p, distance = active[unconverged], p[unconverged], distance[unconverged]
        gradient = torch.stack([(sdf(p + o) - sdf(p - o)) / (2.0 * step) for o in offsets], dim=-1)
        squared_norm = gradient.square().sum(dim=-1, keepdim=True).clamp_min(1e-12)
        points[active] = p - distance.unsqueeze(-1) * gradient / squared_norm
    return points


def _sample_shape(
    spec: _Shape, surface_count: int, interior_count: int, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Surface ``[S, 3]`` and interior ``[I, 3]`` samples in canonical units, float64."""
    lower = torch.tensor(spec.lower, dtype=torch.float64)
    upper = torch.tensor(spec.upper, dtype=torch.float64)
    # A band of ±1 % of the largest side: thin, so the samples are close to uniform over the area.
    band = 0.01 * float((upper - lower).max())
    surface = _rejection_sample(
        lambda p: spec.sdf(p).abs() < band, lower - band, upper + band, surface_count, generator
    )
    surface = _project_to_surface(spec.sdf, surface)
    interior = _rejection_sample(
        lambda p: spec.sdf(p) < 0.0, lower, upper, interior_count, generator
    )
    return surface, interior


def make_procedural_gaussians(
    shape: str,
    num_gaussians: int = 20000,
    seed: int = 0,
    size: float = 0.5,
    texture: str = "checker",
    interior_fraction: float = 0.3,
) -> Gaussians:
    """Gaussians ``[num_gaussians]`` (float32, CPU) for a built-in shape, ready to simulate.

    Args:
        shape: one of ``SHAPES``.
        num_gaussians: total count; ``round(interior_fraction × num_gaussians)`` of them fill the
            inside (hidden, they give the volume its mass), the rest lie on the surface.
        seed: all randomness (samples and texture colours) derives from it.
        size: largest side of the shape's bounding box, metres; the box is centred on the origin.
        texture: one of ``TEXTURES``.
        interior_fraction: in [0, 1).

    Surface Gaussians come first, then interior ones. Scales are isotropic (identity rotations), so
    fixed orientations stay valid when the binding deforms the object.
    """
    _check_choice(shape, SHAPES, "shape")
    _check_choice(texture, TEXTURES, "texture")
    check_sampling_args(num_gaussians, size, interior_fraction)
    interior_count = min(round(interior_fraction * num_gaussians), num_gaussians - 2)
    surface_count = num_gaussians - interior_count

    generator = torch.Generator().manual_seed(int(seed))
    surface, interior = _sample_shape(_SHAPE_TABLE[shape], surface_count, interior_count, generator)
    center, factor = _canonical_placement(shape, size)
    surface = (surface - center) * factor
    interior = (interior - center) * factor

    surface_sigma, interior_sigma = surface_and_interior_sigmas(surface.numpy(), interior.numpy())
    means = torch.cat([surface, interior]).float()  # [N, 3]
    sigma = torch.from_numpy(np.concatenate([surface_sigma, interior_sigma])).float()  # [N]
    return Gaussians.from_activated(
        means=means,
        scales=sigma.unsqueeze(-1).expand(-1, 3).contiguous(),
        opacities=torch.full((num_gaussians,), OPACITY),
        colors=texture_colors(means, texture, size=size, seed=seed),
    )
