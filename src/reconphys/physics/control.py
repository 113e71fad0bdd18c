"""Controllers: grips that hold the object by springs, like a gripper or a hand, and the frame
stepper that applies them (:func:`simulate_frame`, used by the viewer and scripted interaction).

A grip is made where the user picks a point on the object. It attaches to the ``G`` anchors nearest
to that point; each attached anchor gets its own controller point, ``target + offset``, where the
offset is the anchor's position relative to the grip point when it was made. The controller points
move rigidly with the grip's target (no rotation). Each one pulls its anchor with a zero-length
spring and a dashpot on the relative velocity:

    F_a = k_g · (target + offset_a − x_a) + d_g · (v_target − v_a)

``F_a`` enters the simulator as an external force (:class:`reconphys.physics.Control`), so the
object is simulated by the same :func:`reconphys.physics.step` as everywhere else, through
:func:`reconphys.physics.rollout` with a per-substep ``control_fn``.

Grip stiffness: the grip should hold like a firm gripper, as stiff as the explicit integrator
allows. :func:`grip_coefficients` sizes it per anchor from the substep ``h``: ``h² k_g / m`` is
:data:`GRIP_STIFFNESS_SHARE` and the damping ratio is :data:`GRIP_DAMPING_RATIO`, together about a
sixth of the stability budget ``h²ω² + 2hc < 4`` — the headroom that
:func:`reconphys.physics.stable_substeps` leaves (it fills 70 % of it). More substeps therefore
make a stiffer grip: the grip springs are a numerical stand-in for a rigid hold, not a material.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from torch import Tensor

from .._optional import numba_available
from .model import SpringMassModel
from .rollout import rollout
from .state import Control, State

# Fractions of the explicit-Euler stability budget spent on a grip spring (see module docstring):
# h²ω_g² = 0.15 and 2hc_g = 4ζ·hω_g ≈ 0.46, in all ≈ 0.6 of the 1.2 left by stable_substeps.
GRIP_STIFFNESS_SHARE = 0.15
GRIP_DAMPING_RATIO = 0.3


@dataclass
class Grip:
    """One grip: the anchors it holds and where its controller is (tensors on the sim device)."""

    name: str
    anchors: Tensor  # [G] int64 indices of the held anchors
    offsets: Tensor  # [G, 3] held anchor minus grip point when the grip was made, metres
    position: Tensor  # [3] where the controller is now, metres
    goal: Tensor  # [3] where the user wants it; the controller moves there at a capped speed

    @property
    def num_anchors(self) -> int:
        return self.anchors.shape[0]


def nearest_anchors(
    positions: Tensor,  # [N_A, 3] current anchor positions, metres
    point: Tensor,  # [3] metres
    count: int,
) -> Tensor:  # [min(count, N_A)] int64, nearest first
    """Indices of the ``count`` anchors closest to ``point``."""
    distance = torch.linalg.vector_norm(positions - point, dim=-1)
    count = min(int(count), positions.shape[0])
    return torch.topk(distance, count, largest=False).indices


def pick_point(
    positions: Tensor,  # [N, 3] candidate points (anchors or Gaussian centres), metres
    ray_origin: Tensor,  # [3] metres
    ray_direction: Tensor,  # [3] any non-zero length
    radius: float,  # metres: how far from the ray a point may lie and still be hit
) -> int | None:
    """Index of the first point the ray hits: of the points within ``radius`` of the ray and in
    front of its origin, the one nearest to the origin along the ray. ``None`` for a miss."""
    direction = ray_direction / torch.linalg.vector_norm(ray_direction).clamp(min=1e-12)
    relative = positions - ray_origin
    along = relative @ direction  # [N]
    off_ray = torch.linalg.vector_norm(relative - along[:, None] * direction, dim=-1)
    hit = (off_ray <= radius) & (along > 0)
    if not bool(hit.any()):
        return None
    along = torch.where(hit, along, torch.full_like(along, float("inf")))
    return int(torch.argmin(along))


def grip_coefficients(
    mass: Tensor,  # [G] kg, the mass of each held anchor
    substep: float,  # h, seconds
) -> tuple[Tensor, Tensor]:  # k_g [G] N/m, d_g [G] N·s/m
    """Spring and dashpot constants of each controller-anchor link (see module docstring)."""
    stiffness = GRIP_STIFFNESS_SHARE * mass / substep**2
    damping = 2.0 * GRIP_DAMPING_RATIO * torch.sqrt(stiffness * mass)
    return stiffness, damping


@dataclass
class GripPlan:
    """Everything a frame's substeps need to apply the grips, flattened over all grips."""

    anchors: Tensor  # [M] int64 held anchors (an anchor held by two grips appears twice)
    offsets: Tensor  # [M, 3] metres
    start: Tensor  # [M, 3] controller position of each link at the start of the frame
    travel: Tensor  # [M, 3] how far the controller moves during the frame, metres
    stiffness: Tensor  # [M] N/m
    damping: Tensor  # [M] N·s/m
    velocity: Tensor  # [M, 3] controller velocity during the frame, m/s


def plan_frame(
    grips: list[Grip],
    new_positions: list[Tensor],  # one [3] per grip: the controller position at the frame's end
    mass: Tensor,  # [1|B, N_A|1] the model's mass, kg
    substep: float,  # h, seconds
    frame_dt: float,  # seconds
) -> GripPlan | None:
    """Flatten the grips for one frame; the controllers move linearly to ``new_positions``."""
    if not grips:
        return None
    anchors = torch.cat([g.anchors for g in grips])
    offsets = torch.cat([g.offsets for g in grips])
    start = torch.cat([g.position.expand(g.num_anchors, 3) for g in grips])
    end = torch.cat([p.expand(g.num_anchors, 3) for g, p in zip(grips, new_positions, strict=True)])
    per_anchor = mass[0]  # [N_A] or [1]
    if per_anchor.shape[0] > 1:
        held_mass = per_anchor[anchors]
    else:
        held_mass = per_anchor.expand(anchors.shape[0])
    stiffness, damping = grip_coefficients(held_mass, substep)
    travel = end - start
    return GripPlan(anchors, offsets, start, travel, stiffness, damping, travel / frame_dt)


def grip_force(
    plan: GripPlan,
    x: Tensor,  # [B, N_A, 3] positions, metres
    v: Tensor,  # [B, N_A, 3] velocities, m/s
    progress: float,  # fraction of the frame done at the end of this substep, in (0, 1]
) -> Tensor:  # [B, N_A, 3] newtons
    """External force of the grips on every anchor for one substep."""
    controller = plan.start + progress * plan.travel + plan.offsets  # [M, 3]
    held_x = x[:, plan.anchors]  # [B, M, 3]
    held_v = v[:, plan.anchors]
    pull = plan.stiffness[:, None] * (controller - held_x)
    pull = pull + plan.damping[:, None] * (plan.velocity - held_v)
    return torch.zeros_like(x).index_add_(1, plan.anchors, pull)


@contextmanager
def numba_threads(count: int | None) -> Iterator[None]:
    """Run the compiled CPU substeps with ``count`` threads in the calling thread (Numba's
    setting is thread-local); ``None`` leaves Numba's setting alone."""
    if count is None or not numba_available():
        yield
        return
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(count), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(previous)


def simulate_frame(
    model: SpringMassModel,
    state: State,  # x, v [B, N_A, 3]
    frame_dt: float,  # seconds
    substeps: int,
    grips: list[Grip],
    targets: list[Tensor],  # one [3] per grip: controller position at the end of the frame
    threads: int | None = None,  # Numba threads of the compiled CPU substeps (None: Numba's)
) -> State:
    """One frame of ``substeps`` substeps; the grips' controllers move linearly from their
    positions to ``targets`` during the frame.

    The substeps are those of :func:`reconphys.physics.rollout` with its automatic choice of
    method (on CPU the compiled substeps of :mod:`reconphys.physics.numba_backend`, else the
    PyTorch :func:`~reconphys.physics.step`). A grip's force depends on the state, so it is
    recomputed before every substep (held for one substep, as ``step`` holds a ``Control``)
    through rollout's ``control_fn``.
    """
    h = frame_dt / substeps
    with torch.inference_mode(), numba_threads(None if state.x.is_cuda else threads):
        if not grips:
            trajectory = rollout(model, state, 1, frame_dt, substeps=substeps)
        else:
            plan = plan_frame(grips, targets, model.mass, h, frame_dt)

            def grips_control(current: State, substep: int) -> Control:
                progress = (substep + 1) / substeps
                return Control(force=grip_force(plan, current.x, current.v, progress))

            trajectory = rollout(
                model, state, 1, frame_dt, substeps=substeps, control_fn=grips_control
            )
    return State(trajectory.x[:, -1], trajectory.v[:, -1])
