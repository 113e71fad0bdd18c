"""Gradient-free refinement by batched re-simulation: how far analysis-by-synthesis gets.

For each test sample of a dataset: the feed-forward estimate (``--model``, true geometry and
initial state: an upper bound, as ``evaluate``'s † rows), then a coordinate search on the three
observables (log k/m, log d/m, friction): per round and observable, 7 candidates around the current
value (the others fixed) are simulated as one batch, rendered into the recording's view at its
stored resolution, and the one with the lowest photometric error (MSE over frames 1..19) is kept;
spans 2, 0.7, 0.25 in natural log (friction a quarter of that). Mass stays as predicted (a video
fixes only k/m and d/m). Errors are split by launch (drop / toss) and shown beside the trivial
predictor (the training split's median).

    python benchmarks/search_refinement.py data/pyb --model runs/pyb --limit 40

A prototype for issue 22's "refinement fast enough to be the default"; the pipeline's own
refinement is ``predict --refine`` (photometric gradient steps, reconphys.pipeline.refine).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import torch

from reconphys.data.storage import read_manifest
from reconphys.models.shipped import load_predictor
from reconphys.physics import SpringMassModel, State, deform_means, rollout, stable_substeps
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.pipeline.predict import predict_observation
from reconphys.pipeline.samples import load_sample
from reconphys.render import render
from reconphys.threads import set_cpu_threads

NAMES = ("log k/m", "log d/m", "friction")
FRAMES = 20  # frames 0..19: the predictor's window
SPANS = (2.0, 0.7, 0.25)  # coarse to fine, natural log (friction: a quarter)
CANDIDATES = 7


def observables(attributes: dict[str, float]) -> list[float]:
    m = attributes["mass"]
    return [
        math.log(attributes["stiffness"] / m),
        math.log(attributes["damping"] / m),
        attributes["friction"],
    ]


@torch.no_grad()
def photometric_errors(asset, frames, camera, candidates: torch.Tensor) -> torch.Tensor:
    """MSE over frames 1..T−1 of each candidate [B, 3] (log k/m, log d/m, f) → [B]."""
    count, physics, mass = len(candidates), asset.physics, asset.physics.mass
    stiffness = (candidates[:, 0].exp() * mass).clamp(*ATTRIBUTE_RANGES["stiffness"])
    damping = (candidates[:, 1].exp() * mass).clamp(*ATTRIBUTE_RANGES["damping"])
    model = SpringMassModel(
        asset.springs,
        asset.rest_length,
        torch.full((count,), mass),
        stiffness,
        damping,
        candidates[:, 2].clamp(0, 1),
        spring_exponent=physics.spring_exponent,
        restitution=physics.restitution,
        gravity=tuple(physics.gravity),
        ground_height=physics.ground_height,
    )
    x0 = asset.x0[None].expand(count, -1, -1)
    substeps = stable_substeps(model, x0, physics.frame_dt, 25)
    state = State(x0, asset.v0[None].expand(count, -1, -1))
    steps = len(frames) - 1
    trajectory = rollout(model, state, steps, physics.frame_dt, substeps=substeps)
    x = trajectory.x[:, 1:].reshape(count * steps, -1, 3)
    g = asset.gaussians
    means = deform_means(
        g.means, asset.x0[None], x, asset.binding_index, asset.binding_weight
    )  # [B·(T−1), N, 3]
    batch = g.map(lambda t: t.expand(len(x), *t.shape)).with_means(means)
    images = render(batch, camera.cameras()).rgb[:, 0].reshape(count, steps, *frames.shape[1:])
    return ((images - frames[1:][None]) ** 2).mean((1, 2, 3, 4))


def search(asset, frames, camera, start: torch.Tensor) -> torch.Tensor:
    current = start.clone()
    grid = torch.linspace(-1, 1, CANDIDATES)
    for span in SPANS:
        for i in range(3):
            candidates = current.repeat(CANDIDATES, 1)
            candidates[:, i] = current[i] + grid * (span if i < 2 else span / 4)
            candidates[:, 2] = candidates[:, 2].clamp(0, 1)
            errors = photometric_errors(asset, frames, camera, candidates)
            current = candidates[int(errors.argmin())]
    return current


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder written by make-data")
    parser.add_argument("--model", default=None, help="physics predictor (default: shipped)")
    parser.add_argument("--limit", type=int, default=40, help="first N test samples")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default=None, help="per-sample results (JSON)")
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    root = Path(args.data)
    manifest = read_manifest(root)
    train = [s for s in manifest["samples"] if s["split"] == "train"]
    values = [observables(json.loads((root / s["dir"] / "sample.json").read_text())["attributes"])
              for s in train]  # fmt: skip
    median = [sorted(v[i] for v in values)[len(values) // 2] for i in range(3)]
    tests = [s for s in manifest["samples"] if s["split"] == "test"][: args.limit]
    predictor = load_predictor(args.model)
    rows = []
    for entry in tests:
        observation, truth = load_sample(root, entry["id"])
        meta = json.loads((root / entry["dir"] / "sample.json").read_text())
        started = time.perf_counter()
        with torch.no_grad():
            result = predict_observation(observation, predictor, truth=truth)
        network = torch.tensor(observables(result.attributes))
        frames = observation.frames[:FRAMES]
        found = search(result.asset, frames, observation.camera, network)
        row = {
            "id": entry["id"],
            "launch": meta["initial_state"].get("launch", "drop"),
            "seconds": time.perf_counter() - started,
            "true": observables(truth.attributes),
            "network": network.tolist(),
            "search": found.tolist(),
        }
        rows.append(row)
        cells = " ".join(
            f"{t:.2f}/{n:.2f}/{s:.2f}"
            for t, n, s in zip(row["true"], row["network"], row["search"], strict=True)
        )
        print(f"{row['id']} {row['launch']} {row['seconds']:.1f} s  true/net/search {cells}")
    print(f"\n{platform.processor() or platform.machine()}, {args.threads} threads; ratio = trivial"
          " MAE / method MAE")  # fmt: skip
    for kind in ("drop", "toss", "all"):
        chosen = [r for r in rows if kind == "all" or r["launch"] == kind]
        if not chosen:
            continue
        cells = []
        for i, name in enumerate(NAMES):
            trivial = sum(abs(median[i] - r["true"][i]) for r in chosen) / len(chosen)
            ratio = {}
            for method in ("network", "search"):
                error = sum(abs(r[method][i] - r["true"][i]) for r in chosen) / len(chosen)
                ratio[method] = trivial / error
            cells.append(f"{name} net {ratio['network']:.2f}× search {ratio['search']:.2f}×")
        seconds = sum(r["seconds"] for r in chosen) / len(chosen)
        print(f"{kind:5} n={len(chosen):3}: " + "; ".join(cells) + f"; {seconds:.1f} s/scene")
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
