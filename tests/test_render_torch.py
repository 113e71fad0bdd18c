"""Pure-PyTorch rasteriser: checked against independent maths, small images, CPU."""

import math

import pytest
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.render import RenderOutput, available_backends, dataset_views, render
from reconphys.render.torch_backend import MAX_ALPHA, rasterize_torch

F64 = torch.float64
WIDTH = HEIGHT = 64
FOCAL = 60.0


def camera_at_origin(dtype=F64, width=WIDTH, height=HEIGHT, focal=FOCAL):
    """One camera at the world origin looking along +z: world_to_cam [1, 4, 4], K [1, 3, 3]."""
    world_to_cam = torch.eye(4, dtype=dtype)[None]
    K = torch.tensor(
        [[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]], dtype=dtype
    )[None]
    return world_to_cam, K


def identity_quats(n, dtype=F64):
    return torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=dtype).repeat(n, 1)


def random_scene(n, seed, dtype=F64, batch=()):
    """Random Gaussians in a 0.5 m object around (0, 0, 0.3) (world frame, z up)."""
    g = torch.Generator().manual_seed(seed)
    shape = (*batch, n)
    means = (torch.rand(*shape, 3, generator=g, dtype=dtype) - 0.5) * 0.5
    means = means + torch.tensor([0.0, 0.0, 0.3], dtype=dtype)
    quats = torch.randn(*shape, 4, generator=g, dtype=dtype)
    scales = 0.01 + 0.04 * torch.rand(*shape, 3, generator=g, dtype=dtype)
    opacities = 0.05 + 0.9 * torch.rand(*shape, generator=g, dtype=dtype)
    colors = torch.rand(*shape, 3, generator=g, dtype=dtype)
    return means, quats, scales, opacities, colors


def pixel_centres(width=WIDTH, height=HEIGHT, dtype=F64):
    """[H, W, 2] (x + 0.5, y + 0.5)."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype) + 0.5,
        torch.arange(width, dtype=dtype) + 0.5,
        indexing="ij",
    )
    return torch.stack([xs, ys], dim=-1)


def pinhole(point, focal=FOCAL, cx=WIDTH / 2, cy=HEIGHT / 2):
    return torch.stack([focal * point[0] / point[2] + cx, focal * point[1] / point[2] + cy])


def analytic_projection(mean, cov3d, eps2d=0.3):
    """2D centre and covariance by linearising the pinhole map with autograd (the EWA idea)."""
    jacobian = torch.autograd.functional.jacobian(pinhole, mean)  # [2, 3]
    return pinhole(mean), jacobian @ cov3d @ jacobian.T + eps2d * torch.eye(2, dtype=mean.dtype)


def truncated_variance_factor(opacity):
    """Covariance of a 2D Gaussian cut where opacity·exp(−m²/2) < 1/255, relative to the uncut one.

    For m² ~ χ²₂ restricted to m ≤ R: E[x xᵀ] = Σ · (1 − (R²/2) e^{−R²/2} / (1 − e^{−R²/2})).
    """
    half_r2 = math.log(255.0 * opacity)
    return 1.0 - half_r2 * math.exp(-half_r2) / (1.0 - math.exp(-half_r2))


def render_one(means, quats, scales, opacities, colors, **kwargs):
    world_to_cam, K = camera_at_origin(means.dtype)
    rgb, alpha, depth = rasterize_torch(
        means, quats, scales, opacities, colors, world_to_cam, K, WIDTH, HEIGHT, **kwargs
    )
    return rgb[0], alpha[0], depth[0]


def rotation_from_axis_angle(axis, angle):
    """Rotation matrix by the matrix exponential of the cross-product matrix (independent of
    the renderer's quaternion formula)."""
    x, y, z = (torch.tensor(axis, dtype=F64) / torch.tensor(axis, dtype=F64).norm()).tolist()
    cross = torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=F64)
    return torch.linalg.matrix_exp(angle * cross)


def quaternion_from_axis_angle(axis, angle, norm=1.0):
    """(w, x, y, z), scaled by ``norm`` (the renderer must normalise it)."""
    axis = torch.tensor(axis, dtype=F64) / torch.tensor(axis, dtype=F64).norm()
    half = angle / 2
    return norm * torch.cat([torch.tensor([math.cos(half)], dtype=F64), math.sin(half) * axis])


SINGLE_GAUSSIANS = {
    "on-axis isotropic": ((0.0, 0.0, 2.0), (0.12, 0.12, 0.12), ((0.0, 0.0, 1.0), 0.0)),
    "off-axis isotropic": ((0.25, -0.15, 2.0), (0.12, 0.12, 0.12), ((0.0, 0.0, 1.0), 0.0)),
    "rotated anisotropic": ((-0.1, 0.05, 2.5), (0.06, 0.18, 0.1), ((1.0, 2.0, -0.5), 0.8)),
}


@pytest.mark.parametrize("case", SINGLE_GAUSSIANS.values(), ids=SINGLE_GAUSSIANS.keys())
def test_single_gaussian_matches_analytic_projection(case):
    mean, scales, (axis, angle) = case
    mean, scales = torch.tensor(mean, dtype=F64), torch.tensor(scales, dtype=F64)
    opacity = 0.8
    color = torch.tensor([[0.2, 0.5, 0.9]], dtype=F64)
    rgb, alpha, depth = render_one(
        mean[None],
        quaternion_from_axis_angle(axis, angle, norm=1.7)[None],
        scales[None],
        torch.tensor([opacity], dtype=F64),
        color,
    )
    rotation = rotation_from_axis_angle(axis, angle)
    centre, cov2d = analytic_projection(mean, rotation @ torch.diag(scales**2) @ rotation.T)

    # Pixelwise: the analytic alpha, with gsplat's 1/255 cut.
    d = pixel_centres() - centre
    mahalanobis2 = torch.einsum("hwi,ij,hwj->hw", d, torch.linalg.inv(cov2d), d)
    expected = opacity * torch.exp(-0.5 * mahalanobis2)
    expected = torch.where(expected >= 1 / 255, expected, torch.zeros_like(expected))
    torch.testing.assert_close(alpha, expected, atol=1e-10, rtol=1e-8)
    torch.testing.assert_close(rgb, alpha[..., None] * color, atol=1e-12, rtol=0)
    torch.testing.assert_close(depth[alpha > 0], torch.full_like(depth[alpha > 0], mean[2].item()))
    assert (depth[alpha == 0] == 0).all()

    # Moments of the image: centre and σ within 1 % of the analytic projection.
    weights = alpha / alpha.sum()
    measured_centre = torch.einsum("hw,hwi->i", weights, pixel_centres())
    assert (measured_centre - centre).abs().max() < 0.01 * cov2d.diagonal().sqrt().min()
    d = pixel_centres() - measured_centre
    measured_cov = torch.einsum("hw,hwi,hwj->ij", weights, d, d)
    expected_cov = cov2d * truncated_variance_factor(opacity)
    sigma_ratio = measured_cov.diagonal().sqrt() / expected_cov.diagonal().sqrt()
    assert (sigma_ratio - 1).abs().max() < 0.01
    correlation = measured_cov[0, 1] / measured_cov.diagonal().prod().sqrt()
    expected_correlation = expected_cov[0, 1] / expected_cov.diagonal().prod().sqrt()
    assert abs(correlation - expected_correlation) < 0.01


def test_alpha_compositing_of_two_overlapping_gaussians():
    means = torch.tensor([[0.0, 0.0, 2.0], [0.05, 0.02, 3.0]], dtype=F64)
    scales = torch.tensor([[0.1] * 3, [0.2] * 3], dtype=F64)
    opacities = torch.tensor([0.6, 0.7], dtype=F64)
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.5, 1.0]], dtype=F64)
    quats = identity_quats(2)
    rgb, alpha, depth = render_one(means, quats, scales, opacities, colors)

    def alpha_of(i, pixel):
        centre, cov2d = analytic_projection(means[i], scales[i, 0] ** 2 * torch.eye(3, dtype=F64))
        d = pixel - centre
        return opacities[i] * torch.exp(-0.5 * d @ torch.linalg.solve(cov2d, d))

    for x, y in [(32, 32), (35, 30), (28, 36)]:
        pixel = torch.tensor([x + 0.5, y + 0.5], dtype=F64)
        a_near, a_far = alpha_of(0, pixel), alpha_of(1, pixel)
        assert 1 / 255 < min(a_near, a_far) and max(a_near, a_far) < MAX_ALPHA
        expected_alpha = a_near + (1 - a_near) * a_far
        expected_rgb = a_near * colors[0] + (1 - a_near) * a_far * colors[1]
        expected_depth = (a_near * 2.0 + (1 - a_near) * a_far * 3.0) / expected_alpha
        torch.testing.assert_close(alpha[y, x], expected_alpha)
        torch.testing.assert_close(rgb[y, x], expected_rgb)
        torch.testing.assert_close(depth[y, x], expected_depth)

    # The result does not depend on the input order.
    flipped = render_one(means.flip(0), quats, scales.flip(0), opacities.flip(0), colors.flip(0))
    for a, b in zip((rgb, alpha, depth), flipped, strict=True):
        torch.testing.assert_close(a, b)


@pytest.mark.parametrize("near_first", [True, False])
def test_near_opaque_gaussian_hides_far_one(near_first):
    # Both centred on the centre of pixel (32, 32), i.e. at image position (32.5, 32.5).
    offset = 0.5 / FOCAL
    means = torch.tensor(
        [[offset * 1.5, offset * 1.5, 1.5], [offset * 3, offset * 3, 3.0]], dtype=F64
    )
    scales = torch.tensor([[0.1] * 3, [0.4] * 3], dtype=F64)  # 4 px and 8 px on screen
    opacities = torch.tensor([1.0, 1.0], dtype=F64)
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=F64)
    order = [0, 1] if near_first else [1, 0]
    rgb, alpha, depth = render_one(
        means[order], identity_quats(2), scales[order], opacities[order], colors[order]
    )
    centre = (HEIGHT // 2, WIDTH // 2)
    # Near alpha is clamped to 0.999; the far Gaussian would bring the transmittance to about
    # 1e-6 ≤ 1e-4, so compositing stops before it (gsplat's rule): only the near colour is seen.
    assert alpha[centre].item() == pytest.approx(MAX_ALPHA, abs=1e-6)
    torch.testing.assert_close(rgb[centre], MAX_ALPHA * colors[0], atol=1e-6, rtol=0)
    assert depth[centre].item() == pytest.approx(1.5, abs=1e-6)
    # Away from the near Gaussian the far one shows.
    edge = (HEIGHT // 2, WIDTH // 2 + 12)
    assert rgb[edge][2] > rgb[edge][0]


def test_near_plane_culls_and_keeps_gradients_finite():
    means = torch.tensor([[0.0, 0.0, 0.005], [0.0, 0.0, -1.0], [0.0, 0.0, 2.0]], dtype=F64)
    scales = torch.full((3, 3), 0.002, dtype=F64)
    scales[2] = 0.1
    opacities = torch.full((3,), 0.5, dtype=F64)
    colors = torch.eye(3, dtype=F64)
    params = [t.clone().requires_grad_(True) for t in (means, identity_quats(3), scales, opacities)]
    rgb, alpha, _ = render_one(*params, colors)
    # Only the third Gaussian (blue) is in front of the near plane (0.01 m).
    assert rgb[..., :2].abs().max() == 0 and alpha.max() > 0.4
    (rgb.sum() + alpha.sum()).backward()
    for p in params:
        assert torch.isfinite(p.grad).all()
        assert (p.grad[:2] == 0).all()
    # With a nearer plane, the first Gaussian (red, 5 mm in front of the camera) is drawn.
    rgb, _, _ = render_one(means, identity_quats(3), scales, opacities, colors, near_plane=0.001)
    assert rgb[..., 0].max() > 0.1


def gradcheck_inputs() -> list[torch.Tensor]:
    """Three large, half-transparent Gaussians 2–3 m in front of a focal-10 camera (float64,
    requiring grad): means, quats, scales, opacities, colors."""
    means = torch.tensor([[0.0, 0.0, 2.0], [0.2, -0.1, 2.5], [-0.15, 0.2, 3.0]], dtype=F64)
    quats = torch.tensor(
        [[1.0, 0.1, -0.2, 0.3], [0.9, -0.3, 0.2, 0.1], [0.7, 0.2, 0.4, -0.3]], dtype=F64
    )
    scales = torch.tensor([[0.6, 0.8, 0.7], [0.9, 0.7, 0.8], [1.0, 1.2, 0.9]], dtype=F64)
    opacities = torch.tensor([0.5, 0.4, 0.6], dtype=F64)
    colors = torch.tensor([[0.9, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.3, 0.9]], dtype=F64)
    return [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, colors)]


def test_gradients_match_finite_differences():
    """gradcheck in float64 on an 8×8 image, away from the 1/255, 0.999 and 1e-4 cut-offs."""
    width = height = 8
    world_to_cam, K = camera_at_origin(F64, width, height, focal=10.0)
    inputs = gradcheck_inputs()

    def fn(*args):
        return rasterize_torch(*args, world_to_cam, K, width, height, chunk_pixels=16)

    # Stay away from the discontinuities: every Gaussian is above 1/255 on every pixel.
    with torch.no_grad():
        for i in range(3):
            _, alpha, _ = fn(*(t[i : i + 1] for t in inputs))
            assert alpha.min() > 2 / 255 and alpha.max() < 0.9
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_chunking_does_not_change_the_image():
    means, quats, scales, opacities, colors = random_scene(300, seed=1)
    cams = dataset_views(48, 40, dtype=F64)
    args = (means, quats, scales, opacities, colors, cams.world_to_cam, cams.K, 48, 40)
    whole = rasterize_torch(*args, chunk_pixels=48 * 40, chunk_gaussians=10_000)
    tiled = rasterize_torch(*args, chunk_pixels=200, chunk_gaussians=53)
    assert whole[1].max() > 0.9  # the object is in view
    for a, b in zip(whole, tiled, strict=True):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=1e-10)


def test_batch_dims_equal_looping():
    means, quats, scales, opacities, colors = random_scene(50, seed=2, batch=(2,))
    cams = dataset_views(24, 24, dtype=F64).expand((2,))
    batched = rasterize_torch(
        means, quats, scales, opacities, colors, cams.world_to_cam, cams.K, 24, 24
    )
    assert batched[0].shape == (2, 4, 24, 24, 3) and batched[1].shape == (2, 4, 24, 24)
    for b in range(2):
        scene = (means[b], quats[b], scales[b], opacities[b], colors[b])
        single = rasterize_torch(*scene, cams.world_to_cam[b], cams.K[b], 24, 24)
        for a, s in zip(batched, single, strict=True):
            torch.testing.assert_close(a[b], s)


def test_float32_matches_float64():
    scene64 = random_scene(200, seed=3)
    cams = dataset_views(32, 32, dtype=F64)
    out64 = rasterize_torch(*scene64, cams.world_to_cam, cams.K, 32, 32)
    out32 = rasterize_torch(
        *(t.float() for t in scene64), cams.world_to_cam.float(), cams.K.float(), 32, 32
    )
    assert out32[0].dtype == torch.float32
    for a, b in zip(out32, out64, strict=True):
        assert (a.double() - b).abs().mean() < 1e-5


def test_shape_errors_name_the_input():
    means, quats, scales, opacities, colors = random_scene(5, seed=4)
    cams = dataset_views(16, 16, dtype=F64)
    with pytest.raises(ValueError, match="opacities"):
        rasterize_torch(
            means, quats, scales, opacities[:4], colors, cams.world_to_cam, cams.K, 16, 16
        )
    with pytest.raises(ValueError, match="world_to_cam"):
        rasterize_torch(
            means, quats, scales, opacities, colors, cams.world_to_cam[None], cams.K, 16, 16
        )


def test_render_gaussians_with_dataset_views():
    scene = random_scene(400, seed=5, dtype=torch.float32, batch=(2,))
    means, quats, scales, opacities, colors = scene
    gaussians = Gaussians.from_activated(means, scales, opacities, colors, quats)
    out = render(gaussians, dataset_views(32, 32), backend="torch")
    assert isinstance(out, RenderOutput)
    assert out.rgb.shape == (2, 4, 32, 32, 3) and out.depth.shape == (2, 4, 32, 32)
    # The object around the target fills the image centre, at about the camera distance (2 m).
    assert (out.alpha[..., 16, 16] > 0.9).all()
    assert ((out.depth[..., 16, 16] - 2.0).abs() < 0.3).all()
    assert out.rgb.min() >= 0 and out.rgb.max() <= 1 and out.alpha.max() <= 1
    assert "torch" in available_backends()


def test_gsplat_backend_needs_cuda():
    means, quats, scales, opacities, colors = random_scene(4, seed=6, dtype=torch.float32)
    gaussians = Gaussians.from_activated(means, scales, opacities, colors, quats)
    with pytest.raises((RuntimeError, ImportError), match=r"gsplat|CUDA"):
        render(gaussians, dataset_views(16, 16), backend="gsplat")
    with pytest.raises(ValueError, match="backend"):
        render(gaussians, dataset_views(16, 16), backend="opengl")


@pytest.mark.parametrize("sigma_px", [0.15, 0.4])
def test_antialiased_subpixel_gaussian_keeps_its_integral(sigma_px):
    """A Gaussian below a pixel: the image's total alpha is ∫ o·exp(−r²/2σ²) = 2π σ² o in
    antialiased mode (opacity × √(det Σ / det(Σ + εI)) = σ² / (σ² + ε)), while classic mode dilates
    it to 2π (σ² + ε) o. Both less the tail the 1/255 cut drops: a fraction 1 / (255 o′) of a 2D
    Gaussian of peak o′ lies where it is below 1/255."""
    depth, opacity, eps = 2.0, 0.6, 0.3
    scale = sigma_px * depth / FOCAL
    args = (
        torch.tensor([[0.004, -0.003, depth]], dtype=F64),
        identity_quats(1),
        torch.full((1, 3), scale, dtype=F64),
        torch.tensor([opacity], dtype=F64),
        torch.ones(1, 3, dtype=F64),
    )
    _, alpha_aa, _ = render_one(*args, antialiased=True)
    _, alpha_classic, _ = render_one(*args)
    peak = opacity * sigma_px**2 / (sigma_px**2 + eps)
    exact = 2.0 * math.pi * sigma_px**2 * opacity * (1.0 - 1.0 / (255.0 * peak))
    dilated = 2.0 * math.pi * (sigma_px**2 + eps) * opacity * (1.0 - 1.0 / (255.0 * opacity))
    assert float(alpha_aa.sum()) == pytest.approx(exact, rel=0.01)
    assert float(alpha_classic.sum()) == pytest.approx(dilated, rel=0.01)


def test_antialiased_is_classic_for_large_gaussians():
    """σ ≫ √ε: the compensation is ~1 (σ²/(σ² + 0.3) ≥ 0.997 at σ = 10 px)."""
    n = 30
    g = torch.Generator().manual_seed(3)
    means = torch.cat(
        [
            (torch.rand(n, 2, generator=g, dtype=F64) - 0.5) * 0.6,
            torch.full((n, 1), 2.0, dtype=F64),
        ],
        1,
    )
    scales = torch.full((n, 3), 10.0 * 2.0 / FOCAL, dtype=F64)
    args = (
        means,
        identity_quats(n),
        scales,
        torch.full((n,), 0.5, dtype=F64),
        torch.rand(n, 3, generator=g, dtype=F64),
    )
    rgb_aa, alpha_aa, _ = render_one(*args, antialiased=True)
    rgb, alpha, _ = render_one(*args)
    assert (alpha_aa - alpha).abs().mean() < 1e-3  # (a tail crossing the 1/255 cut: ≤ 0.01)
    assert (alpha_aa - alpha).abs().max() < 0.01
    assert (rgb_aa - rgb).abs().max() < 0.01


@pytest.mark.cuda
@pytest.mark.skipif("gsplat" not in available_backends(), reason="needs gsplat and a CUDA GPU")
@pytest.mark.parametrize("antialiased", [False, True])
def test_gsplat_matches_torch_on_cuda(antialiased):
    scene = [t.float().cuda() for t in random_scene(2000, seed=7)]
    cams = dataset_views(64, 64, device="cuda")
    gaussians = Gaussians.from_activated(scene[0], scene[2], scene[3], scene[4], scene[1])
    reference = render(gaussians, cams, backend="torch", antialiased=antialiased)
    fast = render(gaussians, cams, backend="gsplat", antialiased=antialiased)
    assert (reference.rgb - fast.rgb).abs().mean() < 1e-3
    assert (reference.alpha - fast.alpha).abs().mean() < 1e-3
