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
from reconphys.physics import ATTRIBUTE_RANGES
from reconphys.pipeline.predict import predict_observation
from reconphys.pipeline.samples import load_sample
from reconphys.pipeline.search import (
    OBSERVABLES,
    TEMPERATURE_PIXELS,
    observable_bounds,
    observables,
    profile_interval,
    search,
    temperature_for,
)
from reconphys.threads import set_cpu_threads

NAMES = ("log k/m", "log d/m", "friction")
# τ·pixels at REFERENCE_PIXELS tried (pipeline/search.py's law carries them to each sample's size)
PRODUCTS = (100, 200, 300, 400, 500, 600, 700, 800, 1000, 1200, 1500, 2000, 3000, 5000)
PRODUCTS_FINE = (400, 600, 800, 1000, 1500, 2000, 2500, 3000, 4000, 5000, 8000, 12000, 20000)
FRAMES = 20  # frames 0..19: the predictor's window


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder written by make-data")
    parser.add_argument("--model", default=None, help="physics predictor (default: shipped)")
    parser.add_argument("--limit", type=int, default=40, help="first N test samples")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default=None, help="per-sample results (JSON)")
    parser.add_argument("--split", default="test", help="split to run on (train: calibration)")
    parser.add_argument(
        "--skip-objects",
        type=int,
        default=0,
        help="leave out the split's first N objects (data.objects=N trained on them: the rest is "
        "a validation split)",
    )
    parser.add_argument(
        "--rows",
        nargs="+",
        default=None,
        help="calibrate from the per-sample results of earlier --out files (pooled)",
    )
    parser.add_argument(
        "--calibrate",
        action="store_true",
        help="print the 10–90 %% coverage for a range of profile temperatures and, per observable, "
        "the one that covers 80 %% (run it on objects the model never trained on, not the test "
        "split: e.g. --skip-objects)",
    )
    args = parser.parse_args()
    if args.rows:  # no search: recalibrate the intervals from stored profiles
        calibrate([row for path in args.rows for row in json.loads(Path(path).read_text())])
        return
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
    if values:
        median = [sorted(v[i] for v in values)[len(values) // 2] for i in range(3)]
    else:  # a test-only folder: the attribute ranges' midpoints (a uniform prior's medians)
        midpoints = {k: 0.5 * (lo + hi) for k, (lo, hi) in ATTRIBUTE_RANGES.items()}
        median = observables(SimpleNamespace(**midpoints)).tolist()
    tests = [s for s in manifest["samples"] if s["split"] == args.split]
    skipped = set(list(dict.fromkeys(s["object_dir"] for s in tests))[: args.skip_objects])
    tests = [s for s in tests if s["object_dir"] not in skipped][: args.limit]
    predictor = load_predictor(args.model)
    rows = []
    for entry in tests:
        observation, truth = load_sample(root, entry["id"])
        meta = json.loads((root / entry["dir"] / "sample.json").read_text())
        started = time.perf_counter()
        with torch.no_grad():
            result = predict_observation(observation, predictor, truth=truth, refine=False)
        found, history = search(
            result.asset,
            observation.frames[:FRAMES],
            observation.camera,
            masks=observation.masks[:FRAMES],
        )
        row = {
            "id": entry["id"],
            "launch": meta["initial_state"].get("launch", "drop"),
            "seconds": time.perf_counter() - started,
            "true": observables(truth.asset.physics).tolist(),
            "network": observables(result.asset.physics).tolist(),
            "search": observables(found.physics).tolist(),
            "intervals": [history["intervals"][n] for n in OBSERVABLES],
            "profiles": [history["profiles"][n] for n in OBSERVABLES],
            "render_size": history["render_size"],
            "size": int(observation.frames.shape[2]),  # the recording's width in pixels
            "supersample": history["supersample"],
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
        print(f"      10–90 % intervals (τ by size): {coverage_line(chosen)}")
    if args.calibrate:
        calibrate(rows)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


def coverage_line(rows: list[dict], intervals: str = "intervals") -> str:
    """Coverage and mean width of the intervals, per observable."""
    cells = []
    for i, name in enumerate(NAMES):
        inside = [r[intervals][i][0] <= r["true"][i] <= r[intervals][i][1] for r in rows]
        width = sum(r[intervals][i][1] - r[intervals][i][0] for r in rows) / len(rows)
        cells.append(f"{name} covers {sum(inside) / len(rows):.0%}, width {width:.2f}")
    return "; ".join(cells)


def calibrate(rows: list[dict]) -> None:
    """Intervals for a range of products (each sample's τ = ``temperature_for(its compared pixels,
    products=...)``) from the stored profiles; per observable, the product whose coverage is
    nearest 80 %, over all rows and per recording size (the law's exponent is right when the
    sizes agree). Supersampled
    comparisons (fine assets) are calibrated apart: their factor over TEMPERATURE_PIXELS is
    FINE_TEMPERATURE in pipeline/search.py."""
    fine = [r for r in rows if r.get("supersample", 1) > 1]
    plain = [r for r in rows if r.get("supersample", 1) == 1]
    for group, products, what in (
        (plain, PRODUCTS, "TEMPERATURE_PIXELS"),
        (fine, PRODUCTS_FINE, "TEMPERATURE_PIXELS × FINE_TEMPERATURE"),
    ):
        if group:
            chosen = calibrate_group(group, products)
            print(f"calibrated τ·pixels: {chosen} ({what} in pipeline/search.py)")
            if group is fine:
                factors = ", ".join(
                    f"{name} {c / t:.3g}"
                    for name, c, t in zip(NAMES, chosen, TEMPERATURE_PIXELS, strict=True)
                )
                print(f"  = TEMPERATURE_PIXELS × ({factors})")


def calibrate_group(rows: list[dict], products: tuple[int, ...]) -> list[int]:
    bounds = observable_bounds()
    pixels = sorted(r["render_size"][0] * r["render_size"][1] for r in rows)
    supersample = sorted({r.get("supersample", 1) for r in rows})
    print(
        f"{len(rows)} samples, compared pixels: median {pixels[len(pixels) // 2]} "
        f"({pixels[0]}–{pixels[-1]}), supersampled {supersample}"
    )
    best = [None] * 3  # per observable: (|coverage − 0.8|, product)
    sizes = sorted({r["size"] for r in rows if "size" in r})  # recording widths, when stored
    for product in products:
        for r in rows:
            temperature = temperature_for(
                r["render_size"][0] * r["render_size"][1], products=(product,) * 3
            )
            r["trial"] = [
                profile_interval(
                    torch.tensor(p["values"]),
                    torch.tensor(p["errors"]),
                    tuple(bounds[i].tolist()),
                    temperature[i],
                )
                for i, p in enumerate(r["profiles"])
            ]
        by_size = "".join(
            f"\n    {size} px: {coverage_line([r for r in rows if r.get('size') == size], 'trial')}"
            for size in sizes
            if len(sizes) > 1
        )
        print(f"τ·pixels = {product:<5} {coverage_line(rows, 'trial')}{by_size}")
        for i in range(3):
            coverage = sum(r["trial"][i][0] <= r["true"][i] <= r["trial"][i][1] for r in rows)
            miss = abs(coverage / len(rows) - 0.8)
            if best[i] is None or miss < best[i][0]:
                best[i] = (miss, product)
    return [b[1] for b in best]


if __name__ == "__main__":
    main()
