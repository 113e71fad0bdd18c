"""Build an asset from Gaussians: volume anchors, kNN springs, binding, attributes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from ..physics import compute_binding, knn_springs, sample_volume_anchors
from .asset import Asset, PhysicsSettings
from .gaussians import Gaussians


def rigid_velocity(
    points: Tensor,  # [N_A, 3] metres
    linear: Sequence[float] = (0.0, 0.0, 0.0),  # m/s
    angular: Sequence[float] = (0.0, 0.0, 0.0),  # rad/s about the centroid
) -> Tensor:  # [N_A, 3] m/s
    """Velocity field of a rigid motion: v = v_lin + ω × (x − centroid)."""
    linear_t = torch.as_tensor(linear, dtype=points.dtype)
    angular_t = torch.as_tensor(angular, dtype=points.dtype).expand_as(points)
    return linear_t + torch.linalg.cross(angular_t, points - points.mean(0))


def build_asset(
    gaussians: Gaussians,  # world-frame Gaussians at their initial pose (no batch dims)
    physics: PhysicsSettings | None = None,
    linear_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # m/s
    angular_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # rad/s
) -> Asset:
    """Sample anchors in the volume of ``gaussians`` (seeded by ``physics.object_id``), connect
    them with kNN springs and bind every Gaussian to its nearest anchors."""
    physics = replace(physics or PhysicsSettings())
    means = gaussians.means.detach().cpu()
    anchors = sample_volume_anchors(means, physics.num_anchors, seed=physics.object_id or "object")
    physics.num_anchors = anchors.shape[0]
    springs, rest_length = knn_springs(anchors, physics.num_neighbors)
    index, weight = compute_binding(
        means, anchors, physics.binding_neighbors, physics.binding_power
    )
    return Asset(
        gaussians=gaussians.map(lambda t: t.detach().cpu().float()),
        x0=anchors,
        v0=rigid_velocity(anchors, linear_velocity, angular_velocity).float(),
        springs=springs,
        rest_length=rest_length,
        binding_index=index,
        binding_weight=weight,
        physics=physics,
    )
