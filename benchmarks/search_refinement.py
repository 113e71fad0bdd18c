"""Gradient-free refinement by batched re-simulation: how far analysis-by-synthesis gets.

For each test sample of a dataset: the feed-forward estimate (``--model``, true geometry and
initial state: an upper bound, as ``evaluate``'s † rows), then
:func:`reconphys.pipeline.search.search`: a coordinate search on the three observables (log k/m,
log d/m, friction), 7 candidates per observable and round simulated as one batch, rendered into
the recording's view and compared with frames 1..19 (spans 2, 0.7, 0.25 in natural log; friction
a quarter). Mass stays as predicted (a video fixes only k/m and d/m). ``evaluate --methods
reconphys_search`` runs the same search. Errors are split by launch (drop / toss) and shown beside
the trivial predictor (the training split's median).

    python benchmarks/search_refinement.py data/pyb --model runs/pyb --limit 40

Issue 22's "refinement fast enough to be the default", measured; ``predict --refine`` is the
gradient-step refinement (reconphys.pipeline.refine).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from types import SimpleNamespace

import torch

from reconphys.data.storage import read_manifest
from reconphys.models.shipped import load_predictor
from reconphys.pipeline.predict import predict_observation
from reconphys.pipeline.samples import load_sample
from reconphys.pipeline.search import observables, search
from reconphys.threads import set_cpu_threads

NAMES = ("log k/m", "log d/m", "friction")
FRAMES = 20  # frames 0..19: the predictor's window


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
    values = [
        observables(
            SimpleNamespace(
                **json.loads((root / s["dir"] / "sample.json").read_text())["attributes"]
            )
        ).tolist()
        for s in train
    ]
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
        found, _ = search(result.asset, observation.frames[:FRAMES], observation.camera)
        row = {
            "id": entry["id"],
            "launch": meta["initial_state"].get("launch", "drop"),
            "seconds": time.perf_counter() - started,
            "true": observables(truth.asset.physics).tolist(),
            "network": observables(result.asset.physics).tolist(),
            "search": observables(found.physics).tolist(),
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
