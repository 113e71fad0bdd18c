"""Differentiable spring-mass physics: model (topology + attributes), state, stepping, anchors,
binding, controllers. See docs/design.md#physical-model for the exact equations.

- :mod:`.reference`: the plain PyTorch substep (:func:`step`), forces, contact and energies.
- :mod:`.stability`: the stable substep count.
- :mod:`.engine`: the engine interface; :mod:`.torch_backend`, :mod:`.triton_backend` and
  :mod:`.numba_backend` implement it; :mod:`.adjoint` is the engine-generic exact backward.
- :mod:`.rollout`: frames of substeps with the engine that suits the call.
- :mod:`.control`: grips and the frame stepper of interactive use.
"""

from .anchors import sample_volume_anchors, seed_from_id
from .binding import compute_binding, deform_means
from .model import ATTRIBUTE_RANGES, ATTRIBUTES, GRAVITY, SpringMassModel, knn_springs
from .reference import (
    ground_contact,
    kinetic_energy,
    potential_energy,
    spring_energy,
    spring_forces,
    step,
)
from .rollout import Trajectory, rollout
from .stability import scene_stable_substeps, stable_substeps
from .state import Control, State

__all__ = [
    "ATTRIBUTES",
    "ATTRIBUTE_RANGES",
    "GRAVITY",
    "Control",
    "SpringMassModel",
    "State",
    "Trajectory",
    "compute_binding",
    "deform_means",
    "ground_contact",
    "kinetic_energy",
    "knn_springs",
    "potential_energy",
    "rollout",
    "sample_volume_anchors",
    "scene_stable_substeps",
    "seed_from_id",
    "spring_energy",
    "spring_forces",
    "stable_substeps",
    "step",
]
