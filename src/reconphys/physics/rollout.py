"""The rollout dispatcher: frames of substeps with the engine that suits the call
(docs/design.md#physical-model).

:func:`rollout` strings substeps into frames with a substep count taken from
:func:`~reconphys.physics.stability.stable_substeps` and picks the engine
(:mod:`reconphys.physics.engine`) with :func:`choose_method`; the exact backward of
:mod:`reconphys.physics.adjoint` wraps the engines that have a VJP.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from .._optional import numba_available
from .adjoint import rollout_adjoint
from .model import SpringMassModel
from .stability import stable_substeps
from .state import Control, State
from .torch_backend import TorchEngine

METHODS = ("auto", "autograd", "adjoint", "fused", "numba")

# Control for one substep from the state at its start and the substep's index counted from the
# start of the rollout (frame × substeps + substep within the frame); None: no external force.
ControlFn = Callable[[State, int], "Control | None"]


def choose_method(
    method: str,
    model: SpringMassModel,
    state: State,
    control: Control | None = None,
    control_fn: ControlFn | None = None,
) -> str:
    """Resolve ``method="auto"`` (see :func:`rollout`) and check an explicit choice."""
    from .triton_backend import fused_usable

    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if method == "auto":
        method = os.environ.get("RECONPHYS_SIMULATOR", "auto")
        if method not in METHODS:
            raise ValueError(f"RECONPHYS_SIMULATOR: expected one of {METHODS}, got {method!r}")

    needs_grad = _needs_grad(model, state)
    has_control = (control is not None and control.force is not None) or control_fn is not None
    if method in ("adjoint", "fused") and has_control:
        raise ValueError(f"method {method!r} does not take a control force; use 'autograd'")
    if method == "fused" and not fused_usable(state.x.device):
        raise ValueError(
            "method 'fused' needs Triton and a CUDA device (or TRITON_INTERPRET=1 on CPU)"
        )
    if method == "numba":
        if not numba_available():
            raise ValueError("method 'numba' needs Numba (pip install numba)")
        if state.x.is_cuda:
            raise ValueError("method 'numba' runs on CPU")
        if needs_grad and has_control:
            raise ValueError("method 'numba' takes a control force only without gradients")
    if method != "auto":
        return method
    if not state.x.is_cuda and numba_available() and not (needs_grad and has_control):
        return "numba"
    if has_control:
        return "autograd"
    if state.x.is_cuda and fused_usable(state.x.device):
        return "fused"
    return "adjoint" if needs_grad else "autograd"


def _needs_grad(model: SpringMassModel, state: State) -> bool:
    tensors = [state.x, state.v, model.rest_length, model.mass, model.stiffness]
    tensors += [model.damping, model.friction]
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


@dataclass
class Trajectory:
    x: Tensor  # [B, T+1, N_A, 3] positions at each frame boundary, frame 0 = initial state
    v: Tensor  # [B, T+1, N_A, 3] velocities at each frame boundary
    substeps: int  # substeps per frame that were used
    frame_dt: float  # seconds between frames


def rollout(
    model: SpringMassModel,
    state: State,
    num_frames: int,
    frame_dt: float = 0.03,
    min_substeps: int = 1,
    substeps: int | None = None,
    control: Control | None = None,
    progress: bool = False,
    method: str = "auto",
    control_fn: ControlFn | None = None,
) -> Trajectory:
    """Simulate ``num_frames`` frames and keep the state at every frame boundary.

    ``substeps`` forces an exact count (the caller is then responsible for stability); by default
    it is :func:`~reconphys.physics.stability.stable_substeps` with ``min_substeps`` as the floor:
    the stiffest, most damped scene of the batch decides. Gradients flow through every substep to
    the attributes, rest lengths and initial state.

    External forces: ``control`` is held over the whole rollout; ``control_fn(state, substep)``
    instead gives the control of each substep from the state at its start (``substep`` counts
    from 0 at the start of the rollout), e.g. the grips of :mod:`reconphys.physics.control`.

    ``method`` (all give the same trajectory and gradients up to float round-off):

    - ``"autograd"``: the plain reference, autograd through every
      :func:`~reconphys.physics.reference.step`; memory grows with frames × substeps; takes a
      ``control`` or ``control_fn``.
    - ``"adjoint"``: the same forward, with the hand-written exact backward of
      :mod:`reconphys.physics.adjoint` (memory O(frames + substeps)).
    - ``"fused"``: the Triton kernels of :mod:`reconphys.physics.triton_backend` with the same
      backward (CUDA; on CPU only under Triton's interpreter, for tests).
    - ``"numba"``: compiled CPU substeps of :mod:`reconphys.physics.numba_backend`, with the
      same adjoint backward as ``"adjoint"`` (compiled too); takes a ``control`` or
      ``control_fn`` when no gradient is needed.
    - ``"auto"``: on CPU ``"numba"`` (when Numba is installed), unless a gradient and a control
      are both asked for; else ``"autograd"`` with a ``control``; ``"fused"`` on CUDA when Triton
      is installed; else ``"adjoint"`` when a gradient is needed, else ``"autograd"``. The
      environment variable ``RECONPHYS_SIMULATOR`` (one of the names above) overrides the
      automatic choice, e.g. ``RECONPHYS_SIMULATOR=autograd`` forces the fast path off.
    """
    if control is not None and control_fn is not None:
        raise ValueError("give a control or a control_fn, not both")
    if substeps is None:
        substeps = stable_substeps(model, state.x, frame_dt, min_substeps)
    method = choose_method(method, model, state, control, control_fn)
    batch = max(state.x.shape[0], state.v.shape[0], model.batch_size)
    state = State(state.x.expand(batch, -1, -1), state.v.expand(batch, -1, -1))
    if method in ("adjoint", "fused") or (method == "numba" and _needs_grad(model, state)):
        engine = TorchEngine
        if method == "fused":  # Triton (optional) is imported only when used
            from .triton_backend import TritonEngine as engine
        elif method == "numba":  # so is Numba
            from .numba_backend import NumbaEngine as engine
        xs, vs = rollout_adjoint(model, state, num_frames, substeps, frame_dt, engine, progress)
        return Trajectory(xs, vs, substeps, frame_dt)
    make_engine, xs, vs = TorchEngine, [state.x], [state.v]
    if method == "numba":  # Numba (optional) is imported only when used
        from .numba_backend import NumbaEngine as make_engine

        # Compiled substeps work on CPU copies; frame 0 is the initial state, as given.
        xs, vs = [state.x.detach().cpu()], [state.v.detach().cpu()]
    engine = make_engine(model, frame_dt / substeps, batch, state.x.shape[1])
    force = control.force if control is not None else None
    frames = range(num_frames)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc=f"simulate ({substeps} substeps/frame)", unit="frame")
    x, v = state.x, state.v
    for frame in frames:
        if control_fn is None:
            x, v = engine.run(x, v, substeps, force)
        else:
            for substep in range(substeps):
                step_control = control_fn(State(x, v), frame * substeps + substep)
                step_force = None if step_control is None else step_control.force
                x, v = engine.step(x, v, step_force)
        xs.append(x)
        vs.append(v)
    x, v = torch.stack(xs, 1), torch.stack(vs, 1)
    if method == "numba":
        x, v = x.to(state.x.dtype), v.to(state.v.dtype)
    return Trajectory(x, v, substeps, frame_dt)
