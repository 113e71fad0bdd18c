"""Command line: ``reconphys make-asset | inspect | export | demo | simulate | make-data | data
show|merge|export|video | view | evaluate | train | train-gs | predict`` (one module per group).

User errors (missing or corrupt files, bad shapes, NaN, unstable attributes) print one line,
``error: <input>: <what is wrong>``, and exit with status 2; no partial output is left behind.
Every command imports the package's torch code inside its body, so ``reconphys --help`` does not
load torch.
"""

from __future__ import annotations

import sys

import typer

from .. import __version__
from . import asset, data, demo, evaluate, predict, simulate, train, view

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Build and simulate simulation-ready assets (3D Gaussians + spring-mass physics).",
)


def _version(value: bool):
    if value:
        typer.echo(f"reconphys {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
):
    """reconphys: one video of a dropped object → a simulation-ready asset."""
    import torch

    # Settling objects drive velocities into float32 denormals, which are very slow on CPUs.
    torch.set_flush_denormal(True)


for module in (demo, asset, simulate, data, view, evaluate, train, predict):
    app.add_typer(module.app)
app.add_typer(data.data_app, name="data")


def main() -> None:
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)
