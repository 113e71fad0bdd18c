"""The browser UI: a viser web app on top of :class:`~reconphys.viewer.session.ViewerSession`.

The browser draws the asset's 3D Gaussians itself (viser's WebGL Gaussian-splat renderer, sorted in
the browser), so the server only sends new Gaussian centres after each simulated frame (32 bytes
per Gaussian): no server-side rendering, which on a CPU would cost far more than the simulation.

Three threads: viser's (GUI callbacks only change the session's inputs, briefly), the session's
simulation loop, and a display loop here that sends the latest published state to the browser at
most ``display_rate`` times per second, skipping frames when the browser is slower. Nothing the UI
does waits for a simulation frame.

viser is an optional dependency (``pip install 'reconphys[viewer]'``); it is imported only when
a :class:`ViewerApp` is made.

Why one module of ~500 lines: it is one object, the web page, whose GUI callbacks, scene handles
and display thread share the page's state; the simulation it shows lives below it
(:mod:`reconphys.interact`, :mod:`reconphys.physics.control`), so nothing here is physics.
"""

from __future__ import annotations

import math
import threading
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import torch

from ..assets.gaussians import Gaussians
from ..errors import InputError
from ..geometry import quaternion_to_matrix
from ..render import Cameras, intrinsics_from_fov
from .session import ViewerSession

GRIP_SLOTS = ("grip 1", "grip 2")
GRIP_COLORS = {"grip 1": (230, 60, 60), "grip 2": (60, 110, 235)}
MAX_SPRINGS_SHOWN = 8000  # the spring overlay draws every n-th spring above this count
# Keyboard moves of the active grip (viser command-palette hotkeys): key → direction.
KEY_MOVES = {
    "J": (-1.0, 0.0, 0.0),
    "L": (1.0, 0.0, 0.0),
    "K": (0.0, -1.0, 0.0),
    "I": (0.0, 1.0, 0.0),
    "U": (0.0, 0.0, -1.0),
    "O": (0.0, 0.0, 1.0),
}


def require_viser():
    """Import viser or explain how to install it (one line, for the CLI)."""
    try:
        import viser
    except ImportError:
        raise InputError(
            "the browser viewer needs viser, which is not installed: "
            "pip install 'reconphys[viewer]' (or: pip install viser)",
            field="viser",
        ) from None
    return viser


def splat_arrays(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """The Gaussians as viser's splat renderer takes them: centers [N, 3], covariances
    [N, 3, 3] (R diag(s²) Rᵀ, metres²), rgbs [N, 3] in [0, 1], opacities [N, 1]."""
    with torch.no_grad():
        rotation = quaternion_to_matrix(gaussians.quats.float())
        scales = gaussians.scales.float()
        covariance = rotation @ torch.diag_embed(scales * scales) @ rotation.transpose(-1, -2)
        return {
            "centers": gaussians.means.float().cpu().numpy(),
            "covariances": covariance.cpu().numpy(),
            "rgbs": gaussians.colors.float().cpu().numpy(),
            "opacities": gaussians.opacities.float().cpu().numpy()[:, None],
        }


def camera_from_viser(
    position,  # [3] camera centre, world frame, metres
    wxyz,  # [4] camera-to-world rotation (OpenCV camera axes, as viser uses)
    fov: float,  # vertical field of view, radians
    aspect: float,  # width / height
    height: int,  # pixels of the rendered image
) -> Cameras:
    """A browser's camera as a one-camera :class:`~reconphys.render.Cameras`
    (docs/design.md#conventions)."""
    width = max(8, 2 * round(height * aspect / 2))
    rotation = quaternion_to_matrix(torch.tensor(wxyz, dtype=torch.float64))
    centre = torch.tensor(position, dtype=torch.float64)
    world_to_cam = torch.eye(4, dtype=torch.float64)
    world_to_cam[:3, :3] = rotation.T
    world_to_cam[:3, 3] = -rotation.T @ centre
    K = intrinsics_from_fov(math.degrees(fov), width, height, dtype=torch.float64)
    return Cameras(K[None].float(), world_to_cam[None].float(), width, height)


class ViewerApp:
    """A viser server showing ``session`` (call :meth:`start`, then :meth:`close`).

    ``record_dir``: recordings go to ``record_dir/<date-time>/`` (trajectory.npz,
    interaction.json, interaction.mp4).
    """

    def __init__(
        self,
        session: ViewerSession,
        host: str = "127.0.0.1",
        port: int = 8080,
        record_dir: str | Path = "recordings",
        display_rate: float = 30.0,
        verbose: bool = False,
    ):
        viser = require_viser()
        self.session = session
        self.record_dir = Path(record_dir)
        self.display_rate = float(display_rate)
        try:
            self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        except OSError as e:
            message = f"cannot listen on {host}:{port} ({e.strerror or e})"
            raise InputError(message, field="--port") from None
        self.port = self.server.get_port()
        self.host = host
        self._closed = threading.Event()
        self._display_thread: threading.Thread | None = None
        # refresh() runs on the display thread and from UI callbacks: one at a time, or two
        # could both create a grip's nodes and the second would remove the first's handles
        self._refresh_lock = threading.RLock()
        self._armed = False  # the next click on the object makes a grip
        self._dragging: set[str] = set()  # grips whose gizmo the user is dragging
        self._grip_nodes: dict[str, dict] = {}
        self._last_version = -1  # session version last sent to the browsers
        asset = session.asset
        self._springs = asset.springs[:: max(1, asset.springs.shape[0] // MAX_SPRINGS_SHOWN)]
        self._build_scene()
        self._build_gui()

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "") else self.host
        return f"http://{host}:{self.port}"

    # ------------------------------------------------------------------------------------------
    # scene

    def _build_scene(self) -> None:
        scene = self.server.scene
        asset = self.session.asset
        scene.set_up_direction("+z")
        means = self.session.gaussian_means()
        centre = means.mean(0).numpy()
        size = float((means.amax(0) - means.amin(0)).max())
        distance = 0.2 + 1.7 * size  # metres from the object's centre
        look_at = (float(centre[0]), float(centre[1]), 0.5 * float(centre[2]))
        self.server.initial_camera.look_at = look_at
        self.server.initial_camera.position = (
            look_at[0] + 0.75 * distance,
            look_at[1] - 0.45 * distance,
            look_at[2] + 0.5 * distance,
        )
        ground = asset.physics.ground_height
        scene.add_grid(
            "/ground", width=3.0, height=3.0, cell_size=0.1, section_size=0.5,
            position=(0.0, 0.0, ground),
        )  # fmt: skip
        arrays = splat_arrays(asset.gaussians)
        arrays["centers"] = means.numpy()
        self._splats = scene.add_gaussian_splats("/object", **arrays)
        self._anchors = scene.add_point_cloud(
            "/overlay/anchors",
            points=self.session.anchor_positions().numpy(),
            colors=(255, 170, 0),
            point_size=0.008,
            point_shape="circle",
            visible=False,
        )
        self._spring_lines = scene.add_line_segments(
            "/overlay/springs",
            points=self._spring_points(self.session.anchor_positions()),
            colors=(120, 200, 255),
            thickness=1.0,
            thickness_units="screen",
            visible=False,
        )
        scene.on_click()(self._on_click)
        scene.on_click(modifier="shift")(self._on_click)

    def _spring_points(self, anchors: torch.Tensor) -> np.ndarray:  # [E', 2, 3]
        return anchors[self._springs].numpy()

    # ------------------------------------------------------------------------------------------
    # GUI

    def _build_gui(self) -> None:
        """The side panel, top to bottom: status, play/step/reset, drop height, the four
        attributes and substeps, grips, recording, help; each control's callback only changes the
        session's inputs (the simulation thread does the work)."""
        gui = self.server.gui
        session = self.session
        gui.configure_theme(control_width="medium", dark_mode=False, show_share_button=False)
        self._status = gui.add_markdown("starting…")

        with gui.add_folder("Simulation"):
            self._play = gui.add_button("Play", icon="player-play")
            self._play.on_click(lambda _: self._toggle_play())
            step = gui.add_button("Step one frame", icon="player-skip-forward")
            step.on_click(lambda _: session.request_step(1))
            reset = gui.add_button("Reset to the asset's initial state", icon="refresh")
            reset.on_click(lambda _: session.reset())
            realtime = gui.add_checkbox("Real-time pacing", initial_value=session.realtime)
            realtime.on_update(lambda _: setattr(session, "realtime", realtime.value))

        with gui.add_folder("Drop"):
            height = gui.add_slider("Height (m)", min=0.0, max=1.5, step=0.01, initial_value=0.3)
            drop = gui.add_button("Drop from this height", icon="arrow-down")
            drop.on_click(lambda _: session.drop(height.value))

        with gui.add_folder("Physics"):
            self._attribute_sliders = {}
            values = session.attributes
            ranges = {
                "mass": ("Mass per anchor (kg)", 0.05, 10.0, 0.05),
                "stiffness": ("Stiffness k (N/strain)", 1.0, 3000.0, 1.0),
                "damping": ("Damping d (N·s/strain)", 0.0, 20.0, 0.05),
                "friction": ("Friction f", 0.0, 2.0, 0.01),
            }
            for name, (label, low, high, step_size) in ranges.items():
                value = values[name]
                slider = gui.add_slider(
                    label, min=min(low, value), max=max(high, value), step=step_size,
                    initial_value=value,
                )  # fmt: skip
                slider.on_update(self._attribute_callback(name, slider))
                self._attribute_sliders[name] = slider
            self._substeps = gui.add_slider(
                "Substeps per frame", min=1, max=400, step=1,
                initial_value=min(400, session.status().requested_substeps),
                hint="Never below the stability bound of the current attributes.",
            )  # fmt: skip
            self._substeps.on_update(lambda _: session.set_substeps(int(self._substeps.value)))
            fastest = gui.add_button("Fewest stable substeps (fastest)", icon="bolt")
            fastest.on_click(lambda _: setattr(self._substeps, "value", 1))

        with gui.add_folder("Grab"):
            gui.add_markdown(
                "Press **Grab**, then click the object (or shift-click it any time). Drag the "
                "gizmo to move the grip; keys **J/L** (x), **K/I** (y), **U/O** (z) move the "
                "active grip. Two grips stretch or squeeze the object."
            )
            grab = gui.add_button("Grab: click the object", icon="hand-grab")
            grab.on_click(lambda _: self._arm())
            self._active = gui.add_dropdown("Active grip (keys)", GRIP_SLOTS)
            self._key_step = gui.add_slider(
                "Key step (cm)", min=0.5, max=10.0, step=0.5, initial_value=2.0
            )
            for slot in GRIP_SLOTS:
                button = gui.add_button(f"Release {slot}")
                button.on_click(lambda _, slot=slot: self._release(slot))
            release_all = gui.add_button("Release all")
            release_all.on_click(lambda _: session.release_all())
            for key, direction in KEY_MOVES.items():
                command = gui.add_command(f"Move active grip {direction}", hotkey=key)
                command.on_trigger(lambda _, d=direction: self._nudge(d))

        with gui.add_folder("Display"):
            self._show_gaussians = gui.add_checkbox("Gaussians", initial_value=True)
            self._show_anchors = gui.add_checkbox("Anchors", initial_value=False)
            self._show_springs = gui.add_checkbox(
                "Springs", initial_value=False,
                hint=f"At most {MAX_SPRINGS_SHOWN} springs are drawn (every n-th).",
            )  # fmt: skip
            for box in (self._show_gaussians, self._show_anchors, self._show_springs):
                box.on_update(lambda _: self._apply_visibility())

        with gui.add_folder("Record"):
            self._record_view = gui.add_dropdown(
                "Video camera", ("my browser view", "dataset view 0")
            )
            self._record_height = gui.add_slider(
                "Video height (px)", min=64, max=720, step=16, initial_value=256
            )
            self._record = gui.add_button("Start recording", icon="player-record")
            self._record.on_click(self._toggle_record)
            self._record_status = gui.add_markdown(f"Saved under `{self.record_dir}/`.")

    def _attribute_callback(self, name, slider):
        def update(_):
            try:
                self.session.set_attributes(**{name: float(slider.value)})
            except InputError as e:
                self.session.notify(str(e))

        return update

    def _toggle_play(self) -> None:
        self._show_playing(self.session.toggle())

    def _show_playing(self, playing: bool) -> None:
        label = "Pause" if playing else "Play"
        if self._play.label != label:
            self._play.label = label
            self._play.icon = "player-pause" if playing else "player-play"

    def _apply_visibility(self) -> None:
        self._splats.visible = self._show_gaussians.value
        self._anchors.visible = self._show_anchors.value
        self._spring_lines.visible = self._show_springs.value
        self._last_version = -1  # redraw the overlays now

    # ------------------------------------------------------------------------------------------
    # grabbing

    def _arm(self) -> None:
        free = [slot for slot in GRIP_SLOTS if slot not in self.session.grips()]
        if not free:
            self.session.notify("both grips are in use: release one first")
            return
        self._armed = True
        self.session.notify(f"click the object to place {free[0]}")

    def _on_click(self, event) -> None:
        if not (self._armed or event.modifier == "shift"):
            return
        self._armed = False
        point = self.session.pick(event.ray_origin, event.ray_direction)
        if point is None:
            self.session.notify("missed the object: press Grab and click on it")
            return
        self.grab(point)

    def grab(self, point) -> str | None:
        """Place a grip at ``point`` [3] in the first free slot (what a click does)."""
        free = [slot for slot in GRIP_SLOTS if slot not in self.session.grips()]
        if not free:
            self.session.notify("both grips are in use: release one first")
            return None
        name = self.session.grab(point, name=free[0])
        self._active.value = name
        return name

    def _release(self, slot: str) -> None:
        if slot in self.session.grips():
            self.session.release(slot)

    def _nudge(self, direction) -> None:
        name = self._active.value
        if name not in self.session.grips():
            self.session.notify(f"{name} is not placed: press Grab and click the object")
            return
        step = self._key_step.value / 100.0
        self.session.nudge_grip(name, [step * c for c in direction])

    def _sync_grips(self) -> None:
        """Make the grip markers and gizmos match the session's grips."""
        scene = self.server.scene
        grips = self.session.grips()
        for name in list(self._grip_nodes):
            if name not in grips:
                for node in self._grip_nodes.pop(name).values():
                    node.remove()
                self._dragging.discard(name)
        anchors = None
        for name, grip in grips.items():
            slot = name.replace(" ", "_")
            nodes = self._grip_nodes.get(name)
            goal = grip["goal"].numpy()
            if nodes is None:
                color = GRIP_COLORS.get(name, (230, 60, 200))
                handle = scene.add_transform_controls(
                    f"/grips/{slot}/handle", scale=0.15, disable_rotations=True,
                    position=tuple(goal),
                )  # fmt: skip
                handle.on_update(self._gizmo_callback(name))
                nodes = {
                    "handle": handle,
                    "marker": scene.add_icosphere(
                        f"/grips/{slot}/controller", radius=0.012, color=color
                    ),
                    "links": scene.add_line_segments(
                        f"/grips/{slot}/links",
                        points=np.zeros((1, 2, 3), np.float32),
                        colors=color,
                        thickness=1.5,
                        thickness_units="screen",
                    ),
                }
                self._grip_nodes[name] = nodes
            position = grip["position"].numpy()
            nodes["marker"].position = tuple(position)
            if anchors is None:
                anchors = self.session.anchor_positions()
            held = anchors[grip["anchors"]].numpy()
            nodes["links"].points = np.stack([np.broadcast_to(position, held.shape), held], 1)
            if name not in self._dragging and np.abs(nodes["handle"].position - goal).max() > 1e-4:
                nodes["handle"].position = tuple(goal)  # moved by keys: follow

    def _gizmo_callback(self, name: str):
        def update(event) -> None:
            if event.phase == "start":
                self._dragging.add(name)
            elif event.phase == "end":
                self._dragging.discard(name)
            if name in self.session.grips():
                self.session.move_grip(name, np.asarray(event.target.position, dtype=np.float32))

        return update

    # ------------------------------------------------------------------------------------------
    # recording

    def _toggle_record(self, event) -> None:
        session = self.session
        if not session.recording:
            session.start_recording()
            self._record.label = "Stop and save"
            self._record_status.content = "Recording…"
            return
        recording = session.stop_recording()
        self._record.label = "Start recording"
        camera = None
        height = int(self._record_height.value)
        if self._record_view.value == "my browser view" and event.client is not None:
            c = event.client.camera
            camera = camera_from_viser(c.position, c.wxyz, c.fov, c.aspect, height)
        folder = self.record_dir / datetime.now().strftime("%Y%m%d-%H%M%S")
        threading.Thread(
            target=self._save_recording, args=(recording, folder, camera, height), daemon=True
        ).start()

    def _save_recording(self, recording, folder: Path, camera, height: int) -> None:
        from ..interact.recording import write_recording

        frames = recording.anchors.shape[0]

        def progress(done: int, total: int) -> None:
            self._record_status.content = f"Rendering {done}/{total} frames…"

        self._record_status.content = f"Rendering {frames} frames…"
        try:
            paths = write_recording(
                self.session.asset, recording, folder, camera=camera, resolution=height,
                device=self.session.device, progress=progress,
            )  # fmt: skip
            self._record_status.content = f"Saved `{paths['video']}` ({frames} frames)."
        except Exception as e:  # show it; the viewer keeps running
            self._record_status.content = f"Saving failed: {e}"

    # ------------------------------------------------------------------------------------------
    # display loop

    def start(self) -> None:
        """Start the simulation loop and the display loop (both background threads)."""
        self.session.start()
        if self._display_thread is None:
            self._display_thread = threading.Thread(
                target=self._display_loop, name="reconphys-display", daemon=True
            )
            self._display_thread.start()

    def close(self) -> None:
        self._closed.set()
        if self._display_thread is not None:
            self._display_thread.join(timeout=10)
            self._display_thread = None
        self.session.close()
        self.server.stop()

    def __enter__(self) -> ViewerApp:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _display_loop(self) -> None:
        next_status = 0.0
        while not self._closed.is_set():
            started = time.perf_counter()
            version = self.session.version
            if version != self._last_version:
                self._last_version = version
                self.refresh()
            if started >= next_status:
                self._status.content = status_markdown(self.session)
                self._show_playing(self.session.playing)
                next_status = started + 0.25
            self._closed.wait(max(0.0, 1.0 / self.display_rate - (time.perf_counter() - started)))

    def refresh(self) -> None:
        """Send the latest simulated state to the browsers (thread-safe)."""
        with self._refresh_lock:
            self._refresh()

    def _refresh(self) -> None:
        if self._splats.visible:
            self._splats.centers = self.session.gaussian_means().numpy()
        if self._anchors.visible or self._spring_lines.visible:
            anchors = self.session.anchor_positions()
            if self._anchors.visible:
                self._anchors.points = anchors.numpy()
            if self._spring_lines.visible:
                self._spring_lines.points = self._spring_points(anchors)
        self._sync_grips()


def status_markdown(session: ViewerSession) -> str:
    """The status panel: simulated time, simulation speed, substeps, notices."""
    s = session.status()
    state = "playing" if s.playing else "paused"
    speed = "simulation speed: not measured yet"
    if s.frames_per_second:
        capacity = s.frames_per_second * session.frame_dt
        speed = f"simulation {s.frames_per_second:.1f} frames/s = {capacity:.2f}× real time"
        if s.playing and session.realtime and capacity > 1:
            speed += " (paced to 1×)"
    lines = [
        f"**{state}** · frame {s.frame} · t = {s.time:.2f} s",
        speed,
        f"substeps {s.substeps} per frame (stability bound {s.stable_substeps})",
        f"max speed {s.max_speed:.2f} m/s · lowest anchor z = {s.lowest_z:.3f} m",
    ]
    if s.recording_frames is not None:
        lines.append(f"● recording: {s.recording_frames} frames")
    if s.message:
        lines.append(f"_{s.message}_")
    return "  \n".join(lines)
