"""Rollout with a hand-written exact backward (the adjoint of the substep), in plain PyTorch.

The forward pass runs :func:`reconphys.physics.integrator.step` without autograd and keeps only
the frame-boundary states. The backward pass walks the frames in reverse: it recomputes one frame's
substeps from its stored start state, then applies :func:`substep_vjp` (the vector-Jacobian
product of one substep, derived by hand below) from the last substep to the first. Memory is
O(frames + substeps per frame) states instead of autograd's O(frames × substeps × intermediates),
and the backward does no graph bookkeeping.

This is also the reference for the fused kernels (:mod:`reconphys.physics.triton_kernels`), which
implement the same equations per anchor. Derivatives match autograd through
:func:`~reconphys.physics.integrator.step` exactly, including the one-sided choices of its
``clamp`` and ``abs`` at ties. Gradients flow to x0, v0, mass, stiffness, damping, friction and
rest lengths (each in the shape it has in the model), not to gravity, ground height, restitution
or the spring exponent (plain floats in the model).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .integrator import _gather_anchors, _scatter_anchors, step
from .model import SpringMassModel
from .state import State


def sum_to_shape(grad: Tensor, shape: torch.Size) -> Tensor:
    """Sum ``grad`` over the dims where ``shape`` has size 1 (undo broadcasting); same rank."""
    dims = tuple(d for d, size in enumerate(shape) if size == 1 and grad.shape[d] != 1)
    return grad.sum(dims, keepdim=True) if dims else grad


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
    delta = _gather_anchors(x, j) - _gather_anchors(x, i)  # [B, E, 3]
    length = torch.sqrt((delta * delta).sum(-1) + 1e-24)  # [B, E]
    u = delta / length[..., None]
    strain = length / rest - 1.0
    a = strain.abs()
    phi = (1.0 + a) ** p if p != 0.0 else torch.ones_like(a)
    dv = _gather_anchors(v, j) - _gather_anchors(v, i)
    closing = (dv * u).sum(-1)
    magnitude = k * strain * phi + d / rest * closing  # [B, E]
    pull = magnitude[..., None] * u
    both_ends = torch.cat([i, j], dim=-1)
    force = _scatter_anchors(x.shape[1], both_ends, torch.cat([pull, -pull], dim=1))
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
    w = _gather_anchors(grad_force, i) - _gather_anchors(grad_force, j)  # [B, E, 3]
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
    grad_x_prev = grad_x_prev + _scatter_anchors(
        num_anchors, ends, torch.cat([grad_delta, -grad_delta], dim=1)
    )
    grad_v_prev = grad_v_prev + _scatter_anchors(
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


ATTRIBUTES = ("mass", "stiffness", "damping", "friction", "rest_length")


class TorchEngine:
    """Substep and substep-VJP in plain PyTorch (any device and dtype)."""

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int):
        self.model, self.dt = model, dt
        self.totals: dict[str, Tensor] = {}

    def step(self, x: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        state = step(self.model, State(x, v), self.dt)
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


class AdjointRollout(torch.autograd.Function):
    """Frame-boundary states of a rollout; backward by recomputation and substep VJPs.

    ``make_engine(model, dt, batch, num_anchors)`` gives an object with ``step(x, v)``,
    ``vjp(x, v, gx, gv)`` and ``attribute_grads()`` (see :class:`TorchEngine`); the fused CUDA
    path plugs in here too.
    """

    @staticmethod
    def forward(ctx, make_engine, template, frames, substeps, dt, progress, x0, v0, *attributes):
        model = template.with_attributes(**dict(zip(ATTRIBUTES, attributes, strict=True)))
        engine = make_engine(model, dt, *x0.shape[:2])
        x, v = x0, v0
        xs, vs = [x0], [v0]
        frame_range = range(frames)
        if progress:
            from tqdm.auto import tqdm

            label = f"simulate ({substeps} substeps/frame)"
            frame_range = tqdm(frame_range, desc=label, unit="frame")
        for _ in frame_range:
            for _ in range(substeps):
                x, v = engine.step(x, v)
            xs.append(x)
            vs.append(v)
        xs, vs = torch.stack(xs, 1), torch.stack(vs, 1)
        ctx.make_engine, ctx.model, ctx.substeps, ctx.dt = make_engine, model, substeps, dt
        ctx.save_for_backward(xs, vs)
        return xs, vs

    @staticmethod
    def backward(ctx, grad_xs, grad_vs):
        xs, vs = ctx.saved_tensors
        model, substeps = ctx.model, ctx.substeps
        engine = ctx.make_engine(model, ctx.dt, *xs.shape[:1], xs.shape[2])
        num_frames = xs.shape[1] - 1
        grad_x = grad_xs[:, num_frames].contiguous()
        grad_v = grad_vs[:, num_frames].contiguous()
        for frame in reversed(range(num_frames)):
            states = [(xs[:, frame], vs[:, frame])]
            for _ in range(substeps - 1):
                states.append(engine.step(*states[-1]))
            for x, v in reversed(states):
                grad_x, grad_v = engine.vjp(x, v, grad_x, grad_v)
            grad_x = grad_x + grad_xs[:, frame]
            grad_v = grad_v + grad_vs[:, frame]
        totals = engine.attribute_grads()
        grad_attributes = []
        for name in ATTRIBUTES:
            value = getattr(model, name)
            grad = totals[name]
            if value.dim() == 1:  # rest_length [E] shared by the batch
                grad = grad.sum(0)
            grad_attributes.append(sum_to_shape(grad, value.shape))
        return (None, None, None, None, None, None, grad_x, grad_v, *grad_attributes)


def rollout_adjoint(
    model: SpringMassModel,
    state: State,
    num_frames: int,
    substeps: int,
    frame_dt: float = 0.03,
    make_engine=TorchEngine,
    progress: bool = False,
) -> tuple[Tensor, Tensor]:  # x [B, T+1, N_A, 3], v [B, T+1, N_A, 3]
    """Frame-boundary states of ``num_frames`` frames, differentiable through the adjoint.

    With the default :class:`TorchEngine` this is the same trajectory as substepping
    :func:`step` under autograd (bit for bit on CPU), with the exact gradient.
    """
    batch = max(state.x.shape[0], state.v.shape[0], model.batch_size)
    x0 = state.x.expand(batch, -1, -1).contiguous()
    v0 = state.v.expand(batch, -1, -1).contiguous()
    attributes = [getattr(model, name) for name in ATTRIBUTES]
    dt = frame_dt / substeps
    detached = {name: t.detach() for name, t in zip(ATTRIBUTES, attributes, strict=True)}
    template = model.with_attributes(**detached)
    return AdjointRollout.apply(
        make_engine, template, num_frames, substeps, dt, progress, x0, v0, *attributes
    )
