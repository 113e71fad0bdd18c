"""Latency of ``reconphys predict`` (video → asset), step by step, model load excluded.

Two cases, each timed end to end through :func:`reconphys.pipeline.predict.predict` (best of
``--repeats`` after a warm-up call, so Numba compilation and first-call allocations are excluded):

- ``shipped``: a dataset sample exported as a user would bring it (``data video``: the encoded
  mp4, camera.json, gaussians.ply) at the shipped model's input size (32 px, 20 frames read,
  2 000 Gaussians, 256 anchors) — the issue-7 target: physics network + asset build ≤ 1 s on the
  2-core CPU (≤ 0.1 s on an H100);
- ``large``: the same video with a 20 000-Gaussian procedural object and 2 048 anchors;
- ``predicted``: no PLY — the 3DGS predictor makes the Gaussians from frame 0 (``--gs-model``,
  default the shipped one; skipped when there is none): the whole feed-forward pipeline, whose
  issue-8 target is decode → 3DGS → physics → asset ≤ 2 s on the 2-core CPU.

    python benchmarks/bench_predict.py data/cpu_small [--sample ID] [--device cpu|cuda]

Prints the breakdown (decode, gaussians, physics_network, asset_build) per case, the target sum,
the farthest-point-sampling twins of the anchor sampler (plain PyTorch loop vs the compiled one,
16 384 candidates → 2 048 anchors, in the same run) and the machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from common import machine_description

from reconphys.assets.ply import write_ply
from reconphys.assets.procedural import make_procedural_gaussians
from reconphys.errors import InputError
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.physics.anchors import farthest_point_sampling, farthest_point_sampling_reference
from reconphys.pipeline.predict import predict
from reconphys.threads import set_cpu_threads

STEPS = ("decode", "gaussians", "physics_network", "asset_build")


def best_timings(repeats: int, **kwargs) -> dict[str, float]:
    """Best time per step of ``repeats`` calls (the caller has made the warm-up call)."""
    runs = [predict(**kwargs).timings for _ in range(repeats)]
    return {step: min(run[step] for run in runs) for step in STEPS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="dataset folder (make-data)")
    parser.add_argument("--sample", default=None, help="sample id (default: the first test one)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--gs-model", default=None, help="3DGS predictor for the predicted case")
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    manifest = json.loads((Path(args.data) / "manifest.json").read_text())
    sample = args.sample or next(s["id"] for s in manifest["samples"] if s["split"] == "test")
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description(args.device)}")
    with tempfile.TemporaryDirectory() as tmp:
        bundle = Path(tmp) / "bundle"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "reconphys.cli",
                "data",
                "video",
                args.data,
                sample,
                str(bundle),
            ],
            check=True,
            capture_output=True,
        )
        big = make_procedural_gaussians("bunny", 20000, seed=0)
        reference = predict(
            str(bundle / "video.mp4"),
            camera=bundle / "camera.json",
            gaussians=bundle / "gaussians.ply",
            refine=False,
        )
        # the large object where the small one is: same centre, its own size (0.5 m)
        shift = reference.asset.gaussians.means.mean(0) - big.means.mean(0)
        write_ply(Path(tmp) / "big.ply", big.with_means(big.means + shift))
        cases = {
            "shipped": dict(gaussians=bundle / "gaussians.ply"),
            "large": dict(gaussians=Path(tmp) / "big.ply", num_anchors=2048),
        }
        try:
            load_gaussian_predictor(args.gs_model)
            cases["predicted"] = dict(gs_model=args.gs_model)
        except InputError as e:
            print(f"# predicted case skipped: {e}")
        print(
            f"{'case':9s} {'gaussians':>9s} {'anchors':>7s} "
            + " ".join(f"{s:>15s}" for s in STEPS)
            + f" {'network+build':>14s} {'all four':>9s}"
        )
        for name, extra in cases.items():
            kwargs = dict(
                input=str(bundle / "video.mp4"),
                camera=bundle / "camera.json",
                device=args.device,
                placement="as-is",
                refine=False,  # the feed-forward steps (the search: search_refinement.py)
                **extra,
            )
            result = predict(**kwargs)  # warm-up: Numba compilation, allocator, file cache
            timings = best_timings(args.repeats, **kwargs)
            target = timings["physics_network"] + timings["asset_build"]
            print(
                f"{name:9s} {result.asset.gaussians.num_gaussians:9d} "
                f"{result.asset.num_anchors:7d} "
                + " ".join(f"{timings[s]:15.4f}" for s in STEPS)
                + f" {target:14.4f} {sum(timings.values()):9.4f}"
            )
    points = torch.rand(16384, 3, generator=torch.Generator().manual_seed(0)).double()
    farthest_point_sampling(points, 8)  # compile / load from the cache
    seconds = {}
    for name, fn in (
        ("reference", farthest_point_sampling_reference),
        ("compiled", farthest_point_sampling),
    ):
        started = time.perf_counter()
        fn(points, 2048)
        seconds[name] = time.perf_counter() - started
    ratio = seconds["reference"] / seconds["compiled"]
    print(
        f"farthest-point sampling 16384 → 2048: reference {seconds['reference']:.3f} s, "
        f"compiled {seconds['compiled']:.4f} s, ratio {ratio:.0f}×"
    )


if __name__ == "__main__":
    main()
