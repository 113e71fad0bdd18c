"""The object's mask in every frame.

In order of preference:

1. a mask folder (``--masks DIR``): one image per frame (same natural order and count as the
   frames), object = pixels > 127 (any channel count; an alpha channel wins when present);
2. the video's own alpha channel (RGBA PNG frames, transparent GIF): object = alpha > 127;
3. background subtraction for a **static camera** (:func:`subtract_background`): a clean plate
   (``--background IMAGE``) when given, else the backdrop colour estimated from the image border.
   Limits: the object must differ in colour from the backdrop by more than ``tolerance``; the
   camera must not move; shadows and reflections darker/brighter than the tolerance count as
   object; without a clean plate the border of every frame must show only backdrop (a uniform
   sweep, a table top filmed from above, or our black synthetic renders).

Masks are float [T, H, W] in {0, 1}.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from .video import list_images, read_image

DEFAULT_TOLERANCE = 0.08  # colour distance (RGB in [0, 1], Euclidean) that counts as object
BORDER = 2  # pixels of the image border that sample the backdrop colour


def read_mask_folder(folder: str | os.PathLike, num_frames: int, height: int, width: int) -> Tensor:
    """[T, H, W] masks from a folder of images (one per frame, resized to the frames if needed)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("mask folder not found", source=str(folder))
    files = list_images(folder)
    if len(files) != num_frames:
        raise InputError(f"{len(files)} mask images for {num_frames} frames", source=str(folder))
    masks = []
    for path in files:
        image = read_image(path)
        channel = image[..., 3] if image.shape[-1] == 4 else image.max(axis=-1)
        mask = torch.from_numpy((channel > 127).astype(np.float32))
        if mask.shape != (height, width):
            mask = torch.nn.functional.interpolate(
                mask[None, None], size=(height, width), mode="nearest"
            )[0, 0]
        masks.append(mask)
    return torch.stack(masks)


def alpha_masks(frames: np.ndarray) -> Tensor:  # frames [T, H, W, 4] uint8 → [T, H, W]
    return torch.from_numpy((frames[..., 3] > 127).astype(np.float32))


def backdrop_colour(frames: Tensor, border: int = BORDER) -> Tensor:
    """Median colour of the image border over all frames: [T, H, W, 3] → [3]."""
    edges = torch.cat(
        [
            frames[:, :border].reshape(-1, 3),
            frames[:, -border:].reshape(-1, 3),
            frames[:, :, :border].reshape(-1, 3),
            frames[:, :, -border:].reshape(-1, 3),
        ]
    )
    return edges.median(0).values


def subtract_background(
    frames: Tensor,  # [T, H, W, 3] float in [0, 1]
    background: Tensor | None = None,  # [H, W, 3] clean plate, or None: the border's colour
    tolerance: float = DEFAULT_TOLERANCE,
) -> Tensor:  # [T, H, W] in {0, 1}
    """Object = pixels farther than ``tolerance`` (RGB distance) from the background."""
    reference = backdrop_colour(frames) if background is None else background
    distance = (frames - reference).norm(dim=-1)
    return (distance > tolerance).float()


def read_background(path: str | os.PathLike, height: int, width: int) -> Tensor:
    """A clean plate image → [H, W, 3] float in [0, 1] at the frames' size."""
    image = read_image(Path(path))[..., :3]
    if image.shape[-1] == 1:
        image = np.repeat(image, 3, axis=-1)
    plate = torch.from_numpy(image.astype(np.float32) / 255.0)
    if plate.shape[:2] != (height, width):
        raise InputError(
            f"is {plate.shape[1]}×{plate.shape[0]} pixels, the frames {width}×{height}",
            source=str(path),
        )
    return plate


def check_masks(masks: Tensor, source: str, first: int = 1) -> None:
    """Refuse masks that leave the object empty in frame 0 (or in any of the first frames)."""
    empty = [t for t in range(min(first, masks.shape[0])) if float(masks[t].sum()) == 0]
    if empty:
        raise InputError(f"the object's mask is empty in frame {empty[0]}", source=source)
