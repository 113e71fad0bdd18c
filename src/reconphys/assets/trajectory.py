"""``trajectory.npz``: a simulated clip of an asset, written by ``reconphys simulate``, the demo
and the viewer's recordings (docs/usage.md).

Arrays: ``anchors`` [T+1, N_A, 3] float32 metres (frame 0 = initial state), ``velocities``
[T+1, N_A, 3] float32 m/s, ``substeps_used`` int64, ``frame_dt`` float64 seconds, and optionally
``gaussian_means`` [T+1, N, 3] float32 metres.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from torch import Tensor

from ..io import atomic_file
from ..physics import Trajectory


def write_trajectory(
    path: str | os.PathLike,
    trajectory: Trajectory,
    gaussian_means: Tensor | None = None,  # [T+1, N, 3]
) -> Path:
    """``trajectory.npz``: anchors [T+1, N_A, 3] (frame 0 = initial state), velocities,
    substeps_used, frame_dt, and gaussian_means [T+1, N, 3] when given. Written atomically."""
    path = Path(path)
    arrays = {
        "anchors": trajectory.x[0].detach().cpu().float().numpy(),
        "velocities": trajectory.v[0].detach().cpu().float().numpy(),
        "substeps_used": np.int64(trajectory.substeps),
        "frame_dt": np.float64(trajectory.frame_dt),
    }
    if gaussian_means is not None:
        arrays["gaussian_means"] = gaussian_means.detach().cpu().float().numpy()
    with atomic_file(path) as tmp:
        np.savez(tmp, **arrays)
    return path
