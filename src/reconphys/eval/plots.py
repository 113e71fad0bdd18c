"""The report's figures, drawn with Pillow (no plotting library needed): per-frame PSNR curves,
predicted-vs-true attribute scatter plots, and a contact sheet of ground truth vs each method."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..render.video import tile_images
from .evaluate import INITIAL_SUFFIX, INPUT_FRAMES, Results

COLOURS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
]
WHITE, BLACK, GREY = (255, 255, 255), (0, 0, 0), (170, 170, 170)
PSNR_CEILING = 60.0  # dB: the PSNR axis stops here (the oracle sits near 59 dB at 8-bit frames)


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the fixed bitmap font
        return ImageFont.load_default()


def nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round tick values covering [low, high]."""
    if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
        return [low]
    raw = (high - low) / count
    magnitude = 10 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 5, 10) if m * magnitude >= raw)
    first = math.ceil(low / step) * step
    return [first + i * step for i in range(int((high - first) / step + 1e-9) + 1)]


def _label(value: float) -> str:
    if value == 0:
        return "0"
    if abs(value) >= 1000 or abs(value) < 0.01:
        return f"{value:.0e}"
    return f"{value:g}"


class Axes:
    """A rectangle of an image with data coordinates, ticks and labels."""

    def __init__(self, draw, box, x_range, y_range, title="", x_label="", y_label=""):
        self.draw = draw
        self.left, self.top, self.right, self.bottom = box
        self.x_range, self.y_range = x_range, y_range
        font, small = _font(14), _font(11)
        draw.rectangle(box, outline=BLACK)
        for x in nice_ticks(*x_range):
            px = self.px(x, y_range[0])[0]
            draw.line([(px, self.bottom), (px, self.bottom + 4)], fill=BLACK)
            draw.text((px, self.bottom + 6), _label(x), fill=BLACK, font=small, anchor="mt")
        for y in nice_ticks(*y_range):
            py = self.px(x_range[0], y)[1]
            draw.line([(self.left - 4, py), (self.left, py)], fill=BLACK)
            draw.text((self.left - 6, py), _label(y), fill=BLACK, font=small, anchor="rm")
        centre = (self.left + self.right) / 2
        draw.text((centre, self.top - 6), title, fill=BLACK, font=font, anchor="md")
        draw.text((centre, self.bottom + 22), x_label, fill=BLACK, font=small, anchor="mt")
        draw.text((self.left - 40, self.top - 6), y_label, fill=BLACK, font=small, anchor="ld")

    def px(self, x: float, y: float) -> tuple[float, float]:
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        u = self.left + (x - x0) / (x1 - x0) * (self.right - self.left)
        v = self.bottom - (y - y0) / (y1 - y0) * (self.bottom - self.top)
        return u, v

    def inside(self, x: float, y: float) -> bool:
        return self.x_range[0] <= x <= self.x_range[1] and self.y_range[0] <= y <= self.y_range[1]

    def line(self, xs: Sequence[float], ys: Sequence[float], colour, width: int = 2, dash=False):
        points = [self.px(x, y) for x, y in zip(xs, ys, strict=True) if math.isfinite(y)]
        for a, b in itertools.pairwise(points):
            if not dash:
                self.draw.line([a, b], fill=colour, width=width)
                continue
            pieces = max(1, int(math.dist(a, b) / 6))
            for i in range(0, pieces, 2):
                start, stop = i / pieces, min(i + 1, pieces) / pieces
                self.draw.line(
                    [
                        (a[0] + (b[0] - a[0]) * start, a[1] + (b[1] - a[1]) * start),
                        (a[0] + (b[0] - a[0]) * stop, a[1] + (b[1] - a[1]) * stop),
                    ],
                    fill=colour,
                    width=width,
                )

    def marker(self, x: float, y: float, colour, radius: int = 4):
        if math.isfinite(x) and math.isfinite(y) and self.inside(x, y):
            u, v = self.px(x, y)
            self.draw.ellipse([u - radius, v - radius, u + radius, v + radius], fill=colour)


def _legend(draw, names: list[str], x: int, y: int) -> None:
    font = _font(12)
    for i, name in enumerate(names):
        colour = COLOURS[i % len(COLOURS)]
        draw.rectangle([x, y + 18 * i + 3, x + 12, y + 18 * i + 13], fill=colour)
        draw.text((x + 18, y + 18 * i), name, fill=BLACK, font=font)


def _rows_with_data(results: Results) -> list[str]:
    return [row.name for row in results.rows if any(r.row == row.name for r in results.results)]


def psnr_curves(results: Results, path: Path) -> None:
    """Mean PSNR over samples and views per frame, one curve per method."""
    names = _rows_with_data(results)
    curves = {}
    for name in names:
        stack = np.stack([r.psnr for r in results.results if r.row == name and r.failure is None])
        with np.errstate(all="ignore"):
            counts = np.isfinite(stack).sum(0)
            curves[name] = np.where(counts > 0, np.nansum(stack, 0) / np.maximum(counts, 1), np.nan)
    values = np.concatenate([c[np.isfinite(c)] for c in curves.values()] + [np.array([0.0])])
    low = max(0.0, math.floor(values[values > 0].min() / 5) * 5) if (values > 0).any() else 0.0
    high = min(PSNR_CEILING, math.ceil(values.max() / 5) * 5 + 5)
    image = Image.new("RGB", (900, 520), WHITE)
    draw = ImageDraw.Draw(image)
    frames = results.num_frames
    axes = Axes(
        draw,
        (80, 50, 680, 450),
        (0, frames - 1),
        (low, high),
        f"PSNR per frame (mean over {len(results.samples)} samples and the views)",
        "frame",
        "PSNR (dB)",
    )
    split = min(INPUT_FRAMES, frames) - 0.5
    axes.line([split, split], [low, high], GREY, width=1, dash=True)
    draw.text(
        axes.px(split - 0.5, high)[0:2], "reconstruction", fill=GREY, font=_font(11), anchor="rt"
    )
    draw.text(axes.px(split + 0.5, high)[0:2], "future", fill=GREY, font=_font(11), anchor="lt")
    for i, name in enumerate(names):
        curve = np.minimum(curves[name], high)
        axes.line(list(range(frames)), curve.tolist(), COLOURS[i % len(COLOURS)])
    _legend(draw, names, 700, 60)
    image.save(path)


SCATTER_PANELS = (
    ("log_k_over_m", "log(k/m)"),
    ("log_d_over_m", "log(d/m)"),
    ("friction", "friction f"),
    ("stiffness", "stiffness k"),
    ("damping", "damping d"),
    ("mass", "mass m (kg per anchor)"),
)


def _attribute(attributes: dict[str, float], key: str) -> float:
    if key == "log_k_over_m":
        return math.log(attributes["stiffness"] / attributes["mass"])
    if key == "log_d_over_m":
        return math.log(attributes["damping"] / attributes["mass"])
    return attributes[key]


def attribute_scatter(results: Results, path: Path) -> None:
    """Predicted vs true attribute per sample, one colour per method; the diagonal is exact.

    Initial-guess rows are left out: their attributes are the trivial row's by construction.
    """
    names = [
        row.name
        for row in results.rows
        if row.has_physics
        and not row.name.endswith(INITIAL_SUFFIX)
        and any(r.row == row.name for r in results.results)
    ]
    image = Image.new("RGB", (1180, 700), WHITE)
    draw = ImageDraw.Draw(image)
    for panel, (key, title) in enumerate(SCATTER_PANELS):
        points = {
            name: [
                (_attribute(r.true_attributes, key), _attribute(r.predicted_attributes, key))
                for r in results.results
                if r.row == name and r.predicted_attributes is not None and r.failure is None
            ]
            for name in names
        }
        every = [v for pts in points.values() for p in pts for v in p]
        low, high = (min(every), max(every)) if every else (0.0, 1.0)
        pad = 0.05 * (high - low) or 0.5
        low, high = low - pad, high + pad
        column, row = panel % 3, panel // 3
        left, top = 90 + column * 300, 50 + row * 330
        axes = Axes(
            draw,
            (left, top, left + 220, top + 220),
            (low, high),
            (low, high),
            title,
            "true",
            "predicted",
        )
        axes.line([low, high], [low, high], GREY, width=1, dash=True)
        for i, name in enumerate(names):
            for x, y in points[name]:
                axes.marker(x, y, COLOURS[i % len(COLOURS)])
    _legend(draw, names, 1000, 60)
    image.save(path)


SHEET_SCALE = 4  # nearest-neighbour upscaling of each frame in the contact sheet


def sheet_columns(num_frames: int) -> list[int]:
    """Frames shown in the contact sheet: spread over both windows."""
    wanted = [0, 5, 10, 15, 19, 22, 25, 29]
    return [f for f in wanted if f < num_frames]


def contact_sheet(results: Results, path: Path) -> None:
    """Per kept sample: a row of ground-truth frames (view 0), then one row per method."""
    names = _rows_with_data(results)
    columns = sheet_columns(results.num_frames)
    samples = list(results.ground_truth_sheets)
    if not samples:
        return
    height, width = next(iter(results.ground_truth_sheets.values())).shape[1:3]
    tile_h, tile_w = height * SHEET_SCALE, width * SHEET_SCALE
    label_w, header = 180, 24
    rows = [(s, name) for s in samples for name in [None, *names]]
    image = Image.new(
        "RGB", (label_w + len(columns) * (tile_w + 2), header + len(rows) * (tile_h + 2)), WHITE
    )
    draw = ImageDraw.Draw(image)
    font = _font(12)
    for c, frame in enumerate(columns):
        x = label_w + c * (tile_w + 2) + tile_w // 2
        draw.text((x, 4), f"frame {frame}", fill=BLACK, font=font, anchor="mt")
    tiles = []
    for r, (sample, name) in enumerate(rows):
        if name is None:
            frames, label = results.ground_truth_sheets[sample], f"{sample}\nground truth"
        else:
            found = [x for x in results.results if x.row == name and x.sample == sample]
            frames = found[0].sheet if found else None
            label = name
        y = header + r * (tile_h + 2)
        draw.multiline_text((6, y + tile_h // 2), label, fill=BLACK, font=font, anchor="lm")
        tiles.append([None if frames is None or f >= len(frames) else frames[f] for f in columns])
    grid = tile_images(tiles, SHEET_SCALE, pad=(0, 2, 0, 2), fill=WHITE, blank=(60, 60, 60))
    image.paste(Image.fromarray(grid), (label_w, header))
    for r, row in enumerate(tiles):
        for c, tile in enumerate(row):
            if tile is None:
                x, y = label_w + c * (tile_w + 2), header + r * (tile_h + 2)
                draw.text(
                    (x + tile_w // 2, y + tile_h // 2), "n/a", fill=WHITE, font=font, anchor="mm"
                )
    image.save(path)
