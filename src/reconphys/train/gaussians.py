"""Training the feed-forward 3DGS predictor (``reconphys train-gs``, docs/usage.md).

Each training sample is frame 0 of a dataset sample: the predictor reads one view (masked by the
same background subtraction ``predict`` uses), its Gaussians on the object's pixels are rendered
into all four views, and the loss is the mean squared colour error plus ``silhouette_weight`` ×
the mean squared error between the rendered alpha and the views' masks, plus two optional
geometry terms against the true Gaussians (:func:`shape_error`, ``shape_weight``; and
:func:`depth_error`, ``depth_weight``) — the views' colours alone leave the Gaussians' depth
along the input view loose (docs/usage.md "The shape taught by the truth"). The input view cycles
through 0–3 so that every view is both input and target.

A crop predictor (``predictor.crop = true``, docs/usage.md "The 3DGS predictor") reads the
input view's object crop (:func:`~reconphys.models.model_input.frame_crop`) with the object's true
centre depth and is rendered into the four views' object crops; it trains on either look (the
realistic look's frames masked by its stored true masks). ``depth_noise`` scatters that depth
(off by default): its outputs are relative to the depth, so a scattered depth only moves and
scales its object about the input camera, which the other views then punish — the network
learns to hedge, smearing the object along the view, where ``predict`` gives it a depth that is
consistent with everything else it reads (docs/usage.md "One object, not a hedge").

``init`` starts from a trained predictor's weights (fine-tuning); its ``training`` record is
kept in the new model's under ``init``.

The run writes ``OUT/model.safetensors`` + ``model.json`` (the predictor), ``OUT/log.jsonl`` (one
line per step) and ``OUT/checkpoint.pt`` every ``checkpoint_every`` steps; running the same
command again resumes from the checkpoint (same settings) and repeats the uninterrupted run.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..assets.gaussians import Gaussians
from ..capture.masks import subtract_background
from ..data.dataset import DropDataset
from ..errors import InputError
from ..models.gaussian_predictor import GaussianPredictor, GaussianPredictorConfig
from ..models.gaussian_shipped import load_gaussian_predictor, save_gaussian_predictor
from ..models.model_input import frame_crop
from ..render import Cameras, render
from .checkpoint import resume_step, save_step

CHECKPOINT = "checkpoint.pt"


@dataclass
class GaussianTrainSettings:
    """What ``train-gs`` runs: its flags and its ``--config`` file (configs/gs_cpu_small.toml)
    set these fields; ``reconphys.config_loader`` type-checks them."""

    data: str  # dataset folder written by make-data
    out: str  # output folder: model, log, checkpoint (a rerun resumes)
    split: str = "train"  # the dataset split trained on
    steps: int = 2000  # optimiser steps
    batch_size: int = 4  # samples per step
    lr: float = 1e-3  # peak learning rate (cosine to min_lr_ratio × lr)
    min_lr_ratio: float = 0.1
    silhouette_weight: float = 1.0  # weight of the alpha-vs-mask loss
    seed: int = 0  # initialisation and batch order
    checkpoint_every: int = 200  # steps between checkpoints
    depth_noise: float = 0.0  # crop models: the reference depth × exp(N(0, σ²)) (a hedge)
    input_weight: float = 1.0  # the input view's loss weight (each other view's is 1)
    shape_weight: float = 0.0  # weight of the shape term (0: colours and silhouettes only)
    depth_weight: float = 0.0  # weight of the depth term: rendered depth vs the truth's (0: off)
    predictor: dict = field(default_factory=dict)  # GaussianPredictorConfig overrides
    init: str = ""  # a trained 3DGS predictor (.safetensors or a run's folder) to start from


def _recorded(settings: GaussianTrainSettings) -> dict:
    """The settings a checkpoint records: ``init`` only when given (older runs still resume)."""
    recorded = asdict(settings)
    if not recorded["init"]:
        recorded.pop("init")
    return recorded


def frame0_views(dataset: DropDataset, index: int, truth: bool = False) -> dict:
    """Frame 0 of all views of a sample: images [V, R, R, 3] (the object on black), masks
    [V, R, R], K, world_to_cam, and ``depth`` [V]: the camera z of the object's centre (its
    anchors' mean), metres; with ``truth``, also ``truth``: the true Gaussians at frame 0, world
    frame, metres. Plain look: the masks by background subtraction (as
    ``predict``); realistic look: the stored true masks, the frames masked by them."""
    item = dataset[index]
    images = item["frames"][:, 0].float()
    if dataset.settings.scene == "plain":
        masks = subtract_background(images)
    else:
        masks = dataset.masks(index)[:, 0].float()
        images = images * masks[..., None]
    w2c = item["world_to_cam"].float()
    centre = item["anchors"][0].float().mean(0)  # [3] world, frame 0
    views = {
        "images": images,
        "masks": masks,
        "K": item["K"].float(),
        "world_to_cam": w2c,
        "depth": (w2c[:, :3, :3] @ centre + w2c[:, :3, 3])[:, 2],
    }
    if truth:
        with torch.no_grad():
            asset = dataset.asset(index)
            views["truth"] = asset.gaussians.map(lambda t: t.float())
            views["truth"].means = asset.gaussian_means(item["anchors"][:1])[0].float()
    return views


def crop_views(views: dict, resolution: int, margin: float) -> dict:
    """Every view's object crop (frame_crop): images, masks, K at ``resolution``; a view that
    does not show the object (empty mask) is left out."""
    shown = [v for v in range(len(views["masks"])) if bool((views["masks"][v] > 0.5).any())]
    if not shown:
        raise InputError("no view of the training sample shows the object")
    crops = [
        frame_crop(views["images"][v], views["masks"][v], views["K"][v], resolution, margin)
        for v in shown
    ]
    cropped = {
        "images": torch.stack([c[0] for c in crops]),
        "masks": torch.stack([c[1] for c in crops]),
        "K": torch.stack([c[2] for c in crops]),
        "world_to_cam": views["world_to_cam"][shown],
        "depth": views["depth"][shown],
    }
    if "truth" in views:
        cropped["truth"] = views["truth"]
    return cropped


def _mean_squared_radius(points: torch.Tensor) -> torch.Tensor:  # [M, 3] metres → [] m²
    return ((points - points.mean(0)) ** 2).sum(1).mean().clamp_min(1e-12)


def shape_error(
    means: torch.Tensor,  # [N, 3] predicted centres, metres
    points: torch.Tensor,  # [M, 3] the object's true centres, metres
) -> torch.Tensor:  # [] dimensionless
    """Mean squared distance of each predicted centre to its nearest true one, over the true
    centres' mean squared distance to their mean: 0 when every Gaussian lies on the object,
    whatever its size; one-sided, so a shell of the seen side is not pulled to the hidden one."""
    radius2 = _mean_squared_radius(points)
    nearest2 = ((means[:, None] - points[None]) ** 2).sum(-1).min(1).values  # exact, no sqrt
    return nearest2.mean() / radius2


def sample_loss(
    model: GaussianPredictor,
    views: dict,
    input_view: int,
    silhouette_weight: float,
    depth_scatter: float = 1.0,  # crop models: the reference depth × this
    input_weight: float = 1.0,  # the input view's loss weight (each other view's is 1)
    shape_weight: float = 0.0,  # the shape term's weight (needs views["truth"])
    depth_weight: float = 0.0,  # the depth term's weight (needs views["truth"])
) -> tuple[torch.Tensor, dict]:
    """Loss of one sample read from ``input_view`` and rendered into every view (a crop model:
    every view's object crop, ``views`` as :func:`crop_views` gives them)."""
    v = input_view % len(views["images"])
    gaussians = model(
        views["images"][v : v + 1],
        views["masks"][v : v + 1],
        views["K"][v : v + 1],
        views["world_to_cam"][v : v + 1],
        views["depth"][v : v + 1] * depth_scatter,
    )
    keep = views["masks"][v].reshape(-1) > 0.5
    if not bool(keep.any()):
        raise InputError("empty mask in the input view of a training sample")
    object_gaussians = gaussians.map(lambda t: t[0]).select(keep)
    size = views["images"].shape[1]
    cameras = Cameras(views["K"], views["world_to_cam"], size, size)
    out = render(object_gaussians, cameras)
    weights = torch.ones(len(views["images"]))
    weights[v] = input_weight
    weights = weights / weights.sum()
    colour = ((out.rgb - views["images"]) ** 2).mean((1, 2, 3))  # [V]
    alpha = out.alpha.reshape(views["masks"].shape)
    silhouette = ((alpha - views["masks"]) ** 2).mean((1, 2))  # [V]
    loss = (weights * (colour + silhouette_weight * silhouette)).sum()
    parts = {"colour": colour.mean().item(), "silhouette": silhouette.mean().item()}
    if shape_weight > 0:
        shape = shape_error(object_gaussians.means, views["truth"].means)
        loss = loss + shape_weight * shape
        parts["shape"] = shape.item()
    if depth_weight > 0:
        # the truth as the scattered depth told it: moved along the input view's rays by the
        # scatter (the same image there), so the term scores the shape, not the scatter
        told = scaled_about_camera(views["truth"], views["world_to_cam"][v], depth_scatter)
        with torch.no_grad():
            truth = render(told, cameras)
        depth = depth_error(out, truth, told.means)  # [V]
        loss = loss + depth_weight * (weights * depth).sum()
        parts["depth"] = depth.mean().item()
    return loss, parts


def scaled_about_camera(
    gaussians: Gaussians,  # [N] world frame, metres
    world_to_cam: torch.Tensor,  # [4, 4] the camera they are scaled about
    factor: float,
) -> Gaussians:
    """The Gaussians ``factor`` times as far from the camera's centre and as large: the same
    picture in that camera (a pinhole cannot tell them apart), ``factor`` times the depth."""
    rotation, translation = world_to_cam[:3, :3], world_to_cam[:3, 3]
    centre = -rotation.T @ translation  # [3] the camera's centre, world frame
    scaled = gaussians.map(lambda t: t)
    scaled.means = centre + factor * (gaussians.means - centre)
    scaled.log_scales = gaussians.log_scales + math.log(factor)
    return scaled


def depth_error(
    out,  # RenderOutput of the prediction: depth, alpha [V, H, W]
    truth,  # RenderOutput of the true Gaussians in the same cameras
    points: torch.Tensor,  # [M, 3] the true centres (their spread sets the unit)
) -> torch.Tensor:  # [V] dimensionless
    """Per view, the mean squared difference of the rendered depth (expected camera z) against
    the truth's over the pixels both cover (alpha > 0.5), over the true centres' mean squared
    radius: where each view sees the object's surface, not only its outline."""
    radius2 = _mean_squared_radius(points)
    both = ((out.alpha > 0.5) & (truth.alpha > 0.5)).float().reshape(truth.depth.shape)
    squared = (out.depth.reshape(truth.depth.shape) - truth.depth) ** 2 * both
    return squared.sum((-1, -2)) / both.sum((-1, -2)).clamp_min(1) / radius2


def _lr(step: int, settings: GaussianTrainSettings) -> float:
    progress = (step - 1) / max(1, settings.steps - 1)
    floor = settings.min_lr_ratio
    return settings.lr * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress)))


def train_gaussian_predictor(
    settings: GaussianTrainSettings,
    progress: bool = True,
    log=print,
    stop_after: int | None = None,  # tests: end after this step as if killed (no model written)
):
    """Run (or resume) the training described by ``settings``; returns the output folder."""
    out = Path(settings.out)
    dataset = DropDataset(settings.data, split=settings.split, frames=[0])
    resolution = dataset.settings.resolution
    config = GaussianPredictorConfig(**{"resolution": resolution, **settings.predictor})
    if not config.crop:
        dataset.settings.require_plain(
            settings.data, "train-gs", "make its data with --scene plain, or train a crop model"
        )
    if len(dataset) == 0:
        raise InputError(f"no samples in split {settings.split!r}", source=settings.data)
    torch.manual_seed(settings.seed)
    model = GaussianPredictor(config)
    if settings.init:
        start = load_gaussian_predictor(settings.init)
        if start.model.config != config:
            raise InputError(
                "its predictor's settings differ from this run's (give the same [predictor] "
                "and data resolution)",
                source=settings.init,
            )
        model.load_state_dict(start.model.state_dict())
        lineage = {"path": settings.init, "training": start.metadata.get("training")}
    optimizer = torch.optim.Adam(model.parameters(), lr=settings.lr)
    checkpoint_path = out / CHECKPOINT
    first_step = resume_step(checkpoint_path, model, optimizer, _recorded(settings), log)
    out.mkdir(parents=True, exist_ok=True)
    (out / "settings.json").write_text(json.dumps(asdict(settings), indent=1) + "\n")
    log_path = out / "log.jsonl"
    if log_path.exists():  # drop lines past the checkpoint: the resumed run rewrites them
        lines = [
            line
            for line in log_path.read_text().splitlines()
            if json.loads(line)["step"] < first_step
        ]
        log_path.write_text("".join(line + "\n" for line in lines))
    steps = range(first_step, settings.steps + 1)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(
            steps, desc="train-gs", unit="step", initial=first_step - 1, total=settings.steps
        )
    started = time.perf_counter()
    with_truth = settings.shape_weight > 0 or settings.depth_weight > 0
    model.train()
    for step in steps:
        rng = np.random.default_rng([settings.seed, step])
        picks = rng.choice(len(dataset), size=min(settings.batch_size, len(dataset)), replace=False)
        for group in optimizer.param_groups:
            group["lr"] = _lr(step, settings)
        optimizer.zero_grad()
        losses, parts = [], []
        scatter = np.exp(settings.depth_noise * rng.standard_normal(len(picks)))
        for b, index in enumerate(picks):
            views = frame0_views(dataset, int(index), truth=with_truth)
            if config.crop:
                views = crop_views(views, config.resolution, config.crop_margin)
            loss, part = sample_loss(
                model,
                views,
                (step + b) % 4,
                settings.silhouette_weight,
                float(scatter[b]),
                settings.input_weight,
                settings.shape_weight,
                settings.depth_weight,
            )
            losses.append(loss)
            parts.append(part)
        loss = torch.stack(losses).mean()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        record = {
            "step": step,
            "loss": loss.item(),
            "lr": _lr(step, settings),
            "colour": float(np.mean([p["colour"] for p in parts])),
            "silhouette": float(np.mean([p["silhouette"] for p in parts])),
        }
        for name in ("shape", "depth"):
            if name in parts[0]:
                record[name] = float(np.mean([p[name] for p in parts]))
        with open(log_path, "a") as f:
            f.write(json.dumps(record) + "\n")
        if progress:
            steps.set_postfix(loss=f"{record['loss']:.4f}")
        if step % settings.checkpoint_every == 0 or step == settings.steps:
            save_step(checkpoint_path, model, optimizer, step, _recorded(settings))
        if stop_after is not None and step >= stop_after:
            return out
    training = {
        "data": str(Path(settings.data).resolve()),
        "samples": len(dataset),
        "settings": asdict(settings),
        "resolution": resolution,
        "wall_clock_seconds_last_session": round(time.perf_counter() - started, 1),
        "final_loss": record["loss"] if settings.steps >= first_step else None,
    }
    if settings.init:
        training["init"] = lineage
    save_gaussian_predictor(model.eval(), out / "model.safetensors", training)
    return out
