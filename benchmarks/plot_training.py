"""Training curves from ``reconphys train`` logs (OUT/log.jsonl), drawn with Pillow.

One PNG with four panels — the minimised loss (log10), the normalised attribute error (L1 to
the truth in [0, 1] per attribute, logged whatever the objective), the same for the observables
(log m, log k/m, log d/m, f; runs logged before it existed leave it out) and the photometric term
(log10, where present) — one colour per run, raw values faint and a moving average on top.

    python benchmarks/plot_training.py runs/self:self-supervised runs/sup:supervised \\
        runs/mixed:mixed --out docs/images/training_curves.png [--x elapsed] [--smooth 25]

Each run is ``PATH[:LABEL]``: a training output folder or a log.jsonl file.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont

from reconphys.eval.plots import COLOURS, Axes

BLACK, WHITE = (0, 0, 0), (255, 255, 255)
PANELS = (
    ("loss", "loss (minimised)", True),
    ("attribute_error", "attribute error (normalised L1)", False),
    ("observable_error", "observable error (log m, k/m, d/m; f)", False),
    ("photometric", "photometric MSE", True),
)


def read_log(path: Path) -> list[dict]:
    """Records of a log.jsonl (a folder means FOLDER/log.jsonl), skipped steps left out."""
    path = path / "log.jsonl" if path.is_dir() else path
    records = []
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut short by a kill
        if not record.get("skipped_step"):
            records.append(record)
    return records


def moving_average(values: list[float], window: int) -> list[float]:
    out, total, queue = [], 0.0, []
    for value in values:
        queue.append(value)
        total += value
        if len(queue) > window:
            total -= queue.pop(0)
        out.append(total / len(queue))
    return out


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def plot(runs: list[tuple[str, list[dict]]], path: Path, x_key: str, smooth: int) -> None:
    width, height = 60 + 480 * len(PANELS), 520
    image = Image.new("RGB", (width, height), WHITE)
    draw = ImageDraw.Draw(image)
    x_label = "hours" if x_key == "elapsed" else "step"
    for panel, (key, title, log_scale) in enumerate(PANELS):
        series = []
        for index, (_, records) in enumerate(runs):
            points = [(r[x_key], r[key]) for r in records if r.get(key) is not None]
            points = [(x, y) for x, y in points if math.isfinite(y) and (y > 0 or not log_scale)]
            if not points:
                continue
            xs = [x / 3600 if x_key == "elapsed" else x for x, _ in points]
            ys = [math.log10(y) if log_scale else y for _, y in points]
            series.append((index, xs, ys))
        left = 90 + panel * 480
        box = (left, 50, left + 380, 430)
        if not series:
            draw.rectangle(box, outline=BLACK)
            draw.text((left + 190, 240), f"no {key}", fill=BLACK, font=_font(14), anchor="mm")
            continue
        all_x = [x for _, xs, _ in series for x in xs]
        all_y = [y for _, _, ys in series for y in ys]
        low, high = min(all_y), max(all_y)
        pad = 0.05 * (high - low) or 0.5
        axes = Axes(
            draw,
            box,
            (min(all_x), max(all_x) if max(all_x) > min(all_x) else min(all_x) + 1),
            (low - pad, high + pad),
            title,
            x_label,
            "log10" if log_scale else "",
        )
        for index, xs, ys in series:
            colour = COLOURS[index % len(COLOURS)]
            faint = tuple(int(c + (255 - c) * 0.7) for c in colour)
            axes.line(xs, ys, faint, width=1)
            axes.line(xs, moving_average(ys, smooth), colour, width=2)
    font = _font(13)
    for index, (label, records) in enumerate(runs):
        colour = COLOURS[index % len(COLOURS)]
        x = 90 + index * 300
        draw.rectangle([x, 478, x + 12, 490], fill=colour)
        steps = records[-1]["step"] if records else 0
        draw.text((x + 18, 476), f"{label} ({steps} steps)", fill=BLACK, font=font)
    image.save(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="PATH[:LABEL], PATH a run folder or log.jsonl")
    parser.add_argument("--out", type=Path, default=Path("training_curves.png"))
    parser.add_argument("--x", choices=("step", "elapsed"), default="step")
    parser.add_argument("--smooth", type=int, default=25, help="moving-average window, steps")
    args = parser.parse_args()
    runs = []
    for spec in args.runs:
        path, _, label = spec.partition(":")
        runs.append((label or Path(path).name, read_log(Path(path))))
    plot(runs, args.out, args.x, max(1, args.smooth))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
