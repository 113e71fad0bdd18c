"""gradcheck of the simulator in float64 through substeps that include ground contact."""

from __future__ import annotations

import torch
from torch.autograd import gradcheck

from reconphys.physics import SpringMassModel, State, knn_springs, rollout


def small_system():
    """12 anchors just above the ground, falling and sliding: contact within a few substeps."""
    g = torch.Generator().manual_seed(7)
    x0 = 0.05 * torch.rand(12, 3, generator=g, dtype=torch.float64)
    x0[:, 2] += 0.002 - x0[:, 2].min()
    springs, _ = knn_springs(x0, 4)
    rest = (x0[springs[:, 1]] - x0[springs[:, 0]]).norm(dim=1) * 0.95  # pre-stretched 5 %
    v0 = torch.zeros_like(x0)
    v0[:, 0], v0[:, 2] = 0.6, -1.0
    return x0, v0, springs, rest


def simulate(springs, rest, x0, m, k, d, f, v0, substeps=8):
    model = SpringMassModel(springs, rest, m, k, d, f, dtype=torch.float64)
    trajectory = rollout(model, State(x0[None], v0), 1, frame_dt=0.016, substeps=substeps)
    return trajectory.x[:, -1], trajectory.v[:, -1]


def test_contact_happens_in_gradcheck_window():
    x0, v0, springs, rest = small_system()
    x, v = simulate(springs, rest, x0, 0.3, 200.0, 0.5, 0.3, v0[None])
    on_ground = x[0, :, 2] == 0.0
    assert 0 < on_ground.sum() < len(x0), "some, not all, anchors must touch the ground"
    assert (v[0, on_ground, 0].abs() > 1e-3).all(), "contacting anchors must still slide"


def test_gradcheck_scalar_attributes_and_initial_velocity():
    x0, v0, springs, rest = small_system()
    params = [
        torch.tensor([0.3], dtype=torch.float64, requires_grad=True),  # m
        torch.tensor([200.0], dtype=torch.float64, requires_grad=True),  # k
        torch.tensor([0.5], dtype=torch.float64, requires_grad=True),  # d
        torch.tensor([0.3], dtype=torch.float64, requires_grad=True),  # f
        v0[None].clone().requires_grad_(True),
    ]
    assert gradcheck(lambda *p: simulate(springs, rest, x0, *p), params, eps=1e-7, atol=1e-6)


def test_gradcheck_per_anchor_and_per_spring_attributes_and_rest_state():
    x0, v0, springs, rest = small_system()
    n, e = x0.shape[0], springs.shape[0]
    g = torch.Generator().manual_seed(1)

    def around(value, size):
        noise = 1 + 0.2 * torch.rand(1, size, generator=g, dtype=torch.float64)
        return (value * noise).requires_grad_(True)

    params = [
        around(0.3, n),
        around(200.0, e),
        around(0.5, e),
        around(0.3, n),
        rest.clone().requires_grad_(True),
        x0.clone().requires_grad_(True),
    ]

    def fn(m, k, d, f, rest_length, positions):
        return simulate(springs, rest_length, positions, m, k, d, f, v0[None], substeps=6)

    assert gradcheck(fn, params, eps=1e-7, atol=1e-6)
