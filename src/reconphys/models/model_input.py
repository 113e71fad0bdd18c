"""The physics predictor's input from an observation: the frames as the dataset's camera would
have framed them, at the network's resolution.

The network was trained on the dataset's views (40° vertical field of view, square frames). A
recording with other intrinsics (another focal length, aspect or principal point) is resampled
to a virtual camera with the dataset's intrinsics and the recording's pose, i.e. the pixel ``p``
of the virtual image reads the recording at ``K_rec K_virtual⁻¹ p`` (a pure change of intrinsics,
exact for a pinhole camera). Distance and elevation are not changed: film from about the
dataset's (2 m, 15° above the horizontal) for the network's best guess.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..render.cameras import intrinsics_from_fov
from .physics_predictor import resize_frames

DATASET_FOV_DEG = 40.0  # the dataset cameras' vertical field of view (docs/design.md#conventions)
SUPERSAMPLE = 4  # the virtual image is sampled at 4× the network's size, then area-averaged


def virtual_intrinsics(size: int) -> Tensor:  # [3, 3]
    return intrinsics_from_fov(DATASET_FOV_DEG, size, size, dtype=torch.float64)


def matches_dataset_intrinsics(K: Tensor, width: int, height: int, tol: float = 1e-3) -> bool:
    """True when K is the dataset's camera at ``width × height`` (square frames only)."""
    if width != height:
        return False
    return bool(torch.allclose(K.double(), virtual_intrinsics(width), rtol=tol, atol=tol * width))


def predictor_frames(
    frames: Tensor,  # [T, H, W, 3] in [0, 1], background black
    K: Tensor,  # [3, 3] the recording's intrinsics at (W, H)
    resolution: int,  # the network's input size
) -> Tensor:  # [1, T, R, R, 3]
    """The recording resampled to the dataset's intrinsics at ``resolution`` pixels."""
    height, width = frames.shape[1:3]
    if matches_dataset_intrinsics(K, width, height):
        return resize_frames(frames[None], resolution)  # the dataset's own resize (area)
    size = resolution * SUPERSAMPLE
    virtual = virtual_intrinsics(size)
    centres = torch.arange(size, dtype=torch.float64) + 0.5
    ys, xs = torch.meshgrid(centres, centres, indexing="ij")
    pixels = torch.stack([xs, ys, torch.ones_like(xs)], -1)  # [S, S, 3]
    source = pixels @ (K.double() @ torch.linalg.inv(virtual)).T
    u, v = source[..., 0] / source[..., 2], source[..., 1] / source[..., 2]
    grid = torch.stack([2 * u / width - 1, 2 * v / height - 1], -1).float()  # align_corners=False
    images = frames.permute(0, 3, 1, 2)
    warped = F.grid_sample(
        images,
        grid.expand(frames.shape[0], -1, -1, -1),
        mode="bilinear",
        padding_mode="zeros",
        align_corners=False,
    )
    warped = F.interpolate(warped, size=(resolution, resolution), mode="area")
    return warped.permute(0, 2, 3, 1)[None].clamp(0, 1)
