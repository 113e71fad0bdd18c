"""Canonical objects and the per-sample assets made from them.

A canonical object is stored once per dataset object: Gaussians in the object's own frame (centred,
normalised), its volume anchors (seeded by the object id, docs/design.md#conventions), the kNN
springs with their rest lengths, and the binding. A sample places it by a rigid motion (rotation,
then translation): springs, rest lengths and binding are invariant under it, so they are reused as
they are, and every sample of an object has the same anchors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from ..assets.asset import Asset, PhysicsSettings
from ..assets.build import build_from_gaussians
from ..assets.gaussians import Gaussians
from ..assets.normalize import rotate_gaussians
from ..geometry import rigid_velocity
from .sampling import SampleSpec, centroid_height_for_contact
from .settings import DataSettings


@dataclass
class CanonicalObject:
    id: str  # stable object id (seeds the anchors)
    key: str  # folder name under objects/
    description: dict  # source-specific facts (shape, texture, file, ...)
    gaussians: Gaussians  # [N] object frame, metres
    anchors: Tensor  # [N_A, 3] float32, object frame, metres
    springs: Tensor  # [E, 2] int64
    rest_length: Tensor  # [E] float32, metres
    binding_index: Tensor  # [N, n_b] int64
    binding_weight: Tensor  # [N, n_b] float32


def build_object(
    object_id: str,
    key: str,
    gaussians: Gaussians,  # [N] normalised, object frame
    settings: DataSettings,
    description: dict,
) -> CanonicalObject:
    """Anchors (seeded by ``object_id``), springs and binding for ``gaussians``."""
    asset = build_from_gaussians(gaussians, {}, settings, object_id)
    return CanonicalObject(
        id=object_id,
        key=key,
        description=description,
        gaussians=asset.gaussians,
        anchors=asset.x0,
        springs=asset.springs,
        rest_length=asset.rest_length,
        binding_index=asset.binding_index,
        binding_weight=asset.binding_weight,
    )


def scale_object(obj: CanonicalObject, factor: float) -> CanonicalObject:
    """The same object ``factor`` times larger (Gaussians, anchors, rest lengths; springs and
    binding are unchanged: the binding's weights depend only on distance ratios)."""
    if factor == 1.0:
        return obj
    g = obj.gaussians
    gaussians = replace(g, means=g.means * factor, log_scales=g.log_scales + math.log(factor))
    return replace(
        obj,
        gaussians=gaussians,
        anchors=obj.anchors * factor,
        rest_length=obj.rest_length * factor,
    )


@dataclass(frozen=True)
class Placement:
    """Where a sample starts: world = rotation · object + translation (SI units)."""

    rotation: np.ndarray  # [3, 3] float64
    translation: np.ndarray  # [3] float64, metres
    drop_height: float  # lowest anchor at frame 0, metres

    def apply(self, points: Tensor) -> Tensor:  # [..., 3] float32 → float32
        rotation = torch.from_numpy(self.rotation).to(points)
        return points @ rotation.T + torch.from_numpy(self.translation).to(points)


def place(obj: CanonicalObject, spec: SampleSpec) -> Placement:
    """Rotate the object, centre its anchors over ``spec.start`` (the origin for a drop) and lift
    them so that it first touches the ground at ``spec.target_contact_time``."""
    anchors = obj.anchors.double().numpy()
    centroid = anchors.mean(0)
    relative = (anchors - centroid) @ spec.rotation.T
    height = centroid_height_for_contact(
        relative, spec.linear_velocity[2], spec.angular_velocity, spec.target_contact_time
    )
    translation = np.array([*spec.start, height]) - spec.rotation @ centroid
    return Placement(spec.rotation, translation, float(height + relative[:, 2].min()))


def sample_asset(
    obj: CanonicalObject,
    spec: SampleSpec,
    placement: Placement,
    settings: DataSettings,
) -> Asset:
    """The simulation-ready asset of one sample: the placed object with its attributes and
    initial velocity (what ``reconphys data export`` writes)."""
    x0 = placement.apply(obj.anchors)
    rotation = torch.from_numpy(placement.rotation).float()
    gaussians = rotate_gaussians(obj.gaussians, rotation)
    gaussians = gaussians.with_means(placement.apply(obj.gaussians.means))
    physics = PhysicsSettings.from_data_settings(settings, spec.attributes, obj.id)
    return Asset(
        gaussians=gaussians,
        x0=x0,
        v0=rigid_velocity(x0, spec.linear_velocity, spec.angular_velocity).float(),
        springs=obj.springs,
        rest_length=obj.rest_length,
        binding_index=obj.binding_index,
        binding_weight=obj.binding_weight,
        physics=physics,
    )
