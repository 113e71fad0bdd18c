"""reconphys.geometry: rotations and rigid velocity against scipy, and their gradients."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from reconphys.geometry import (
    axis_angle_to_matrix,
    matrix_to_quaternion,
    quaternion_multiply,
    quaternion_to_matrix,
    random_rotation,
    rigid_velocity,
)

SCIPY = Rotation.random(64, random_state=0)


def _wxyz(rotation: Rotation) -> torch.Tensor:
    return torch.from_numpy(rotation.as_quat()[..., [3, 0, 1, 2]].copy())


def test_quaternion_to_matrix_matches_scipy_and_ignores_the_norm():
    quats = _wxyz(SCIPY)
    expected = torch.from_numpy(SCIPY.as_matrix())
    assert torch.allclose(quaternion_to_matrix(quats), expected, atol=1e-12)
    assert torch.allclose(
        quaternion_to_matrix(3.0 * quats.reshape(8, 8, 4)).reshape(64, 3, 3), expected, atol=1e-12
    )


def test_matrix_to_quaternion_matches_scipy_near_180_degrees_too():
    half_turns = Rotation.from_rotvec(np.pi * np.eye(3) * (1 - 1e-9))
    rotations = Rotation.concatenate([SCIPY, half_turns])
    quats = matrix_to_quaternion(torch.from_numpy(rotations.as_matrix()))
    expected = _wxyz(rotations)
    expected = torch.where(expected[..., :1] < 0, -expected, expected)
    assert (quats[..., 0] >= 0).all()
    assert torch.allclose(quats, expected, atol=1e-7)


def test_quaternion_multiply_composes_like_scipy():
    a, b = SCIPY[:32], SCIPY[32:]
    product = quaternion_multiply(_wxyz(a), _wxyz(b))
    assert torch.allclose(
        quaternion_to_matrix(product), torch.from_numpy((a * b).as_matrix()), atol=1e-12
    )


def test_axis_angle_to_matrix_matches_scipy_and_is_the_identity_at_zero():
    vectors = torch.from_numpy(SCIPY.as_rotvec()).reshape(4, 16, 3)
    expected = torch.from_numpy(SCIPY.as_matrix()).reshape(4, 16, 3, 3)
    assert torch.allclose(axis_angle_to_matrix(vectors), expected, atol=1e-10)
    assert torch.allclose(
        axis_angle_to_matrix(torch.zeros(3, dtype=torch.float64)), torch.eye(3, dtype=torch.float64)
    )


def test_random_rotation_is_a_seeded_rotation():
    r = random_rotation(7)
    assert r.shape == (3, 3) and r.dtype == torch.float64
    assert torch.equal(r, random_rotation(torch.Generator().manual_seed(7)))
    batch = random_rotation(3, size=(500,))
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(batch @ batch.transpose(-1, -2), eye.expand(500, 3, 3), atol=1e-12)
    assert torch.allclose(torch.det(batch), torch.ones(500, dtype=torch.float64))
    assert batch.mean(0).abs().max() < 0.15  # uniform on SO(3): the mean matrix is zero
    assert random_rotation(1, dtype=torch.float32).dtype == torch.float32


def test_random_rotation_keeps_the_cli_numbers():
    """The QR method the CLI used for make-asset --seed: same numbers bit for bit."""
    g = torch.Generator().manual_seed(11)
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    assert torch.equal(random_rotation(11), q)


def test_rigid_velocity():
    points = torch.randn(2, 10, 3, dtype=torch.float64)
    linear = torch.randn(2, 3, dtype=torch.float64)
    angular = torch.randn(2, 3, dtype=torch.float64)
    v = rigid_velocity(points, linear, angular)
    arm = points - points.mean(-2, keepdim=True)
    expected = linear[:, None] + torch.cross(angular[:, None].expand_as(arm), arm, dim=-1)
    assert torch.allclose(v, expected)
    centre = torch.zeros(2, 3, dtype=torch.float64)
    assert torch.allclose(
        rigid_velocity(points, 0 * linear, angular, centre)[0, 0],
        torch.cross(angular[0], points[0, 0], dim=-1),
    )


@pytest.mark.parametrize(
    "function, shape",
    [
        (quaternion_to_matrix, (5, 4)),
        (matrix_to_quaternion, None),
        (quaternion_multiply, (5, 4)),
        (axis_angle_to_matrix, (5, 3)),
        (rigid_velocity, None),
    ],
)
def test_gradcheck(function, shape):
    g = torch.Generator().manual_seed(0)
    if function is matrix_to_quaternion:
        inputs = (random_rotation(g, size=(5,)).requires_grad_(),)
    elif function is rigid_velocity:
        inputs = tuple(
            torch.randn(*s, generator=g, dtype=torch.float64).requires_grad_()
            for s in ((7, 3), (3,), (3,), (3,))
        )
    elif function is quaternion_multiply:
        inputs = tuple(
            torch.randn(*shape, generator=g, dtype=torch.float64).requires_grad_() for _ in range(2)
        )
    else:
        inputs = (torch.randn(*shape, generator=g, dtype=torch.float64).requires_grad_(),)
    assert torch.autograd.gradcheck(function, inputs)
