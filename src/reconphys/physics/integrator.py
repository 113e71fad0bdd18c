"""Semi-implicit Euler stepping of the spring-mass model with ground contact (DESIGN §4).

This is the plain PyTorch reference: differentiable with respect to every attribute (scalar,
per-anchor or per-spring), the rest lengths and the initial state; CPU or CUDA; float32 or
float64; batched over scenes. One substep is :func:`step`; :func:`rollout` strings substeps into
frames with a substep count taken from :func:`stable_substeps`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import torch
from torch import Tensor

from .model import SpringMassModel
from .state import Control, State

# The stability bound accounts for the stiffening of the non-linear spring law (tangent stiffness
# grows with |ε| when p_k > 0) up to strains of this magnitude.
MAX_STRAIN_FOR_BOUND = 1.0
# Power iteration approaches the largest eigenvalue from below; this factor covers the remainder
# (30 iterations reach within ~4 % on kNN lattices, see tests/test_physics_stability.py).
EIGENVALUE_MARGIN = 1.1
POWER_ITERATIONS = 30
# Fraction of the stability limit used: h²Ω² + 2hC ≤ 4·SAFETY (see stable_substeps).
SAFETY = 0.7


def _gather_anchors(values: Tensor, index: Tensor) -> Tensor:
    """values [B, N_A, C], index [E] or [B, E] → [B, E, C]."""
    if index.dim() == 1:
        return values.index_select(1, index)
    return torch.gather(values, 1, index[..., None].expand(-1, -1, values.shape[-1]))


def _scatter_anchors(num_anchors: int, index: Tensor, values: Tensor) -> Tensor:
    """Σ values [B, E, C] into anchors at index [E] or [B, E] → [B, N_A, C].

    scatter_add over the anchor dim is several times faster on CPU than index_add along dim 1.
    """
    batch, _, channels = values.shape
    out = values.new_zeros(batch, num_anchors, channels)
    index = index.expand(batch, -1) if index.dim() == 1 else index
    return out.scatter_add(1, index[..., None].expand(-1, -1, channels), values)


def spring_forces(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions, metres
    v: Tensor,  # [B, N_A, 3] velocities, m/s
) -> Tensor:  # [B, N_A, 3] newtons
    """Sum of non-linear spring and dashpot forces on each anchor."""
    i, j = model.springs[..., 0], model.springs[..., 1]
    delta = _gather_anchors(x, j) - _gather_anchors(x, i)  # [B, E, 3]
    # The tiny floor keeps the direction (and its gradient) finite if two anchors ever coincide,
    # e.g. when a very soft, heavy object is flattened against the ground.
    length = torch.sqrt((delta * delta).sum(-1) + 1e-24)  # [B, E]
    direction = delta / length[..., None]
    strain = length / model.rest_length - 1.0
    magnitude = model.stiffness * strain
    if model.spring_exponent != 0.0:
        magnitude = magnitude * (1.0 + strain.abs()) ** model.spring_exponent
    closing_speed = ((_gather_anchors(v, j) - _gather_anchors(v, i)) * direction).sum(-1)
    magnitude = magnitude + model.damping / model.rest_length * closing_speed
    force_on_i = magnitude[..., None] * direction  # [B, E, 3], pulls i towards j when stretched
    # One scatter for both ends: +F on i, −F on j.
    both_ends = torch.cat([i, j], dim=-1)
    return _scatter_anchors(x.shape[1], both_ends, torch.cat([force_on_i, -force_on_i], dim=1))


def ground_contact(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions after the free update, metres
    v: Tensor,  # [B, N_A, 3] velocities after the free update, m/s
    dt: float,  # substep length h, seconds
) -> tuple[Tensor, Tensor]:
    """Project anchors below the ground back onto it; restitution and Coulomb friction.

    An anchor below the plane is put on it. If it moves into the ground (v_n < 0) its normal
    velocity becomes −e·v_n and its tangential velocity shrinks by the Coulomb impulse,
    ``v_t ← v_t · max(0, 1 − f (1 + e) |v_n| / ‖v_t‖)``. An anchor below the plane that already
    moves away from it keeps its velocity. The friction impulse is proportional to |v_n| accrued in
    one substep, so the deceleration (f·g when resting) does not depend on the substep count.

    The tangential position of a contacting anchor is advanced with the corrected velocity
    (x_t = x_t,prev + h·v_t,new), so static friction really holds: without this, the free update
    would let anchors held by friction creep by F_t/m·h² every substep.
    """
    e = model.restitution
    below = x[..., 2] < model.ground_height  # [B, N_A]
    normal_speed = v[..., 2]
    approach = normal_speed.clamp(max=0.0)  # ≤ 0
    new_normal = torch.where(below, normal_speed - (1.0 + e) * approach, normal_speed)

    tangential = v[..., :2]
    # sqrt(·+tiny) keeps the gradient finite when an anchor is at rest (‖v_t‖ = 0).
    tangential_speed = torch.sqrt((tangential * tangential).sum(-1) + 1e-30)
    retained = 1.0 - model.friction * (1.0 + e) * (-approach) / tangential_speed
    retained = torch.where(below, retained.clamp(min=0.0), torch.ones_like(retained))
    new_tangential = tangential * retained[..., None]
    new_v = torch.cat([new_tangential, new_normal[..., None]], dim=-1)

    ground = torch.full_like(x[..., 2], model.ground_height)
    tangential_position = x[..., :2] - dt * (tangential - new_tangential)
    new_z = torch.where(below, ground, x[..., 2])
    return torch.cat([tangential_position, new_z[..., None]], dim=-1), new_v


def step(
    model: SpringMassModel,
    state: State,
    dt: float,  # substep length h, seconds
    control: Control | None = None,
) -> State:
    """One semi-implicit Euler substep: v ← v + (F/m + g)·h, x ← x + v·h, then ground contact."""
    force = spring_forces(model, state.x, state.v)
    if control is not None and control.force is not None:
        force = force + control.force
    v = state.v + (force / model.mass[..., None] + model.gravity_vector) * dt
    x = state.x + v * dt
    x, v = ground_contact(model, x, v, dt)
    return State(x, v)


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
    direction = _gather_anchors(x, j) - _gather_anchors(x, i)
    direction = direction / torch.linalg.vector_norm(direction, dim=-1, keepdim=True)
    weight = (coefficient / model.rest_length).abs()
    inverse_sqrt_mass = mass.rsqrt()[..., None]
    both_ends = torch.cat([i, j], dim=-1)

    def apply(u: Tensor) -> Tensor:
        displacement = u * inverse_sqrt_mass
        stretch = (_gather_anchors(displacement, j) - _gather_anchors(displacement, i)) * direction
        pull = (weight * stretch.sum(-1))[..., None] * direction
        force = _scatter_anchors(x.shape[1], both_ends, torch.cat([pull, -pull], dim=1))
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
def stability_rates(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] positions, metres
) -> tuple[float, float]:
    """Bounds over the batch on the squared frequency Ω² (1/s²) and damping rate C (1/s).

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
        unit = largest_eigenvalue(model, x, one, one)  # [B] shared topology → one value per x
        omega_sq = unit * (model.stiffness / model.mass).abs()[:, 0]
        damping_rate = unit * (model.damping / model.mass).abs()[:, 0]
    else:
        omega_sq = largest_eigenvalue(model, x, model.stiffness, model.mass)
        damping_rate = largest_eigenvalue(model, x, model.damping, model.mass)
    margin = EIGENVALUE_MARGIN
    return (
        margin * stiffening * omega_sq.max().item(),
        margin * damping_rate.max().item(),
    )


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
    if not (torch.isfinite(model.mass).all() and (model.mass > 0).all()):
        raise ValueError("mass must be finite and positive")
    omega_sq, damping_rate = stability_rates(model, x)
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


METHODS = ("auto", "autograd", "adjoint", "fused", "numba")


def choose_method(
    method: str, model: SpringMassModel, state: State, control: Control | None = None
) -> str:
    """Resolve ``method="auto"`` (see :func:`rollout`) and check an explicit choice."""
    from .fused import fused_usable

    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if method == "auto":
        method = os.environ.get("RECONPHYS_SIMULATOR", "auto")
        if method not in METHODS:
            raise ValueError(f"RECONPHYS_SIMULATOR: expected one of {METHODS}, got {method!r}")
    from .cpu_kernels import numba_available

    tensors = [state.x, state.v, model.rest_length, model.mass, model.stiffness]
    tensors += [model.damping, model.friction]
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
    has_control = control is not None and control.force is not None
    if method in ("adjoint", "fused") and has_control:
        raise ValueError(f"method {method!r} does not take a control force; use 'autograd'")
    if method == "fused" and not fused_usable(state.x.device):
        raise ValueError(
            "method 'fused' needs Triton and a CUDA device (or TRITON_INTERPRET=1 on CPU)"
        )
    if method == "numba":
        if not numba_available():
            raise ValueError("method 'numba' needs Numba (pip install numba)")
        if state.x.is_cuda or needs_grad:
            raise ValueError("method 'numba' runs on CPU without gradients")
    if method != "auto":
        return method
    if not state.x.is_cuda and not needs_grad and numba_available():
        return "numba"
    if has_control:
        return "autograd"
    if state.x.is_cuda and fused_usable(state.x.device):
        return "fused"
    return "adjoint" if needs_grad else "autograd"


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
) -> Trajectory:
    """Simulate ``num_frames`` frames and keep the state at every frame boundary.

    ``substeps`` forces an exact count (the caller is then responsible for stability); by default
    it is :func:`stable_substeps` with ``min_substeps`` as the floor: the stiffest, most damped
    scene of the batch decides. Gradients flow through every substep to the attributes, rest
    lengths and initial state.

    ``method`` (all give the same trajectory and gradients up to float round-off):

    - ``"autograd"``: the plain reference, autograd through every :func:`step`; memory grows with
      frames × substeps; the only method that takes a ``control``.
    - ``"adjoint"``: the same forward, with the hand-written exact backward of
      :mod:`reconphys.physics.adjoint` (memory O(frames + substeps)).
    - ``"fused"``: the Triton kernels of :mod:`reconphys.physics.fused` with the same backward
      (CUDA; on CPU only under Triton's interpreter, for tests).
    - ``"numba"``: compiled CPU substeps of :mod:`reconphys.physics.cpu_kernels`, forward only
      (CPU, no gradient); takes a ``control``.
    - ``"auto"``: on CPU without a gradient ``"numba"`` (when Numba is installed); else
      ``"autograd"`` with a ``control``; ``"fused"`` on CUDA when Triton is installed; else
      ``"adjoint"`` when a gradient is needed, else ``"autograd"``. The environment
      variable ``RECONPHYS_SIMULATOR`` (one of the names above) overrides the automatic choice,
      e.g. ``RECONPHYS_SIMULATOR=autograd`` forces the fast path off.
    """
    if substeps is None:
        substeps = stable_substeps(model, state.x, frame_dt, min_substeps)
    method = choose_method(method, model, state, control)
    batch = max(state.x.shape[0], state.v.shape[0], model.batch_size)
    state = State(state.x.expand(batch, -1, -1), state.v.expand(batch, -1, -1))
    if method == "numba":
        from .cpu_kernels import CompiledRollout

        return _rollout_compiled(
            CompiledRollout(model, state, substeps, frame_dt), state, num_frames, control, progress
        )
    if method != "autograd":
        from .adjoint import TorchEngine, rollout_adjoint
        from .fused import FusedEngine

        engine = FusedEngine if method == "fused" else TorchEngine
        xs, vs = rollout_adjoint(model, state, num_frames, substeps, frame_dt, engine, progress)
        return Trajectory(xs, vs, substeps, frame_dt)
    h = frame_dt / substeps
    xs, vs = [state.x], [state.v]
    frames = range(num_frames)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc=f"simulate ({substeps} substeps/frame)", unit="frame")
    for _ in frames:
        for _ in range(substeps):
            state = step(model, state, h, control)
        xs.append(state.x)
        vs.append(state.v)
    return Trajectory(torch.stack(xs, 1), torch.stack(vs, 1), substeps, frame_dt)


def _rollout_compiled(runner, state: State, num_frames: int, control, progress) -> Trajectory:
    force = control.force if control is not None else None
    xs, vs = [state.x.detach().cpu()], [state.v.detach().cpu()]
    frames = range(num_frames)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc=f"simulate ({runner.substeps} substeps/frame)", unit="frame")
    for _ in frames:
        new = runner.frame(force)
        xs.append(new.x)
        vs.append(new.v)
    x = torch.stack(xs, 1).to(state.x.dtype)
    v = torch.stack(vs, 1).to(state.v.dtype)
    return Trajectory(x, v, runner.substeps, runner.frame_dt)


def kinetic_energy(
    model: SpringMassModel,
    v: Tensor,  # [B, N_A, 3] m/s
) -> Tensor:  # [B] joules
    return 0.5 * (model.mass * (v * v).sum(-1)).sum(-1)


def spring_energy(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] metres
) -> Tensor:  # [B] joules
    """Elastic energy of the non-linear springs, the potential of F = k ε (1 + |ε|)^p.

    Per spring U = k l [(1+a)^(p+2)/(p+2) − (1+a)^(p+1)/(p+1) + 1/((p+1)(p+2))] with a = |ε|;
    for p = 0 this is ½ (k / l)(‖x_j − x_i‖ − l)².
    """
    i, j = model.springs[..., 0], model.springs[..., 1]
    length = torch.linalg.vector_norm(_gather_anchors(x, j) - _gather_anchors(x, i), dim=-1)
    a = (length / model.rest_length - 1.0).abs()
    p = model.spring_exponent
    per_length = (
        (1 + a) ** (p + 2) / (p + 2) - (1 + a) ** (p + 1) / (p + 1) + 1 / ((p + 1) * (p + 2))
    )
    return (model.stiffness * model.rest_length * per_length).sum(-1)


def potential_energy(
    model: SpringMassModel,
    x: Tensor,  # [B, N_A, 3] metres
) -> Tensor:  # [B] joules
    """Spring energy plus gravitational energy −m g·x (zero at the origin)."""
    gravity = -(model.mass[..., None] * x * model.gravity_vector).sum((-1, -2))
    return spring_energy(model, x) + gravity
