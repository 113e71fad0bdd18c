"""Gradient-free refinement (pipeline/search.py) and the ``reconphys_search`` evaluate method.

The search runs the simulator and renderer that made the dataset, so from wrong attributes it
must walk back to the true observables (checked against the sample's stored truth). One thread,
16-px frames, 24 anchors.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from reconphys.data import make_dataset, make_settings
from reconphys.pipeline.samples import load_sample
from reconphys.pipeline.search import observables, search
from reconphys.threads import set_cpu_threads


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    yield
    set_cpu_threads(threads)


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    root = tmp_path_factory.mktemp("search") / "data"
    settings = make_settings(
        objects=0,
        test_objects=1,
        test_samples_per_object=1,
        resolution=24,
        num_gaussians=200,
        num_anchors=24,
        num_neighbors=6,
        min_substeps=20,
        toss_fraction=1.0,  # a slide: friction shows
        seed=2,
    )
    manifest = make_dataset(settings, root, workers=1, device="cpu").manifest
    return load_sample(root, manifest["samples"][0]["id"])


def test_search_walks_back_to_the_true_observables(sample):
    observation, truth = sample
    physics = truth.asset.physics
    true = observables(physics)
    wrong = replace(
        physics,
        stiffness=min(physics.stiffness * math.e**1.5, 1200.0),
        damping=max(physics.damping / math.e, 0.1),
        friction=0.9 if physics.friction < 0.5 else 0.1,
    )
    start = observables(wrong)
    found, history = search(replace(truth.asset, physics=wrong), observation.frames[:20],
                            observation.camera)  # fmt: skip
    after = observables(found.physics)
    before_error, after_error = (start - true).abs(), (after - true).abs()
    assert history["error"] <= min(history["rounds"][0]["errors"])  # never worse than a step
    assert found.physics.mass == physics.mass  # only ratios are observable
    assert after_error[0] < 0.25 * before_error[0], (true, start, after)  # log k/m
    assert after_error[2] < 0.5 * before_error[2], (true, start, after)  # friction
    assert after_error.sum() < 0.5 * before_error.sum()


def test_search_refuses_a_single_frame(sample):
    observation, truth = sample
    with pytest.raises(ValueError, match="frames"):
        search(truth.asset, observation.frames[:1], observation.camera)


def test_search_keeps_what_the_video_does_not_show(sample, monkeypatch):
    """Where no candidate explains the frames better than another (an observable the video does
    not show), the start comes back unchanged, not a grid end."""
    from reconphys.pipeline import search as module

    observation, truth = sample
    monkeypatch.setattr(module, "photometric_errors", lambda *a: torch.full((7,), 1e-3))
    found, history = search(truth.asset, observation.frames[:20], observation.camera)
    assert found.physics == truth.asset.physics
    assert len(history["rounds"]) == 9
