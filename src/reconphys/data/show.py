"""``reconphys data show``: a summary table of a dataset folder and a contact-sheet PNG."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from ..io import read_npz
from ..physics import ATTRIBUTES
from ..render.video import tile_images
from .storage import read_manifest

SHEET_TILE = 96  # pixels: small renders are enlarged (nearest neighbour) to at least this


def summary(root: Path) -> str:
    """Counts per split, attribute ranges and the contact-frame histogram, as plain text."""
    manifest = read_manifest(root)
    settings = manifest["parsed_settings"]
    samples = manifest["samples"]
    lines = [
        f"dataset {root}: {len(samples)} samples"
        + ("" if manifest["complete"] else " (INCOMPLETE: rerun make-data to finish)"),
        f"source {settings.source}, seed {settings.seed}, {settings.resolution}² px, "
        f"{settings.num_frames} frames × {settings.frame_dt} s, 4 views, "
        f"N_A {settings.num_anchors}, {settings.num_gaussians} Gaussians, "
        f"{settings.distribution} attributes, "
        f"reconphys {manifest['package_version']}",
        "",
        f"{'split':<6} {'objects':>7} {'samples':>7}  "
        + "  ".join(f"{a + ' min/median/max':<26}" for a in ATTRIBUTES),
    ]
    for split in ("train", "test"):
        chosen = [s for s in samples if s["split"] == split]
        objects = sum(o["split"] == split for o in manifest["objects"])
        columns = []
        for name in ATTRIBUTES:
            values = np.array([s["attributes"][name] for s in chosen])
            text = (
                f"{values.min():.3g} / {np.median(values):.3g} / {values.max():.3g}"
                if len(values)
                else "-"
            )
            columns.append(f"{text:<26}")
        lines.append(f"{split:<6} {objects:>7} {len(chosen):>7}  " + "  ".join(columns))
    frames = Counter(s["contact_frame"] for s in samples)
    lines += ["", "first ground contact (frame: samples)"]
    for frame in sorted(frames):
        label = "never" if frame < 0 else f"{frame:>5}"
        lines.append(f"  {label}: {frames[frame]:>4} {'#' * min(frames[frame], 60)}")
    if samples:
        inside = sum(5 <= s["contact_frame"] <= 20 for s in samples)
        lines.append(
            f"  in frames 5–20: {inside}/{len(samples)} ({100 * inside / len(samples):.0f} %)"
        )
    return "\n".join(lines)


def contact_sheet(
    root: Path,
    num_samples: int = 4,
    view: int = 0,
    columns: int = 8,
) -> np.ndarray:  # [rows·h, columns·w, 3] uint8
    """Rows of evenly spaced samples, each ``columns`` evenly spaced frames of one view."""
    manifest = read_manifest(root)
    samples = manifest["samples"]
    if not samples:
        return np.zeros((SHEET_TILE, SHEET_TILE, 3), np.uint8)
    picks = np.unique(np.linspace(0, len(samples) - 1, min(num_samples, len(samples))).round())
    rows = []
    for i in picks.astype(int):
        frames = read_npz(root / samples[i]["frames"], (f"view_{view}",))[f"view_{view}"]
        times = np.linspace(0, len(frames) - 1, min(columns, len(frames))).round().astype(int)
        rows.append(list(frames[times]))
    factor = max(1, -(-SHEET_TILE // rows[0][0].shape[0]))
    return tile_images(rows, scale=factor, pad=1, fill=60)
