"""The supervised objective: zero at the truth; the observables target ignores the scale."""

from __future__ import annotations

import math

import pytest
import torch

from reconphys.data.dataset import GeneratedDropDataset
from reconphys.data.settings import make_settings
from reconphys.physics import ATTRIBUTES
from reconphys.threads import set_cpu_threads
from reconphys.train.objective import supervised_loss

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


def test_supervised_loss_is_zero_at_the_truth(tiny_batch):
    true = torch.stack([item["attributes"] for item in tiny_batch[1]])
    attributes = {n: true[:, i] for i, n in enumerate(ATTRIBUTES)}
    assert supervised_loss(attributes, true).item() == pytest.approx(0.0, abs=1e-6)
    attributes["friction"] = attributes["friction"] * 0 + 0.5
    assert supervised_loss(attributes, true).item() > 0


def test_observable_target_ignores_the_unobservable_scale():
    """Scaling m, k and d together leaves k/m and d/m (what a video shows) unchanged: the
    observables loss sees only the mass column move (|log s| / log(m_max/m_min) / 4), the
    attributes loss sees three columns move."""
    true = torch.tensor([[0.5, 200.0, 1.0, 0.3], [2.0, 50.0, 0.4, 0.8]])
    scale = 1.5
    scaled = true * torch.tensor([scale, scale, scale, 1.0])
    attributes = {n: scaled[:, i] for i, n in enumerate(ATTRIBUTES)}
    mass_width = math.log(6.0 / 0.2)
    expected = math.log(scale) / mass_width / 4
    observed = supervised_loss(attributes, true, "observables").item()
    assert observed == pytest.approx(expected, rel=1e-5)
    assert supervised_loss(attributes, true, "attributes").item() > 2 * observed
    with pytest.raises(ValueError, match="target"):
        supervised_loss(attributes, true, "pixels")
