"""``reconphys simulate``: roll an asset forward, write its trajectory and a video."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from ..errors import InputError
from ..names import RENDER_BACKENDS
from ._common import DEVICE_CHOICES, check_choice, check_resolution, or_list, user_errors

app = typer.Typer()


def _simulate_to(
    asset,
    out: Path,
    frames: int | None,
    render_video: bool,
    device,
    resolution,
    view,
    backend,
    save_gaussians: bool,
    steps: list[dict] | None = None,
) -> dict:
    """Simulate (``steps``: a controller script, run as by ``view --script``; ``frames`` is then
    the total or None for the script's own length) and write trajectory.npz, the mp4 and the
    preview strip into ``out`` (and interaction.json for a script)."""
    from ..render.video import to_uint8, write_mp4, write_strip
    from ..simulate import (
        default_view,
        gaussian_centres,
        render_frames,
        simulate_asset,
        simulate_script,
        write_trajectory,
    )

    started = time.perf_counter()
    recording = None
    if steps is None:
        trajectory = simulate_asset(asset, frames, device, progress=True)
    else:
        trajectory, recording = simulate_script(asset, steps, device, frames)
    sim_seconds = time.perf_counter() - started
    anchors = trajectory.x[0].to(device)  # [T+1, N_A, 3]
    means = gaussian_centres(asset, anchors) if save_gaussians else None
    out.mkdir(parents=True, exist_ok=True)
    write_trajectory(out / "trajectory.npz", trajectory, means)
    summary = {
        "frames": anchors.shape[0] - 1,
        "substeps_used": trajectory.substeps,
        "simulate_seconds": round(sim_seconds, 3),
        "lowest_z_m": float(anchors[..., 2].min()),
    }
    if recording is not None:
        from ..viewer.recording import write_interaction

        write_interaction(out / "interaction.json", recording)
    if render_video:
        camera = default_view(resolution, resolution, view)
        started = time.perf_counter()
        images = to_uint8(render_frames(asset, anchors, camera, backend, progress=True))
        summary["render_seconds"] = round(time.perf_counter() - started, 3)
        write_mp4(out / "simulation.mp4", images, fps=1.0 / asset.physics.frame_dt)
        write_strip(out / "preview.png", images)
    return summary


@app.command()
@user_errors
def simulate(
    asset_dir: Path = typer.Argument(..., help="Asset folder (physics.json, anchors.npz, ...)."),
    frames: int = typer.Option(
        None,
        "--frames",
        help="Frames to simulate (frame_dt each; default 30). With --script: the total, free "
        "after the script (default: the script's own length).",
    ),
    out: Path = typer.Option(..., "--out", help="Output folder for trajectory.npz and the mp4."),
    no_render: bool = typer.Option(False, "--no-render", help="Skip rendering the mp4."),
    device: str = typer.Option("auto", help=f"{DEVICE_CHOICES}."),
    resolution: int = typer.Option(256, help="Video width and height, pixels."),
    view: int = typer.Option(0, help="Dataset view 0–3 (azimuth 0°, 90°, 180°, 270°)."),
    backend: str = typer.Option("auto", help=f"Renderer: {or_list(RENDER_BACKENDS)}."),
    save_gaussians: bool = typer.Option(False, help="Also store Gaussian centres per frame."),
    script: Path = typer.Option(
        None, "--script", help="JSON controller script (grab, move, release, ...; docs/viewer.md)."
    ),
    push: str = typer.Option(
        None,
        "--push",
        help='"X,Y,Z" metres: at frame N/3 grab the side facing away from the push, move it by '
        "X,Y,Z over 10 frames, release (docs/viewer.md).",
    ),
):
    """Simulate an asset: writes OUT/trajectory.npz (anchors [T+1, N_A, 3], substeps_used) and,
    unless --no-render, OUT/simulation.mp4 and OUT/preview.png from a dataset view. --script or
    --push drive it with the viewer's controller (grips) and add OUT/interaction.json."""
    from ..assets.asset import read_asset
    from ..simulate import resolve_device
    from ..viewer.script import load_script, parse_vector, push_script

    if frames is not None and frames < 1:
        raise InputError(f"must be ≥ 1, got {frames}", field="--frames")
    check_resolution(resolution)
    check_choice(backend, RENDER_BACKENDS, "--backend")
    if script is not None and push is not None:
        raise InputError("give --script or --push, not both", field="--push")
    steps = None
    if script is not None:
        steps = load_script(script)
    elif push is not None:
        frames = 30 if frames is None else frames
        steps = push_script(frames, parse_vector(push, "--push"))
    elif frames is None:
        frames = 30
    torch_device = resolve_device(device)
    asset = read_asset(asset_dir)
    try:
        summary = _simulate_to(
            asset,
            out,
            frames,
            not no_render,
            torch_device,
            resolution,
            view,
            backend,
            save_gaussians,
            steps,
        )
    except InputError as e:
        raise InputError(str(e), source=str(asset_dir)) from None
    typer.echo(json.dumps(summary))
