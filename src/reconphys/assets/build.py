"""Build an asset from Gaussians: volume anchors, kNN springs, binding, attributes.

The one path from Gaussians + attributes + settings to an asset, for every caller (the data
generator, the predict pipeline, the baselines, the CLI's ``make-asset``/``demo``):
:func:`build_asset` (settings already made), :func:`build_from_gaussians` (settings from a
dataset's), :func:`place_for_drop` (oriented and lifted for a drop first).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import torch

from ..geometry import random_rotation, rigid_velocity
from ..physics import compute_binding, knn_springs, sample_volume_anchors
from .asset import Asset, PhysicsSettings
from .gaussians import Gaussians
from .normalize import place_on_ground, rotate_gaussians


def lifted_above(gaussians: Gaussians, ground_height: float) -> Gaussians:
    """The Gaussians moved up just above ``ground_height`` (metres) where their lowest centre is
    below it: an object must start above its ground."""
    lowest = float(gaussians.means[:, 2].min())
    if lowest >= ground_height:
        return gaussians
    return gaussians.with_means(
        gaussians.means + torch.tensor([0.0, 0.0, ground_height - lowest + 1e-3])
    )


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


def with_gaussians(asset: Asset, gaussians: Gaussians) -> Asset:
    """The asset with other Gaussians (world frame, at the asset's initial pose; no batch dims)
    on the same anchors and springs, each bound to its nearest anchors as :func:`build_asset`
    binds: a finer appearance on the same physics."""
    means = gaussians.means.detach().cpu()
    physics = asset.physics
    index, weight = compute_binding(
        means, asset.x0, physics.binding_neighbors, physics.binding_power
    )
    return replace(
        asset,
        gaussians=gaussians.map(lambda t: t.detach().cpu().float()),
        binding_index=index,
        binding_weight=weight,
    )


def build_from_gaussians(
    gaussians: Gaussians,  # world-frame Gaussians at their initial pose (no batch dims)
    attributes: Mapping[str, float],  # mass (kg/anchor), stiffness, damping, friction
    settings,  # a dataset's settings: see PhysicsSettings.from_data_settings
    object_id: str,  # seeds the anchors
    linear_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # m/s
    angular_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # rad/s
    lift: bool = False,  # move the Gaussians just above the ground first (lifted_above)
    **overrides,  # PhysicsSettings fields set explicitly (frame_dt, ground_height, num_anchors)
) -> Asset:
    """Gaussians + attributes + a dataset's spring-mass settings (+ initial velocity) → asset."""
    physics = PhysicsSettings.from_data_settings(settings, attributes, object_id, **overrides)
    if lift:
        gaussians = lifted_above(gaussians, physics.ground_height)
    return build_asset(gaussians, physics, linear_velocity, angular_velocity)


def place_for_drop(
    gaussians: Gaussians,  # object frame (e.g. normalised)
    height: float,  # lowest point above the ground, metres
    seed: int,  # the random orientation's
    physics: PhysicsSettings | None = None,
    linear_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # m/s
    angular_velocity: Sequence[float] = (0.0, 0.0, 0.0),  # rad/s
    rotate: bool = True,
) -> Asset:
    """Orient the object (random rotation from ``seed``), lift its lowest point to ``height``
    metres and build the asset."""
    if rotate:
        gaussians = rotate_gaussians(gaussians, random_rotation(seed, dtype=torch.float32))
    gaussians = place_on_ground(gaussians, height)
    return build_asset(gaussians, physics, linear_velocity, angular_velocity)
