"""The preview: the observed frames beside the simulated asset, from the recording's camera.

Left: the recording as filmed, with the outline of the masks ``predict`` read (black after its
last frame). Right: the asset simulated from its initial state and rendered into the same camera
over the recording's own background (:func:`background_plate`: the scene without the object),
continuing past the recording, with the same outline while the recording lasts — where the
simulated object leaves the outline, the re-simulation and the recording part. Panels are
enlarged (nearest neighbour) to at least ``PREVIEW_MIN_SIZE`` pixels so small inputs stay visible,
and a large recording is shown (and the asset rendered) at most ``PREVIEW_MAX_SIDE`` pixels a side.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.asset import Asset
from ..capture import CameraSpec, Observation
from .settings import PREVIEW_MAX_SIDE, PREVIEW_MIN_SIZE

SEPARATOR = 2  # pixels of grey between the panels
OUTLINE = (0.2, 1.0, 0.2)  # the masks' outline over the recording: what was taken for the object
# The masks are widened by this share of the frame's longer side before the background is read
# where they leave it free: their rim's error and the darkest part of the object's shadow
PLATE_MARGIN = 0.03
PLATE_FRAMES = 16  # the background is read from at most this many frames, evenly spaced


def outlined(
    frames: Tensor,  # [T, H, W, 3] the recording as it was filmed (background included)
    masks: Tensor,  # [T, H, W] in {0, 1}
) -> Tensor:  # [T, H, W, 3]
    """The recording with each mask's outline (its pixels next to a background pixel) drawn in
    green: the preview shows what ``predict`` took for the object, so a wrong mask shows."""
    inside = masks[:, None].float()
    eroded = 1.0 - F.max_pool2d(1.0 - inside, 3, stride=1, padding=1)
    edge = ((inside - eroded)[:, 0] > 0.5)[..., None]
    return torch.where(edge, torch.tensor(OUTLINE, dtype=frames.dtype), frames)


def _enlarge(images: Tensor, factor: int) -> Tensor:  # [T, H, W, 3] → [T, fH, fW, 3]
    if factor == 1:
        return images
    return F.interpolate(images.permute(0, 3, 1, 2), scale_factor=factor, mode="nearest").permute(
        0, 2, 3, 1
    )


def background_plate(
    frames: Tensor,  # [T, H, W, 3] a static camera's recording, background included
    masks: Tensor,  # [T, H, W] in {0, 1}: the object
) -> Tensor:  # [H, W, 3]
    """The scene without the object: per pixel, the (lower) median over the frames where the
    masks, widened by ``PLATE_MARGIN`` of the frame's longer side, leave it free (a falling
    object uncovers where it comes to rest; at most ``PLATE_FRAMES`` frames, evenly spaced); a
    pixel covered in every frame takes the nearest free pixel's value, and with no free pixel at
    all the plate is black."""
    from scipy import ndimage

    picks = np.unique(np.linspace(0, masks.shape[0] - 1, PLATE_FRAMES).round().astype(int))
    frames, masks = frames[picks], masks[picks]
    height, width = masks.shape[1:]
    radius = max(1, round(PLATE_MARGIN * max(height, width)))
    covered = (masks > 0.5).numpy().astype(np.uint8)
    widened = ndimage.maximum_filter(covered, size=(1, 2 * radius + 1, 2 * radius + 1))
    free = torch.from_numpy(widened == 0)  # [T, H, W]
    # the lower median of the free values: the covered ones sorted last (as +inf)
    values = torch.where(free[..., None], frames.float(), torch.tensor(math.inf))
    values = values.permute(1, 2, 3, 0).contiguous().sort(-1).values  # [H, W, 3, T]: sorted
    middle = ((free.sum(0) - 1).clamp(min=0) // 2)[..., None, None].expand(-1, -1, 3, 1)
    plate = values.gather(-1, middle)[..., 0]  # [H, W, 3]
    never = ~free.any(0)
    if bool(never.all()):
        return torch.zeros_like(plate)
    if bool(never.any()):
        _, (rows, cols) = ndimage.distance_transform_edt(never.numpy(), return_indices=True)
        plate = plate[torch.from_numpy(rows), torch.from_numpy(cols)]
    return plate


def over_plate(
    rendered: Tensor,  # [T, H, W, 4] colour on black and accumulated opacity (render_sequence)
    plate: Tensor,  # [H, W, 3]
) -> Tensor:  # [T, H, W, 3]
    """The rendered frames laid over the background ``plate``: ``rgb + (1 − alpha)·plate``."""
    rgb, alpha = rendered[..., :3], rendered[..., 3:]
    return (rgb + (1.0 - alpha) * plate).clamp(0.0, 1.0)


def preview_view(
    observation: Observation, max_side: int = PREVIEW_MAX_SIDE
) -> tuple[Tensor, Tensor, CameraSpec]:
    """The recording as filmed [T, h, w, 3], its masks [T, h, w] in {0, 1} and its camera at the
    preview's size: at most ``max_side`` px a side (the frames area-averaged, a pixel in the
    masks where they cover at least half of it, K scaled), the recording's own where it fits."""
    from ..models.mask_segmenter import segmented_size  # a clip area-averaged to max_side

    frames, masks, camera = observation.unmasked.cpu(), observation.masks.cpu(), observation.camera
    if max(masks.shape[1:]) <= max_side:
        return frames, masks, camera
    frames = segmented_size(frames, max_side)
    masks = (segmented_size(masks[..., None].float(), max_side)[..., 0] >= 0.5).float()
    return frames, masks, camera.resized(frames.shape[2], frames.shape[1])


def simulate_and_render(
    asset: Asset,
    frames: Tensor,  # [T_obs, H, W, 3] the recording as filmed (preview_view)
    masks: Tensor,  # [T_obs, H, W] in {0, 1}
    camera: CameraSpec,  # at (W, H)
    num_frames: int,
    device="cpu",
    backend="auto",
) -> Tensor:  # [num_frames, H, W, 3] frames 0..num_frames−1 in the recording's camera
    """The asset simulated and rendered in the recording's camera over its background (the
    recording's :func:`background_plate`), the recorded masks' outline on its frames."""
    from ..render.sequence import render_sequence

    trajectory = asset.simulate(num_frames - 1, torch.device(device))
    means = asset.gaussian_means(trajectory.x[0])
    cameras = camera.cameras()
    rendered = render_sequence(asset.gaussians, means, cameras, backend, with_alpha=True).cpu()
    simulated = over_plate(rendered, background_plate(frames, masks))
    shown = min(masks.shape[0], num_frames)
    simulated[:shown] = outlined(simulated[:shown], masks[:shown])
    return simulated


def contact_sheet(
    observed: Tensor,  # [T_obs, H, W, 3]
    simulated: Tensor,  # [T, H, W, 3]
    count: int = 6,
) -> np.ndarray:  # [2H' + SEPARATOR, count·(W' + SEPARATOR), 3] uint8
    """``count`` evenly spaced frames: the recording on top (black past its end), the simulated
    asset below, so each column compares one instant."""
    from ..render.video import tile_images, to_uint8

    num_frames, height, width = simulated.shape[:3]
    picks = np.linspace(0, num_frames - 1, min(count, num_frames)).round().astype(int)
    factor = max(1, math.ceil(PREVIEW_MIN_SIZE / 2 / max(height, width)))
    # Enlarged by torch's nearest interpolation (as side_by_side), not tile_images' repetition:
    # the two differ for some factors (41, 47, …), and the preview stays as it was.
    shown = [t for t in picks if t < observed.shape[0]]  # a prefix of the columns
    top = list(to_uint8(_enlarge(observed[shown], factor))) if shown else []
    bottom = list(to_uint8(_enlarge(simulated[picks], factor)))
    rows = [top + [None] * (len(picks) - len(top)), bottom]
    grey = 128  # to_uint8(0.5)
    sheet = tile_images(rows, pad=(0, SEPARATOR, 0, SEPARATOR), fill=grey)
    return sheet[:-SEPARATOR]  # no bar under the last row


def side_by_side(
    observed: Tensor,  # [T_obs, H, W, 3]
    simulated: Tensor,  # [T, H, W, 3], T ≥ T_obs
) -> np.ndarray:  # [T, H', 2W' + SEPARATOR, 3] uint8
    from ..render.video import to_uint8

    num_frames, height, width = simulated.shape[:3]
    left = torch.zeros_like(simulated)
    shown = min(observed.shape[0], num_frames)
    left[:shown] = observed[:shown]
    factor = max(1, math.ceil(PREVIEW_MIN_SIZE / max(height, width)))
    left, right = _enlarge(left, factor), _enlarge(simulated, factor)
    bar = torch.full((num_frames, left.shape[1], SEPARATOR, 3), 0.5)
    return to_uint8(torch.cat([left, bar, right], dim=2))


CAPTION_WIDTH = 800  # px of sheet per caption letter size: a wider sheet's text is enlarged


def with_caption(image: np.ndarray, lines: list[str]) -> np.ndarray:  # [H, W, 3] → [H + h, W, 3]
    """The image with ``lines`` of white text on a black strip below it (PIL's built-in font,
    enlarged by a whole factor for every CAPTION_WIDTH px of the image's width, so a sheet of a
    1080p recording stays readable when it is shown smaller)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    line_height = 12
    factor = max(1, image.shape[1] // CAPTION_WIDTH)
    width = -(-image.shape[1] // factor)
    strip = Image.new("RGB", (width, 4 + line_height * len(lines)), (0, 0, 0))
    draw = ImageDraw.Draw(strip)
    for i, line in enumerate(lines):
        draw.text((4, 2 + line_height * i), line, fill=(255, 255, 255), font=font)
    strip = np.asarray(strip, dtype=np.uint8).repeat(factor, 0).repeat(factor, 1)
    return np.concatenate([image, strip[:, : image.shape[1]]], axis=0)


def interval_lines(observables: dict[str, float], intervals: dict | None) -> list[str]:
    """The preview's caption: each observable with its 10–90 % interval (or why there is none)."""
    if not intervals:
        return ["feed-forward only (--no-refine), not an ensemble: no intervals"]
    names = {"log_k_over_m": "log k/m", "log_d_over_m": "log d/m", "friction": "friction"}
    return [
        f"{names[key]} {observables[key]:.2f}  [{low:.2f}, {high:.2f}] (10-90 %)"
        for key, (low, high) in intervals.items()
    ]
