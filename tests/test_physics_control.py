"""Grips and the frame stepper (physics/control.py)."""

from __future__ import annotations

import pytest
import torch
from test_physics_adjoint import small_system

from reconphys.physics import Control, SpringMassModel, State, step
from reconphys.physics.control import (
    Grip,
    grip_coefficients,
    grip_force,
    nearest_anchors,
    pick_point,
    plan_frame,
    simulate_frame,
)


def test_pick_finds_the_first_point_along_the_ray():
    points = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.5, 0.0, 0.5]])
    down = torch.tensor([0.0, 0.0, -1.0])
    assert pick_point(points, torch.tensor([0.0, 0.0, 5.0]), down, 0.01) == 1
    assert pick_point(points, torch.tensor([0.0, 0.0, 1.5]), down, 0.01) == 0
    assert pick_point(points, torch.tensor([0.2, 0.0, 5.0]), down, 0.01) is None


def test_grip_springs_fit_the_stability_budget():
    k, d = grip_coefficients(torch.tensor([2.0]), substep=1e-3)
    h = 1e-3
    omega_sq, rate = float(k[0]) / 2.0, float(d[0]) / 2.0
    assert h * h * omega_sq + 2 * h * rate < 4 * 0.3  # the headroom stable_substeps leaves


@pytest.mark.parametrize("simulator", ["auto", "autograd"])  # compiled substeps / torch step
def test_simulate_frame_recomputes_the_grip_force_every_substep(simulator, monkeypatch):
    monkeypatch.setenv("RECONPHYS_SIMULATOR", simulator)
    springs, rest, x0, v0, attributes = small_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    state = State(x0, v0)
    point = x0[0, 0]
    anchors = nearest_anchors(x0[0], point, 4)
    grip = Grip("g", anchors, x0[0, anchors] - point, point.clone(), point.clone())
    target = point + torch.tensor([0.0, 0.0, 0.02])
    frame_dt, substeps = 0.03, 6
    result = simulate_frame(model, state, frame_dt, substeps, [grip], [target])
    # By hand with the reference step: the force from the state at the start of each substep.
    h = frame_dt / substeps
    plan = plan_frame([grip], [target], model.mass, h, frame_dt)
    expected = state
    for s in range(substeps):
        force = grip_force(plan, expected.x, expected.v, (s + 1) / substeps)
        expected = step(model, expected, h, Control(force=force))
    atol = 0.0 if simulator == "autograd" else 1e-6  # compiled: float round-off only
    torch.testing.assert_close(result.x, expected.x, rtol=0, atol=atol)
    torch.testing.assert_close(result.v, expected.v, rtol=0, atol=atol * 100)
