"""``reconphys view``: the interactive viewer, or its controls from a script (docs/viewer.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import InputError
from ._common import DEVICE_CHOICES, check_resolution, user_errors

app = typer.Typer()


@app.command()
@user_errors
def view(
    asset_dir: Path = typer.Argument(..., help="Asset folder to manipulate."),
    port: int = typer.Option(8080, help="Port of the web viewer."),
    host: str = typer.Option("127.0.0.1", help="Interface to listen on (0.0.0.0: all)."),
    device: str = typer.Option("auto", help=f"Simulation device: {DEVICE_CHOICES}."),
    substeps: int = typer.Option(None, help="Substeps per frame (never below stability)."),
    paused: bool = typer.Option(False, "--paused", help="Start paused."),
    record_dir: Path = typer.Option(Path("recordings"), help="Where recordings are saved."),
    script: Path = typer.Option(None, help="Run this JSON action script headless instead."),
    out: Path = typer.Option(None, help="Output folder of --script (trajectory, mp4)."),
    resolution: int = typer.Option(256, help="Video size of --script, pixels."),
    benchmark: int = typer.Option(0, help="Time this many frames headless, print, exit."),
):
    """Open ASSET in a browser viewer: live simulation; drop, grab, squeeze and stretch it
    (needs the `viewer` extra). With --script: the same controls, headless, from a file."""
    from ..assets.asset import read_asset
    from ..devices import resolve_device
    from ..viewer.command import view_command

    if not 0 <= port < 65536:
        raise InputError(f"must be a port number 0–65535, got {port}", field="--port")
    check_resolution(resolution)
    if substeps is not None and substeps < 1:
        raise InputError(f"must be ≥ 1, got {substeps}", field="--substeps")
    torch_device = resolve_device(device)
    asset = read_asset(asset_dir)
    view_command(
        asset, torch_device, host, port, substeps, paused, record_dir, script, out, resolution,
        benchmark, echo=typer.echo,
    )  # fmt: skip
