"""`predict` on realistic-look recordings as a user brings them
(docs/usage.md#camera-and-ground-from-the-video).

For view 0 of the first N test samples of a realistic dataset, the sample is written as
`reconphys data video` writes it (the mp4, camera.json, the true Gaussians as gaussians.ply) and
`predict`'s default path (network + search, segmenter masks) runs on it three ways:

- `true_geometry`: the mp4 + camera.json + the true Gaussians († an upper bound),
- `camera_file`: the mp4 + camera.json (the 3DGS predictor's geometry),
- `mp4_only`: the mp4 alone (camera estimated from the video),
- `masks_dir` (not in the default set): the mp4 + the true masks as `--masks DIR` (a
  segmentation tool's masks at their best; camera estimated from the video, its ground from
  the first touch),
- `mp4_drop_height` (not in the default set): the mp4 alone with the true drop height given
  (`--drop-height`: frame 0's lowest point above the ground, as a user with a tape measure);
  `mp4_search_ground` (not in the default set): the mp4 alone, the search moving the ground
  read from the video too (`predict(search_ground=True)`).

Printed: MAE of log k/m, log d/m and friction against the truth, beside the trivial predictor
(the attribute ranges' midpoints, the medians of a uniform training distribution), their ratios,
refusals and seconds a scene.

    python benchmarks/realistic_predict.py data/real_other --limit 20

Future PSNR: the returned asset simulated from its initial state and rendered into the camera
`predict` used (the file's or the one read from the video), frames 20–29 against the recording
cut out by its true masks, PSNR over the true masks' pixels (eval/metrics.psnr), beside the same
asset with the trivial attributes (what the physics adds), and the asset's silhouette IoU
against the true masks over the same frames (spill and misplacement counted, which the PSNR over
the true masks' pixels does not).

Drop height: the returned asset's lowest anchor above its ground at frame 0 minus the object's
(what decides when the simulated object lands), mean |·| in cm.

Intervals: the share of samples whose 10–90 % interval holds the truth. ``--split train``
chooses a setting on training samples (never the test split).
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from common import after_first_objects, user_bundle

import reconphys
from reconphys.capture.masks import subtract_background
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.eval.metrics import psnr
from reconphys.physics import ATTRIBUTE_RANGES
from reconphys.pipeline.demo import true_observables
from reconphys.pipeline.preview import simulate_and_render
from reconphys.render import render
from reconphys.render.video import write_image
from reconphys.threads import set_cpu_threads

FUTURE = slice(20, 30)  # evaluate's future window (frames 20–29)

CONFIGS = ("true_geometry", "camera_file", "mp4_only")  # the default set; also: module doc


def observables(attributes: dict) -> np.ndarray:  # [3] log k/m, log d/m, friction
    return np.array(list(true_observables(attributes).values()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=20)
    parser.add_argument("--configs", default=",".join(CONFIGS))
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    parser.add_argument("--split", default="test", help="test, or train to choose a setting")
    parser.add_argument(
        "--after-objects",
        type=int,
        default=0,
        help="skip the split's first N objects (with --split train: the validation meshes a "
        "model trained on the first N never saw)",
    )
    parser.add_argument("--threads", type=int, default=2, help="CPU threads (torch and Numba)")
    args = parser.parse_args()
    configs = args.configs.split(",")
    set_cpu_threads(args.threads)  # torch's and Numba's: a second busy thread each otherwise
    root = Path(args.data)
    dataset = DropDataset(root, split=args.split, views=[0])
    if args.after_objects:
        dataset.samples = after_first_objects(dataset.samples, args.after_objects)
    midpoints = {k: 0.5 * (lo + hi) for k, (lo, hi) in ATTRIBUTE_RANGES.items()}
    trivial = observables(midpoints)
    rows = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        for index in range(min(args.limit, len(dataset))):
            meta = dataset.meta(index)
            item = dataset[index]
            bundle = user_bundle(dataset, index, Path(folder), item)
            truth = observables(meta["attributes"])
            if dataset.settings.scene == "plain":  # the object on black: its stored frames say
                masks = subtract_background(item["frames"][0]) > 0.5
            else:
                masks = dataset.masks(index)[0]  # [T, H, W] bool, view 0
            if "masks_dir" in configs:
                (bundle / "masks").mkdir()
                for t, mask in enumerate(masks.numpy()):
                    write_image(
                        bundle / "masks" / f"{t:04d}.png",
                        mask.astype(np.uint8)[..., None].repeat(3, -1) * 255,
                    )
            target = item["frames"][0] * masks[..., None]

            def future_psnr(asset, observation, masks=masks, target=target) -> float:
                frames = simulate_and_render(  # over the recording's plate, as the preview
                    asset,
                    observation.unmasked.cpu(),
                    observation.masks.cpu(),
                    observation.camera,
                    masks.shape[0],
                )
                if frames.shape != target.shape:
                    raise ValueError(f"rendered {list(frames.shape)}, recording {target.shape}")
                scores = psnr(frames[FUTURE], target[FUTURE], mask=masks[FUTURE])
                return float(scores.nanmean())

            def future_iou(asset, observation, masks=masks) -> float:
                """The asset's silhouette (alpha > 0.5) against the true masks, frames 20–29:
                where the re-simulated object is, spill counted (the PSNR above is not)."""
                trajectory = asset.simulate(FUTURE.stop - 1, torch.device("cpu"))
                means = asset.gaussian_means(trajectory.x[0])  # [T, N, 3]
                cameras = observation.camera.cameras()
                scores = []
                with torch.no_grad():
                    for t in range(FUTURE.start, FUTURE.stop):
                        alpha = render(asset.gaussians.with_means(means[t]), cameras).alpha[0]
                        drawn, truth = alpha.reshape(masks.shape[1:]) > 0.5, masks[t] > 0.5
                        scores.append(
                            float((drawn & truth).sum() / (drawn | truth).sum().clamp_min(1))
                        )
                return float(np.mean(scores))

            row = {"id": meta["id"], "truth": truth.tolist()}
            for config in configs:
                kwargs = {}
                if not config.startswith("mp4_") and config != "masks_dir":
                    kwargs["camera"] = bundle / "camera.json"
                if config == "mp4_drop_height":
                    kwargs["drop_height"] = meta["initial_state"]["drop_height"]
                if config == "mp4_search_ground":
                    kwargs["search_ground"] = True
                if config == "masks_dir":
                    kwargs["masks"] = bundle / "masks"
                if config == "true_geometry":
                    kwargs["gaussians"] = bundle / "gaussians.ply"
                tic = time.perf_counter()
                try:
                    result = reconphys.predict(bundle / "video.mp4", **kwargs)
                except InputError as e:
                    row[config] = {"refused": str(e)}
                    continue
                predicted = np.array([result.observables[k] for k in result.observables])
                intervals = result.intervals
                motion = result.details.get("initial_velocity", {})
                row[config] = {
                    "predicted": predicted.tolist(),
                    "error": np.abs(predicted - truth).tolist(),
                    "seconds": time.perf_counter() - tic,
                    "speed": float(np.linalg.norm(motion.get("linear_m_s", [np.nan] * 3))),
                    "future_psnr": future_psnr(result.asset, result.observation),
                    "future_iou": future_iou(result.asset, result.observation),
                    # what decides when the simulated object lands: the asset's lowest anchor
                    # above its ground at frame 0, minus the object's (the dataset's z = 0)
                    "drop_height_error_m": float(
                        result.asset.x0[:, 2].min()
                        - result.asset.physics.ground_height
                        - item["anchors"][0][:, 2].min()
                    ),
                    "future_psnr_trivial": future_psnr(
                        replace(result.asset, physics=replace(result.asset.physics, **midpoints)),
                        result.observation,
                    ),
                    "search": result.details.get("search"),  # start, profiles, temperature
                    "intervals": intervals,
                    "network_sigma": result.details.get("network_sigma"),
                    "covered": None
                    if intervals is None
                    else [
                        bool(lo <= t <= hi)
                        for (lo, hi), t in zip(intervals.values(), truth, strict=True)
                    ],
                }
            rows.append(row)
            print(
                meta["id"],
                " ".join(
                    f"{c}: "
                    + (
                        " ".join(f"{e:.2f}" for e in row[c]["error"])
                        if "error" in row[c]
                        else "refused"
                    )
                    for c in configs
                ),
                flush=True,
            )
    print(
        f"\n{len(rows)} test samples of {args.data}, view 0; "
        f"{platform.machine()}, torch {torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    for config in configs:
        done = [r for r in rows if "error" in r[config]]
        if not done:
            print(f"{config}: all refused")
            continue
        mae = np.mean([r[config]["error"] for r in done], axis=0)
        base = np.mean([np.abs(trivial - np.array(r["truth"])) for r in done], axis=0)
        seconds = np.mean([r[config]["seconds"] for r in done])
        covered = [r[config]["covered"] for r in done if r[config]["covered"] is not None]
        coverage = (
            " / ".join(f"{100 * c:.0f} %" for c in np.mean(covered, axis=0)) if covered else "–"
        )
        widths = [[hi - lo for lo, hi in r[config]["intervals"].values()] for r in done
                  if r[config]["intervals"] is not None]  # fmt: skip
        if widths:
            coverage += " (mean widths " + " / ".join(f"{w:.2f}" for w in np.mean(widths, 0)) + ")"
        print(
            f"{config}: {len(done)} answered, {len(rows) - len(done)} refused; MAE log k/m "
            f"{mae[0]:.3f} log d/m {mae[1]:.3f} f {mae[2]:.3f} (trivial {base[0]:.3f} / "
            f"{base[1]:.3f} / {base[2]:.3f}; ratios {base[0] / mae[0]:.2f}× / "
            f"{base[1] / mae[1]:.2f}× / {base[2] / mae[2]:.2f}×); 10–90 % intervals cover "
            f"{coverage}; {seconds:.1f} s a scene; initial speed read mean "
            f"{np.mean([r[config]['speed'] for r in done]):.3f}, max "
            f"{np.max([r[config]['speed'] for r in done]):.3f} m/s"
        )
        future = np.array([r[config]["future_psnr"] for r in done])
        future_trivial = np.array([r[config]["future_psnr_trivial"] for r in done])
        print(
            f"  future PSNR (view 0, frames 20–29, true masks' pixels) {np.nanmean(future):.2f} "
            f"dB, its asset with the trivial attributes {np.nanmean(future_trivial):.2f} dB; "
            f"ahead on {np.mean(future > future_trivial):.0%}; its silhouette IoU there "
            f"{np.mean([r[config]['future_iou'] for r in done]):.3f}"
        )
        drop = 100 * np.array([r[config]["drop_height_error_m"] for r in done])
        print(
            f"  the asset's drop height (its lowest anchor above its ground) − the truth: "
            f"|mean| {np.abs(drop).mean():.1f} cm, median {np.median(np.abs(drop)):.1f} cm, "
            f"signed {drop.mean():+.1f} cm, ≤ 2 cm {np.mean(np.abs(drop) <= 2):.0%}"
        )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
