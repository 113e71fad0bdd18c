"""The viewer's controller: an :class:`~reconphys.interact.Interaction` run by a background
thread.

:class:`ViewerSession` is the interaction of :mod:`reconphys.interact` (state, attributes, grips,
recording) plus play / pause and a simulation thread. The browser UI (:mod:`reconphys.viewer.app`),
the scripted mode (:mod:`reconphys.interact.script`) and the tests all drive this same API.

Threading: :meth:`ViewerSession.start` runs the simulation in a background thread. Every public
method only takes a short lock to read or change the session's inputs (attributes, grips, flags) or
its latest published state; none waits for a frame to finish. A frame reads its inputs at its start,
computes without the lock and publishes at its end; a frame that a reset or drop overtook is
discarded. Changes made during a frame therefore apply from the next frame on (at most one frame,
0.03 s of simulated time, of latency).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import torch

from ..assets.asset import Asset
from ..interact.interaction import Interaction


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


class ViewerSession(Interaction):
    """Interactive spring-mass simulation of one asset (see the module docstring).

    The arguments are those of :class:`~reconphys.interact.Interaction`, plus ``realtime``: when
    playing, do not run faster than real time.
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
        super().__init__(
            asset,
            device=device,
            grip_anchor_count=grip_anchor_count,
            max_grip_speed=max_grip_speed,
            max_record_frames=max_record_frames,
            simulation_threads=simulation_threads,
        )
        self.realtime = realtime
        self._lock = threading.Lock()  # guards the session's fields; held only briefly
        self._step_lock = threading.Lock()  # one frame computation at a time
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._playing = False
        self._pending_steps = 0

    # ------------------------------------------------------------------------------------------
    # reading

    @property
    def playing(self) -> bool:
        return self._playing

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

    def _on_unstable(self) -> None:  # with self._lock held
        self._playing = False
        self._pending_steps = 0

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
