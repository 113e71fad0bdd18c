"""The rollout (physics/rollout.py): gradcheck in float64 through substeps that include ground
contact, the choice of method and the per-substep control hook."""

from __future__ import annotations

import pytest
import torch
from test_physics_adjoint import small_system as adjoint_system
from torch.autograd import gradcheck

from reconphys._optional import numba_available
from reconphys.physics import SpringMassModel, State, knn_springs, rollout
from reconphys.physics.rollout import choose_method
from reconphys.physics.state import Control


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


def test_method_choice():
    springs, rest, x0, v0, attributes = adjoint_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    state = State(x0, v0)
    forward_only = "numba" if numba_available() else "autograd"
    assert choose_method("auto", model, state) == forward_only  # nothing needs a gradient
    grad_state = State(x0, v0.clone().requires_grad_(True))
    assert choose_method("auto", model, grad_state) == ("numba" if numba_available() else "adjoint")
    with torch.no_grad():
        assert choose_method("auto", model, grad_state) == forward_only
    control = Control(force=torch.zeros_like(x0))
    assert choose_method("auto", model, grad_state, control) == "autograd"
    assert choose_method("auto", model, state, control) == forward_only
    with pytest.raises(ValueError, match="control"):
        choose_method("adjoint", model, state, control)
    with pytest.raises(ValueError, match="method"):
        choose_method("warp", model, state)


def test_environment_overrides_auto(monkeypatch):
    springs, rest, x0, v0, attributes = adjoint_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    state = State(x0, v0.clone().requires_grad_(True))
    monkeypatch.setenv("RECONPHYS_SIMULATOR", "autograd")
    assert choose_method("auto", model, state) == "autograd"
    monkeypatch.setenv("RECONPHYS_SIMULATOR", "bogus")
    with pytest.raises(ValueError, match="RECONPHYS_SIMULATOR"):
        choose_method("auto", model, state)


def test_fused_on_cpu_needs_the_interpreter(monkeypatch):
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    springs, rest, x0, v0, attributes = adjoint_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    with pytest.raises(ValueError, match="fused"):
        choose_method("fused", model, State(x0, v0))


@pytest.mark.parametrize("method", ["autograd", "numba"])
def test_control_fn_per_substep_matches_a_constant_control(method):
    if method == "numba" and not numba_available():
        pytest.skip("needs Numba")
    springs, rest, x0, v0, attributes = adjoint_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    force = 0.05 * torch.randn(x0.shape, generator=torch.Generator().manual_seed(3))
    constant = rollout(
        model, State(x0, v0), 3, substeps=4, control=Control(force=force), method=method
    )
    seen = []

    def control_fn(state, substep):
        seen.append(substep)
        return Control(force=force) if substep % 2 == 0 else Control(force=force.clone())

    hooked = rollout(model, State(x0, v0), 3, substeps=4, control_fn=control_fn, method=method)
    assert seen == list(range(12))
    assert torch.equal(hooked.x, constant.x) and torch.equal(hooked.v, constant.v)
    none = rollout(model, State(x0, v0), 3, substeps=4, control_fn=lambda s, i: None, method=method)
    assert torch.equal(none.x, rollout(model, State(x0, v0), 3, substeps=4, method=method).x)


def test_control_fn_needs_a_forward_method():
    springs, rest, x0, v0, attributes = adjoint_system(batch=1, dtype=torch.float32)
    model = SpringMassModel(springs, rest, **attributes)
    state = State(x0, v0.clone().requires_grad_(True))
    assert choose_method("auto", model, state, control_fn=lambda s, i: None) == "autograd"
    with pytest.raises(ValueError, match="control"):
        rollout(model, state, 1, control_fn=lambda s, i: None, method="adjoint")
    with pytest.raises(ValueError, match="not both"):
        rollout(model, state, 1, control=Control(), control_fn=lambda s, i: None)
