"""One sample in memory: draw its randomness, simulate 30 frames, render the 4 dataset views
(the plain look, or the realistic one of data/scene.py).

Shared by ``make-data`` (which writes the result) and the on-the-fly dataset (which returns it), so
both give the same sample for the same settings and seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..assets.asset import Asset
from ..physics import GRAVITY
from ..render import Cameras, dataset_views, render
from ..render.hand import arm_direction, composite_hand, hand_gaussians, object_grip
from ..render.scene import (
    SceneLook,
    add_sensor_noise,
    composite_in_scene,
    scene_background,
    shade_gaussians,
)
from ..render.video import compress_video, to_uint8
from .objects import CanonicalObject, Placement, place, sample_asset, scale_object
from .sampling import SampleSpec, contact_frame, draw_sample
from .scene import SceneSpec, draw_scene, framed_cameras, printed_object
from .settings import DataSettings

AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)
FRAMES_PER_RENDER_CALL = 8  # bounds renderer memory at large resolutions
# Renders averaged per frame while the shutter is open (settings.exposure_range_s): the blur of
# a 128-px drop at landing speed spans ~4–8 px at 1/60–1/30 s, so ~1 px between renders
SHUTTER_SAMPLES = 8
# A rolling shutter (settings.readout_range_s) reads the rows in this many bands, each at its
# own time (≤ 2 ms apart at 1/30 s), each band's exposure in this many renders
READOUT_BANDS = 16
READOUT_SHUTTER_SAMPLES = 4


@dataclass
class GeneratedSample:
    spec: SampleSpec
    placement: Placement
    asset: Asset  # the sample's simulation-ready asset (initial state + attributes)
    anchors: np.ndarray  # [T, N_A, 3] float32, frame 0 = initial state, metres
    velocities: np.ndarray  # [T, N_A, 3] float32, m/s
    substeps: int  # substeps per frame used
    frames: np.ndarray  # [V, T, H, W, 3] uint8: black background, or the realistic scene
    cameras: Cameras  # V = 4 cameras, no batch dims
    contact_frame: int  # first frame touching the ground (−1: never)
    # the realistic look only (None in the plain one):
    scene: SceneSpec | None = None
    masks: np.ndarray | None = None  # [V, T, H, W] bool, the object's true masks (alpha > 0.5)
    videos: list[bytes] | None = None  # the V encoded mp4 files whose decoded frames are `frames`


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
    return render_object_views(asset, anchors, cameras)[0]


def render_object_views(
    asset: Asset,
    anchors: torch.Tensor,  # [T, N_A, 3] metres
    cameras: Cameras,  # C cameras, no batch dims
    look: SceneLook | None = None,  # shade the colours by its light (the realistic look)
) -> tuple[torch.Tensor, torch.Tensor]:  # rgb [C, T, H, W, 3] on black, alpha [C, T, H, W]
    """:func:`render_views` with the alpha, the colours shaded by ``look``'s light if given."""
    device = anchors.device
    gaussians = asset.gaussians.to(device)
    cameras = cameras.to(device)
    rgb, alpha = [], []
    with torch.no_grad():
        for start in range(0, anchors.shape[0], FRAMES_PER_RENDER_CALL):
            part = anchors[start : start + FRAMES_PER_RENDER_CALL]
            means = asset.gaussian_means(part)  # [t, N, 3]
            batch = gaussians.map(lambda t, n=part.shape[0]: t.expand(n, *t.shape))
            batch = batch.with_means(means)
            if look is not None:
                batch = shade_gaussians(batch, look)
            out = render(batch, cameras)
            rgb.append(out.rgb)  # [t, C, H, W, 3]
            alpha.append(out.alpha)
    return torch.cat(rgb).transpose(0, 1), torch.cat(alpha).transpose(0, 1)


def carried_anchors(
    anchors: torch.Tensor,  # [T, N_A, 3] metres, at the frames' times
    velocities: torch.Tensor,  # [T, N_A, 3] m/s
    offsets: list[float],  # S times, seconds from each frame's time, each within ± frame_dt
    frame_dt: float,  # seconds between frames
    ground_height: float = 0.0,  # metres
) -> torch.Tensor:  # [S, T, N_A, 3] metres
    """Where the anchors are ``offset`` seconds from each frame's time: carried from the last
    frame at or before that time by its velocity under gravity (exact in free fall; within the
    contact's few mm during the frame at most between the two), never below the ground. Before
    frame 0 the object is held where it is let go."""
    if any(abs(offset) > frame_dt for offset in offsets):
        raise ValueError(f"offsets: expected within ± frame_dt = {frame_dt} s, got {offsets}")
    gravity = torch.tensor(GRAVITY, dtype=anchors.dtype, device=anchors.device)
    out = []
    for offset in offsets:
        if offset >= 0:
            start, velocity, after = anchors, velocities, offset
        else:  # from the frame before (frame 0: held still until the release)
            start = torch.cat([anchors[:1], anchors[:-1]])
            velocity = torch.cat([torch.zeros_like(velocities[:1]), velocities[:-1]])
            after = torch.full((anchors.shape[0], 1, 1), frame_dt + offset, dtype=anchors.dtype)
            after[0] = 0.0
        moved = start + velocity * after + 0.5 * gravity * after**2
        floor = torch.minimum(start[..., 2], torch.full_like(start[..., 2], ground_height))
        moved[..., 2] = torch.maximum(moved[..., 2], floor)
        out.append(moved)
    return torch.stack(out)


def shutter_anchors(
    anchors: torch.Tensor,  # [T, N_A, 3] metres, at the frames' times
    velocities: torch.Tensor,  # [T, N_A, 3] m/s
    exposure: float,  # seconds the shutter is open, centred on each frame's time (+ shift)
    frame_dt: float,  # seconds between frames
    ground_height: float = 0.0,  # metres
    samples: int = SHUTTER_SAMPLES,
    shift: float = 0.0,  # seconds: the exposure's centre from the frame's time (a row's readout)
) -> torch.Tensor:  # [S, T, N_A, 3] metres
    """Where the anchors are at ``samples`` times spread evenly over each frame's exposure (the
    midpoints of equal parts of [t + shift − e/2, t + shift + e/2]; :func:`carried_anchors`)."""
    if not 0 < exposure <= frame_dt:
        raise ValueError(f"exposure: expected (0, frame_dt = {frame_dt}] s, got {exposure}")
    parts = (torch.arange(samples, dtype=torch.float64) + 0.5) / samples * exposure
    offsets = (shift + parts - exposure / 2).tolist()
    return carried_anchors(anchors, velocities, offsets, frame_dt, ground_height)


def _render_moments(
    asset: Asset, moments: torch.Tensor, cameras: Cameras, look: SceneLook
) -> tuple[torch.Tensor, torch.Tensor]:  # rgb [C, T, H, W, 3] on black, alpha [C, T, H, W]
    """The object rendered at each of S moments [S, T, N_A, 3] and averaged: the colour on black
    is premultiplied, so colour and coverage both average as they are."""
    rgb = alpha = 0.0
    for at in moments:
        rgb_at, alpha_at = render_object_views(asset, at, cameras, look)
        rgb, alpha = rgb + rgb_at / len(moments), alpha + alpha_at / len(moments)
    return rgb, alpha


def render_realistic(
    asset: Asset,
    anchors: torch.Tensor,  # [T, N_A, 3] metres
    spec: SceneSpec,
    settings: DataSettings,
    velocities: torch.Tensor | None = None,  # [T, N_A, 3] m/s: needed with an open shutter
) -> tuple[Cameras, np.ndarray, np.ndarray, list[bytes]]:
    """The realistic look: cameras framed on the motion, the shaded object over the scene with
    its shadow (blurred along its motion while the shutter is open, ``spec.exposure_s``; its
    rows read one after the other, ``spec.readout_s``), sensor noise and H.264 compression.
    Returns the cameras, the decoded frames [V, T, H, W, 3] uint8, the true masks [V, T, H, W]
    bool (the object's coverage over ½, as the sensor caught it) and the V mp4 files."""
    anchors_np = anchors.detach().cpu().double().numpy()
    cameras = framed_cameras(anchors_np, spec, settings.resolution)
    if spec.exposure_s == 0 and spec.readout_s == 0:
        rgb, alpha = render_object_views(asset, anchors, cameras, spec.look)
    else:  # a rolling shutter reads each band of rows at its own time, top to bottom
        if velocities is None:
            raise ValueError("an open shutter or a rolling readout needs the velocities")
        ground, dt, height = asset.physics.ground_height, settings.frame_dt, settings.resolution
        bands = READOUT_BANDS if spec.readout_s > 0 else 1
        samples = READOUT_SHUTTER_SAMPLES if bands > 1 else SHUTTER_SAMPLES
        rgb_rows, alpha_rows = [], []
        for band in range(bands):
            shift = ((band + 0.5) / bands - 0.5) * spec.readout_s
            if spec.exposure_s > 0:
                moments = shutter_anchors(
                    anchors, velocities, spec.exposure_s, dt, ground, samples, shift
                )
            else:
                moments = carried_anchors(anchors, velocities, [shift], dt, ground)
            rgb_band, alpha_band = _render_moments(asset, moments, cameras, spec.look)
            rows = slice(band * height // bands, (band + 1) * height // bands)
            rgb_rows.append(rgb_band[:, :, rows])
            alpha_rows.append(alpha_band[:, :, rows])
        rgb, alpha = torch.cat(rgb_rows, 2), torch.cat(alpha_rows, 2)
    background = scene_background(cameras, spec.look)
    extent = anchors_np[0].max(0) - anchors_np[0].min(0)
    spacing = float(np.prod(np.maximum(extent, 1e-3)) / anchors_np.shape[1]) ** (1 / 3)
    frames = composite_in_scene(
        rgb.cpu().double(), alpha.cpu().double(), anchors.cpu(), background, spec.look, spacing
    )
    masks = alpha > 0.5
    if spec.hand is not None:
        frames, masks = held_in_hand(frames, masks, anchors, cameras, spec, settings.frame_dt)
    frames = add_sensor_noise(frames, spec.look.noise_sigma, spec.noise_seed)
    fps = 1.0 / settings.frame_dt
    decoded, videos = [], []
    for view in to_uint8(frames):
        frames_v, data = compress_video(view, fps, spec.video_quality)
        decoded.append(frames_v)
        videos.append(data)
    return cameras, np.stack(decoded), masks.cpu().numpy(), videos


def held_in_hand(
    frames: torch.Tensor,  # [V, T, H, W, 3] in [0, 1]
    masks: torch.Tensor,  # [V, T, H, W] bool
    anchors: torch.Tensor,  # [T, N_A, 3] metres
    cameras: Cameras,  # V cameras
    spec: SceneSpec,  # with a hand
    frame_dt: float,  # s
) -> tuple[torch.Tensor, torch.Tensor]:  # frames, the object's visible masks
    """The sample's hand over its frames (render/hand.py): holding the object's top at frame 0
    (the release), its forearm pointing away from view 0's camera, then moving."""
    points = anchors.detach().cpu().double()
    top, half_width = object_grip(points[0].numpy())
    w2c = cameras.world_to_cam.cpu().double()  # [V, 4, 4]
    eye = (-w2c[0, :3, :3].T @ w2c[0, :3, 3]).numpy()
    arm = arm_direction(spec.hand, top, eye)
    hand = hand_gaussians(top, half_width, arm, spec.hand)
    centre = points.mean(1)  # [T, 3]
    depth = (centre @ w2c[:, 2, :3].T + w2c[:, 2, 3]).T  # [V, T] camera-space z
    times = torch.arange(frames.shape[1], dtype=torch.float64) * frame_dt
    return composite_hand(frames, masks.cpu(), depth, hand, arm * spec.hand.speed, times,
                          cameras.to("cpu"), spec.look)  # fmt: skip


def generate_sample(
    obj: CanonicalObject,
    sample_index: int,
    settings: DataSettings,
    device: torch.device | str = "cpu",
) -> GeneratedSample:
    spec = draw_sample(settings, obj.id, sample_index)
    if settings.scene == "realistic":  # the object at the sample's size, with its print
        drawn = draw_scene(settings, obj.id, sample_index)
        obj = printed_object(scale_object(obj, drawn.size / settings.size), drawn.look)
    placement = place(obj, spec)
    asset = sample_asset(obj, spec, placement, settings)
    trajectory = asset.simulate(settings.num_frames - 1, torch.device(device))
    anchors = trajectory.x[0]  # [T, N_A, 3]
    scene = masks = videos = None
    if settings.scene == "realistic":
        scene = draw_scene(settings, obj.id, sample_index)
        cameras, frames, masks, videos = render_realistic(
            asset, anchors, scene, settings, trajectory.v[0]
        )
    else:
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
        scene=scene,
        masks=masks,
        videos=videos,
    )
