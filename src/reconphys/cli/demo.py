"""``reconphys demo``: the main job on a shipped recording, video → asset (docs/usage.md#the-demo).

The default reads ``examples/duck_toss_scene`` (a realistic scene) with ``predict``'s default
path and writes OUT/asset, OUT/preview.mp4, OUT/contact_sheet.png, OUT/prediction.json and
OUT/summary.md. ``--example duck_toss`` is the same toss in the plain look; ``--example
procedural`` is the older demo: build a procedural object and drop it (no video involved).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import typer

from ..errors import InputError
from ._common import DEVICE_CHOICES, user_errors

app = typer.Typer()

PROCEDURAL = "procedural"
DEMO_MARKERS = ("summary.md", "simulation.mp4")  # files only a demo writes into OUT


def _check_out(out: Path, overwrite: bool) -> None:
    """A demo replaces an earlier demo's OUT, never another folder unless --overwrite."""
    if not out.exists() or overwrite:
        return
    if not out.is_dir():
        raise InputError("exists and is not a folder (use --overwrite to replace it)", str(out))
    entries = list(out.iterdir())
    if entries and not any((out / name).exists() for name in DEMO_MARKERS):
        raise InputError("exists and is not a demo's output (use --overwrite to replace it)",
                         str(out), "--out")  # fmt: skip


@app.command()
@user_errors
def demo(
    out: Path = typer.Option(
        Path("demo_out"), help="Output folder (an earlier demo's is replaced)."
    ),
    example: str = typer.Option(
        None, help="A shipped recording (see --list; default duck_toss_scene), or 'procedural'."
    ),
    list_examples: bool = typer.Option(False, "--list", help="List the examples and exit."),
    refine: bool = typer.Option(
        True, "--refine/--no-refine", help="predict's batched search (--no-refine: < 1 s)."
    ),
    overwrite: bool = typer.Option(False, help="Replace OUT even if it is not a demo's output."),
    device: str = typer.Option("auto", help=f"{DEVICE_CHOICES}."),
    shape: str = typer.Option("bunny", help="procedural: the shape."),
    frames: int = typer.Option(50, help="procedural: frames to simulate (0.03 s each)."),
    resolution: int = typer.Option(256, help="procedural: video size, pixels."),
    num_gaussians: int = typer.Option(12000, help="procedural: Gaussians of the object."),
    num_anchors: int = typer.Option(2048, help="procedural: anchors N_A."),
    seed: int = typer.Option(0, help="procedural: seed for the shape and orientation."),
):
    """Run the main job on a shipped recording: video → simulation-ready asset, with a preview,
    a contact sheet and summary.md (the answer beside the truth). ``--example procedural`` builds
    a procedural object and drops it instead."""
    from ..pipeline.demo import DEFAULT_EXAMPLE, example_names, load_example

    if list_examples:
        for name in example_names():
            typer.echo(f"{name:<12} {load_example(name).truth.get('description', '')}")
        typer.echo(f"{PROCEDURAL:<12} a procedural shape built and dropped (no video)")
        return
    _check_out(out, overwrite)
    from ..devices import resolve_device

    torch_device = resolve_device(device)
    if example == PROCEDURAL:
        _procedural(out, shape, frames, resolution, num_gaussians, num_anchors, seed, torch_device)
        return
    _recording(load_example(example or DEFAULT_EXAMPLE), out, refine, torch_device)


def _recording(example, out: Path, refine: bool, device) -> None:
    from ..io import atomic_folder
    from ..pipeline.demo import FUTURE_FRAMES, summary_markdown
    from ..pipeline.predict import predict, write_outputs

    started = time.perf_counter()
    typer.echo(f"reading {example.video} with reconphys predict (no PLY, no ground truth) …")
    result = predict(
        example.video, camera=example.camera, refine=refine, device=device, progress=True
    )
    with atomic_folder(out, overwrite=True) as staging:
        preview = result.observation.num_frames + FUTURE_FRAMES
        prediction = write_outputs(result, staging / "asset", preview_frames=preview, device=device)
        os.replace(staging / "asset" / "preview.mp4", staging / "preview.mp4")
        os.replace(staging / "asset" / "preview.png", staging / "contact_sheet.png")
        os.replace(staging / "asset" / "prediction.json", staging / "prediction.json")
        summary = summary_markdown(example, prediction, time.perf_counter() - started, out)
        (staging / "summary.md").write_text(summary)
    typer.echo(summary)
    files = ("asset/", "preview.mp4", "contact_sheet.png", "prediction.json", "summary.md")
    typer.echo(f"wrote {out}: " + ", ".join(files))


def _procedural(out, shape, frames, resolution, num_gaussians, num_anchors, seed, device) -> None:
    from ..assets.asset import PhysicsSettings, read_asset, write_asset
    from ..assets.build import place_for_drop
    from ..assets.procedural import make_procedural_gaussians
    from ..io import atomic_folder
    from ..simulate import simulate_to_folder

    started = time.perf_counter()
    gaussians = make_procedural_gaussians(shape, num_gaussians, seed=seed)
    physics = PhysicsSettings(
        mass=1.0,
        stiffness=250.0,
        damping=1.0,
        friction=0.6,
        num_anchors=num_anchors,
        object_id=f"demo-{shape}-{seed}",
    )
    asset = place_for_drop(gaussians, 0.35, seed, physics, angular_velocity=(1.5, -2.0, 0.5))
    with atomic_folder(out, overwrite=True) as staging:
        write_asset(asset, staging / "asset")
        typer.echo(
            f"asset: {out / 'asset'} ({asset.gaussians.num_gaussians} Gaussians, "
            f"{asset.num_anchors} anchors, {asset.springs.shape[0]} springs) in "
            f"{time.perf_counter() - started:.1f} s"
        )
        # simulate what was written: the file format is the contract
        asset = read_asset(staging / "asset")
        summary = simulate_to_folder(
            asset, staging, frames, True, device, resolution, 0, "auto", False
        )
    typer.echo(json.dumps(summary))
    typer.echo(f"video: {out / 'simulation.mp4'}   preview: {out / 'preview.png'}")
