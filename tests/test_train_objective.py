"""The supervised objective: zero at the truth; the observables target ignores the scale."""

from __future__ import annotations

import math

import pytest
import torch

from reconphys.physics import ATTRIBUTES
from reconphys.train.objective import supervised_loss


def test_supervised_loss_is_zero_at_the_truth():
    true = torch.tensor([[0.8, 300.0, 2.0, 0.4], [2.5, 4000.0, 0.3, 0.9]])  # m, k, d, f
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
