"""The viewer's controller: a headless, thread-safe simulation session.

:class:`ViewerSession` owns the spring-mass state of one asset and everything a user can do to it:
play / pause / step / reset, drop from a height, change the attributes and the substeps, grab the
object with grips and move them, record. The browser UI (:mod:`reconphys.viewer.app`), the scripted
mode (:mod:`reconphys.viewer.script`) and the tests all drive this same API.

Threading: :meth:`ViewerSession.start` runs the simulation in a background thread. Every public
method only takes a short lock to read or change the session's inputs (attributes, grips, flags) or
its latest published state; none waits for a frame to finish. A frame reads its inputs at its start,
computes without the lock and publishes at its end; a frame that a reset or drop overtook is
discarded. Changes made during a frame therefore apply from the next frame on (at most one frame,
0.03 s of simulated time, of latency).
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..assets.asset import Asset
from ..errors import InputError
from ..physics import Control, State, deform_means, rollout, stable_substeps, step
from ..physics.cpu_kernels import CompiledRollout, numba_available
from ..physics.integrator import choose_method
from .grips import Grip, grip_force, nearest_anchors, pick_point, plan_frame

ATTRIBUTES = ("mass", "stiffness", "damping", "friction")


@dataclass
class SessionStatus:
    """A snapshot of the session for display (all plain Python values)."""

    frame: int  # frames simulated since the last reset or drop
    time: float  # simulated seconds since the last reset or drop
    playing: bool
    substeps: int  # substeps per frame in use: max(requested, stability bound)
    requested_substeps: int  # what the user asked for
    stable_substeps: int  # the stability bound for the current attributes
    frames_per_second: float  # simulation frames per wall-clock second of computing (0: none yet)
    realtime_factor: float  # simulated seconds per wall-clock second while playing (paced ≤ 1)
    max_speed: float  # fastest anchor, m/s
    lowest_z: float  # lowest anchor, metres
    grips: int  # active grips
    recording_frames: int | None  # frames recorded so far; None when not recording
    message: str  # last notice for the user ("" when none)


@dataclass
class Recording:
    """Anchor states of a recorded interaction, one row per published frame (CPU, float32)."""

    anchors: Tensor  # [T+1, N_A, 3] metres; row 0 is the state when recording started
    velocities: Tensor  # [T+1, N_A, 3] m/s
    grip_positions: list[dict[str, list[float]]]  # per row: grip name → controller position, m
    substeps: list[int]  # per row: substeps of the frame that produced it (row 0: 0)
    frame_dt: float  # seconds between rows


@dataclass
class _RecordingBuffer:
    anchors: list[Tensor] = field(default_factory=list)
    velocities: list[Tensor] = field(default_factory=list)
    grip_positions: list[dict[str, list[float]]] = field(default_factory=list)
    substeps: list[int] = field(default_factory=list)


class ViewerSession:
    """Interactive spring-mass simulation of one asset (see the module docstring).

    ``grip_anchor_count``: anchors each grip holds (G). ``max_grip_speed`` (m/s): a grip's
    controller follows the user's pointer at most this fast, so a pointer jump (or a simulation
    slower than real time) does not yank the object. ``realtime``: when playing, do not run faster
    than real time. ``max_record_frames`` caps a recording (24 KB per frame for 2048 anchors).
    ``simulation_threads``: Numba threads of the compiled CPU substeps (``None``: Numba's default,
    all cores). One by default: the parallel build meets its threads twice per substep, and when
    another process (the browser, the display thread, other jobs) holds a core, every meeting
    waits for a time slice — 10-20x slower on the shared 2-core machine (docs/viewer.md).
    """

    def __init__(
        self,
        asset: Asset,
        device: torch.device | str = "cpu",
        grip_anchor_count: int = 16,
        max_grip_speed: float = 1.5,
        realtime: bool = True,
        max_record_frames: int = 3000,
        simulation_threads: int | None = 1,
    ):
        self.asset = asset
        self.device = torch.device(device)
        self.frame_dt = float(asset.physics.frame_dt)
        self.grip_anchor_count = int(grip_anchor_count)
        self.max_grip_speed = float(max_grip_speed)
        self.realtime = realtime
        self.max_record_frames = int(max_record_frames)
        self.simulation_threads = simulation_threads

        self._lock = threading.Lock()  # guards the fields below; held only briefly
        self._step_lock = threading.Lock()  # one frame computation at a time
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

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
        self._playing = False
        self._pending_steps = 0
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
    def playing(self) -> bool:
        return self._playing

    @property
    def attributes(self) -> dict[str, float]:
        """The scalar attributes in use (m kg per anchor, k, d, f); see DESIGN §4."""
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
        """Centres of the Gaussians following the latest anchor positions (DESIGN §4 binding)."""
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

    def status(self) -> SessionStatus:
        with self._lock:
            state, frame, playing = self._state, self._frame, self._playing
            frame_seconds, message = self._frame_seconds, self._message
            recording = None if self._recording is None else len(self._recording.anchors) - 1
            grips = len(self._grips)
            substeps, requested = self.substeps, self._requested_substeps
            bound = self._stable_substeps
        fps = 1.0 / frame_seconds if frame_seconds > 0 else 0.0
        capacity = fps * self.frame_dt
        realtime_factor = (min(1.0, capacity) if self.realtime else capacity) if playing else 0.0
        speed = torch.linalg.vector_norm(state.v[0], dim=-1).max()
        return SessionStatus(
            frame=frame,
            time=frame * self.frame_dt,
            playing=playing,
            substeps=substeps,
            requested_substeps=requested,
            stable_substeps=bound,
            frames_per_second=fps,
            realtime_factor=realtime_factor,
            max_speed=float(speed),
            lowest_z=float(state.x[0, :, 2].min()),
            grips=grips,
            recording_frames=recording,
            message=message,
        )

    def notify(self, message: str) -> None:
        """Show ``message`` to the user (it is the ``message`` of :meth:`status`)."""
        with self._lock:
            self._message = message

    # ------------------------------------------------------------------------------------------
    # playback

    def play(self) -> None:
        with self._lock:
            self._playing = True
        self._wake.set()

    def pause(self) -> None:
        with self._lock:
            self._playing = False

    def toggle(self) -> bool:
        """Play if paused, pause if playing; returns whether it now plays."""
        with self._lock:
            self._playing = not self._playing
            playing = self._playing
        self._wake.set()
        return playing

    def request_step(self, frames: int = 1) -> None:
        """Ask the background loop to simulate ``frames`` frames (for a Step button while
        paused); returns at once."""
        with self._lock:
            self._pending_steps += int(frames)
        self._wake.set()

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
                    self._playing = False
                    self._pending_steps = 0
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

    # ------------------------------------------------------------------------------------------
    # background loop

    def start(self) -> None:
        """Run the simulation in a background thread (daemon); :meth:`close` stops it."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="reconphys-sim", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None

    def __enter__(self) -> ViewerSession:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _loop(self) -> None:
        # Flush-to-zero is per thread: settling objects otherwise hit slow float32 denormals.
        torch.set_flush_denormal(True)
        next_frame_at = time.perf_counter()
        while not self._stop.is_set():
            self._wake.clear()
            with self._lock:
                run = self._playing or self._pending_steps > 0
                if not self._playing and self._pending_steps > 0:
                    self._pending_steps -= 1
                playing = self._playing
            if not run:
                self._wake.wait(0.25)
                next_frame_at = time.perf_counter()
                continue
            try:
                self._advance_one()
            except Exception as error:  # keep the UI alive; show the error instead
                with self._lock:
                    self._playing = False
                    self._message = f"simulation error: {error}"
                    self._version += 1
                continue
            if playing and self.realtime:
                next_frame_at += self.frame_dt
                delay = next_frame_at - time.perf_counter()
                if delay > 0:
                    self._wake.wait(delay)
                else:
                    next_frame_at = time.perf_counter()  # behind real time: do not catch up


@contextmanager
def numba_threads(count: int | None):
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
    model,
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
    method (on CPU the compiled substeps of :mod:`reconphys.physics.cpu_kernels`, else the PyTorch
    :func:`~reconphys.physics.step`). A grip's force depends on the state, so it is recomputed
    before every substep (held for one substep, as ``step`` holds a ``Control``): with grips the
    compiled path is called one substep at a time.
    """
    h = frame_dt / substeps
    with torch.inference_mode(), numba_threads(None if state.x.is_cuda else threads):
        if not grips:
            trajectory = rollout(model, state, 1, frame_dt, substeps=substeps)
            return State(trajectory.x[:, -1], trajectory.v[:, -1])
        plan = plan_frame(grips, targets, model.mass, h, frame_dt)
        probe = Control(force=state.x)  # only its presence matters to the choice of method
        if choose_method("auto", model, state, probe) == "numba":
            runner = CompiledRollout(model, state, 1, h)
            for s in range(substeps):
                state = runner.frame(grip_force(plan, state.x, state.v, (s + 1) / substeps))
            return state
        for s in range(substeps):
            control = Control(force=grip_force(plan, state.x, state.v, (s + 1) / substeps))
            state = step(model, state, h, control)
    return state
