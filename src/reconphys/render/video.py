"""Writing rendered frames: mp4 (H.264 through imageio-ffmpeg) and a PNG contact strip."""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import torch
from torch import Tensor

from ..io import atomic_file


def to_uint8(
    images: Tensor,  # [..., H, W, 3] floats in [0, 1]
) -> np.ndarray:  # [..., H, W, 3] uint8
    return (images.detach().clamp(0, 1) * 255 + 0.5).to(torch.uint8).cpu().numpy()


def write_mp4(
    path: str | os.PathLike,
    frames: np.ndarray,  # [T, H, W, 3] uint8
    fps: float,
) -> Path:
    """Write an H.264 mp4 (yuv420p, so every player opens it); odd sizes are padded by one pixel."""
    path = Path(path)
    frames = np.asarray(frames)
    pad_h, pad_w = frames.shape[1] % 2, frames.shape[2] % 2
    if pad_h or pad_w:
        frames = np.pad(frames, ((0, 0), (0, pad_h), (0, pad_w), (0, 0)))
    with atomic_file(path) as tmp:
        writer = imageio.get_writer(
            tmp,
            format="FFMPEG",
            fps=fps,
            codec="libx264",
            quality=8,
            macro_block_size=1,
            pixelformat="yuv420p",
        )
        with writer:
            for frame in frames:
                writer.append_data(frame)
    return path


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write one [H, W, 3] uint8 image as PNG, atomically."""
    path = Path(path)
    with atomic_file(path) as tmp:
        imageio.imwrite(tmp, image, format="PNG")
    return path


def write_strip(
    path: str | os.PathLike,
    frames: np.ndarray,  # [T, H, W, 3] uint8
    count: int = 6,
) -> Path:
    """A PNG of ``count`` evenly spaced frames side by side (a look without a video player)."""
    path = Path(path)
    frames = np.asarray(frames)
    picks = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    return write_image(path, np.concatenate(list(frames[picks]), axis=1))
