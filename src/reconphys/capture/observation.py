"""Everything ``predict`` reads from the user's input, in one object.

INPUT is one of:

- a video file (mp4/mov/avi/mkv/webm/gif): decoded, its frame rate from the file (or ``fps``);
- a folder of frame images (png/jpg/...): frame rate ``fps`` (default ``1 / frame_dt``).

A dataset sample (its stored frames, camera and truth) is read by
:func:`reconphys.pipeline.samples.load_sample`; :func:`stored_observation` wraps its frames.

Frames are resampled in time to ``frame_dt`` (nearest recorded frame), masked (background set
to black, as in the synthetic renders the models were trained on) and kept at their size.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from .camera import CameraSpec, default_camera, read_camera
from .masks import (
    alpha_masks,
    check_masks,
    read_background,
    read_mask_folder,
    subtract_background,
)
from .video import (
    VIDEO_SUFFIXES,
    read_frame_folder,
    read_video,
    resample_indices,
    resample_times,
)


@dataclass
class Observation:
    """The recording as the models read it."""

    frames: Tensor  # [T, H, W, 3] float32 in [0, 1], background black
    masks: Tensor  # [T, H, W] float32 in {0, 1}
    camera: CameraSpec  # at (W, H)
    frame_dt: float  # seconds between frames (after resampling)
    source: str  # what was read
    mask_source: str  # where the masks came from
    recorded_fps: float | None = None  # the file's frame rate (None: not stored / not a video)
    recorded_frames: int = 0  # frames before resampling

    @property
    def num_frames(self) -> int:
        return self.frames.shape[0]

    @property
    def size(self) -> tuple[int, int]:  # (width, height)
        return self.frames.shape[2], self.frames.shape[1]


def stored_observation(
    frames: Tensor,  # [T, H, W, 3] in [0, 1], black background (a dataset view)
    K: Tensor,  # [3, 3] pixels at (W, H)
    world_to_cam: Tensor,  # [4, 4]
    frame_dt: float,
    source: str,
) -> Observation:
    """An observation of frames already in memory (a dataset view: black backdrop, ground z = 0)."""
    height, width = frames.shape[1:3]
    camera = CameraSpec(K.double(), world_to_cam.double(), width, height, 0.0, source)
    return Observation(
        frames=frames,
        masks=subtract_background(frames),
        camera=camera,
        frame_dt=frame_dt,
        source=source,
        mask_source="background subtraction (black backdrop)",
        recorded_frames=frames.shape[0],
    )


def load_observation(
    input: str | os.PathLike,
    *,
    masks: str | os.PathLike | None = None,  # folder of mask images
    background: str | os.PathLike | None = None,  # clean plate image
    camera: str | os.PathLike | None = None,  # camera JSON (see .camera)
    fps: float | None = None,  # frame rate of a frame folder / override of the file's
    frame_dt: float = 0.03,
) -> Observation:
    """Read INPUT (see module doc) → :class:`Observation`. Raises InputError naming the input."""
    path = Path(input)
    if not path.exists():
        raise InputError("not found", source=str(path))
    if path.is_dir() and (path / "manifest.json").is_file():
        raise InputError("a dataset folder: give the sample with --sample ID", source=str(path))
    times = None
    if path.is_dir():
        raw, recorded_fps = read_frame_folder(path), None
    elif path.suffix.lower() in VIDEO_SUFFIXES:
        raw, recorded_fps, times = read_video(path)
    else:
        raise InputError(
            f"expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of frames",
            source=str(path),
        )
    if times is not None and fps is None:  # variable frame rate (GIF): the display times
        picks = resample_times(times, frame_dt)
    else:
        picks = resample_indices(raw.shape[0], fps or recorded_fps or 1.0 / frame_dt, frame_dt)
    height, width = raw.shape[1:3]
    if masks is not None:
        all_masks = read_mask_folder(masks, raw.shape[0], height, width)
        mask_source = f"mask folder {masks}"
    elif raw.shape[-1] == 4:
        all_masks = alpha_masks(raw)
        mask_source = "alpha channel"
    else:
        all_masks = None
        mask_source = ""
    recorded = raw.shape[0]
    raw = raw[picks]
    rgb = torch.from_numpy(raw[..., :3].astype(np.float32) / 255.0)
    if all_masks is None:
        plate = read_background(background, height, width) if background is not None else None
        chosen = subtract_background(rgb, plate)
        reference = f"clean plate {background}" if plate is not None else "border colour"
        mask_source = f"background subtraction ({reference})"
    else:
        chosen = all_masks[torch.from_numpy(picks)]
    check_masks(chosen, str(masks) if masks is not None else str(path))
    if camera is not None:
        spec = read_camera(camera, width, height)
    else:
        spec = default_camera(width, height)
    return Observation(
        frames=rgb * chosen[..., None],
        masks=chosen,
        camera=spec,
        frame_dt=frame_dt,
        source=str(path),
        mask_source=mask_source,
        recorded_fps=recorded_fps,
        recorded_frames=recorded,
    )
