"""Saving a recorded interaction: ``trajectory.npz`` (the format ``simulate`` writes),
``interaction.json`` (grip positions and substeps per frame) and ``interaction.mp4``.

Frames are rendered after the recording stops, with the project's renderer (DESIGN §3: the object
alone on black), so recording costs the live simulation nothing but a copy of each frame's state.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import torch

from ..assets.asset import Asset
from ..physics import Trajectory
from ..render import Cameras
from ..render.video import to_uint8, write_mp4
from ..simulate import default_view, render_frames, write_trajectory
from .session import Recording

RENDER_CHUNK = 16  # frames rendered at a time (bounds the float image memory)


def recording_trajectory(recording: Recording) -> Trajectory:
    """The recording as a batch-of-one :class:`~reconphys.physics.Trajectory` (x, v
    ``[1, T+1, N_A, 3]``; ``substeps`` the most any frame used)."""
    return Trajectory(
        x=recording.anchors[None],
        v=recording.velocities[None],
        substeps=max(recording.substeps),
        frame_dt=recording.frame_dt,
    )


def write_interaction(path: str | os.PathLike, recording: Recording) -> Path:
    """``interaction.json``: frames, frame_dt, substeps per frame and the grip positions
    (metres) of every frame."""
    info = {
        "frames": recording.anchors.shape[0] - 1,
        "frame_dt": recording.frame_dt,
        "substeps_per_frame": recording.substeps,
        "grip_positions_m": recording.grip_positions,
    }
    path = Path(path)
    path.write_text(json.dumps(info) + "\n")
    return path


def write_recording(
    asset: Asset,
    recording: Recording,
    folder: str | os.PathLike,
    camera: Cameras | None = None,  # one camera (C = 1); default: dataset view 0
    resolution: int = 256,  # pixels, for the default camera
    backend: str = "auto",
    device: torch.device | str = "cpu",
    render_video: bool = True,
    progress=None,  # called with (frames rendered, total) while rendering
) -> dict[str, Path]:
    """Write the recording into ``folder``; returns the written paths by kind."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    anchors = recording.anchors  # [T+1, N_A, 3]
    trajectory = recording_trajectory(recording)
    paths = {"trajectory": write_trajectory(folder / "trajectory.npz", trajectory)}
    paths["interaction"] = write_interaction(folder / "interaction.json", recording)
    if render_video:
        camera = camera or default_view(resolution, resolution, 0)
        device = torch.device(device)
        chunks = []
        for start in range(0, anchors.shape[0], RENDER_CHUNK):
            chunk = anchors[start : start + RENDER_CHUNK].to(device)
            chunks.append(to_uint8(render_frames(asset, chunk, camera, backend)))
            if progress is not None:
                progress(min(start + RENDER_CHUNK, anchors.shape[0]), anchors.shape[0])
        frames = np.concatenate(chunks)
        paths["video"] = write_mp4(folder / "interaction.mp4", frames, fps=1.0 / recording.frame_dt)
    return paths
