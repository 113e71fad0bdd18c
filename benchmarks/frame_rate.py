"""A recording at 30 fps against the same drops at the simulator's 33.3 fps
(docs/usage.md#the-input): what `predict` reads from the mp4 alone — the camera (scale and
drop-height errors, as benchmarks/realistic_input.py measures them), the initial speed and the
physics (|error| of log k/m, log d/m, f).

The two datasets hold the same drops (objects, attributes, initial states, cameras within a few
mm of framing), one filmed every 0.03 s and one every 1/30 s:

    reconphys make-data --config configs/data_frame_rate_33.toml --out data/rate33
    reconphys make-data --config configs/data_frame_rate_30.toml --out data/rate30
    python benchmarks/frame_rate.py data/rate33 data/rate30 [--limit 40] [--search]

``--nearest`` reads each wanted time's nearest recorded frame instead of the frames made between
two recorded ones (capture/interpolate.py): the behaviour before 2026-11-26, for comparison.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from realistic_input import camera_errors

import reconphys
import reconphys.capture.observation as observation_module
from reconphys.capture.calibrate import SEGMENTER_FALL_FIT_PX
from reconphys.capture.video import resample_indices
from reconphys.data import DropDataset
from reconphys.data.storage import video_name
from reconphys.errors import InputError
from reconphys.pipeline.demo import true_observables


def read_nearest_frames() -> None:
    """Make ``load_observation`` read the nearest recorded frame to each time (no frames
    between two recorded ones): the reading before capture/interpolate.py."""

    def nearest(*args, **kwargs):
        picks = resample_indices(*args, **kwargs)
        return picks, picks, np.zeros(len(picks))

    observation_module.resample_between = nearest


def run(data: str, limit: int, search: bool) -> list[dict]:
    dataset = DropDataset(data, split="test", views=[0])
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for index in range(min(limit, len(dataset))):
            meta, item = dataset.meta(index), dataset[index]
            video = Path(folder) / f"{index}.mp4"
            shutil.copyfile(Path(data) / dataset.samples[index]["dir"] / video_name(0), video)
            truth = np.array(list(true_observables(meta["attributes"]).values()))
            row = {"id": meta["id"]}
            tic = time.perf_counter()
            try:
                result = reconphys.predict(video, refine=search)
            except InputError as e:
                rows.append({**row, "refused": str(e)})
                continue
            predicted = np.array(list(result.observables.values()))
            masks, dt = result.observation.masks, result.observation.frame_dt
            camera = camera_errors(masks, item, {"frame_dt": dt}, None, SEGMENTER_FALL_FIT_PX)
            speed = np.linalg.norm(result.details["initial_velocity"]["linear_m_s"])
            rows.append(
                {
                    **row,
                    "error": np.abs(predicted - truth).tolist(),
                    "scale_error": camera["scale_error"],
                    "ground_error_m": camera["ground_error_m"],
                    "speed_error": abs(speed - float(item["v0"].mean(0).norm())),
                    "seconds": time.perf_counter() - tic,
                }
            )
    return rows


def summary(name: str, rows: list[dict], ids: set[str]) -> str:
    done = [r for r in rows if r["id"] in ids]
    scale = np.abs([r["scale_error"] for r in done])
    ground = np.abs([r["ground_error_m"] for r in done])
    mae = np.mean([r["error"] for r in done], axis=0)
    return (
        f"{name}: {len(rows) - sum('refused' in r for r in rows)}/{len(rows)} answered; on the "
        f"{len(done)} answered at both rates: |scale error| mean {100 * scale.mean():.1f} % "
        f"(median {100 * np.median(scale):.1f} %, ≤ 10 % on {np.mean(scale <= 0.1):.0%}); "
        f"|drop-height error| mean {100 * ground.mean():.1f} cm (median "
        f"{100 * np.median(ground):.1f} cm); |speed error| mean "
        f"{np.mean([r['speed_error'] for r in done]):.3f} m/s; MAE log k/m {mae[0]:.3f}, "
        f"log d/m {mae[1]:.3f}, f {mae[2]:.3f}; {np.mean([r['seconds'] for r in done]):.1f} s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", help="the drops at 1 / frame_dt (33.3 fps)")
    parser.add_argument("other", help="the same drops at another rate (30 fps)")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--search", action="store_true", help="predict's default path")
    parser.add_argument("--nearest", action="store_true", help="the reading before (doc)")
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    args = parser.parse_args()
    torch.set_num_threads(2)
    if args.nearest:
        read_nearest_frames()
    started = time.perf_counter()
    rows = {name: run(name, args.limit, args.search) for name in (args.reference, args.other)}
    answered = [{r["id"] for r in v if "refused" not in r} for v in rows.values()]
    both = answered[0] & answered[1]
    print(
        f"{'default path (network + search)' if args.search else 'feed-forward'}, "
        f"{'nearest recorded frame' if args.nearest else 'frames between recorded ones'}; "
        f"{platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{time.perf_counter() - started:.0f} s"
    )
    for name, value in rows.items():
        print(summary(name, value, both))
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
