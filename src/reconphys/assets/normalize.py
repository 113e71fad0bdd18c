"""Rigid placement of Gaussians: normalise size and centre, put on the ground, rotate.

All functions return new ``Gaussians`` and accept any leading batch dimensions (``[..., N, 3]``);
batched inputs are treated scene by scene (each scene gets its own bounding box).
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from reconphys.assets.gaussians import Gaussians
from reconphys.errors import InputError
from reconphys.geometry import matrix_to_quaternion, quaternion_multiply


def bounding_box(means: Tensor) -> tuple[Tensor, Tensor]:  # means [..., N, 3] metres
    """Axis-aligned bounding box of the centres: ``(lower [..., 3], upper [..., 3])`` in metres."""
    return means.amin(dim=-2), means.amax(dim=-2)


def normalize_gaussians(g: Gaussians, size: float = 0.5) -> Gaussians:
    """Centre the centres' bounding box on the origin and scale its largest side to ``size`` metres.

    Scales grow by the same factor (``log_scales`` shift by ``log(factor)``), so the appearance is a
    uniformly scaled copy. Only the centres define the box; the Gaussians' own extent is ignored.
    """
    if not size > 0:
        raise InputError(f"size must be > 0 metres, got {size}", field="size")
    if g.num_gaussians == 0:
        raise InputError("cannot normalise an empty set of Gaussians", field="means")
    lower, upper = bounding_box(g.means)
    largest_side = (upper - lower).amax(dim=-1, keepdim=True)  # [..., 1]
    if not bool((largest_side > 0).all()):
        raise InputError("all Gaussian centres coincide; cannot normalise", field="means")
    factor = size / largest_side  # [..., 1]
    center = 0.5 * (lower + upper)  # [..., 3]
    means = (g.means - center.unsqueeze(-2)) * factor.unsqueeze(-2)
    log_scales = g.log_scales + torch.log(factor).unsqueeze(-2)
    return replace(g, means=means, log_scales=log_scales)


def place_on_ground(g: Gaussians, height: float = 0.0) -> Gaussians:
    """Translate along z so the lowest Gaussian centre is at ``z = height`` metres."""
    if g.num_gaussians == 0:
        raise InputError("cannot place an empty set of Gaussians", field="means")
    lowest = g.means[..., 2].amin(dim=-1, keepdim=True)  # [..., 1]
    shift = torch.zeros_like(g.means[..., :1, :])  # [..., 1, 3]
    shift[..., 0, 2] = height - lowest[..., 0]
    return replace(g, means=g.means + shift)


def rotate_gaussians(
    g: Gaussians,
    rotation: Tensor,  # [3, 3] or [..., 3, 3] proper rotation matrix (world ← object)
) -> Gaussians:
    """Rotate the Gaussians rigidly about the world origin.

    Centres become ``R @ mean`` and every Gaussian's orientation is composed with R
    (``q ← q_R ⊗ q``), so each covariance becomes ``R Σ Rᵀ``. Quaternion norms are preserved.
    Normalised objects are centred on the origin, so this rotates them in place.
    """
    rotation = rotation.to(dtype=g.means.dtype, device=g.means.device)
    if rotation.shape[-2:] != (3, 3):
        raise InputError(
            f"rotation must be [..., 3, 3], got {list(rotation.shape)}", field="rotation"
        )
    identity = torch.eye(3, dtype=rotation.dtype, device=rotation.device)
    orthogonality_error = (rotation @ rotation.transpose(-1, -2) - identity).abs().amax()
    if orthogonality_error > 1e-4 or bool((torch.linalg.det(rotation) <= 0).any()):
        raise InputError("rotation must be orthonormal with determinant +1", field="rotation")
    means = g.means @ rotation.transpose(-1, -2)
    rotation_quat = matrix_to_quaternion(rotation).unsqueeze(-2)  # [..., 1, 4]
    quats = quaternion_multiply(rotation_quat, g.quats)
    return replace(g, means=means, quats=quats)
