"""The physics network's input: the object's crop (models/model_input.object_crop) reads the same
picture whatever the recording's framing, zoom and resolution; a constructed check against the
analytic disc it samples."""

from __future__ import annotations

import torch

from reconphys.models.model_input import CROP_MARGIN, network_input, object_crop
from reconphys.models.physics_predictor import (
    resize_frames,
    silhouette_motion,
    silhouette_statistics,
)


def disc_clip(size: int, centre: tuple[float, float], radius: float, drop: float) -> torch.Tensor:
    """[T=6, size, size, 3]: a grey disc of ``radius`` pixels falling ``drop`` pixels a frame²
    from ``centre`` (x, y pixels), antialiased by 8× supersampling."""
    fine = size * 8
    ys, xs = torch.meshgrid(
        (torch.arange(fine) + 0.5) / 8, (torch.arange(fine) + 0.5) / 8, indexing="ij"
    )
    frames = []
    for t in range(6):
        cy = centre[1] + drop * t * t
        inside = ((xs - centre[0]) ** 2 + (ys - cy) ** 2 <= radius**2).float()
        cover = torch.nn.functional.avg_pool2d(inside[None, None], 8)[0, 0]
        frames.append(cover[..., None].expand(size, size, 3) * 0.6)
    return torch.stack(frames)


def test_the_crop_does_not_depend_on_framing_zoom_or_resolution():
    """One motion filmed at 128 px (A); the same at 256 px (B: twice the resolution); A's pixels
    placed elsewhere in a 256-px frame (C: another framing and field of view). C's crop is A's
    exactly, where the resized whole frames differ wholly; B's agrees to ~3 % of the motion
    (the box's edges snap to whole source pixels, and the silhouette's saturated rim is a
    fixed part of a crop pixel); and A's crop matches the analytic motion box."""
    a = disc_clip(128, (40.0, 28.0), 12.0, 1.0)
    b = disc_clip(256, (80.0, 56.0), 24.0, 2.0)
    c = disc_clip(256, (150.0, 30.0), 12.0, 1.0)
    crops = [object_crop(clip, 32) for clip in (a, b, c)]
    assert all(crop.shape == (1, 6, 32, 32, 3) for crop in crops)
    stats = [silhouette_statistics(crop) for crop in crops]
    motion = [silhouette_motion(s) for s in stats]
    assert float((stats[0] - stats[2]).abs().max()) < 1e-4
    assert float((motion[0] - motion[2]).abs().max()) < 1e-4
    whole = [silhouette_statistics(resize_frames(clip[None], 32)) for clip in (a, c)]
    assert float((whole[0] - whole[1]).abs().max()) > 0.3
    assert float((stats[0] - stats[1]).abs().max()) < 0.01
    assert float((motion[0] - motion[1]).abs().max()) < 0.15  # of a 4-radius fall
    # A's box: x 28..52, y 16..65 (the disc's extent over the clip) grown by the margin to a
    # side of 49 px × (1 + 2·margin), centred on (40, 40.5): the disc's centre, at y = 28 in
    # frame 0 and 53 in frame 5, is (y − 40.5) / side × 32 crop pixels from the centre: × 2 / 31
    # in the statistics' units (−1 and 1 at the first and last pixel centres)
    side = 49.0 * (1 + 2 * CROP_MARGIN)
    centroids = stats[0][0, :, 1:3]
    assert float(centroids[:, 0].abs().max()) < 1e-4
    assert abs(float(centroids[0, 1]) - (28.0 - 40.5) / side * 64 / 31) < 0.005
    assert abs(float(centroids[5, 1]) - (53.0 - 40.5) / side * 64 / 31) < 0.005


def test_an_empty_clip_and_a_frame_model_read_the_whole_frame():
    empty = torch.zeros(3, 40, 40, 3)
    assert torch.equal(object_crop(empty, 16), resize_frames(empty[None], 16))
    clip = disc_clip(64, (20.0, 14.0), 6.0, 0.5)
    assert torch.equal(network_input(clip, None, 32, crop=False), resize_frames(clip[None], 32))
    assert torch.equal(network_input(clip, None, 32, crop=True), object_crop(clip, 32))
