"""Commands of the user's path: ``reconphys predict`` and ``reconphys data video`` (docs/usage.md).

Plain functions with typer annotations; :mod:`reconphys.cli` registers them on its app (so they
work the same through the ``reconphys`` script and ``python -m reconphys.cli``).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import typer

from .errors import InputError

TIMING_ORDER = (
    "model_load",
    "decode",
    "gaussians",
    "physics_network",
    "asset_build",
    "refine",
    "write",
    "preview",
)


def predict_command(
    input: Path = typer.Argument(
        ..., help="Video file (mp4/mov/gif/...), folder of frames, or a dataset folder (--sample)."
    ),
    out: Path = typer.Option(..., "--out", help="Asset folder to write (DESIGN §6 + preview)."),
    gaussians: Path = typer.Option(
        None, help="Gaussian PLY of the object (default: predicted from frame 0)."
    ),
    masks: Path = typer.Option(None, help="Folder of object masks, one image per frame."),
    background: Path = typer.Option(None, help="Clean plate image for background subtraction."),
    camera: Path = typer.Option(None, help="Camera JSON (K, world_to_cam, ground_height)."),
    fps: float = typer.Option(None, help="Frame rate of a frame folder (or to override)."),
    sample: str = typer.Option(None, help="Dataset input: the sample id."),
    view: int = typer.Option(None, help="Dataset input: the view (default: the model's)."),
    model: Path = typer.Option(None, help="Physics predictor (default: the shipped model)."),
    geometry: str = typer.Option(
        "auto",
        help="auto (--gaussians, else a dataset's true Gaussians, else the 3DGS predictor) or "
        "predicted (the 3DGS predictor even for a dataset sample).",
    ),
    gs_model: Path = typer.Option(None, help="3DGS predictor (default: the shipped one)."),
    placement: str = typer.Option("auto", help="Given PLY: auto, as-is or fit (to frame 0)."),
    ground: str = typer.Option(
        "camera", help="Ground plane: camera (its file's ground_height, else 0) or landed."
    ),
    anchors: int = typer.Option(None, help="Anchors N_A (default: the model's training data)."),
    refine: int = typer.Option(0, "--refine", help="Test-time refinement steps (0: none)."),
    refine_resolution: int = typer.Option(64, help="Render size of the refinement, pixels."),
    preview_frames: int = typer.Option(60, help="Frames in preview.mp4 (0: no preview)."),
    device: str = typer.Option("auto", help="auto, cpu or cuda."),
    overwrite: bool = typer.Option(False, help="Replace an existing OUT."),
):
    """Predict a simulation-ready asset from one recording of a dropped object: OUT gets the
    asset (gaussians.ply, anchors.npz, binding.npz, physics.json), preview.mp4/.png (observed |
    simulated) and prediction.json (attributes, timings, how each input was read)."""
    from .devices import resolve_device
    from .pipeline.predict import predict, write_outputs

    if out.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"must be a positive frame rate, got {fps}", field="--fps")
    if anchors is not None and anchors < 4:
        raise InputError(f"must be ≥ 4, got {anchors}", field="--anchors")
    if preview_frames < 0:
        raise InputError(f"must be ≥ 0, got {preview_frames}", field="--preview-frames")
    torch_device = resolve_device(device)
    result = predict(
        input,
        gaussians=gaussians,
        masks=masks,
        background=background,
        camera=camera,
        fps=fps,
        sample=sample,
        view=view,
        model=model,
        geometry=geometry,
        gs_model=gs_model,
        placement=placement,
        ground=ground,
        num_anchors=anchors,
        refine_steps=refine,
        refine_resolution=refine_resolution,
        device=torch_device,
        progress=True,
    )
    summary = write_outputs(result, out, overwrite, preview_frames, torch_device)
    attributes = summary["attributes"]
    typer.echo(
        f"wrote {out}: mass {attributes['mass']:.3g} kg/anchor, stiffness "
        f"{attributes['stiffness']:.4g}, damping {attributes['damping']:.3g}, friction "
        f"{attributes['friction']:.2f} ({summary['anchors']} anchors, {summary['gaussians']} "
        f"Gaussians; geometry: {summary['geometry']})"
    )
    if "refine" in summary:
        r = summary["refine"]
        typer.echo(
            f"refine: {r['steps']} steps in {r['seconds']} s, photometric loss "
            f"{r['loss_initial']:.3g} → {r['loss_best']:.3g} (best at step {r['best_step']})"
        )
    timings = summary["timings_s"]
    parts = [f"{k} {timings[k]:.3f}" for k in TIMING_ORDER if k in timings]
    typer.echo("seconds: " + ", ".join(parts))


def data_video(
    root: Path = typer.Argument(..., help="Dataset folder."),
    sample: str = typer.Argument(..., help="Sample id (see manifest.json)."),
    out: Path = typer.Argument(..., help="Folder to write video.mp4, camera.json, gaussians.ply."),
    view: int = typer.Option(0, help="View 0–3."),
    overwrite: bool = typer.Option(False, help="Replace an existing folder."),
):
    """Write one sample as a user would bring it to `reconphys predict`: its encoded video
    (view_V.mp4), the camera file and the object's Gaussians placed as in frame 0."""
    import tempfile

    from .assets.ply import write_ply
    from .capture import CameraSpec, write_camera
    from .data.dataset import DropDataset
    from .data.storage import video_name

    if not 0 <= view < 4:
        raise InputError(f"expected 0–3, got {view}", field="--view")
    if out.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))
    dataset = DropDataset(root, views=[view], allow_incomplete=True, verify=False)
    index = dataset.index_of(sample)
    meta = dataset.samples[index]
    video = root / meta["dir"] / video_name(view)
    if not video.is_file():
        raise InputError("the sample's video is missing", source=str(video))
    item = dataset[index]
    height, width = item["frames"].shape[2:4]
    camera = CameraSpec(item["K"][0].double(), item["world_to_cam"][0].double(), width, height)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        shutil.copyfile(video, staging / "video.mp4")
        write_camera(staging / "camera.json", camera)
        write_ply(staging / "gaussians.ply", dataset.asset(index).gaussians)
        (staging / "truth.json").write_text(
            json.dumps({"sample": sample, "view": view, **meta["attributes"]}, indent=1) + "\n"
        )
        staging.chmod(0o755)  # mkdtemp makes it 0700
        if out.exists():
            shutil.rmtree(out)
        staging.replace(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    typer.echo(f"wrote {out}: video.mp4, camera.json, gaussians.ply, truth.json")


def train_gs_command(
    data: Path = typer.Option(..., "--data", help="Dataset folder written by make-data."),
    out: Path = typer.Option(..., "--out", help="Output folder (resumes when run again)."),
    steps: int = typer.Option(2000, help="Optimiser steps."),
    batch_size: int = typer.Option(4, help="Samples per step."),
    lr: float = typer.Option(1e-3, help="Peak learning rate (cosine to 10 %)."),
    silhouette_weight: float = typer.Option(1.0, help="Weight of the alpha-vs-mask loss."),
    checkpoint_every: int = typer.Option(200, help="Steps between checkpoints."),
    seed: int = typer.Option(0, help="Seed of the initialisation and the batches."),
    threads: int = typer.Option(2, help="CPU threads (torch)."),
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
):
    """Train the feed-forward 3DGS predictor (first frame → one Gaussian per object pixel) on
    frame 0 of a dataset's four views; writes OUT/model.safetensors + model.json."""
    from .threads import set_cpu_threads
    from .train.gaussians import GaussianTrainSettings, train_gaussian_predictor

    for name, value in (
        ("--steps", steps),
        ("--batch-size", batch_size),
        ("--checkpoint-every", checkpoint_every),
        ("--threads", threads),
    ):
        if value < 1:
            raise InputError(f"must be ≥ 1, got {value}", field=name)
    if not (math.isfinite(lr) and lr > 0):
        raise InputError(f"must be a positive number, got {lr}", field="--lr")
    if not data.is_dir():
        raise InputError("dataset folder not found", source=str(data))
    set_cpu_threads(threads)
    settings = GaussianTrainSettings(
        data=str(data),
        out=str(out),
        steps=steps,
        batch_size=batch_size,
        lr=lr,
        silhouette_weight=silhouette_weight,
        seed=seed,
        checkpoint_every=checkpoint_every,
    )
    train_gaussian_predictor(settings, progress=not no_progress, log=typer.echo)
    typer.echo(f"wrote {out / 'model.safetensors'}")
