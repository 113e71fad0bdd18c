"""Decoding a recording: a video file (mp4/mov/avi/webm/gif through imageio's ffmpeg and pillow
plugins) or a folder of frames, and resampling it in time to the simulator's ``frame_dt``."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".gif")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def _as_rgb_or_rgba(frame: np.ndarray, source: str) -> np.ndarray:
    """[H, W] / [H, W, 1|3|4] uint8 or uint16 → [H, W, 3|4] uint8."""
    frame = np.asarray(frame)
    if frame.dtype == np.uint16:
        frame = (frame >> 8).astype(np.uint8)
    if frame.dtype == np.bool_:
        frame = frame.astype(np.uint8) * 255
    if frame.dtype != np.uint8:
        raise InputError(f"expected 8- or 16-bit images, got {frame.dtype}", source=source)
    if frame.ndim == 2:
        frame = frame[..., None]
    if frame.ndim != 3 or frame.shape[-1] not in (1, 3, 4):
        raise InputError(f"expected [H, W, 1|3|4] images, got {list(frame.shape)}", source=source)
    if frame.shape[-1] == 1:
        frame = np.repeat(frame, 3, axis=-1)
    return frame


def _same_channels(frames: list[np.ndarray]) -> list[np.ndarray]:
    """RGB and RGBA frames mixed (GIF decoders give the first frame without alpha) → all RGBA,
    or all RGB when no frame is transparent anywhere."""
    if all(f.shape[-1] == 3 for f in frames):
        return frames
    if all(f.shape[-1] == 3 or bool((f[..., 3] == 255).all()) for f in frames):
        return [f[..., :3] for f in frames]
    opaque = np.uint8(255)
    return [f if f.shape[-1] == 4 else np.dstack([f, np.full(f.shape[:2], opaque)]) for f in frames]


def _read_gif(path: Path) -> tuple[list[np.ndarray], np.ndarray]:
    """GIF frames (RGBA) and the time each one appears, seconds [T + 1] (the last entry is when
    the clip ends): GIF encoders merge repeated frames into one longer frame, so the frame rate
    is not constant."""
    from PIL import Image, ImageSequence

    frames, durations = [], []
    with Image.open(path) as image:
        for frame in ImageSequence.Iterator(image):
            frames.append(np.asarray(frame.convert("RGBA")))
            durations.append(float(frame.info.get("duration") or 0.0) / 1000.0)
    if frames and not all(d > 0 for d in durations):
        durations = [0.1] * len(frames)  # browsers' default for a missing delay
    return frames, np.concatenate([[0.0], np.cumsum(durations)])


def read_video(path: str | os.PathLike) -> tuple[np.ndarray, float | None, np.ndarray | None]:
    """All frames of a video file → ([T, H, W, 3|4] uint8, frames per second or None, display
    times [T + 1] seconds for variable-rate files (GIF) or None).

    GIF keeps its alpha channel when it has transparency. Raises InputError (one line naming the
    file) for a missing or unreadable file and for a video without frames.
    """
    import imageio.v2 as imageio

    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise InputError("video file not found", source=source)
    fps, times = None, None
    frames = []
    try:
        if path.suffix.lower() == ".gif":
            raw, times = _read_gif(path)
            frames = [_as_rgb_or_rgba(frame, source) for frame in raw]
        else:
            with imageio.get_reader(path, format="FFMPEG") as reader:
                fps = reader.get_meta_data().get("fps")
                for frame in reader:
                    frames.append(_as_rgb_or_rgba(frame, source))
    except InputError:
        raise
    except Exception as e:  # decoders raise many types (OSError, RuntimeError, IndexError, ...)
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"cannot decode the video ({message})", source=source) from None
    if not frames:
        raise InputError("the video has no frames", source=source)
    frames = _same_channels(frames)
    if len({f.shape for f in frames}) != 1:
        raise InputError("frames of different sizes", source=source)
    fps = float(fps) if fps and np.isfinite(fps) and fps > 0 else None
    return np.stack(frames), fps, times


def resample_times(
    times: np.ndarray, frame_dt: float, start: float = 0.0, end: float | None = None
) -> np.ndarray:
    """Indices of the frames on screen at start, start + frame_dt, ... before the clip ends (or
    ``end``, seconds), for frames that appear at ``times[:-1]`` and a clip that ends at
    ``times[-1]`` (seconds)."""
    stop = float(times[-1]) if end is None else min(end, float(times[-1]))
    _check_span(start, stop - 1e-9)  # a frame must be on screen at the start
    count = int(np.floor((stop - start - 1e-9) / frame_dt)) + 1
    targets = start + np.arange(count) * frame_dt
    return np.searchsorted(times[:-1], targets + 1e-9, side="right") - 1


def _check_span(start: float, stop: float) -> None:
    if start > stop:
        raise InputError(
            f"{start:g} s is after the recording's end ({stop:.2f} s)", field="--start"
        )


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files of a folder in natural order (frame_2 before frame_10)."""
    import re

    folder = Path(folder)
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]

    def key(p: Path):
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted(files, key=key)


def read_image(path: Path) -> np.ndarray:
    """One image → [H, W, C] uint8 (C as stored: 1, 3 or 4; greyscale kept as [H, W, 1])."""
    import imageio.v2 as imageio

    try:
        image = np.asarray(imageio.imread(path))
    except Exception as e:
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"cannot read the image ({message})", source=str(path)) from None
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype == np.bool_:
        image = image.astype(np.uint8) * 255
    if image.dtype != np.uint8:
        raise InputError(f"expected 8- or 16-bit images, got {image.dtype}", source=str(path))
    return image if image.ndim == 3 else image[..., None]


def read_frame_folder(folder: str | os.PathLike) -> np.ndarray:
    """A folder of frame images (sorted naturally) → [T, H, W, 3|4] uint8."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("frame folder not found", source=str(folder))
    files = list_images(folder)
    if not files:
        kinds = "/".join(IMAGE_SUFFIXES)
        raise InputError(f"no frames ({kinds}) in the folder", source=str(folder))
    frames = _same_channels([_as_rgb_or_rgba(read_image(p), str(p)) for p in files])
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise InputError(f"frames of different sizes {sorted(shapes)}", source=str(folder))
    return np.stack(frames)


def resample_indices(
    num_frames: int, fps: float, frame_dt: float, start: float = 0.0, end: float | None = None
) -> np.ndarray:
    """Indices of the recorded frames nearest to the times start, start + frame_dt, ... (seconds
    into the recording, as long as they lie inside it and before ``end``); identity when
    ``fps == 1 / frame_dt`` and ``start == 0``."""
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"must be a positive frame rate, got {fps}", field="--fps")
    duration = (num_frames - 1) / fps
    stop = duration if end is None else min(end, duration)
    _check_span(start, stop + 1e-9)
    count = int(np.floor((stop - start) / frame_dt + 1e-6)) + 1
    times = start + np.arange(count) * frame_dt
    return np.clip(np.round(times * fps).astype(np.int64), 0, num_frames - 1)
