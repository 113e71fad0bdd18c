"""The feed-forward 3DGS predictor: placement along the pixel rays, world-frame rotations,
gradients, pruning, and its training (loss goes down, exact resume)."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import make_tiny_dataset

from reconphys.capture import default_camera
from reconphys.capture.placement import project
from reconphys.geometry import quaternion_multiply
from reconphys.models.gaussian_predictor import (
    GaussianPredictor,
    GaussianPredictorConfig,
    prune_gaussians,
)
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.train.gaussians import GaussianTrainSettings, train_gaussian_predictor


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
