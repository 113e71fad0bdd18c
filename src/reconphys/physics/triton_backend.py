"""The Triton engine: fused kernels for the substep and its exact VJP, the fast twin of the
PyTorch engine (:mod:`reconphys.physics.torch_backend`) on CUDA.

Layout: anchors are processed in blocks, one program per (block of anchors, scene). Each anchor
walks its incident springs through a padded adjacency table (ELL format, ``[B_t, N_A, D]``, D the
largest degree, -1 padding), so forces are gathered, never scattered: no atomics, deterministic
results, and one kernel per substep (spring + dashpot forces, semi-implicit Euler, ground contact).
The backward of a substep is two kernels: (A) per anchor, the contact and integration adjoint,
giving dL/dF; (B) per anchor, the spring adjoint, which needs dL/dF of the neighbours. Attribute
gradients are accumulated per element (per anchor for mass and friction, per spring for stiffness,
damping and rest length; a spring's gradient is written by its lower-index end only) and summed to
the attributes' shapes once per rollout.

The equations are exactly those of :func:`reconphys.physics.reference.step` and
:func:`reconphys.physics.torch_backend.substep_vjp` (same clamps and ties), with ``(1 + |ε|)^p``
evaluated as ``exp(p·log(1 + |ε|))``; results differ from the PyTorch path by float round-off
(summation order). ``tests/test_physics_triton_backend.py`` compares the two through Triton's CPU
interpreter (``TRITON_INTERPRET=1``); ``benchmarks/check_fused_vs_reference.py`` does it on a GPU.
"""

from __future__ import annotations

import os

import torch
from torch import Tensor

from .engine import BackwardEngine
from .model import SpringMassModel

try:  # Triton is optional: the PyTorch path is used wherever it is missing.
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - depends on the machine
    triton = None

BLOCK_ANCHORS = 128  # anchors per program


def fused_usable(device: torch.device) -> bool:
    """True where the fused kernels can run: Triton present and CUDA, or the CPU interpreter."""
    if triton is None:
        return False
    if device.type == "cuda":
        return True
    return os.environ.get("TRITON_INTERPRET") == "1"


def adjacency_table(springs: Tensor, num_anchors: int) -> tuple[Tensor, Tensor]:
    """Per-anchor incident springs of ``springs [E, 2]`` or ``[B, E, 2]``.

    Returns (other_end, spring_id), both int32 ``[B_t, N_A, D]`` (B_t = 1 for a shared topology),
    padded with -1; D is the largest number of springs at one anchor.
    """
    batched = springs if springs.dim() == 3 else springs[None]
    tables = []
    for pairs in batched:
        num_springs = pairs.shape[0]
        ends = torch.cat([pairs[:, 0], pairs[:, 1]])  # the anchor that owns the entry
        others = torch.cat([pairs[:, 1], pairs[:, 0]])
        ids = torch.arange(num_springs, device=pairs.device).repeat(2)
        order = torch.argsort(ends, stable=True)
        ends, others, ids = ends[order], others[order], ids[order]
        degree = torch.bincount(ends, minlength=num_anchors)
        start = torch.cumsum(degree, 0) - degree
        slot = torch.arange(len(ends), device=pairs.device) - start[ends]
        tables.append((ends, others, ids, slot, int(degree.max().item())))
    width = max(t[4] for t in tables)
    other = torch.full((len(batched), num_anchors, max(width, 1)), -1, dtype=torch.int32)
    spring = torch.full_like(other, -1)
    other, spring = other.to(springs.device), spring.to(springs.device)
    for b, (ends, others, ids, slot, _) in enumerate(tables):
        other[b, ends, slot] = others.to(torch.int32)
        spring[b, ends, slot] = ids.to(torch.int32)
    return other.contiguous(), spring.contiguous()


if triton is not None:

    @triton.jit
    def _load3(ptr, base, mask):
        """The three components at ``ptr + base`` (a block of [·, 3] rows), 0 where masked."""
        c0 = tl.load(ptr + base, mask=mask, other=0.0)
        c1 = tl.load(ptr + base + 1, mask=mask, other=0.0)
        c2 = tl.load(ptr + base + 2, mask=mask, other=0.0)
        return c0, c1, c2

    @triton.jit
    def _add3(ptr, base, mask, c0, c1, c2):
        """Add (c0, c1, c2) to the three components at ``ptr + base``, in place."""
        tl.store(ptr + base, tl.load(ptr + base, mask=mask) + c0, mask=mask)
        tl.store(ptr + base + 1, tl.load(ptr + base + 1, mask=mask) + c1, mask=mask)
        tl.store(ptr + base + 2, tl.load(ptr + base + 2, mask=mask) + c2, mask=mask)

    @triton.jit
    def _spring_terms(
        x_ptr, v_ptr, b, n, valid, other, spring, num_anchors,
        xi0, xi1, xi2, vi0, vi1, vi2,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se, p,
    ):  # fmt: skip
        """Geometry and force of the springs (self → other) in one adjacency column."""
        ob = (b * num_anchors + other) * 3
        xo0, xo1, xo2 = _load3(x_ptr, ob, valid)
        vo0, vo1, vo2 = _load3(v_ptr, ob, valid)
        rest = tl.load(rest_ptr + b * rest_sb + spring * rest_se, mask=valid, other=1.0)
        k = tl.load(k_ptr + b * k_sb + spring * k_se, mask=valid, other=0.0)
        d = tl.load(d_ptr + b * d_sb + spring * d_se, mask=valid, other=0.0)
        dx0 = xo0 - xi0
        dx1 = xo1 - xi1
        dx2 = xo2 - xi2
        length = tl.sqrt(dx0 * dx0 + dx1 * dx1 + dx2 * dx2 + 1e-24)
        u0 = dx0 / length
        u1 = dx1 / length
        u2 = dx2 / length
        strain = length / rest - 1.0
        a = tl.abs(strain)
        phi = tl.exp(p * tl.log(1.0 + a))
        dv0 = vo0 - vi0
        dv1 = vo1 - vi1
        dv2 = vo2 - vi2
        closing = dv0 * u0 + dv1 * u1 + dv2 * u2
        magnitude = k * strain * phi + d / rest * closing
        magnitude = tl.where(valid, magnitude, 0.0)
        return (u0, u1, u2, length, strain, a, phi, dv0, dv1, dv2, closing, magnitude,
                rest, k, d)  # fmt: skip

    @triton.jit
    def _anchor_force(
        x_ptr, v_ptr, b, n, mask, num_anchors,
        xi0, xi1, xi2, vi0, vi1, vi2,
        other_ptr, spring_ptr, ell_sb, degree,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se, p,
    ):  # fmt: skip
        """Sum of spring and dashpot forces on each anchor of the block."""
        f0 = tl.zeros_like(xi0)
        f1 = tl.zeros_like(xi0)
        f2 = tl.zeros_like(xi0)
        for column in range(degree):
            entry = b * ell_sb + n * degree + column
            other = tl.load(other_ptr + entry, mask=mask, other=-1)
            valid = mask & (other >= 0)
            spring = tl.load(spring_ptr + entry, mask=valid, other=0)
            other = tl.where(valid, other, 0)
            terms = _spring_terms(
                x_ptr, v_ptr, b, n, valid, other, spring, num_anchors,
                xi0, xi1, xi2, vi0, vi1, vi2,
                rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se, p,
            )  # fmt: skip
            magnitude = terms[11]  # (u0, u1, u2, ..., magnitude, ...): see _spring_terms
            f0 += magnitude * terms[0]
            f1 += magnitude * terms[1]
            f2 += magnitude * terms[2]
        return f0, f1, f2

    @triton.jit
    def _free_update(
        x_ptr, v_ptr, b, n, mask, base, num_anchors,
        other_ptr, spring_ptr, ell_sb, degree,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
        m_ptr, m_sb, m_se, p, g0, g1, g2, h,
    ):  # fmt: skip
        """Positions, spring forces and the free velocity update v + (F/m + g)·h of a block."""
        xi0, xi1, xi2 = _load3(x_ptr, base, mask)
        vi0, vi1, vi2 = _load3(v_ptr, base, mask)
        f0, f1, f2 = _anchor_force(
            x_ptr, v_ptr, b, n, mask, num_anchors, xi0, xi1, xi2, vi0, vi1, vi2,
            other_ptr, spring_ptr, ell_sb, degree,
            rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se, p,
        )  # fmt: skip
        m = tl.load(m_ptr + b * m_sb + n * m_se, mask=mask, other=1.0)
        vf0 = vi0 + (f0 / m + g0) * h
        vf1 = vi1 + (f1 / m + g1) * h
        vf2 = vi2 + (f2 / m + g2) * h
        return xi0, xi1, xi2, vf0, vf1, vf2, f0, f1, f2, m

    @triton.jit
    def _substep_kernel(
        x_ptr, v_ptr, x_out_ptr, v_out_ptr, num_anchors,
        other_ptr, spring_ptr, ell_sb, degree,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
        m_ptr, m_sb, m_se, f_ptr, f_sb, f_se,
        s_ptr,
        BLOCK: tl.constexpr,
    ):  # fmt: skip
        """One substep for a block of anchors of one scene (see reference.step)."""
        p, e = tl.load(s_ptr), tl.load(s_ptr + 1)  # scalars in the model's dtype (see below)
        g0, g1, g2 = tl.load(s_ptr + 2), tl.load(s_ptr + 3), tl.load(s_ptr + 4)
        ground, h = tl.load(s_ptr + 5), tl.load(s_ptr + 6)
        b = tl.program_id(1)
        n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        mask = n < num_anchors
        base = (b * num_anchors + n) * 3
        xi0, xi1, xi2, vf0, vf1, vf2, _f0, _f1, _f2, _m = _free_update(
            x_ptr, v_ptr, b, n, mask, base, num_anchors,
            other_ptr, spring_ptr, ell_sb, degree,
            rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
            m_ptr, m_sb, m_se, p, g0, g1, g2, h,
        )  # fmt: skip
        xf0 = xi0 + vf0 * h
        xf1 = xi1 + vf1 * h
        xf2 = xi2 + vf2 * h
        below = xf2 < ground
        approach = tl.minimum(vf2, 0.0)
        vn = tl.where(below, vf2 - (1.0 + e) * approach, vf2)
        speed = tl.sqrt(vf0 * vf0 + vf1 * vf1 + 1e-30)
        friction = tl.load(f_ptr + b * f_sb + n * f_se, mask=mask, other=0.0)
        raw = 1.0 + friction * ((1.0 + e) * approach) / speed
        retained = tl.where(below, tl.maximum(raw, 0.0), 1.0)
        vt0 = vf0 * retained
        vt1 = vf1 * retained
        tl.store(x_out_ptr + base, xf0 - h * (vf0 - vt0), mask=mask)
        tl.store(x_out_ptr + base + 1, xf1 - h * (vf1 - vt1), mask=mask)
        tl.store(x_out_ptr + base + 2, tl.where(below, ground, xf2), mask=mask)
        tl.store(v_out_ptr + base, vt0, mask=mask)
        tl.store(v_out_ptr + base + 1, vt1, mask=mask)
        tl.store(v_out_ptr + base + 2, vn, mask=mask)

    @triton.jit
    def _contact_vjp_kernel(
        x_ptr, v_ptr, gx_ptr, gv_ptr, gforce_ptr, num_anchors,
        other_ptr, spring_ptr, ell_sb, degree,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
        m_ptr, m_sb, m_se, f_ptr, f_sb, f_se, gm_acc_ptr, gf_acc_ptr,
        s_ptr,
        BLOCK: tl.constexpr,
    ):  # fmt: skip
        """VJP of contact and integration, in place: (gx, gv) after the substep become the
        direct terms before it; dL/dF goes to gforce; mass and friction gradients accumulate."""
        p, e = tl.load(s_ptr), tl.load(s_ptr + 1)  # scalars in the model's dtype (see below)
        g0, g1, g2 = tl.load(s_ptr + 2), tl.load(s_ptr + 3), tl.load(s_ptr + 4)
        ground, h = tl.load(s_ptr + 5), tl.load(s_ptr + 6)
        b = tl.program_id(1)
        n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        mask = n < num_anchors
        base = (b * num_anchors + n) * 3
        _xi0, _xi1, xi2, vf0, vf1, vf2, f0, f1, f2, m = _free_update(
            x_ptr, v_ptr, b, n, mask, base, num_anchors,
            other_ptr, spring_ptr, ell_sb, degree,
            rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
            m_ptr, m_sb, m_se, p, g0, g1, g2, h,
        )  # fmt: skip
        xf2 = xi2 + vf2 * h
        below = xf2 < ground
        approaching = vf2 <= 0.0
        approach = tl.minimum(vf2, 0.0)
        speed = tl.sqrt(vf0 * vf0 + vf1 * vf1 + 1e-30)
        friction = tl.load(f_ptr + b * f_sb + n * f_se, mask=mask, other=0.0)
        coefficient = (1.0 + e) * approach
        raw = 1.0 + friction * coefficient / speed
        retained = tl.where(below, tl.maximum(raw, 0.0), 1.0)

        gx0, gx1, gx2 = _load3(gx_ptr, base, mask)
        gv0, gv1, gv2 = _load3(gv_ptr, base, mask)
        gnew0 = gv0 + h * gx0
        gnew1 = gv1 + h * gx1
        gt0 = retained * gnew0 - h * gx0
        gt1 = retained * gnew1 - h * gx1
        g_retained = vf0 * gnew0 + vf1 * gnew1
        g_raw = tl.where(below & (raw >= 0.0), g_retained, 0.0)
        g_friction = g_raw * coefficient / speed
        g_approach = g_raw * friction * (1.0 + e) / speed
        g_speed = -g_raw * friction * coefficient / (speed * speed)
        gt0 += g_speed / speed * vf0
        gt1 += g_speed / speed * vf1
        g_approach += tl.where(below, -(1.0 + e) * gv2, 0.0)
        gn = gv2 + tl.where(approaching, g_approach, 0.0)
        gxf2 = tl.where(below, 0.0, gx2)
        # free update
        gvf0 = gt0 + h * gx0
        gvf1 = gt1 + h * gx1
        gvf2 = gn + h * gxf2
        scale = h / m
        tl.store(gforce_ptr + base, gvf0 * scale, mask=mask)
        tl.store(gforce_ptr + base + 1, gvf1 * scale, mask=mask)
        tl.store(gforce_ptr + base + 2, gvf2 * scale, mask=mask)
        g_mass = -(gvf0 * f0 + gvf1 * f1 + gvf2 * f2) * h / (m * m)
        slot = b * num_anchors + n
        tl.store(gm_acc_ptr + slot, tl.load(gm_acc_ptr + slot, mask=mask) + g_mass, mask=mask)
        tl.store(gf_acc_ptr + slot, tl.load(gf_acc_ptr + slot, mask=mask) + g_friction, mask=mask)
        tl.store(gx_ptr + base + 2, gxf2, mask=mask)
        tl.store(gv_ptr + base, gvf0, mask=mask)
        tl.store(gv_ptr + base + 1, gvf1, mask=mask)
        tl.store(gv_ptr + base + 2, gvf2, mask=mask)

    @triton.jit
    def _spring_vjp_kernel(
        x_ptr, v_ptr, gx_ptr, gv_ptr, gforce_ptr, num_anchors, num_springs,
        other_ptr, spring_ptr, ell_sb, degree,
        rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se,
        gk_acc_ptr, gd_acc_ptr, gr_acc_ptr, s_ptr,
        BLOCK: tl.constexpr,
    ):  # fmt: skip
        """VJP of the spring forces, in place on (gx, gv); per-spring gradients accumulate."""
        p = tl.load(s_ptr)  # the spring exponent, in the model's dtype
        b = tl.program_id(1)
        n = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        mask = n < num_anchors
        base = (b * num_anchors + n) * 3
        xi0, xi1, xi2 = _load3(x_ptr, base, mask)
        vi0, vi1, vi2 = _load3(v_ptr, base, mask)
        gfi0, gfi1, gfi2 = _load3(gforce_ptr, base, mask)
        gx0 = tl.zeros_like(xi0)
        gx1 = tl.zeros_like(xi0)
        gx2 = tl.zeros_like(xi0)
        gv0 = tl.zeros_like(xi0)
        gv1 = tl.zeros_like(xi0)
        gv2 = tl.zeros_like(xi0)
        for column in range(degree):
            entry = b * ell_sb + n * degree + column
            other = tl.load(other_ptr + entry, mask=mask, other=-1)
            valid = mask & (other >= 0)
            spring = tl.load(spring_ptr + entry, mask=valid, other=0)
            other = tl.where(valid, other, 0)
            (u0, u1, u2, length, strain, a, phi, dv0, dv1, dv2, closing, magnitude,
             rest, k, d) = _spring_terms(
                x_ptr, v_ptr, b, n, valid, other, spring, num_anchors,
                xi0, xi1, xi2, vi0, vi1, vi2,
                rest_ptr, rest_sb, rest_se, k_ptr, k_sb, k_se, d_ptr, d_sb, d_se, p,
            )  # fmt: skip
            gfo0, gfo1, gfo2 = _load3(gforce_ptr, (b * num_anchors + other) * 3, valid)
            w0 = gfi0 - gfo0
            w1 = gfi1 - gfo1
            w2 = gfi2 - gfo2
            g_mag = w0 * u0 + w1 * u1 + w2 * u2
            gu0 = magnitude * w0
            gu1 = magnitude * w1
            gu2 = magnitude * w2
            dmag_dstrain = k * tl.exp((p - 1.0) * tl.log(1.0 + a)) * (1.0 + a + p * a)
            g_strain = g_mag * dmag_dstrain
            g_k = g_mag * strain * phi
            g_d = g_mag * closing / rest
            g_closing = g_mag * d / rest
            g_rest = -g_mag * d * closing / (rest * rest) - g_strain * length / (rest * rest)
            gu0 += g_closing * dv0
            gu1 += g_closing * dv1
            gu2 += g_closing * dv2
            g_length = g_strain / rest
            radial = u0 * gu0 + u1 * gu1 + u2 * gu2
            gd0 = (gu0 - u0 * radial) / length + g_length * u0
            gd1 = (gu1 - u1 * radial) / length + g_length * u1
            gd2 = (gu2 - u2 * radial) / length + g_length * u2
            # δ = x_other − x_self and Δv = v_other − v_self: self gets the negative.
            gx0 -= tl.where(valid, gd0, 0.0)
            gx1 -= tl.where(valid, gd1, 0.0)
            gx2 -= tl.where(valid, gd2, 0.0)
            gv0 -= tl.where(valid, g_closing * u0, 0.0)
            gv1 -= tl.where(valid, g_closing * u1, 0.0)
            gv2 -= tl.where(valid, g_closing * u2, 0.0)
            owner = valid & (n < other)
            slot = b * num_springs + spring
            tl.store(gk_acc_ptr + slot, tl.load(gk_acc_ptr + slot, mask=owner) + g_k, mask=owner)
            tl.store(gd_acc_ptr + slot, tl.load(gd_acc_ptr + slot, mask=owner) + g_d, mask=owner)
            tl.store(gr_acc_ptr + slot, tl.load(gr_acc_ptr + slot, mask=owner) + g_rest, mask=owner)
        _add3(gx_ptr, base, mask, gx0, gx1, gx2)
        _add3(gv_ptr, base, mask, gv0, gv1, gv2)


def _strided(value: Tensor, batch: int, size: int) -> tuple[Tensor, int, int]:
    """A [B|1, M|1] (or [M]) attribute as (tensor, batch stride, element stride), 0 = broadcast."""
    if value.dim() == 1:
        value = value[None]
    value = value.contiguous()
    batch_stride = value.stride(0) if value.shape[0] == batch and batch > 1 else 0
    element_stride = value.stride(1) if value.shape[1] == size and size > 1 else 0
    return value, batch_stride, element_stride


class TritonEngine(BackwardEngine):
    """Substep and substep-VJP with the Triton kernels (the interface of
    :class:`~reconphys.physics.engine.BackwardEngine`, like ``TorchEngine``; no external force).

    Built once per rollout: the adjacency table and the attribute strides are prepared here.
    """

    def __init__(self, model: SpringMassModel, dt: float, batch: int, num_anchors: int):
        if triton is None:
            raise RuntimeError("the fused simulator needs Triton (pip install triton)")
        self.model, self.dt = model, dt
        self.batch, self.num_anchors = batch, num_anchors
        self.num_springs = model.num_springs
        self.other, self.spring = adjacency_table(model.springs, num_anchors)
        self.ell_sb = self.other.stride(0) if self.other.shape[0] > 1 else 0
        self.degree = self.other.shape[2]
        e_size, n_size = self.num_springs, num_anchors
        self.rest = _strided(model.rest_length, batch, e_size)
        self.k = _strided(model.stiffness, batch, e_size)
        self.d = _strided(model.damping, batch, e_size)
        self.m = _strided(model.mass, batch, n_size)
        self.f = _strided(model.friction, batch, n_size)
        self.grid = (triton.cdiv(num_anchors, BLOCK_ANCHORS), batch)
        dtype, device = model.dtype, model.device
        self.totals = {
            "mass": torch.zeros(batch, n_size, dtype=dtype, device=device),
            "friction": torch.zeros(batch, n_size, dtype=dtype, device=device),
            "stiffness": torch.zeros(batch, e_size, dtype=dtype, device=device),
            "damping": torch.zeros(batch, e_size, dtype=dtype, device=device),
            "rest_length": torch.zeros(batch, e_size, dtype=dtype, device=device),
        }
        gravity = model.gravity
        # A Python float reaches a Triton kernel as fp32, so a float64 model would step with
        # dt and g rounded to fp32 (relative error ~1e-8, seen on an H100): the scalars travel
        # as a tensor of the model's dtype instead.
        self.scalars = torch.tensor(
            [model.spring_exponent, model.restitution, *(float(g) for g in gravity),
             model.ground_height, dt],
            dtype=dtype, device=device,
        )  # fmt: skip

    def _springs_args(self):
        rest, k, d = self.rest, self.k, self.d
        return (self.other, self.spring, self.ell_sb, self.degree, *rest, *k, *d)

    def step(self, x: Tensor, v: Tensor, force: Tensor | None = None) -> tuple[Tensor, Tensor]:
        if force is not None:
            raise ValueError("the Triton engine takes no external force; use the PyTorch engine")
        x, v = x.contiguous(), v.contiguous()
        x_out, v_out = torch.empty_like(x), torch.empty_like(v)
        _substep_kernel[self.grid](
            x, v, x_out, v_out, self.num_anchors, *self._springs_args(),
            *self.m, *self.f, self.scalars, BLOCK=BLOCK_ANCHORS,
        )  # fmt: skip
        return x_out, v_out

    def vjp(self, x: Tensor, v: Tensor, grad_x: Tensor, grad_v: Tensor) -> tuple[Tensor, Tensor]:
        x, v = x.contiguous(), v.contiguous()
        grad_x, grad_v = grad_x.clone(), grad_v.clone()  # the kernels work in place
        grad_force = torch.empty_like(x)
        totals = self.totals
        _contact_vjp_kernel[self.grid](
            x, v, grad_x, grad_v, grad_force, self.num_anchors, *self._springs_args(),
            *self.m, *self.f, totals["mass"], totals["friction"], self.scalars,
            BLOCK=BLOCK_ANCHORS,
        )  # fmt: skip
        _spring_vjp_kernel[self.grid](
            x, v, grad_x, grad_v, grad_force, self.num_anchors, self.num_springs,
            *self._springs_args(), totals["stiffness"], totals["damping"],
            totals["rest_length"], self.scalars, BLOCK=BLOCK_ANCHORS,
        )  # fmt: skip
        return grad_x, grad_v

    def attribute_grads(self) -> dict[str, Tensor]:
        return self.totals
