"""The photometric part of one training step with each CPU renderer, in one run.

One step of the self-supervised objective at the cpu_small sizes: a batch of samples (true
geometry), their true attributes as the "prediction" (with gradients), the self-forced rollout of
frames 1..T−1, one render per sample and frame, the mean squared error and its backward through
renderer and simulator — what `reconphys train` does besides the (cheap) predictor. Timed with the
torch reference renderer and with the numba one; the rest of the step is the same code.

    python benchmarks/bench_training_step.py data/cpu_small [--batch 4] [--threads 2]
"""

from __future__ import annotations

import argparse
import datetime
import time
from pathlib import Path

import torch
from common import machine_description

from reconphys.data.storage import read_manifest
from reconphys.physics import ATTRIBUTES
from reconphys.render import Cameras, available_backends
from reconphys.render.photometric import SceneBatch, photometric_loss
from reconphys.threads import set_cpu_threads
from reconphys.train.config import DataConfig
from reconphys.train.data import TrainingSamples, collate


def step_seconds(batch, backend: str, min_substeps: int, repeats: int) -> tuple[float, float]:
    """Best (forward, forward + backward) seconds of the photometric loss over ``repeats``."""
    size = batch.frames.shape[2]
    cameras = Cameras(batch.K, batch.world_to_cam, size, size)
    scenes = SceneBatch.from_assets(batch.assets)
    forward, total = [], []
    for _ in range(repeats):
        attributes = {
            name: batch.attributes[:, i].clone().requires_grad_(True)
            for i, name in enumerate(ATTRIBUTES)
        }
        start = time.perf_counter()
        loss = photometric_loss(
            attributes, scenes, batch.frames, cameras, min_substeps=min_substeps, backend=backend
        )
        middle = time.perf_counter()
        loss.backward()
        forward.append(middle - start)
        total.append(time.perf_counter() - start)
    return min(forward), min(total)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="dataset folder (make-data), e.g. data/cpu_small")
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--min-substeps", type=int, default=25, help="as configs/cpu_small.toml")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    torch.set_flush_denormal(True)
    settings = read_manifest(Path(args.data))["parsed_settings"]
    samples = TrainingSamples(
        DataConfig(source=args.data, frames=args.frames, resolution=settings.resolution)
    )
    batch = collate([samples[i] for i in range(args.batch)])
    print(f"training-step benchmark, {datetime.date.today()}")
    print(machine_description("cpu"))
    print(
        f"batch {args.batch}, {args.frames} frames at {settings.resolution} px, "
        f"≥ {args.min_substeps} substeps, {batch.assets[0].gaussians.num_gaussians} Gaussians, "
        f"{batch.assets[0].num_anchors} anchors; best of {args.repeats}, seconds"
    )
    backends = [b for b in ("torch", "numba") if b in available_backends()]
    results = {}
    for backend in backends:
        step_seconds(batch, backend, args.min_substeps, 1)  # warm-up (compilation)
        results[backend] = step_seconds(batch, backend, args.min_substeps, args.repeats)
        fwd, total = results[backend]
        print(f"{backend:>6}: forward {fwd:6.2f}  forward + backward {total:6.2f}")
    if len(results) == 2:
        ratio = results["torch"][1] / results["numba"][1]
        print(f"numba / torch, forward + backward: {ratio:.2f}× faster")


if __name__ == "__main__":
    main()
