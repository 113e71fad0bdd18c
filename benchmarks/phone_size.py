"""The camera read from the same clip at the data's size and enlarged to a phone's 1080 × 1080
(docs/usage.md#the-segmenters-pixel-at-a-phones-size).

For each test sample of a realistic-look dataset (view 0), brought in as a user would
(``common.user_bundle``: the stored mp4 alone), ``predict``'s own reading
(``pipeline.samples.load_input``: the mask segmenter, the camera from the fall, 45° assumed) of
the mp4 as it is and of the same frames enlarged to 1080 × 1080 (``common.enlarged_video``: a
phone's size, the 128-px clip's detail; read at 640 px, segmented at 128). Scale and
drop-height errors as ``realistic_input.py`` (``common.camera_read_errors``, the true K brought
to the masks' size), refusals, fall frames.

With ``--velocity``: ``reconphys.predict`` (``refine=False``: the same reading, then the 3DGS
predictor's Gaussians and the initial velocity) instead of ``load_input``, and the initial
velocity read against the truth in the camera's axes (x right, y down, along the view; the
estimated camera's for the read one, the true camera's for the truth): the mean |error| per axis
over the moving clips, and for clips released from rest how many are read over 0.1 m/s.

    python benchmarks/phone_size.py data/mval128_41 --out rows.json [--limit 36] [--velocity]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from common import camera_read_errors, enlarged_video, machine_description, user_bundle

import reconphys.capture.observation as observation
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.pipeline.predict import predict
from reconphys.pipeline.samples import load_input
from reconphys.threads import set_cpu_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="a realistic-look dataset (make-data --scene realistic)")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--side", type=int, default=1080, help="the enlarged clip's side, px")
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    parser.add_argument(
        "--velocity", action="store_true", help="predict (no refinement): the initial velocity"
    )
    args = parser.parse_args()
    set_cpu_threads(2)
    print(f"# {' '.join(sys.argv)}\n# {machine_description('cpu')}")
    dataset = DropDataset(args.data, split="test", views=[0])
    read, estimate_camera = {}, observation.estimate_camera

    def kept(*positional, **named):  # the estimate predict makes, and the masks' width
        read["estimate"] = estimate_camera(*positional, **named)
        read["width"] = positional[0].shape[2]
        return read["estimate"]

    observation.estimate_camera = kept
    rows = []
    count = len(dataset) if args.limit is None else min(args.limit, len(dataset))
    with tempfile.TemporaryDirectory() as tmp:
        for index in range(count):
            item = dataset[index]
            bundle = user_bundle(dataset, index, Path(tmp), item)
            enlarged_video(bundle / "video.mp4", bundle / "large.mp4", args.side)
            anchors = item["anchors"].double()
            lowest = anchors[0][anchors[0][:, 2].argmin()]
            true_K = item["K"][0].double()
            truth = np.array(dataset.meta(index)["initial_state"]["linear_velocity"])
            rotation = item["world_to_cam"][0][:3, :3].double().numpy()
            row = {"id": item["id"], "at_rest": bool(not truth.any())}
            for name, path in (
                ("recorded", bundle / "video.mp4"),
                ("enlarged", bundle / "large.mp4"),
            ):
                read.clear()
                try:
                    result = predict(path, refine=False) if args.velocity else load_input(path)
                except InputError as e:
                    row[name] = {"refused": str(e)}
                    continue
                K = true_K.clone()
                K[:2] *= read["width"] / item["frames"].shape[3]
                row[name] = camera_read_errors(
                    read["estimate"], K, item["world_to_cam"][0], anchors[0].mean(0), lowest
                )
                if args.velocity:
                    velocity = np.array(result.details["initial_velocity"]["linear_m_s"])
                    read_rotation = result.observation.camera.world_to_cam[:3, :3].double()
                    error = read_rotation.numpy() @ velocity - rotation @ truth
                    row[name]["velocity_error_camera_m_s"] = error.tolist()
                    row[name]["speed_m_s"] = float(np.linalg.norm(velocity))
            rows.append(row)
            print(json.dumps(row), flush=True)
    for name in ("recorded", "enlarged"):
        good = [r[name] for r in rows if "scale_error" in r[name]]
        scale = np.abs([g["scale_error"] for g in good])
        ground = np.abs([g["ground_error_m"] for g in good])
        print(
            f"{name}: answered {len(good)}, refused {len(rows) - len(good)}; |scale error| mean "
            f"{100 * scale.mean():.1f} %; |drop-height error| mean {100 * ground.mean():.2f} cm; "
            f"fall frames mean {np.mean([g['fall_frames'] for g in good]):.1f}"
        )
        if args.velocity:
            moving = [r[name] for r in rows if "speed_m_s" in r[name] and not r["at_rest"]]
            still = [r[name] for r in rows if "speed_m_s" in r[name] and r["at_rest"]]
            if moving:
                off = np.abs([g["velocity_error_camera_m_s"] for g in moving]).mean(0)
                print(
                    f"  velocity, {len(moving)} moving: mean |error| (x right, y down, along the "
                    f"view) {off[0]:.3f}, {off[1]:.3f}, {off[2]:.3f} m/s"
                )
            if still:
                speeds = [g["speed_m_s"] for g in still]
                print(
                    f"  velocity, {len(still)} released from rest: read over 0.1 m/s "
                    f"{sum(v > 0.1 for v in speeds)}, largest {max(speeds):.3f} m/s"
                )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
