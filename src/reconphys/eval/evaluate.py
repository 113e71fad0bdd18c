"""Run methods over the samples of a split and score every prediction frame by frame.

For each sample and method: ``predict`` (timed: the seconds per scene), then the prediction is
turned into Gaussian centres for every frame — a physics method's asset is simulated for the
clip's ``T − 1`` steps from its own initial state and its Gaussians follow the anchors through
the binding; a no-physics method gives its fitted centres directly — rendered in the sample's
views and compared with the stored frames and the true Gaussian centres:

- per frame and view: PSNR, SSIM (and LPIPS when its weights are on this machine) over the
  ground truth's foreground (:mod:`.metrics`); the frame's value is the mean over the views;
- per frame: Chamfer distance and EMD between predicted and true Gaussian centres;
- per sample and window (reconstruction = frames 0–19, future = frames 20–T−1): the mean over
  the window's frames; per method: the mean over samples (see :mod:`.summary`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..assets.gaussians import Gaussians
from ..errors import InputError
from ..render import Cameras, render
from ..render.video import to_uint8
from .lpips import load_lpips
from .methods import METHODS, Method, MethodOptions, Prediction
from .methods.base import INPUT_FRAMES
from .metrics import (
    CHAMFER_POINTS,
    EMD_POINTS,
    chamfer_distance,
    earth_movers_distance,
    foreground_mask,
    psnr,
    ssim,
)
from .samples import EvalSample, EvalSet, TrivialAttributes

FRAMES_PER_RENDER_CALL = 8  # bounds renderer memory at large resolutions
INITIAL_SUFFIX = "_initial"  # row of a method's initial guess (springgaus_initial)


@dataclass(frozen=True)
class EvalSettings:
    methods: tuple[str, ...] = tuple(METHODS)
    budget_seconds: float = 60.0  # per scene, for springgaus and appearance
    device: str = "cpu"
    seed: int = 0
    chamfer_points: int = CHAMFER_POINTS
    emd_points: int = EMD_POINTS
    sheet_samples: int = 2  # samples whose frames are kept for the contact sheet
    model: str | None = None  # weights of the ``reconphys`` method (None: the default model)


@dataclass
class Row:
    """One line of the report: a method, or a method's initial guess."""

    name: str
    description: str
    geometry: str
    has_physics: bool
    uses_ground_truth: bool
    timed: bool = True  # False for an initial guess (its time is part of its method's)


@dataclass
class SampleResult:
    row: str
    sample: str
    object: str
    psnr: np.ndarray  # [T] mean over views; NaN for frames without a prediction
    ssim: np.ndarray  # [T]
    lpips: np.ndarray | None  # [T], None when LPIPS is unavailable
    cd: np.ndarray  # [T] m²
    emd: np.ndarray  # [T] m
    true_attributes: dict[str, float]
    predicted_attributes: dict[str, float] | None
    seconds: float | None  # predict wall-clock
    failure: str | None = None
    intervals: dict[str, list[float]] | None = None  # the method's 10–90 % intervals, if any
    info: dict = field(default_factory=dict)
    sheet: np.ndarray | None = None  # [T', H, W, 3] uint8, view 0, kept for a few samples


@dataclass
class Results:
    settings: EvalSettings
    rows: list[Row]
    results: list[SampleResult]
    trivial: TrivialAttributes
    samples: list[str]
    num_frames: int
    lpips_available: bool
    seconds: float
    ground_truth_sheets: dict[str, np.ndarray]  # sample → [T, H, W, 3] uint8, view 0


def render_sequence(
    gaussians: Gaussians,  # [N] at rest (colours, scales, opacities)
    means: Tensor,  # [T, N, 3] centres per frame, metres
    cameras: Cameras,  # V cameras, no batch dims
) -> Tensor:  # [V, T, H, W, 3] in [0, 1]
    device = means.device
    gaussians, cameras = gaussians.to(device), cameras.to(device)
    chunks = []
    with torch.no_grad():
        for start in range(0, means.shape[0], FRAMES_PER_RENDER_CALL):
            part = means[start : start + FRAMES_PER_RENDER_CALL]
            batch = gaussians.map(lambda t, n=part.shape[0]: t.expand(n, *t.shape))
            chunks.append(render(batch.with_means(part), cameras).rgb)  # [t, V, H, W, 3]
    return torch.cat(chunks).transpose(0, 1)


def predicted_means(
    prediction: Prediction, num_frames: int, device: torch.device
) -> tuple[Gaussians, Tensor]:  # Gaussians [N], centres [T', N, 3]
    """The Gaussians and their centres per frame that a prediction implies."""
    if prediction.asset is not None:
        trajectory = prediction.asset.simulate(num_frames - 1, device)
        with torch.no_grad():
            means = prediction.asset.gaussian_means(trajectory.x[0])
        return prediction.asset.gaussians, means
    if prediction.gaussians is None or prediction.means is None:
        raise ValueError("a prediction needs an asset, or Gaussians and their centres")
    return prediction.gaussians, prediction.means[:num_frames].to(device)


def score(
    sample: EvalSample,
    gaussians: Gaussians,
    means: Tensor,  # [T', N, 3], T' ≤ T
    settings: EvalSettings,
    lpips_model,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per-frame metrics (arrays [T], NaN past T') and the rendered view 0 ([T', H, W, 3] uint8)."""
    device = means.device
    frames = render_sequence(gaussians, means, sample.cameras)  # [V, T', H, W, 3]
    count = frames.shape[1]
    truth = sample.frames[:, :count].to(device)
    total = sample.num_frames
    out = {name: np.full(total, math.nan) for name in ("psnr", "ssim", "lpips", "cd", "emd")}
    out["psnr"][:count] = psnr(frames, truth).nanmean(0).cpu().numpy()
    out["ssim"][:count] = ssim(frames, truth).nanmean(0).cpu().numpy()
    if lpips_model is not None:
        mask = foreground_mask(truth)[..., None]
        values = lpips_model((frames * mask).flatten(0, 1), (truth * mask).flatten(0, 1))
        out["lpips"][:count] = values.reshape(frames.shape[:2]).mean(0).cpu().numpy()
    true_means = sample.gaussian_means
    for t in range(count):
        predicted = means[t].cpu()
        out["cd"][t] = chamfer_distance(predicted, true_means[t], settings.chamfer_points, seed=t)
        out["emd"][t] = earth_movers_distance(predicted, true_means[t], settings.emd_points, t)
    return out, to_uint8(frames[0])


def _failed(row: str, sample: EvalSample, reason: str, seconds: float | None) -> SampleResult:
    nan = np.full(sample.num_frames, math.nan)
    return SampleResult(
        row=row,
        sample=sample.id,
        object=sample.object,
        psnr=nan,
        ssim=nan,
        lpips=None,
        cd=nan,
        emd=nan,
        true_attributes=sample.attributes,
        predicted_attributes=None,
        seconds=seconds,
        failure=reason,
    )


def evaluate_prediction(
    row: str,
    sample: EvalSample,
    prediction: Prediction,
    seconds: float | None,
    settings: EvalSettings,
    lpips_model,
    keep_sheet: bool,
) -> SampleResult:
    device = torch.device(settings.device)
    try:
        gaussians, means = predicted_means(prediction, sample.num_frames, device)
    except (InputError, ValueError) as e:  # e.g. attributes that make the simulation blow up
        return _failed(row, sample, f"simulation failed: {e}", seconds)
    values, sheet = score(sample, gaussians, means, settings, lpips_model)
    return SampleResult(
        row=row,
        sample=sample.id,
        object=sample.object,
        psnr=values["psnr"],
        ssim=values["ssim"],
        lpips=values["lpips"] if lpips_model is not None else None,
        cd=values["cd"],
        emd=values["emd"],
        true_attributes=sample.attributes,
        predicted_attributes=prediction.attributes,
        seconds=seconds,
        info=prediction.info,
        intervals=prediction.intervals,
        sheet=sheet if keep_sheet else None,
    )


def make_rows(methods: list[Method]) -> list[Row]:
    rows = []
    for method in methods:
        rows.append(
            Row(
                method.name,
                method.description,
                method.geometry,
                method.has_physics,
                method.uses_ground_truth,
            )
        )
        if method.name == "springgaus":
            rows.append(
                Row(
                    method.name + INITIAL_SUFFIX,
                    "springgaus's starting point: the trivial attributes on its fitted geometry "
                    "and initial velocity (what its dynamic stage starts from)",
                    method.geometry,
                    True,
                    method.uses_ground_truth,
                    timed=False,
                )
            )
    return rows


def run_evaluation(
    eval_set: EvalSet,
    settings: EvalSettings,
    log: Callable[[str], None] = lambda line: None,
) -> Results:
    """Predict and score every (sample, method) of ``eval_set``; ``log`` receives progress lines."""
    started = time.perf_counter()
    trivial = eval_set.trivial_attributes()
    options = MethodOptions(
        trivial=trivial,
        budget_seconds=settings.budget_seconds,
        device=torch.device(settings.device),
        seed=settings.seed,
        model=settings.model,
    )
    methods = [METHODS[name](options) for name in settings.methods]
    lpips_model = load_lpips(settings.device)
    results: list[SampleResult] = []
    sheets: dict[str, np.ndarray] = {}
    num_frames = 0
    for position in range(len(eval_set)):
        sample = eval_set.load(position)
        num_frames = sample.num_frames
        keep_sheet = position < settings.sheet_samples
        if keep_sheet:
            sheets[sample.id] = to_uint8(sample.frames[0])
        for method in methods:
            tick = time.perf_counter()
            try:
                prediction = method.predict(sample)
            except (InputError, ValueError) as e:
                results.append(_failed(method.name, sample, f"predict failed: {e}", None))
                log(f"{sample.id:<28} {method.name:<12} failed: {e}")
                continue
            seconds = time.perf_counter() - tick + prediction.reused_seconds
            result = evaluate_prediction(
                method.name, sample, prediction, seconds, settings, lpips_model, keep_sheet
            )
            results.append(result)
            if prediction.initial_guess is not None:
                initial = Prediction(asset=prediction.initial_guess)
                results.append(
                    evaluate_prediction(
                        method.name + INITIAL_SUFFIX,
                        sample,
                        initial,
                        None,
                        settings,
                        lpips_model,
                        keep_sheet,
                    )
                )
            log(
                f"{sample.id:<28} {method.name:<12} predict {seconds:6.1f} s, scored in "
                f"{time.perf_counter() - tick - seconds + prediction.reused_seconds:5.1f} s: PSNR "
                f"{_window_mean(result.psnr, 0, INPUT_FRAMES):5.2f} / "
                f"{_window_mean(result.psnr, INPUT_FRAMES, num_frames):5.2f} dB"
            )
        options.cache.clear()
    return Results(
        settings=settings,
        rows=make_rows(methods),
        results=results,
        trivial=trivial,
        samples=eval_set.ids,
        num_frames=num_frames,
        lpips_available=lpips_model is not None,
        seconds=time.perf_counter() - started,
        ground_truth_sheets=sheets,
    )


def _window_mean(values: np.ndarray, start: int, stop: int) -> float:
    window = values[start:stop]
    window = window[np.isfinite(window)]
    return float(window.mean()) if window.size else math.nan
