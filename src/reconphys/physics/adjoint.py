"""Rollout with a hand-written exact backward (the adjoint of the substep), for any engine.

The forward pass runs an engine's substep (:mod:`reconphys.physics.engine`; by default the
PyTorch reference :class:`~reconphys.physics.torch_backend.TorchEngine`) without autograd and keeps
only the frame-boundary states. The backward pass walks the frames in reverse: it recomputes one
frame's substeps from its stored start state, then applies the engine's substep VJP (for the
PyTorch engine :func:`~reconphys.physics.torch_backend.substep_vjp`) from the last substep to the
first. Memory is O(frames + substeps per frame) states instead of autograd's O(frames × substeps ×
intermediates), and the backward does no graph bookkeeping.

Derivatives match autograd through :func:`~reconphys.physics.reference.step` exactly. Gradients
flow to x0, v0, mass, stiffness, damping, friction and rest lengths (each in the shape it has in
the model), not to gravity, ground height, restitution or the spring exponent (plain floats in the
model).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .model import ATTRIBUTES, SpringMassModel
from .state import State
from .torch_backend import TorchEngine


def sum_to_shape(grad: Tensor, shape: torch.Size) -> Tensor:
    """Sum ``grad`` over the dims where ``shape`` has size 1 (undo broadcasting); same rank."""
    dims = tuple(d for d, size in enumerate(shape) if size == 1 and grad.shape[d] != 1)
    return grad.sum(dims, keepdim=True) if dims else grad


# The model tensors the backward differentiates: the four attributes and the springs' rest lengths.
DIFFERENTIABLE = (*ATTRIBUTES, "rest_length")


class AdjointRollout(torch.autograd.Function):
    """Frame-boundary states of a rollout; backward by recomputation and substep VJPs.

    ``make_engine(model, dt, batch, num_anchors)`` gives a
    :class:`~reconphys.physics.engine.BackwardEngine` (``TorchEngine`` or ``TritonEngine``).
    """

    @staticmethod
    def forward(ctx, make_engine, template, frames, substeps, dt, progress, x0, v0, *attributes):
        model = template.with_attributes(**dict(zip(DIFFERENTIABLE, attributes, strict=True)))
        engine = make_engine(model, dt, *x0.shape[:2])
        x, v = x0, v0
        xs, vs = [x0], [v0]
        frame_range = range(frames)
        if progress:
            from tqdm.auto import tqdm

            label = f"simulate ({substeps} substeps/frame)"
            frame_range = tqdm(frame_range, desc=label, unit="frame")
        for _ in frame_range:
            x, v = engine.run(x, v, substeps)
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
            grad_x, grad_v = engine.frame_vjp(xs[:, frame], vs[:, frame], substeps, grad_x, grad_v)
            grad_x = grad_x + grad_xs[:, frame]
            grad_v = grad_v + grad_vs[:, frame]
        totals = engine.attribute_grads()
        grad_attributes = []
        for name in DIFFERENTIABLE:
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
    :func:`~reconphys.physics.reference.step` under autograd (bit for bit on CPU), with the exact
    gradient.
    """
    batch = max(state.x.shape[0], state.v.shape[0], model.batch_size)
    x0 = state.x.expand(batch, -1, -1).contiguous()
    v0 = state.v.expand(batch, -1, -1).contiguous()
    attributes = [getattr(model, name) for name in DIFFERENTIABLE]
    dt = frame_dt / substeps
    detached = {name: t.detach() for name, t in zip(DIFFERENTIABLE, attributes, strict=True)}
    template = model.with_attributes(**detached)
    return AdjointRollout.apply(
        make_engine, template, num_frames, substeps, dt, progress, x0, v0, *attributes
    )
