"""The object's mask in every frame.

In order of preference:

1. a mask folder (``--masks DIR``): one image per frame (same natural order and count as the
   frames), object = pixels > 127 (any channel count; an alpha channel wins when present);
2. the video's own alpha channel (RGBA PNG frames, transparent GIF): object = alpha > 127;
3. background subtraction for a **static camera** (:func:`subtract_background`): a clean plate
   (``--background IMAGE``) when given, else, when the image border is one colour
   (:func:`border_is_uniform`: a sweep, a table top filmed from above, our black renders), that
   colour. Limits: the object must differ in colour from the backdrop by more than
   ``tolerance``; the camera must not move; shadows and reflections darker/brighter than the
   tolerance count as object;
4. otherwise (a floor, a wall, shadows in view, no clean plate; or a one-colour border whose
   masks fail :func:`check_masks`) the mask segmenter (models/mask_segmenter.py), which reads
   the background from the clip itself; the caller passes it in
   (``load_observation(segment=...)``), as it lives above this layer.

Masks are float [T, H, W] in {0, 1}.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..physics import GRAVITY
from .video import fit_within, list_images, read_image
from .window import pixel_bounds

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
        if mask.shape != (height, width):  # area-averaged (a larger recording read smaller)
            mask = torch.nn.functional.interpolate(
                mask[None, None], size=(height, width), mode="area"
            )[0, 0]
            mask = (mask >= 0.5).float()
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


UNIFORM_BORDER = 0.9  # share of border pixels within tolerance of their median: one colour


def border_is_uniform(frames: Tensor, tolerance: float = DEFAULT_TOLERANCE) -> bool:
    """Whether the border of frames [T, H, W, 3] shows one backdrop colour (see module doc)."""
    b = BORDER
    edges = torch.cat(
        [
            frames[:, :b].reshape(-1, 3),
            frames[:, -b:].reshape(-1, 3),
            frames[:, :, :b].reshape(-1, 3),
            frames[:, :, -b:].reshape(-1, 3),
        ]
    )
    near = (edges - edges.median(0).values).norm(dim=-1) <= tolerance
    return float(near.float().mean()) >= UNIFORM_BORDER


def subtract_background(
    frames: Tensor,  # [T, H, W, 3] float in [0, 1]
    background: Tensor | None = None,  # [H, W, 3] clean plate, or None: the border's colour
    tolerance: float = DEFAULT_TOLERANCE,
) -> Tensor:  # [T, H, W] in {0, 1}
    """Object = pixels farther than ``tolerance`` (RGB distance) from the background."""
    reference = backdrop_colour(frames) if background is None else background
    distance = (frames - reference).norm(dim=-1)
    return (distance > tolerance).float()


def read_background(
    path: str | os.PathLike,
    height: int,
    width: int,
    recorded: tuple[int, int] | None = None,  # (width, height) of the recording, if not read so
) -> Tensor:
    """A clean plate image → [H, W, 3] float in [0, 1] at the frames' size: of the frames as
    read, or of the recording (then area-averaged to the frames' as they were)."""
    image = read_image(Path(path))[..., :3]
    if image.shape[-1] == 1:
        image = np.repeat(image, 3, axis=-1)
    if recorded is not None and image.shape[:2] == (recorded[1], recorded[0]):
        image = fit_within(image[None], max(height, width))[0]
    plate = torch.from_numpy(image.astype(np.float32) / 255.0)
    if plate.shape[:2] != (height, width):
        size = recorded or (width, height)
        raise InputError(
            f"is {image.shape[1]}×{image.shape[0]} pixels, the frames {size[0]}×{size[1]}",
            source=str(path),
        )
    return plate


# Plausibility of the masks (:func:`check_masks`). Measured on 576 views of our drops and
# tosses (data/pyb, data/other, cal128, a duck; docs/usage.md#the-input): frame 0's mask covers
# at most 39 % of the frame and 24 % of its border, never touches two opposite edges, and
# overlaps some later frame's mask by IoU ≤ 0.55 (the object falls away from where it was let go).
MAX_AREA = 0.5  # of the frame, in frame 0: more is background (a floor, a wall), not one object
STATIC_IOU = 0.8  # every frame's mask overlaps frame 0's at least this much: nothing fell
MIN_FOUND = 0.5  # share of the frames with a non-empty mask
# A released object's mask moves off frame 0's (IoU < STILL_IOU) by frame 3 at the latest (drops,
# tosses and drops from rest, 32–512 px: 286 clips of seven datasets, docs/usage.md "The
# input"); STILL_FRAMES or more frames that do not are an object held before its release.
STILL_IOU = 0.95
STILL_FRAMES = 5
# The first frames show one object: in 2 frames (0.06 s) a released object moves, turns and
# grows little. Frame 0's mask against frame 2's, the two centred on each other: exact masks of
# 3,800 views (drops, tosses and drops from rest of thirteen datasets, plain and realistic,
# 32–128 px) overlap by IoU ≥ 0.72 and differ in area by ×0.77–1.24 (docs/usage.md "Bad
# input"). Less is a segmentation that changed its mind (a ghost where the object will land, a
# floor patch): frame 0 sets the shape, the place and the velocity, so such masks are refused.
FIRST_FRAMES_IOU = 0.5
FIRST_FRAMES_AREA = 1.5  # largest area ratio of frame 0's mask to frame 2's, either way
# Over frames 0–3 (0.09 s) a released object's mask keeps its size: |log(area_t / area_0)| was at
# most 0.09 on 59 drops from rest and 0.143 on 73 moving drops and tosses (a toss towards the
# camera grows), segmenter masks, 96 px. A hand in view that hides the object's top, or that the
# masks take in, changes it more as the object leaves it: 12 of the 15 reads over 0.1 m/s of 54
# drops from rest with a hand in view, and 1 of their 39 right reads, were above this
# (benchmarks/hand_release.py; docs/usage.md "A hand in view"). The velocity read from such
# masks is flagged, not refused (a toss towards a near camera may grow as much).
FIRST_FRAMES_AREA_CHANGE = 0.15
WHAT_TO_GIVE = (
    "give the object's masks with --masks DIR (one image per frame) or a clean plate with "
    "--background IMAGE"
)


def check_masks(masks: Tensor, source: str, first: int = 1) -> None:
    """Refuse masks [T, H, W] that cannot be one released object (one-line InputError naming
    ``source`` and what to give instead): empty in frame 0 (or any of the first ``first``
    frames), found in fewer than half the frames, covering more than half of frame 0 or
    spanning it edge to edge (background, not an object), not moving (every frame's mask
    overlaps frame 0's by IoU ≥ 0.8: a static region, not a falling body), or a frame 0 whose
    mask is not the object of frame 2 (see :func:`first_frames_agreement`)."""
    empty = [t for t in range(min(first, masks.shape[0])) if float(masks[t].sum()) == 0]
    if empty:
        raise InputError(
            f"the object's mask is empty in frame {empty[0]}: no object found; {WHAT_TO_GIVE}",
            source=source,
        )
    seen = masks.detach().reshape(masks.shape[0], -1) > 0.5  # [T, H·W]
    found = int(seen.any(1).sum())
    if found < MIN_FOUND * masks.shape[0]:
        raise InputError(
            f"the object is found in only {found} of {masks.shape[0]} frames; {WHAT_TO_GIVE}",
            source=source,
        )
    start = masks[0] > 0.5  # [H, W]
    area = float(start.float().mean())
    if area > MAX_AREA:
        raise InputError(
            f"the object's mask covers {area:.0%} of frame 0: that is background, not one "
            f"object; {WHAT_TO_GIVE}",
            source=source,
        )
    if (start[:, 0].any() and start[:, -1].any()) or (start[0].any() and start[-1].any()):
        raise InputError(
            "the object's mask spans frame 0 from edge to edge: that is background, not one "
            f"object; {WHAT_TO_GIVE}",
            source=source,
        )
    if masks.shape[0] >= 3:
        overlap = float(_overlap_with_first(masks)[1:].min())
        if overlap >= STATIC_IOU:
            raise InputError(
                f"the masked region does not move (every frame overlaps frame 0 by IoU ≥ "
                f"{overlap:.2f}): not a released object; record the release and the fall, or "
                f"{WHAT_TO_GIVE}",
                source=source,
            )
        overlap, ratio = first_frames_agreement(masks)
        if overlap < FIRST_FRAMES_IOU or not 1 / FIRST_FRAMES_AREA <= ratio <= FIRST_FRAMES_AREA:
            raise InputError(
                f"the object's mask in frame 0 is not the one of frame 2 (area ×{ratio:.2f}, "
                f"overlap IoU {overlap:.2f} centred on each other; a falling object changes "
                f"little in 0.06 s): the masks do not find one object; {WHAT_TO_GIVE}",
                source=source,
            )


def check_in_view(
    masks: Tensor,  # [T, H, W]
    source: str,
    start: float = 0.0,  # seconds into the recording of frame 0
    frame_dt: float = 0.03,
    needed: int = 1,  # frames the reader needs (predict's model: 20)
) -> None:
    """Refuse masks empty in a frame after frame 0 (one-line InputError naming ``source``): the
    object leaves the view (rolls out, is hidden) or the masks lose it, and every reader of the
    fall, the landing and the rest needs it in each frame. The refusal names the ``--end`` that
    keeps the frames before it where those are ``needed`` or more."""
    seen = (masks.detach().flatten(1) > 0.5).any(1)  # [T]
    if bool(seen.all()):
        return
    first = int(torch.nonzero(~seen)[0])
    if first >= needed:
        cut = f"cut the recording before it with --end {start + (first - 0.5) * frame_dt:.2f}, "
    else:
        cut = f"too early to cut the recording there (the model reads {needed} frames); "
    raise InputError(
        f"the object's mask is empty from frame {first} ({first * frame_dt:.2f} s after the "
        f"release): the object leaves the view or the masks lose it; {cut}or {WHAT_TO_GIVE}",
        source=source,
    )


# The masks' centroid cannot jump: its second difference between frames, over the object's
# size (√area), was at most 0.86 on 432 reads of this project's validation drops (128 and 384
# px, exact and segmenter masks) and 0.83 on 80 pybullet drops' exact masks (rigid bounces
# included); masks that follow the object's shadow until it comes into view from above jump by
# 2.0 (docs/usage.md "Bad input"). Judged over the first frames, which read the release.
MASKS_JUMP = 1.5
JUMP_FRAMES = 6  # a jump centred on frames 1–5


def masks_jump(masks: Tensor) -> tuple[float, int]:
    """The largest jump of masks [T ≥ 3, H, W] (every frame non-empty), over frames 1 … T − 2:
    the centroid's second difference (px per frame²) over the object's size (√area, the smaller
    of the centre frame's and the next one's), and the frame it is centred on."""
    seen = masks.detach().cpu() > 0.5
    centroid = torch.stack([_pixel_centroid(mask) for mask in seen])  # [T, 2] px (row, column)
    second = (centroid[2:] - 2 * centroid[1:-1] + centroid[:-2]).norm(dim=1)  # [T − 2]
    size = seen.flatten(1).sum(1).double().sqrt()  # [T]
    ratio = second / torch.minimum(size[1:-1], size[2:])
    frame = int(ratio.argmax())
    return float(ratio[frame]), frame + 1


def check_first_frames_track(masks: Tensor, source: str) -> None:
    """Refuse masks [T, H, W] (every frame non-empty) whose centroid jumps in the first frames
    (:func:`masks_jump` over MASKS_JUMP, centred before JUMP_FRAMES): before the jump they follow
    something else — the object's shadow, while the object itself is not yet in view (a release
    above the frame) — and frame 0, the release, is not the object."""
    if masks.shape[0] < 3:
        return
    jump, frame = masks_jump(masks[: JUMP_FRAMES + 1])
    if jump > MASKS_JUMP:
        raise InputError(
            f"the object's mask jumps at frame {frame} (its centroid leaves its track by "
            f"{jump:.1f}× the object's size in one frame; no falling body does): frames 0–"
            f"{frame - 1} follow something else (its shadow while the object is not yet in "
            "view: the release above the frame?); film the release in view, give --start "
            f"SECONDS where the whole object is in view, or {WHAT_TO_GIVE}",
            source=source,
        )


def first_frames_agreement(masks: Tensor) -> tuple[float, float]:
    """How alike frame 0's and frame 2's masks of [T ≥ 3, H, W] are: their IoU with frame 2's
    moved (by whole pixels) so that its centroid is on frame 0's, and the area ratio frame 0 /
    frame 2 (0 and inf for an empty frame 2)."""
    first, later = masks[0].detach() > 0.5, masks[2].detach() > 0.5
    if not first.any() or not later.any():
        return 0.0, (float("inf") if first.any() else 0.0)
    ratio = float(first.sum()) / float(later.sum())
    dy, dx = (round(float(x)) for x in _pixel_centroid(first) - _pixel_centroid(later))
    moved = torch.zeros_like(later)
    height, width = later.shape
    moved[max(0, dy) : height + min(0, dy), max(0, dx) : width + min(0, dx)] = later[
        max(0, -dy) : height + min(0, -dy), max(0, -dx) : width + min(0, -dx)
    ]
    return float((first & moved).sum()) / float((first | moved).sum()), ratio


def first_frames_area_change(masks: Tensor, frames: int = 4) -> float:
    """The largest |log(area_t / area_0)| of masks [T, H, W] over frames 1..frames−1 (inf when
    frame 0 is empty, 0 with one frame): how much the object's mask changes size while it has
    barely moved (see :data:`FIRST_FRAMES_AREA_CHANGE`)."""
    areas = (masks[:frames].detach() > 0.5).reshape(min(frames, masks.shape[0]), -1).sum(1)
    if float(areas[0]) == 0:
        return float("inf")
    return float((areas.double().clamp_min(1) / float(areas[0])).log().abs().max())


def _pixel_centroid(mask: Tensor) -> Tensor:  # [H, W] bool → [2] (row, column)
    return torch.nonzero(mask).double().mean(0)


def _overlap_with_first(masks: Tensor) -> Tensor:  # [T, H, W] → [T] IoU with frame 0's mask
    """Counted on the bounding box of every frame's mask (outside it both are empty: the same
    IoU, a few times less work on a large frame)."""
    seen = masks.detach() > 0.5
    bounds = pixel_bounds(seen.any(0))
    if bounds is not None:
        top, bottom, left, right = bounds
        seen = seen[:, top:bottom, left:right]
    seen = seen.reshape(seen.shape[0], -1)
    inter = (seen & seen[:1]).sum(1).float()
    return inter / (seen | seen[:1]).sum(1).float().clamp_min(1)


def still_frames(masks: Tensor) -> int:
    """How many frames from frame 0 of masks [T, H, W] overlap frame 0's by IoU ≥ STILL_IOU
    (frame 0 included): the object not yet moving."""
    moved = (_overlap_with_first(masks) < STILL_IOU).nonzero()
    return int(moved[0]) if len(moved) else masks.shape[0]


# --start auto: the release is read from the first frames of the flight after a hold, fitted as
# the centroid's row y0 + ½ a (t − t_r)² (a drop from rest; a > 0), or, where that fits clearly
# worse, y0 + v (t − t_r) + ½ a (t − t_r)² (a vertical launch speed v), over the last 3 frames of
# the hold and the first 5 after it, t_r on a grid of a twentieth of a frame.
RELEASE_WINDOW = (3, 5)  # frames before / after the first frame that moved off frame 0's mask
RELEASE_NOISE_PX2 = 0.1  # a mask centroid's squared noise (px²): below it the launch speed is noise
# A hand that opens lets the object go at rest; the fingers it withdraws, in the first frames'
# masks, move the centroid across by a fraction of this (m/s); a throw leaves faster.
RELEASE_ACROSS_M_S = 0.25


@dataclass(frozen=True)
class Release:
    """An object held still, then let go (:func:`read_release`)."""

    time_s: float  # seconds from frame 0 of the masks read
    held_frames: int  # frames still from frame 0 (masks.still_frames)
    across_m_s: float  # the column's speed after the release, m/s (inf: the row not from rest)

    @property
    def from_rest(self) -> bool:
        """Let go from rest: the centroid's row falls from rest at ``time_s`` and its column
        moves across at most RELEASE_ACROSS_M_S."""
        return self.across_m_s <= RELEASE_ACROSS_M_S


def _explained_at_rest(rest: float, launched: float, noise: float) -> bool:
    """A motion at rest (residual ``rest``, px²) explains the masks as well as one with a launch
    speed (``launched``): within twice its residual and the centroid's noise."""
    return math.isfinite(rest) and rest <= 2.0 * launched + noise


def read_release(
    masks: Tensor,
    frame_dt: float,
    pixel: float = 1.0,  # the masks' own pixel in image pixels (calibrate.mask_pixel)
) -> Release | None:
    """The release of an object held still at first (STILL_FRAMES or more frames overlapping
    frame 0's mask [T, H, W] by IoU ≥ STILL_IOU), or None when it is not held (it moves from
    the start) or never moves. The object's centroid row is at rest until t_r, then falls as
    ½ a (t − t_r)² from rest, or as v (t − t_r) + ½ a (t − t_r)² with a vertical launch speed
    where that fits clearly better (a > 0: pixels, rows down): t_r by least squares, to a
    twentieth of a frame. ``from_rest`` when the row falls from rest and the column's speed
    from t_r over the same frames, in metres by the fall's own pixels per metre (a / g), is at
    most RELEASE_ACROSS_M_S: a hold, then a hand that opens (an object thrown leaves the hand
    moving). The centroid's noise
    (RELEASE_NOISE_PX2) is in the masks' own pixels: ``pixel``² image px² each."""
    still = still_frames(masks)
    count = masks.shape[0]
    if still < STILL_FRAMES or still >= count:
        return None
    seen = masks.detach() > 0.5
    rows = seen.sum(2, dtype=torch.float64)  # [T, H] object pixels per row
    cols = seen.sum(1, dtype=torch.float64)  # [T, W] per column
    area = rows.sum(1).clamp_min(1)
    row = rows @ torch.arange(masks.shape[1], dtype=torch.float64) / area  # [T] centroids, px
    col = cols @ torch.arange(masks.shape[2], dtype=torch.float64) / area
    first, last = max(0, still - RELEASE_WINDOW[0]), min(count, still + RELEASE_WINDOW[1])
    times = torch.arange(first, last, dtype=torch.float64) * frame_dt
    moved = row[first:last] - float(row[: still - 2].median())  # [W] pixels from the hold
    candidates = torch.arange(max(0, still - 4) * 20, still * 20 + 1, dtype=torch.float64)
    candidates = candidates * frame_dt / 20  # [C] release times tried
    tau = (times[None] - candidates[:, None]).clamp_min(0)  # [C, W]
    fits = []  # (least residual, its t_r, a): from rest (a), then with a launch speed (v, a)
    for design in (0.5 * tau[..., None] ** 2, torch.stack([tau, 0.5 * tau**2], -1)):
        normal = design.transpose(1, 2) @ design
        normal = normal + 1e-9 * torch.eye(normal.shape[-1], dtype=torch.float64)
        fitted = torch.linalg.solve(normal, design.transpose(1, 2) @ moved[:, None])  # [C, P, 1]
        residual = ((design @ fitted)[..., 0] - moved).pow(2).sum(1)
        residual[fitted[:, -1, 0] <= 0] = math.inf  # it must fall: a > 0
        best = int(residual.argmin())
        fits.append((float(residual[best]), float(candidates[best]), float(fitted[best, -1, 0])))
    (rest, at_rest, accel), (launched, at_launch, _) = fits
    noise = RELEASE_NOISE_PX2 * pixel**2 * len(moved)  # px²
    falls_from_rest = _explained_at_rest(rest, launched, noise)
    if falls_from_rest:  # its release is better pinned
        time_s = at_rest
    elif math.isfinite(launched):
        time_s = at_launch
    else:
        return None
    # across: the column's speed from the release (px/s), in m/s by the fall's pixels per metre
    shifted = col[first:last] - float(col[: still - 2].median())  # [W] pixels from the hold
    since = (times - time_s).clamp_min(0)  # [W] s
    speed = float((since * shifted).sum() / (since**2).sum().clamp_min(1e-12))  # px/s
    per_metre = accel / -GRAVITY[2]  # px/m: the fall's rows a over g
    across = abs(speed) / per_metre if falls_from_rest else math.inf  # m/s
    return Release(time_s, still, across)


def check_release(
    masks: Tensor,
    source: str,
    start: float = 0.0,
    frame_dt: float = 0.03,
    auto: bool = False,  # --start auto was asked and found no release in ``masks``
) -> None:
    """Refuse a recording whose object stays still for STILL_FRAMES or more frames from frame 0
    (frame 0 must be the release; the first 1–2 frames of a fall from rest move less than a
    pixel), saying which ``--start`` would cut it there: about two frames before it moves."""
    still = still_frames(masks)
    if STILL_FRAMES <= still < masks.shape[0]:
        release = start + max(0, still - 2) * frame_dt
        instead = (
            "--start auto found no fall from the hold (the object does not leave it falling)"
            if auto
            else "or --start auto to read it from the fall"
        )
        raise InputError(
            f"the object does not move in frames 0–{still - 1} ({still * frame_dt:.2f} s): frame "
            f"0 must be the release; give --start SECONDS (about {release:.2f} here, the time "
            f"in the recording where it is let go){';' if auto else ','} {instead}",
            source=source,
        )
