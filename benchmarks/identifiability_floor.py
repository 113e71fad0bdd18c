"""The best MAE any video-only predictor can reach on one observable: an oracle bound.

For every sample of a dataset split, the sample's asset (true geometry, anchors, initial state
and the other attributes) is simulated and rendered in the predictor's view (8-bit frames, as in
the dataset) once per value of a grid over one attribute — friction uniform on its range, or
damping uniform on its range (the data's ``uniform`` distribution; m fixed, so the error in
log d equals the error in log d/m). Each grid value in turn plays the truth; an oracle that
knows everything but that attribute, and can tell two videos apart only when their PSNR
(frames 1..T−1) is below ``τ``, cannot rule out any grid value whose video is within ``τ`` of
the truth's. Its best answer under absolute error is the median of those values (the posterior
median with the data's uniform prior); the script averages its error over the grid and the
samples and prints it beside the trivial predictor's (the grid's median) for several ``τ``.

τ = ∞ means "any 8-bit difference at all": what the video holds, a bound no network beats.
Finite τ are what a model matching videos to that precision can use (the shipped model's
reconstruction PSNR is ~42 dB). The oracle is given the geometry and the other attributes, so
a real predictor does worse.

    python benchmarks/identifiability_floor.py data/cpu_small --split test --attribute friction

Prints one line per sample and a summary table; records the machine and the command.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np
import torch
from common import machine_description

from reconphys.data.generate import dataset_cameras, render_views
from reconphys.physics import rollout
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.render.video import to_uint8
from reconphys.threads import set_cpu_threads
from reconphys.train.config import DataConfig
from reconphys.train.data import TrainingSamples

THRESHOLDS_DB = (35.0, 40.0, 45.0, 50.0, math.inf)


def grid_videos(asset, settings, attribute: str, grid: np.ndarray, frames: int, view: int):
    """8-bit videos [G, T, H, W, 3] of the asset with ``attribute`` set to each grid value."""
    model = asset.model("cpu")
    values = torch.tensor(grid, dtype=torch.float32)  # [G]: one value per scene
    model = model.with_attributes(**{attribute: values})
    state = asset.initial_state("cpu")
    with torch.no_grad():
        trajectory = rollout(
            model, state, frames - 1, asset.physics.frame_dt, min_substeps=asset.physics.substeps
        )
    cameras = dataset_cameras(settings)
    videos = [
        to_uint8(render_views(asset, trajectory.x[g], cameras))[view] for g in range(len(grid))
    ]
    return np.stack(videos)


def pairwise_psnr(videos: np.ndarray) -> np.ndarray:  # [G, G] dB over frames 1..T−1
    flat = videos[:, 1:].reshape(len(videos), -1).astype(np.float64) / 255
    mse = ((flat[:, None] - flat[None]) ** 2).mean(-1)
    with np.errstate(divide="ignore"):
        return np.where(mse == 0, np.inf, -10 * np.log10(mse))


def oracle_errors(psnr: np.ndarray, coords: np.ndarray, threshold: float) -> np.ndarray:
    """|truth − posterior median| per grid value, the error measured on ``coords``."""
    errors = []
    for i in range(len(coords)):
        alike = coords[psnr[i] >= threshold]  # includes i itself (PSNR ∞)
        errors.append(abs(coords[i] - np.median(alike)))
    return np.array(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder written by make-data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--attribute", choices=("friction", "damping"), default="friction")
    parser.add_argument("--grid", type=int, default=21, help="grid values over the range")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--limit", type=int, default=0, help="first N samples (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    torch.set_flush_denormal(True)
    data = TrainingSamples(DataConfig(source=args.data, split=args.split, frames=2, resolution=8))
    count = len(data) if args.limit <= 0 else min(args.limit, len(data))
    low, high = ATTRIBUTE_RANGES[args.attribute]
    grid = np.linspace(low, high, args.grid)
    coords = grid if args.attribute == "friction" else np.log(grid)  # where errors are measured
    name = "f" if args.attribute == "friction" else "log d/m"
    trivial = np.abs(coords - np.median(coords)).mean()
    errors = {t: [] for t in THRESHOLDS_DB}
    started = time.perf_counter()
    for index in range(count):
        asset = data.asset(index)
        psnr = pairwise_psnr(
            grid_videos(asset, data.settings, args.attribute, grid, args.frames, args.view)
        )
        for t in THRESHOLDS_DB:
            errors[t].append(oracle_errors(psnr, coords, t).mean())
        line = ", ".join(f"τ={t:g}: {errors[t][-1]:.3f}" for t in THRESHOLDS_DB)
        print(f"{data.sample_id(index)}: oracle MAE {name} {line}", flush=True)
    print(
        f"\noracle MAE of {name} ({args.grid}-value uniform grid over {args.attribute} "
        f"[{low:g}, {high:g}], everything else true; frames 1..{args.frames - 1}, view "
        f"{args.view}; {count} samples of {args.data} ({args.split})); trivial (grid median) "
        f"{trivial:.3f}:"
    )
    print("| τ (dB) | oracle MAE | trivial / oracle |")
    print("|---|---|---|")
    for t in THRESHOLDS_DB:
        mean = statistics.fmean(errors[t])
        ratio = trivial / mean if mean > 0 else math.inf
        print(f"| {t:g} | {mean:.3f} | {ratio:.2f}× |")
    print(
        f"machine: {machine_description('cpu')}; {time.perf_counter() - started:.0f} s; "
        f"command: {' '.join(sys.argv)}"
    )


if __name__ == "__main__":
    main()
