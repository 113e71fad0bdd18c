"""Differentiable spring-mass physics: model (topology + attributes), state, stepping, anchors,
binding. See DESIGN §4 for the exact equations."""

from .anchors import sample_volume_anchors, seed_from_id
from .binding import compute_binding, deform_means
from .integrator import (
    Trajectory,
    ground_contact,
    kinetic_energy,
    potential_energy,
    rollout,
    spring_energy,
    spring_forces,
    stable_substeps,
    step,
)
from .model import ATTRIBUTE_RANGES, ATTRIBUTES, GRAVITY, SpringMassModel, knn_springs
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
    "seed_from_id",
    "spring_energy",
    "spring_forces",
    "stable_substeps",
    "step",
]
