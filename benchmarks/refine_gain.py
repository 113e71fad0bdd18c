"""Does test-time refinement (``predict --refine N``) improve future prediction?

For every sample of a dataset split: the shipped (or ``--model``) physics predictor gives the
feed-forward attributes on the sample's true geometry and initial state (as ``predict DATASET
--sample ID`` does); :func:`reconphys.pipeline.refine.refine` then takes N photometric steps on
the input view's frames 0..19. Both assets are simulated for 30 frames and scored like
``reconphys evaluate`` (PSNR over the 4 views, frames 0–19 = reconstruction, 20–29 = future).

    python benchmarks/refine_gain.py data/cpu_small --split test --steps 50

Prints one line per sample, how many improved, the median gain and the seconds per refinement;
records the machine and the command. Ground-truth geometry: the numbers are upper bounds.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time

import numpy as np
import torch
from common import machine_description  # benchmarks/common.py (run from anywhere: same folder)

from reconphys.eval.evaluate import EvalSettings, predicted_means, score
from reconphys.eval.methods import Prediction
from reconphys.eval.samples import EvalSet
from reconphys.pipeline.predict import predict
from reconphys.pipeline.refine import refine
from reconphys.threads import set_cpu_threads

INPUT_FRAMES = 20


def windows(sample, asset) -> tuple[float, float]:
    """(reconstruction PSNR frames 0–19, future PSNR frames 20–29), dB, mean over 4 views."""
    gaussians, means = predicted_means(
        Prediction(asset=asset), sample.num_frames, torch.device("cpu")
    )
    values, _ = score(
        sample, gaussians, means, EvalSettings(emd_points=64, chamfer_points=256), None
    )
    psnr = values["psnr"]
    return float(np.nanmean(psnr[:INPUT_FRAMES])), float(np.nanmean(psnr[INPUT_FRAMES:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--model", default=None)
    parser.add_argument("--resolution", type=int, default=64, help="render size of the loss")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", default=None, help="also write the per-sample rows here")
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    torch.set_flush_denormal(True)
    eval_set = EvalSet(args.data, args.split, limit=args.limit)
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description('cpu')}")
    print("sample              recon FF→refined    future FF→refined   gain   seconds")
    rows = []
    for index in range(len(eval_set)):
        sample = eval_set.load(index)
        result = predict(args.data, sample=sample.id, model=args.model, refine=False)
        observation = result.observation  # the model's view of the stored frames
        started = time.perf_counter()
        refined, history = refine(result.asset, observation, args.steps, resolution=args.resolution)
        seconds = time.perf_counter() - started
        recon_ff, future_ff = windows(sample, result.asset)
        recon_rf, future_rf = windows(sample, refined)
        gain = future_rf - future_ff
        rows.append(
            {
                "sample": sample.id,
                "recon_ff": recon_ff,
                "recon_refined": recon_rf,
                "future_ff": future_ff,
                "future_refined": future_rf,
                "seconds": seconds,
                "loss_initial": history["loss_initial"],
                "loss_best": history["loss_best"],
                "feed_forward": result.attributes,
                "refined": history["attributes"],
                "truth": sample.attributes,
            }
        )
        print(
            f"{sample.id:18s}  {recon_ff:6.2f} → {recon_rf:6.2f}   {future_ff:6.2f} → "
            f"{future_rf:6.2f}   {gain:+5.2f}  {seconds:7.1f}",
            flush=True,
        )
    gains = [r["future_refined"] - r["future_ff"] for r in rows]
    better = sum(g > 0 for g in gains)
    print(
        f"future PSNR improved on {better}/{len(rows)} samples; median gain "
        f"{statistics.median(gains):+.2f} dB, mean {statistics.fmean(gains):+.2f} dB; "
        f"{statistics.median(r['seconds'] for r in rows):.1f} s per refinement (median)"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    if any(not math.isfinite(g) for g in gains):
        print("warning: some scores are NaN (a simulation failed)")


if __name__ == "__main__":
    main()
