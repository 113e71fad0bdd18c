"""The PyTorch engine: the reference substep (:func:`reconphys.physics.reference.step`) and its
exact vector-Jacobian product, derived by hand below (docs/design.md#physical-model).

The VJP matches autograd through :func:`~reconphys.physics.reference.step` exactly, including the
one-sided choices of its ``clamp`` and ``abs`` at ties. It is also the reference for the fused
Triton kernels (:mod:`reconphys.physics.triton_backend`), which implement the same equations per
anchor.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .engine import BackwardEngine
from .model import SpringMassModel
from .reference import gather_anchors, scatter_anchors, step
from .state import Control, State


def substep_vjp(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions at the start of the substep, metres
    v: Tensor,  # [B, N_A, 3] velocities at the start of the substep, m/s
    dt: float,  # substep length h, seconds
    grad_x: Tensor,  # [B, N_A, 3] dL/dx' (positions after the substep)
    grad_v: Tensor,  # [B, N_A, 3] dL/dv'
) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
    """Vector-Jacobian product of one :func:`step` (no control force).

    Returns (dL/dx [B, N_A, 3], dL/dv [B, N_A, 3], per-element attribute gradients
    {"mass" [B, N_A], "friction" [B, N_A], "stiffness" [B, E], "damping" [B, E],
    "rest_length" [B, E]}), not yet summed to the attributes' broadcast shapes.
    """
    h = dt
    e = model.restitution
    p = model.spring_exponent
    i, j = model.springs[..., 0], model.springs[..., 1]
    rest = model.rest_length
    k, d = model.stiffness, model.damping

    # --- recompute the forward quantities ---------------------------------------------------
    delta = gather_anchors(x, j) - gather_anchors(x, i)  # [B, E, 3]
    length = torch.sqrt((delta * delta).sum(-1) + 1e-24)  # [B, E]
    u = delta / length[..., None]
    strain = length / rest - 1.0
    a = strain.abs()
    phi = (1.0 + a) ** p if p != 0.0 else torch.ones_like(a)
    dv = gather_anchors(v, j) - gather_anchors(v, i)
    closing = (dv * u).sum(-1)
    magnitude = k * strain * phi + d / rest * closing  # [B, E]
    pull = magnitude[..., None] * u
    both_ends = torch.cat([i, j], dim=-1)
    force = scatter_anchors(x.shape[1], both_ends, torch.cat([pull, -pull], dim=1))
    mass = model.mass[..., None]  # [B|1, N_A|1, 1]
    v_free = v + (force / mass + model.gravity_vector) * h
    x_free = x + v_free * h

    below = x_free[..., 2] < model.ground_height  # [B, N_A]
    normal_speed = v_free[..., 2]
    approaching = normal_speed <= 0.0  # where clamp(max=0) passes its gradient
    approach = normal_speed.clamp(max=0.0)
    tangential = v_free[..., :2]
    tangential_speed = torch.sqrt((tangential * tangential).sum(-1) + 1e-30)
    friction = model.friction
    coefficient = (1.0 + e) * approach  # ≤ 0
    retained_raw = 1.0 + friction * coefficient / tangential_speed
    retained = torch.where(below, retained_raw.clamp(min=0.0), torch.ones_like(retained_raw))

    # --- ground contact ----------------------------------------------------------------------
    # x'_xy = x_free_xy − h (v_t − v_t'), x'_z = below ? ground : x_free_z;
    # v_t' = v_t · retained, v_n' = below ? v_n − (1 + e) min(v_n, 0) : v_n.
    grad_new_tangential = grad_v[..., :2] + h * grad_x[..., :2]
    grad_tangential = retained[..., None] * grad_new_tangential - h * grad_x[..., :2]
    grad_retained = (tangential * grad_new_tangential).sum(-1)
    grad_raw = torch.where(below & (retained_raw >= 0.0), grad_retained, 0.0)
    grad_friction = grad_raw * coefficient / tangential_speed
    grad_approach = grad_raw * friction * (1.0 + e) / tangential_speed
    grad_speed = -grad_raw * friction * coefficient / tangential_speed**2
    grad_tangential = grad_tangential + (grad_speed / tangential_speed)[..., None] * tangential
    grad_normal_out = grad_v[..., 2]
    grad_approach = grad_approach + torch.where(below, -(1.0 + e) * grad_normal_out, 0.0)
    grad_normal = grad_normal_out + torch.where(approaching, grad_approach, 0.0)
    grad_v_free = torch.cat([grad_tangential, grad_normal[..., None]], dim=-1)
    grad_x_free = torch.cat(
        [grad_x[..., :2], torch.where(below, 0.0, grad_x[..., 2])[..., None]], dim=-1
    )

    # --- free update: v_free = v + (F/m + g) h, x_free = x + v_free h ------------------------
    grad_v_free = grad_v_free + h * grad_x_free
    grad_force = grad_v_free * (h / mass)
    grad_mass = -(grad_v_free * force).sum(-1) * h / model.mass**2  # [B, N_A]
    grad_x_prev = grad_x_free
    grad_v_prev = grad_v_free

    # --- springs: F_i += mag·u, F_j −= mag·u --------------------------------------------------
    w = gather_anchors(grad_force, i) - gather_anchors(grad_force, j)  # [B, E, 3]
    grad_magnitude = (w * u).sum(-1)
    grad_u = magnitude[..., None] * w
    if p != 0.0:
        dmag_dstrain = k * (1.0 + a) ** (p - 1.0) * (1.0 + a + p * a)
    else:
        dmag_dstrain = k.expand_as(strain)
    grad_strain = grad_magnitude * dmag_dstrain
    grad_stiffness = grad_magnitude * strain * phi
    grad_damping = grad_magnitude * closing / rest
    grad_closing = grad_magnitude * d / rest
    grad_rest = -grad_magnitude * d * closing / rest**2
    grad_dv = grad_closing[..., None] * u
    grad_u = grad_u + grad_closing[..., None] * dv
    grad_length = grad_strain / rest
    grad_rest = grad_rest - grad_strain * length / rest**2
    radial = (u * grad_u).sum(-1, keepdim=True)
    grad_delta = (grad_u - u * radial) / length[..., None] + grad_length[..., None] * u
    ends = torch.cat([j, i], dim=-1)
    num_anchors = x.shape[1]
    grad_x_prev = grad_x_prev + scatter_anchors(
        num_anchors, ends, torch.cat([grad_delta, -grad_delta], dim=1)
    )
    grad_v_prev = grad_v_prev + scatter_anchors(
        num_anchors, ends, torch.cat([grad_dv, -grad_dv], dim=1)
    )
    attributes = {
        "mass": grad_mass,
        "friction": grad_friction,
        "stiffness": grad_stiffness,
        "damping": grad_damping,
        "rest_length": grad_rest,
    }
    return grad_x_prev, grad_v_prev, attributes


class TorchEngine(BackwardEngine):
    """Substep and substep-VJP in plain PyTorch (any device and dtype); the step is
    differentiable by autograd too (``rollout(method="autograd")``)."""

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int):
        self.model, self.dt = model, dt
        self.totals: dict[str, Tensor] = {}

    def step(self, x: Tensor, v: Tensor, force: Tensor | None = None) -> tuple[Tensor, Tensor]:
        control = None if force is None else Control(force=force)
        state = step(self.model, State(x, v), self.dt, control)
        return state.x, state.v

    def vjp(self, x: Tensor, v: Tensor, grad_x: Tensor, grad_v: Tensor) -> tuple[Tensor, Tensor]:
        """dL/d(x, v) before the substep; attribute gradients are accumulated in ``totals``."""
        grad_x, grad_v, grads = substep_vjp(self.model, x, v, self.dt, grad_x, grad_v)
        for name, g in grads.items():
            self.totals[name] = self.totals[name] + g if name in self.totals else g
        return grad_x, grad_v

    def attribute_grads(self) -> dict[str, Tensor]:
        """Per-element gradients summed over every VJP so far: mass/friction [B, N_A],
        stiffness/damping/rest_length [B, E]."""
        return self.totals
