"""The object's window in a recording: crop the frames (and their camera) to the box around the
object's masks and area-average them down to a working size. Used wherever renders are compared
with a recording (the physics search, gradient refinement): background pixels cost rendering and
tell nothing."""

from __future__ import annotations

import math

import torch.nn.functional as F
from torch import Tensor

from .camera import CameraSpec

CROP_MARGIN = 0.25  # the window around the object: its masks' box grown by this share a side


def pixel_bounds(mask: Tensor) -> tuple[int, int, int, int] | None:
    """(top, bottom, left, right) of a [H, W] bool mask's pixels, bottom and right exclusive;
    None when it has none."""
    rows, cols = mask.any(1).nonzero(), mask.any(0).nonzero()
    if len(rows) == 0:
        return None
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def object_window(masks: Tensor, margin: float = CROP_MARGIN) -> tuple[int, int, int, int] | None:
    """(left, top, width, height) in pixels of the box around every frame's mask [T, H, W] grown
    by ``margin`` of its size on each side (at least 2 px), inside the image; None when no mask
    has a pixel."""
    seen = masks.detach().reshape(-1, *masks.shape[-2:]).amax(0) > 0.5  # [H, W]
    bounds = pixel_bounds(seen)
    if bounds is None:
        return None
    height, width = seen.shape
    top, bottom, left, right = bounds
    grow_y = max(2, math.ceil(margin * (bottom - top)))
    grow_x = max(2, math.ceil(margin * (right - left)))
    top, bottom = max(0, top - grow_y), min(height, bottom + grow_y)
    left, right = max(0, left - grow_x), min(width, right + grow_x)
    return left, top, right - left, bottom - top


def comparison_view(
    frames: Tensor,  # [T, H, W, 3]
    camera: CameraSpec,
    resolution: int,
    window: tuple[int, int, int, int] | None = None,  # (left, top, width, height) pixels
) -> tuple[Tensor, CameraSpec]:
    """The frames the search compares with, and their camera: cropped to ``window`` (the object's
    region: background pixels cost rendering and tell nothing), then area-averaged down so the
    longest side is at most ``resolution`` (never up)."""
    if window is not None:
        left, top, width, height = window
        frames = frames[:, top : top + height, left : left + width]
        camera = camera.cropped(left, top, width, height)
    height, width = frames.shape[1:3]
    scale = min(1.0, resolution / max(height, width))
    size = (max(8, round(height * scale)), max(8, round(width * scale)))
    if size != (height, width):
        frames = F.interpolate(frames.permute(0, 3, 1, 2), size=size, mode="area")
        frames = frames.permute(0, 2, 3, 1)
    return frames, camera.resized(size[1], size[0])
