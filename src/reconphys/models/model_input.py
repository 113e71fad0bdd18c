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
from .physics_predictor import OBJECT_LEVEL, resize_frames

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
    return _resample(frames, grid, resolution)


def _resample(
    frames: Tensor,  # [T, H, W, 3]
    grid: Tensor,  # [S, S, 2] where each sample reads the frames (grid_sample's [−1, 1] units)
    resolution: int,
) -> Tensor:  # [1, T, R, R, 3]
    """The frames read bilinearly at ``grid`` (black outside), then area-averaged to
    ``resolution``."""
    sampled = F.grid_sample(
        frames.permute(0, 3, 1, 2),
        grid.to(frames.dtype).expand(frames.shape[0], -1, -1, -1),
        mode="bilinear",
        padding_mode="zeros",
        align_corners=False,
    )
    sampled = F.interpolate(sampled, size=(resolution, resolution), mode="area")
    return sampled.permute(0, 2, 3, 1)[None].clamp(0, 1)


# --- object-centric input -------------------------------------------------------------------

CROP_MARGIN = 0.15  # the crop: the object's motion box grown by this share of its side, each way
CROP_LEVEL = 0.5  # a pixel is in the motion box where the object covers this much of it


def object_crop(
    frames: Tensor,  # [T, H, W, 3] in [0, 1], the object on a black backdrop
    resolution: int,  # the crop's side, pixels
    margin: float = CROP_MARGIN,
) -> Tensor:  # [1, T, R, R, 3]
    """The clip cropped to the square around the object's motion box (every pixel that the
    object covers in any frame, :data:`CROP_LEVEL`; grown by ``margin`` a side) and resampled to
    ``resolution`` (bilinear at 4× then area-averaged; outside the frame is black).

    The physics network then reads the same object-sized picture whatever the recording's
    framing, field of view, distance or resolution: a centimetre of slide or squash is the same
    share of the crop (docs/training.md "Object-centric input"). No camera is needed. An empty
    clip (no object pixel) is resized whole."""
    if frames.dim() != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected [T, H, W, 3], got {list(frames.shape)}")
    covered = ((frames.amax(-1) / OBJECT_LEVEL).clamp(0, 1) >= CROP_LEVEL).any(0)  # [H, W]
    box = square_box(covered, margin)
    if box is None:
        return resize_frames(frames[None], resolution)
    return _resample(frames, _box_grid(box, resolution, *frames.shape[1:3]), resolution)


def square_box(
    covered: Tensor,  # [H, W] bool: the object's pixels
    margin: float = CROP_MARGIN,
) -> tuple[float, float, float] | None:  # (centre u, centre v, side), pixels; None: empty
    """The square around the bounding box of ``covered``, grown by ``margin`` of its longer side
    each way (pixel coordinates: 0 is the image's left/top edge)."""
    if not bool(covered.any()):
        return None
    rows = covered.any(1).nonzero()[:, 0]
    cols = covered.any(0).nonzero()[:, 0]
    top, bottom = float(rows[0]), float(rows[-1]) + 1.0
    left, right = float(cols[0]), float(cols[-1]) + 1.0
    side = max(bottom - top, right - left) * (1.0 + 2.0 * margin)
    return (left + right) / 2, (top + bottom) / 2, side


def _box_grid(box: tuple[float, float, float], resolution: int, height: int, width: int) -> Tensor:
    """grid_sample's grid [S, S, 2] that reads the square ``box`` at SUPERSAMPLE × resolution."""
    centre_u, centre_v, side = box
    size = resolution * SUPERSAMPLE
    step = (torch.arange(size, dtype=torch.float64) + 0.5) / size - 0.5  # [S] in (−½, ½)
    u = centre_u + step * side  # pixel coordinates (0 = the left edge)
    v = centre_v + step * side
    gy, gx = torch.meshgrid(2 * v / height - 1, 2 * u / width - 1, indexing="ij")
    return torch.stack([gx, gy], -1)  # align_corners=False


def crop_intrinsics(
    K: Tensor,  # [3, 3] the image's intrinsics
    box: tuple[float, float, float],  # square_box's (centre u, centre v, side), pixels
    resolution: int,
) -> Tensor:  # [3, 3] the crop's intrinsics at resolution × resolution
    """A square crop of a pinhole image, resampled to ``resolution``, is a pinhole image: the same
    pose, the focal lengths × resolution / side, the principal point moved to the crop's corner."""
    centre_u, centre_v, side = box
    scale = resolution / side
    cropped = K.clone().double()
    cropped[0, 0], cropped[1, 1] = K[0, 0] * scale, K[1, 1] * scale
    cropped[0, 2] = (K[0, 2] - (centre_u - side / 2)) * scale
    cropped[1, 2] = (K[1, 2] - (centre_v - side / 2)) * scale
    return cropped.to(K.dtype)


def frame_crop(
    image: Tensor,  # [H, W, 3] in [0, 1]
    mask: Tensor,  # [H, W] in {0, 1}: the object
    K: Tensor,  # [3, 3] the image's intrinsics
    resolution: int,
    margin: float = CROP_MARGIN,
) -> tuple[Tensor, Tensor, Tensor]:  # [R, R, 3] masked image, [R, R] mask, [3, 3] K
    """One frame's object: the square around its mask's box (grown by ``margin``), the masked
    image and the mask resampled to ``resolution`` (bilinear at 4× then area; a crop pixel is on
    the object where the mask covers half of it), and the crop's intrinsics
    (:func:`crop_intrinsics`). The 3DGS predictor's object-centric input."""
    covered = mask > 0.5
    box = square_box(covered, margin)
    if box is None:
        raise ValueError("the mask is empty: no object to crop")
    height, width = mask.shape
    stacked = torch.stack(
        [image * covered[..., None], covered[..., None].to(image.dtype).expand_as(image)]
    )  # [2, H, W, 3]
    grid = _box_grid(box, resolution, height, width)
    crops = _resample(stacked, grid, resolution)[0]  # [2, R, R, 3]
    return crops[0], (crops[1, ..., 0] >= 0.5).to(image.dtype), crop_intrinsics(K, box, resolution)


def network_input(
    frames: Tensor,  # [T, H, W, 3] in [0, 1], the object on a black backdrop
    K: Tensor | None,  # [3, 3] the recording's intrinsics at (W, H); None: the dataset's
    resolution: int,
    crop: bool,  # the model reads the object's crop (PredictorConfig.crop)
) -> Tensor:  # [1, T, R, R, 3]
    """What a physics network reads of a recording: :func:`object_crop` for a network trained on
    crops, else the frames as the dataset's camera would have framed them
    (:func:`predictor_frames`)."""
    if crop:
        return object_crop(frames, resolution)
    if K is None:
        return resize_frames(frames[None], resolution)
    return predictor_frames(frames, K, resolution)
