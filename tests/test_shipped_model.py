"""The physics predictor shipped in the package: found without flags, small, and it reads physics.

The behavioural check is independent of the training data: one procedural object of the cpu_small
kind (32 px, 256 anchors, 2 000 Gaussians) is dropped twice with everything equal but the
stiffness, 30× apart; the model must order the two videos' log k/m correctly, with a margin.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from reconphys.data.dataset import GeneratedDropDataset
from reconphys.data.generate import dataset_cameras, generate_sample, render_views
from reconphys.data.settings import make_settings
from reconphys.models.shipped import ENV_VAR, SHIPPED_PATH, load_predictor
from reconphys.physics import ATTRIBUTES
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.render.video import to_uint8
from reconphys.threads import set_cpu_threads


@pytest.fixture(scope="module")
def model():
    return load_predictor(SHIPPED_PATH)


def test_shipped_model_is_found_without_flags(model, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert load_predictor().path == SHIPPED_PATH
    assert SHIPPED_PATH.stat().st_size < 20 * 2**20  # < 20 MB in the repository
    training = model.metadata["training"]
    assert training["geometry"].startswith("ground truth")  # its scores are labelled †
    assert training["steps"] > 0 and training["skipped_steps"] == 0
    out = model.predict(torch.rand(3, model.num_frames, 48, 48, 3))
    for name in ATTRIBUTES:
        low, high = ATTRIBUTE_RANGES[name]
        assert torch.isfinite(out[name]).all()
        assert ((out[name] >= low) & (out[name] <= high)).all(), name


def _video(asset, settings, model) -> torch.Tensor:  # [1, T, H, W, 3] of the model's view
    trajectory = asset.simulate(model.num_frames - 1, torch.device("cpu"))
    rgb = render_views(asset, trajectory.x[0], dataset_cameras(settings))
    video = torch.from_numpy(to_uint8(rgb)).float() / 255  # [V, T, H, W, 3]
    return video[model.view : model.view + 1]


def test_shipped_model_orders_stiffness(model):
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    try:
        settings = make_settings(
            objects=1, test_objects=0, samples_per_object=1, resolution=32,
            contact_frame_range=(6.0, 8.0), max_horizontal_speed=0.0,
        )  # fmt: skip
        dataset = GeneratedDropDataset(settings, views=[0], frames=range(2))
        generated = generate_sample(dataset.object(0), 0, settings)
        ratios = []
        for stiffness in (30.0, 900.0):
            physics = replace(generated.asset.physics, mass=1.0, stiffness=stiffness,
                              damping=0.5, friction=0.5)  # fmt: skip
            asset = replace(generated.asset, physics=physics)
            out = model.predict(_video(asset, settings, model))
            ratios.append(math.log(float(out["stiffness"][0]) / float(out["mass"][0])))
    finally:
        set_cpu_threads(threads)
    soft, stiff = ratios
    assert stiff - soft > 1.0, ratios  # truth: log 30 ≈ 3.4 apart
