"""From per-frame scores to the numbers of the report: windows, means over samples, attribute MAE.

- a sample's window score is the mean over the window's frames (frames without a prediction are
  skipped; a window with none is "unavailable");
- a method's score is the mean of its samples' window scores over the samples it did not fail on;
- attribute MAE is over the same samples (:func:`reconphys.eval.metrics.attribute_errors`);
- ``seconds_per_scene`` is the mean wall-clock of ``predict``.

Values that do not exist (LPIPS without weights, the future of a method without physics, the
attributes of the appearance baseline) are ``None`` here and ``null`` in metrics.json.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch

from ..physics import ATTRIBUTES
from ..pipeline.search import OBSERVABLES, observables
from .evaluate import INITIAL_SUFFIX, INPUT_FRAMES, Results, Row, SampleResult
from .metrics import attribute_errors

IMAGE_AND_POINT_METRICS = ("psnr", "ssim", "lpips", "cd", "emd")
ATTRIBUTE_KEYS = (*ATTRIBUTES, "log_k_over_m", "log_d_over_m")


def windows(num_frames: int) -> dict[str, tuple[int, int]]:
    """Frame ranges
    [start, stop) of the two windows (docs/design.md#conventions, docs/design.md#evaluation)."""
    return {
        "reconstruction": (0, min(INPUT_FRAMES, num_frames)),
        "future": (min(INPUT_FRAMES, num_frames), num_frames),
    }


def _finite_mean(values) -> float | None:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(values)) if values else None


def window_score(result: SampleResult, metric: str, start: int, stop: int) -> float | None:
    """Mean of one metric over a window of one sample (None when nothing was predicted there)."""
    values = getattr(result, metric)
    if values is None:
        return None
    return _finite_mean(values[start:stop].tolist())


def per_sample_scores(result: SampleResult, num_frames: int) -> dict[str, dict]:
    return {
        window: {m: window_score(result, m, *frames) for m in IMAGE_AND_POINT_METRICS}
        for window, frames in windows(num_frames).items()
    }


def attribute_mae(results: list[SampleResult]) -> dict[str, float | None]:
    have = [r for r in results if r.predicted_attributes is not None and r.failure is None]
    if not have:
        return dict.fromkeys(ATTRIBUTE_KEYS)
    names = ATTRIBUTES

    def column(source: str, name: str) -> torch.Tensor:
        return torch.tensor([getattr(r, source)[name] for r in have], dtype=torch.float64)

    errors = attribute_errors(
        {n: column("predicted_attributes", n) for n in names},
        {n: column("true_attributes", n) for n in names},
    )
    return {key: errors[key] for key in ATTRIBUTE_KEYS}


def interval_summary(results: list[SampleResult]) -> dict | None:
    """Per observable: the share of samples whose 10–90 % interval holds the truth (a calibrated
    method: about 0.8) and the intervals' mean width; None when the method gives no intervals."""
    have = [r for r in results if r.intervals is not None and r.failure is None]
    if not have:
        return None
    truths = [observables(SimpleNamespace(**r.true_attributes)).tolist() for r in have]
    out = {}
    for i, key in enumerate(OBSERVABLES):
        bounds = [r.intervals[key] for r in have]
        inside = [lo <= t[i] <= hi for t, (lo, hi) in zip(truths, bounds, strict=True)]
        out[key] = {
            "coverage": float(np.mean(inside)),
            "mean_width": float(np.mean([hi - lo for lo, hi in bounds])),
            "samples": len(have),
        }
    return out


def method_summary(row: Row, results: list[SampleResult], num_frames: int) -> dict:
    """The metrics.json entry of one row."""
    good = [r for r in results if r.failure is None]
    scores = [per_sample_scores(r, num_frames) for r in good]
    entry = {
        window: {
            m: _finite_mean(s[window][m] for s in scores) if scores else None
            for m in IMAGE_AND_POINT_METRICS
        }
        for window in windows(num_frames)
    }
    entry["attribute_mae"] = (
        attribute_mae(good) if row.has_physics else dict.fromkeys(ATTRIBUTE_KEYS)
    )
    entry["intervals"] = interval_summary(good) if row.has_physics else None
    seconds = [r.seconds for r in results if r.seconds is not None]
    entry["seconds_per_scene"] = float(np.mean(seconds)) if row.timed and seconds else None
    entry.update(
        {
            "description": row.description,
            "geometry": row.geometry,
            "upper_bound": row.uses_ground_truth,
            "has_physics": row.has_physics,
            "samples_scored": len(good),
            "failures": [f"{r.sample}: {r.failure}" for r in results if r.failure is not None],
        }
    )
    return entry


def wins(
    results: list[SampleResult],
    control: list[SampleResult],
    num_frames: int,
    window: str = "future",
    metric: str = "psnr",
) -> tuple[int, int]:
    """(samples where ``results`` scores higher than ``control``, samples where both exist)."""
    frames = windows(num_frames)[window]
    theirs = {r.sample: window_score(r, metric, *frames) for r in control if r.failure is None}
    won = compared = 0
    for r in results:
        mine = window_score(r, metric, *frames) if r.failure is None else None
        other = theirs.get(r.sample)
        if mine is None or other is None:
            continue
        compared += 1
        won += mine > other
    return won, compared


def summarise(results: Results) -> dict:
    """The ``methods`` part of metrics.json, plus per-row win counts (samples with the higher
    window PSNR) against ``trivial`` and, for springgaus, against its own initial guess."""
    by_row = {row.name: [r for r in results.results if r.row == row.name] for row in results.rows}
    methods = {}
    for row in results.rows:
        entry = method_summary(row, by_row[row.name], results.num_frames)
        if "trivial" in by_row and row.name != "trivial":
            entry["beats_trivial"] = {
                f"{window}_psnr": list(
                    wins(by_row[row.name], by_row["trivial"], results.num_frames, window)
                )
                for window in windows(results.num_frames)
            }
        initial = by_row.get(row.name + INITIAL_SUFFIX)
        if initial:
            entry["beats_initial_guess"] = {
                f"{window}_psnr": list(wins(by_row[row.name], initial, results.num_frames, window))
                for window in windows(results.num_frames)
            }
        methods[row.name] = entry
    return methods
