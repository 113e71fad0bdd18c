"""A recorded interaction (:class:`Recording`) and how it is saved: ``trajectory.npz`` (the format
``simulate`` writes), ``interaction.json`` (grip positions and substeps per frame) and
``interaction.mp4``.

Frames are rendered after the recording stops, with the project's renderer
(docs/design.md#conventions: the object alone on black), so recording costs the live simulation
nothing but a copy of each frame's state.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..assets.asset import Asset
from ..assets.trajectory import write_trajectory
from ..physics import Trajectory
from ..render import Cameras
from ..render.cameras import dataset_view
from ..render.sequence import render_sequence
from ..render.video import to_uint8, write_mp4

RENDER_CHUNK = 16  # frames rendered at a time (bounds the float image memory)


@dataclass
class Recording:
    """Anchor states of a recorded interaction, one row per published frame (CPU, float32)."""

    anchors: Tensor  # [T+1, N_A, 3] metres; row 0 is the state when recording started
    velocities: Tensor  # [T+1, N_A, 3] m/s
    grip_positions: list[dict[str, list[float]]]  # per row: grip name → controller position, m
    substeps: list[int]  # per row: substeps of the frame that produced it (row 0: 0)
    frame_dt: float  # seconds between rows


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
        camera = camera or dataset_view(resolution, resolution, 0)
        device = torch.device(device)
        chunks = []
        for start in range(0, anchors.shape[0], RENDER_CHUNK):
            chunk = anchors[start : start + RENDER_CHUNK].to(device)
            means = asset.gaussian_means(chunk)
            chunks.append(to_uint8(render_sequence(asset.gaussians, means, camera, backend)))
            if progress is not None:
                progress(min(start + RENDER_CHUNK, anchors.shape[0]), anchors.shape[0])
        frames = np.concatenate(chunks)
        paths["video"] = write_mp4(folder / "interaction.mp4", frames, fps=1.0 / recording.frame_dt)
    return paths
