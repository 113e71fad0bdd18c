"""A hand-held camera's shake, read from the recording's background and taken out.

The mask segmenter, a clean plate and the camera read from the video all assume a static
camera; a phone held in the hand moves the image by pixels from frame to frame, which reads as
the object's motion (a drop 0.46 m high read as 0.28 m, docs/usage.md "A hand-held camera").
A small turn of the camera moves near and far alike: the background shifts as a whole. So each
frame's shift against frame 0 is read from the background and taken out:

- the frame (grey) is cut into :data:`TILE_GRID` × :data:`TILE_GRID` tiles, and in each a
  translation is fitted by Gauss–Newton (Lucas–Kanade), 2× area-averaged first, then at full
  size, with a Cauchy weight (:data:`RESIDUAL_SCALE`) under which pixels that do not match —
  the falling object, its shadow — count little; consecutive frames first (shifts of a pixel
  or two; 2× averaged only), their chain the start of the fit against frame 0 (a shift of many
  pixels, or a repeating floor pattern, would otherwise be caught a period away);
- a tile whose structure tensor's smaller eigenvalue per pixel stays below
  :data:`TEXTURE_MIN` (a plain wall, a muted floor at 96 px: too little texture to say where it
  moved) is not used; the frame's shift is the median of the others' (the object covers one or
  two); with fewer than :data:`MIN_TILES`, or all within two rows or two columns of tiles
  (:data:`MIN_SPREAD`: an object on a plain background), the shake is not readable and the
  clip is left as it is;
- a clip larger than :data:`READ_MAX_SIDE` is read area-averaged down to it, the shifts scaled
  back: the tiles' texture per pixel (:data:`TEXTURE_MIN`) depends on the pixel's size, and a
  phone's frame at the working 640 px showed no tile textured enough on floors whose 128-px
  view was read to a tenth of a pixel there — besides taking 7 s where 0.1 s does
  (docs/usage.md "A hand-held camera");
- a clip whose shift stays under :data:`STILL_PX` is left as it is (a static camera: nothing
  changes); one that moves more than :data:`MAX_SHAKE_SHARE` of the frame is refused (a pan
  that follows the object is not a shake); otherwise every frame is moved back onto frame 0
  (bilinear) and the clip is cropped by the largest shift on every side, so that no frame
  shows a border it did not film (:func:`steady`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

TILE_GRID = 4  # tiles a side
# Per pixel, the smaller eigenvalue of a tile's (weighted) structure tensor below which it
# cannot say where it moved; chosen on still and shaken validation clips: at 5e-5 and below
# still clips of the muted look were read as moving by pixels (docs/usage.md)
TEXTURE_MIN = 2e-4
MIN_TILES = 4  # textured tiles needed to read a frame's shift ...
# ... spread over at least this many rows and columns of tiles: an object on a plain background
# (a textured toy on a white floor) covers a block of two by two at most, and its own motion is
# not the camera's
MIN_SPREAD = 3
RESIDUAL_SCALE = 0.03  # grey levels (0–1): the Cauchy weight's scale (compression noise ×3)
STILL_PX = 0.5  # a shake below this (the masks' own rim noise) is left in
MAX_SHAKE_SHARE = 0.15  # of the shorter side: more is a moving camera, refused
MIN_SIDE = 32  # px: a smaller clip is not read (its tiles would be a few pixels)
# px: a larger clip's shake is read area-averaged down to this longer side (module doc) — the
# size the thresholds were chosen at (96–128-px clips) and the mask segmenter reads
# (models/mask_segmenter.MAX_SIDE), so a tenth of its pixel is a tenth of the masks'
READ_MAX_SIDE = 128
_ITERATIONS = 8  # Gauss–Newton steps per scale
_MAX_STEP_PX = 2.0  # per step, at the scale's pixels


@dataclass(frozen=True)
class Shake:
    """The camera's shake read from a clip."""

    shifts: Tensor | None  # [T, 2] px (x right, y down): the background's shift from frame 0
    tiles_read: int  # tiles textured enough to read (None shifts: too few, or not spread)

    @property
    def largest_px(self) -> float:
        return 0.0 if self.shifts is None else float(self.shifts.norm(dim=1).max())

    def to_json(self) -> dict:
        crop = crop_margin(self)
        return {
            "readable": self.shifts is not None,
            "tiles_read": self.tiles_read,
            "largest_shift_px": round(self.largest_px, 3),
            "taken_out": crop > 0,
            "crop_px": crop,
            "how": "the background's shift from frame 0, read in tiles (capture/stabilize.py); "
            f"taken out above {STILL_PX:g} px",
        }


def warp(images: Tensor, shifts: Tensor) -> Tensor:
    """Images [N, H, W, C] with their content moved by ``shifts`` [N, 2] px (x right, y down):
    out(p) = in(p − shift), bilinear, the border repeated."""
    height, width = images.shape[1:3]
    rows, cols = torch.meshgrid(
        torch.arange(height, dtype=torch.float32) + 0.5,
        torch.arange(width, dtype=torch.float32) + 0.5,
        indexing="ij",
    )
    shifts = shifts.float()
    grid_x = (cols[None] - shifts[:, 0, None, None]) / width * 2 - 1
    grid_y = (rows[None] - shifts[:, 1, None, None]) / height * 2 - 1
    grid = torch.stack([grid_x, grid_y], -1)
    moved = F.grid_sample(
        images.permute(0, 3, 1, 2).float(),
        grid,
        mode="bilinear",
        padding_mode="border",
        align_corners=False,
    )
    return moved.permute(0, 2, 3, 1)


def _gradients(images: Tensor) -> tuple[Tensor, Tensor]:
    """Central differences of [..., H, W], zero on the outer rows and columns."""
    gx = torch.zeros_like(images)
    gy = torch.zeros_like(images)
    gx[..., 1:-1] = 0.5 * (images[..., 2:] - images[..., :-2])
    gy[..., 1:-1, :] = 0.5 * (images[..., 2:, :] - images[..., :-2, :])
    return gx, gy


def _tile_pixels(height: int, width: int, grid: int) -> tuple[Tensor, Tensor]:
    """Row and column indices of each tile's pixels, [K, th] and [K, tw], K = grid²: equal
    tiles inside the outer pixel ring."""
    th, tw = (height - 2) // grid, (width - 2) // grid
    rows = 1 + torch.arange(grid)[:, None] * th + torch.arange(th)  # [grid, th]
    cols = 1 + torch.arange(grid)[:, None] * tw + torch.arange(tw)  # [grid, tw]
    return rows.repeat_interleave(grid, 0), cols.repeat(grid, 1)


def _fit_tiles(
    moving: Tensor,  # [N, H, W] grey
    reference: Tensor,  # [N, H, W] (or [1, H, W]) grey
    start: Tensor,  # [N, K, 2] px: the shifts to start from
    grid: int,
    scales: tuple[int, ...] = (2, 1),
) -> tuple[Tensor, Tensor]:  # [N, K, 2] px, [N, K] texture (smaller eigenvalue per pixel)
    """Each tile's translation of ``moving`` against ``reference`` (Lucas–Kanade, coarse to
    fine, Cauchy-weighted residuals), and how textured it is.
    Each tile's pixels are sampled from the moving frame at their own shift, all tiles in one
    ``grid_sample`` call."""
    n, count = moving.shape[0], grid * grid
    shifts = start.clone().float()
    texture = torch.zeros(n, count)
    for scale in scales:
        mov, ref = moving, reference
        if scale > 1:
            mov = F.avg_pool2d(moving[:, None], scale)[:, 0]
            ref = F.avg_pool2d(reference[:, None], scale)[:, 0]
        height, width = mov.shape[-2:]
        rows, cols = _tile_pixels(height, width, grid)  # [K, th], [K, tw]
        th, tw = rows.shape[1], cols.shape[1]

        ref_tiles = ref[:, rows[:, :, None], cols[:, None, :]]  # [N or 1, K, th, tw]
        x = (cols.float() + 0.5)[None, :, None, :]  # pixel centres, [1, K, 1, tw]
        y = (rows.float() + 0.5)[None, :, :, None]  # [1, K, th, 1]
        for _ in range(_ITERATIONS):
            at = shifts / scale  # back(p) = moving(p + shift): the frame moved back
            grid_x = (x + at[..., 0, None, None]) / width * 2 - 1  # [N, K, 1, tw]
            grid_y = (y + at[..., 1, None, None]) / height * 2 - 1  # [N, K, th, 1]
            sample = torch.stack(torch.broadcast_tensors(grid_x, grid_y), -1)  # [N,K,th,tw,2]
            back = F.grid_sample(
                mov[:, None],
                sample.reshape(n, count * th, tw, 2),
                mode="bilinear",
                padding_mode="border",
                align_corners=False,
            ).reshape(n, count, th, tw)
            residual = back - ref_tiles
            gx, gy = _gradients(back)  # within each tile (its outer ring: 0)
            weight = torch.reciprocal(1 + (residual * (1 / RESIDUAL_SCALE)).square())
            wgx, wgy = weight * gx, weight * gy
            a11, a12, a22 = (wgx * gx).sum((2, 3)), (wgx * gy).sum((2, 3)), (wgy * gy).sum((2, 3))
            b1, b2 = -(wgx * residual).sum((2, 3)), -(wgy * residual).sum((2, 3))
            det = a11 * a22 - a12**2
            safe = det.clamp_min(1e-14)
            step = torch.stack([(a22 * b1 - a12 * b2) / safe, (a11 * b2 - a12 * b1) / safe], -1)
            step = torch.where((det > 1e-14)[..., None], step, torch.zeros_like(step))
            shifts = shifts + step.clamp(-_MAX_STEP_PX, _MAX_STEP_PX) * scale
        trace = a11 + a22
        smaller = 0.5 * (trace - torch.sqrt((a11 - a22) ** 2 + 4 * a12**2))
        texture = smaller / (th * tw)
    return shifts, texture


def read_shake(frames: Tensor, grid: int = TILE_GRID) -> Shake:
    """The background's shift from frame 0 in every frame of a clip [T, H, W, 3] in [0, 1]
    (module doc), or ``shifts=None`` where too few tiles are textured enough to read it."""
    if frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected [T, H, W, 3], got {list(frames.shape)}")
    if frames.shape[0] < 2 or min(frames.shape[1:3]) < MIN_SIDE:
        return Shake(None, 0)  # nothing to compare, or too few pixels a tile
    height, width = frames.shape[1:3]
    if max(height, width) > READ_MAX_SIDE:  # read at the size the thresholds are for
        factor = READ_MAX_SIDE / max(height, width)
        size = (max(MIN_SIDE, round(height * factor)), max(MIN_SIDE, round(width * factor)))
        small = F.interpolate(frames.permute(0, 3, 1, 2).float(), size, mode="area")
        read = read_shake(small.permute(0, 2, 3, 1), grid)
        if read.shifts is None:
            return read
        per_read_px = torch.tensor([width / size[1], height / size[0]])  # (x, y)
        return Shake(read.shifts * per_read_px, read.tiles_read)
    grey = frames.float().mean(-1)  # [T, H, W]
    count = grid * grid
    zero = torch.zeros(frames.shape[0] - 1, count, 2)
    # each against the frame before, 2× averaged only: their chain is just the start of the
    # fit against frame 0, which reads both sizes
    steps, _ = _fit_tiles(grey[1:], grey[:-1], zero, grid, scales=(2,))
    chained = torch.cat([torch.zeros(1, count, 2), steps.cumsum(0)])
    shifts, texture = _fit_tiles(grey[1:], grey[:1], chained[1:], grid)
    textured = texture.median(0).values > TEXTURE_MIN  # [K], judged over the clip
    read = int(textured.sum())
    rows, cols = textured.reshape(grid, grid).any(1), textured.reshape(grid, grid).any(0)
    if read < MIN_TILES or min(int(rows.sum()), int(cols.sum())) < MIN_SPREAD:
        return Shake(None, read)
    per_frame = shifts[:, textured].median(1).values  # [T − 1, 2]
    return Shake(torch.cat([torch.zeros(1, 2), per_frame]), read)


def crop_margin(shake: Shake) -> int:
    """Pixels to crop on every side once the shake is taken out (0: left as it is)."""
    if shake.shifts is None or shake.largest_px < STILL_PX:
        return 0
    return math.ceil(float(shake.shifts.abs().max()))


def steady(images: Tensor, shake: Shake) -> Tensor:
    """Images [T, H, W, C] (frames, or masks with C = 1) moved back onto frame 0 and cropped by
    :func:`crop_margin` on every side; unchanged where the margin is 0."""
    margin = crop_margin(shake)
    if margin == 0:
        return images
    back = warp(images, -shake.shifts)
    return back[:, margin:-margin, margin:-margin]
