"""The Numba engine: compiled CPU substeps, the forward-only fast twin of ``reference.step``.

The viewer, the demo and ``simulate`` run long forward rollouts on CPUs, where the plain PyTorch
step spends most of its time in per-op dispatch and temporaries (~15 tensors of [B, E, 3] per
substep). Here a whole frame of substeps runs inside one compiled function: springs are split
into one chunk per thread, each thread accumulates its forces into its own buffer (no atomics),
then anchors are integrated in parallel. Same equations as
:func:`reconphys.physics.reference.step` (same clamps and ground contact); results differ from it by
float round-off (summation order).

No autograd: ``rollout`` uses this path only when no gradient is needed (``method="auto"`` on CPU
with gradients off, or ``method="numba"``). ``tests/test_physics_numba_backend.py`` compares it with
the PyTorch reference; ``benchmarks/bench_simulator.py`` measures both in one run.
"""

from __future__ import annotations

import types

import numpy as np
import torch
from torch import Tensor

from .._optional import numba_available
from .engine import Engine
from .model import SpringMassModel

if numba_available():  # Numba is optional: the PyTorch path is used wherever it is missing.
    import numba
else:  # pragma: no cover - depends on the machine
    numba = None


def _frame_py(x, v, springs, rest, k, d, mass, friction, external, params, substeps, buffers):
    """Advance x, v [B, N, 3] in place by ``substeps`` substeps.

    springs [B, E, 2] int64, rest/k/d [B, E], mass/friction [B, N], external [B, N, 3] force
    (N) held over the substeps, params = (p, e, g0, g1, g2, ground, h), buffers [B, T, N, 3]
    scratch: the springs of each scene are split into T chunks, each with its own force buffer.
    """
    p, e, g0, g1, g2, ground, h = (
        params[0], params[1], params[2], params[3], params[4], params[5], params[6],
    )  # fmt: skip
    batch, num_anchors = x.shape[0], x.shape[1]
    num_springs = springs.shape[1]
    chunks = buffers.shape[1]
    chunk = (num_springs + chunks - 1) // chunks
    for _ in range(substeps):
        for task in numba.prange(batch * chunks):
            b = task // chunks
            c = task % chunks
            buf = buffers[b, c]
            buf[:] = 0.0
            for s in range(c * chunk, min(num_springs, (c + 1) * chunk)):
                i = springs[b, s, 0]
                j = springs[b, s, 1]
                dx0 = x[b, j, 0] - x[b, i, 0]
                dx1 = x[b, j, 1] - x[b, i, 1]
                dx2 = x[b, j, 2] - x[b, i, 2]
                length = np.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2 + 1e-24)
                u0 = dx0 / length
                u1 = dx1 / length
                u2 = dx2 / length
                r = rest[b, s]
                strain = length / r - 1.0
                magnitude = k[b, s] * strain
                if p == 0.5:
                    magnitude *= np.sqrt(1.0 + abs(strain))
                elif p != 0.0:
                    magnitude *= (1.0 + abs(strain)) ** p
                closing = (
                    (v[b, j, 0] - v[b, i, 0]) * u0
                    + (v[b, j, 1] - v[b, i, 1]) * u1
                    + (v[b, j, 2] - v[b, i, 2]) * u2
                )
                magnitude += d[b, s] / r * closing
                f0 = magnitude * u0
                f1 = magnitude * u1
                f2 = magnitude * u2
                buf[i, 0] += f0
                buf[i, 1] += f1
                buf[i, 2] += f2
                buf[j, 0] -= f0
                buf[j, 1] -= f1
                buf[j, 2] -= f2
        for task in numba.prange(batch * num_anchors):
            b = task // num_anchors
            n = task % num_anchors
            f0 = external[b, n, 0]
            f1 = external[b, n, 1]
            f2 = external[b, n, 2]
            for c in range(chunks):
                f0 += buffers[b, c, n, 0]
                f1 += buffers[b, c, n, 1]
                f2 += buffers[b, c, n, 2]
            m = mass[b, n]
            vf0 = v[b, n, 0] + (f0 / m + g0) * h
            vf1 = v[b, n, 1] + (f1 / m + g1) * h
            vf2 = v[b, n, 2] + (f2 / m + g2) * h
            xf0 = x[b, n, 0] + vf0 * h
            xf1 = x[b, n, 1] + vf1 * h
            xf2 = x[b, n, 2] + vf2 * h
            if xf2 < ground:
                approach = min(vf2, 0.0)
                speed = np.sqrt(vf0 * vf0 + vf1 * vf1 + 1e-30)
                retained = max(1.0 + friction[b, n] * ((1.0 + e) * approach) / speed, 0.0)
                vt0 = vf0 * retained
                vt1 = vf1 * retained
                x[b, n, 0] = xf0 - h * (vf0 - vt0)
                x[b, n, 1] = xf1 - h * (vf1 - vt1)
                x[b, n, 2] = ground
                v[b, n, 0] = vt0
                v[b, n, 1] = vt1
                v[b, n, 2] = vf2 - (1.0 + e) * approach
            else:
                x[b, n, 0] = xf0
                x[b, n, 1] = xf1
                x[b, n, 2] = xf2
                v[b, n, 0] = vf0
                v[b, n, 1] = vf1
                v[b, n, 2] = vf2


def _renamed(fn, name: str):
    """A copy of ``fn`` under another name. Numba's on-disk cache keys a compiled function by its
    qualified name and line, not by its compile options: two builds of one function (parallel and
    serial) would share one cache entry, and whichever a process compiled first would be what
    every later process loads for both (a serial kernel on the parallel path)."""
    copy = types.FunctionType(fn.__code__, fn.__globals__, name, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = name
    return copy


if numba is not None:
    # One function, compiled twice: threads pay off only when there is enough work per substep.
    _frame_parallel = numba.njit(parallel=True, cache=True)(_renamed(_frame_py, "_frame_parallel"))
    _frame_serial = numba.njit(parallel=False, cache=True)(_renamed(_frame_py, "_frame_serial"))

# Springs × scenes per substep below which the serial version is faster (thread wake-up costs
# more than it saves); measured on the 2-core CI machine, see docs/benchmarks.md.
PARALLEL_MIN_SPRINGS = 16_384
# Spring chunks per scene in the parallel version. Fixed (not the thread count) so that the force
# summation order, and hence the result to the last bit, does not depend on the machine.
PARALLEL_CHUNKS = 4


def _array(t: Tensor, shape: tuple[int, ...], dtype) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(t.detach().cpu().numpy().astype(dtype), shape))


class NumbaEngine(Engine):
    """Substeps with :func:`_frame_py` compiled by Numba (CPU, float32 or float64, no gradient).

    Computes in the model's dtype; :meth:`run` does all its substeps in one compiled call.
    """

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int):
        if numba is None:
            raise RuntimeError("the compiled CPU simulator needs Numba (pip install numba)")
        num_springs = model.num_springs
        dtype = np.float64 if model.dtype == torch.float64 else np.float32
        self.dtype, self.dt = dtype, dt
        springs = model.springs if model.springs.dim() == 3 else model.springs[None]
        self.springs = _array(springs, (batch, num_springs, 2), np.int64)
        rest = model.rest_length if model.rest_length.dim() == 2 else model.rest_length[None]
        self.rest = _array(rest, (batch, num_springs), dtype)
        self.k = _array(model.stiffness, (batch, num_springs), dtype)
        self.d = _array(model.damping, (batch, num_springs), dtype)
        self.mass = _array(model.mass, (batch, num_anchors), dtype)
        self.friction = _array(model.friction, (batch, num_anchors), dtype)
        gravity = model.gravity
        self.params = np.array(
            [model.spring_exponent, model.restitution, *gravity, model.ground_height, dt],
            dtype=dtype,
        )
        parallel = batch * num_springs >= PARALLEL_MIN_SPRINGS
        chunks = PARALLEL_CHUNKS if parallel else 1
        self.kernel = _frame_parallel if parallel else _frame_serial
        self.buffers = np.zeros((batch, chunks, num_anchors, 3), dtype=dtype)
        self.no_force = np.zeros((batch, num_anchors, 3), dtype=dtype)

    def step(self, x: Tensor, v: Tensor, force: Tensor | None = None) -> tuple[Tensor, Tensor]:
        return self.run(x, v, 1, force)

    def run(
        self, x: Tensor, v: Tensor, substeps: int, force: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """``substeps`` substeps in one compiled call; returns new CPU tensors (model dtype)."""
        x = x.detach().cpu().numpy().astype(self.dtype, copy=True)
        v = v.detach().cpu().numpy().astype(self.dtype, copy=True)
        external = self.no_force if force is None else _array(force, x.shape, self.dtype)
        self.kernel(
            x, v, self.springs, self.rest, self.k, self.d, self.mass, self.friction,
            external, self.params, substeps, self.buffers,
        )  # fmt: skip
        return torch.from_numpy(x), torch.from_numpy(v)
