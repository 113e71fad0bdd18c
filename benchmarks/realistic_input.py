"""What the front end reads from a realistic recording, against the truth
(docs/usage.md#masks-without-a-clean-plate, docs/usage.md#camera-and-ground-from-the-video).

For view 0 of every test sample of a realistic-look dataset (``make-data --scene realistic``),
taken as a user's recording (frames only):

- masks: the mask segmenter's IoU with the stored true masks (mean over frames), beside the
  temporal-median background subtraction;
- camera and ground (capture/calibrate.py), from the segmenter's masks (read to a pixel of the
  size they were segmented at, as predict reads them: a 384-px clip segmented at 128 px to
  three of its own) and from the true masks,
  with the vertical field of view known (a camera file without pose) or assumed (the default),
  the ground as predict reads it (from the first touch, else where the object rests) and, for
  the record, from the rest alone:
  scale error = the object's metric size read from the video / the truth − 1 (from the distance
  and the focal length: size = pixels · distance / f), and how often the size's 10–90 % interval
  (prediction.json's size_factor_10_90) holds the truth, and the drop height's
  (drop_height_m_10_90: frame 0's lowest point above the ground read); ground error = the drop
  height read from the video − the true one (the height above the estimated ground of the
  object's true lowest point in frame 0, at its pixel and the depth the estimate gives the
  object), metres: what decides when the simulated object lands.

Rows ``segmenter_default_fov_drop_height_given_x{F}`` give the estimate the true drop height
times F (``--drop-height-factors``, default 1: a user who measured it; 0.5 or 2: one who did not),
as ``predict --drop-height`` does, and count its refusals and warnings.

``--aspect W:H`` cuts each clip to that shape about its centre first (a phone's 9:16 portrait
frame from the data's square one; the true camera's principal point follows) and adds the rule
before 2026-11-28 as a row: 45° vertical whatever the shape (``segmenter_45_vertical``).

    python benchmarks/realistic_input.py data/real_other [--limit 40] [--aspect 9:16]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

import numpy as np
import torch
from common import camera_read_errors, mean_mask_iou, rating_line

from reconphys.capture.calibrate import (
    FALL_FIT_PX,
    SEGMENTER_FALL_FIT_PX,
    estimate_camera,
)
from reconphys.capture.lens import default_fov_deg
from reconphys.capture.observation import segmented_pixel
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.models.mask_segmenter import MAX_SIDE, load_mask_segmenter, rated_segment_clip


def centre_cut(frames, truth, K, aspect: tuple[int, int] | None):
    """Frames [T, H, W, 3], masks [T, H, W] and K [3, 3] cut about the centre to ``aspect``
    (width, height); unchanged when None."""
    if aspect is None:
        return frames, truth, K
    height, width = truth.shape[1:]
    if width * aspect[1] > height * aspect[0]:  # too wide: keep the middle columns
        keep_h, keep_w = height, round(height * aspect[0] / aspect[1])
    else:
        keep_h, keep_w = round(width * aspect[1] / aspect[0]), width
    top, left = (height - keep_h) // 2, (width - keep_w) // 2
    K = K.clone().double()
    K[0, 2] -= left
    K[1, 2] -= top
    rows, cols = slice(top, top + keep_h), slice(left, left + keep_w)
    return frames[:, rows, cols], truth[:, rows, cols], K


def camera_errors(
    masks, item, meta, fov_deg, fit_px=FALL_FIT_PX, touch=True, K=None, drop_factor=None
) -> dict:
    anchors = item["anchors"].double()  # [T, N_A, 3]
    lowest = anchors[0][anchors[0][:, 2].argmin()]  # frame 0's lowest point: the drop height
    given = None if drop_factor is None else drop_factor * float(lowest[2])  # --drop-height
    frame_dt = float(meta["frame_dt"])
    estimate = estimate_camera(masks, frame_dt, fov_deg, fit_px, touch, drop_height=given)
    K = item["K"][0] if K is None else K
    errors = camera_read_errors(estimate, K, item["world_to_cam"][0], anchors[0].mean(0), lowest)
    return {
        **errors,
        "contact_s": estimate.contact_s,
        "size_factor_10_90": list(estimate.size_factor_10_90),  # true size / read: 10–90 %
        "drop_height_m": estimate.drop_height,  # frame 0's lowest point above the ground read
        "drop_height_m_10_90": list(estimate.drop_height_10_90),
        "drop_height_true_m": float(lowest[2]),
        "drop_height_warned": estimate.drop_height_warning is not None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--split", default="test")
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    parser.add_argument(
        "--segmenter",
        nargs="+",
        default=None,
        help="weights: one file, or several averaged (default: the shipped ensemble)",
    )
    parser.add_argument(
        "--max-side", type=int, default=MAX_SIDE, help="segment at most this size, px"
    )
    parser.add_argument("--aspect", default=None, help="W:H: cut each clip to it (module doc)")
    parser.add_argument(
        "--drop-height-factors",
        default="1",
        help="comma-separated: rows with the true drop height times each given (--drop-height)",
    )
    args = parser.parse_args()
    factors = [float(x) for x in args.drop_height_factors.split(",") if x]
    aspect = tuple(int(v) for v in args.aspect.split(":")) if args.aspect else None
    torch.set_num_threads(2)
    dataset = DropDataset(args.data, split=args.split, views=[0])
    model = load_mask_segmenter(args.segmenter)
    rows = []
    started = time.perf_counter()
    count = len(dataset) if args.limit is None else min(args.limit, len(dataset))
    for index in range(count):
        item, meta = dataset[index], dataset.meta(index)
        frames, truth = item["frames"][0], dataset.masks(index)[0].float()
        frames, truth, K = centre_cut(frames, truth, item["K"][0], aspect)
        tic = time.perf_counter()
        masks, rating = rated_segment_clip(model, frames, args.max_side)
        seconds = time.perf_counter() - tic
        median = ((frames - frames.median(0).values).norm(dim=-1) > 0.08).float()
        row = {
            "id": item["id"],
            "launch": meta["initial_state"]["launch"],
            "iou_segmenter": mean_mask_iou(masks, truth),
            "masks_rating": rating,
            "iou_median": mean_mask_iou(median, truth),
            "segment_seconds": seconds,
        }
        fov_true = math.degrees(2 * math.atan(0.5 * frames.shape[1] / float(K[1, 1])))
        # the segmenter's masks are right to a pixel of the size they were segmented at: a clip
        # larger than that is read to as many of its own pixels, as predict reads it
        segmenter_px = SEGMENTER_FALL_FIT_PX * segmented_pixel(masks, rating)
        # as predict reads them (the ground from the first touch, else the rest); the last row
        # is the ground from the rest alone, the rule before the touch (for the record)
        for name, used, fov, fit_px, touch in (
            ("true_masks_true_fov", truth, fov_true, FALL_FIT_PX, True),
            ("segmenter_true_fov", masks, fov_true, segmenter_px, True),
            ("segmenter_default_fov", masks, None, segmenter_px, True),
            ("segmenter_default_fov_rest", masks, None, segmenter_px, False),
        ) + ((("segmenter_45_vertical", masks, 45.0, segmenter_px, True),) if aspect else ()):
            try:
                row[name] = camera_errors(used, item, meta, fov, fit_px, touch, K)
            except InputError as e:
                row[name] = {"refused": str(e)}
        for factor in factors:  # a user who measured the drop height (× factor: wrongly)
            name = f"segmenter_default_fov_drop_height_given_x{factor:g}"
            try:
                row[name] = camera_errors(masks, item, meta, None, segmenter_px, True, K, factor)
            except InputError as e:
                row[name] = {"refused": str(e), "field": e.field}
        rows.append(row)
        print(
            f"{row['id']}: IoU {row['iou_segmenter']:.3f} (median {row['iou_median']:.3f}) "
            + " ".join(
                f"{n}: "
                + (
                    f"scale {row[n]['scale_error']:+.3f} ground {row[n]['ground_error_m']:+.3f}"
                    if "scale_error" in row[n]
                    else "refused"
                )
                for n in ("true_masks_true_fov", "segmenter_default_fov")
            ),
            flush=True,
        )
    print(
        f"\n{len(rows)} samples of {args.data} ({args.split}), view 0; "
        f"{platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{time.perf_counter() - started:.0f} s; segmenter {args.segmenter or 'shipped'}, "
        f"at most {args.max_side} px"
    )
    ious = np.array([r["iou_segmenter"] for r in rows])
    print(
        f"mask IoU: segmenter mean {ious.mean():.3f} (median {np.median(ious):.3f}, min "
        f"{ious.min():.3f}), temporal median {np.mean([r['iou_median'] for r in rows]):.3f}; "
        f"segmenter {np.mean([r['segment_seconds'] for r in rows]):.2f} s a clip"
    )
    print(rating_line([r["masks_rating"] for r in rows], list(ious)))
    for name in [n for n in rows[0] if isinstance(rows[0][n], dict) and n != "masks_rating"]:
        good = [r[name] for r in rows if "scale_error" in r[name]]
        refused = len(rows) - len(good)
        if not good:
            print(f"{name}: all refused")
            continue
        scale = np.abs([g["scale_error"] for g in good])
        ground = np.abs([g["ground_error_m"] for g in good])
        held = [
            lo <= 1 / (1 + g["scale_error"]) <= hi
            for g in good
            for lo, hi in [g["size_factor_10_90"]]
        ]
        drop = [g["drop_height_m_10_90"] + [g["drop_height_true_m"]] for g in good]
        if "_given_" in name:  # the interval is the value given; what the checks made of it
            checked = sum(r[name].get("field") == "--drop-height" for r in rows)
            print(
                f"{name}: |ground error| mean {100 * ground.mean():.1f} cm median "
                f"{100 * np.median(ground):.1f} cm ≤ 2 cm: {(ground <= 0.02).mean():.0%}; "
                f"refused {refused} (by the drop height's check {checked}); warned of "
                f"{sum(g['drop_height_warned'] for g in good)} of {len(good)} answered"
            )
            continue
        print(
            f"{name}: |scale error| mean {scale.mean():.3f} median {np.median(scale):.3f} "
            f"≤ 10 %: {(scale <= 0.1).mean():.0%}; |ground error| mean {100 * ground.mean():.1f} "
            f"cm median {100 * np.median(ground):.1f} cm ≤ 2 cm: {(ground <= 0.02).mean():.0%}; "
            f"refused {refused}; the size's 10–90 % interval holds the truth on {np.mean(held):.0%}"
            f"; the drop height's on {np.mean([lo <= t <= hi for lo, hi, t in drop]):.0%} "
            f"(mean width {100 * np.mean([hi - lo for lo, hi, _ in drop]):.1f} cm)"
        )
    height, width = truth.shape[1:]
    print(
        f"(the default vertical field of view: {default_fov_deg(width, height):.1f}° at "
        f"{width}×{height})"
    )
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
