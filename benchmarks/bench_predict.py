"""Latency of ``reconphys predict`` (video → asset), step by step, model load excluded.

Two cases, each timed end to end through :func:`reconphys.pipeline.predict.predict` (best of
``--repeats`` after a warm-up call, so Numba compilation and first-call allocations are excluded;
ffmpeg's listings of the file, which ``predict`` keeps per file, are read again in every call):

- ``shipped``: a dataset sample exported as a user would bring it (``data video``: the encoded
  mp4, camera.json, gaussians.ply) at the shipped model's input size (32 px, 20 frames read,
  2 000 Gaussians, 256 anchors) — the issue-7 target: physics network + asset build ≤ 1 s on the
  2-core CPU (≤ 0.1 s on an H100);
- ``large``: the same video with a 20 000-Gaussian procedural object and 2 048 anchors;
- ``predicted``: no PLY — the 3DGS predictor makes the Gaussians from frame 0 (``--gs-model``,
  default the shipped one; skipped when there is none): the whole feed-forward pipeline, whose
  issue-8 target is decode → 3DGS → physics → asset ≤ 2 s on the 2-core CPU.

``--realistic DATA`` (a ``make-data --scene realistic`` dataset) adds the path a phone video
takes: view 0 of its first test sample as the mp4 alone (no camera file, no PLY, no masks), so
``decode`` holds the mask segmenter (its share printed as ``masks``) and the camera read from
the fall, and the object-centric networks make the Gaussians and read the physics; the same with
the segmenter on whole frames (the twin of following the object, the ratio printed), and
without the clip's colour model (models/mask_colours.py; its milliseconds printed); where the
segmenter runs in bfloat16 (``native_bfloat16``: the CPU runs it and a probe finds it faster),
the same in float32 (the fast path's twin), and where the CPU runs bfloat16 but the probe chose
float32, the same in bfloat16 (the ratio printed either way); then the same clip resized to
1080 × 1080 (a phone's shorter side), the same in the middle of a 3840 × 2160 frame (a phone's
4K) and as an iPhone's HDR (HLG, HEVC 10-bit: read as SDR), the clip held still for 10 frames
first and read with ``--start`` at the release (the hold before it read too) and with ``--start
auto`` (their ratios to the mp4 alone printed), the same at 1080 × 1080 held 3 s (a phone's
video: the release later in a longer file), then — once, not best of — a cold
``reconphys predict
--no-refine --preview-frames 0`` process on the mp4, what a user waits for (interpreter, imports
and model loads included).

    python benchmarks/bench_predict.py data/cpu_small [--sample ID] [--device cpu|cuda]
    python benchmarks/bench_predict.py data/cpu_small --realistic data/real_other

Prints the breakdown (decode, gaussians, physics_network, asset_build) per case, the target sum,
the farthest-point-sampling twins of the anchor sampler (plain PyTorch loop vs the compiled one,
16 384 candidates → 2 048 anchors, in the same run) and the machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import machine_description
from hdr_input import write_hevc
from PIL import Image

import reconphys.pipeline.samples as samples
from reconphys.assets.ply import write_ply
from reconphys.assets.procedural import make_procedural_gaussians
from reconphys.capture.video import forget_listings, read_video
from reconphys.errors import InputError
from reconphys.models.gaussian_shipped import load_gaussian_predictor
from reconphys.models.mask_segmenter import bfloat16_supported, native_bfloat16, rated_segment_clip
from reconphys.physics.anchors import farthest_point_sampling, farthest_point_sampling_reference
from reconphys.pipeline.predict import predict
from reconphys.render.video import write_mp4
from reconphys.threads import set_cpu_threads

STEPS = ("decode", "gaussians", "physics_network", "asset_build")


def best_timings(repeats: int, **kwargs) -> dict[str, float]:
    """Best time per step of ``repeats`` calls (the caller has made the warm-up call); each
    call lists the file with ffmpeg again, as a user's first call on it does."""
    runs = []
    for _ in range(repeats):
        forget_listings()
        runs.append(predict(**kwargs).timings)
    return {step: min(run[step] for run in runs) for step in STEPS}


def first_test_sample(data: str) -> str:
    manifest = json.loads((Path(data) / "manifest.json").read_text())
    tests = [s["id"] for s in manifest["samples"] if s["split"] == "test"]
    if not tests:
        raise SystemExit(
            f"error: {data} has no test sample (make-data --test-objects 1, or --sample ID)"
        )
    return tests[0]


def export_video(data: str, sample: str, out: Path) -> Path:
    """The sample as a user brings it (``reconphys data video``): the bundle's folder."""
    command = [sys.executable, "-m", "reconphys.cli", "data", "video", data, sample, str(out)]
    subprocess.run(command, check=True, capture_output=True)
    return out


class SegmenterClock:
    """Seconds spent in the mask segmenter (pipeline.samples.segment_frames) while installed;
    ``bfloat16=False`` runs it in float32 (the reference twin of the bfloat16 fast path),
    ``track=False`` on whole frames (the reference twin of following the object),
    ``colours=False`` without the clip's colour model (the network's masks alone)."""

    def __init__(self, bfloat16: bool | None = None, track: bool = True, colours: bool = True):
        self.seconds = 0.0
        self._segment = samples.segment_frames
        self.bfloat16 = bfloat16
        self.track = track
        self.colours = colours

    def __enter__(self):
        def timed(frames):
            started = time.perf_counter()
            try:
                if self.bfloat16 is None and self.track and self.colours:
                    return self._segment(frames)
                model = samples._segmenter()
                return rated_segment_clip(
                    model, frames, bfloat16=self.bfloat16, track=self.track, colours=self.colours
                )
            finally:
                self.seconds += time.perf_counter() - started

        samples.segment_frames = timed
        return self

    def __exit__(self, *_):
        samples.segment_frames = self._segment


def realistic_rows(data: str, tmp: Path, repeats: int, device: str) -> None:
    """The mp4 alone of a realistic recording, as recorded and at 1080 × 1080 (module doc)."""
    sample = first_test_sample(data)
    bundle = export_video(data, sample, tmp / "realistic")
    video = bundle / "video.mp4"
    frames, fps = read_video(video)[:2]
    large = np.stack([np.asarray(Image.fromarray(f).resize((1080, 1080))) for f in frames])
    write_mp4(tmp / "large.mp4", large[..., :3], fps=fps or 1 / 0.03)
    # a phone's 4K (the 1080 × 1080 frames in the middle of 3840 × 2160, its edges repeated)
    wide = [
        np.pad(
            np.asarray(Image.fromarray(f).resize((2160, 2160))),
            ((0, 0), (840, 840), (0, 0)),
            mode="edge",
        )
        for f in large[..., :3]
    ]
    write_mp4(tmp / "4k.mp4", np.stack(wide), fps=fps or 1 / 0.03)
    del wide
    # an iPhone's HDR: the 1080 × 1080 frames as HLG, HEVC 10-bit 4:2:0 (hdr_input.py)
    write_hevc(large[..., :3], tmp / "hlg.mov", "hlg", "420", "18", lossless=False)
    # held still for 10 frames, then the clip: --start given at the release (the hold before it
    # read again: capture/observation._release_before), and --start auto
    held = np.concatenate([frames[:1].repeat(10, 0), frames])
    write_mp4(tmp / "held.mp4", held[..., :3], fps=fps or 1 / 0.03)
    held_start = 10 / (fps or 1 / 0.03)
    # a phone's: held 3 s at 1080 × 1080 (the start later in a longer video)
    held_long = np.concatenate([large[:1].repeat(100, 0), large])[..., :3]
    write_mp4(tmp / "held_1080.mp4", held_long, fps=fps or 1 / 0.03)
    del held_long
    held_long_start = 100 / (fps or 1 / 0.03)
    print(f"# realistic: {data} sample {sample}, view 0, the mp4 alone")
    print(
        f"{'case':16s} {'size':>9s} {'gaussians':>9s} {'anchors':>7s} "
        + " ".join(f"{s:>15s}" for s in STEPS)
        + f" {'of which masks':>14s} {'all four':>9s}"
    )
    cases = [  # name, file, the segmenter's bfloat16, following the object, colours, --start
        ("mp4 alone", video, None, True, True, 0.0),
        ("mp4, whole frames", video, None, False, True, 0.0),  # the twin of following the object
        ("mp4, no colours", video, None, True, False, 0.0),  # the network's masks alone
        ("held, start given", tmp / "held.mp4", None, True, True, held_start),
        ("held, start auto", tmp / "held.mp4", None, True, True, "auto"),
        ("mp4 1080×1080", tmp / "large.mp4", None, True, True, 0.0),
        ("held 3 s, given", tmp / "held_1080.mp4", None, True, True, held_long_start),
        ("held 3 s, auto", tmp / "held_1080.mp4", None, True, True, "auto"),
        ("mp4 3840×2160", tmp / "4k.mp4", None, True, True, 0.0),
        ("HLG 1080×1080", tmp / "hlg.mov", None, True, True, 0.0),
    ]
    if native_bfloat16():  # the segmenter's bfloat16 fast path is taken: time its twin too
        cases.insert(1, ("mp4, float32 seg", video, False, True, True, 0.0))
    elif bfloat16_supported():  # the probe chose float32: time bfloat16 as the twin
        cases.insert(1, ("mp4, bfloat16 seg", video, True, True, True, 0.0))
    masks_seconds, totals = {}, {}
    for name, path, bfloat16, track, colours, start in cases:
        kwargs = dict(input=str(path), device=device, refine=False, start=start)
        with SegmenterClock(bfloat16, track, colours):
            result = predict(**kwargs)  # warm-up: model loads, Numba, allocator
        runs = []
        for _ in range(repeats):
            forget_listings()  # ffmpeg's listings of the file read again, as a user's call does
            with SegmenterClock(bfloat16, track, colours) as clock:
                timings = predict(**kwargs).timings
            runs.append({**timings, "masks": clock.seconds})
        best = {step: min(run[step] for run in runs) for step in (*STEPS, "masks")}
        size = "×".join(str(n) for n in result.observation.recorded_size or result.observation.size)
        print(
            f"{name:16s} {size:>9s} {result.asset.gaussians.num_gaussians:9d} "
            f"{result.asset.num_anchors:7d} "
            + " ".join(f"{best[s]:15.4f}" for s in STEPS)
            + f" {best['masks']:14.4f} {sum(best[s] for s in STEPS):9.4f}"
        )
        masks_seconds[name] = best["masks"]
        totals[name] = sum(best[s] for s in STEPS)
    ratio = masks_seconds["mp4, whole frames"] / masks_seconds["mp4 alone"]
    print(f"segmenter on whole frames / following the object: {ratio:.2f}×")
    extra = masks_seconds["mp4 alone"] - masks_seconds["mp4, no colours"]
    print(f"the clip's colour model: {extra * 1000:+.0f} ms of the masks' time")
    if "mp4, float32 seg" in masks_seconds:
        ratio = masks_seconds["mp4, float32 seg"] / masks_seconds["mp4 alone"]
        print(f"segmenter float32 / bfloat16 (this CPU runs bfloat16 natively): {ratio:.2f}×")
    elif "mp4, bfloat16 seg" in masks_seconds:
        ratio = masks_seconds["mp4, bfloat16 seg"] / masks_seconds["mp4 alone"]
        print(f"segmenter bfloat16 / float32 (the probe took float32 here): {ratio:.2f}×")
    else:
        print("segmenter in float32: this CPU does not run bfloat16 natively")
    for name in ("held, start given", "held, start auto"):
        print(f"{name} / the mp4 alone: {totals[name] / totals['mp4 alone']:.2f}× in all")
    for name in ("held 3 s, given", "held 3 s, auto"):
        print(
            f"{name} (1080×1080) / the mp4 1080×1080: {totals[name] / totals['mp4 1080×1080']:.2f}×"
        )
    out = tmp / "cold"
    command = [sys.executable, "-m", "reconphys.cli", "predict", str(video), "--no-refine"]
    command += ["--preview-frames", "0", "--out", str(out), "--device", device]
    started = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    wall = time.perf_counter() - started
    steps = json.loads((out / "prediction.json").read_text())["timings_s"]
    print(
        f"cold `reconphys predict --no-refine --preview-frames 0` on the mp4: {wall:.2f} s wall "
        f"(its steps: {', '.join(f'{k} {v:.3f}' for k, v in steps.items())})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="dataset folder (make-data)")
    parser.add_argument("--sample", default=None, help="sample id (default: the first test one)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--gs-model", default=None, help="3DGS predictor for the predicted case")
    parser.add_argument("--realistic", default=None, help="a realistic-look dataset (module doc)")
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    sample = args.sample or first_test_sample(args.data)
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description(args.device)}")
    with tempfile.TemporaryDirectory() as tmp:
        bundle = export_video(args.data, sample, Path(tmp) / "bundle")
        big = make_procedural_gaussians("bunny", 20000, seed=0)
        reference = predict(
            str(bundle / "video.mp4"),
            camera=bundle / "camera.json",
            gaussians=bundle / "gaussians.ply",
            refine=False,
        )
        # the large object where the small one is: same centre, its own size (0.5 m)
        shift = reference.asset.gaussians.means.mean(0) - big.means.mean(0)
        write_ply(Path(tmp) / "big.ply", big.with_means(big.means + shift))
        cases = {
            "shipped": dict(gaussians=bundle / "gaussians.ply"),
            "large": dict(gaussians=Path(tmp) / "big.ply", num_anchors=2048),
        }
        try:
            load_gaussian_predictor(args.gs_model)
            cases["predicted"] = dict(gs_model=args.gs_model)
        except InputError as e:
            print(f"# predicted case skipped: {e}")
        print(
            f"{'case':9s} {'gaussians':>9s} {'anchors':>7s} "
            + " ".join(f"{s:>15s}" for s in STEPS)
            + f" {'network+build':>14s} {'all four':>9s}"
        )
        for name, extra in cases.items():
            kwargs = dict(
                input=str(bundle / "video.mp4"),
                camera=bundle / "camera.json",
                device=args.device,
                placement="as-is",
                refine=False,  # the feed-forward steps (the search: search_refinement.py)
                **extra,
            )
            try:
                result = predict(**kwargs)  # warm-up: Numba compilation, allocator, file cache
            except InputError as e:  # the bunny refused where the sample's object is no bunny
                print(f"# {name} case skipped: {str(e).splitlines()[0][:160]}")
                continue
            timings = best_timings(args.repeats, **kwargs)
            target = timings["physics_network"] + timings["asset_build"]
            print(
                f"{name:9s} {result.asset.gaussians.num_gaussians:9d} "
                f"{result.asset.num_anchors:7d} "
                + " ".join(f"{timings[s]:15.4f}" for s in STEPS)
                + f" {target:14.4f} {sum(timings.values()):9.4f}"
            )
        if args.realistic:
            realistic_rows(args.realistic, Path(tmp), args.repeats, args.device)
    points = torch.rand(16384, 3, generator=torch.Generator().manual_seed(0)).double()
    farthest_point_sampling(points, 8)  # compile / load from the cache
    seconds = {}
    for name, fn in (
        ("reference", farthest_point_sampling_reference),
        ("compiled", farthest_point_sampling),
    ):
        started = time.perf_counter()
        fn(points, 2048)
        seconds[name] = time.perf_counter() - started
    ratio = seconds["reference"] / seconds["compiled"]
    print(
        f"farthest-point sampling 16384 → 2048: reference {seconds['reference']:.3f} s, "
        f"compiled {seconds['compiled']:.4f} s, ratio {ratio:.0f}×"
    )


if __name__ == "__main__":
    main()
