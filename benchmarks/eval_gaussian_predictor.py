"""The 3DGS predictor on held-out objects: novel-view PSNR of frame 0 and Chamfer distance.

For every sample of a split: frame 0 of view 0 (masked as ``predict`` masks it) → the predictor's
Gaussians on the object's pixels (world frame, the known camera) → rendered into the three views
it did not see (1, 2, 3) and into view 0 → PSNR against the stored frames (over the foreground of
the truth, as ``evaluate``); Chamfer distance (squared, m², as ``evaluate``) between the predicted
and the true Gaussian centres at frame 0. Beside it, the trivial geometry: a flat cut-out of the
input view's object pixels at the reference depth (2 m), one pixel-sized Gaussian each.

    python benchmarks/eval_gaussian_predictor.py data/cpu_small [--model runs/gs_cpu_small]
"""

from __future__ import annotations

import argparse
import statistics
import sys

import torch
from common import machine_description

from reconphys.capture.masks import subtract_background
from reconphys.eval.metrics import chamfer_distance, psnr
from reconphys.eval.samples import EvalSet
from reconphys.models.gaussian_predictor import billboard_gaussians, prune_gaussians
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.render import Cameras, render
from reconphys.threads import set_cpu_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--model", default=None, help="default: $RECONPHYS_GS_MODEL or shipped")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    torch.set_flush_denormal(True)
    loaded = load_gaussian_predictor(args.model)
    eval_set = EvalSet(args.data, args.split)
    print(f"# {' '.join(sys.argv)}  (model {loaded.path})")
    print(f"# {machine_description('cpu')}")
    rows = {
        "model": {"novel": [], "input": [], "cd": []},
        "flat cut-out": {"novel": [], "input": [], "cd": []},
    }
    for index in range(len(eval_set)):
        sample = eval_set.load(index)
        frames = sample.frames[:, 0]  # [V, H, W, 3] frame 0
        size = frames.shape[1]
        mask = subtract_background(frames[:1])[0]
        K, w2c = sample.cameras.K, sample.cameras.world_to_cam
        with torch.no_grad():
            g = loaded.model(frames[:1], mask[None], K[:1], w2c[:1]).map(lambda t: t[0])
        predicted = {
            "model": prune_gaussians(g, mask.reshape(-1)),
            "flat cut-out": billboard_gaussians(
                frames[0], mask, K[0], w2c[0], loaded.model.config.reference_depth
            ),
        }
        truth = sample.gaussian_means[0]
        line = []
        for name, gaussians in predicted.items():
            with torch.no_grad():
                rgb = render(gaussians, Cameras(K, w2c, size, size)).rgb  # [V, H, W, 3]
            scores = psnr(rgb, frames)
            rows[name]["input"].append(float(scores[0]))
            rows[name]["novel"].append(float(scores[1:].nanmean()))
            rows[name]["cd"].append(chamfer_distance(gaussians.means, truth, 2048))
            line.append(
                f"{name}: novel {rows[name]['novel'][-1]:5.2f} dB, input "
                f"{rows[name]['input'][-1]:5.2f} dB, CD {rows[name]['cd'][-1]:.2e}"
            )
        print(f"{sample.id:18s} " + " | ".join(line), flush=True)
    print(
        f"\nmean over {len(eval_set)} {args.split} samples: novel views (1–3) PSNR / input view "
        "PSNR / Chamfer (m²)"
    )
    for name, values in rows.items():
        print(
            f"  {name:13s} {statistics.fmean(values['novel']):6.2f} dB  "
            f"{statistics.fmean(values['input']):6.2f} dB  {statistics.fmean(values['cd']):.3e}"
        )


if __name__ == "__main__":
    main()
