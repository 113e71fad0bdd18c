"""Simulator dynamics against analytic solutions, invariances and conservation laws."""

from __future__ import annotations

import itertools

import pytest
import torch
from helpers import box_grid

from reconphys._optional import numba_available
from reconphys.physics import (
    SpringMassModel,
    State,
    kinetic_energy,
    knn_springs,
    potential_energy,
    rollout,
    spring_energy,
    stable_substeps,
)

G = 9.8


@pytest.fixture(autouse=True, params=["autograd", "numba"])
def simulator(request, monkeypatch):
    """Every dynamics test runs on the plain reference and on the compiled CPU substeps."""
    if request.param == "numba" and not numba_available():
        pytest.skip("needs Numba")
    monkeypatch.setenv("RECONPHYS_SIMULATOR", request.param)
    return request.param


def make_model(springs, rest, m, k, d, f, **kwargs) -> SpringMassModel:
    kwargs.setdefault("dtype", rest.dtype)
    return SpringMassModel(springs, rest, m, k, d, f, **kwargs)


def test_free_fall_follows_parabola(ball_anchors):
    anchors, springs, rest = ball_anchors
    x0 = anchors + torch.tensor([0.0, 0.0, 1.0], dtype=anchors.dtype)
    model = make_model(springs, rest, 1.0, 300.0, 1.0, 0.5)
    state = State(x0[None].clone(), torch.zeros_like(x0)[None])
    trajectory = rollout(model, state, num_frames=10, frame_dt=0.03, min_substeps=100)
    assert trajectory.x[..., 2].min() > 0.1, "the object must not reach the ground in this test"
    t = torch.arange(11, dtype=anchors.dtype) * 0.03
    expected = x0[:, 2].mean() - 0.5 * G * t**2
    centre = trajectory.x[0, :, :, 2].mean(-1)
    assert (centre - expected).abs().max() < 2e-3
    # Internal forces cancel: the shape does not change in free fall from rest.
    drift = trajectory.x[0, -1] - trajectory.x[0, -1].mean(0) - (x0 - x0.mean(0))
    assert drift.abs().max() < 1e-9


def test_scaling_mass_stiffness_damping_leaves_motion_unchanged(ball_anchors):
    anchors, springs, rest = ball_anchors
    x0 = anchors + torch.tensor([0.0, 0.0, 0.25], dtype=anchors.dtype)
    v0 = torch.zeros_like(x0)
    v0[:, 0] = 0.8  # sliding, so friction acts after contact
    state = State(x0[None], v0[None])
    runs = []
    for scale in (1.0, 3.7):
        model = make_model(springs, rest, 0.5 * scale, 200.0 * scale, 0.8 * scale, 0.4)
        runs.append(rollout(model, state, num_frames=20, min_substeps=20))
    assert runs[0].substeps == runs[1].substeps
    assert runs[0].x[..., 2].min() == 0.0, "the test must include ground contact"
    assert (runs[0].x - runs[1].x).abs().max() < 1e-5


def test_momentum_and_energy_conserved_without_gravity_damping_ground(ball_anchors):
    anchors, springs, rest = ball_anchors
    g = torch.Generator().manual_seed(3)
    v0 = 0.3 * torch.randn(anchors.shape, generator=g, dtype=anchors.dtype)
    model = make_model(
        springs,
        rest,
        0.7,
        150.0,
        0.0,
        0.5,
        spring_exponent=0.0,
        gravity=(0, 0, 0),
        ground_height=-100.0,
    )
    state = State(anchors[None].clone(), v0[None])
    trajectory = rollout(model, state, num_frames=30, min_substeps=100)
    momentum = 0.7 * trajectory.v[0].sum(1)  # [T+1, 3]
    assert (momentum - momentum[0]).abs().max() < 1e-12
    energy = torch.stack(
        [
            kinetic_energy(model, trajectory.v[:, t]) + spring_energy(model, trajectory.x[:, t])
            for t in range(31)
        ]
    )[:, 0]
    assert spring_energy(model, trajectory.x[:, 15])[0] > 0.05 * energy[0], "springs must work"
    assert ((energy - energy[0]).abs() / energy[0]).max() < 0.01


def test_all_attribute_corners_rest_on_ground_and_settle(ball_anchors):
    anchors, springs, rest = ball_anchors
    corners = torch.tensor(
        list(itertools.product((0.2, 6.0), (10.0, 1200.0), (0.1, 5.0), (0.0, 1.0))),
        dtype=torch.float32,
    )  # [16, 4] = (m, k, d, f)
    model = SpringMassModel(
        springs, rest.float(), corners[:, 0], corners[:, 1], corners[:, 2], corners[:, 3]
    )
    x0 = (anchors.float() + torch.tensor([0.0, 0.0, 0.22])).expand(16, -1, -1).contiguous()
    state = State(x0, torch.zeros_like(x0))
    trajectory = rollout(model, state, num_frames=100, min_substeps=1)
    assert torch.isfinite(trajectory.x).all() and torch.isfinite(trajectory.v).all()
    assert trajectory.x[..., 2].min() > -1e-3
    assert trajectory.x[..., 2].max() < 0.5, "nothing may be thrown upwards"
    frames = range(101)
    kinetic = torch.stack([kinetic_energy(model, trajectory.v[:, t]) for t in frames], 1)
    total = kinetic + torch.stack([potential_energy(model, trajectory.x[:, t]) for t in frames], 1)
    # Damping, inelastic contact and friction only ever remove energy.
    increase = (total[:, 1:] - total[:, :-1]).max(1).values / total[:, 0]
    assert (increase < 1e-4).all(), f"energy gained: {increase.tolist()}"
    assert (total[:, -1] < 0.99 * total[:, 0]).all()
    peak = kinetic.max(1).values  # [16]
    late = kinetic[:, -10:].max(1).values
    assert (late < peak).all()
    damped = corners[:, 2] == 5.0  # strongly damped corners come to rest within 3 s
    assert (late[damped] < 0.05 * peak[damped]).all(), (late / peak).tolist()


def sliding_slab(friction: float, frames: int):
    grid = box_grid(8, 8, 2, 0.05)
    springs, rest = knn_springs(grid, 12)
    rest = (grid[springs[:, 1]] - grid[springs[:, 0]]).norm(dim=1)
    model = make_model(springs, rest, 0.2, 1200.0, 1.0, friction)
    v0 = torch.zeros_like(grid)
    v0[:, 0] = 1.0
    return rollout(model, State(grid[None], v0[None]), num_frames=frames, min_substeps=50)


def test_friction_free_slab_keeps_sliding():
    trajectory = sliding_slab(0.0, 20)
    velocity = trajectory.v[0].mean(1)  # [T+1, 3]
    assert (velocity[:, 0] - 1.0).abs().max() < 1e-3


@pytest.mark.parametrize("friction", [0.2, 1.0])
def test_coulomb_friction_stopping_distance(friction):
    trajectory = sliding_slab(friction, 30)
    speed = trajectory.v[0].mean(1)[:, 0]
    distance = trajectory.x[0, -1, :, 0].mean() - trajectory.x[0, 0, :, 0].mean()
    assert speed[-1].abs() < 0.02, "a slab on the ground with friction must stop"
    expected = 1.0 / (2 * friction * G)  # v²/(2 μ g) for a rigid block
    assert abs(distance - expected) < 0.15 * expected


def test_more_friction_stops_sooner():
    def stop_frame(friction):
        speed = sliding_slab(friction, 30).v[0].mean(1)[:, 0]
        return int((speed < 0.02).nonzero()[0])

    assert stop_frame(1.0) < stop_frame(0.2)


def test_per_scene_topology_matches_shared(ball_anchors):
    anchors, springs, rest = ball_anchors
    x0 = (anchors + torch.tensor([0.0, 0.0, 0.21], dtype=anchors.dtype)).expand(2, -1, -1)
    state = State(x0.contiguous(), torch.zeros_like(x0))
    m, k = (
        torch.tensor([0.5, 2.0], dtype=rest.dtype),
        torch.tensor([100.0, 900.0], dtype=rest.dtype),
    )
    shared = make_model(springs, rest, m, k, 1.0, 0.5)
    batched = make_model(springs.expand(2, -1, -1), rest.expand(2, -1), m, k, 1.0, 0.5)
    a = rollout(shared, state, num_frames=5, substeps=60)
    b = rollout(batched, state, num_frames=5, substeps=60)
    assert torch.allclose(a.x, b.x, atol=1e-12)


def test_per_anchor_and_per_spring_attributes_match_scalars(ball_anchors):
    anchors, springs, rest = ball_anchors
    x0 = anchors + torch.tensor([0.0, 0.0, 0.21], dtype=anchors.dtype)
    state = State(x0[None], torch.zeros_like(x0)[None])
    n, e = anchors.shape[0], springs.shape[0]
    scalar = make_model(springs, rest, 0.5, 300.0, 1.0, 0.5)
    ones_a = torch.ones(1, n, dtype=rest.dtype)
    ones_e = torch.ones(1, e, dtype=rest.dtype)
    per_element = make_model(springs, rest, 0.5 * ones_a, 300.0 * ones_e, ones_e, 0.5 * ones_a)
    assert stable_substeps(scalar, state.x) == stable_substeps(per_element, state.x)
    a = rollout(scalar, state, num_frames=5, substeps=40)
    b = rollout(per_element, state, num_frames=5, substeps=40)
    assert torch.allclose(a.x, b.x, atol=1e-12)
    # A heavier half must respond more slowly to the same springs: per-anchor mass matters.
    heavy = make_model(springs, rest, 0.5 * ones_a * (1 + (x0[:, 0] > 0)), 300.0, 1.0, 0.5)
    c = rollout(heavy, state, num_frames=5, substeps=40)
    assert (c.x - a.x).abs().max() > 1e-4


@pytest.mark.cuda
def test_cuda_matches_cpu(ball_anchors):
    anchors, springs, rest = ball_anchors
    x0 = anchors + torch.tensor([0.0, 0.0, 0.21], dtype=anchors.dtype)
    state = State(x0[None], torch.zeros_like(x0)[None])
    model = make_model(springs, rest, 0.5, 300.0, 1.0, 0.5)
    cpu = rollout(model, state, num_frames=5, substeps=40)
    gpu = rollout(
        model.to("cuda"), State(state.x.cuda(), state.v.cuda()), 5, substeps=40, method="autograd"
    )
    assert torch.allclose(cpu.x, gpu.x.cpu(), atol=1e-9)
