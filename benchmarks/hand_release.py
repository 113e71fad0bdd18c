"""A hand in view: does `predict` read a drop whose release shows the hand that let it go?

Every clip of our data shows the object alone; a real drop starts in a hand, which opens and
withdraws (or stays where it was) after the release. For view 0 of the first N test samples of a
dataset of realistic drops released from rest (``make-data --preset paper --scene realistic``),
this benchmark renders a hand holding the object from above (``reconphys.render.hand``, as
``make-data --hand-share`` draws it) — a palm, four fingers and a thumb over the object's top
(``--grip front``: the fingers over the side that faces the camera; ``behind``: all of the hand
behind the object; ``drawn``: either), a forearm reaching up and away from the camera, in a skin
tone drawn from light to dark, shaded by the scene's light; 3D Gaussians through the sample's
own camera, so it has the object's perspective, and it hides the object where it is nearer than
the object's centre — held still with the object for a random 5–20 frames, then
withdrawn along the arm at a random 0.2–1 m/s (a quarter of the clips: kept still). No shadow
of the hand is drawn. Each clip is written as an mp4 and read as ``predict --no-refine`` reads
it (the mp4 alone: the segmenter's masks, the camera from the video), two ways (``--reads``):
``--start auto`` (the release read from the masks) and ``--start`` the true release (a user who
gives it; ``--start-offset K``: K frames after it, a user who scrubbed to a frame late, or
before it with K < 0; the truth's velocity and drop height are then those at that time, a fall
from rest). Printed: the answers and refusals, the mask IoU against the stored masks (frames 0–29
after the release, and 0–4; the hand's pixels count as background; read masks of a larger
clip area-averaged to the stored size), the size's and the drop height's errors, the initial
speed (the drops are from rest: it should be ≤ 0.1 m/s), the release read, and how often the
velocity was flagged (the first frames' masks change size:
``capture.masks.FIRST_FRAMES_AREA_CHANGE``), and how many ``--start auto`` read as held, then
let go from rest (``capture.masks.read_release``; with ``--start`` given, the hold read before
it), with the mean |velocity − truth| and how often it is over 0.1 m/s (a dataset
of moving drops, each held first: a flick, what the hold rule costs) — beside the same clips
without the hand (the ``no_hand`` rows). ``--json`` keeps each read's velocity in the camera's
axes, its error, the truth's velocity and the release read (seconds into the recording).

With ``--side N`` each clip is enlarged to N × N before it is read (``common.enlarged_video``:
a phone's size, the clip's own detail; read at 256 px for ``--start auto``, at 640 after it).

    python benchmarks/hand_release.py data/rest96 --limit 40 [--grip behind] [--json out.json]
        [--side 1080] [--reads given] [--start-offset 1]
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
from common import enlarged_video

import reconphys
from reconphys.assets.gaussians import Gaussians
from reconphys.capture.placement import GRAVITY_MAGNITUDE
from reconphys.data import DropDataset
from reconphys.data.scene import look_from_dict
from reconphys.errors import InputError
from reconphys.models import mask_segmenter
from reconphys.render.cameras import Cameras
from reconphys.render.hand import (
    arm_direction,
    composite_hand,
    draw_hand,
    hand_gaussians,
    object_grip,
)
from reconphys.render.video import to_uint8, write_mp4

FRAME_DT = 0.03


def with_hand(
    frames: np.ndarray,  # [T, H, W, 3] float in [0, 1], the drop from its release
    masks: np.ndarray,  # [T, H, W] bool, the object's true masks
    depths: np.ndarray,  # [T] camera-space z of the object's centre, metres
    hold: int,  # frames held still before the release
    hand: Gaussians,
    velocity: np.ndarray,  # [3] the hand's velocity after the release, m/s
    cameras: Cameras,  # one camera
    look,
) -> np.ndarray:  # [hold + T, H, W, 3]
    """The clip held still for ``hold`` frames (frame 0 repeated), then the drop, with the hand
    over it (render/hand.py: still until the release, then moving)."""

    def held(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.concatenate([x[:1].repeat(hold, 0), x]))[None]

    times = (torch.arange(hold + len(frames), dtype=torch.float64) - hold) * FRAME_DT
    clip, _ = composite_hand(held(frames), held(masks), held(depths), hand, velocity, times,
                             cameras, look)  # fmt: skip
    return clip[0].numpy()


def _iou(read: np.ndarray, true: np.ndarray) -> float:  # [T, H, W] bool each
    union = np.logical_or(read, true).sum((1, 2))
    inter = np.logical_and(read, true).sum((1, 2))
    return float(np.mean(np.where(union > 0, inter / np.maximum(union, 1), 1.0)))


def read(path: Path, start, true_masks: np.ndarray, truth: dict) -> dict:
    try:
        result = reconphys.predict(path, start=start, refine=False)
    except InputError as e:
        return {"refused": str(e)}
    obs = result.observation
    masks = obs.masks[:, None]
    if masks.shape[-2:] != true_masks.shape[-2:]:  # an enlarged clip: at the stored size
        masks = torch.nn.functional.interpolate(masks, true_masks.shape[-2:], mode="area")
    masks = masks[:, 0].numpy() > 0.5
    n = min(len(masks), len(true_masks))
    velocity = result.details["initial_velocity"]
    release = getattr(obs, "release", None)  # --start auto's hold (None: not read)
    estimate = obs.camera_estimate or {}
    return {
        "start_s": obs.start_s,
        "iou": _iou(masks[:n], true_masks[:n]),
        "iou_0_4": _iou(masks[:5], true_masks[:5]),
        # the object's size read / the truth (size = pixels · distance / f: the field of view
        # assumed moves the distance, not the size), and the drop height read − the truth
        "scale": (estimate.get("distance_m", float("nan")) / float(obs.camera.K[1, 1]))
        / (truth["distance"] / (truth["focal"] * obs.camera.height / true_masks.shape[1])),
        "drop_height_error": estimate.get("drop_height_m", float("nan")) - truth["drop_height"],
        "speed": float(np.linalg.norm(velocity["linear_m_s"])),
        # in the camera's axes (x right, y down, z along the view), m/s
        "velocity_camera": (
            obs.camera.world_to_cam[:3, :3].double() @ torch.tensor(velocity["linear_m_s"]).double()
        ).tolist(),
        "how": velocity["how"],
        "held": None if release is None else release.from_rest,  # let go from rest
        "across_m_s": None if release is None else release.across_m_s,
        "velocity_error": float(
            np.linalg.norm(np.subtract(velocity["linear_m_s"], truth["velocity"]))
        ),
        "release_s": None if release is None else release.time_s,  # into the recording
        "truth_velocity": list(truth["velocity"]),
        "warned": "warning" in velocity,  # the first frames' masks flagged (capture/masks.py)
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--keep", type=Path, default=None, help="also write the mp4s here")
    parser.add_argument("--grip", choices=("front", "behind", "drawn"), default="front",
                        help="the fingers over the object's camera side, behind it, or either "
                        "(drawn per clip, as make-data --hand-share does)")  # fmt: skip
    parser.add_argument("--side", type=int, default=None,
                        help="enlarge each clip to SIDE x SIDE before reading it")  # fmt: skip
    parser.add_argument("--start-offset", type=float, default=0.0,
                        help="give --start this many frames after the true release (a user "
                        "who scrubbed to a frame late: > 0; early: < 0)")  # fmt: skip
    parser.add_argument(
        "--reads",
        nargs="+",
        choices=("auto", "given"),
        default=("auto", "given"),
        help="which starts to read: --start auto, --start the release given",
    )
    parser.add_argument("--segmenter", nargs="+", type=Path, default=None,
                        help="read the masks with these weights (one file, or several "
                        "averaged) instead of the shipped ensemble's")  # fmt: skip
    args = parser.parse_args()
    torch.set_num_threads(2)
    if args.segmenter:  # predict's segmenter loads the shipped paths when it is first used
        mask_segmenter.SHIPPED_MASKS_PATHS = tuple(args.segmenter)
    dataset = DropDataset(args.data, split="test", views=[0])
    rng = np.random.default_rng(args.seed)
    rows, started = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.keep or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        for index in range(min(args.limit, len(dataset))):
            item, meta = dataset[index], dataset.meta(index)
            frames = item["frames"][0].double().numpy()  # [T, H, W, 3]
            true_masks = dataset.masks(index)[0].numpy()  # [T, H, W]
            K, world_to_cam = item["K"][0].double(), item["world_to_cam"][0].double()
            height, width = frames.shape[1:3]
            cameras = Cameras(K[None], world_to_cam[None], width, height)
            anchors = item["anchors"][0].double().numpy()  # [N, 3] frame 0
            spec = draw_hand(rng)
            if args.grip != "drawn":
                spec = replace(spec, grip=args.grip)
            top, half_width = object_grip(anchors)
            eye = -world_to_cam[:3, :3].T.numpy() @ world_to_cam[:3, 3].numpy()
            arm = arm_direction(spec, top, eye)
            hand = hand_gaussians(top, half_width, arm, spec)
            hold, speed = int(rng.integers(5, 21)), spec.speed
            look = look_from_dict(meta["scene"]["look"])
            track = item["anchors"].double().mean(1).numpy()  # [T, 3] the object's centre
            depths = track @ world_to_cam[:3, :3].numpy().T[:, 2] + world_to_cam[2, 3].item()
            clip = with_hand(frames, true_masks, depths, hold, hand, arm * speed, cameras, look)
            held = folder / f"{index:03d}_hand.mp4"
            plain = folder / f"{index:03d}_nohand.mp4"
            write_mp4(held, to_uint8(torch.from_numpy(clip)), fps=1 / FRAME_DT)
            still = np.concatenate([frames[:1].repeat(hold, 0), frames])
            write_mp4(plain, to_uint8(torch.from_numpy(still)), fps=1 / FRAME_DT)
            if args.side:  # a phone's size: the clips enlarged, read as predict reads them
                held = enlarged_video(held, held.with_name(held.stem + "_large.mp4"), args.side)
                plain = enlarged_video(plain, plain.with_name(plain.stem + "_large.mp4"), args.side)
            centre = world_to_cam[:3, :3].numpy() @ anchors.mean(0) + world_to_cam[:3, 3].numpy()
            truth = {
                "distance": float(np.linalg.norm(centre)),  # camera to the object's centre
                "focal": float(K[1, 1]),
                "drop_height": float(anchors[:, 2].min()),  # frame 0's lowest point
                "velocity": meta["initial_state"]["linear_velocity"],  # m/s, world
            }
            hold_s = hold * FRAME_DT
            row = {"id": meta["id"], "hold_s": hold_s, "hand_speed": speed}
            given = hold_s + args.start_offset * FRAME_DT
            # the truth at the start given: a start after the release finds the object falling
            fallen = max(given - hold_s, 0.0)  # seconds
            late = {
                **truth,
                "velocity": list(
                    np.add(truth["velocity"], [0.0, 0.0, -GRAVITY_MAGNITUDE * fallen])
                ),
                "drop_height": truth["drop_height"] - 0.5 * GRAVITY_MAGNITUDE * fallen**2,
            }
            for name, path in (("hand", held), ("no_hand", plain)):
                if "auto" in args.reads:
                    row[f"{name}_auto"] = read(path, "auto", true_masks, truth)
                if "given" in args.reads:
                    row[f"{name}_given"] = read(path, given, true_masks, late)
            rows.append(row)
            brief = {k: ("refused" if "refused" in v else round(v["iou"], 3))
                     for k, v in row.items() if isinstance(v, dict)}  # fmt: skip
            print(meta["id"][:40], f"hold {hold_s:.2f} s, hand {speed:.2f} m/s", brief, flush=True)
    print(
        f"\n{len(rows)} drops of {args.data} (view 0); {platform.machine()}, torch "
        f"{torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    for key in ("no_hand_given", "hand_given", "no_hand_auto", "hand_auto"):
        if key not in rows[0]:
            continue
        answered = [r[key] for r in rows if "refused" not in r[key]]
        if not answered:
            print(f"{key:14s} all refused")
            continue
        iou = np.array([a["iou"] for a in answered])
        ratio = np.array([a["scale"] for a in answered])
        drop = np.abs([a["drop_height_error"] for a in answered])
        speed = np.array([a["speed"] for a in answered])
        start = np.array([r[key]["start_s"] - r["hold_s"] for r in rows if "refused" not in r[key]])
        print(
            f"{key:14s} answered {len(answered)}/{len(rows)}; mask IoU {iou.mean():.3f} "
            f"(min {iou.min():.3f}), frames 0-4 {np.mean([a['iou_0_4'] for a in answered]):.3f}; "
            f"|scale error| {np.nanmean(np.abs(ratio - 1)):.1%} (median "
            f"{np.nanmedian(np.abs(ratio - 1)):.1%}), drop height {np.nanmean(drop) * 100:.1f} "
            f"cm; speed > 0.1 m/s on {int((speed > 0.1).sum())} "
            f"(max {speed.max():.2f}); |release error| {np.abs(start).mean() * 1000:.1f} ms"
        )
        held = sum(bool(a.get("held")) for a in answered)
        errors = np.array([a["velocity_error"] for a in answered])
        print(
            f"{'':14s} read as let go from rest {held}; mean |v - truth| {errors.mean():.3f} m/s"
            f", over 0.1 m/s on {int((errors > 0.1).sum())} (max {errors.max():.2f})"
        )
        warned, over = np.array([a["warned"] for a in answered]), speed > 0.1
        print(
            f"{'':14s} velocity flagged on {int(warned.sum())}: {int((warned & over).sum())} of "
            f"the {int(over.sum())} over 0.1 m/s, {int((warned & ~over).sum())} of the "
            f"{int((~over).sum())} at most"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
