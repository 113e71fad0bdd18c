"""Training objectives (docs/design.md#models, paper §3.4): self-supervised photometric, supervised,
mixed.

Self-supervised: the photometric loss of the self-forced rollout
(:func:`reconphys.render.photometric.photometric_loss`, shared with test-time refinement).

Geometry and the initial state come from the scene assets given (for now the dataset's canonical
Gaussians: ground-truth geometry, an upper bound that reports must label as such).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..models.physics_predictor import normalize_attributes
from ..physics import ATTRIBUTES
from ..physics.model import observable_bounds
from .config import SUPERVISED_TARGETS


def normalize_observables(attributes: Tensor) -> Tensor:
    """[..., 4] attributes (ATTRIBUTES) → [..., 4] (log m, log k/m, log d/m, f), each scaled
    to [0, 1] over its range (:func:`observable_bounds`): the quantities a video determines
    (docs/design.md#physical-model), and the mass."""
    mass, stiffness, damping, friction = attributes.unbind(-1)
    bounds = observable_bounds().to(attributes.dtype)
    ratios = torch.stack([torch.log(stiffness / mass), torch.log(damping / mass), friction], -1)
    scaled = (ratios - bounds[:, 0]) / (bounds[:, 1] - bounds[:, 0])
    return torch.cat([normalize_attributes(attributes)[..., :1], scaled], -1)


def observable_scale_loss(
    attributes: dict[str, Tensor],  # predicted, name → [B]
    scale: Tensor,  # [B, 3] predicted mean |error| of log k/m, log d/m, f (natural units)
    true: Tensor,  # [B, 4] true attributes in ATTRIBUTES
) -> Tensor:
    """Laplace negative log-likelihood of the answer's error under the predicted scale b:
    mean of |e| / b + log b over the batch and the three observables, both in the observables'
    [0, 1] units. The error is detached: this term trains the scale alone (its minimum is b =
    E|e| given the input), never the answer."""
    predicted = torch.stack([attributes[n] for n in ATTRIBUTES], -1)
    error = (normalize_observables(predicted) - normalize_observables(true))[..., 1:].detach()
    bounds = observable_bounds().to(scale.dtype)
    b = scale / (bounds[:, 1] - bounds[:, 0])
    return (error.abs() / b + b.log()).mean()


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
