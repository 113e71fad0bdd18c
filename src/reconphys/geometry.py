"""Rotations and rigid motion in torch, batched over any leading dimensions.

Quaternions are ``(w, x, y, z)`` (scalar first, the 3DGS PLY order); rotation matrices act on
column vectors (``x_world = R @ x_object``); rotation vectors are axis × angle in radians. Every
function is differentiable (``tests/test_geometry.py`` runs gradcheck on each).

``data/sampling.py`` keeps numpy twins of :func:`quaternion_to_matrix` (inside its Shoemake
``random_rotation``) and of :func:`axis_angle_to_matrix`: a generated dataset is reproducible bit
for bit from its seed, and a torch path could differ from numpy's in the last bit.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def quaternion_to_matrix(
    quats: Tensor,  # [..., 4] (w, x, y, z), any non-zero norm
) -> Tensor:  # [..., 3, 3]
    """Rotation matrices of (normalised) wxyz quaternions."""
    w, x, y, z = F.normalize(quats, dim=-1).unbind(-1)
    # fmt: off
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    # fmt: on
    return torch.stack(rows, dim=-1).reshape(*quats.shape[:-1], 3, 3)


def matrix_to_quaternion(
    rotation: Tensor,  # [..., 3, 3] proper rotation matrices
) -> Tensor:  # [..., 4] unit (w, x, y, z) with w >= 0
    """Rotation matrices to unit quaternions ``(w, x, y, z)`` with ``w >= 0``.

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


def quaternion_multiply(
    a: Tensor,  # [..., 4] wxyz
    b: Tensor,  # [..., 4] wxyz
) -> Tensor:  # [..., 4]
    """Hamilton product ``a ⊗ b`` (rotation b first, then a), broadcasting."""
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


def axis_angle_to_matrix(
    rotation_vectors: Tensor,  # [..., 3] axis × angle, radians
) -> Tensor:  # [..., 3, 3]
    """Rodrigues' formula, differentiable at zero (the angle gets a tiny floor: |ω|² + 1e-12)."""
    angle = torch.sqrt((rotation_vectors**2).sum(-1, keepdim=True) + 1e-12)  # [..., 1]
    x, y, z = (rotation_vectors / angle).unbind(-1)
    zero = torch.zeros_like(x)
    cross = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1)
    cross = cross.reshape(*cross.shape[:-1], 3, 3)  # [..., 3, 3] the axis' cross-product matrix
    s, c = torch.sin(angle)[..., None], torch.cos(angle)[..., None]
    eye = torch.eye(3, dtype=rotation_vectors.dtype, device=rotation_vectors.device)
    return eye + s * cross + (1 - c) * (cross @ cross)


def random_rotation(
    generator: torch.Generator | int,  # a generator, or a seed for a fresh CPU one
    size: tuple[int, ...] = (),
    dtype: torch.dtype = torch.float64,
) -> Tensor:  # [*size, 3, 3]
    """Uniformly distributed (Haar) random rotations: QR of a Gaussian matrix, signs fixed so R
    has a positive diagonal, then one column flipped where needed so det R = +1."""
    if isinstance(generator, int):
        generator = torch.Generator().manual_seed(generator)
    gaussian = torch.randn(*size, 3, 3, generator=generator, dtype=torch.float64)
    q, r = torch.linalg.qr(gaussian)
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1)).unsqueeze(-2)
    flip = torch.where(torch.det(q) < 0, -1.0, 1.0).to(q.dtype)  # [*size]
    q = torch.cat([q[..., :, :1] * flip[..., None, None], q[..., :, 1:]], dim=-1)
    return q.to(dtype)


def rigid_velocity(
    points: Tensor,  # [..., N, 3] metres
    linear: Tensor,  # [..., 3] m/s
    angular: Tensor,  # [..., 3] rad/s
    centre: Tensor | None = None,  # [..., 3] metres; default: the points' centroid
) -> Tensor:  # [..., N, 3] m/s
    """Velocity field of a rigid motion: ``v = v_lin + ω × (x − c)``."""
    if centre is None:
        centre = points.mean(-2)
    angular = torch.as_tensor(angular, dtype=points.dtype, device=points.device)
    linear = torch.as_tensor(linear, dtype=points.dtype, device=points.device)
    arm = points - centre.unsqueeze(-2)
    return linear.unsqueeze(-2) + torch.linalg.cross(angular.unsqueeze(-2).expand_as(arm), arm)
