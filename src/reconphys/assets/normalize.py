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


def rotation_to_quaternion(rotation: Tensor) -> Tensor:  # rotation [..., 3, 3]
    """Rotation matrices to unit quaternions ``[..., 4]`` (w, x, y, z) with ``w >= 0``.

    Picks, per matrix, the best-conditioned of the four classic formulas (largest diagonal term),
    so it is accurate for rotations near 180° too.
    """
    m = rotation
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # 4·q_i² for i = w, x, y, z
    four_q_squared = torch.stack(
        [
            1.0 + m00 + m11 + m22,
            1.0 + m00 - m11 - m22,
            1.0 - m00 + m11 - m22,
            1.0 - m00 - m11 + m22,
        ],
        dim=-1,
    )
    # Row i: 4·q_i·(w, x, y, z); divided by 4·q_i below.
    candidates = torch.stack(
        [
            torch.stack([four_q_squared[..., 0], m21 - m12, m02 - m20, m10 - m01], dim=-1),
            torch.stack([m21 - m12, four_q_squared[..., 1], m01 + m10, m02 + m20], dim=-1),
            torch.stack([m02 - m20, m01 + m10, four_q_squared[..., 2], m12 + m21], dim=-1),
            torch.stack([m10 - m01, m02 + m20, m12 + m21, four_q_squared[..., 3]], dim=-1),
        ],
        dim=-2,
    )  # [..., 4, 4]
    four_q = 2.0 * four_q_squared.clamp_min(1e-12).sqrt()  # [..., 4] = 4·|q_i|
    best = four_q_squared.argmax(dim=-1, keepdim=True)  # [..., 1]
    row = torch.gather(candidates, -2, best.unsqueeze(-1).expand(*best.shape, 4)).squeeze(-2)
    quat = row / torch.gather(four_q, -1, best)
    quat = torch.where(quat[..., :1] < 0, -quat, quat)
    return quat / quat.norm(dim=-1, keepdim=True)


def quaternion_multiply(a: Tensor, b: Tensor) -> Tensor:  # a, b [..., 4] wxyz
    """Hamilton product ``a ⊗ b`` (rotation b first, then a), broadcasting, ``[..., 4]``."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


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
    rotation_quat = rotation_to_quaternion(rotation).unsqueeze(-2)  # [..., 1, 4]
    quats = quaternion_multiply(rotation_quat, g.quats)
    return replace(g, means=means, quats=quats)
