"""The feed-forward 3DGS predictor: placement along the pixel rays, world-frame rotations,
gradients, pruning, and its training (loss goes down, exact resume)."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch
from helpers import make_tiny_dataset

from reconphys.assets.gaussians import SH_C0, Gaussians
from reconphys.capture import CameraSpec, default_camera
from reconphys.capture.observation import stored_observation
from reconphys.capture.placement import project
from reconphys.errors import InputError
from reconphys.geometry import quaternion_multiply
from reconphys.models.gaussian_predictor import (
    DETAIL_OVERLAP,
    GaussianPredictor,
    GaussianPredictorConfig,
    billboard_gaussians,
    prune_gaussians,
    upsampled_outputs,
)
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.models.model_input import frame_crop
from reconphys.models.reconstruct import object_distance
from reconphys.render import Cameras, render
from reconphys.train.gaussians import (
    GaussianTrainSettings,
    depth_error,
    frame0_views,
    scaled_about_camera,
    shape_error,
    train_gaussian_predictor,
)


def quaternion_matrix(q: torch.Tensor) -> torch.Tensor:  # [..., 4] wxyz → [..., 3, 3]
    w, x, y, z = torch.nn.functional.normalize(q, dim=-1).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(*q.shape[:-1], 3, 3)


def zero_head_model(size: int = 16) -> GaussianPredictor:
    model = GaussianPredictor(GaussianPredictorConfig(resolution=size, channels=[8, 16]))
    with torch.no_grad():
        model.unet.head.weight.zero_()
        model.unet.head.bias.zero_()
        model.unet.head.bias[7] = 1.0  # identity rotation in the camera frame
    return model


def test_gaussians_sit_on_their_pixel_rays_at_the_reference_depth():
    camera = default_camera(16, 16, view=1)
    model = zero_head_model()
    g = model(
        torch.rand(1, 16, 16, 3),
        torch.ones(1, 16, 16),
        camera.K[None].float(),
        camera.world_to_cam[None].float(),
    )
    uv, depth = project(g.means[0].double(), camera)
    centres = torch.arange(16, dtype=torch.float64) + 0.5
    v, u = torch.meshgrid(centres, centres, indexing="ij")
    assert torch.allclose(uv, torch.stack([u.reshape(-1), v.reshape(-1)], -1), atol=1e-4)
    assert torch.allclose(depth, torch.full_like(depth, 2.0), atol=1e-5)


def test_rotations_are_turned_from_the_camera_to_the_world_frame():
    camera = default_camera(16, 16, view=2)
    model = zero_head_model()
    q_cam = torch.nn.functional.normalize(torch.tensor([0.9, 0.2, -0.3, 0.1]), dim=0)
    with torch.no_grad():
        model.unet.head.bias[7:11] = q_cam * 5  # any scale: normalised by the model
    g = model(
        torch.rand(1, 16, 16, 3),
        torch.ones(1, 16, 16),
        camera.K[None].float(),
        camera.world_to_cam[None].float(),
    )
    cam_to_world = camera.world_to_cam[:3, :3].T.float()
    expected = cam_to_world @ quaternion_matrix(q_cam)  # world ← camera ← Gaussian
    assert torch.allclose(quaternion_matrix(g.quats[0, 0]), expected, atol=1e-5)
    # the product helper agrees on the composition order
    assert quaternion_multiply(q_cam, torch.tensor([1.0, 0, 0, 0])).allclose(q_cam)


def test_gradients_reach_every_output_head():
    model = GaussianPredictor(GaussianPredictorConfig(resolution=16, channels=[8, 16]))
    camera = default_camera(16, 16)
    g = model(
        torch.rand(2, 16, 16, 3),
        torch.ones(2, 16, 16),
        camera.K[None].expand(2, 3, 3).float(),
        camera.world_to_cam[None].expand(2, 4, 4).float(),
    )
    loss = g.means.sum() + g.quats.sum() + g.log_scales.sum() + g.opacity_logits.sum() + g.sh0.sum()
    loss.backward()
    grad = model.unet.head.weight.grad
    assert torch.isfinite(grad).all() and bool((grad.abs().sum((1, 2, 3)) > 0).all())


def test_pruning_keeps_opaque_object_pixels_and_caps_the_count():
    model = zero_head_model(8)
    camera = default_camera(8, 8)
    g = model(
        torch.rand(1, 8, 8, 3),
        torch.ones(1, 8, 8),
        camera.K[None].float(),
        camera.world_to_cam[None].float(),
    ).map(lambda t: t[0])
    g.opacity_logits = torch.linspace(-6, 6, 64)
    mask = torch.zeros(64)
    mask[::2] = 1
    kept = prune_gaussians(g, mask, min_opacity=0.5)
    assert kept.num_gaussians == int(((g.opacities >= 0.5) & (mask > 0)).sum())
    capped = prune_gaussians(g, mask, min_opacity=0.0, max_count=5)
    assert torch.equal(capped.opacity_logits, g.opacity_logits[mask > 0][-5:])
    with pytest.raises(ValueError):
        prune_gaussians(g, torch.zeros(64))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_tiny_dataset(
        tmp_path_factory.mktemp("gs") / "data",
        objects=2,
        samples_per_object=1,
        test_objects=0,
        seed=2,
    )


def _settings(data, out, **kw):
    return GaussianTrainSettings(
        data=str(data),
        out=str(out),
        steps=4,
        batch_size=2,
        checkpoint_every=2,
        predictor={"channels": [8, 16]},
        **kw,
    )


def test_training_lowers_the_loss_and_resumes_exactly(dataset, tmp_path):
    torch.set_num_threads(1)
    reference = train_gaussian_predictor(
        _settings(dataset, tmp_path / "a", lr=3e-3), progress=False, log=lambda s: None
    )
    log = [json.loads(x) for x in (reference / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4]
    assert log[-1]["loss"] < log[0]["loss"]
    killed = _settings(dataset, tmp_path / "b", lr=3e-3)
    train_gaussian_predictor(killed, progress=False, log=lambda s: None, stop_after=3)
    assert not (tmp_path / "b" / "model.safetensors").exists()
    train_gaussian_predictor(killed, progress=False, log=lambda s: None)  # resumes at step 3
    resumed = [json.loads(x) for x in (tmp_path / "b" / "log.jsonl").read_text().splitlines()]
    assert resumed == log
    loaded = load_gaussian_predictor(tmp_path / "b")
    assert loaded.metadata["predictor"]["resolution"] == 32
    with pytest.raises(Exception, match="other settings"):
        train_gaussian_predictor(
            _settings(dataset, tmp_path / "b", lr=1e-3), progress=False, log=lambda s: None
        )


# --- the object-centric (crop) predictor ---------------------------------------------------


def blob(count: int = 200, seed: int = 0) -> Gaussians:
    """A coloured ellipsoidal cloud of small Gaussians, 0.3 m across, 0.5 m above the origin."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=g) * torch.tensor([0.08, 0.05, 0.06])
    return Gaussians(
        means=means + torch.tensor([0.0, 0.0, 0.5]),
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(count, 4).clone(),
        log_scales=torch.full((count, 3), math.log(0.02)),
        opacity_logits=torch.full((count,), 3.0),
        sh0=(torch.rand(count, 3, generator=g) - 0.5) / SH_C0,
    )


def centroid(alpha: torch.Tensor) -> torch.Tensor:  # [H, W] → (u, v) pixels
    v, u = torch.meshgrid(
        torch.arange(alpha.shape[0]) + 0.5, torch.arange(alpha.shape[1]) + 0.5, indexing="ij"
    )
    return torch.stack([(alpha * u).sum(), (alpha * v).sum()]) / alpha.sum()


def test_a_frame_crop_is_the_pinhole_image_of_its_intrinsics():
    """The object cropped out of a 256-px render and resampled to 32 px is the render at the
    crop's intrinsics (crop_intrinsics): colours to ~1 %, the silhouette's centroid to a third of a
    pixel (the crop cuts the faint rim outside the mask; a principal point 2 px off is 2 px off)."""
    big = default_camera(256, 256, view=1)
    gaussians = blob()
    with torch.no_grad():
        out = render(
            gaussians, Cameras(big.K[None].float(), big.world_to_cam[None].float(), 256, 256)
        )
    image, alpha = out.rgb[0], out.alpha[0].reshape(256, 256)
    crop, crop_mask, K = frame_crop(image, (alpha > 0.5).float(), big.K.float(), 32)
    assert 0.1 < float(crop_mask.mean()) < 0.8  # the object fills the crop, with a margin
    soft, _, _ = frame_crop(
        alpha[..., None].expand(-1, -1, 3), (alpha > 0.5).float(), big.K.float(), 32
    )
    with torch.no_grad():
        direct = render(gaussians, Cameras(K[None], big.world_to_cam[None].float(), 32, 32))
    assert float((direct.rgb[0] * crop_mask[..., None] - crop).abs().mean()) < 0.02
    direct_alpha = direct.alpha[0].reshape(32, 32)
    assert float((centroid(direct_alpha) - centroid(soft[..., 0])).abs().max()) < 0.35
    shifted = K.clone()
    shifted[0, 2] += 2.0
    with torch.no_grad():
        moved = render(gaussians, Cameras(shifted[None], big.world_to_cam[None].float(), 32, 32))
    moved_alpha = moved.alpha[0].reshape(32, 32)
    assert abs(float(centroid(moved_alpha)[0] - centroid(soft[..., 0])[0]) - 2.0) < 0.35


def test_a_crop_model_places_relative_to_the_reference_depth():
    """A crop model with a zero head puts every Gaussian on its pixel's ray at the reference
    depth, with its pixel's colour; twice the depth (the same crop) gives twice the distance and
    twice the sizes: one network for every object size and distance."""
    config = GaussianPredictorConfig(resolution=16, channels=[8, 16], crop=True)
    model = GaussianPredictor(config)
    with torch.no_grad():
        model.unet.head.weight.zero_()
        model.unet.head.bias.zero_()
        model.unet.head.bias[7] = 1.0
    camera = default_camera(16, 16, view=0)
    inputs = (
        torch.rand(1, 16, 16, 3),
        torch.ones(1, 16, 16),
        camera.K[None].float(),
        camera.world_to_cam[None].float(),
    )
    with pytest.raises(ValueError, match="reference_depth"):
        model(*inputs)
    near = model(*inputs, torch.tensor([1.5])).map(lambda t: t[0])
    far = model(*inputs, torch.tensor([3.0])).map(lambda t: t[0])
    uv, depth = project(near.means.double(), camera)
    centres = torch.arange(16, dtype=torch.float64) + 0.5
    v, u = torch.meshgrid(centres, centres, indexing="ij")
    assert torch.allclose(uv, torch.stack([u, v], -1).reshape(-1, 2), atol=1e-3)
    assert torch.allclose(depth, torch.full_like(depth, 1.5), atol=1e-4)
    eye = -camera.world_to_cam[:3, :3].T.double() @ camera.world_to_cam[:3, 3].double()
    ratio = (far.means.double() - eye).norm(dim=-1) / (near.means.double() - eye).norm(dim=-1)
    assert torch.allclose(ratio, torch.full_like(ratio, 2.0), atol=1e-4)
    assert torch.allclose(
        far.log_scales - near.log_scales, torch.full_like(near.log_scales, math.log(2)), atol=1e-5
    )
    colours = near.sh0 * SH_C0 + 0.5  # the input pixels' own colours (no correction yet)
    assert torch.allclose(colours, inputs[0].reshape(-1, 3).clamp(0.01, 0.99), atol=1e-5)


def crop_model(size: int = 16) -> GaussianPredictor:
    """A crop model with a zero head but for a depth that varies across the crop (with one of
    the U-Net's features)."""
    torch.manual_seed(0)
    model = GaussianPredictor(GaussianPredictorConfig(resolution=size, channels=[8, 16], crop=True))
    with torch.no_grad():
        model.unet.head.weight.zero_()
        model.unet.head.bias.zero_()
        model.unet.head.bias[7] = 1.0
        model.unet.head.weight[0, 6] = 0.5
        model.unet.head.bias[4:7] = 1.07  # σ half a pixel: the Gaussians cover their pixels
        model.unet.head.bias[11] = 4.0  # opaque
    return model


def checker(size: int, squares: int = 8) -> torch.Tensor:  # [S, S, 3]: squares × squares
    index = torch.arange(size) * squares // size
    pattern = ((index[:, None] + index[None, :]) % 2).float()
    return torch.stack(
        [0.2 + 0.6 * pattern, 0.8 - 0.6 * pattern, torch.full_like(pattern, 0.5)], -1
    )


def test_detail_at_the_models_size_is_the_plain_forward():
    model, camera = crop_model(), default_camera(16, 16, view=0)
    inputs = (torch.rand(1, 16, 16, 3), torch.ones(1, 16, 16))
    K, w2c = camera.K[None].float(), camera.world_to_cam[None].float()
    depth = torch.tensor([2.0])
    plain = model(*inputs, K, w2c, depth)
    same = model(*inputs, K, w2c, depth, detail=inputs)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh0"):
        assert torch.equal(getattr(plain, name), getattr(same, name)), name
    with pytest.raises(ValueError, match="S ≥ 16"):
        model(*inputs, K, w2c, depth, detail=(torch.rand(1, 8, 8, 3), torch.ones(1, 8, 8)))


def test_detail_keeps_the_surface_and_draws_the_finer_crop():
    """The network reads a 16-px crop; on a 48-px crop of the same square its Gaussians lie on
    the same depth surface (interpolated between the 16-px pixels' depths), a third the size,
    one per fine pixel, on that pixel's ray, with that pixel's colour (the 16-px ones carry
    the checker's squares at a third of the resolution)."""
    model, camera = crop_model(), default_camera(16, 16, view=0)
    K, w2c = camera.K[None].float(), camera.world_to_cam[None].float()
    fine_K = K.clone()
    fine_K[:, :2] *= 3
    image = checker(48)  # squares of 6 fine pixels, 2 coarse ones
    coarse_image = image.reshape(16, 3, 16, 3, 3).mean((1, 3))  # the same crop, area-averaged
    depth = torch.tensor([2.0])
    with torch.no_grad():
        plain = model(coarse_image[None], torch.ones(1, 16, 16), K, w2c, depth)
        fine = model(
            coarse_image[None], torch.ones(1, 16, 16), K, w2c, depth,
            detail=(image[None], torch.ones(1, 48, 48)),
        )  # fmt: skip
    assert fine.means.shape[1] == 9 * plain.means.shape[1]
    camera_z = lambda g: g.means[0] @ w2c[0, :3, :3].T[:, 2] + w2c[0, 2, 3]  # noqa: E731
    plain_z, fine_z = camera_z(plain).reshape(16, 16), camera_z(fine).reshape(48, 48)
    assert float(plain_z.std()) > 1e-3  # the surface is not flat
    assert float(fine_z.min()) >= float(plain_z.min()) - 1e-5
    assert float(fine_z.max()) <= float(plain_z.max()) + 1e-5
    blocks = fine_z.reshape(16, 3, 16, 3).mean((1, 3))  # each coarse pixel's 3 × 3 fine ones
    assert float((blocks - plain_z).abs().mean()) < 0.25 * float(plain_z.std())
    shrink = fine.log_scales.mean() - plain.log_scales.mean()
    assert abs(float(shrink) - math.log(DETAIL_OVERLAP / 3)) < 1e-4
    colours = fine.sh0[0] * SH_C0 + 0.5  # each fine pixel's own colour (no correction yet)
    assert torch.allclose(colours, image.reshape(-1, 3).clamp(0.01, 0.99), atol=1e-5)
    fine_camera = CameraSpec(fine_K[0].double(), w2c[0].double(), 48, 48)
    uv, _ = project(fine.means[0].double(), fine_camera)  # on its own fine pixel's ray
    centres = torch.arange(48, dtype=torch.float64) + 0.5
    v, u = torch.meshgrid(centres, centres, indexing="ij")
    assert torch.allclose(uv, torch.stack([u, v], -1).reshape(-1, 2), atol=1e-3)


def test_the_detail_does_not_take_the_backgrounds_outputs():
    """An edge pixel of the fine crop takes the outputs of the object's pixels near it, not of
    the background's (untrained there: their depths would fly off the surface)."""
    mask = torch.zeros(1, 8, 8)
    mask[:, 2:6, 2:6] = 1
    out = torch.where(mask[..., None] > 0, 1.0, 100.0).expand(1, 8, 8, 3)
    fine = upsampled_outputs(out, mask, 32)
    fine_mask = mask.repeat_interleave(4, 1).repeat_interleave(4, 2)
    assert torch.allclose(fine[fine_mask > 0], torch.ones(1)), float(fine[fine_mask > 0].max())
    assert float(fine.max()) == 100.0  # far from the object: the background's own


def test_a_crop_model_trains_on_the_realistic_look(tmp_path):
    """train-gs refuses a realistic-look dataset for a whole-frame model and trains a crop
    model on it (frames masked by the stored true masks, every view cropped)."""
    torch.set_num_threads(1)
    data = make_tiny_dataset(
        tmp_path / "real", objects=1, samples_per_object=1, test_objects=0, scene="realistic"
    )
    with pytest.raises(InputError, match="plain"):
        train_gaussian_predictor(
            _settings(data, tmp_path / "a"), progress=False, log=lambda s: None
        )
    settings = GaussianTrainSettings(
        data=str(data),
        out=str(tmp_path / "b"),
        steps=3,
        batch_size=1,
        lr=3e-3,
        predictor={
            "channels": [8, 16],
            "crop": True,
            "resolution": 16,
            "depth_range": 0.5,
            "offset_range": 0.05,
            "min_scale": 0.004,
            "max_scale": 0.1,
        },
    )
    out = train_gaussian_predictor(settings, progress=False, log=lambda s: None)
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert all(math.isfinite(r["loss"]) for r in log)
    assert load_gaussian_predictor(out).model.config.crop
    assert "shape" not in log[0]

    settings.out, settings.shape_weight, settings.depth_weight = str(tmp_path / "c"), 1.0, 1.0
    out = train_gaussian_predictor(settings, progress=False, log=lambda s: None)
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert all(math.isfinite(r["shape"]) and r["shape"] > 0 for r in log)
    assert all(math.isfinite(r["depth"]) for r in log)
    assert all(r["loss"] > r["colour"] for r in log)  # the shape terms are in the loss

    # Fine-tuning starts from the given predictor's weights (a negligible step keeps them); one
    # of other settings is refused, naming it.
    start = load_gaussian_predictor(out).model.state_dict()
    tuned = dataclasses.replace(settings, out=str(tmp_path / "d"), steps=1, lr=1e-12, init=str(out))
    loaded = load_gaussian_predictor(train_gaussian_predictor(tuned, progress=False))
    for name, tensor in loaded.model.state_dict().items():
        assert torch.allclose(tensor, start[name], atol=1e-6), name
    lineage = loaded.metadata["training"]["init"]  # the start's own training is kept
    assert lineage["path"] == str(out) and lineage["training"]["settings"]["shape_weight"] == 1.0
    other = dataclasses.replace(
        tuned, out=str(tmp_path / "e"), predictor={**settings.predictor, "channels": [8]}
    )
    with pytest.raises(InputError, match="settings differ") as error:
        train_gaussian_predictor(other, progress=False)
    assert str(out) in str(error.value)

    # The true centres are frame 0's object: they project onto its stored mask.
    from reconphys.data import DropDataset

    dataset = DropDataset(data, split="train", frames=[0])
    views = frame0_views(dataset, 0, truth=True)
    size = views["masks"].shape[-1]
    view0 = CameraSpec(views["K"][0], views["world_to_cam"][0], size, size)
    uv, _ = project(views["truth"].means, view0)
    inside = ((uv >= 0) & (uv < size)).all(1)
    pixel = uv[inside].long()
    on_mask = views["masks"][0][pixel[:, 1], pixel[:, 0]] > 0.5
    assert float(inside.float().mean()) == 1.0
    assert float(on_mask.float().mean()) > 0.8, float(on_mask.float().mean())


def test_the_depth_error_is_the_squared_depth_gap_where_both_cover():
    """Two flat cut-outs of one square, 2.0 m and 2.1 m from the camera: every covered pixel's
    expected depth is its plane's, so the error is 0.1² over the centres' mean squared radius
    in that view, and 0 against itself; a view where they do not overlap scores 0."""
    camera = default_camera(32, 32, view=0)
    K, w2c = camera.K.float(), camera.world_to_cam.float()
    mask = torch.zeros(32, 32)
    mask[10:22, 8:20] = 1
    image = torch.full((32, 32, 3), 0.5)
    near = billboard_gaussians(image, mask, K, w2c, 2.0)
    far = billboard_gaussians(image, mask, K, w2c, 2.1)
    cameras = Cameras(K[None], w2c[None], 32, 32)
    truth, out = render(near, cameras), render(far, cameras)
    radius2 = float(((near.means - near.means.mean(0)) ** 2).sum(1).mean())
    assert math.isclose(float(depth_error(out, truth, near.means)[0]), 0.01 / radius2, rel_tol=1e-3)
    assert float(depth_error(truth, truth, near.means)[0]) == 0.0
    moved = near.map(lambda t: t.clone())
    moved.means = moved.means + 10.0  # out of view: nothing covered by both
    assert float(depth_error(render(moved, cameras), truth, near.means)[0]) == 0.0


def test_gaussians_scaled_about_a_camera_look_the_same_there_and_lie_deeper():
    """scaled_about_camera: in its own camera the picture is unchanged (a pinhole cannot see the
    scale) and every pixel's depth is ×factor; from another view the two differ."""
    generator = torch.Generator().manual_seed(1)
    gaussians = Gaussians.from_activated(
        means=torch.randn(60, 3, generator=generator) * 0.1 + torch.tensor([0.0, 0.0, 0.3]),
        scales=torch.full((60, 3), 0.03),
        opacities=torch.full((60,), 0.8),
        colors=torch.rand(60, 3, generator=generator),
        quats=torch.nn.functional.normalize(torch.randn(60, 4, generator=generator), dim=-1),
    )
    views = [default_camera(32, 32, view=v) for v in (0, 1)]
    K = torch.stack([c.K.float() for c in views])
    w2c = torch.stack([c.world_to_cam.float() for c in views])
    cameras = Cameras(K, w2c, 32, 32)
    before = render(gaussians, cameras)
    after = render(scaled_about_camera(gaussians, w2c[0], 1.2), cameras)
    assert torch.allclose(after.rgb[0], before.rgb[0], atol=1e-4)
    assert torch.allclose(after.alpha[0], before.alpha[0], atol=1e-4)
    covered = before.alpha[0].reshape(32, 32) > 0.5
    ratio = after.depth[0].reshape(32, 32)[covered] / before.depth[0].reshape(32, 32)[covered]
    assert torch.allclose(ratio, torch.full_like(ratio, 1.2), rtol=1e-3)
    assert float((after.rgb[1] - before.rgb[1]).abs().max()) > 0.05


def test_the_shape_error_is_the_mean_squared_nearest_distance_over_the_size():
    """shape_error against scipy's k-d tree: one-sided (a subset of the object scores 0), in
    units of the object's mean squared radius (the same at any scale)."""
    from scipy.spatial import cKDTree

    generator = torch.Generator().manual_seed(0)
    points = torch.randn(300, 3, generator=generator, dtype=torch.float64) * 0.1
    assert float(shape_error(points[:50], points)) == 0.0
    means = points[:80] + 0.02 * torch.randn(80, 3, generator=generator, dtype=torch.float64)
    nearest, _ = cKDTree(points.numpy()).query(means.numpy())
    radius2 = ((points - points.mean(0)) ** 2).sum(1).mean()
    expected = (nearest**2).mean() / float(radius2)
    assert math.isclose(float(shape_error(means, points)), expected, rel_tol=1e-9)
    assert math.isclose(float(shape_error(3 * means, 3 * points)), expected, rel_tol=1e-9)


def sliding_masks(rows: slice) -> torch.Tensor:  # [30, 64, 64]: 8 px wide, 1 px a frame right
    masks = torch.zeros(30, 64, 64)
    for t in range(30):
        masks[t, rows, 14 + t : 22 + t] = 1.0
    return masks


def test_the_object_distance_without_a_fall_is_where_it_rests_on_the_ground():
    """No free fall to read (the object slides along the ground from the first frame): the
    distance is where the ray through its last lowest pixel meets the camera's ground — that
    point is on z = 0 — and an object whose rays never meet the ground (above the horizon) is
    refused, asking for the geometry."""
    camera = default_camera(64, 64, view=0)
    observations = []
    for name, rows in (("slide", slice(44, 50)), ("sky", slice(2, 6))):
        masks = sliding_masks(rows)
        frames = masks[..., None].expand(-1, -1, -1, 3) * 0.5
        observations.append(
            stored_observation(frames, camera.K, camera.world_to_cam, 0.03, name, masks=masks)
        )
    depth, how, _ = object_distance(observations[0])
    assert how == "rest on the ground"
    K, w2c = camera.K.double(), camera.world_to_cam.double()
    pixel = torch.tensor([47.0, 50.0, 1.0], dtype=torch.float64)  # last frame: bottom edge, centre
    point_cam = depth * torch.linalg.solve(K, pixel)
    point_world = w2c[:3, :3].T @ (point_cam - w2c[:3, 3])
    assert abs(float(point_world[2])) < 1e-6
    with pytest.raises(InputError, match="--gaussians or --mesh"):
        object_distance(observations[1])


def test_a_fall_read_at_another_speed_names_the_rate_it_was_filmed_at():
    """Played s× slower than filmed, gravity shows s² weaker and the fall reads the object s²
    farther than it rests: a 30-fps drop played at 20 fps reads ×2.25 and names 30 fps; a 30-fps
    drop played at 60 (fast) reads ×0.25 and names 30 fps too."""
    from reconphys.models.reconstruct import _fall_rest_warning

    slow = _fall_rest_warning(4.5, 2.0, 20.0)
    assert "×2.2 where it rests" in slow and "slower (slow motion?)" in slow
    assert slow.endswith("--fps (about 30 fps)")
    fast = _fall_rest_warning(0.5, 2.0, 60.0)
    assert "plays faster" in fast and fast.endswith("--fps (about 30 fps)")
    assert _fall_rest_warning(2e4, 2.0, 30.0).endswith("--fps (its real frame rate)")  # ×100


def test_a_fall_misread_against_a_known_cameras_ground_gives_way_to_the_rest():
    """With a known camera the fall's distance is checked against where the object rests on its
    ground: a fall whose pixels accelerate ten times too slowly (read ~10× too far) is not used,
    the rest is (and prediction.json says why); with a camera read from the video the ground
    itself comes from the fall, so the fall stands. A distance that makes the object over
    MAX_READ_SIZE_M across is refused, naming the camera file."""
    from dataclasses import replace

    from reconphys.capture.calibrate import object_depth, rest_depth

    camera = default_camera(64, 64, view=0)
    masks = torch.zeros(30, 64, 64)
    for t in range(30):  # 6 px, falling at 40 px/s² from row 10 (a 0.9-s fall: 15 px)
        top = 10 + round(0.5 * 40.0 * (t * 0.03) ** 2)
        masks[t, top : top + 6, 29:35] = 1.0
    frames = masks[..., None].expand(-1, -1, -1, 3) * 0.5
    known = stored_observation(frames, camera.K, camera.world_to_cam, 0.03, "slow", masks=masks)
    fall = object_depth(masks, 0.03, camera)
    rest = rest_depth(masks, camera)
    assert fall > 2 * rest > 0
    depth, how, warning = object_distance(known)
    assert depth == rest and how.startswith("rest on the ground (the fall read")
    assert "plays slower (slow motion?)" in warning and "--fps (its real frame rate)" in warning
    estimated = replace(known, camera_estimate={"how": "from the video"})
    assert object_distance(estimated) == (fall, "fall", None)
    wide = torch.zeros(30, 64, 64)
    for t in range(30):  # 24 px wide, falling at 20 px/s² from the top: resting ~13 m away
        top = round(0.5 * 20.0 * (t * 0.03) ** 2)
        wide[t, top : top + 6, 20:44] = 1.0
    frames = wide[..., None].expand(-1, -1, -1, 3) * 0.5
    far = stored_observation(frames, camera.K, camera.world_to_cam, 0.03, "wide", masks=wide)
    with pytest.raises(InputError, match=r"the object would be 3\.\d+ m across"):
        object_distance(far)
