"""The feed-forward physics predictor on a dataset's test split: MAE ratios to trivial, fast.

For each model given, the observables (log k/m, log d/m, friction) predicted from view 0 of every
test video (the model's own frames and size), against the truth; trivial is the median of the
training split. Ratios are trivial's MAE / the model's (> 1: better than the median guess), per
launch (drop / toss) and over all. No rendering or simulation: seconds for a data curve where
``evaluate`` (future PSNR, Chamfer, EMD) takes minutes.

    python benchmarks/feed_forward.py data/pyb --model runs/trk_pyb runs/trk_big

A realistic-look dataset (``make-data --scene realistic``) is read as ``predict`` reads a
recording: its frames times the object's masks — the stored true masks (``--masks true``) or the
shipped mask segmenter's (``--masks segmenter``, what a user without masks gets). Its test-only
folders have no training split: ``--trivial-from DATA`` takes the medians of another dataset's.

``--by-aspect`` splits the ratios by how elongated each object is: the spread (standard
deviation) of its anchors along their longest principal axis over that along their shortest, in
bins below 2.5, 2.5–4 and from 4 (docs/training.md "Stretched meshes").

``--curve PNG`` draws the ratios against each model's number of training videos (its model.json):
a data curve, one panel per observable, drops and all (docs/images/track_data_curve.png).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from common import after_first_objects
from PIL import Image, ImageDraw

from reconphys.data.dataset import DropDataset
from reconphys.data.storage import read_manifest
from reconphys.eval.plots import COLOURS, Axes
from reconphys.models.mask_segmenter import load_mask_segmenter, segment_clip
from reconphys.models.shipped import load_predictor
from reconphys.physics import ATTRIBUTES
from reconphys.pipeline.search import observables
from reconphys.threads import set_cpu_threads

NAMES = ("log k/m", "log d/m", "friction")
LAUNCHES = ("drop", "toss", "all")
ASPECT_BINS = (1.0, 2.5, 4.0, math.inf)  # edges of --by-aspect's bins


def elongation(anchors: np.ndarray) -> float:
    """Spread of ``anchors`` [N, 3] along their longest principal axis / along their shortest."""
    spread = np.sqrt(np.linalg.eigvalsh(np.cov((anchors - anchors.mean(0)).T)).clip(1e-12))
    return float(spread[-1] / spread[0])


def observables_of(attributes: dict) -> torch.Tensor:  # [3] log k/m, log d/m, f (float64)
    return observables(SimpleNamespace(**{k: float(attributes[k]) for k in ATTRIBUTES})).double()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="dataset folder written by make-data")
    parser.add_argument("--model", nargs="+", default=[None], help="runs or weights (shipped)")
    parser.add_argument("--split", default="test")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--curve", type=Path, default=None, help="PNG: ratios vs training videos")
    parser.add_argument(
        "--masks",
        choices=("true", "segmenter"),
        default="true",
        help="realistic datasets: the object's masks that cut it out",
    )
    parser.add_argument(
        "--after-objects",
        type=int,
        default=0,
        help="only the samples of the split's objects after its first N (a validation split)",
    )
    parser.add_argument("--segmenter", default=None, help="weights (default: the shipped ones)")
    parser.add_argument(
        "--objects-of",
        type=Path,
        default=None,
        help="with --after-objects: the first N objects are this dataset's training split's "
        "(by mesh), e.g. a validation split of meshes a model of several folders never saw",
    )
    parser.add_argument(
        "--by-aspect", action="store_true", help="ratios by the objects' elongation as well"
    )
    parser.add_argument(
        "--trivial-from",
        type=Path,
        default=None,
        help="the medians of this dataset's training split (default: DATA's)",
    )
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    segmenter = load_mask_segmenter(args.segmenter) if args.masks == "segmenter" else None
    manifest = read_manifest(args.data)
    train = [s for s in manifest["samples"] if s["split"] == "train"]
    truth_of = {}
    for s in manifest["samples"]:
        meta = json.loads((args.data / s["dir"] / "sample.json").read_text())
        launch = meta["initial_state"].get("launch", "drop")
        truth_of[s["id"]] = (observables_of(meta["attributes"]), launch)
    aspect_of = {}  # object id → elongation of its anchors (--by-aspect)
    if args.by_aspect:
        for o in manifest["objects"]:
            with np.load(args.data / o["dir"] / "anchors.npz") as stored:
                aspect_of[o["id"]] = elongation(stored["x0"])
    source = args.trivial_from or args.data
    trivial_truth = {s["id"]: truth_of[s["id"]][0] for s in train}
    if args.trivial_from is not None:  # its sample ids may be DATA's too (another seed)
        train = [s for s in read_manifest(source)["samples"] if s["split"] == "train"]
        trivial_truth = {}
        for s in train:
            meta = json.loads((source / s["dir"] / "sample.json").read_text())
            trivial_truth[s["id"]] = observables_of(meta["attributes"])
    median = torch.stack([trivial_truth[s["id"]] for s in train]).median(0).values
    print(f"{args.data}: trivial = median of {len(train)} training samples of {source}")
    realistic = manifest["parsed_settings"].scene != "plain"
    if realistic:
        print(f"realistic look: frames × {args.masks} masks")
    curve = []  # (training videos, {launch: ratios [3]})
    for model in args.model:
        predictor = load_predictor(model)
        dataset = DropDataset(args.data, args.split, views=[predictor.view])
        if args.after_objects:
            order = None
            if args.objects_of is not None:
                order = [
                    s for s in read_manifest(args.objects_of)["samples"] if s["split"] == "train"
                ]
            dataset.samples = after_first_objects(dataset.samples, args.after_objects, order)
        started = time.perf_counter()
        rows = []
        for index in range(len(dataset)):
            item = dataset[index]
            frames = item["frames"][0]  # [T, H, W, 3]
            if realistic:
                if args.masks == "true":
                    masks = dataset.masks(index)[0].float()
                else:
                    masks = segment_clip(segmenter, frames)
                frames = frames * masks[..., None]
            out = predictor.predict(frames[None])
            predicted = observables_of({k: out[k][0] for k in ATTRIBUTES})
            true, launch = truth_of[item["id"]]
            rows.append((predicted, true, launch, aspect_of.get(dataset.samples[index]["object"])))
        seconds = (time.perf_counter() - started) / max(len(rows), 1)
        videos = predictor.metadata.get("training", {}).get("data", {}).get("samples", 0)
        print(f"{model or 'shipped'} ({videos} training videos; {seconds * 1e3:.0f} ms / video)")
        curve.append((videos, {}))
        groups = [(kind, [r for r in rows if kind == "all" or r[2] == kind]) for kind in LAUNCHES]
        if args.by_aspect:
            edges = itertools.pairwise(ASPECT_BINS)
            groups += [
                (f"{lo:g}-{hi:g}:1", [r for r in rows if lo <= r[3] < hi]) for lo, hi in edges
            ]
        for kind, chosen in groups:
            if not chosen:
                continue
            predicted = torch.stack([r[0] for r in chosen])
            true = torch.stack([r[1] for r in chosen])
            ratio = (median - true).abs().mean(0) / (predicted - true).abs().mean(0)
            if kind in LAUNCHES:
                curve[-1][1][kind] = ratio.tolist()
            cells = " / ".join(f"{v:.2f}×" for v in ratio.tolist())
            print(f"  {kind:7} n={len(chosen):3}: {cells}  ({' / '.join(NAMES)})")
    if args.curve:
        plot_curve(sorted(curve, key=lambda c: c[0]), args.curve, str(args.data))


def plot_curve(curve: list[tuple[int, dict]], path: Path, title: str) -> None:
    """Ratio to trivial vs training videos (log axis), one panel per observable."""
    image = Image.new("RGB", (60 + 400 * 3, 420), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    xs = [math.log10(max(v, 1)) for v, _ in curve]
    kinds = [k for k in ("drop", "all") if all(k in ratios for _, ratios in curve)]
    top = max(max(r[k][i] for _, r in curve for k in kinds) for i in range(3))
    for i, name in enumerate(NAMES):
        left = 70 + 400 * i
        axes = Axes(draw, (left, 40, left + 320, 360), (min(xs) - 0.05, max(xs) + 0.05),
                    (0.0, top * 1.1), f"{name}: trivial MAE / model MAE",
                    "log10 training videos")  # fmt: skip
        axes.line([min(xs) - 0.05, max(xs) + 0.05], [1.0, 1.0], (0, 0, 0), width=1, dash=True)
        for j, kind in enumerate(kinds):
            ys = [r[kind][i] for _, r in curve]
            axes.line(xs, ys, COLOURS[j])
            for x, y in zip(xs, ys, strict=True):
                axes.marker(x, y, COLOURS[j])
            draw.text((left + 10, 50 + 16 * j), f"{kind}", fill=COLOURS[j])
    draw.text((10, 400), f"{title} test split; dashed: the median guess", fill=(0, 0, 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
