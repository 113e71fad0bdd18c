"""Seconds ``predict`` spends on its preview (``preview.mp4`` and ``preview.png``): the asset
simulated and rendered in the recording's camera over the recording's background, beside the
recording, at most ``PREVIEW_MAX_SIDE`` px a side against the recording's own (working) size, in
one run (docs/usage.md#what-predict-writes).

The recording: view 0 of the first test sample of a realistic-look dataset as the mp4 alone, as
recorded and resized to 1080 × 1080 (a phone's shorter side; read at 640 px). ``predict
--no-refine`` makes each asset once; the preview is then timed alone, best of ``--repeats``.

    python benchmarks/bench_preview.py data/real_other [--frames 60] [--repeats 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from bench_predict import export_video, first_test_sample
from common import enlarged_video, machine_description

from reconphys.pipeline.predict import predict
from reconphys.pipeline.preview import (
    contact_sheet,
    outlined,
    preview_view,
    side_by_side,
    simulate_and_render,
)
from reconphys.pipeline.settings import PREVIEW_MAX_SIDE
from reconphys.render.video import write_image, write_mp4
from reconphys.threads import set_cpu_threads


def preview_seconds(result, max_side: int, frames: int, out: Path, repeats: int) -> tuple:
    """Best-of seconds of the preview at ``max_side`` and the panel's (width, height)."""
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        shown, masks, camera = preview_view(result.observation, max_side)
        count = max(frames, result.observation.num_frames)
        simulated = simulate_and_render(result.asset, shown, masks, camera, count)
        observed = outlined(shown, masks)
        write_mp4(out / "preview.mp4", side_by_side(observed, simulated), fps=1 / 0.03)
        write_image(out / "preview.png", contact_sheet(observed, simulated))
        best = min(best, time.perf_counter() - started)
    return best, (camera.width, camera.height)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="a realistic-look dataset (make-data --scene realistic)")
    parser.add_argument("--frames", type=int, default=60, help="preview frames (predict's)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description('cpu')}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        video = export_video(args.data, first_test_sample(args.data), tmp / "bundle") / "video.mp4"
        large = enlarged_video(video, tmp / "large.mp4")
        print(f"{'recording':12s} {'panel':>9s} {'seconds':>8s}   {'panel':>9s} {'seconds':>8s}")
        for name, path in (("as recorded", video), ("1080 × 1080", large)):
            result = predict(str(path), refine=False)
            capped = preview_seconds(result, PREVIEW_MAX_SIDE, args.frames, tmp, args.repeats)
            whole = preview_seconds(result, 10**6, args.frames, tmp, args.repeats)
            ratio = (
                f"at most {PREVIEW_MAX_SIDE} px: {whole[0] / capped[0]:.1f}× sooner"
                if capped[1] != whole[1]
                else "the same panel: the recording fits"
            )
            print(
                f"{name:12s} {'×'.join(map(str, capped[1])):>9s} {capped[0]:8.2f}   "
                f"{'×'.join(map(str, whole[1])):>9s} {whole[0]:8.2f}   ({ratio})"
            )


if __name__ == "__main__":
    main()
