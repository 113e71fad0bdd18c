"""Procedural shapes (checked against independent geometry) and rigid normalisation helpers."""

from __future__ import annotations

import math

import pytest
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.assets.normalize import normalize_gaussians, place_on_ground, rotate_gaussians
from reconphys.assets.procedural import SHAPES, make_procedural_gaussians, procedural_sdf
from reconphys.errors import InputError

NUM = 3000
INTERIOR_FRACTION = 0.3
NUM_INTERIOR = round(NUM * INTERIOR_FRACTION)
SIZE = 0.6  # not the default, so a hard-coded 0.5 would show
BACKGROUND_THRESHOLD = 0.0392


def _norm_xy(p):
    return p[:, :2].norm(dim=-1)


# Independent signed distances (metres) of each analytic shape after normalisation to SIZE, from
# the shape's documented proportions: h = SIZE / 2 is half the largest side.
def _reference_sdf(shape: str, p: torch.Tensor) -> torch.Tensor:
    h = SIZE / 2
    if shape == "sphere":
        return p.norm(dim=-1) - h
    if shape == "box":  # half extents (1, 0.75, 0.5) h
        q = p.abs() - torch.tensor([1.0, 0.75, 0.5], dtype=p.dtype) * h
        return q.clamp_min(0).norm(dim=-1) + q.amax(dim=-1).clamp_max(0)
    if shape == "cylinder":  # radius 0.6 h, half height h, axis z
        q = torch.stack([_norm_xy(p) - 0.6 * h, p[:, 2].abs() - h], dim=-1)
        return q.clamp_min(0).norm(dim=-1) + q.amax(dim=-1).clamp_max(0)
    if shape == "torus":  # major 0.7 h, minor 0.3 h, axis z
        return torch.stack([_norm_xy(p) - 0.7 * h, p[:, 2]], dim=-1).norm(dim=-1) - 0.3 * h
    if shape == "capsule":  # radius 0.5 h, segment z in [-0.5 h, 0.5 h]
        on_axis = torch.zeros_like(p)
        on_axis[:, 2] = p[:, 2].clamp(-0.5 * h, 0.5 * h)
        return (p - on_axis).norm(dim=-1) - 0.5 * h
    if shape == "ellipsoid":  # semi-axes (1, 0.7, 0.5) h; sign and zero set only
        radii = torch.tensor([1.0, 0.7, 0.5], dtype=p.dtype) * h
        return ((p / radii).square().sum(dim=-1) - 1.0) * 0.5 * h
    return procedural_sdf(shape, p, size=SIZE)  # bunny: no closed form to compare with


@pytest.fixture(scope="module")
def shapes() -> dict[str, Gaussians]:
    return {
        shape: make_procedural_gaussians(
            shape, NUM, seed=3, size=SIZE, interior_fraction=INTERIOR_FRACTION
        )
        for shape in SHAPES
    }


@pytest.mark.parametrize("shape", SHAPES)
def test_size_centre_and_count(shapes, shape):
    g = shapes[shape]
    assert g.means.shape == (NUM, 3) and g.num_gaussians == NUM
    assert g.means.dtype == torch.float32
    lower, upper = g.means.amin(dim=0), g.means.amax(dim=0)
    assert (upper - lower).max().item() == pytest.approx(SIZE, rel=0.01)
    assert ((upper + lower) / 2).abs().max().item() < 0.01 * SIZE


@pytest.mark.parametrize("shape", SHAPES)
def test_samples_lie_on_and_inside_the_true_shape(shapes, shape):
    g = shapes[shape]
    means = g.means.double()
    surface, interior = means[: NUM - NUM_INTERIOR], means[NUM - NUM_INTERIOR :]
    assert len(interior) == NUM_INTERIOR
    assert _reference_sdf(shape, surface).abs().max().item() < 1e-5 * SIZE
    assert _reference_sdf(shape, interior).max().item() < 0.0
    assert procedural_sdf(shape, interior, size=SIZE).max().item() < 0.0


@pytest.mark.parametrize("shape", SHAPES)
def test_appearance_values(shapes, shape):
    g = shapes[shape]
    assert (g.colors > BACKGROUND_THRESHOLD + 0.02).all()  # every channel of every Gaussian
    assert ((g.opacities >= 0.9) & (g.opacities <= 0.99)).all()
    assert torch.allclose(g.scales, g.scales[:, :1].expand(-1, 3))  # isotropic
    assert (g.scales > 0).all() and g.scales.max().item() < 0.1 * SIZE
    assert torch.isfinite(g.quats).all() and torch.isfinite(g.sh0).all()


def test_surface_is_closed():
    """A front-facing patch of surface is nearly opaque everywhere: no see-through holes.

    Probes are true surface points (analytic sphere); each surface Gaussian adds opacity
    o·exp(−d²/2σ²) at a probe, and the probe's coverage is 1 − Π(1 − that).
    """
    num, radius = 4000, SIZE / 2
    g = make_procedural_gaussians("sphere", num, seed=5, size=SIZE, interior_fraction=0.0)
    probes = torch.randn(1000, 3, generator=torch.Generator().manual_seed(11), dtype=torch.float64)
    probes = radius * probes / probes.norm(dim=-1, keepdim=True)
    squared = torch.cdist(probes, g.means.double()).square()
    sigma, opacity = g.scales[:, 0].double(), g.opacities.double()
    alpha = opacity * torch.exp(-0.5 * squared / sigma.square())
    coverage = 1.0 - torch.prod(1.0 - alpha, dim=1)
    assert coverage.min().item() > 0.85
    assert coverage.quantile(0.05).item() > 0.97


def test_deterministic_given_seed():
    a = make_procedural_gaussians("torus", 500, seed=7)
    b = make_procedural_gaussians("torus", 500, seed=7)
    c = make_procedural_gaussians("torus", 500, seed=8)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh0"):
        assert torch.equal(getattr(a, name), getattr(b, name))
    assert not torch.allclose(a.means, c.means)


def test_textures_make_rotation_visible():
    def distinct_colors(texture: str) -> int:
        g = make_procedural_gaussians("sphere", 2000, texture=texture, seed=1)
        return len(torch.unique((g.colors * 255).round(), dim=0))

    assert distinct_colors("checker") == 3
    assert distinct_colors("stripes") == 3
    assert distinct_colors("solid") == 1

    # Checker cells: about 7 across the object, so a line through it crosses 6–8 colour changes.
    g = make_procedural_gaussians("box", 6000, texture="checker", size=SIZE, seed=2)
    on_line = (g.means[:, 1] - 0.75 * SIZE / 2).abs() < 1e-6  # the +y face
    on_line &= (g.means[:, 2] - 0.01).abs() < 0.01
    order = g.means[on_line, 0].argsort()
    colors = g.colors[on_line][order]
    changes = (colors[1:] - colors[:-1]).abs().sum(dim=-1) > 1e-3
    assert 5 <= int(changes.sum()) <= 9


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(InputError, match=r"sphere.*torus.*bunny") as info:
        make_procedural_gaussians("dodecahedron", 100)
    assert "dodecahedron" in str(info.value)
    with pytest.raises(InputError, match="checker, stripes, solid"):
        make_procedural_gaussians("sphere", 100, texture="plaid")
    with pytest.raises(InputError, match="interior_fraction"):
        make_procedural_gaussians("sphere", 100, interior_fraction=1.0)
    with pytest.raises(InputError, match="num_gaussians"):
        make_procedural_gaussians("sphere", 3)


# --- normalize.py ---


def _quat_to_matrix(q: torch.Tensor) -> torch.Tensor:  # [N, 4] wxyz → [N, 3, 3]
    w, x, y, z = (q / q.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        dim=-2,
    )


def _covariance(g: Gaussians) -> torch.Tensor:  # [N, 3, 3]
    rotation = _quat_to_matrix(g.quats)
    return rotation @ torch.diag_embed(g.scales.square()) @ rotation.transpose(-1, -2)


def _random_gaussians(n: int = 50) -> Gaussians:
    gen = torch.Generator().manual_seed(0)
    return Gaussians(
        means=torch.rand(n, 3, generator=gen, dtype=torch.float64) * torch.tensor([3.0, 1.0, 2.0])
        + 5.0,
        quats=torch.randn(n, 4, generator=gen, dtype=torch.float64) * 2.0,
        log_scales=torch.randn(n, 3, generator=gen, dtype=torch.float64) - 3.0,
        opacity_logits=torch.randn(n, generator=gen, dtype=torch.float64),
        sh0=torch.randn(n, 3, generator=gen, dtype=torch.float64),
    )


def _distances(points: torch.Tensor) -> torch.Tensor:  # [N, 3] → [N, N], exact (no matmul trick)
    return (points[:, None, :] - points[None, :, :]).norm(dim=-1)


def test_normalize_centres_and_scales_consistently():
    g = _random_gaussians()
    out = normalize_gaussians(g, size=0.5)
    lower, upper = out.means.amin(0), out.means.amax(0)
    assert (upper - lower).max().item() == pytest.approx(0.5)
    assert torch.allclose((upper + lower) / 2, torch.zeros(3, dtype=torch.float64), atol=1e-12)
    factor = 0.5 / (g.means.amax(0) - g.means.amin(0)).max()
    assert torch.allclose(out.scales, g.scales * factor)
    # Relative geometry is a uniformly scaled copy.
    assert torch.allclose(_distances(out.means), _distances(g.means) * factor)
    assert torch.equal(out.quats, g.quats) and torch.equal(out.sh0, g.sh0)


_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh0")


def test_normalize_batched_scenes_independently():
    a, b = _random_gaussians(), _random_gaussians()
    b.means = b.means * 3.0 - 1.0
    batch = Gaussians(**{k: torch.stack([getattr(a, k), getattr(b, k)]) for k in _FIELDS})
    out = normalize_gaussians(batch, size=0.4)
    assert torch.allclose(out.means[0], normalize_gaussians(a, size=0.4).means)
    assert torch.allclose(out.means[1], normalize_gaussians(b, size=0.4).means)


def test_place_on_ground():
    g = _random_gaussians()
    out = place_on_ground(g, height=0.3)
    assert out.means[:, 2].min().item() == pytest.approx(0.3)
    assert torch.allclose(out.means[:, :2], g.means[:, :2])
    shift = out.means[:, 2] - g.means[:, 2]
    assert torch.allclose(shift, shift[:1].expand_as(shift))


def _rotation(axis, angle: float) -> torch.Tensor:
    axis = torch.tensor(axis, dtype=torch.float64)
    axis = axis / axis.norm()
    k = torch.tensor(
        [[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]],
        dtype=torch.float64,
    )
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


@pytest.mark.parametrize(
    "axis, angle",
    [
        ((0, 0, 1), 0.3),
        ((1, 2, 3), 2.0),
        ((1, 0, 0), math.pi),
        ((0.2, -1, 0.1), 3.1),
        ((0, 1, 0), 0),
    ],
)
def test_rotate_rotates_centres_and_covariances(axis, angle):
    g = _random_gaussians()
    rotation = _rotation(axis, angle)
    out = rotate_gaussians(g, rotation)
    assert torch.allclose(out.means, g.means @ rotation.T)
    expected = rotation @ _covariance(g) @ rotation.T
    assert torch.allclose(_covariance(out), expected, atol=1e-12)
    assert torch.allclose(out.quats.norm(dim=-1), g.quats.norm(dim=-1))


def test_rotate_rejects_non_rotations():
    g = _random_gaussians()
    with pytest.raises(InputError, match="rotation"):
        rotate_gaussians(g, torch.diag(torch.tensor([1.0, 1.0, -1.0])))
    with pytest.raises(InputError, match="rotation"):
        rotate_gaussians(g, 2 * torch.eye(3))
