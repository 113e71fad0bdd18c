"""Simulating and rendering an asset: the steps behind ``reconphys simulate`` and the demo."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .assets.asset import Asset
from .errors import InputError
from .physics import Trajectory, deform_means, rollout
from .render import Cameras, dataset_views, render


def resolve_device(name: str) -> torch.device:
    """ "auto" → CUDA when available, else CPU; "cuda" without a GPU is a user error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise InputError(f"expected auto, cpu or cuda, got {name!r}", field="--device")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("CUDA was asked for but no CUDA device is available", field="--device")
    return torch.device(name)


def simulate_asset(
    asset: Asset,
    num_frames: int,
    device: torch.device,
    progress: bool = False,
) -> Trajectory:
    """Roll the asset's spring-mass system forward ``num_frames`` frames (float32)."""
    model = asset.model(device)
    state = asset.initial_state(device)
    with torch.no_grad():
        trajectory = rollout(
            model,
            state,
            num_frames,
            frame_dt=asset.physics.frame_dt,
            min_substeps=asset.physics.substeps,
            progress=progress,
        )
    if not torch.isfinite(trajectory.x).all():
        raise InputError("simulation produced NaN: the attributes are unstable")
    return trajectory


def simulate_script(
    asset: Asset,
    steps: list[dict],  # a controller script (docs/viewer.md), e.g. from viewer.script.load_script
    device: torch.device,
    num_frames: int | None = None,  # total frames; None: as many as the script simulates
):  # -> tuple[Trajectory, viewer.session.Recording]
    """Run a controller script headless from the asset's initial state; returns the trajectory
    (x, v ``[1, T+1, N_A, 3]``, frame 0 = the initial state) and the recording (grip positions).

    The same :class:`~reconphys.viewer.ViewerSession` and
    :func:`~reconphys.viewer.script.run_script` as ``reconphys view --script``, so grips act
    through the viewer's controller springs. With ``num_frames``, the object runs free after the
    script until the trajectory has ``num_frames`` frames; a script that simulates more is an
    error. Every frame the script publishes counts, including the state a ``drop`` or ``reset``
    jumps to.
    """
    from .viewer.recording import recording_trajectory
    from .viewer.script import run_script
    from .viewer.session import ViewerSession

    # As `view --script` (one simulation thread), without real-time pacing or a recording cap.
    session = ViewerSession(asset, device=device, realtime=False, max_record_frames=2**62)
    session.start_recording()
    run_script(session, steps, record=False)
    recorded = session.status().recording_frames
    if num_frames is not None:
        if recorded > num_frames:
            raise InputError(
                f"the script simulates {recorded} frames, more than the {num_frames} asked for",
                field="--frames",
            )
        session.advance(num_frames - recorded)
        recorded = session.status().recording_frames
        if recorded != num_frames:
            raise InputError("the simulation became unstable (NaN): raise the substeps")
    recording = session.stop_recording()
    return recording_trajectory(recording), recording


def gaussian_centres(
    asset: Asset,
    anchors: Tensor,  # [T, N_A, 3] anchor positions per frame, metres
) -> Tensor:  # [T, N, 3]
    """Gaussian centres following the anchors through the asset's binding."""
    device = anchors.device
    return deform_means(
        asset.gaussians.means.to(device),
        asset.x0.to(device),
        anchors,
        asset.binding_index.to(device),
        asset.binding_weight.to(device),
    )


def render_frames(
    asset: Asset,
    anchors: Tensor,  # [T, N_A, 3] anchor positions per frame, metres
    cameras: Cameras,  # one camera (C = 1), no batch dims
    backend: str = "auto",
    progress: bool = False,
) -> Tensor:  # [T, H, W, 3] colour in [0, 1], black background
    """Render the deformed Gaussians frame by frame (bounded memory)."""
    device = anchors.device
    gaussians = asset.gaussians.to(device)
    cameras = cameras.to(device)
    frames = range(anchors.shape[0])
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc="render", unit="frame")
    images = []
    with torch.no_grad():
        for t in frames:
            means = gaussian_centres(asset, anchors[t])
            images.append(render(gaussians.with_means(means), cameras, backend).rgb[0])
    return torch.stack(images)


def default_view(width: int, height: int, view: int = 0) -> Cameras:
    """Dataset view ``view`` (0–3: azimuth 0°, 90°, 180°, 270°) as a single camera."""
    if not 0 <= view < 4:
        raise InputError(f"expected 0, 1, 2 or 3, got {view}", field="--view")
    cameras = dataset_views(width, height)
    return Cameras(cameras.K[view : view + 1], cameras.world_to_cam[view : view + 1], width, height)


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
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".trajectory.", suffix=".npz", dir=path.parent)
    os.close(fd)
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
