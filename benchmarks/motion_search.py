"""Search the initial motion with the physics (``search(..., motion=)``): does it recover the spin
and the velocity along the view, and with them the physics? (docs/usage.md "Initial motion").

For the first test drops of a dataset (view 0; tosses skipped), the sample's own asset (its true
Gaussians, anchors and placement) starts from wrong attributes (k/8, 3·d, f = 0.5) and the initial
motion ``predict`` reads (the masks' free-fall velocity, no spin), then is searched three ways:

- `truth`: the true initial motion, physics only († an upper bound),
- `masks`: the masks' velocity and no spin, physics only (what ``predict`` does),
- `joint`: the same start, the motion searched with the physics.

Masks: the stored true masks of a realistic-look dataset (its frames are masked with them), the
background subtraction of a plain one. Printed per drop: |error| of log k/m, log d/m, f, the
observables left "not shown", and for `joint` the motion found beside the truth.

    python benchmarks/motion_search.py data/pyb1 --limit 10
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from reconphys.capture.camera import CameraSpec
from reconphys.capture.masks import subtract_background
from reconphys.capture.placement import linear_velocity_fit
from reconphys.capture.video import read_video
from reconphys.data import DropDataset
from reconphys.geometry import rigid_velocity
from reconphys.pipeline.search import observables, search

MODES = ("truth", "masks", "joint")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=10, help="test samples looked at")
    parser.add_argument("--modes", default=",".join(MODES))
    parser.add_argument("--silhouette-weight", type=float, default=0.0)
    parser.add_argument("--temperature-scale", type=float, default=1.0)
    parser.add_argument(
        "--mp4",
        action="store_true",
        help="the frames decoded from view_0.mp4 "
        "(as predict reads a recording) instead of the stored lossless frames",
    )
    args = parser.parse_args()
    torch.set_num_threads(2)
    root = Path(args.data)
    dataset = DropDataset(root, split="test", views=[0])
    modes = args.modes.split(",")
    errors = {mode: [] for mode in modes}
    seconds = {mode: [] for mode in modes}
    motion_errors = []
    started = time.perf_counter()
    for i in range(min(args.limit, len(dataset))):
        item, asset = dataset[i], dataset.asset(i)
        state = dataset.meta(i)["initial_state"]
        if np.linalg.norm(state["linear_velocity"][:2]) > 0.45:  # a toss (drops: ≤ 0.3 per axis)
            continue
        size = item["frames"].shape[2]
        camera = CameraSpec(item["K"][0].double(), item["world_to_cam"][0].double(), size, size)
        frames = item["frames"][0][:20]
        if args.mp4:
            decoded = read_video(root / "samples" / item["id"] / "view_0.mp4")[0][:20]
            frames = torch.from_numpy(decoded.astype(np.float32) / 255.0)[..., :3]
        stored = root / "samples" / item["id"] / "masks.npz"
        if stored.is_file():
            masks = torch.from_numpy(np.load(stored)["view_0"][:20]).float()
            frames = frames * masks[..., None]
        else:
            masks = subtract_background(frames)
        true_motion = torch.tensor(state["linear_velocity"] + state["angular_velocity"])
        velocity = linear_velocity_fit(asset.gaussians.means, masks, camera, 0.03)[0]
        start = replace(asset.physics, stiffness=asset.physics.stiffness / 8,
                        damping=asset.physics.damping * 3, friction=0.5)  # fmt: skip
        true_values = observables(asset.physics)
        row = [item["id"][:28]]
        for mode in modes:
            linear, angular = (true_motion[:3], true_motion[3:]) if mode == "truth" else (
                velocity, torch.zeros(3))  # fmt: skip
            begin = replace(asset, physics=start,
                            v0=rigid_velocity(asset.x0, linear, angular).float())  # fmt: skip
            clock = time.perf_counter()
            found, history = search(
                begin, frames, camera, masks=masks,
                motion=torch.cat([linear, angular]) if mode == "joint" else None,
                silhouette_weight=args.silhouette_weight if mode == "joint" else 0.0,
                temperature_scale=args.temperature_scale,
            )  # fmt: skip
            seconds[mode].append(time.perf_counter() - clock)
            error = (observables(found.physics) - true_values).abs().numpy()
            errors[mode].append(error)
            shown = "".join(name[4] for name in history["undetermined"]) or "-"
            row += [f"{mode}: {' '.join(f'{e:.2f}' for e in error)} ({shown})"]
            if mode == "joint":
                motion = np.array(history["initial_motion"])
                motion_errors.append(
                    [np.linalg.norm(motion[:3] - true_motion[:3].numpy()),
                     np.linalg.norm(velocity.numpy() - true_motion[:3].numpy()),
                     np.linalg.norm(motion[3:] - true_motion[3:].numpy()),
                     np.linalg.norm(true_motion[3:].numpy())]
                )  # fmt: skip
        print(*row, flush=True)
    print(
        f"\n{len(errors[modes[0]])} test drops of {root}, view 0; {platform.machine()}, "
        f"torch {torch.__version__}, {time.perf_counter() - started:.0f} s "
        "(|error| of log k/m, log d/m, f; in brackets the observables left 'not shown': k, d, t)"
    )
    for mode in modes:
        mean = np.mean(errors[mode], 0)
        print(f"{mode}: mean |error| {mean[0]:.3f} / {mean[1]:.3f} / {mean[2]:.3f}; "
              f"{np.mean(seconds[mode]):.1f} s a drop")  # fmt: skip
    if motion_errors:
        m = np.mean(motion_errors, 0)
        print(f"joint: |v − v_true| {m[0]:.3f} m/s (the masks' {m[1]:.3f}); "
              f"|ω − ω_true| {m[2]:.3f} rad/s (no spin: {m[3]:.3f})")  # fmt: skip


if __name__ == "__main__":
    main()
