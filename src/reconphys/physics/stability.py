"""The substep count that keeps semi-implicit Euler stable (docs/design.md#physical-model): a
power-iteration bound on the spring operator's largest eigenvalues."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .model import SpringMassModel
from .reference import gather_anchors, scatter_anchors

# The stability bound accounts for the stiffening of the non-linear spring law (tangent stiffness
# grows with |ε| when p_k > 0) up to strains of this magnitude.
MAX_STRAIN_FOR_BOUND = 1.0
# Power iteration approaches the largest eigenvalue from below; this factor covers the remainder
# (30 iterations reach within ~4 % on kNN lattices, see tests/test_physics_stability.py).
EIGENVALUE_MARGIN = 1.1
POWER_ITERATIONS = 30
# Fraction of the stability limit used: h²Ω² + 2hC ≤ 4·SAFETY (see stable_substeps).
SAFETY = 0.7


@torch.no_grad()
def largest_eigenvalue(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions giving the spring directions, metres
    coefficient: Tensor,  # [B|1, E|1] spring coefficient per unit strain (k or d)
    mass: Tensor,  # [B|1, N_A|1] kg
    iterations: int = POWER_ITERATIONS,
) -> Tensor:  # [B] 1/s² (for k) or 1/s (for d)
    """Largest eigenvalue of M⁻¹A per scene; A is the linearised spring operator with c/l.

    ``(A δ)_i = Σ_j (c_ij / l_ij) (u_ij u_ijᵀ)(δ_i − δ_j)``; power iteration on the symmetric
    M^-½ A M^-½ with a fixed start, so the estimate is deterministic (and slightly low).
    """
    i, j = model.springs[..., 0], model.springs[..., 1]
    x = x.detach()
    direction = gather_anchors(x, j) - gather_anchors(x, i)
    direction = direction / torch.linalg.vector_norm(direction, dim=-1, keepdim=True)
    weight = (coefficient / model.rest_length).abs()
    inverse_sqrt_mass = mass.rsqrt()[..., None]
    both_ends = torch.cat([i, j], dim=-1)

    def apply(u: Tensor) -> Tensor:
        displacement = u * inverse_sqrt_mass
        stretch = (gather_anchors(displacement, j) - gather_anchors(displacement, i)) * direction
        pull = (weight * stretch.sum(-1))[..., None] * direction
        force = scatter_anchors(x.shape[1], both_ends, torch.cat([pull, -pull], dim=1))
        return -force * inverse_sqrt_mass

    generator = torch.Generator().manual_seed(0)
    u = torch.randn(x.shape, generator=generator, dtype=torch.float64).to(x)
    estimate = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    for _ in range(iterations):
        w = apply(u)
        estimate = (u * w).sum((1, 2)) / (u * u).sum((1, 2))
        u = w / torch.linalg.vector_norm(w, dim=(1, 2), keepdim=True).clamp(min=1e-30)
    return estimate


@torch.no_grad()
def scene_stability_rates(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions, metres
) -> tuple[Tensor, Tensor]:  # [B'] each (B' = 1 when one value serves every scene)
    """Bounds per scene on the squared frequency Ω² (1/s²) and damping rate C (1/s).

    Ω² is the largest eigenvalue of M⁻¹K, with K the spring constants k/l scaled by the stiffening
    of the non-linear law up to MAX_STRAIN_FOR_BOUND; C that of M⁻¹D with dashpots d/l. Both get
    EIGENVALUE_MARGIN. When m, k and d are one value per scene, one eigenvalue of the unit-weight
    operator serves every scene (scaled by k/m and d/m).
    """
    p = model.spring_exponent
    s = MAX_STRAIN_FOR_BOUND
    stiffening = (1.0 + s) ** p * (1.0 + p * s / (1.0 + s)) if p > 0 else 1.0
    scalar = all(t.shape[1] == 1 for t in (model.mass, model.stiffness, model.damping))
    if scalar:
        one = torch.ones(1, 1, dtype=x.dtype, device=x.device)
        shared = model.springs.dim() == 2 and model.rest_length.dim() == 1
        if shared and x.shape[0] > 1 and bool((x == x[:1]).all()):  # one object, many attributes
            x = x[:1]  # (refinement, searches): the unit eigenvalue is computed once
        unit = largest_eigenvalue(model, x, one, one)  # [B|1] shared topology: one value per x
        omega_sq = unit * (model.stiffness / model.mass).abs()[:, 0]
        damping_rate = unit * (model.damping / model.mass).abs()[:, 0]
    else:
        omega_sq = largest_eigenvalue(model, x, model.stiffness, model.mass)
        damping_rate = largest_eigenvalue(model, x, model.damping, model.mass)
    margin = EIGENVALUE_MARGIN
    return margin * stiffening * omega_sq, margin * damping_rate


def stability_rates(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions, metres
) -> tuple[float, float]:
    """Bounds over the batch on Ω² (1/s²) and C (1/s) (see :func:`scene_stability_rates`)."""
    omega_sq, damping_rate = scene_stability_rates(model, x)
    return omega_sq.max().item(), damping_rate.max().item()


def stable_substeps(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions (the initial state), metres
    frame_dt: float = 0.03,
    min_substeps: int = 1,
) -> int:
    """Substeps per frame that keep semi-implicit Euler stable for every scene of the batch.

    For a mode x'' = −ω²x − c x', semi-implicit Euler with step h is stable iff
    h²ω² + 2hc < 4. With the bounds Ω², C of :func:`stability_rates` we solve
    h²Ω² + 2hC = 4·SAFETY for h. The result never falls below ``min_substeps``. It depends on k/m
    and d/m only, so scaling (m, k, d) together does not change it.
    """
    _check_mass(model)
    omega_sq, damping_rate = stability_rates(model, x)
    return _substeps_for(omega_sq, damping_rate, frame_dt, min_substeps)


def scene_stable_substeps(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions (the initial state), metres
    frame_dt: float = 0.03,
    min_substeps: int = 1,
) -> list[int]:  # [B] the substeps each scene needs on its own (one entry when all share them)
    """:func:`stable_substeps` per scene: a batch of candidates can be rolled out in groups of
    similar need instead of all at the stiffest one's step."""
    _check_mass(model)
    omega_sq, damping_rate = scene_stability_rates(model, x)
    count = max(len(omega_sq), len(damping_rate))
    omega_sq, damping_rate = omega_sq.expand(count), damping_rate.expand(count)
    return [
        _substeps_for(float(w), float(c), frame_dt, min_substeps)
        for w, c in zip(omega_sq, damping_rate, strict=True)
    ]


def _check_mass(model: SpringMassModel) -> None:
    if not (torch.isfinite(model.mass).all() and (model.mass > 0).all()):
        raise ValueError("mass must be finite and positive")


def _substeps_for(omega_sq: float, damping_rate: float, frame_dt: float, min_substeps: int) -> int:
    """The smallest substep count with h²Ω² + 2hC ≤ 4·SAFETY (and ≥ ``min_substeps``)."""
    budget = 4.0 * SAFETY
    if not (math.isfinite(omega_sq) and math.isfinite(damping_rate)):
        raise ValueError("attributes give no stable step (non-finite stiffness or damping)")
    if omega_sq > 0:
        h = (-damping_rate + math.sqrt(damping_rate**2 + budget * omega_sq)) / omega_sq
    elif damping_rate > 0:
        h = budget / (2.0 * damping_rate)
    else:
        return max(1, int(min_substeps))
    return max(int(min_substeps), math.ceil(frame_dt / h - 1e-9))
