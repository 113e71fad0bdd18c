"""The Numba engine: compiled CPU substeps and their exact VJP, the fast twin of the PyTorch engine.

Training, refinement, the viewer and ``simulate`` spend their time in rollouts on CPUs, where the
plain PyTorch step spends most of its time in per-op dispatch and temporaries. Here whole frames of
substeps (and, backwards, whole frames of substep VJPs) run inside compiled functions.

Layout (built once per engine): each scene's anchors are renumbered so that springs join near
numbers (reverse Cuthill–McKee; x, v and per-anchor attributes are permuted on the way in and
out), and its springs are sorted by their first anchor, so the springs leaving anchor n are one
contiguous row (``row_start``), and a second index lists the springs arriving at n
(``in_start``/``in_spring``). A substep is two parallel passes with no atomics
and no per-thread force buffers:

1. one task per spring: its pull ``magnitude · u`` (the force on its first anchor), written to
   ``pull [B, E, 3]``;
2. one task per anchor: gather the pulls of its row (+) and of its incoming springs (−), then the
   semi-implicit Euler update and ground contact, in place.

The VJP of a substep is four such passes (pulls; contact and free update backwards per anchor;
spring backwards per spring; gather of the spring gradients per anchor). Every anchor sums its
terms in a fixed order, so results do not depend on the thread count or the machine; they differ
from the PyTorch reference (:func:`reconphys.physics.reference.step`,
:func:`reconphys.physics.torch_backend.substep_vjp`) by float round-off only (summation order).

``tests/test_physics_numba_backend.py`` compares both directions with the PyTorch engine;
``benchmarks/bench_simulator.py`` and ``benchmarks/bench_vs_warp.py`` measure them.
"""

from __future__ import annotations

import types
from collections import OrderedDict

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee
from torch import Tensor

from .._optional import numba_available
from .engine import BackwardEngine
from .model import SpringMassModel

if numba_available():  # Numba is optional: the PyTorch path is used wherever it is missing.
    import numba
else:  # pragma: no cover - depends on the machine
    numba = None

# How the spring law's factor (1 + |ε|)^p is computed: the common exponents get their own branch.
LINEAR, SQUARE_ROOT, POWER = 0, 1, 2


def _exponent_mode(p: float) -> int:
    return LINEAR if p == 0.0 else SQUARE_ROOT if p == 0.5 else POWER


# Springs gathered at a time into small local arrays, so that their maths vectorises (SIMD).
BLOCK = 128


def _spring_factors_py(strain, count, p, one, mode, phi, slope_per_k):
    """phi = (1 + |ε|)^p and dphi-slope (1 + |ε|)^(p−1) (1 + |ε| + p|ε|) for strain[:count]: the
    spring law's non-linear factor and d(ε·phi)/dε, one branch-free loop per exponent kind."""
    if mode == 0:
        for t in range(count):
            phi[t] = one
            slope_per_k[t] = one
    elif mode == 1:
        for t in range(count):
            a = abs(strain[t])
            phi[t] = np.sqrt(one + a)
            slope_per_k[t] = (one + a + p * a) / phi[t]
    else:
        for t in range(count):
            a = abs(strain[t])
            phi[t] = (one + a) ** p
            slope_per_k[t] = phi[t] / (one + a) * (one + a + p * a)


def _spring_pulls_py(x, v, topology, spring_params, params, mode, chunks, pull, blocks):
    """pull[b, 3s:3s+3] = magnitude · u of every spring s: the force on its first anchor (N).

    x, v [B, 3N] (flat xyz); topology = (3·first, 3·second [B, E] uint32, row_start,
    in_start [B, N+1] int64, 3·in_spring [B, E] uint32); spring_params [B, 5, E] = (rest, k, d,
    1/rest, d/rest); params = (p, e, g0, g1, g2, ground, h, 1, 1e-24, 0, 1e-30) in the model's
    dtype (a Python literal would be float64); pull [B, 3E] out; blocks [B·chunks, ≥ 10, BLOCK]
    scratch (allocating inside a parallel loop costs far more than the loop).
    """
    first3, second3 = topology[0], topology[1]
    p, one, tiny = params[0], params[7], params[8]
    batch = first3.shape[0]
    row_start, cuts = topology[2], topology[5]
    for task in numba.prange(batch * chunks):
        b = task // chunks
        lo = row_start[b, cuts[b, 0, task % chunks]]  # the springs leaving the task's anchors
        hi = row_start[b, cuts[b, 0, task % chunks + 1]]
        xb, vb, out, i3, j3 = x[b], v[b], pull[b], first3[b], second3[b]
        k, inv_rest, d_over_rest = spring_params[b, 1], spring_params[b, 3], spring_params[b, 4]
        scratch = blocks[task]
        dx0, dx1, dx2 = scratch[0], scratch[1], scratch[2]
        dv_dx = scratch[3]
        for start in range(lo, hi, BLOCK):
            count = min(hi - start, BLOCK)
            last = np.uint32(4294967295)  # the row's first anchor, loaded once per row
            xi0 = xi1 = xi2 = vi0 = vi1 = vi2 = one
            for t in range(count):
                i = i3[start + t]
                j = j3[start + t]
                if i != last:
                    xi0 = xb[i]
                    xi1 = xb[i + 1]
                    xi2 = xb[i + 2]
                    vi0 = vb[i]
                    vi1 = vb[i + 1]
                    vi2 = vb[i + 2]
                    last = i
                d0 = xb[j] - xi0
                d1 = xb[j + 1] - xi1
                d2 = xb[j + 2] - xi2
                dx0[t] = d0
                dx1[t] = d1
                dx2[t] = d2
                # (v_j − v_i)·(x_j − x_i): the closing speed times the length
                dv_dx[t] = (vb[j] - vi0) * d0 + (vb[j + 1] - vi1) * d1 + (vb[j + 2] - vi2) * d2
            # One fused branch-free loop per exponent kind (LLVM vectorises it): ε, the factor
            # (1 + |ε|)^p (one, a square root, or a power) and the pull = scale · (x_j − x_i).
            if mode == 2:
                for t in range(count):
                    s = start + t
                    length = np.sqrt(dx0[t] * dx0[t] + dx1[t] * dx1[t] + dx2[t] * dx2[t] + tiny)
                    inverse = one / length
                    strain = length * inv_rest[s] - one
                    magnitude = k[s] * strain * (one + abs(strain)) ** p
                    scale = (magnitude + d_over_rest[s] * dv_dx[t] * inverse) * inverse
                    dx0[t] *= scale
                    dx1[t] *= scale
                    dx2[t] *= scale
            else:  # p = 0.5 or 0: (1 + |ε|)^p = √(1 + w|ε|), w = 1 or 0 (√1 = 1 exactly)
                w = one if mode == 1 else one - one
                for t in range(count):
                    s = start + t
                    length = np.sqrt(dx0[t] * dx0[t] + dx1[t] * dx1[t] + dx2[t] * dx2[t] + tiny)
                    inverse = one / length
                    strain = length * inv_rest[s] - one
                    magnitude = k[s] * strain * np.sqrt(one + w * abs(strain))
                    scale = (magnitude + d_over_rest[s] * dv_dx[t] * inverse) * inverse
                    dx0[t] *= scale
                    dx1[t] *= scale
                    dx2[t] *= scale
            for t in range(count):
                s3 = 3 * (start + t)
                out[s3] = dx0[t]
                out[s3 + 1] = dx1[t]
                out[s3 + 2] = dx2[t]


def _advance_anchors_py(x, v, topology, mass, friction, external, params, chunks, pull):
    """Sum the pulls on each anchor, then the free update and ground contact, in place.

    mass/friction [B, N], external [B, 3N] force held over the substep (newtons).
    """
    row_start, in_start, in3 = topology[2], topology[3], topology[4]
    e, g0, g1, g2, ground, h = params[1], params[2], params[3], params[4], params[5], params[6]
    one, zero, floor = params[7], params[9], params[10]
    batch = mass.shape[0]
    cuts = topology[5]
    for task in numba.prange(batch * chunks):
        b = task // chunks
        lo, hi = cuts[b, 1, task % chunks], cuts[b, 1, task % chunks + 1]
        xb, vb, fb, pb = x[b], v[b], external[b], pull[b]
        rows, ins, incoming = row_start[b], in_start[b], in3[b]
        for n in range(lo, hi):
            n3 = 3 * n
            f0 = fb[n3]
            f1 = fb[n3 + 1]
            f2 = fb[n3 + 2]
            for s3 in range(3 * rows[n], 3 * rows[n + 1], 3):
                f0 += pb[s3]
                f1 += pb[s3 + 1]
                f2 += pb[s3 + 2]
            for t in range(ins[n], ins[n + 1]):
                s3 = incoming[t]
                f0 -= pb[s3]
                f1 -= pb[s3 + 1]
                f2 -= pb[s3 + 2]
            m = mass[b, n]
            vf0 = vb[n3] + (f0 / m + g0) * h
            vf1 = vb[n3 + 1] + (f1 / m + g1) * h
            vf2 = vb[n3 + 2] + (f2 / m + g2) * h
            xf0 = xb[n3] + vf0 * h
            xf1 = xb[n3 + 1] + vf1 * h
            xf2 = xb[n3 + 2] + vf2 * h
            if xf2 < ground:
                approach = min(vf2, zero)
                speed = np.sqrt(vf0 * vf0 + vf1 * vf1 + floor)
                retained = max(one + friction[b, n] * ((one + e) * approach) / speed, zero)
                vt0 = vf0 * retained
                vt1 = vf1 * retained
                xb[n3] = xf0 - h * (vf0 - vt0)
                xb[n3 + 1] = xf1 - h * (vf1 - vt1)
                xb[n3 + 2] = ground
                vb[n3] = vt0
                vb[n3 + 1] = vt1
                vb[n3 + 2] = vf2 - (one + e) * approach
            else:
                xb[n3] = xf0
                xb[n3 + 1] = xf1
                xb[n3 + 2] = xf2
                vb[n3] = vf0
                vb[n3 + 1] = vf1
                vb[n3 + 2] = vf2


# The drivers below call these names; :func:`_build` binds them to one variant's compiled kernels.
_spring_factors = _spring_pulls = _advance_anchors = None
_contact_vjp = _spring_vjp = _gather_vjp = _frame = None


def _frame_py(x, v, topology, spring_params, mass, friction, external, params, mode, substeps,
              chunks, pull, blocks):  # fmt: skip
    """Advance x, v [B, 3N] in place by ``substeps`` substeps."""
    for _ in range(substeps):
        _spring_pulls(x, v, topology, spring_params, params, mode, chunks, pull, blocks)
        _advance_anchors(x, v, topology, mass, friction, external, params, chunks, pull)


def _contact_vjp_py(x, v, topology, mass, friction, params, chunks, pull, grad_x, grad_v,
                    grad_force, grad_mass, grad_friction):  # fmt: skip
    """Backwards through ground contact and the free update of every anchor.

    grad_x, grad_v [B, 3N]: dL/d(x', v') after the substep in, dL/d(x, v) of the direct paths
    (x' ← x + h v_free, v_free ← v + …) out, in place; grad_force [B, 3N] dL/dF out;
    grad_mass, grad_friction [B, N] accumulated.
    """
    row_start, in_start, in3 = topology[2], topology[3], topology[4]
    e, g0, g1, g2, ground, h = params[1], params[2], params[3], params[4], params[5], params[6]
    one, zero, floor = params[7], params[9], params[10]
    batch = mass.shape[0]
    cuts = topology[5]
    for task in numba.prange(batch * chunks):
        b = task // chunks
        lo, hi = cuts[b, 1, task % chunks], cuts[b, 1, task % chunks + 1]
        xb, vb, pb, gxb, gvb, gfb = x[b], v[b], pull[b], grad_x[b], grad_v[b], grad_force[b]
        rows, ins, incoming = row_start[b], in_start[b], in3[b]
        for n in range(lo, hi):
            n3 = 3 * n
            f0 = zero
            f1 = zero
            f2 = zero
            for s3 in range(3 * rows[n], 3 * rows[n + 1], 3):
                f0 += pb[s3]
                f1 += pb[s3 + 1]
                f2 += pb[s3 + 2]
            for t in range(ins[n], ins[n + 1]):
                s3 = incoming[t]
                f0 -= pb[s3]
                f1 -= pb[s3 + 1]
                f2 -= pb[s3 + 2]
            m = mass[b, n]
            vf0 = vb[n3] + (f0 / m + g0) * h
            vf1 = vb[n3 + 1] + (f1 / m + g1) * h
            vf2 = vb[n3 + 2] + (f2 / m + g2) * h
            gx0 = gxb[n3]
            gx1 = gxb[n3 + 1]
            gx2 = gxb[n3 + 2]
            gv0 = gvb[n3]
            gv1 = gvb[n3 + 1]
            gv2 = gvb[n3 + 2]
            if xb[n3 + 2] + vf2 * h < ground:
                fr = friction[b, n]
                approach = min(vf2, zero)
                speed = np.sqrt(vf0 * vf0 + vf1 * vf1 + floor)
                coefficient = (one + e) * approach
                raw = one + fr * coefficient / speed
                retained = max(raw, zero)
                gn0 = gv0 + h * gx0  # dL/d(v_t') through v' and x'
                gn1 = gv1 + h * gx1
                gt0 = retained * gn0 - h * gx0
                gt1 = retained * gn1 - h * gx1
                graw = vf0 * gn0 + vf1 * gn1 if raw >= zero else zero
                grad_friction[b, n] += graw * coefficient / speed
                gapproach = graw * fr * (one + e) / speed - (one + e) * gv2
                gspeed = -graw * fr * coefficient / (speed * speed)
                gt0 += gspeed / speed * vf0
                gt1 += gspeed / speed * vf1
                gn = gv2 + (gapproach if vf2 <= zero else zero)
                gxf2 = zero
            else:
                gt0 = gv0
                gt1 = gv1
                gn = gv2
                gxf2 = gx2
            gvf0 = gt0 + h * gx0
            gvf1 = gt1 + h * gx1
            gvf2 = gn + h * gxf2
            scale = h / m
            gfb[n3] = gvf0 * scale
            gfb[n3 + 1] = gvf1 * scale
            gfb[n3 + 2] = gvf2 * scale
            grad_mass[b, n] -= (gvf0 * f0 + gvf1 * f1 + gvf2 * f2) * scale / m
            gxb[n3 + 2] = gxf2
            gvb[n3] = gvf0
            gvb[n3 + 1] = gvf1
            gvb[n3 + 2] = gvf2


def _spring_vjp_py(x, v, topology, spring_params, params, mode, chunks, grad_force, grad_delta,
                   grad_springs, blocks):  # fmt: skip
    """Backwards through every spring's pull, given dL/dF of its anchors.

    grad_delta [B, 6E] out: dL/d(x_j − x_i), dL/d(v_j − v_i) of each spring; grad_springs
    [B, 3, E] accumulated: dL/d(k, d, rest).
    """
    first3, second3 = topology[0], topology[1]
    p, one, tiny = params[0], params[7], params[8]
    batch = first3.shape[0]
    row_start, cuts = topology[2], topology[5]
    for task in numba.prange(batch * chunks):
        b = task // chunks
        lo = row_start[b, cuts[b, 0, task % chunks]]  # the springs leaving the task's anchors
        hi = row_start[b, cuts[b, 0, task % chunks + 1]]
        xb, vb, gfb, out, i3, j3 = x[b], v[b], grad_force[b], grad_delta[b], first3[b], second3[b]
        k, d = spring_params[b, 1], spring_params[b, 2]
        inv_rest, d_over_rest = spring_params[b, 3], spring_params[b, 4]
        grad_k, grad_d, grad_rest = grad_springs[b, 0], grad_springs[b, 1], grad_springs[b, 2]
        scratch = blocks[task]
        dx0, dx1, dx2 = scratch[0], scratch[1], scratch[2]
        dv0, dv1, dv2 = scratch[3], scratch[4], scratch[5]
        w0, w1, w2 = scratch[6], scratch[7], scratch[8]
        length, strain, phi, slope = scratch[9], scratch[10], scratch[11], scratch[12]
        for start in range(lo, hi, BLOCK):
            count = min(hi - start, BLOCK)
            for t in range(count):
                i = i3[start + t]
                j = j3[start + t]
                dx0[t] = xb[j] - xb[i]
                dx1[t] = xb[j + 1] - xb[i + 1]
                dx2[t] = xb[j + 2] - xb[i + 2]
                dv0[t] = vb[j] - vb[i]
                dv1[t] = vb[j + 1] - vb[i + 1]
                dv2[t] = vb[j + 2] - vb[i + 2]
                w0[t] = gfb[i] - gfb[j]
                w1[t] = gfb[i + 1] - gfb[j + 1]
                w2[t] = gfb[i + 2] - gfb[j + 2]
            for t in range(count):  # branch-free loops vectorise
                length[t] = np.sqrt(dx0[t] * dx0[t] + dx1[t] * dx1[t] + dx2[t] * dx2[t] + tiny)
                strain[t] = length[t] * inv_rest[start + t] - one
            _spring_factors(strain, count, p, one, mode, phi, slope)
            for t in range(count):
                s = start + t
                inverse = one / length[t]
                u0 = dx0[t] * inverse
                u1 = dx1[t] * inverse
                u2 = dx2[t] * inverse
                closing = dv0[t] * u0 + dv1[t] * u1 + dv2[t] * u2
                magnitude = k[s] * strain[t] * phi[t] + d_over_rest[s] * closing
                gmag = w0[t] * u0 + w1[t] * u1 + w2[t] * u2
                gstrain = gmag * k[s] * slope[t]
                gclosing = gmag * d_over_rest[s]
                grad_k[s] += gmag * strain[t] * phi[t]
                grad_d[s] += gmag * closing * inv_rest[s]
                grad_rest[s] -= (gmag * d[s] * closing + gstrain * length[t]) * (
                    inv_rest[s] * inv_rest[s]
                )
                gu0 = magnitude * w0[t] + gclosing * dv0[t]
                gu1 = magnitude * w1[t] + gclosing * dv1[t]
                gu2 = magnitude * w2[t] + gclosing * dv2[t]
                radial = u0 * gu0 + u1 * gu1 + u2 * gu2
                glength = gstrain * inv_rest[s]
                dx0[t] = (gu0 - u0 * radial) * inverse + glength * u0
                dx1[t] = (gu1 - u1 * radial) * inverse + glength * u1
                dx2[t] = (gu2 - u2 * radial) * inverse + glength * u2
                dv0[t] = gclosing * u0
                dv1[t] = gclosing * u1
                dv2[t] = gclosing * u2
            for t in range(count):
                s6 = 6 * (start + t)
                out[s6] = dx0[t]
                out[s6 + 1] = dx1[t]
                out[s6 + 2] = dx2[t]
                out[s6 + 3] = dv0[t]
                out[s6 + 4] = dv1[t]
                out[s6 + 5] = dv2[t]


def _gather_vjp_py(topology, chunks, grad_delta, grad_x, grad_v):
    """grad_x/grad_v [B, 3N] += the spring gradients of each anchor (+ arriving, − leaving)."""
    row_start, in_start, in3 = topology[2], topology[3], topology[4]
    batch = row_start.shape[0]
    cuts = topology[5]
    for task in numba.prange(batch * chunks):
        b = task // chunks
        lo, hi = cuts[b, 1, task % chunks], cuts[b, 1, task % chunks + 1]
        gd, gxb, gvb = grad_delta[b], grad_x[b], grad_v[b]
        rows, ins, incoming = row_start[b], in_start[b], in3[b]
        for n in range(lo, hi):
            n3 = 3 * n
            gx0 = gxb[n3]
            gx1 = gxb[n3 + 1]
            gx2 = gxb[n3 + 2]
            gv0 = gvb[n3]
            gv1 = gvb[n3 + 1]
            gv2 = gvb[n3 + 2]
            for s6 in range(6 * rows[n], 6 * rows[n + 1], 6):
                gx0 -= gd[s6]
                gx1 -= gd[s6 + 1]
                gx2 -= gd[s6 + 2]
                gv0 -= gd[s6 + 3]
                gv1 -= gd[s6 + 4]
                gv2 -= gd[s6 + 5]
            for t in range(ins[n], ins[n + 1]):
                s6 = 2 * incoming[t]
                gx0 += gd[s6]
                gx1 += gd[s6 + 1]
                gx2 += gd[s6 + 2]
                gv0 += gd[s6 + 3]
                gv1 += gd[s6 + 4]
                gv2 += gd[s6 + 5]
            gxb[n3] = gx0
            gxb[n3 + 1] = gx1
            gxb[n3 + 2] = gx2
            gvb[n3] = gv0
            gvb[n3 + 1] = gv1
            gvb[n3 + 2] = gv2


def _frame_vjp_py(x, v, topology, spring_params, mass, friction, params, mode, substeps, chunks,
                  pull, blocks, states, grad_x, grad_v, grad_force, grad_delta, grad_mass,
                  grad_friction, grad_springs):  # fmt: skip
    """dL/d(x, v) at the start of a frame from dL/d(x, v) at its end, in place in grad_x/grad_v.

    x, v [B, 3N]: the frame's start state (not modified); states [S, 2, B, 3N] scratch for the
    recomputed substep start states; attribute gradients accumulated.
    """
    no_force = np.zeros_like(x)
    states[0, 0] = x
    states[0, 1] = v
    for s in range(1, substeps):
        states[s] = states[s - 1]
        _frame(states[s, 0], states[s, 1], topology, spring_params, mass, friction, no_force,
               params, mode, 1, chunks, pull, blocks)  # fmt: skip
    for s in range(substeps - 1, -1, -1):
        xs = states[s, 0]
        vs = states[s, 1]
        _spring_pulls(xs, vs, topology, spring_params, params, mode, chunks, pull, blocks)
        _contact_vjp(xs, vs, topology, mass, friction, params, chunks, pull, grad_x, grad_v,
                     grad_force, grad_mass, grad_friction)  # fmt: skip
        _spring_vjp(xs, vs, topology, spring_params, params, mode, chunks, grad_force,
                    grad_delta, grad_springs, blocks)  # fmt: skip
        _gather_vjp(topology, chunks, grad_delta, grad_x, grad_v)


def _renamed(fn, name: str, namespace: dict | None = None):
    """A copy of ``fn`` under another name (and, optionally, with other globals). Numba's on-disk
    cache keys a compiled function by its qualified name and line, not by its compile options: two
    builds of one function (parallel and serial) would share one cache entry, and whichever a
    process compiled first would be what every later process loads for both (a serial kernel on
    the parallel path)."""
    globals_ = fn.__globals__ if namespace is None else namespace
    copy = types.FunctionType(fn.__code__, globals_, name, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = name
    return copy


# Kernels with a parallel loop; the helper they call and the drivers that call them have none.
_HELPERS = ("_spring_factors",)
_KERNELS = ("_spring_pulls", "_advance_anchors", "_contact_vjp", "_spring_vjp", "_gather_vjp")
_DRIVERS = ("_frame", "_frame_vjp")


def _build(parallel: bool) -> types.SimpleNamespace:
    """Every kernel compiled with or without threads; each driver calls its own variant's kernels.

    ``error_model="numpy"``: a division by zero gives inf/nan instead of raising, which is what
    lets LLVM vectorise the loops (Python's check is a branch per division)."""
    suffix = "parallel" if parallel else "serial"
    namespace = dict(globals())
    for name in (
        _HELPERS + _KERNELS + _DRIVERS
    ):  # names resolve in ``namespace`` when first compiled
        fn = _renamed(globals()[f"{name}_py"], f"{name}_{suffix}", namespace)
        threads = parallel and name in _KERNELS
        namespace[name] = numba.njit(parallel=threads, cache=True, error_model="numpy")(fn)
    names = _HELPERS + _KERNELS + _DRIVERS
    return types.SimpleNamespace(**{name: namespace[name] for name in names})


if numba is not None:
    # Threads pay off only when there is enough work per substep.
    PARALLEL, SERIAL = _build(parallel=True), _build(parallel=False)

# Springs × scenes per substep below which the serial build is faster (thread wake-up costs more
# than it saves); measured on the 2-core CI machine, see docs/benchmarks.md.
PARALLEL_MIN_SPRINGS = 16_384


def _array(t: Tensor, shape: tuple[int, ...], dtype) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(t.detach().cpu().numpy().astype(dtype), shape))


def _anchor_order(springs: np.ndarray, num_anchors: int) -> np.ndarray:
    """A numbering of the anchors [N] (engine → model index) in which springs join near numbers:
    reverse Cuthill–McKee on the spring graph. Each thread's block of anchors then mostly pulls on
    its own block (fewer cache lines crossing between cores) and neighbours share cache lines."""
    ones = np.ones(len(springs), np.int8)
    graph = coo_matrix((ones, (springs[:, 0], springs[:, 1])), shape=(num_anchors,) * 2).tocsr()
    return reverse_cuthill_mckee(graph + graph.T, symmetric_mode=True).astype(np.int64)


def _topology(springs: np.ndarray, num_anchors: int):
    """Renumber one scene's anchors (:func:`_anchor_order`), sort its springs [E, 2] by first
    anchor; the leaving rows and the arriving lists.

    Returns (anchor_order [N]: engine → model's anchor index, order [E]: sorted → model's spring
    index, 3·first, 3·second [E] uint32, row_start, in_start [N+1] int64, 3·in_spring [E]
    uint32): flat xyz offsets, unsigned so that Numba skips its negative-index wrap-around.
    """
    anchor_order = _anchor_order(springs, num_anchors)
    rank = np.empty(num_anchors, np.int64)
    rank[anchor_order] = np.arange(num_anchors)
    springs = np.sort(rank[springs], axis=1)  # a spring pulls both ends alike: lower end first
    order = np.argsort(springs[:, 0], kind="stable")
    first, second = springs[order, 0], springs[order, 1]
    row_start = np.zeros(num_anchors + 1, np.int64)
    np.cumsum(np.bincount(first, minlength=num_anchors), out=row_start[1:])
    in_spring = np.argsort(second, kind="stable")
    in_start = np.zeros(num_anchors + 1, np.int64)
    np.cumsum(np.bincount(second, minlength=num_anchors), out=in_start[1:])
    offsets = [(3 * a).astype(np.uint32) for a in (first, second, in_spring)]
    return anchor_order, order, offsets[0], offsets[1], row_start, in_start, offsets[2]


# Topologies of recent spring sets (a rollout builds an engine; refinement, the viewer and
# benchmarks roll the same object out many times): springs' bytes → (springs, _topology(...)).
_TOPOLOGIES: OrderedDict[tuple, tuple] = OrderedDict()
_TOPOLOGY_CACHE_SIZE = 16


def _cached_topology(springs: np.ndarray, num_anchors: int):
    """:func:`_topology`, remembered for the last few spring sets (compared in full on a hit)."""
    key = (num_anchors, springs.shape, hash(springs.tobytes()))
    hit = _TOPOLOGIES.get(key)
    if hit is not None and np.array_equal(hit[0], springs):
        _TOPOLOGIES.move_to_end(key)
        return hit[1]
    _TOPOLOGIES[key] = (springs.copy(), _topology(springs, num_anchors))
    if len(_TOPOLOGIES) > _TOPOLOGY_CACHE_SIZE:
        _TOPOLOGIES.popitem(last=False)
    return _TOPOLOGIES[key][1]


def _cuts(row_start: np.ndarray, in_start: np.ndarray, chunks: int) -> np.ndarray:
    """Anchor ranges of the parallel tasks [B, 2, chunks + 1]: [:, 0] for the spring passes (a
    task takes the springs leaving its anchors; equal spring counts), [:, 1] for the anchor passes
    (equal work: springs leaving and arriving, plus the update). The two nearly coincide, so an
    anchor task finds most of its pulls in the core that computed them."""
    work = [np.diff(row_start, axis=1), np.diff(row_start + in_start, axis=1) + 2]
    cuts = np.zeros((len(row_start), 2, chunks + 1), np.int64)
    cuts[:, :, -1] = row_start.shape[1] - 1
    for b in range(len(row_start)):
        for n, per_anchor in enumerate(work):
            total = np.cumsum(per_anchor[b])
            cuts[b, n, 1:-1] = np.searchsorted(total, total[-1] * np.arange(1, chunks) / chunks)
    return cuts


class NumbaEngine(BackwardEngine):
    """Substeps and substep VJPs compiled by Numba (CPU, float32 or float64).

    Computes in the model's dtype; :meth:`run` does a frame's substeps in one compiled call and
    :meth:`frame_vjp` walks a frame backwards in one compiled call.
    """

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int):
        if numba is None:
            raise RuntimeError("the compiled CPU simulator needs Numba (pip install numba)")
        num_springs = model.num_springs
        dtype = np.float64 if model.dtype == torch.float64 else np.float32
        self.dtype, self.dt = dtype, dt
        self.batch, self.num_anchors, self.num_springs = batch, num_anchors, num_springs
        springs = model.springs if model.springs.dim() == 3 else model.springs[None]
        springs = springs.detach().cpu().numpy().astype(np.int64)
        scenes = [_cached_topology(s, num_anchors) for s in springs]  # one per distinct topology
        scenes = [scenes[b % len(scenes)] for b in range(batch)]
        self.anchor_order = np.stack([scene[0] for scene in scenes])  # [B, N] engine → model
        self.order = np.stack([scene[1] for scene in scenes])  # [B, E] sorted → model's order
        self.topology = tuple(np.stack([scene[n] for scene in scenes]) for n in range(2, 7))
        rest = model.rest_length if model.rest_length.dim() == 2 else model.rest_length[None]
        rest, k, d = (
            np.take_along_axis(_array(t, (batch, num_springs), np.float64), self.order, 1)
            for t in (rest, model.stiffness, model.damping)
        )
        self.spring_params = np.ascontiguousarray(
            np.stack([rest, k, d, 1.0 / rest, d / rest], 1).astype(dtype)
        )  # [B, 5, E]
        self.mass, self.friction = (
            np.take_along_axis(_array(t, (batch, num_anchors), dtype), self.anchor_order, 1)
            for t in (model.mass, model.friction)
        )
        self.params = np.array(
            [model.spring_exponent, model.restitution, *model.gravity, model.ground_height, dt,
             1.0, 1e-24, 0.0, 1e-30],  # constants in the model's dtype (a literal is float64)
            dtype=dtype,
        )  # fmt: skip
        self.mode = _exponent_mode(model.spring_exponent)
        parallel = batch * num_springs >= PARALLEL_MIN_SPRINGS
        self.kernels = PARALLEL if parallel else SERIAL
        # Tasks per scene: enough for every thread when the batch is small. The result does not
        # depend on it (each spring and each anchor is one task with a fixed summation order).
        self.chunks = max(1, -(-numba.get_num_threads() // batch)) if parallel else 1
        self.topology += (_cuts(*self.topology[2:4], self.chunks),)
        self.pull = np.zeros((batch, 3 * num_springs), dtype=dtype)
        self.blocks = np.zeros((batch * self.chunks, 13, BLOCK), dtype=dtype)  # per-task scratch
        self.no_force = np.zeros((batch, 3 * num_anchors), dtype=dtype)
        self.grads: dict[str, np.ndarray] | None = None

    def _flat(self, t: Tensor) -> np.ndarray:
        """[B, N, 3] tensor (model's anchor order) → a new C-contiguous [B, 3N] array in the
        engine's dtype and anchor order."""
        a = t.detach().cpu().numpy().astype(self.dtype, copy=False)
        a = np.take_along_axis(a, self.anchor_order[:, :, None], 1)
        return a.reshape(self.batch, 3 * self.num_anchors)

    def _tensor(self, a: np.ndarray) -> Tensor:
        """[B, 3N] engine array → [B, N, 3] tensor in the model's anchor order."""
        out = np.empty((self.batch, self.num_anchors, 3), self.dtype)
        index = self.anchor_order[:, :, None]
        np.put_along_axis(out, index, a.reshape(self.batch, self.num_anchors, 3), 1)
        return torch.from_numpy(out)

    def step(self, x: Tensor, v: Tensor, force: Tensor | None = None) -> tuple[Tensor, Tensor]:
        return self.run(x, v, 1, force)

    def run(
        self, x: Tensor, v: Tensor, substeps: int, force: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """``substeps`` substeps in one compiled call; returns new CPU tensors (model dtype)."""
        x, v = self._flat(x), self._flat(v)
        if force is None:
            external = self.no_force
        else:
            external = self._flat(force.expand(self.batch, self.num_anchors, 3))
        self.kernels._frame(
            x, v, self.topology, self.spring_params, self.mass, self.friction, external,
            self.params, self.mode, substeps, self.chunks, self.pull, self.blocks,
        )  # fmt: skip
        return self._tensor(x), self._tensor(v)

    def vjp(self, x: Tensor, v: Tensor, grad_x: Tensor, grad_v: Tensor) -> tuple[Tensor, Tensor]:
        return self.frame_vjp(x, v, 1, grad_x, grad_v)

    def frame_vjp(
        self, x: Tensor, v: Tensor, substeps: int, grad_x: Tensor, grad_v: Tensor
    ) -> tuple[Tensor, Tensor]:
        """dL/d(x, v) at the start of ``substeps`` substeps from x, v, given dL/d(x, v) after them;
        attribute gradients are accumulated (:meth:`attribute_grads`)."""
        x, v, grad_x, grad_v = (self._flat(t) for t in (x, v, grad_x, grad_v))
        batch, anchors3, springs = self.batch, 3 * self.num_anchors, self.num_springs
        if self.grads is None:
            self.grads = {
                "mass": np.zeros((batch, self.num_anchors), self.dtype),
                "friction": np.zeros((batch, self.num_anchors), self.dtype),
                "springs": np.zeros((batch, 3, springs), self.dtype),
                "force": np.zeros((batch, anchors3), self.dtype),
                "delta": np.zeros((batch, 6 * springs), self.dtype),
            }
        states = np.empty((substeps, 2, batch, anchors3), self.dtype)
        g = self.grads
        self.kernels._frame_vjp(
            x, v, self.topology, self.spring_params, self.mass, self.friction, self.params,
            self.mode, substeps, self.chunks, self.pull, self.blocks, states, grad_x, grad_v,
            g["force"], g["delta"], g["mass"], g["friction"], g["springs"],
        )  # fmt: skip
        return self._tensor(grad_x), self._tensor(grad_v)

    def attribute_grads(self) -> dict[str, Tensor]:
        """Per-element gradients summed over every VJP so far: mass/friction [B, N_A],
        stiffness/damping/rest_length [B, E] (in the model's spring order)."""
        batch, anchors, springs = self.batch, self.num_anchors, self.num_springs
        zeros = np.zeros((batch, anchors), self.dtype)
        g = self.grads or {"mass": zeros, "friction": zeros}
        per_spring = np.zeros((batch, 3, springs), self.dtype)
        if self.grads is not None:  # sorted → the model's spring order
            index = np.broadcast_to(self.order[:, None], per_spring.shape)
            np.put_along_axis(per_spring, index, g["springs"], 2)
        per_anchor = {name: np.empty_like(g[name]) for name in ("mass", "friction")}
        for name, values in per_anchor.items():  # engine → the model's anchor order
            np.put_along_axis(values, self.anchor_order, g[name], 1)
        out = {"mass": per_anchor["mass"], "friction": per_anchor["friction"]}
        out |= {"stiffness": per_spring[:, 0]}
        out |= {"damping": per_spring[:, 1], "rest_length": per_spring[:, 2]}
        return {name: torch.from_numpy(np.ascontiguousarray(a)) for name, a in out.items()}
