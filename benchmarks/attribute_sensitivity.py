"""How much does each observable change the input video? A diagnostic of identifiability.

For every sample of a dataset split, the sample's asset (true geometry and initial state) is
simulated and rendered in the predictor's view twice per observable, with the observable at the
low and at the high end of a span and everything else at the truth — log k/m and log d/m moved
by ±``--log-span``/2 around the truth (clamped to the attribute ranges; m fixed), friction set to
0.1 and 0.9 (``--friction-pairs`` compares other values, e.g. 0.5:0.9). The score is the PSNR
between the two videos over frames 1..T−1 (higher = the observable changes the pixels less);
8-bit frames cannot resolve differences much above ~50 dB, and a network reading the video cannot
recover an observable that does not move the pixels.

    python benchmarks/attribute_sensitivity.py data/cpu_small --split test --frames 20

Prints one line per sample and the median per observable; records the machine and the command.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from dataclasses import replace

import torch

from reconphys.data.generate import dataset_cameras, render_views
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.render.video import to_uint8
from reconphys.threads import set_cpu_threads
from reconphys.train.config import DataConfig
from reconphys.train.data import TrainingSamples


def video(asset, settings, frames: int, view: int) -> torch.Tensor:  # [T, H, W, 3] in [0, 1]
    trajectory = asset.simulate(frames - 1, torch.device("cpu"))
    rgb = render_views(asset, trajectory.x[0], dataset_cameras(settings))
    return torch.from_numpy(to_uint8(rgb)[view]).float() / 255


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a[1:] - b[1:]) ** 2).mean())  # frames 1..T−1 (frame 0 is shared)
    return math.inf if mse == 0 else 10 * math.log10(1.0 / mse)


def clamp(name: str, value: float) -> float:
    low, high = ATTRIBUTE_RANGES[name]
    return min(max(value, low), high)


def variants(
    physics, log_span: float, friction_pairs: list[tuple[float, float]]
) -> dict[str, tuple[dict, dict]]:
    k, d = physics.stiffness, physics.damping  # m stays the truth: k/m and d/m move
    half = math.exp(log_span / 2)
    out = {
        "log k/m": (
            {"stiffness": clamp("stiffness", k / half)},
            {"stiffness": clamp("stiffness", k * half)},
        ),
        "log d/m": (
            {"damping": clamp("damping", d / half)},
            {"damping": clamp("damping", d * half)},
        ),
    }
    for low, high in friction_pairs:
        name = "friction" if (low, high) == (0.1, 0.9) else f"f {low:g}→{high:g}"
        out[name] = ({"friction": low}, {"friction": high})
    return out


def parse_pairs(text: str) -> list[tuple[float, float]]:
    """ "0.1:0.9,0.5:0.9" → [(0.1, 0.9), (0.5, 0.9)]."""
    pairs = []
    for item in text.split(","):
        low, high = (float(x) for x in item.split(":"))
        pairs.append((low, high))
    return pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder written by make-data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--view", type=int, default=0)
    parser.add_argument("--log-span", type=float, default=1.0, help="natural-log span of k, d")
    parser.add_argument("--limit", type=int, default=0, help="first N samples (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--friction-pairs", default="0.1:0.9", help="friction values compared, e.g. 0.1:0.9,0.5:0.9"
    )
    parser.add_argument("--only-friction", action="store_true", help="skip k/m and d/m")
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    config = DataConfig(source=args.data, split=args.split, frames=2, resolution=8)
    data = TrainingSamples(config)
    count = len(data) if args.limit <= 0 else min(args.limit, len(data))
    scores: dict[str, list[float]] = {}
    started = time.perf_counter()
    for index in range(count):
        asset = data.asset(index)
        line = []
        pairs = parse_pairs(args.friction_pairs)
        for name, (low, high) in variants(asset.physics, args.log_span, pairs).items():
            if args.only_friction and not name.startswith("f"):
                continue
            a = video(
                replace(asset, physics=replace(asset.physics, **low)),
                data.settings,
                args.frames,
                args.view,
            )
            b = video(
                replace(asset, physics=replace(asset.physics, **high)),
                data.settings,
                args.frames,
                args.view,
            )
            score = psnr(a, b)
            scores.setdefault(name, []).append(score)
            line.append(f"{name} {score:6.1f} dB")
        print(f"{data.sample_id(index)}: " + ", ".join(line), flush=True)
    print(
        f"\nmedian PSNR between the two videos, frames 1..{args.frames - 1}, view {args.view}, "
        f"{count} samples of {args.data} ({args.split}), log span {args.log_span}:"
    )
    for name, values in scores.items():
        finite = [v for v in values if math.isfinite(v)]
        median = statistics.median(finite) if finite else math.inf
        print(
            f"  {name:9s} median {median:6.1f} dB  (min {min(values):.1f}, max {max(values):.1f})"
        )
    print(
        f"machine: {platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{args.threads} threads; {time.perf_counter() - started:.0f} s; "
        f"command: {' '.join(sys.argv)}"
    )


if __name__ == "__main__":
    main()
