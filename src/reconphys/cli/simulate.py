"""``reconphys simulate``: roll an asset forward, write its trajectory and a video."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ..errors import InputError
from ..names import RENDER_BACKENDS
from ._common import DEVICE_CHOICES, check_choice, check_resolution, or_list, user_errors

app = typer.Typer()


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
    from ..devices import resolve_device
    from ..interact.script import load_script, parse_vector, push_script
    from ..simulate import simulate_to_folder

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
        summary = simulate_to_folder(
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
