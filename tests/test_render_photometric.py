"""The photometric loss of a self-forced rollout: gradients reach the predictor; the truth
minimises it; padded springs change nothing."""

from __future__ import annotations

import pytest
import torch

from reconphys.data.dataset import GeneratedDropDataset
from reconphys.data.settings import make_settings
from reconphys.models.physics_predictor import PhysicsPredictor, PredictorConfig
from reconphys.physics import ATTRIBUTES
from reconphys.render import Cameras
from reconphys.render.photometric import SceneBatch, photometric_loss
from reconphys.threads import set_cpu_threads

FRAMES = 4


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """torch and Numba on one thread: on a 2-core machine shared with other jobs, more threads
    than free cores slow the simulation many times over."""
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    yield
    set_cpu_threads(threads)


@pytest.fixture(scope="module")
def tiny_batch():
    settings = make_settings(
        objects=1, samples_per_object=2, resolution=16, num_gaussians=200, num_anchors=24,
        num_neighbors=6, min_substeps=20, num_frames=12, contact_frame_range=(1.0, 2.0),
        drop_height_range=(0.02, 0.05),
    )  # fmt: skip
    dataset = GeneratedDropDataset(settings, views=[0], frames=range(FRAMES))
    items = [dataset[i] for i in range(len(dataset))]
    return settings, items, dataset


def _inputs(tiny_batch):
    settings, items, dataset = tiny_batch
    assets = [_asset(dataset, i) for i in range(len(items))]
    scenes = SceneBatch.from_assets(assets)
    frames = torch.stack([item["frames"][0] for item in items])  # [B, T, H, W, 3]
    K = torch.stack([item["K"][0] for item in items])
    w2c = torch.stack([item["world_to_cam"][0] for item in items])
    cameras = Cameras(K, w2c, settings.resolution, settings.resolution)
    true = torch.stack([item["attributes"] for item in items])
    return scenes, frames, cameras, true


def _asset(dataset, index):
    """The sample's placed asset (the generating dataset builds it the way make-data does)."""
    from reconphys.data.generate import generate_sample

    planned = dataset.samples[index]
    return generate_sample(dataset.object(index), planned.index, dataset.settings).asset


def test_photometric_gradient_reaches_the_predictor(tiny_batch):
    scenes, frames, cameras, _ = _inputs(tiny_batch)
    torch.manual_seed(0)
    config = PredictorConfig(
        encoder_channels=(8,), token_channels=8, trunk_blocks=1, attention_heads=2,
        mlp_hidden=(16,), num_frames=FRAMES, resolution=16,
    )  # fmt: skip
    predictor = PhysicsPredictor(config)
    attributes = predictor(frames)
    loss = photometric_loss(attributes, scenes, frames, cameras, window=1, min_substeps=20)
    loss.backward()
    grads = [p.grad for p in predictor.parameters()]
    assert torch.isfinite(loss) and loss > 0
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert sum(g.abs().sum() for g in grads) > 0


def test_true_attributes_score_better_than_wrong_ones(tiny_batch):
    scenes, frames, cameras, true = _inputs(tiny_batch)

    def loss_of(values):
        attributes = {n: values[:, i] for i, n in enumerate(ATTRIBUTES)}
        substeps = tiny_batch[0].min_substeps  # as the data was made
        return photometric_loss(
            attributes, scenes, frames, cameras, window=2, min_substeps=substeps
        ).item()

    wrong = true.clone()
    wrong[:, 1] = torch.where(true[:, 1] > 300, 15.0, 1100.0)  # stiffness far off
    wrong[:, 3] = 1.0 - true[:, 3]
    assert loss_of(true) < loss_of(wrong)
    assert loss_of(true) < 1e-3  # the truth re-renders the video up to uint8 rounding


def test_window_must_be_positive(tiny_batch):
    scenes, frames, cameras, true = _inputs(tiny_batch)
    attributes = {n: true[:, i] for i, n in enumerate(ATTRIBUTES)}
    with pytest.raises(ValueError, match="window"):
        photometric_loss(attributes, scenes, frames, cameras, window=0)


def test_padded_springs_change_nothing(tiny_batch):
    """Scenes with different spring counts share a batch: the pads (k = d = 0) must leave the
    stability bound and the forces finite and every scene's loss as it is alone."""
    from dataclasses import replace

    scenes, frames, cameras, true = _inputs(tiny_batch)
    first, second = scenes.assets
    fewer = replace(second, springs=second.springs[:-7], rest_length=second.rest_length[:-7])
    attributes = {n: true[:, i].clone().requires_grad_(True) for i, n in enumerate(ATTRIBUTES)}

    def loss_of(assets, index):
        picked = {n: v[index] for n, v in attributes.items()}
        cams = cameras.select(index)
        return photometric_loss(
            picked, SceneBatch.from_assets(assets), frames[index], cams, min_substeps=200
        )  # 200 substeps: more than either scene's bound, so both runs use the same

    both = loss_of([first, fewer], [0, 1])
    both.backward()
    assert torch.isfinite(both) and all(torch.isfinite(v.grad).all() for v in attributes.values())
    alone = (loss_of([first], [0]) + loss_of([fewer], [1])) / 2
    assert both.item() == pytest.approx(alone.item(), rel=1e-5, abs=1e-12)
