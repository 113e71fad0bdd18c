"""What a phone-sized recording costs `predict` (docs/usage.md#the-input): wall-clock and peak
memory of `reconphys predict` on a clip made like a phone's — one realistic drop of a dataset
(view 0) enlarged to 1080 px high, padded to 1920 × 1080, filmed at 30 fps, the object resting
for the rest of N seconds — with the release at frame 0, and again held still for 2 s first
(``--start auto``).

    python benchmarks/long_recording.py data/rate30 [--seconds 8] [--index 2]

Each run is a fresh process (`/usr/bin/time`-like: the children's peak resident memory).
"""

from __future__ import annotations

import argparse
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import torch
import torch.nn.functional as F

from reconphys.data import DropDataset
from reconphys.data.storage import video_name

HEIGHT, WIDTH, FPS = 1080, 1920, 30.0


def phone_clip(data: str, index: int, seconds: float, held_s: float, path: Path) -> None:
    dataset = DropDataset(data, split="test", views=[0])
    clip = Path(data) / dataset.samples[index]["dir"] / video_name(0)
    frames = torch.from_numpy(np.stack(imageio.mimread(clip, memtest=False)))
    with imageio.get_writer(path, fps=FPS, codec="libx264", quality=8, macro_block_size=1) as out:
        held = [frames[0]] * round(held_s * FPS)
        rest = [frames[-1]] * max(round(seconds * FPS) - len(frames), 0)
        for frame in [*held, *frames, *rest]:  # one at a time: the clip is never in memory
            x = F.interpolate(frame.permute(2, 0, 1)[None].float(), size=(HEIGHT, HEIGHT))
            x = x[0].permute(1, 2, 0).round().clamp(0, 255).byte().numpy()
            pad = (WIDTH - HEIGHT) // 2
            out.append_data(np.pad(x, ((0, 0), (pad, pad), (0, 0)), mode="edge"))


def run(args: list[str]) -> tuple[float, float, int]:  # seconds, peak GB, exit status
    tic = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "reconphys.cli", "predict", *args], capture_output=True, text=True
    )
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6  # kB → GB (Linux)
    if done.returncode:
        print(done.stdout[-2000:], done.stderr[-2000:])
    return time.perf_counter() - tic, peak, done.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a realistic-look dataset (make-data --scene realistic)")
    parser.add_argument("--index", type=int, default=2, help="its test sample")
    parser.add_argument("--seconds", type=float, default=8.0, help="the clip's length")
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, torch {torch.__version__}")
    with tempfile.TemporaryDirectory() as folder:
        for held_s, extra in ((0.0, []), (2.0, ["--start", "auto"])):
            clip = Path(folder) / f"phone_{held_s:.0f}.mp4"
            phone_clip(args.data, args.index, args.seconds + held_s, held_s, clip)
            seconds, peak, status = run([str(clip), *extra, "--out", str(Path(folder) / "o")])
            shutil.rmtree(Path(folder) / "o", ignore_errors=True)
            print(
                f"{WIDTH}×{HEIGHT}, {FPS:.0f} fps, {args.seconds + held_s:.0f} s"
                f"{', held 2 s, --start auto' if held_s else ''}: exit {status}, {seconds:.1f} s, "
                f"peak memory so far {peak:.2f} GB"
            )


if __name__ == "__main__":
    main()
