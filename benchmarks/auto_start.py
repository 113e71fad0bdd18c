"""`--start auto` on recordings that begin before the release: is the release found?

For view 0 of the first N test samples of a dataset of drops released from rest (``make-data
--preset paper``), the stored frames are written as an mp4 that first holds frame 0 still for a
random 5–20 frames (the object held before it is let go; no hand in view), then plays the drop.
``load_observation(..., start="auto")`` reads it as ``predict --start auto`` does (no mask file,
the camera file or the camera read from the video): the release time it finds against the true
one (the hold's length), and what the rest of the pipeline then reads — the camera's scale and
the initial speed — beside the same drop given from its release (``--start`` 0 on the drop's own
mp4).

    python benchmarks/auto_start.py data/rest96 --limit 40
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from reconphys.capture import CameraSpec, load_observation, write_camera
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.pipeline.samples import segment_frames
from reconphys.render.video import to_uint8, write_mp4

FRAME_DT = 0.03


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(2)
    dataset = DropDataset(args.data, split="test", views=[0])
    rng = np.random.default_rng(args.seed)
    rows, started = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        for index in range(min(args.limit, len(dataset))):
            item, meta = dataset[index], dataset.meta(index)
            frames = to_uint8(item["frames"][0])  # [T, H, W, 3]
            hold = int(rng.integers(5, 21))
            height, width = frames.shape[1:3]
            camera = Path(folder) / f"{index}.json"
            write_camera(camera, CameraSpec(item["K"][0].double(), item["world_to_cam"][0].double(),
                                            width, height))  # fmt: skip
            drop, held = Path(folder) / f"{index}.mp4", Path(folder) / f"{index}_held.mp4"
            write_mp4(drop, frames, fps=1 / FRAME_DT)
            write_mp4(held, np.concatenate([frames[:1].repeat(hold, 0), frames]), fps=1 / FRAME_DT)
            row = {"id": meta["id"], "hold_s": hold * FRAME_DT}
            for name, path, start in (("drop", drop, 0.0), ("auto", held, "auto")):
                try:
                    read = load_observation(path, start=start, segment=segment_frames)
                    row[name] = {
                        "start_s": read.start_s,
                        "scale": read.camera_estimate["distance_m"],
                        "frames": read.num_frames,
                    }
                except InputError as e:
                    row[name] = {"refused": str(e)}
            try:
                given = load_observation(held, start="auto", camera=camera, segment=segment_frames)
                row["auto_camera_file"] = {"start_s": given.start_s}
            except InputError as e:
                row["auto_camera_file"] = {"refused": str(e)}
            rows.append(row)
            auto = row["auto"]
            print(
                meta["id"],
                f"hold {row['hold_s']:.2f} s:",
                "refused: " + auto["refused"][:80]
                if "refused" in auto
                else f"release read at {auto['start_s']:.3f} s",
                flush=True,
            )
    found = [r for r in rows if "start_s" in r["auto"]]
    error = np.array([r["auto"]["start_s"] - r["hold_s"] for r in found])
    print(
        f"\n{len(rows)} held drops of {args.data} (view 0); {platform.machine()}, torch "
        f"{torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    print(
        f"release found on {len(found)}/{len(rows)}; error (read − true) mean {error.mean():+.4f} "
        f"s, |error| mean {np.abs(error).mean():.4f} s, max {np.abs(error).max():.4f} s; within "
        f"half a frame on {np.mean(np.abs(error) <= FRAME_DT / 2):.0%}"
    )
    with_file = [r for r in rows if "start_s" in r["auto_camera_file"]]
    error_file = np.array([r["auto_camera_file"]["start_s"] - r["hold_s"] for r in with_file])
    print(
        f"with a camera file: found on {len(with_file)}/{len(rows)}, |error| mean "
        f"{np.abs(error_file).mean():.4f} s"
    )
    both = [r for r in found if "scale" in r["drop"]]
    ratio = np.array([r["auto"]["scale"] / r["drop"]["scale"] for r in both])
    print(
        f"camera read from the video, auto-cut against the drop's own mp4: distance ratio mean "
        f"{ratio.mean():.3f}, |log| mean {np.abs(np.log(ratio)).mean():.3f} ({len(both)} drops)"
    )


if __name__ == "__main__":
    main()
