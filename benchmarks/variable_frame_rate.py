"""A phone that drops its frame rate while filming (docs/usage.md#a-variable-frame-rate-2026-11-28).

Each test sample's view 0 (its decoded frames, 0.03 s apart) is written as a variable-rate mp4:
every frame for the first ``--full`` frames, then every other one (a phone halving its rate in
low light), each frame at its own time. ``predict --no-refine`` reads it with the mp4 alone
(masks by the segmenter, the camera from the video) twice: at each frame's own time (now), and
as one constant mean rate (before 2026-11-28: ffmpeg's frames repeated or dropped to that rate),
beside the same clip written at its constant rate. Printed: the camera read from the video
against the truth (|scale error|, |drop-height error|: benchmarks/common.camera_read_errors)
and the initial speed read, for clips answered every way.

    python benchmarks/variable_frame_rate.py data/real_other --limit 40
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from common import camera_read_errors

import reconphys
import reconphys.capture.video as video_module
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.render.video import run_ffmpeg, write_image, write_mp4

WAYS = ("constant_rate", "variable_own_times", "variable_mean_rate")


def write_variable_rate(frames: np.ndarray, frame_dt: float, full: int, path: Path) -> None:
    """Frames [T, H, W, 3] uint8 at ``frame_dt``: all of the first ``full``, then every other
    one, encoded (H.264) each at its own time."""
    keep = [k for k in range(len(frames)) if k < full or (k - full) % 2 == 0]
    with tempfile.TemporaryDirectory() as folder:
        for k in range(len(frames)):
            write_image(Path(folder) / f"{k:03d}.png", frames[k])
        select = "+".join(f"eq(n\\,{k})" for k in keep)
        command = ["-v", "error", "-framerate", f"{1 / frame_dt:.6f}"]
        command += ["-i", str(Path(folder) / "%03d.png"), "-vf", f"select={select}"]
        command += ["-fps_mode", "passthrough", "-c:v", "libx264", "-crf", "18"]
        run = run_ffmpeg([*command, "-pix_fmt", "yuv420p", str(path)])
    if run.returncode != 0:
        raise RuntimeError(run.stderr.strip()[:300])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--full", type=int, default=8, help="frames before the rate halves")
    args = parser.parse_args()
    torch.set_num_threads(2)
    dataset = DropDataset(args.data, split="test", views=[0])
    rows, started = [], time.perf_counter()
    detect = video_module.variable_rate
    with tempfile.TemporaryDirectory() as folder:
        for index in range(min(args.limit, len(dataset))):
            item, meta = dataset[index], dataset.meta(index)
            frames = (item["frames"][0].numpy() * 255).round().astype(np.uint8)
            frame_dt = float(meta["frame_dt"])
            steady = Path(folder) / f"{index}_constant.mp4"
            write_mp4(steady, frames, fps=1 / frame_dt, quality=9)
            variable = Path(folder) / f"{index}_variable.mp4"
            write_variable_rate(frames, frame_dt, args.full, variable)
            anchors = item["anchors"].double()
            lowest = anchors[0][anchors[0][:, 2].argmin()]
            row = {"id": meta["id"]}
            for way in WAYS:
                video_module.variable_rate = (
                    (lambda times: False) if way == "variable_mean_rate" else detect
                )
                path = steady if way == "constant_rate" else variable
                try:
                    result = reconphys.predict(path, refine=False)
                except InputError as e:
                    row[way] = {"refused": str(e)}
                    continue
                finally:
                    video_module.variable_rate = detect
                estimate = result.observation.camera_estimate
                read = SimpleNamespace(
                    distance=estimate["distance_m"],
                    camera=result.observation.camera,
                    pitch_deg=estimate["pitch_deg"],
                    fall_frames=estimate["fall_frames"],
                )
                errors = camera_read_errors(
                    read, item["K"][0], item["world_to_cam"][0], anchors[0].mean(0), lowest
                )
                speed = np.linalg.norm(result.details["initial_velocity"]["linear_m_s"])
                true_speed = float(np.linalg.norm(meta["initial_state"]["linear_velocity"]))
                row[way] = {**errors, "speed_error": abs(float(speed) - true_speed)}
            rows.append(row)
            print(
                f"{row['id']}: "
                + " ".join(
                    f"{way} {row[way]['scale_error']:+.3f}"
                    if "scale_error" in row[way]
                    else f"{way} refused"
                    for way in WAYS
                ),
                flush=True,
            )
    print(
        f"\n{len(rows)} test samples of {args.data}, view 0, all frames for {args.full} then "
        f"every other; {platform.processor() or platform.machine()}, torch {torch.__version__}, "
        f"{time.perf_counter() - started:.0f} s"
    )
    answered = [r for r in rows if all("scale_error" in r[w] for w in WAYS)]
    for way in WAYS:
        count = sum("scale_error" in r[way] for r in rows)
        scale = np.abs([r[way]["scale_error"] for r in answered])
        ground = np.abs([r[way]["ground_error_m"] for r in answered])
        speed = np.array([r[way]["speed_error"] for r in answered])
        print(
            f"{way}: answered {count} of {len(rows)}; on the {len(answered)} answered every way: "
            f"|scale error| {scale.mean():.3f} (median {np.median(scale):.3f}), |drop-height "
            f"error| {100 * ground.mean():.1f} cm, |speed error| {speed.mean():.2f} m/s"
        )


if __name__ == "__main__":
    main()
