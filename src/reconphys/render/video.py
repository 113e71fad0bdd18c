"""Writing rendered frames: mp4 (H.264 through imageio-ffmpeg), PNG images, and the image grid
(``tile_images``) that every contact sheet and strip is drawn with."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import torch
from torch import Tensor

from ..io import atomic_file

# QuickTime metadata key an iPhone writes into its videos: the lens's 35 mm-equivalent focal
# length, mm (capture/lens.py reads the field of view from it)
FOCAL_35MM_KEY = "com.apple.quicktime.camera.focal_length.35mm_equivalent"


def to_uint8(
    images: Tensor,  # [..., H, W, 3] floats in [0, 1]
) -> np.ndarray:  # [..., H, W, 3] uint8
    return (images.detach().clamp(0, 1) * 255 + 0.5).to(torch.uint8).cpu().numpy()


def write_mp4(
    path: str | os.PathLike,
    frames: np.ndarray,  # [T, H, W, 3] uint8
    fps: float,
    quality: float = 8.0,
) -> Path:
    """Write an H.264 mp4 (yuv420p, so every player opens it); odd sizes are padded by one pixel.
    ``quality`` is imageio-ffmpeg's 0–10 (10: best; libx264's CRF = 51·(1 − quality/10))."""
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
            quality=quality,
            macro_block_size=1,
            pixelformat="yuv420p",
        )
        with writer:
            for frame in frames:
                writer.append_data(frame)
    return path


def run_ffmpeg(arguments: list[str], timeout: float = 120.0):
    """imageio-ffmpeg's ffmpeg binary with ``arguments``, its output captured as text →
    ``subprocess.CompletedProcess`` (bytes that are not UTF-8 — a tag or a file name in another
    encoding — replaced, not raised on)."""
    import subprocess

    import imageio_ffmpeg

    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", *arguments]
    return subprocess.run(
        command, capture_output=True, text=True, errors="replace", timeout=timeout
    )


def copy_with_metadata(
    source: str | os.PathLike, target: str | os.PathLike, metadata: dict[str, str]
) -> Path:
    """Copy a video file (the streams as they are, no re-encoding) with ``metadata`` added as
    QuickTime keys (what a phone writes, e.g. :data:`FOCAL_35MM_KEY`), atomically."""
    target = Path(target)
    tags = [arg for key, value in metadata.items() for arg in ("-metadata", f"{key}={value}")]
    with atomic_file(target) as tmp:
        command = ["-v", "error", "-y", "-i", str(source), "-c", "copy"]
        run = run_ffmpeg([*command, "-movflags", "use_metadata_tags", *tags, str(tmp)])
        if run.returncode != 0:
            raise RuntimeError(f"ffmpeg could not copy {source}: {run.stderr.strip()[:200]}")
    return target


def compress_video(
    frames: np.ndarray,  # [T, H, W, 3] uint8
    fps: float,
    quality: float,
) -> tuple[np.ndarray, bytes]:  # decoded [T, H, W, 3] uint8, the mp4 file's bytes
    """Encode as :func:`write_mp4` does and decode again: what a camera's compressed video gives."""
    height, width = frames.shape[1:3]
    with tempfile.TemporaryDirectory() as folder:
        path = write_mp4(Path(folder) / "video.mp4", frames, fps, quality)
        data = path.read_bytes()
        reader = imageio.get_reader(path, format="FFMPEG")
        with reader:
            decoded = np.stack([np.asarray(f)[:height, :width, :3] for f in reader])
    if decoded.shape != frames.shape:
        raise RuntimeError(f"decoded {decoded.shape} frames for {frames.shape} encoded")
    return decoded, data


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write one [H, W, 3] uint8 image as PNG, atomically."""
    path = Path(path)
    with atomic_file(path) as tmp:
        imageio.imwrite(tmp, image, format="PNG")
    return path


def tile_images(
    rows: Sequence[Sequence[np.ndarray | None]],  # rows × columns of [H, W, 3] uint8 tiles
    scale: int = 1,
    pad: int | tuple[int, int, int, int] = 0,
    fill: int | tuple[int, int, int] = 0,
    blank: int | tuple[int, int, int] = 0,
) -> np.ndarray:  # [rows·(scale·H + pad_h), columns·(scale·W + pad_w), 3] uint8
    """A grid of equally sized images, each enlarged ``scale`` times (pixel repetition) and padded
    by ``pad`` pixels (all sides, or ``(top, bottom, left, right)``) in the colour ``fill``; a
    ``None`` tile is a rectangle of the colour ``blank``. Colours are a grey level or RGB."""
    top, bottom, left, right = (pad,) * 4 if isinstance(pad, int) else pad
    height, width = next(t.shape[:2] for row in rows for t in row if t is not None)
    height, width = height * scale, width * scale
    cell_h, cell_w = top + height + bottom, left + width + right
    columns = max(len(row) for row in rows)
    grid = np.empty((len(rows) * cell_h, columns * cell_w, 3), np.uint8)
    grid[:] = fill
    for r, row in enumerate(rows):
        for c, tile in enumerate(row):
            y, x = r * cell_h + top, c * cell_w + left
            if tile is None:
                grid[y : y + height, x : x + width] = blank
            else:
                grid[y : y + height, x : x + width] = (
                    np.asarray(tile).repeat(scale, 0).repeat(scale, 1)
                )
    return grid


def write_strip(
    path: str | os.PathLike,
    frames: np.ndarray,  # [T, H, W, 3] uint8
    count: int = 6,
) -> Path:
    """A PNG of ``count`` evenly spaced frames side by side (a look without a video player)."""
    path = Path(path)
    frames = np.asarray(frames)
    picks = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    return write_image(path, tile_images([list(frames[picks])]))
