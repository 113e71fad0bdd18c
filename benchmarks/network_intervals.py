"""The network's own 10–90 % intervals: how wide its members' spread must be taken.

For an ensemble physics model (members ≥ 2) on a dataset's videos (view 0, the model's frames;
a realistic-look dataset cut out by its true masks or the shipped segmenter's, as
``feed_forward.py``), the members' standard deviation of log k/m, log d/m and friction
(``models.physics_predictor.observable_spread``) against the ensemble's error: its rank
correlation with the error, and the share of videos whose interval answer ± 1.2816 · a · σ₁
(σ₁: the spread) holds the truth, for several factors a. An ensemble's factors (its JSON's
``spread_factor``) are those that hold it about 80 % of the time on objects it never trained on
— run it on a validation split, never a test split:

    python benchmarks/network_intervals.py data/real_pybullet --split train --after-objects 849 \\
        --model src/reconphys/weights/physics_predictor_crop.safetensors --masks segmenter
    python benchmarks/network_intervals.py VALIDATION_FOLDER          # the shipped plain ensemble

Each ensemble carries its own factors in its JSON ("spread_factor"; without one,
``models.physics_predictor.DEFAULT_SPREAD_FACTOR``). ``--write`` stores the factor of the grid below
whose interval holds the truth nearest 80 % of the time, per observable, into the model's JSON
(`make model` does it on its validation drops, data/val200).

An ensemble trained with ``model.scale_head = true`` also predicts its own error's scale b per
video (a Laplace scale, :func:`reconphys.models.physics_predictor.observable_scale`); for it the
table's σ₁ is the spread and the scale together (``physics_predictor.network_sigma`` before its
factors: the root sum of squares of the spread and ln 5 · b / 1.28), and the scale alone's
coverage of answer ± a · ln 5 · b is printed after it.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
import torch
from common import after_first_objects
from feed_forward import observables_of
from scipy.stats import spearmanr

from reconphys.data.dataset import DropDataset
from reconphys.data.storage import read_manifest
from reconphys.models.mask_segmenter import load_mask_segmenter, segment_clip
from reconphys.models.physics_predictor import LN5, network_sigma
from reconphys.models.shipped import config_path, load_predictor, save_predictor
from reconphys.physics import ATTRIBUTES
from reconphys.pipeline.search import Z_10_90
from reconphys.threads import set_cpu_threads

NAMES = ("log k/m", "log d/m", "friction")
FACTORS = (0.8, 0.9, 1.0, 1.1, 1.2, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 6.0)
SCALE_FACTORS = (0.8, 1.0, 1.2, 1.5)  # × the scale head's Laplace 10–90 % half-width


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="dataset folder written by make-data")
    parser.add_argument("--model", default=None, help="an ensemble's weights (default: shipped)")
    parser.add_argument("--split", default="test")
    parser.add_argument(
        "--after-objects", type=int, default=0, help="skip the split's first N objects"
    )
    parser.add_argument("--masks", choices=("true", "segmenter"), default="true")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--write", action="store_true", help="store the factors nearest 80 %% in the model's JSON"
    )
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    predictor = load_predictor(args.model)
    dataset = DropDataset(args.data, args.split, views=[predictor.view])
    if args.after_objects:
        dataset.samples = after_first_objects(dataset.samples, args.after_objects)
    realistic = read_manifest(args.data)["parsed_settings"].scene != "plain"
    segmenter = load_mask_segmenter() if realistic and args.masks == "segmenter" else None
    errors, spreads, scales = [], [], []
    started = time.perf_counter()
    for index in range(len(dataset)):
        item = dataset[index]
        frames = item["frames"][0]
        if realistic:
            if segmenter is None:
                masks = dataset.masks(index)[0].float()
            else:
                masks = segment_clip(segmenter, frames)
            frames = frames * masks[..., None]
        with torch.no_grad():
            out = predictor.predict(frames[None])
        belief = network_sigma(out, (1.0, 1.0, 1.0))  # before the factors
        if belief is None:
            raise SystemExit(f"{predictor.path}: no belief (a single network, no scale head)")
        answer = observables_of({k: out[k][0] for k in ATTRIBUTES})
        errors.append((answer - observables_of(dataset.meta(index)["attributes"])).tolist())
        spreads.append(belief[0].tolist())
        if "observable_scale" in out:
            scales.append(out["observable_scale"][0].tolist())
    error, spread = np.abs(np.array(errors)), np.array(spreads)
    print(
        f"{len(error)} videos of {args.data} ({args.split}, after {args.after_objects} objects, "
        f"{args.masks if realistic else 'plain'} masks), model {predictor.path}; "
        f"{platform.machine()}, torch {torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    for i, name in enumerate(NAMES):
        rho = spearmanr(error[:, i], spread[:, i])[0]
        cells = "  ".join(
            f"a={a:g}: {np.mean(error[:, i] <= Z_10_90 * a * spread[:, i]):.0%}" for a in FACTORS
        )
        print(
            f"{name:9} MAE {error[:, i].mean():.3f}, mean σ₁ {spread[:, i].mean():.3f}, rank "
            f"correlation with the error {rho:+.2f}; 10–90 % holds the truth: {cells}"
        )
    if scales:  # model.scale_head: the members' own estimate of their error (a Laplace scale)
        scale = np.array(scales)
        for i, name in enumerate(NAMES):
            rho = spearmanr(error[:, i], scale[:, i])[0]
            own = "  ".join(
                f"a={a:g}: {np.mean(error[:, i] <= a * LN5 * scale[:, i]):.0%}"
                for a in SCALE_FACTORS
            )
            print(
                f"{name:9} the scale head alone: mean b {scale[:, i].mean():.3f}, rank correlation "
                f"with the error {rho:+.2f}; ± a · ln 5 · b holds the truth: {own}"
            )
    if args.write:
        chosen = [  # the grid's factor whose coverage is nearest 80 % (ties: the wider)
            min(
                FACTORS[::-1],
                key=lambda a: abs(np.mean(error[:, i] <= Z_10_90 * a * spread[:, i]) - 0.8),
            )
            for i in range(len(NAMES))
        ]
        predictor.metadata["spread_factor"] = chosen
        predictor.metadata["spread_factor_how"] = (
            f"benchmarks/network_intervals.py on {len(error)} videos of {args.data.name} "
            f"({args.split}): per observable, the factor whose 10–90 % interval held the truth "
            "nearest 80 % of the time"
        )
        save_predictor(predictor.model, predictor.path, predictor.metadata)  # weights unchanged
        print(f"wrote spread_factor {chosen} into {config_path(predictor.path)}")
    factor = np.array(predictor.spread_factor)
    held = np.mean(error <= Z_10_90 * factor * spread, 0)
    width = np.mean(2 * Z_10_90 * factor * spread, 0)
    print(
        f"the model's factors {' / '.join(f'{a:g}' for a in factor)}: holds "
        + " / ".join(f"{h:.0%}" for h in held)
        + ", mean width "
        + " / ".join(f"{w:.2f}" for w in width)
        + " (before cutting to the reachable range)"
    )


if __name__ == "__main__":
    main()
