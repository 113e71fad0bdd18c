"""Semi-implicit Euler stepping of the spring-mass model with ground contact
(docs/design.md#physical-model).

This is the plain PyTorch reference: differentiable with respect to every attribute (scalar,
per-anchor or per-spring), the rest lengths and the initial state; CPU or CUDA; float32 or
float64; batched over scenes. One substep is :func:`step`; :func:`reconphys.physics.rollout.rollout`
strings substeps into frames with a substep count taken from
:func:`reconphys.physics.stability.stable_substeps`. The fast twins (``torch_backend``,
``triton_backend``, ``numba_backend``) implement these equations.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .model import SpringMassModel
from .state import Control, State


def gather_anchors(values: Tensor, index: Tensor) -> Tensor:
    """values [B, N_A, C], index [E] or [B, E] → [B, E, C]."""
    if index.dim() == 1:
        return values.index_select(1, index)
    return torch.gather(values, 1, index[..., None].expand(-1, -1, values.shape[-1]))


def scatter_anchors(num_anchors: int, index: Tensor, values: Tensor) -> Tensor:
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
    delta = gather_anchors(x, j) - gather_anchors(x, i)  # [B, E, 3]
    # The tiny floor keeps the direction (and its gradient) finite if two anchors ever coincide,
    # e.g. when a very soft, heavy object is flattened against the ground.
    length = torch.sqrt((delta * delta).sum(-1) + 1e-24)  # [B, E]
    direction = delta / length[..., None]
    strain = length / model.rest_length - 1.0
    magnitude = model.stiffness * strain
    if model.spring_exponent != 0.0:
        magnitude = magnitude * (1.0 + strain.abs()) ** model.spring_exponent
    closing_speed = ((gather_anchors(v, j) - gather_anchors(v, i)) * direction).sum(-1)
    magnitude = magnitude + model.damping / model.rest_length * closing_speed
    force_on_i = magnitude[..., None] * direction  # [B, E, 3], pulls i towards j when stretched
    # One scatter for both ends: +F on i, −F on j.
    both_ends = torch.cat([i, j], dim=-1)
    return scatter_anchors(x.shape[1], both_ends, torch.cat([force_on_i, -force_on_i], dim=1))


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
    length = torch.linalg.vector_norm(gather_anchors(x, j) - gather_anchors(x, i), dim=-1)
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
