"""3DGS predictors on held-out objects: PSNR of frame 0 in the 4 views and Chamfer distance.

For every sample of a split: frame 0 of view 0 (the object on black: the plain look masked as
``predict`` masks it, the realistic look by its stored true masks) → each predictor's Gaussians
on the object's pixels (world frame, the true camera) → rendered into view 0 (the input) and
views 1–3 (unseen) → PSNR against the stored frames over the truth's foreground (the object's
pixels, as ``evaluate``); beside it two scores that count Gaussians spilled past the object's
outline, which that one does not: PSNR over the whole image (the object on black) in the unseen
views, and their silhouette IoU (alpha > 0.5 against the truth's pixels); Chamfer distance
(squared, m², as ``evaluate``) between the predicted and the true Gaussian centres at frame 0;
the centres' extent along view 0's depth over the truth's (a shape too deep along the view sits
too low: the asset lands early) and the lowest centre's height against the truth's. Rows:

- each ``--model`` (a whole-frame model, or a crop model with the object's distance read from
  the video's free fall as ``predict`` reads it, ``object_distance``, its Gaussians on the
  finer crop ``predict`` puts them on, ``reconstruct.DETAIL_FACTOR`` times the model's;
  ``--truth-depth`` adds the crop models with the true distance; ``--detail S`` a row with the
  Gaussians on an S-px crop, 0: the model's own);
- the trivial geometry: a flat cut-out of the input view's object pixels, at the distance the
  video gives (2 m for the plain look's whole-frame model), one pixel-sized Gaussian each;
- the true Gaussians † (their colours are the object's, unlit: on the realistic look the frames
  are lit, shaded, noisy and compressed), and on the realistic look the same shaded by the
  scene's light as the frames were (``shade_gaussians`` with the sample's stored look; the
  upper bound of a score against the lit frames: the right shape and the light known). On
  the realistic look every row also gets a score without the frames' noise, compression and
  backdrop: PSNR in all 4 views against the lit true Gaussians' render, over its pixels
  (alpha > 0.5) — how far the reconstruction is from the object as our renderer draws it.

    python benchmarks/eval_gaussian_predictor.py data/real_pyb --model runs/gs_crop \
        --model src/reconphys/weights/gaussian_predictor.safetensors [--limit 40]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import torch
from common import machine_description

from reconphys.capture.masks import subtract_background
from reconphys.capture.observation import stored_observation
from reconphys.data import DropDataset
from reconphys.data.scene import look_from_dict
from reconphys.errors import InputError
from reconphys.eval.metrics import chamfer_distance, foreground_mask, psnr
from reconphys.models.gaussian_predictor import billboard_gaussians
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.models.reconstruct import object_distance, predicted_gaussians
from reconphys.render import Cameras, render
from reconphys.render.scene import shade_gaussians
from reconphys.threads import set_cpu_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--model", action="append", default=None, help="repeatable")
    parser.add_argument("--truth-depth", action="store_true")
    parser.add_argument(
        "--detail",
        action="append",
        type=int,
        default=[],
        help="crop models: a row with the Gaussians on an S-px crop (0: the model's size); "
        "repeatable. The model's row is predict's (reconstruct.DETAIL_FACTOR)",
    )
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    torch.set_flush_denormal(True)
    models = [load_gaussian_predictor(m) for m in (args.model or [None])]
    dataset = DropDataset(args.data, split=args.split)
    realistic = dataset.settings.scene != "plain"
    count = len(dataset) if args.limit is None else min(args.limit, len(dataset))
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description('cpu')}")
    rows: dict[str, dict[str, list[float]]] = {}
    started = time.perf_counter()

    def depth_extent(means, w2c) -> float:  # 5–95 % extent of the centres in camera z, m
        z = means @ w2c[2, :3] + w2c[2, 3]
        return float(torch.quantile(z, 0.95) - torch.quantile(z, 0.05))

    def add(name: str, gaussians, cameras, targets, truth_means, lit=None) -> str:
        with torch.no_grad():
            out = render(gaussians, cameras)
        rgb = out.rgb  # [V, H, W, 3]
        scores = psnr(rgb, targets)
        truth = foreground_mask(targets)[1:]  # the unseen views' object pixels
        whole = psnr(rgb[1:], targets[1:], torch.ones_like(truth))
        drawn = out.alpha.reshape(targets.shape[:-1])[1:] > 0.5
        iou = (drawn & truth).sum((-1, -2)) / (drawn | truth).sum((-1, -2)).clamp_min(1)
        row = rows.setdefault(
            name,
            {
                k: []
                for k in ("input", "novel", "all", "cd", "n", "whole", "iou", "deep", "low", "lit")
            },
        )
        if lit is not None:  # the lit truth's render (rgb [V, H, W, 3], alpha [V, H, W])
            row["lit"].append(float(psnr(rgb, lit[0], lit[1] > 0.5).nanmean()))
        w2c0 = cameras.world_to_cam[0].to(truth_means)
        row["deep"].append(depth_extent(gaussians.means, w2c0) / depth_extent(truth_means, w2c0))
        row["low"].append(float(gaussians.means[:, 2].min() - truth_means[:, 2].min()))
        row["whole"].append(float(whole.nanmean()))
        row["iou"].append(float(iou.mean()))
        row["input"].append(float(scores[0]))
        row["novel"].append(float(scores[1:].nanmean()))
        row["all"].append(float(scores.nanmean()))
        row["cd"].append(chamfer_distance(gaussians.means, truth_means, 2048))
        row["n"].append(gaussians.num_gaussians)
        return f"{name}: {row['all'][-1]:5.2f} dB"

    for index in range(count):
        item, meta = dataset[index], dataset.meta(index)
        frames = item["frames"].float()  # [V, T, H, W, 3]
        if realistic:
            masks = dataset.masks(index).float()  # [V, T, H, W]
            frames = frames * masks[..., None]
        else:
            masks = torch.stack([subtract_background(view) for view in frames])
        size = frames.shape[2]
        K, w2c = item["K"].float(), item["world_to_cam"].float()
        cameras = Cameras(K, w2c, size, size)
        targets = frames[:, 0]
        observation = stored_observation(
            frames[0],
            K[0],
            w2c[0],
            float(meta["frame_dt"]),
            item["id"],
            masks=masks[0] if realistic else None,
        )
        asset = dataset.asset(index)
        with torch.no_grad():
            truth = asset.gaussians.map(lambda t: t.clone())
            truth.means = asset.gaussian_means(item["anchors"][:1])[0]
        true_depth = float((w2c[0, :3, :3] @ item["anchors"][0].mean(0) + w2c[0, :3, 3])[2])
        try:
            video_depth, how = object_distance(observation)
        except InputError:
            video_depth, how = float("nan"), "none"
        lit = None
        if realistic:
            lit_truth = shade_gaussians(truth, look_from_dict(meta["scene"]["look"]))
            with torch.no_grad():
                drawn = render(lit_truth, cameras)
            lit = (drawn.rgb, drawn.alpha.reshape(targets.shape[:-1]))
        line = [add("true Gaussians †", truth, cameras, targets, truth.means, lit)]
        if realistic:
            line.append(add("true Gaussians, lit †", lit_truth, cameras, targets, truth.means))
        for loaded in models:
            name = (
                loaded.path.parent.name
                if loaded.path.name == "model.safetensors"
                else loaded.path.stem
            )
            try:
                gaussians, _ = predicted_gaussians(observation, loaded)
                line.append(add(name, gaussians, cameras, targets, truth.means, lit))
            except InputError as e:
                line.append(f"{name}: refused ({e})")
            for detail in args.detail if loaded.model.config.crop else []:
                try:
                    gaussians, _ = predicted_gaussians(observation, loaded, detail=detail)
                    row = f"{name} (detail {detail or loaded.model.config.resolution} px)"
                    line.append(add(row, gaussians, cameras, targets, truth.means, lit))
                except InputError as e:
                    line.append(f"{name}: refused ({e})")
            if loaded.model.config.crop and args.truth_depth:
                gaussians, _ = predicted_gaussians(observation, loaded, distance=true_depth)
                line.append(
                    add(name + " (true distance)", gaussians, cameras, targets, truth.means, lit)
                )
        flat_depth = video_depth if video_depth == video_depth else 2.0
        flat = billboard_gaussians(frames[0, 0], masks[0, 0], K[0], w2c[0], flat_depth)
        line.append(add("flat cut-out", flat, cameras, targets, truth.means, lit))
        print(
            f"{item['id'][-28:]:28s} depth {true_depth:.2f} m, from the video {video_depth:.2f} "
            f"({how}) | " + " | ".join(line),
            flush=True,
        )
    print(
        f"\n{count} {args.split} samples of {args.data} ({'realistic' if realistic else 'plain'} "
        f"look, {size} px), {time.perf_counter() - started:.0f} s. PSNR of frame 0 over the "
        "truth's foreground: all 4 views / input view 0 / unseen views 1–3; Chamfer (m²); "
        "Gaussians kept; the unseen views' PSNR over the whole image and silhouette IoU (spill "
        "counted); the centres' depth extent along view 0 over the truth's (5–95 %, median); the "
        "lowest centre's height − the truth's (cm, mean)"
        + ("; PSNR, 4 views, against the lit true Gaussians' render" if realistic else "")
    )
    for name, values in rows.items():
        print(
            f"  {name:34s} {statistics.fmean(values['all']):6.2f} dB  "
            f"{statistics.fmean(values['input']):6.2f} dB  "
            f"{statistics.fmean(values['novel']):6.2f} dB  "
            f"{statistics.fmean(values['cd']):.3e}  {statistics.fmean(values['n']):7.0f}  "
            f"{statistics.fmean(values['whole']):6.2f} dB  {statistics.fmean(values['iou']):.3f}  "
            f"×{statistics.median(values['deep']):.2f}  "
            f"{100 * statistics.fmean(values['low']):+5.1f} cm"
            + (f"  {statistics.fmean(values['lit']):6.2f} dB" if values.get("lit") else "")
        )


if __name__ == "__main__":
    main()
