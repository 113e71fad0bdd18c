"""``reconphys simulate`` and the demo: simulate an asset (free or driven by a controller script),
write ``trajectory.npz`` and render the clip. Orchestration only; imported only by the CLI.

The parts live with their owners: the rollout in :meth:`reconphys.assets.asset.Asset.simulate`,
the file in :mod:`reconphys.assets.trajectory`, scripted grips in :mod:`reconphys.interact`, the
frames in :mod:`reconphys.render.sequence` and the camera in
:func:`reconphys.render.cameras.dataset_view`.
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from .assets.asset import Asset
from .assets.trajectory import write_trajectory
from .errors import InputError
from .interact.interaction import Interaction
from .interact.recording import Recording, recording_trajectory, write_interaction
from .interact.script import run_script
from .physics import Trajectory
from .render.cameras import dataset_view
from .render.sequence import render_sequence
from .render.video import to_uint8, write_mp4, write_strip


def simulate_script(
    asset: Asset,
    steps: list[dict],  # a controller script (docs/viewer.md), e.g. from interact.load_script
    device: torch.device,
    num_frames: int | None = None,  # total frames; None: as many as the script simulates
) -> tuple[Trajectory, Recording]:
    """Run a controller script headless from the asset's initial state; returns the trajectory
    (x, v ``[1, T+1, N_A, 3]``, frame 0 = the initial state) and the recording (grip positions).

    The same :class:`~reconphys.interact.Interaction` and
    :func:`~reconphys.interact.script.run_script` as ``reconphys view --script`` (without its
    thread), so grips act through the same controller springs. With ``num_frames``, the object
    runs free after the script until the trajectory has ``num_frames`` frames; a script that
    simulates more is an error. Every frame the script publishes counts, including the state a
    ``drop`` or ``reset`` jumps to.
    """
    # As `view --script` (one simulation thread), without a recording cap.
    interaction = Interaction(asset, device=device, max_record_frames=2**62)
    interaction.start_recording()
    run_script(interaction, steps, record=False)
    recorded = interaction.recorded_frames
    if num_frames is not None:
        if recorded > num_frames:
            raise InputError(
                f"the script simulates {recorded} frames, more than the {num_frames} asked for",
                field="--frames",
            )
        interaction.advance(num_frames - recorded)
        recorded = interaction.recorded_frames
        if recorded != num_frames:
            raise InputError("the simulation became unstable (NaN): raise the substeps")
    recording = interaction.stop_recording()
    return recording_trajectory(recording), recording


def simulate_to_folder(
    asset: Asset,
    out: Path,
    frames: int | None,
    render_video: bool,
    device: torch.device,
    resolution: int,  # video width and height, pixels
    view: int,  # dataset view 0–3
    backend: str,  # renderer
    save_gaussians: bool,
    steps: list[dict] | None = None,
) -> dict:
    """Simulate (``steps``: a controller script, run as by ``view --script``; ``frames`` is then
    the total or None for the script's own length) and write trajectory.npz, the mp4 and the
    preview strip into ``out`` (and interaction.json for a script); returns the printed summary."""
    started = time.perf_counter()
    recording = None
    if steps is None:
        trajectory = asset.simulate(frames, device, progress=True)
    else:
        trajectory, recording = simulate_script(asset, steps, device, frames)
    sim_seconds = time.perf_counter() - started
    anchors = trajectory.x[0].to(device)  # [T+1, N_A, 3]
    means = asset.gaussian_means(anchors) if save_gaussians or render_video else None
    out.mkdir(parents=True, exist_ok=True)
    write_trajectory(out / "trajectory.npz", trajectory, means if save_gaussians else None)
    summary = {
        "frames": anchors.shape[0] - 1,
        "substeps_used": trajectory.substeps,
        "simulate_seconds": round(sim_seconds, 3),
        "lowest_z_m": float(anchors[..., 2].min()),
    }
    if recording is not None:
        write_interaction(out / "interaction.json", recording)
    if render_video:
        camera = dataset_view(resolution, resolution, view)
        started = time.perf_counter()
        images = render_sequence(asset.gaussians, means, camera, backend, progress=True)
        images = to_uint8(images)
        summary["render_seconds"] = round(time.perf_counter() - started, 3)
        write_mp4(out / "simulation.mp4", images, fps=1.0 / asset.physics.frame_dt)
        write_strip(out / "preview.png", images)
    return summary
