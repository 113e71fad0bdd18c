"""Training commands: ``train`` (the physics predictor), ``train-gs`` (the 3DGS predictor), both
reading a config file into their settings dataclass (docs/training.md, docs/usage.md), and
``train-masks`` (the mask segmenter, docs/usage.md#masks-without-a-clean-plate), ``segment-data``
(its masks of a dataset, to train on)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import typer

from ..errors import InputError
from ._common import given_options, user_errors

app = typer.Typer()


@app.command("train")
@user_errors
def train(
    config: Path = typer.Argument(..., help="Config file (.toml or .json): see configs/."),
    overrides: list[str] = typer.Argument(
        None, help="KEY=VALUE overrides with dotted keys, e.g. optim.lr=3e-4 train.steps=200."
    ),
    overwrite: bool = typer.Option(
        False, help="Start again: remove OUT's checkpoint, logs and model instead of resuming."
    ),
    progress: bool = typer.Option(True, help="Show a progress bar (else a line per log_every)."),
):
    """Train the physics predictor: self-supervised (photometric loss through simulator and
    renderer), supervised or mixed. Resumes from OUT/checkpoint.pt when there is one; runs
    under torchrun for DDP. Writes OUT/log.jsonl, OUT/checkpoint.pt, OUT/model.safetensors and
    OUT/model.json (OUT = train.out)."""
    from ..train.config import load_config
    from ..train.trainer import train as run_training

    settings = load_config(config, overrides or [])
    result = run_training(settings, overwrite=overwrite, progress=progress, log=typer.echo)
    if int(os.environ.get("RANK", "0")) != 0:
        return  # under torchrun: rank 0 reports
    if result.records or result.first_step == 1:
        last = result.records[-1] if result.records else {}
        typer.echo(
            f"trained {result.step} steps ({result.seconds:.0f} s in total), final loss "
            f"{last.get('loss', float('nan')):.5g}: {result.out / 'model.safetensors'}"
        )
    else:
        typer.echo(f"{result.out} already has {result.step} steps (train.steps); nothing to do")


# train-gs options that are fields of GaussianTrainSettings (the rest: how the run is executed)
GS_SETTINGS = (
    "data",
    "out",
    "steps",
    "batch_size",
    "lr",
    "silhouette_weight",
    "shape_weight",
    "depth_weight",
    "checkpoint_every",
    "seed",
    "init",
)


@app.command("train-gs")
@user_errors
def train_gs(
    ctx: typer.Context,
    data: Path = typer.Option(
        None, "--data", help="Dataset folder written by make-data (required; or data in --config)."
    ),
    out: Path = typer.Option(
        None, "--out", help="Output folder (resumes when run again; required; or out in --config)."
    ),
    steps: int = typer.Option(2000, help="Optimiser steps."),
    batch_size: int = typer.Option(4, help="Samples per step."),
    lr: float = typer.Option(1e-3, help="Peak learning rate (cosine to 10 %)."),
    silhouette_weight: float = typer.Option(1.0, help="Weight of the alpha-vs-mask loss."),
    shape_weight: float = typer.Option(
        0.0, help="Weight of the shape term: predicted centres to the true ones (0: off)."
    ),
    depth_weight: float = typer.Option(
        0.0, help="Weight of the depth term: rendered depth to the true one, 4 views (0: off)."
    ),
    checkpoint_every: int = typer.Option(200, help="Steps between checkpoints."),
    seed: int = typer.Option(0, help="Seed of the initialisation and the batches."),
    init: str = typer.Option(
        "",
        "--init",
        help="A trained 3DGS predictor (.safetensors or a run's folder) to start from "
        "(fine-tuning; its [predictor] settings must be this run's).",
    ),
    threads: int = typer.Option(2, help="CPU threads (torch)."),
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
    config: Path = typer.Option(
        None,
        "--config",
        help="TOML/JSON file of GaussianTrainSettings fields (e.g. configs/gs_cpu_small.toml); "
        "options given here override it.",
    ),
):
    """Train the feed-forward 3DGS predictor (first frame → one Gaussian per object pixel) on
    frame 0 of a dataset's four views; writes OUT/model.safetensors + model.json."""
    from ..config_loader import load_settings, read_table
    from ..threads import set_cpu_threads
    from ..train.gaussians import GaussianTrainSettings, train_gaussian_predictor

    given = given_options(ctx)
    options = {name: ctx.params[name] for name in GS_SETTINGS}
    options = {
        k: str(v) if isinstance(v, Path) else v
        for k, v in options.items()
        if v is not None and (config is None or k in given)
    }
    layers = [(options, None)]
    if config is not None:
        layers.insert(0, (read_table(config), str(config)))
    for name in ("data", "out"):
        if not any(name in table for table, _ in layers):
            raise InputError(f"missing (give --{name} or set {name} in --config)", f"--{name}")
    settings = load_settings(GaussianTrainSettings, *layers)
    for name, value in (
        ("--steps", settings.steps),
        ("--batch-size", settings.batch_size),
        ("--checkpoint-every", settings.checkpoint_every),
        ("--threads", threads),
    ):
        if value < 1:
            raise InputError(f"must be ≥ 1, got {value}", field=name)
    if not (math.isfinite(settings.lr) and settings.lr > 0):
        raise InputError(f"must be a positive number, got {settings.lr}", field="--lr")
    for name, value in (
        ("--shape-weight", settings.shape_weight),
        ("--depth-weight", settings.depth_weight),
    ):
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"must be ≥ 0, got {value}", field=name)
    if not Path(settings.data).is_dir():
        raise InputError("dataset folder not found", source=settings.data)
    set_cpu_threads(threads)
    train_gaussian_predictor(settings, progress=not no_progress, log=typer.echo)
    typer.echo(f"wrote {Path(settings.out) / 'model.safetensors'}")


@app.command("train-masks")
@user_errors
def train_masks(
    data: list[Path] = typer.Option(
        ...,
        "--data",
        help="Realistic-look dataset folder (make-data --scene realistic), or a folder of "
        "recordings with masks (NNNN/video.mp4 + masks.npz: benchmarks/other_engine.py "
        "render); repeat.",
    ),
    out: Path = typer.Option(..., "--out", help="Output folder (resumes when run again)."),
    steps: int = typer.Option(4000, help="Optimiser steps."),
    batch_size: int = typer.Option(16, help="Frames per step."),
    crop: int = typer.Option(96, help="Training window, pixels per side."),
    lr: float = typer.Option(2e-3, help="Peak learning rate (cosine to 5 %)."),
    seed: int = typer.Option(0, help="Seed of the initialisation and the batches."),
    zoom: tuple[float, float] = typer.Option(
        (1.0, 1.0), help="Per step, frames resampled by a factor log-uniform in LO HI."
    ),
    exclude: list[Path] = typer.Option(
        [],
        "--exclude",
        help="Meshes left out: a dataset folder's test split's, or a file of meshes "
        "(configs/masks_held_out.txt); repeat.",
    ),
    views_per_sample: int = typer.Option(4, help="Views of each sample read (1–4): less memory."),
    channels: str = typer.Option(
        "24,32,48,64", help="The U-Net's channels per level, comma-separated (multiples of 4)."
    ),
    init: Path = typer.Option(
        None, help="Start from this trained segmenter (.safetensors or a train-masks folder)."
    ),
    photometric: float = typer.Option(
        0.0,
        help="Share (0–1) of training clips seen as another camera would take them (exposure, "
        "white balance, tone curve, blur; docs/usage.md).",
    ),
    threads: int = typer.Option(2, help="CPU threads (torch)."),
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
):
    """Train the mask segmenter (the object's masks from a recording without a clean plate) on
    the true masks of realistic-look datasets; writes OUT/model.safetensors + model.json."""
    from ..threads import set_cpu_threads
    from ..train.masks import MaskTrainSettings, train_mask_segmenter

    named = (("--steps", steps), ("--batch-size", batch_size), ("--crop", crop))
    for name, value in (*named, ("--views-per-sample", views_per_sample)):
        if value < 1:
            raise InputError(f"must be ≥ 1, got {value}", field=name)
    if not (math.isfinite(lr) and lr > 0):
        raise InputError(f"must be a positive number, got {lr}", field="--lr")
    if not 0 <= photometric <= 1:
        raise InputError(
            f"must be a share between 0 and 1, got {photometric}", field="--photometric"
        )
    if not (all(math.isfinite(z) and z > 0 for z in zoom) and zoom[0] <= zoom[1]):
        raise InputError(f"must be 0 < LO ≤ HI, got {zoom[0]} {zoom[1]}", field="--zoom")
    try:
        widths = tuple(int(c) for c in channels.split(","))
    except ValueError:
        widths = ()
    if len(widths) < 2 or any(c < 4 or c % 4 for c in widths):
        raise InputError(
            f"must be two or more multiples of 4, comma-separated, got {channels!r}",
            field="--channels",
        )
    for folder in data:
        if not folder.is_dir():
            raise InputError("dataset folder not found", source=str(folder))
    for held_out in exclude:
        if not held_out.exists():
            raise InputError("dataset folder or mesh list not found", source=str(held_out))
    settings = MaskTrainSettings(
        data=tuple(str(d) for d in data),
        out=str(out),
        steps=steps,
        batch_size=batch_size,
        crop=crop,
        lr=lr,
        seed=seed,
        zoom=zoom,
        exclude=tuple(str(d) for d in exclude),
        views_per_sample=views_per_sample,
        channels=widths,
        init="" if init is None else str(init),
        photometric=photometric,
    )
    set_cpu_threads(threads)
    path = train_mask_segmenter(settings, progress=not no_progress, log=typer.echo)
    typer.echo(f"wrote {path}")


@app.command("segment-data")
@user_errors
def segment_data(
    data: Path = typer.Argument(
        ..., help="Realistic-look dataset folder (make-data --scene realistic)."
    ),
    workers: int = typer.Option(2, help="Worker processes (one CPU thread each)."),
    overwrite: bool = typer.Option(False, help="Write again the samples that have them."),
    no_progress: bool = typer.Option(False, "--no-progress", help="No progress bar."),
):
    """Write the shipped mask segmenter's masks of every view of every sample beside its frames
    (segmenter_masks.npz): the masks a user without masks gets, to train a model of object crops
    on (data.masks = "segmenter", docs/training.md)."""
    from ..train.masks import segment_dataset

    if workers < 1:
        raise InputError(f"must be ≥ 1, got {workers}", field="--workers")
    if not data.is_dir():
        raise InputError("dataset folder not found", source=str(data))
    count = segment_dataset(data, workers, overwrite, progress=not no_progress)
    typer.echo(f"segmenter masks of {count} samples in {data} (segmenter_masks.npz beside frames)")
