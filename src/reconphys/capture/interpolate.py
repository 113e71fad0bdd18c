"""Frames between two recorded frames, for a recording whose frame times are not the simulator's.

A phone records at 30 (or 25, 60) frames per second; the models read frames 0.03 s apart. The
nearest recorded frame is up to half a recorded interval off its time (17 ms at 30 fps: 5 cm at
3 m/s), which bends the fall that gives the scale and the motion the physics is read from. Each
wanted frame is made instead from the recorded frames just before and after it
(:func:`reconphys.capture.video.resample_between`) by **motion-compensated interpolation**:

- the object moves by ``d`` pixels (its masks' centroids) from the earlier frame to the later;
  each mask is shifted along ``d`` to the wanted time (``w·d`` from the earlier, ``−(1 − w)·d``
  from the later; bilinear, sub-pixel, as coverage in [0, 1]) and the two are blended with
  weights ``1 − w`` and ``w``; the wanted mask is where the blend reaches ½. A translating shape
  comes out translated, its size and thin parts kept (blending in place would double it or
  leave a gap); a squashing one in between;
- the object's colours (the frames times their masks) are shifted the same way and blended,
  normalised by the shifted masks' coverage, so the object is not doubled.

The recording itself (the background) is blended in place. Frames with ``weight == 0`` are the
recorded ones, unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

MARGIN_PX = 2  # pixels around both masks (and the motion between them) that are shifted


def _shift(image: np.ndarray, offset: np.ndarray, fill: float) -> np.ndarray:
    """``image`` [h, w(, C)] moved by ``offset`` (rows, columns) pixels, bilinear."""
    from scipy import ndimage

    shift = (*offset, 0.0) if image.ndim == 3 else tuple(offset)
    return ndimage.shift(image, shift, order=1, mode="constant", cval=fill)


def _centroid(mask: np.ndarray) -> np.ndarray:  # [2] (row, column) pixels
    return np.argwhere(mask).mean(0)


def _between(
    m0: np.ndarray, m1: np.ndarray, c0: np.ndarray, c1: np.ndarray, w: float
) -> tuple[np.ndarray, np.ndarray]:
    """The mask [H, W] bool and object colours [H, W, 3] (float64, black outside the mask) a
    fraction ``w`` of the way from the earlier frame (m0, c0) to the later (m1, c1) (module
    doc); only the box around both masks and the motion is computed."""
    d = _centroid(m1) - _centroid(m0)
    margin = MARGIN_PX + math.ceil(float(np.abs(d).max()))
    rows, cols = np.nonzero(m0 | m1)
    top, left = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
    bottom = min(rows.max() + margin + 1, m0.shape[0])
    right = min(cols.max() + margin + 1, m0.shape[1])
    box = (slice(top, bottom), slice(left, right))
    c0, c1 = c0[box].astype(np.float64), c1[box].astype(np.float64)
    a0 = _shift(m0[box].astype(np.float64), w * d, 0.0)  # the masks' coverage, moved
    a1 = _shift(m1[box].astype(np.float64), -(1 - w) * d, 0.0)
    p0 = _shift(c0 * m0[box][..., None], w * d, 0.0)  # premultiplied colours, moved
    p1 = _shift(c1 * m1[box][..., None], -(1 - w) * d, 0.0)
    coverage = (1 - w) * a0 + w * a1
    inside = coverage >= 0.5
    mask = np.zeros_like(m0)
    mask[box] = inside
    colour = np.zeros((*m0.shape, 3))
    colour[box] = (
        ((1 - w) * p0 + w * p1) / np.maximum(coverage, 1e-6)[..., None] * inside[..., None]
    )
    return mask, colour


def frames_between(
    recorded: Tensor,  # [N, H, W, 3] in [0, 1], the recorded frames used
    masks: Tensor,  # [N, H, W] in {0, 1}, theirs
    before: np.ndarray,  # [J] index into recorded of the frame at or before each wanted time
    after: np.ndarray,  # [J] the frame after it (= before where weight is 0)
    weight: np.ndarray,  # [J] in [0, 1): the later frame's share
) -> tuple[Tensor, Tensor, Tensor]:
    """The wanted frames: ``(recording [J, H, W, 3], masks [J, H, W], object [J, H, W, 3])``,
    the recording blended in place, the masks and the object on black motion-compensated
    (module doc). Where either side's mask (or the result) is empty, the nearer frame is taken."""
    binary = masks > 0.5
    count = len(before)
    out_rgb = torch.empty((count, *recorded.shape[1:]), dtype=recorded.dtype)
    out_masks = torch.empty((count, *masks.shape[1:]), dtype=torch.float32)
    out_object = torch.empty_like(out_rgb)
    for j, (b, a, w) in enumerate(
        zip(before.tolist(), after.tolist(), weight.tolist(), strict=True)
    ):
        mask = None
        if w > 0 and bool(binary[b].any()) and bool(binary[a].any()):
            m0, m1 = binary[b].numpy(), binary[a].numpy()
            mask, colour = _between(m0, m1, recorded[b].numpy(), recorded[a].numpy(), w)
        if mask is None or not mask.any():  # on a recorded frame, or nothing to move
            near = b if w < 0.5 else a
            out_rgb[j], out_masks[j] = recorded[near], binary[near]
            out_object[j] = recorded[near] * binary[near][..., None]
            continue
        out_rgb[j] = (1 - w) * recorded[b] + w * recorded[a]
        out_masks[j] = torch.from_numpy(mask)
        out_object[j] = torch.from_numpy(colour)
    return out_rgb, out_masks, out_object
