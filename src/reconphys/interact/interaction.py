"""Interactive control of one asset's simulation, without threads: :class:`Interaction`.

:class:`Interaction` owns the spring-mass state of one asset and everything a user can do to it:
step, reset, drop from a height, change the attributes and the substeps, grab the object with grips
and move them, record. Frames are simulated in the calling thread (:meth:`Interaction.advance`).
Scripts (:mod:`reconphys.interact.script`) and ``reconphys simulate --push/--script`` drive it
directly; the viewer's :class:`~reconphys.viewer.session.ViewerSession` adds a lock and a
background thread.

The fields that a frame reads and publishes are touched only inside ``with self._lock`` (a no-op
here; the viewer's session puts a real lock there), so the same methods serve both. The module is
a little over 400 lines because it is one class: the whole user-facing surface of an interaction
(state, attributes, grips, recording, stepping), each method short.
"""

from __future__ import annotations

import math
import time
from contextlib import nullcontext
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..assets.asset import Asset
from ..errors import InputError
from ..physics import ATTRIBUTES, State, deform_means, stable_substeps
from ..physics.control import Grip, nearest_anchors, pick_point, simulate_frame
from .recording import Recording


@dataclass
class _RecordingBuffer:
    anchors: list[Tensor] = field(default_factory=list)
    velocities: list[Tensor] = field(default_factory=list)
    grip_positions: list[dict[str, list[float]]] = field(default_factory=list)
    substeps: list[int] = field(default_factory=list)


class Interaction:
    """Interactive spring-mass simulation of one asset, in the calling thread (module docstring).

    ``grip_anchor_count``: anchors each grip holds (G). ``max_grip_speed`` (m/s): a grip's
    controller follows the user's pointer at most this fast, so a pointer jump (or a simulation
    slower than real time) does not yank the object. ``max_record_frames`` caps a recording (24 KB
    per frame for 2048 anchors). ``simulation_threads``: Numba threads of the compiled CPU substeps
    (``None``: Numba's default, all cores). One by default: the parallel build meets its threads
    twice per substep, and when another process (the browser, the display thread, other jobs)
    holds a core, every meeting waits for a time slice — 10-20x slower on the shared 2-core
    machine (docs/viewer.md).
    """

    def __init__(
        self,
        asset: Asset,
        device: torch.device | str = "cpu",
        grip_anchor_count: int = 16,
        max_grip_speed: float = 1.5,
        max_record_frames: int = 3000,
        simulation_threads: int | None = 1,
    ):
        self.asset = asset
        self.device = torch.device(device)
        self.frame_dt = float(asset.physics.frame_dt)
        self.grip_anchor_count = int(grip_anchor_count)
        self.max_grip_speed = float(max_grip_speed)
        self.max_record_frames = int(max_record_frames)
        self.simulation_threads = simulation_threads

        self._lock = nullcontext()  # guards the fields below (a real lock in ViewerSession)
        self._step_lock = nullcontext()  # one frame computation at a time

        self._rest = asset.x0.to(self.device, torch.float32)  # [N_A, 3]
        self._rest_means = asset.gaussians.means.to(self.device, torch.float32)  # [N, 3]
        self._binding_index = asset.binding_index.to(self.device)
        self._binding_weight = asset.binding_weight.to(self.device)
        # Picking radius: about one anchor spacing.
        self.pick_radius = float(asset.rest_length.float().median())

        self._model = asset.model(self.device)
        self._attributes = {name: float(getattr(asset.physics, name)) for name in ATTRIBUTES}
        self._requested_substeps = int(asset.physics.substeps)
        self._stable_substeps = self._stability_bound(self._model)
        self._state = asset.initial_state(self.device)
        self._frame = 0
        self._version = 0  # bumped whenever the published state changes
        self._generation = 0  # bumped by reset / drop: frames started before are discarded
        self._grips: dict[str, Grip] = {}
        self._grip_counter = 0
        self._frame_seconds = 0.0  # moving average of the compute time per frame
        self._message = ""
        self._recording: _RecordingBuffer | None = None

    # ------------------------------------------------------------------------------------------
    # reading

    @property
    def version(self) -> int:
        """Increases whenever the state shown to the user changes (poll it to redraw)."""
        return self._version

    @property
    def substeps(self) -> int:
        """Substeps per frame in use: the requested count, raised to the stability bound."""
        return max(self._requested_substeps, self._stable_substeps)

    @property
    def attributes(self) -> dict[str, float]:
        """The scalar attributes in use (m kg per anchor, k, d, f); see
        docs/design.md#physical-model."""
        return dict(self._attributes)

    def state(self) -> State:
        """The latest published state, ``x, v [1, N_A, 3]`` (a CPU copy)."""
        with self._lock:
            state = self._state
        return State(state.x.detach().cpu().clone(), state.v.detach().cpu().clone())

    def anchor_positions(self) -> Tensor:  # [N_A, 3] metres, CPU
        with self._lock:
            x = self._state.x
        return x[0].detach().cpu().clone()

    def gaussian_means(self) -> Tensor:  # [N, 3] metres, CPU
        """Centres of the Gaussians following the latest anchor positions
        (docs/design.md#binding)."""
        with self._lock:
            x = self._state.x
        with torch.no_grad():
            means = deform_means(
                self._rest_means, self._rest, x[0], self._binding_index, self._binding_weight
            )
        return means.cpu()

    def grips(self) -> dict[str, dict]:
        """Per grip: ``position`` and ``goal`` (metres) and the held ``anchors`` (CPU tensors)."""
        with self._lock:
            grips = list(self._grips.values())
        return {
            g.name: {
                "position": g.position.cpu().clone(),
                "goal": g.goal.cpu().clone(),
                "anchors": g.anchors.cpu().clone(),
            }
            for g in grips
        }

    @property
    def frame(self) -> int:
        """Frames simulated since the last reset or drop."""
        return self._frame

    @property
    def recorded_frames(self) -> int | None:
        """Frames recorded so far; None when not recording."""
        with self._lock:
            return None if self._recording is None else len(self._recording.anchors) - 1

    def notify(self, message: str) -> None:
        """Show ``message`` to the user (it is the ``message`` of :meth:`status`)."""
        with self._lock:
            self._message = message

    # ------------------------------------------------------------------------------------------
    # state

    def reset(self) -> None:
        """Back to the asset's initial state (position and velocity); grips are released."""
        self._set_state(self.asset.initial_state(self.device), "reset to the asset's initial state")

    def drop(self, height: float) -> None:
        """Put the object at rest in its initial shape with its lowest Gaussian centre ``height``
        metres above the ground; grips are released."""
        if not (math.isfinite(height) and height >= 0):
            raise InputError(f"must be a finite height ≥ 0 m, got {height}", field="height")
        lowest = float(self._rest_means[:, 2].min())
        shift = torch.zeros(3, device=self.device)
        shift[2] = self._model.ground_height + height - lowest
        x = (self._rest + shift)[None]
        self._set_state(State(x, torch.zeros_like(x)), f"dropped from {height:.2f} m")

    def _set_state(self, state: State, message: str) -> None:
        with self._lock:
            self._state = state
            self._frame = 0
            self._generation += 1
            self._grips.clear()
            self._message = message
            self._version += 1
            if self._recording is not None:
                self._record(state, 0)

    # ------------------------------------------------------------------------------------------
    # attributes and substeps

    def set_attributes(self, **values: float) -> None:
        """Change any of mass (kg per anchor, > 0), stiffness, damping and friction (≥ 0); one
        value for the whole object, replacing per-anchor / per-spring arrays of the asset."""
        for name, value in values.items():
            if name not in ATTRIBUTES:
                raise InputError(f"unknown attribute, expected one of {ATTRIBUTES}", field=name)
            value = float(value)
            positive = name == "mass"
            if not math.isfinite(value) or value < 0 or (positive and value == 0):
                expected = "> 0" if positive else "≥ 0"
                raise InputError(f"must be a finite number {expected}, got {value}", field=name)
        with self._lock:
            attributes = {**self._attributes, **{k: float(v) for k, v in values.items()}}
            model = self._model
        tensors = {k: torch.tensor(attributes[k], device=self.device) for k in values}
        model = model.with_attributes(**tensors)
        bound = self._stability_bound(model)  # outside the lock: ~10 ms of power iteration
        with self._lock:
            self._model = model
            self._attributes = attributes
            self._stable_substeps = bound
            self._message = f"substeps {self.substeps} (stability bound {bound})"

    def set_substeps(self, substeps: int) -> int:
        """Request a substep count per frame; returns the count used, which is never below the
        stability bound of the current attributes (lowering it below gives the bound)."""
        if int(substeps) < 1:
            raise InputError(f"must be ≥ 1, got {substeps}", field="substeps")
        with self._lock:
            self._requested_substeps = int(substeps)
            used = self.substeps
            if used > substeps:
                self._message = f"substeps raised to the stability bound {used}"
            else:
                self._message = ""
        return used

    def _stability_bound(self, model) -> int:
        return stable_substeps(model, self._rest[None], self.frame_dt, 1)

    # ------------------------------------------------------------------------------------------
    # grabbing

    def pick(
        self,
        ray_origin,  # [3] metres
        ray_direction,  # [3]
        radius: float | None = None,  # metres; default: about one anchor spacing
    ) -> Tensor | None:  # [3] metres, CPU; None when the ray misses the object
        """The point of the object (a Gaussian centre) that a viewing ray hits first."""
        means = self.gaussian_means()
        origin = torch.as_tensor(ray_origin, dtype=torch.float32)
        direction = torch.as_tensor(ray_direction, dtype=torch.float32)
        hit = pick_point(means, origin, direction, radius or self.pick_radius)
        return None if hit is None else means[hit]

    def grab(self, point, count: int | None = None, name: str | None = None) -> str:
        """Attach a new grip at ``point`` [3] (metres) to the ``count`` nearest anchors (default
        ``grip_anchor_count``); returns its name. The grip holds them where they are until it
        is moved."""
        point = torch.as_tensor(point, dtype=torch.float32, device=self.device).reshape(3)
        if not bool(torch.isfinite(point).all()):
            raise InputError("must be a finite point [x, y, z] in metres", field="grab point")
        with self._lock:
            x = self._state.x[0]
            if name is None:
                self._grip_counter += 1
                name = f"grip {self._grip_counter}"
            if name in self._grips:
                raise InputError("a grip of that name exists already", field=name)
            anchors = nearest_anchors(x, point, count or self.grip_anchor_count)
            self._grips[name] = Grip(
                name=name,
                anchors=anchors,
                offsets=x[anchors] - point,
                position=point.clone(),
                goal=point.clone(),
            )
            self._message = f"{name}: holding {anchors.shape[0]} anchors"
            self._version += 1
        return name

    def move_grip(self, name: str, goal) -> None:
        """Move a grip's controller towards ``goal`` [3] (metres), at most ``max_grip_speed``."""
        goal = torch.as_tensor(goal, dtype=torch.float32, device=self.device).reshape(3)
        if not bool(torch.isfinite(goal).all()):
            raise InputError("must be a finite point [x, y, z] in metres", field="grip goal")
        with self._lock:
            self._grip(name).goal = goal

    def nudge_grip(self, name: str, delta) -> None:
        """Move a grip's goal by ``delta`` [3] metres (keyboard moves)."""
        delta = torch.as_tensor(delta, dtype=torch.float32, device=self.device).reshape(3)
        with self._lock:
            grip = self._grip(name)
            grip.goal = grip.goal + delta

    def release(self, name: str) -> None:
        with self._lock:
            self._grip(name)
            del self._grips[name]
            self._message = f"{name} released"
            self._version += 1

    def release_all(self) -> None:
        with self._lock:
            self._grips.clear()
            self._version += 1

    def _grip(self, name: str) -> Grip:
        if name not in self._grips:
            raise InputError(f"no such grip (have: {', '.join(self._grips) or 'none'})", field=name)
        return self._grips[name]

    # ------------------------------------------------------------------------------------------
    # recording

    def start_recording(self) -> None:
        """Record every published frame from now on (anchors, velocities, grip positions)."""
        with self._lock:
            self._recording = _RecordingBuffer()
            self._record(self._state, 0)
            self._message = "recording"

    def stop_recording(self) -> Recording | None:
        """Stop recording and return what was recorded (None when not recording)."""
        with self._lock:
            buffer, self._recording = self._recording, None
            self._message = ""
        if buffer is None:
            return None
        return Recording(
            anchors=torch.stack(buffer.anchors),
            velocities=torch.stack(buffer.velocities),
            grip_positions=buffer.grip_positions,
            substeps=buffer.substeps,
            frame_dt=self.frame_dt,
        )

    @property
    def recording(self) -> bool:
        return self._recording is not None

    def _record(self, state: State, substeps: int) -> None:  # with self._lock held
        buffer = self._recording
        if len(buffer.anchors) > self.max_record_frames:
            self._message = f"recording full ({self.max_record_frames} frames): stop it to save"
            return
        buffer.anchors.append(state.x[0].detach().float().cpu().clone())
        buffer.velocities.append(state.v[0].detach().float().cpu().clone())
        buffer.grip_positions.append(
            {g.name: g.position.cpu().tolist() for g in self._grips.values()}
        )
        buffer.substeps.append(substeps)

    # ------------------------------------------------------------------------------------------
    # stepping

    def advance(self, frames: int = 1) -> int:
        """Simulate ``frames`` frames now, in the calling thread (scripted / headless use);
        returns how many were published (fewer if the simulation became unstable)."""
        torch.set_flush_denormal(True)
        done = 0
        for _ in range(int(frames)):
            if not self._advance_one():
                break
            done += 1
        return done

    def _advance_one(self) -> bool:
        with self._step_lock:
            with self._lock:
                generation = self._generation
                model, state, substeps = self._model, self._state, self.substeps
                grips = list(self._grips.values())
                targets = [self._controller_target(g) for g in grips]
            started = time.perf_counter()
            state = simulate_frame(
                model, state, self.frame_dt, substeps, grips, targets, self.simulation_threads
            )
            finite = bool(torch.isfinite(state.x).all() and torch.isfinite(state.v).all())
            elapsed = time.perf_counter() - started
            with self._lock:
                if generation != self._generation:
                    return True  # a reset or drop replaced the state meanwhile
                if not finite:
                    self._on_unstable()
                    self._message = (
                        "the simulation became unstable and was paused (state kept from the "
                        "frame before): raise the substeps or lower the stiffness"
                    )
                    self._version += 1
                    return False
                self._state = state
                self._frame += 1
                for grip, target in zip(grips, targets, strict=True):
                    grip.position = target
                average = self._frame_seconds
                self._frame_seconds = elapsed if average == 0 else 0.8 * average + 0.2 * elapsed
                if self._recording is not None:
                    self._record(state, substeps)
                self._version += 1
        return True

    def _controller_target(self, grip: Grip) -> Tensor:  # with self._lock held
        """Where the grip's controller is at the end of the next frame (speed-capped)."""
        travel = grip.goal - grip.position
        distance = float(torch.linalg.vector_norm(travel))
        limit = self.max_grip_speed * self.frame_dt
        if distance <= limit:
            return grip.goal.clone()
        return grip.position + travel * (limit / distance)

    def _on_unstable(self) -> None:  # with self._lock held
        """Called when a frame became unstable (before its state is discarded)."""
