"""The preview: the observed frames beside the simulated asset, from the recording's camera.

Left: the masked recording (black after its last frame). Right: the asset simulated from its
initial state and rendered into the same camera, continuing past the recording. Panels are
enlarged (nearest neighbour) to at least ``PREVIEW_MIN_SIZE`` pixels so small inputs stay visible.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.asset import Asset
from ..capture import Observation
from .settings import PREVIEW_MIN_SIZE

SEPARATOR = 2  # pixels of grey between the panels
OUTLINE = (0.2, 1.0, 0.2)  # the masks' outline over the recording: what was taken for the object


def outlined(
    frames: Tensor,  # [T, H, W, 3] the recording as it was filmed (background included)
    masks: Tensor,  # [T, H, W] in {0, 1}
) -> Tensor:  # [T, H, W, 3]
    """The recording with each mask's outline (its pixels next to a background pixel) drawn in
    green: the preview shows what ``predict`` took for the object, so a wrong mask shows."""
    inside = masks[:, None].float()
    eroded = 1.0 - F.max_pool2d(1.0 - inside, 3, stride=1, padding=1)
    edge = ((inside - eroded)[:, 0] > 0.5)[..., None]
    return torch.where(edge, torch.tensor(OUTLINE, dtype=frames.dtype), frames)


def _enlarge(images: Tensor, factor: int) -> Tensor:  # [T, H, W, 3] → [T, fH, fW, 3]
    if factor == 1:
        return images
    return F.interpolate(images.permute(0, 3, 1, 2), scale_factor=factor, mode="nearest").permute(
        0, 2, 3, 1
    )


def simulate_and_render(
    asset: Asset, observation: Observation, num_frames: int, device="cpu", backend="auto"
) -> Tensor:  # [num_frames, H, W, 3] frames 0..num_frames−1 in the recording's camera
    from ..render.sequence import render_sequence

    trajectory = asset.simulate(num_frames - 1, torch.device(device))
    means = asset.gaussian_means(trajectory.x[0])
    return render_sequence(asset.gaussians, means, observation.camera.cameras(), backend).cpu()


def contact_sheet(
    observed: Tensor,  # [T_obs, H, W, 3]
    simulated: Tensor,  # [T, H, W, 3]
    count: int = 6,
) -> np.ndarray:  # [2H' + SEPARATOR, count·(W' + SEPARATOR), 3] uint8
    """``count`` evenly spaced frames: the recording on top (black past its end), the simulated
    asset below, so each column compares one instant."""
    from ..render.video import tile_images, to_uint8

    num_frames, height, width = simulated.shape[:3]
    picks = np.linspace(0, num_frames - 1, min(count, num_frames)).round().astype(int)
    factor = max(1, math.ceil(PREVIEW_MIN_SIZE / 2 / max(height, width)))
    # Enlarged by torch's nearest interpolation (as side_by_side), not tile_images' repetition:
    # the two differ for some factors (41, 47, …), and the preview stays as it was.
    shown = [t for t in picks if t < observed.shape[0]]  # a prefix of the columns
    top = list(to_uint8(_enlarge(observed[shown], factor))) if shown else []
    bottom = list(to_uint8(_enlarge(simulated[picks], factor)))
    rows = [top + [None] * (len(picks) - len(top)), bottom]
    grey = 128  # to_uint8(0.5)
    sheet = tile_images(rows, pad=(0, SEPARATOR, 0, SEPARATOR), fill=grey)
    return sheet[:-SEPARATOR]  # no bar under the last row


def side_by_side(
    observed: Tensor,  # [T_obs, H, W, 3]
    simulated: Tensor,  # [T, H, W, 3], T ≥ T_obs
) -> np.ndarray:  # [T, H', 2W' + SEPARATOR, 3] uint8
    from ..render.video import to_uint8

    num_frames, height, width = simulated.shape[:3]
    left = torch.zeros_like(simulated)
    shown = min(observed.shape[0], num_frames)
    left[:shown] = observed[:shown]
    factor = max(1, math.ceil(PREVIEW_MIN_SIZE / max(height, width)))
    left, right = _enlarge(left, factor), _enlarge(simulated, factor)
    bar = torch.full((num_frames, left.shape[1], SEPARATOR, 3), 0.5)
    return to_uint8(torch.cat([left, bar, right], dim=2))


def with_caption(image: np.ndarray, lines: list[str]) -> np.ndarray:  # [H, W, 3] → [H + h, W, 3]
    """The image with ``lines`` of white text on a black strip below it (PIL's built-in font)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    line_height = 12
    strip = Image.new("RGB", (image.shape[1], 4 + line_height * len(lines)), (0, 0, 0))
    draw = ImageDraw.Draw(strip)
    for i, line in enumerate(lines):
        draw.text((4, 2 + line_height * i), line, fill=(255, 255, 255), font=font)
    return np.concatenate([image, np.asarray(strip, dtype=np.uint8)], axis=0)


def interval_lines(observables: dict[str, float], intervals: dict | None) -> list[str]:
    """The preview's caption: each observable with its 10–90 % interval (or why there is none)."""
    if not intervals:
        return ["feed-forward only (--no-refine), not an ensemble: no intervals"]
    names = {"log_k_over_m": "log k/m", "log_d_over_m": "log d/m", "friction": "friction"}
    return [
        f"{names[key]} {observables[key]:.2f}  [{low:.2f}, {high:.2f}] (10-90 %)"
        for key, (low, high) in intervals.items()
    ]
