"""The camera read from the same clip at the data's size and enlarged to a phone's 1080 × 1080
(docs/usage.md#the-segmenters-pixel-at-a-phones-size).

For each test sample of a realistic-look dataset (view 0), brought in as a user would
(``common.user_bundle``: the stored mp4 alone), ``predict``'s own reading
(``pipeline.samples.load_input``: the mask segmenter, the camera from the fall, 45° assumed) of
the mp4 as it is and of the same frames enlarged to 1080 × 1080 (``common.enlarged_video``: a
phone's size, the 128-px clip's detail; read at 640 px, segmented at 128). Scale and
drop-height errors as ``realistic_input.py`` (``common.camera_read_errors``, the true K brought
to the masks' size), refusals, fall frames.

    python benchmarks/phone_size.py data/mval128_41 --out rows.json [--limit 36]
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
from reconphys.pipeline.samples import load_input
from reconphys.threads import set_cpu_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="a realistic-look dataset (make-data --scene realistic)")
    parser.add_argument("--limit", type=int, default=None)
    parser.add_argument("--side", type=int, default=1080, help="the enlarged clip's side, px")
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
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
            row = {"id": item["id"]}
            for name, path in (
                ("recorded", bundle / "video.mp4"),
                ("enlarged", bundle / "large.mp4"),
            ):
                read.clear()
                try:
                    load_input(path)
                except InputError as e:
                    row[name] = {"refused": str(e)}
                    continue
                K = true_K.clone()
                K[:2] *= read["width"] / item["frames"].shape[3]
                row[name] = camera_read_errors(
                    read["estimate"], K, item["world_to_cam"][0], anchors[0].mean(0), lowest
                )
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
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
