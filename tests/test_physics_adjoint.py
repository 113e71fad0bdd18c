"""The hand-written adjoint (physics/adjoint.py) against autograd through the reference step."""

from __future__ import annotations

import pytest
import torch

from reconphys.physics import SpringMassModel, State, knn_springs, rollout, sample_volume_anchors

F64 = torch.float64


def small_system(num_anchors=18, batch=2, seed=0, per_scene_topology=False, dtype=F64):
    """A few anchors just above the ground, moving down and sideways: contact within 2 substeps."""
    g = torch.Generator().manual_seed(seed)
    points = torch.rand(500, 3, generator=g, dtype=F64) * 0.2
    anchors = sample_volume_anchors(points, num_anchors, seed=f"adjoint-{seed}").to(dtype)
    springs, rest = knn_springs(anchors, 6)
    rest = rest.to(dtype)
    if per_scene_topology:  # scene 1 drops the last springs (padded with zero-stiffness ones)
        springs = springs.expand(batch, -1, -1).clone()
        rest = rest.expand(batch, -1).clone()
    x0 = (anchors + torch.tensor([0.0, 0.0, 0.002], dtype=dtype)).expand(batch, -1, -1).clone()
    v0 = 0.3 * torch.randn(batch, num_anchors, 3, generator=g, dtype=F64).to(dtype)
    v0 = v0 + torch.tensor([0.4, 0.0, -0.5], dtype=dtype)
    num_springs = springs.shape[-2]
    attributes = {
        "mass": (torch.rand(batch, num_anchors, generator=g, dtype=F64) + 0.5).to(dtype),
        "stiffness": (100 * torch.rand(batch, num_springs, generator=g, dtype=F64) + 10).to(dtype),
        "damping": (torch.rand(batch, generator=g, dtype=F64) + 0.2).to(dtype),
        "friction": (0.8 * torch.rand(batch, num_anchors, generator=g, dtype=F64)).to(dtype),
    }
    if per_scene_topology:
        attributes["stiffness"][1, -5:] = 0.0
    return springs, rest, x0, v0, attributes


def trajectories(method, springs, rest, x0, v0, attributes, exponent=0.5, restitution=0.0):
    inputs = {"x0": x0, "v0": v0, "rest": rest, **attributes}
    inputs = {name: t.clone().requires_grad_(True) for name, t in inputs.items()}
    model = SpringMassModel(
        springs,
        inputs["rest"],
        inputs["mass"],
        inputs["stiffness"],
        inputs["damping"],
        inputs["friction"],
        spring_exponent=exponent,
        restitution=restitution,
        dtype=x0.dtype,
    )
    traj = rollout(model, State(inputs["x0"], inputs["v0"]), 3, substeps=5, method=method)
    g = torch.Generator().manual_seed(1)
    weights = torch.randn(traj.x.shape, generator=g, dtype=F64).to(x0.dtype)
    loss = (traj.x * weights).sum() + (traj.v * weights.flip(1)).sum()
    grads = torch.autograd.grad(loss, list(inputs.values()))
    return traj, dict(zip(inputs, grads, strict=True))


@pytest.mark.parametrize(
    "exponent, restitution, per_scene", [(0.5, 0.0, False), (0.0, 0.5, False), (0.5, 0.3, True)]
)
def test_adjoint_matches_autograd(exponent, restitution, per_scene):
    system = small_system(per_scene_topology=per_scene)
    reference, grads_ref = trajectories("autograd", *system, exponent, restitution)
    adjoint, grads_adj = trajectories("adjoint", *system, exponent, restitution)
    assert (reference.x[..., 2] <= 1e-12).any(), "the window must include ground contact"
    assert torch.equal(reference.x, adjoint.x) and torch.equal(reference.v, adjoint.v)
    for name, expected in grads_ref.items():
        assert grads_adj[name].shape == expected.shape, name
        assert expected.abs().max() > 0, name
        error = (grads_adj[name] - expected).abs().max() / expected.abs().max()
        assert error < 1e-12, f"{name}: relative error {error:.2e}"


def test_adjoint_gradcheck_with_contact():
    springs, rest, x0, v0, attributes = small_system(num_anchors=10, batch=1)

    def run(v0, mass, stiffness, damping, friction, rest):
        model = SpringMassModel(springs, rest, mass, stiffness, damping, friction, dtype=F64)
        traj = rollout(model, State(x0, v0), 2, substeps=3, method="adjoint")
        return traj.x[:, -1], traj.v[:, -1]

    inputs = [v0, *attributes.values(), rest]
    inputs = [t.clone().requires_grad_(True) for t in inputs]
    assert torch.autograd.gradcheck(run, inputs, eps=1e-7, atol=1e-6, rtol=1e-5)


def test_broadcast_state_and_scalar_attributes_reduce_like_autograd():
    """x0 [1, N, 3] shared by a batch of 3 attribute sets; scalar friction and rest [E]."""
    springs, rest, x0, v0, attributes = small_system(batch=1)
    attributes = {
        "mass": torch.tensor([0.5, 1.0, 2.0], dtype=F64),
        "stiffness": torch.tensor(80.0, dtype=F64),
        "damping": torch.tensor([0.5, 1.0, 2.0], dtype=F64),
        "friction": torch.tensor(0.4, dtype=F64),
    }
    reference, grads_ref = trajectories("autograd", springs, rest, x0, v0, attributes)
    adjoint, grads_adj = trajectories("adjoint", springs, rest, x0, v0, attributes)
    assert adjoint.x.shape[0] == 3 and torch.equal(reference.x, adjoint.x)
    for name, expected in grads_ref.items():
        assert grads_adj[name].shape == expected.shape, name
        torch.testing.assert_close(grads_adj[name], expected, rtol=1e-11, atol=1e-14)
