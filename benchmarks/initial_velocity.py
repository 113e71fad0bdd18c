"""The initial linear velocity read from the masks' free fall, against the truth
(docs/usage.md, "Initial state").

For view 0 of every test sample of a dataset: the sample's true Gaussians at frame 0 and its
camera (what `predict --gaussians --camera` gives the fit), the masks a user gets (the plain
look: background subtraction by the border colour, as predict; the realistic look: the stored
true masks and, with --segmenter, the mask segmenter's), and
capture.placement.linear_velocity_fit as predict reads it (since 2026-11-28: the test for a
release from rest on frames 0–3, placement.REST_CHI2, then a clip not at rest read again over
the free fall, calibrate.fall_frames less 2 frames, with a 1-px noise floor), over frames 0–3
only (the rule before 2026-11-28), without the rest test (before 2026-11-27) and over the fall
without the rest test (measured and not kept, docs/usage.md). Printed per launch
(drops, tosses, released from rest): the mean |error| in the camera's axes (x right, y down,
along the view), the largest speed read for clips released from rest, and how often ± 1.2816
standard errors held the truth (the fit's own; predict widens it by the size's error when the
camera is read from the video).

    python benchmarks/initial_velocity.py data/pyb [--segmenter] [--limit N]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
import torch
from common import machine_description

from reconphys.capture import placement
from reconphys.capture.calibrate import (
    FALL_FIT_PX,
    SEGMENTER_FALL_FIT_PX,
    fall_frames,
    mask_track,
)
from reconphys.capture.camera import CameraSpec
from reconphys.capture.masks import subtract_background
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.models.mask_segmenter import load_mask_segmenter, segment_clip

NOISE, CHI2 = placement.VELOCITY_NOISE_PX, placement.REST_CHI2  # predict's
RULES = {  # name: (frames: "four", "fall" or "gated" (predict's), noise floor px, frames less, χ²)
    "predict: the rest test on frames 0-3, then the fall less 2 frames (1 px)": (
        "gated",
        NOISE,
        0,
        CHI2,
    ),
    "before 2026-11-28: frames 0-3, the rest test": ("four", NOISE, 0, CHI2),
    "before 2026-11-27: no rest test": ("four", NOISE, 0, 0.0),
    "the fall less 2 frames, 1 px, no rest test (not kept)": ("fall", 1.0, 2, 0.0),
}
FOUR = 4
Z_10_90 = 1.2816


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument(
        "--segmenter", action="store_true", help="realistic look: the segmenter's masks"
    )
    args = parser.parse_args()
    torch.set_num_threads(2)
    dataset = DropDataset(args.data, split=args.split, views=[0])
    realistic = dataset.settings.scene != "plain"
    segmenter = load_mask_segmenter() if args.segmenter else None
    count = len(dataset) if args.limit is None else min(args.limit, len(dataset))
    rows = {name: [] for name in RULES}
    started = time.perf_counter()
    for index in range(count):
        item, meta = dataset[index], dataset.meta(index)
        frames = item["frames"][0]
        if segmenter is not None:
            masks, fit_px = segment_clip(segmenter, frames), SEGMENTER_FALL_FIT_PX
        elif realistic:
            masks, fit_px = dataset.masks(index)[0].float(), FALL_FIT_PX
        else:
            masks, fit_px = subtract_background(frames), FALL_FIT_PX
        camera = CameraSpec(
            item["K"][0].double(), item["world_to_cam"][0].double(), *frames.shape[1:3][::-1]
        )
        rotation = camera.world_to_cam[:3, :3].double()
        truth = torch.tensor(meta["initial_state"]["linear_velocity"], dtype=torch.float64)
        spin = float(np.linalg.norm(meta["initial_state"]["angular_velocity"]))
        at_rest = float(truth.norm()) == 0 and spin == 0
        launch = "rest" if at_rest else meta["initial_state"]["launch"]
        means = dataset.asset(index).gaussians.means
        try:
            fall = fall_frames(mask_track(masks), float(meta["frame_dt"]), fit_px)
        except InputError:  # a frame with an empty mask: the fall is not read
            fall = FOUR
        for name, (which, floor, less, chi2) in RULES.items():
            placement.VELOCITY_NOISE_PX, placement.REST_CHI2 = floor, chi2
            used = FOUR if which != "fall" else max(FOUR, fall - less)
            velocity, error = placement.linear_velocity_fit(
                means,
                masks,
                camera,
                float(meta["frame_dt"]),
                used,
                fall=fall if which == "gated" else None,
            )
            if which == "gated" and velocity.any():
                used = max(FOUR, fall - placement.FALL_WINDOW_LESS)
            off = (rotation @ (velocity.double() - truth)).abs()
            held = off <= Z_10_90 * error.double()
            speed = float(velocity.norm())
            rows[name].append((launch, off.numpy(), held.numpy(), speed, used))
    placement.VELOCITY_NOISE_PX, placement.REST_CHI2 = NOISE, CHI2
    look = "segmenter" if segmenter is not None else ("true" if realistic else "background")
    print(
        f"{count} samples of {args.data} ({args.split}), view 0, masks: {look}; "
        f"{time.perf_counter() - started:.0f} s; {machine_description('cpu')}; "
        f"{platform.platform()}"
    )
    for name, chosen in rows.items():
        print(name)
        for launch in ("drop", "toss", "rest"):
            part = [r for r in chosen if r[0] == launch]
            if not part:
                continue
            off = np.mean([r[1] for r in part], 0)
            held = 100 * np.mean([r[2] for r in part], 0)
            speeds = [r[3] for r in part]
            frames = np.mean([r[4] for r in part])
            extra = (
                f"; speed read mean {np.mean(speeds):.3f}, max {np.max(speeds):.3f} m/s, "
                f"over 0.1 m/s on {np.sum(np.array(speeds) > 0.1)}"
            )
            print(
                f"  {launch:5} n={len(part):3}: mean |error| x/y/view "
                + " / ".join(f"{v:.3f}" for v in off)
                + " m/s; held "
                + " / ".join(f"{v:.0f}" for v in held)
                + f" %; {frames:.1f} frames"
                + (extra if launch == "rest" else "")
            )


if __name__ == "__main__":
    main()
