"""Training objectives (docs/design.md#models, paper §3.4): self-supervised photometric, supervised,
mixed.

Self-supervised: the photometric loss of the self-forced rollout
(:func:`reconphys.render.photometric.photometric_loss`, shared with test-time refinement).

Geometry and the initial state come from the scene assets given (for now the dataset's canonical
Gaussians: ground-truth geometry, an upper bound that reports must label as such).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..models.physics_predictor import normalize_attributes
from ..physics import ATTRIBUTES
from ..physics.model import ATTRIBUTE_RANGES
from .config import SUPERVISED_TARGETS


def _log_ratio_bounds(numerator: str) -> tuple[float, float]:
    """Bounds of log(numerator / mass) over the docs/design.md#attribute-ranges ranges."""
    (n_low, n_high), (m_low, m_high) = ATTRIBUTE_RANGES[numerator], ATTRIBUTE_RANGES["mass"]
    return math.log(n_low / m_high), math.log(n_high / m_low)


def normalize_observables(attributes: Tensor) -> Tensor:
    """[..., 4] attributes (ATTRIBUTES) → [..., 4] (log m, log k/m, log d/m, f), each scaled
    to [0, 1] over its range: the quantities a video determines (docs/design.md#physical-model), and
    the mass."""
    mass, stiffness, damping, friction = attributes.unbind(-1)
    columns = [normalize_attributes(attributes)[..., 0]]
    for name, value in (("stiffness", stiffness), ("damping", damping)):
        low, high = _log_ratio_bounds(name)
        columns.append((torch.log(value / mass) - low) / (high - low))
    columns.append(friction)
    return torch.stack(columns, -1)


def supervised_loss(
    attributes: dict[str, Tensor],  # predicted, name → [B]
    true: Tensor,  # [B, 4] true attributes in ATTRIBUTES
    target: str = "attributes",
) -> Tensor:
    """Mean L1 between predicted and true values, normalised to [0, 1] ranges.

    ``target="attributes"``: m, k, d (log scale) and f — the paper's supervised baseline.
    ``target="observables"``: log m, log k/m, log d/m and f (:func:`normalize_observables`): the
    unobservable absolute scale no longer leaks into the stiffness and damping errors.
    """
    predicted = torch.stack([attributes[n] for n in ATTRIBUTES], -1)
    if target == "attributes":
        return (normalize_attributes(predicted) - normalize_attributes(true)).abs().mean()
    if target == "observables":
        return (normalize_observables(predicted) - normalize_observables(true)).abs().mean()
    raise ValueError(f"target: expected one of {SUPERVISED_TARGETS}, got {target!r}")
