"""The stability bound (physics/stability.py) against dense algebra and actual rollouts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from reconphys.physics import SpringMassModel, State, rollout, stable_substeps
from reconphys.physics.stability import largest_eigenvalue, stability_rates


def dense_stiffness(points: torch.Tensor, springs: torch.Tensor, rest: torch.Tensor) -> np.ndarray:
    """The linearised stiffness matrix Σ (1/l) [u uᵀ, −u uᵀ; −u uᵀ, u uᵀ] built entry by entry."""
    n = points.shape[0]
    matrix = np.zeros((3 * n, 3 * n))
    p = points.double().numpy()
    for (i, j), length in zip(springs.tolist(), rest.double().tolist(), strict=True):
        u = (p[j] - p[i]) / np.linalg.norm(p[j] - p[i])
        block = np.outer(u, u) / length
        for a, b, sign in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
            matrix[3 * a : 3 * a + 3, 3 * b : 3 * b + 3] += sign * block
    return matrix


def test_power_iteration_eigenvalue_matches_dense_solver(ball_anchors):
    anchors, springs, rest = ball_anchors
    mass = 0.5 + torch.rand(1, anchors.shape[0], generator=torch.Generator().manual_seed(0))
    mass = mass.double()
    model = SpringMassModel(springs, rest, mass, 1.0, 1.0, 0.0, dtype=torch.float64)
    one = torch.ones(1, 1, dtype=torch.float64)
    estimate = largest_eigenvalue(model, anchors[None], one, mass).item()
    inverse_sqrt_mass = np.repeat(mass[0].numpy() ** -0.5, 3)
    matrix = dense_stiffness(anchors, springs, rest)
    exact = np.linalg.eigvalsh(inverse_sqrt_mass[:, None] * matrix * inverse_sqrt_mass[None]).max()
    assert 0.9 * exact < estimate <= exact * (1 + 1e-9)


@pytest.mark.parametrize("m, k, d", [(0.2, 1200.0, 5.0), (0.2, 1200.0, 0.1), (1.0, 300.0, 1.0)])
def test_stability_bound_is_stable_and_not_wasteful(ball_anchors, m, k, d):
    anchors, springs, rest = ball_anchors
    model = SpringMassModel(springs, rest, m, k, d, 0.5, dtype=torch.float64)
    x0 = anchors + torch.tensor([0.0, 0.0, 0.21], dtype=torch.float64)
    v0 = 0.3 * torch.randn(x0.shape, generator=torch.Generator().manual_seed(0), dtype=x0.dtype)
    state = State(x0[None], v0[None])
    substeps = stable_substeps(model, state.x)
    stable = rollout(model, state, num_frames=5, substeps=substeps)
    assert torch.isfinite(stable.x).all() and stable.x.abs().max() < 1.0
    unstable = rollout(model, state, num_frames=5, substeps=max(1, substeps // 4))
    assert not (torch.isfinite(unstable.x).all() and unstable.x.abs().max() < 1.0), (
        "a quarter of the bound should already blow up: the bound would be too conservative"
    )


def test_one_object_with_many_attribute_sets_matches_scene_by_scene(ball_anchors):
    """A batch of one object under several (k/m, d/m) — refinement's candidates — computes the
    unit eigenvalue once; the bounds equal those of each scene alone (and of a moved copy)."""
    anchors, springs, rest = ball_anchors
    k = torch.tensor([10.0, 300.0, 1200.0])
    d = torch.tensor([5.0, 0.1, 1.0])
    m = torch.tensor([0.2, 1.0, 6.0])
    x = anchors[None].expand(3, -1, -1).float()
    batch = stability_rates(SpringMassModel(springs, rest, m, k, d, 0.5), x)
    alone = [
        stability_rates(SpringMassModel(springs, rest, m[b : b + 1], k[b], d[b], 0.5), x[:1])
        for b in range(3)
    ]
    assert batch == pytest.approx((max(a[0] for a in alone), max(a[1] for a in alone)), rel=1e-6)
    moved = x.clone()
    moved[1] *= 0.5  # a different shape: springs twice as stiff per metre, not deduplicated
    rates = stability_rates(SpringMassModel(springs, rest, m, k, d, 0.5), moved)
    assert rates[0] > batch[0]
