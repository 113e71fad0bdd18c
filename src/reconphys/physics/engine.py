"""The engine interface: what every simulator twin implements (the ``SolverBase.step`` idea of
NVIDIA Newton, see docs/design.md#physical-model for the equations every engine follows).

An engine is built once per rollout for one model, one substep length ``dt`` and one batch shape;
:meth:`Engine.step` then advances positions and velocities by one substep, with an optional
external force held over it. Engines hold no simulation state between calls.

- :class:`reconphys.physics.torch_backend.TorchEngine`: the plain PyTorch reference step (any
  device and dtype, differentiable by autograd) and its hand-written VJP.
- :class:`reconphys.physics.triton_backend.TritonEngine`: fused Triton kernels of the same step and
  VJP (CUDA; no external force).
- :class:`reconphys.physics.numba_backend.NumbaEngine`: compiled CPU substeps and VJP.

:class:`BackwardEngine` adds the substep VJP that :mod:`reconphys.physics.adjoint` needs for its
engine-generic exact backward, and :meth:`BackwardEngine.frame_vjp`, a frame of them (recompute
the frame's substeps from its start state, then their VJPs in reverse), which an engine may do in
one call (Numba does). :func:`reconphys.physics.rollout.rollout` picks the engine.
"""

from __future__ import annotations

from typing import Protocol

from torch import Tensor

from .model import SpringMassModel


class Engine(Protocol):
    """Substeps of length ``dt`` seconds for a batch of ``batch`` scenes of ``num_anchors`` anchors.

    Constructed as ``Engine(model, dt, batch, num_anchors)``.
    """

    dt: float  # substep length h, seconds

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int) -> None: ...

    def step(
        self,
        x: Tensor,  # [B, N_A, 3] positions, metres
        v: Tensor,  # [B, N_A, 3] velocities, m/s
        force: Tensor | None = None,  # [B, N_A, 3] external force held over the substep, newtons
    ) -> tuple[Tensor, Tensor]:  # x, v [B, N_A, 3] after the substep
        """One substep (semi-implicit Euler, then ground contact)."""
        ...

    def run(
        self,
        x: Tensor,  # [B, N_A, 3] positions, metres
        v: Tensor,  # [B, N_A, 3] velocities, m/s
        substeps: int,
        force: Tensor | None = None,  # [B, N_A, 3] external force held over all substeps, N
    ) -> tuple[Tensor, Tensor]:  # x, v [B, N_A, 3] after ``substeps`` substeps
        """``substeps`` substeps in a row; an engine may do them in one call (Numba does)."""
        for _ in range(substeps):
            x, v = self.step(x, v, force)
        return x, v


class BackwardEngine(Engine, Protocol):
    """An engine with the exact vector-Jacobian product of its substep (no external force)."""

    def vjp(
        self,
        x: Tensor,  # [B, N_A, 3] positions at the start of the substep, metres
        v: Tensor,  # [B, N_A, 3] velocities at the start of the substep, m/s
        grad_x: Tensor,  # [B, N_A, 3] dL/dx' (positions after the substep)
        grad_v: Tensor,  # [B, N_A, 3] dL/dv'
    ) -> tuple[Tensor, Tensor]:  # dL/dx, dL/dv [B, N_A, 3] before the substep
        """dL/d(x, v) before the substep; attribute gradients are accumulated in the engine."""
        ...

    def frame_vjp(
        self,
        x: Tensor,  # [B, N_A, 3] positions at the start of the frame, metres
        v: Tensor,  # [B, N_A, 3] velocities at the start of the frame, m/s
        substeps: int,
        grad_x: Tensor,  # [B, N_A, 3] dL/dx after ``substeps`` substeps
        grad_v: Tensor,  # [B, N_A, 3] dL/dv after them
    ) -> tuple[Tensor, Tensor]:  # dL/dx, dL/dv [B, N_A, 3] at the start
        """VJP of ``substeps`` substeps from (x, v): recompute their start states, then
        :meth:`vjp` from the last to the first. Memory: ``substeps`` states."""
        states = [(x, v)]
        for _ in range(substeps - 1):
            states.append(self.step(*states[-1]))
        for x, v in reversed(states):
            grad_x, grad_v = self.vjp(x, v, grad_x, grad_v)
        return grad_x, grad_v

    def attribute_grads(self) -> dict[str, Tensor]:
        """Per-element gradients summed over every VJP so far: mass/friction [B, N_A],
        stiffness/damping/rest_length [B, E]."""
        ...
