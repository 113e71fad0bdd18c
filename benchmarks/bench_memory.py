"""Peak memory of a large object: build, simulate, render and back-propagate 200k Gaussians.

The issue-10 memory target: 200,000 Gaussians (a PhysTwin user's failure case) must render and
simulate without running out of memory. One object of N Gaussians (a random 0.5 m ball) is
built into an asset (2,048 anchors, K = 32, 16-anchor binding), simulated for 30 frames,
rendered into the 4 dataset views with every frame's deformed centres, and rendered once more
with gradients (a loss on rgb and alpha back to every Gaussian parameter). Each stage reports
its wall-clock and the peak memory: on CUDA ``torch.cuda.max_memory_allocated`` per stage; on
CPU the process's peak resident set (``ru_maxrss``, an upper bound that includes Python, torch
and Numba themselves).

    python benchmarks/bench_memory.py --device cpu [--gaussians 200000] [--side 256]
    python benchmarks/bench_memory.py --device cuda --side 512
"""

from __future__ import annotations

import argparse
import datetime
import resource
import time

import torch
from bench_renderer import random_object
from common import machine_description

from reconphys.assets.asset import PhysicsSettings
from reconphys.assets.build import build_asset
from reconphys.assets.gaussians import Gaussians
from reconphys.physics.binding import deform_means
from reconphys.render import dataset_views, render


def peak_mib(device: str) -> float:
    if device == "cuda":
        return torch.cuda.max_memory_allocated() / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10  # KiB on Linux


class Stages:
    """Times each stage and records the peak memory it reached."""

    def __init__(self, device: str):
        self.device = device
        self.rows: list[tuple[str, float, float]] = []

    def run(self, name: str, fn):
        if self.device == "cuda":
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
        start = time.perf_counter()
        result = fn()
        if self.device == "cuda":
            torch.cuda.synchronize()
        self.rows.append((name, time.perf_counter() - start, peak_mib(self.device)))
        print(f"{name:<44} {self.rows[-1][1]:8.2f} s {self.rows[-1][2]:10.0f} MiB", flush=True)
        return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default_device = "cuda" if torch.cuda.is_available() else "cpu"
    parser.add_argument("--device", choices=["cpu", "cuda"], default=default_device)
    parser.add_argument("--gaussians", type=int, default=200_000)
    parser.add_argument("--anchors", type=int, default=2048)
    parser.add_argument("--side", type=int, default=256, help="image side, pixels")
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device available")
    torch.set_flush_denormal(True)
    device = args.device
    print(f"memory benchmark on {device}, {datetime.date.today()}")
    print(machine_description(device))
    print(
        f"{args.gaussians:,} Gaussians, {args.anchors} anchors, {args.frames} frames, "
        f"4 views at {args.side}²"
    )
    print(f"{'stage':<44} {'wall':>10} {'peak':>14}")
    stages = Stages(device)
    scene = random_object(args.gaussians)
    gaussians = Gaussians.from_activated(
        scene["means"], scene["scales"], scene["opacities"], scene["colors"], scene["quats"]
    )
    physics = PhysicsSettings(num_anchors=args.anchors, num_neighbors=32, object_id="memory")
    asset = stages.run(
        "build asset (anchors, springs, binding)", lambda: build_asset(gaussians, physics)
    )
    trajectory = stages.run(
        f"simulate {args.frames} frames", lambda: asset.simulate(args.frames, device)
    )
    cameras = dataset_views(args.side, args.side, device=device)
    g = asset.gaussians.to(device)
    index, weight = asset.binding_index.to(device), asset.binding_weight.to(device)
    x0 = asset.x0.to(device)

    def render_video() -> None:
        with torch.no_grad():
            for t in range(trajectory.x.shape[1]):
                means = deform_means(g.means, x0, trajectory.x[0, t].to(device), index, weight)
                render(g.with_means(means), cameras)

    stages.run(f"render {args.frames + 1} frames × 4 views", render_video)

    def render_backward() -> None:
        params = {
            name: getattr(g, name).clone().requires_grad_(True)
            for name in ("means", "quats", "log_scales", "opacity_logits", "sh0")
        }
        out = render(Gaussians(**params), cameras)
        (out.rgb.square().mean() + out.alpha.mean()).backward()

    stages.run("render 4 views forward + backward", render_backward)


if __name__ == "__main__":
    main()
