"""Writing an evaluation: metrics.json, report.md (the paper's Tables 1–3), CSVs and figures.

The folder is assembled under a hidden name beside the target and renamed into place, so a
killed run never leaves a half-written report.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
from pathlib import Path

import torch

from .. import __version__
from ..errors import InputError
from ..io import atomic_folder
from ..physics import ATTRIBUTES
from ..pipeline.search import OBSERVABLES
from .evaluate import INITIAL_SUFFIX, Results
from .lpips import MIN_SIDE
from .metrics import FOREGROUND_THRESHOLD, SSIM_SIGMA, SSIM_WINDOW
from .plots import attribute_scatter, contact_sheet, psnr_curves
from .summary import IMAGE_AND_POINT_METRICS, per_sample_scores, summarise, windows

LPIPS_UNAVAILABLE = (
    "LPIPS unavailable: the AlexNet and LPIPS v0.1 weights were not found on this machine "
    "(see reconphys.eval.lpips); reported as null, no other network stands in for it"
)


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            cpu = next(
                (
                    line.split(":", 1)[1].strip()
                    for line in cpuinfo
                    if line.startswith("model name")
                ),
                cpu,
            )
    except OSError:
        pass
    threads = torch.get_num_threads()
    return f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} ({threads} threads)"


def settings_block(results: Results, data: str, split: str, limit: int | None, dataset) -> dict:
    s = results.settings
    frames = windows(results.num_frames)
    lpips_note = None
    if not results.lpips_available:
        lpips_note = LPIPS_UNAVAILABLE
    elif dataset.resolution < MIN_SIDE:
        lpips_note = f"images upsampled to {MIN_SIDE} px before LPIPS (AlexNet needs that size)"
    return {
        "data": data,
        "split": split,
        "limit": limit,
        "methods": list(s.methods),
        "budget_seconds": s.budget_seconds,
        "device": s.device,
        "seed": s.seed,
        "num_frames": results.num_frames,
        "windows": {name: [start, stop - 1] for name, (start, stop) in frames.items()},
        "resolution": dataset.resolution,
        "views": 4,
        "foreground_threshold": FOREGROUND_THRESHOLD,
        "ssim": {"window": SSIM_WINDOW, "sigma": SSIM_SIGMA},
        "chamfer": {"points": s.chamfer_points, "squared": True, "units": "m^2"},
        "emd": {"points": s.emd_points, "squared": False, "units": "m"},
        "lpips": {"available": results.lpips_available, "note": lpips_note},
        "trivial": {"values": results.trivial.values, "source": results.trivial.source},
        "dataset_settings": dataset.to_dict(),
        "package_version": __version__,
        "machine": machine_description(),
        "total_seconds": round(results.seconds, 1),
    }


def metrics_document(results: Results, settings: dict) -> dict:
    return {
        "methods": summarise(results),
        "samples": len(results.samples),
        "sample_ids": results.samples,
        "settings": settings,
    }


# ----------------------------------------------------------------------------------------------
# CSVs


def _number(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def write_csvs(results: Results, document: dict, folder: Path) -> None:
    metric_columns = [
        f"{window}_{metric}" for window in windows(1) for metric in IMAGE_AND_POINT_METRICS
    ]
    attribute_columns = list(next(iter(document["methods"].values()))["attribute_mae"])
    with open(folder / "summary.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            [
                "method",
                "geometry",
                "upper_bound",
                *metric_columns,
                *[f"mae_{a}" for a in attribute_columns],
                "seconds_per_scene",
                "samples_scored",
            ]
        )
        for name, entry in document["methods"].items():
            writer.writerow(
                [
                    name,
                    entry["geometry"],
                    entry["upper_bound"],
                    *[_number(entry[w][m]) for w in windows(1) for m in IMAGE_AND_POINT_METRICS],
                    *[_number(entry["attribute_mae"][a]) for a in attribute_columns],
                    _number(entry["seconds_per_scene"]),
                    entry["samples_scored"],
                ]
            )
    names = ATTRIBUTES
    bounds = [(o, i, end) for o in OBSERVABLES for i, end in enumerate(("lo", "hi"))]
    with open(folder / "per_sample.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            [
                "method",
                "sample",
                "object",
                *metric_columns,
                *[f"true_{n}" for n in names],
                *[f"predicted_{n}" for n in names],
                *[f"interval_{o}_{end}" for o, _, end in bounds],
                "seconds",
                "failure",
                "info",
            ]
        )
        for r in results.results:
            scores = per_sample_scores(r, results.num_frames)
            predicted = r.predicted_attributes or {}
            writer.writerow(
                [
                    r.row,
                    r.sample,
                    r.object,
                    *[_number(scores[w][m]) for w in scores for m in IMAGE_AND_POINT_METRICS],
                    *[_number(r.true_attributes[n]) for n in names],
                    *[_number(predicted.get(n)) for n in names],
                    *[_number(r.intervals[o][i]) if r.intervals else "" for o, i, _ in bounds],
                    _number(r.seconds),
                    r.failure or "",
                    json.dumps(r.info, sort_keys=True) if r.info else "",
                ]
            )
    with open(folder / "per_frame.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["method", "sample", "frame", *IMAGE_AND_POINT_METRICS])
        for r in results.results:
            for t in range(results.num_frames):
                values = [getattr(r, m) for m in IMAGE_AND_POINT_METRICS]
                row = [_number(float(v[t])) if v is not None else "" for v in values]
                if any(row):
                    writer.writerow([r.row, r.sample, t, *row])


# ----------------------------------------------------------------------------------------------
# report.md

FORMATS = {"psnr": "{:.2f}", "ssim": "{:.3f}", "lpips": "{:.4f}", "cd": "{:.2e}", "emd": "{:.4f}"}


def _cell(value, fmt: str = "{:.3g}") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return fmt.format(value)


def _row_label(name: str, entry: dict) -> str:
    return f"{name} †" if entry["upper_bound"] else name


def report_markdown(results: Results, document: dict, command: str | None) -> str:
    """report.md: the settings, Table 1 (per method, both windows), Table 2 (per sample),
    Table 3 (attribute errors) and the figures, from the metrics.json ``document``."""
    frames = windows(results.num_frames)
    lines = _settings_lines(results, document, command, frames)
    lines += _table_methods(document, frames)
    lines += _table_samples(results, document, frames)
    lines += _table_attributes(document)
    lines += _figure_lines()
    return "\n".join(lines)


def _settings_lines(results: Results, document: dict, command: str | None, frames) -> list[str]:
    """The title and the run's settings, one bullet each."""
    settings = document["settings"]
    (r0, r1), (f0, f1) = frames["reconstruction"], frames["future"]
    lines = [
        "# Evaluation report",
        "",
        f"- data: `{settings['data']}`, split `{settings['split']}`, {document['samples']} "
        f"samples, {settings['resolution']}×{settings['resolution']} px, 4 views, "
        f"{results.num_frames} frames",
        f"- windows: dynamic reconstruction = frames {r0}–{r1 - 1}, future prediction = "
        f"frames {f0}–{f1 - 1}"
        + ("" if f1 > f0 else " (the clips are too short: no future window)"),
        f"- trivial predictor: {settings['trivial']['source']}: "
        + ", ".join(f"{k} {v:.4g}" for k, v in settings["trivial"]["values"].items()),
        f"- per-scene budget (springgaus, appearance): {settings['budget_seconds']:g} s; "
        f"device {settings['device']}; seed {settings['seed']}",
        f"- machine: {settings['machine']}; total {settings['total_seconds']:.0f} s",
    ]
    if command:
        lines.insert(2, f"- command: `{command}`")
    if settings["lpips"]["note"]:
        lines.append(f"- {settings['lpips']['note']}")
    return lines


def _table_methods(document: dict, frames) -> list[str]:
    """Table 1: every method's means over both windows, with the notes on each method."""
    methods = document["methods"]
    settings = document["settings"]
    (r0, r1), (f0, f1) = frames["reconstruction"], frames["future"]
    lines = [
        "",
        "**†: uses the ground-truth geometry and initial state** (true Gaussians, anchors, "
        "springs, binding and initial velocity): an upper bound for any method that must "
        "reconstruct them from the video. Rows without † fit everything from the 4 views.",
        "",
        "Image metrics are over the ground truth's foreground pixels (any channel ≥ 10/255); "
        "PSNR/SSIM/LPIPS are means over frames and views, then samples. CD: squared Chamfer "
        f"distance in m² on ≤ {settings['chamfer']['points']} points; EMD: mean matched "
        f"distance in m on {settings['emd']['points']}-point subsamples (identical point sets "
        "score ≈ the subsampling floor, not 0, when a set has more points than that). "
        "See docs/evaluation.md.",
        "",
        f"## Table 1 — reconstruction (frames {r0}–{r1 - 1}) and future prediction "
        f"(frames {f0}–{f1 - 1})",
        "",
        "| method | PSNR↑ | SSIM↑ | LPIPS↓ | CD↓ (m²) | EMD↓ (m) | PSNR↑ | SSIM↑ | LPIPS↓ | "
        "CD↓ (m²) | EMD↓ (m) | time (s/scene) | future PSNR > trivial |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, entry in methods.items():
        cells = [
            _cell(entry[w][m], FORMATS[m]) for w in ("reconstruction", "future") for m in FORMATS
        ]
        beats = entry.get("beats_trivial", {}).get("future_psnr")
        beats_cell = f"{beats[0]}/{beats[1]}" if beats and beats[1] else "–"
        lines.append(
            f"| {_row_label(name, entry)} | "
            + " | ".join(cells)
            + f" | {_cell(entry['seconds_per_scene'], '{:.1f}')} | {beats_cell} |"
        )
    lines += ["", "Columns 2–6: reconstruction window; 7–11: future window.", ""]
    for name, entry in methods.items():
        lines.append(f"- **{name}**: {entry['description']} (geometry: {entry['geometry']}).")
        if entry["failures"]:
            lines.append(f"  Failed on {len(entry['failures'])}: " + "; ".join(entry["failures"]))
    for name, entry in methods.items():
        won = entry.get("beats_initial_guess", {}).get("future_psnr")
        if won and won[1]:
            lines.append(
                f"- {name} beats its initial guess ({name}{INITIAL_SUFFIX}) on future PSNR on "
                f"{won[0]} of {won[1]} samples."
            )
    return lines


def _table_samples(results: Results, document: dict, frames) -> list[str]:
    """Table 2: every metric per sample and method, one block per window."""
    methods = document["methods"]
    lines = ["", "## Table 2 — per sample", ""]
    samples = results.samples
    for window in ("reconstruction", "future"):
        start, stop = frames[window]
        if stop <= start:
            continue
        lines += [
            f"{window.capitalize()} (frames {start}–{stop - 1}):",
            "",
            "| metric | method | " + " | ".join(samples) + " |",
            "|---|---|" + "---|" * len(samples),
        ]
        for metric in IMAGE_AND_POINT_METRICS:
            if metric == "lpips" and not results.lpips_available:
                continue
            for name, entry in methods.items():
                values = []
                for sample in samples:
                    found = [r for r in results.results if r.row == name and r.sample == sample]
                    value = None
                    if found and found[0].failure is None:
                        value = per_sample_scores(found[0], results.num_frames)[window][metric]
                    values.append(_cell(value, FORMATS[metric]))
                lines.append(
                    f"| {metric.upper()} | {_row_label(name, entry)} | " + " | ".join(values) + " |"
                )
        lines.append("")
    return lines


def _table_attributes(document: dict) -> list[str]:
    """Table 3: attribute MAE of the methods that predict physics."""
    methods = document["methods"]
    lines = [
        "## Table 3 — attribute errors (MAE over samples)",
        "",
        "Mass, stiffness and damping are not observable from video one by one "
        "(docs/design.md#physical-model: "
        "scaling m, k, d together leaves the motion unchanged); log(k/m), log(d/m) and friction "
        "are. Compare every row with trivial.",
        "",
        "| method | stiffness | damping | mass | friction | log(k/m) | log(d/m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, entry in methods.items():
        if not entry["has_physics"]:
            continue
        mae = entry["attribute_mae"]
        keys = ("stiffness", "damping", "mass", "friction", "log_k_over_m", "log_d_over_m")
        lines.append(
            f"| {_row_label(name, entry)} | "
            + " | ".join(_cell(mae[k], "{:.4g}") for k in keys)
            + " |"
        )
    with_intervals = {n: e for n, e in methods.items() if e.get("intervals")}
    if with_intervals:
        lines += [
            "",
            "### 10–90 % intervals: coverage of the truth (calibrated: about 80 %) and mean width",
            "",
            "| method | log(k/m) | log(d/m) | friction |",
            "|---|---|---|---|",
        ]
        for name, entry in with_intervals.items():
            cells = [
                f"{entry['intervals'][k]['coverage']:.0%}, width "
                f"{entry['intervals'][k]['mean_width']:.3g}"
                for k in ("log_k_over_m", "log_d_over_m", "friction")
            ]
            lines.append(f"| {_row_label(name, entry)} | " + " | ".join(cells) + " |")
    return lines


def _figure_lines() -> list[str]:
    """The figures and the other files of the folder."""
    return [
        "",
        "## Figures",
        "",
        "![PSNR per frame](psnr_per_frame.png)",
        "",
        "![predicted vs true attributes](attributes_scatter.png)",
        "",
        "![contact sheet: ground truth and each method, view 0](contact_sheet.png)",
        "",
        "Files: metrics.json, summary.csv, per_sample.csv, per_frame.csv.",
        "",
    ]


# ----------------------------------------------------------------------------------------------
# the folder


def check_output(out: Path, overwrite: bool) -> None:
    """Refuse an existing ``out`` unless ``overwrite``; checked before any work is done."""
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", source=str(out))
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))


def write_report(
    results: Results,
    out: str | os.PathLike,
    data: str,
    split: str,
    limit: int | None,
    dataset_settings,
    command: str | None = None,
    overwrite: bool = False,
) -> dict:
    """Write the report folder atomically; returns the metrics.json document."""
    out = Path(out)
    check_output(out, overwrite)
    settings = settings_block(results, data, split, limit, dataset_settings)
    if command:
        settings["command"] = command
    document = metrics_document(results, settings)
    try:
        with atomic_folder(out, overwrite=True) as staging:  # check_output refused a used one
            with open(staging / "metrics.json", "w") as f:
                json.dump(document, f, indent=1, allow_nan=False)
                f.write("\n")
            write_csvs(results, document, staging)
            (staging / "report.md").write_text(report_markdown(results, document, command))
            psnr_curves(results, staging / "psnr_per_frame.png")
            attribute_scatter(results, staging / "attributes_scatter.png")
            contact_sheet(results, staging / "contact_sheet.png")
    except OSError as e:
        raise InputError(f"cannot write ({e.strerror or e})", source=str(out)) from None
    return document
