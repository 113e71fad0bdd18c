"""Compiled CPU compositing (render/numba_backend.py) against its twin, the torch renderer."""

import pytest
import torch
from test_render_torch import F64, camera_at_origin, gradcheck_inputs, identity_quats, random_scene

from reconphys.assets.gaussians import Gaussians
from reconphys.render import auto_backend, available_backends, dataset_views, render
from reconphys.render.numba_backend import rasterize_numba
from reconphys.render.torch_backend import rasterize_torch

NAMES = ("means", "quats", "scales", "opacities", "colors")
pytestmark = pytest.mark.skipif("numba" not in available_backends(), reason="needs numba")


def render_and_grad(rasterize, scene, cams, width, height, seed=0):
    """Images and the gradients of a loss touching rgb, alpha and depth w.r.t. every input."""
    params = [t.clone().requires_grad_(True) for t in scene]
    rgb, alpha, depth = rasterize(*params, cams.world_to_cam, cams.K, width, height)
    g = torch.Generator().manual_seed(seed)
    loss = (rgb * torch.rand(rgb.shape, generator=g, dtype=rgb.dtype)).sum()
    loss = loss + (alpha * torch.rand(alpha.shape, generator=g, dtype=alpha.dtype)).sum()
    loss = loss + (depth * alpha).sum()
    loss.backward()
    return (rgb.detach(), alpha.detach(), depth.detach()), [p.grad for p in params]


@pytest.mark.parametrize(
    ("n", "width", "height", "batch", "seed"),
    [(300, 48, 40, (), 1), (120, 21, 37, (2,), 2), (1, 16, 16, (), 3)],
)
def test_values_and_gradients_match_the_torch_reference(n, width, height, batch, seed):
    """float64, image sides that are no multiple of the 16-px tile, batch dims, 4 views."""
    scene = random_scene(n, seed=seed, batch=batch)
    cams = dataset_views(width, height, dtype=F64)
    if batch:
        cams = cams.expand(batch)
    images, grads = render_and_grad(rasterize_torch, scene, cams, width, height)
    fast_images, fast_grads = render_and_grad(rasterize_numba, scene, cams, width, height)
    assert images[1].max() > 0.1  # the object is in view
    for a, b in zip(images, fast_images, strict=True):
        torch.testing.assert_close(b, a, atol=1e-12, rtol=1e-10)
    for name, a, b in zip(NAMES, grads, fast_grads, strict=True):
        assert a.abs().max() > 0, name
        torch.testing.assert_close(b, a, atol=1e-11, rtol=1e-8, msg=name)


def test_antialiased_mode_matches_the_torch_reference():
    """The antialiased opacities come from the shared projection: values and gradients agree."""
    scene = random_scene(200, seed=4)
    cams = dataset_views(24, 20, dtype=F64)

    def aa(rasterize):
        return lambda *args: rasterize(*args, antialiased=True)

    images, grads = render_and_grad(aa(rasterize_torch), scene, cams, 24, 20)
    fast_images, fast_grads = render_and_grad(aa(rasterize_numba), scene, cams, 24, 20)
    classic, _ = render_and_grad(rasterize_torch, scene, cams, 24, 20)
    assert (images[1] - classic[1]).abs().max() > 1e-3  # the mode changes the image
    for a, b in zip(images, fast_images, strict=True):
        torch.testing.assert_close(b, a, atol=1e-12, rtol=1e-10)
    for name, a, b in zip(NAMES, grads, fast_grads, strict=True):
        torch.testing.assert_close(b, a, atol=1e-11, rtol=1e-8, msg=name)


def test_float32_matches_the_reference():
    scene = [t.float() for t in random_scene(400, seed=4)]
    cams = dataset_views(32, 32)
    images, grads = render_and_grad(rasterize_torch, scene, cams, 32, 32)
    fast_images, fast_grads = render_and_grad(rasterize_numba, scene, cams, 32, 32)
    assert fast_images[0].dtype == torch.float32 and fast_grads[0].dtype == torch.float32
    for a, b in zip(images, fast_images, strict=True):
        assert (a - b).abs().max() < 1e-5
    for a, b in zip(grads, fast_grads, strict=True):
        assert (a - b).norm() <= 1e-5 * a.norm()


def test_opaque_stack_stops_like_the_reference():
    """Twenty near-opaque Gaussians on one pixel: compositing stops before the transmittance would
    reach 1e-4, and some alphas are clamped to 0.999 (no gradient through the clamp)."""
    n = 20
    means = torch.zeros(n, 3, dtype=F64)
    means[:, 2] = torch.linspace(1.5, 3.0, n, dtype=F64)
    scales = torch.full((n, 3), 0.2, dtype=F64)
    opacities = torch.linspace(0.97, 1.0, n, dtype=F64)
    colors = torch.rand(n, 3, generator=torch.Generator().manual_seed(5), dtype=F64)
    scene = (means, identity_quats(n), scales, opacities, colors)
    world_to_cam, K = camera_at_origin(F64, 32, 32)
    cams = type("Cams", (), {"world_to_cam": world_to_cam, "K": K})
    images, grads = render_and_grad(rasterize_torch, scene, cams, 32, 32)
    fast_images, fast_grads = render_and_grad(rasterize_numba, scene, cams, 32, 32)
    centre = fast_images[1][0, 16, 16].item()
    assert 0.998 < centre < 1 - 1e-4  # saturated, but stopped above 1e-4 transmittance
    for a, b in zip(images, fast_images, strict=True):
        torch.testing.assert_close(b, a, atol=1e-12, rtol=1e-10)
    for a, b in zip(grads, fast_grads, strict=True):
        torch.testing.assert_close(b, a, atol=1e-11, rtol=1e-8)


def test_gradients_match_finite_differences():
    """gradcheck in float64, independent of the reference: 3 Gaussians on a 12×10 image, every
    alpha between 2/255 and 0.9 (away from the cut-offs)."""
    width, height = 12, 10
    world_to_cam, K = camera_at_origin(F64, width, height, focal=10.0)
    inputs = gradcheck_inputs()

    def fn(*args):
        return rasterize_numba(*args, world_to_cam, K, width, height)

    with torch.no_grad():
        for i in range(3):
            _, alpha, _ = fn(*(t[i : i + 1] for t in inputs))
            assert alpha.min() > 2 / 255 and alpha.max() < 0.9
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_nothing_visible_gives_black_images_and_zero_gradients():
    means, quats, scales, opacities, colors = random_scene(10, seed=6)
    means = means - torch.tensor([0.0, 0.0, 10.0], dtype=F64)  # far below the ground, behind
    world_to_cam, K = camera_at_origin(F64, 16, 16)
    params = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, colors)]
    rgb, alpha, depth = rasterize_numba(*params, world_to_cam, K, 16, 16)
    assert rgb.abs().max() == 0 and alpha.abs().max() == 0 and depth.abs().max() == 0
    (rgb.sum() + alpha.sum()).backward()
    assert all((p.grad == 0).all() for p in params)


def test_render_picks_numba_on_cpu_and_agrees_with_torch():
    scene = random_scene(200, seed=7, dtype=torch.float32, batch=(2,))
    means, quats, scales, opacities, colors = scene
    gaussians = Gaussians.from_activated(means, scales, opacities, colors, quats)
    assert auto_backend(torch.device("cpu")) == "numba"
    fast = render(gaussians, dataset_views(24, 24))
    reference = render(gaussians, dataset_views(24, 24), backend="torch")
    for name in ("rgb", "alpha", "depth"):
        assert (getattr(fast, name) - getattr(reference, name)).abs().max() < 1e-5, name


def test_errors_name_the_input():
    means, quats, scales, opacities, colors = random_scene(5, seed=8)
    cams = dataset_views(16, 16, dtype=F64)
    with pytest.raises(ValueError, match="scales"):
        rasterize_numba(
            means, quats, scales[:3], opacities, colors, cams.world_to_cam, cams.K, 16, 16
        )
    if torch.cuda.is_available():  # pragma: no cover - CI has no GPU
        with pytest.raises(ValueError, match="CPU"):
            rasterize_numba(*(t.cuda() for t in (means, quats, scales, opacities, colors)),
                            cams.world_to_cam.cuda(), cams.K.cuda(), 16, 16)  # fmt: skip
