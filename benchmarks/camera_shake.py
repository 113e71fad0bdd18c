"""A hand-held camera: what its shake does to the masks and the camera read from the video, and
what taking it out gives back (capture/stabilize.py; docs/usage.md "A hand-held camera").

For view 0 of each clip (a realistic-look dataset's test split, or a folder of
``other_engine.py render`` clips), three ways, each written as an H.264 mp4 and decoded as a
user's recording:

- still: the clip as rendered, cropped by the shake's largest shift on every side;
- shaken: every frame moved by a random walk of ``--step`` px a frame (at most ``--largest``
  px from frame 0, the border repeated), then the same crop — a hand-held phone's turns;
- shaken, taken out: the shaken clip through ``read_shake`` and ``steady``, as ``predict``
  reads it.

Each gets the shipped segmenter's masks (mean IoU with the true masks moved the same way) and
the camera read from them (45° assumed): scale and drop-height errors as
``realistic_input.py``, refusals counted. Also: how often a still clip's shake is read as
more than ``stabilize.STILL_PX`` (a static camera's clip would be changed).

    python benchmarks/camera_shake.py data/engine_val [--limit 40]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import camera_read_errors, mean_mask_iou

from reconphys.capture import read_camera
from reconphys.capture.calibrate import SEGMENTER_FALL_FIT_PX, estimate_camera
from reconphys.capture.masks import border_is_uniform
from reconphys.capture.stabilize import STILL_PX, Shake, crop_margin, read_shake, steady, warp
from reconphys.capture.video import read_video
from reconphys.errors import InputError
from reconphys.models.mask_segmenter import load_mask_segmenter, segment_clip
from reconphys.render.video import write_mp4

FRAME_DT = 0.03


def clips(folder: Path, limit: int | None):
    """(name, frames [T, H, W, 3] in [0, 1], true masks [T, H, W], K, world_to_cam, frame-0
    centre, frame-0 lowest point) of each clip: an engine folder or a dataset's test split."""
    engine = sorted(f for f in folder.iterdir() if (f / "truth.json").is_file())
    if engine:
        for clip in engine[:limit]:
            truth = json.loads((clip / "truth.json").read_text())
            masks = torch.from_numpy(np.load(clip / "masks.npz")["masks"]).float()
            decoded, *_ = read_video(clip / "video.mp4")
            height, width = masks.shape[1:]
            frames = torch.from_numpy(decoded[:, :height, :width, :3]).float() / 255
            camera = read_camera(clip / "camera.json", width, height)
            centre = torch.tensor(truth["centre_m"][0], dtype=torch.float64)
            lowest = torch.tensor(truth["lowest_point_m"][0], dtype=torch.float64)
            yield clip.name, frames, masks, camera.K, camera.world_to_cam, centre, lowest
        return
    from reconphys.data import DropDataset

    dataset = DropDataset(folder, split="test", views=[0])
    for index in range(len(dataset) if limit is None else min(limit, len(dataset))):
        item = dataset[index]
        anchors = item["anchors"][0].double()
        lowest = anchors[anchors[:, 2].argmin()]
        masks = dataset.masks(index)[0].float()
        yield (
            item["id"],
            item["frames"][0].float(),
            masks,
            item["K"][0],
            item["world_to_cam"][0],
            anchors.mean(0),
            lowest,
        )


def shake_walk(count: int, step: float, largest: float, seed: int) -> torch.Tensor:
    """[count, 2] px: a random walk from 0 (``step`` px a frame, each axis), within ±largest."""
    generator = torch.Generator().manual_seed(seed)
    steps = torch.randn(count, 2, generator=generator, dtype=torch.float64) * step
    steps[0] = 0
    return steps.cumsum(0).clamp(-largest, largest).float()


def as_user_reads(frames: torch.Tensor, folder: Path) -> torch.Tensor:
    """The frames through an H.264 mp4 and back."""
    path = folder / "clip.mp4"
    write_mp4(path, (frames.clamp(0, 1).numpy() * 255).round().astype(np.uint8), 1 / FRAME_DT)
    decoded, *_ = read_video(path)
    return torch.from_numpy(decoded[:, : frames.shape[1], : frames.shape[2], :3]).float() / 255


def read_camera_errors(masks, K, w2c, centre, lowest, crop: int) -> dict:
    K = K.double().clone()
    K[0, 2] -= crop
    K[1, 2] -= crop
    try:
        estimate = estimate_camera(masks, FRAME_DT, None, SEGMENTER_FALL_FIT_PX)
    except InputError as error:
        return {"refused": str(error)}
    return camera_read_errors(estimate, K, w2c, centre, lowest)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--step", type=float, default=0.5, help="px a frame, each axis")
    parser.add_argument("--largest", type=float, default=6.0, help="px from frame 0, at most")
    parser.add_argument("--out", default=None, help="JSON file of the per-clip rows")
    args = parser.parse_args()
    torch.set_num_threads(2)
    segmenter = load_mask_segmenter(None)
    crop = math.ceil(args.largest)
    rows, started = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        for index, (name, frames, masks, K, w2c, centre, lowest) in enumerate(
            clips(Path(args.data), args.limit)
        ):
            walk = shake_walk(frames.shape[0], args.step, args.largest, index)
            inner = slice(crop, -crop)
            still = as_user_reads(frames[:, inner, inner], Path(scratch))
            shaken = as_user_reads(warp(frames, walk)[:, inner, inner], Path(scratch))
            shaken_masks = (warp(masks[..., None], walk)[..., 0] > 0.5).float()[:, inner, inner]
            still_masks = masks[:, inner, inner]
            tic = time.perf_counter()
            shake = (
                Shake(None, 0) if border_is_uniform(shaken) else read_shake(shaken)
            )  # as predict
            seconds = time.perf_counter() - tic
            margin = crop_margin(shake)
            steadied = steady(shaken, shake)
            cut = slice(margin, still_masks.shape[1] - margin)
            row = {
                "clip": name,
                "largest_px": float(walk.norm(dim=1).max()),
                "still_read_px": read_shake(still).largest_px,
                "still_readable": read_shake(still).shifts is not None,
                "read": shake.shifts is not None,
                "read_error_px": None
                if shake.shifts is None
                else float((shake.shifts - walk).norm(dim=1).max()),
                "margin": margin,
                "read_seconds": seconds,
            }
            for key, clip, truth, cropped in (
                ("still", still, still_masks, crop),
                ("shaken", shaken, shaken_masks, crop),
                # (not read, or under STILL_PX: the shaken clip as it is)
                (
                    "taken_out",
                    steadied,
                    still_masks[:, cut, cut] if margin else shaken_masks,
                    crop + margin,
                ),
            ):
                found = segment_clip(segmenter, clip)
                row[key] = {
                    "iou": mean_mask_iou(found, truth),
                    **read_camera_errors(found, K, w2c, centre, lowest, cropped),
                }
            rows.append(row)
            print(
                f"{name}: shake {row['largest_px']:.1f} px, read "
                + ("no" if not row["read"] else f"to {row['read_error_px']:.2f} px")
                + "; "
                + "; ".join(
                    f"{k} IoU {row[k]['iou']:.3f} "
                    + (
                        f"scale {row[k]['scale_error']:+.3f} drop {row[k]['ground_error_m']:+.3f}"
                        if "scale_error" in row[k]
                        else "refused"
                    )
                    for k in ("still", "shaken", "taken_out")
                ),
                flush=True,
            )
    print(
        f"\n{len(rows)} clips of {args.data}, view 0; walk {args.step} px a frame, at most "
        f"{args.largest} px; {platform.processor() or platform.machine()}, torch "
        f"{torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    read = [r for r in rows if r["read"]]
    read_error = np.mean([r["read_error_px"] for r in read]) if read else float("nan")
    print(
        f"shake readable on {len(read)} of {len(rows)} shaken clips (still clips: "
        f"{sum(r['still_readable'] for r in rows)}); read to {read_error:.2f} px "
        f"on average (worst frame of each clip); still clips read as moving more than "
        f"{STILL_PX} px: {sum(r['still_read_px'] >= STILL_PX for r in rows)}; "
        f"{np.mean([r['read_seconds'] for r in rows]):.2f} s a clip to read"
    )
    for subset, label in ((rows, "all clips"), (read, "clips whose shake was read")):
        for key in ("still", "shaken", "taken_out"):
            if not subset:
                continue
            good = [r[key] for r in subset if "scale_error" in r[key]]
            scale = np.abs([g["scale_error"] for g in good]) if good else np.array([np.nan])
            drop = np.abs([g["ground_error_m"] for g in good]) if good else np.array([np.nan])
            print(
                f"{label}, {key}: mask IoU {np.mean([r[key]['iou'] for r in subset]):.3f}; "
                f"|scale error| mean {scale.mean():.3f} (median {np.median(scale):.3f}); "
                f"|drop-height error| mean {100 * drop.mean():.1f} cm; "
                f"refused {len(subset) - len(good)} of {len(subset)}"
            )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
