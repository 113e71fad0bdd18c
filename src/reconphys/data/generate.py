"""One sample in memory: draw its randomness, simulate 30 frames, render the 4 dataset views.

Shared by ``make-data`` (which writes the result) and the on-the-fly dataset (which returns it), so
both give the same sample for the same settings and seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..assets.asset import Asset
from ..render import Cameras, dataset_views, render
from ..render.video import to_uint8
from .objects import CanonicalObject, Placement, place, sample_asset
from .sampling import SampleSpec, contact_frame, draw_sample
from .settings import DataSettings

AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
FRAMES_PER_RENDER_CALL = 8  # bounds renderer memory at large resolutions


@dataclass
class GeneratedSample:
    spec: SampleSpec
    placement: Placement
    asset: Asset  # the sample's simulation-ready asset (initial state + attributes)
    anchors: np.ndarray  # [T, N_A, 3] float32, frame 0 = initial state, metres
    velocities: np.ndarray  # [T, N_A, 3] float32, m/s
    substeps: int  # substeps per frame used
    frames: np.ndarray  # [V, T, H, W, 3] uint8, black background
    cameras: Cameras  # V = 4 cameras, no batch dims
    contact_frame: int  # first frame touching the ground (−1: never)


def dataset_cameras(settings: DataSettings, device=None) -> Cameras:
    """The four views of docs/design.md#conventions at the dataset's resolution."""
    return dataset_views(
        settings.resolution,
        settings.resolution,
        radius=settings.camera_radius,
        fov_deg=settings.camera_fov_deg,
        elevation_deg=settings.camera_elevation_deg,
        target=settings.camera_target,
        azimuths_deg=AZIMUTHS_DEG,
        device=device,
    )


def render_views(
    asset: Asset,
    anchors: torch.Tensor,  # [T, N_A, 3] metres
    cameras: Cameras,  # C cameras, no batch dims
) -> torch.Tensor:  # [C, T, H, W, 3] in [0, 1]
    """Render every frame from every camera (renderer "auto": gsplat on CUDA, else torch)."""
    device = anchors.device
    gaussians = asset.gaussians.to(device)
    cameras = cameras.to(device)
    chunks = []
    with torch.no_grad():
        for start in range(0, anchors.shape[0], FRAMES_PER_RENDER_CALL):
            part = anchors[start : start + FRAMES_PER_RENDER_CALL]
            means = asset.gaussian_means(part)  # [t, N, 3]
            batch = gaussians.map(lambda t, n=part.shape[0]: t.expand(n, *t.shape))
            chunks.append(render(batch.with_means(means), cameras).rgb)  # [t, C, H, W, 3]
    return torch.cat(chunks).transpose(0, 1)


def generate_sample(
    obj: CanonicalObject,
    sample_index: int,
    settings: DataSettings,
    device: torch.device | str = "cpu",
) -> GeneratedSample:
    spec = draw_sample(settings, obj.id, sample_index)
    placement = place(obj, spec)
    asset = sample_asset(obj, spec, placement, settings)
    trajectory = asset.simulate(settings.num_frames - 1, torch.device(device))
    anchors = trajectory.x[0]  # [T, N_A, 3]
    cameras = dataset_cameras(settings)
    frames = to_uint8(render_views(asset, anchors, cameras))
    anchors_np = anchors.cpu().float().numpy()
    return GeneratedSample(
        spec=spec,
        placement=placement,
        asset=asset,
        anchors=anchors_np,
        velocities=trajectory.v[0].cpu().float().numpy(),
        substeps=trajectory.substeps,
        frames=frames,
        cameras=cameras,
        contact_frame=contact_frame(anchors_np, asset.physics.ground_height),
    )
