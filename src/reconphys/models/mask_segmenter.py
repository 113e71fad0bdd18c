"""The object's masks from the recording itself: a small temporal U-Net
(docs/usage.md#masks-without-a-clean-plate).

For a static camera with no clean plate and a backdrop that is not one colour (a floor, a wall,
shadows), each frame ``F_t`` is segmented from what the whole clip says about the background:
``A`` (the mean of the first two frames: the scene with the object where it was let go),
``Z`` (the median of the last three: the object at rest), ``M`` (the per-pixel median of all
frames). A pixel's own history is ambiguous — a step from one colour to another is an object
arriving (``A`` is background) or leaving (``Z`` is) — so the network also sees the image around
it (the object falls downwards in the image) and the clip time ``t``. Inputs per frame, 16
channels: ``F_t, F_t − A, F_t − Z, F_t − M, A − Z, t/(T−1)``; output: the object's logit per pixel.
Trained on the realistic look's stored masks (``reconphys train-masks``, train/masks.py). The
shipped segmenter is an ensemble of two such networks, trained on different looks
(``reconphys/weights/mask_segmenter.safetensors`` and ``mask_segmenter_2.safetensors``, each with
its ``.json``): their logits are averaged (``SegmenterEnsemble``).
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from ..capture.window import pixel_bounds
from ..errors import InputError
from ..io import atomic_file, read_json
from .mask_colours import colour_refined, near_object

FORMAT = "reconphys.mask_segmenter"
VERSION = 1
INPUT_CHANNELS = 16
_WEIGHTS = Path(__file__).resolve().parent.parent / "weights"
SHIPPED_MASKS_PATHS = (  # the shipped ensemble's members (docs/usage.md#two-networks-averaged)
    _WEIGHTS / "mask_segmenter.safetensors",
    _WEIGHTS / "mask_segmenter_2.safetensors",
)
FRAMES_PER_CALL = 8  # bounds memory at large resolutions
MAX_SIDE = 128  # px: a larger clip is segmented area-averaged down to this, the logits upsampled
MAIN_BLOB_SHARE = 0.2  # regions smaller than this share of the largest are dropped
# Following the object (clip_logits' ``track``; docs/usage.md#following-the-object-2026-11-29):
TRACK_MARGIN = 24  # px of the segmented clip around the object's last box, each side
TRACK_MIN_SIDE = 80  # px: no window smaller (the network trained on 96-px windows)
TRACK_SPAN = 2.0  # a window side is at least this many times the object's (GroupNorm's statistics)
TRACK_QUANTUM = 16  # px: window sides are multiples of this (few shapes; the U-Net's stride)
TRACK_CHUNK = 5  # frames segmented together, each in its own window of one shared size
TRACK_MAX_SHARE = 0.6  # a window over this share of the frame: the whole frame instead
OUTSIDE_LOGIT = -20.0  # the logit of a pixel outside its frame's window: background
# segment_clip's steps after the network, named in the shipped fingerprint (stored masks of
# another rule are stale): "colours-1" the clip's colour model (mask_colours.py, 2026-12-03)
MASKS_RULE = "colours-1"
# How sure the masks are (mask_rating; docs/usage.md#how-sure-the-masks-are): the share of
# pixels within UNSURE_BAND_PX of the masks whose final logit is within ±UNSURE_LOGIT, over the
# masks' area, at the segmented size. On 188 validation clips of four looks (this project's in
# colour and grey, pybullet's and Mitsuba's renders) the masks' IoU with the truth was
# EXPECTED_IOU[0] − EXPECTED_IOU[1] · that share (least squares; Spearman −0.90 over the clips);
# below MASKS_WARN_IOU predict says to check them. The 10–90 % interval is ±1.2816
# EXPECTED_IOU_SD, the spread on a look the line never saw: the RMS error on Mitsuba's validation
# renders of a line fitted on the other looks' clips (0.075; the residual SD over all 188 was
# 0.044, whose interval held the truth on 55 % of Mitsuba's test renders: a user's own video is
# a look no training render had).
UNSURE_LOGIT = 2.0
UNSURE_BAND_PX = 2
EXPECTED_IOU = (1.011, 1.454)
EXPECTED_IOU_SD = 0.075
MASKS_WARN_IOU = 0.8


# bfloat16 is taken where a probe runs it at least this much faster than float32 (below)
BFLOAT16_MIN_GAIN = 1.1
BFLOAT16_ENV = "RECONPHYS_SEGMENTER_BFLOAT16"  # "1" / "0": take it or not, without the probe


@functools.cache
def native_bfloat16() -> bool:
    """Whether the segmenter runs its convolutions in bfloat16 on this CPU: oneDNN must run
    bfloat16 (AVX-512 BF16 or AMX; elsewhere it is emulated, ~3× slower than float32), and a
    probe — a 3×3 convolution of the segmenter's widths, timed both ways once per process — must
    find it :data:`BFLOAT16_MIN_GAIN` times faster: with AVX-512 BF16 but no AMX the segmenter
    ran 1.34× faster in bfloat16 on an AMD EPYC and 1.36× slower on an Intel Xeon
    (docs/benchmarks.md), and the flags cannot tell them apart.
    ``RECONPHYS_SEGMENTER_BFLOAT16`` = 1 / 0 decides instead."""
    chosen = os.environ.get(BFLOAT16_ENV, "").strip()
    if chosen in ("0", "1"):
        return chosen == "1"
    return bfloat16_supported() and _bfloat16_probe() >= BFLOAT16_MIN_GAIN


def bfloat16_supported() -> bool:
    """Whether oneDNN runs bfloat16 convolutions on this CPU at all (AVX-512 BF16 or AMX)."""
    try:
        return bool(
            torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported()
        )
    except (AttributeError, RuntimeError):  # a build without oneDNN or without the query
        return False


def _bfloat16_probe(repeats: int = 3) -> float:
    """float32's time over bfloat16's for a 3×3 convolution, 32 → 32 channels on 8 × 64 × 64
    (channels last, as the segmenter runs): best of ``repeats`` each after a warm-up. Its own
    generator: torch's global random stream is left as it was."""
    import time

    generator = torch.Generator().manual_seed(0)
    weight = torch.randn(32, 32, 3, 3, generator=generator) * 0.05
    weight = weight.to(memory_format=torch.channels_last)
    x = torch.randn(8, 32, 64, 64, generator=generator).to(memory_format=torch.channels_last)
    best = {}
    with torch.no_grad():
        for bfloat16 in (False, True):
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bfloat16):
                F.conv2d(x, weight, padding=1)
                seconds = []
                for _ in range(repeats):
                    started = time.perf_counter()
                    F.conv2d(x, weight, padding=1)
                    seconds.append(time.perf_counter() - started)
            best[bfloat16] = min(seconds)
    return best[False] / max(best[True], 1e-9)


@dataclass(frozen=True)
class SegmenterConfig:
    channels: tuple[int, ...] = (24, 32, 48, 64)  # per level; the deepest is dilated (context)
    groups: int = 4  # GroupNorm groups

    @staticmethod
    def from_dict(data: dict) -> SegmenterConfig:
        return SegmenterConfig(channels=tuple(data["channels"]), groups=int(data["groups"]))


def _block(inputs: int, outputs: int, groups: int, dilation: int = 1) -> nn.Sequential:
    conv = lambda i, o: nn.Conv2d(i, o, 3, padding=dilation, dilation=dilation)  # noqa: E731
    return nn.Sequential(
        conv(inputs, outputs),
        nn.GroupNorm(groups, outputs),
        nn.ReLU(inplace=True),
        conv(outputs, outputs),
        nn.GroupNorm(groups, outputs),
        nn.ReLU(inplace=True),
    )


class MaskSegmenter(nn.Module):
    """U-Net over 16 input channels ([B, 16, H, W], any H, W) → object logits [B, H, W]."""

    def __init__(self, config: SegmenterConfig = SegmenterConfig()):
        super().__init__()
        self.config = config
        c, g = config.channels, config.groups
        levels = len(c)
        self.down = nn.ModuleList(
            _block(INPUT_CHANNELS if i == 0 else c[i - 1], c[i], g, 2 if i == levels - 1 else 1)
            for i in range(levels)
        )
        self.up = nn.ModuleList(_block(c[i + 1] + c[i], c[i], g) for i in range(levels - 1))
        self.head = nn.Conv2d(c[0], 1, 1)
        self.stride = 2 ** (levels - 1)

    def forward(self, x: Tensor) -> Tensor:
        height, width = x.shape[-2:]
        x = F.pad(x, (0, (-width) % self.stride, 0, (-height) % self.stride), mode="replicate")
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        for i in reversed(range(len(self.up))):
            skip = skips[i]
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = self.up[i](torch.cat([x, skip], 1))
        return self.head(x)[:, 0, :height, :width]


class SegmenterEnsemble(nn.Module):
    """Networks read as one: the mean of the members' logits [B, H, W] for [B, 16, H, W]."""

    def __init__(self, members: list[MaskSegmenter]):
        super().__init__()
        if not members:
            raise ValueError("an ensemble needs at least one member")
        self.members = nn.ModuleList(members)

    def forward(self, x: Tensor) -> Tensor:
        return torch.stack([member(x).float() for member in self.members]).mean(0)


Segmenter = MaskSegmenter | SegmenterEnsemble


def clip_references(frames: Tensor) -> Tensor:  # [T, H, W, 3] in [0, 1] → [3, 3, H, W]
    """``A`` (mean of frames 0–1), ``Z`` (median of the last three), ``M`` (median of all),
    channels first."""
    first = frames[:2].mean(0)
    last = frames[-3:].median(0).values
    middle = frames.median(0).values
    return torch.stack([first, last, middle]).permute(0, 3, 1, 2)


def frame_inputs(
    frames: Tensor,  # [t, H, W, 3] in [0, 1]: some frames of the clip
    references: Tensor,  # [3, 3, H, W] from clip_references
    times: Tensor,  # [t] clip time of each frame in [0, 1]
) -> Tensor:  # [t, 16, H, W]
    f = frames.permute(0, 3, 1, 2)
    first, last, middle = references
    time = times[:, None, None, None].to(f).expand(-1, 1, *f.shape[-2:])
    return torch.cat([f, f - first, f - last, f - middle, (first - last).expand_as(f), time], 1)


@torch.no_grad()
def clip_logits(
    model: Segmenter,
    frames: Tensor,
    max_side: int = MAX_SIDE,
    channels_last: bool = True,
    bfloat16: bool | None = None,
    track: bool = True,
    colours: bool = False,
) -> Tensor:
    """Object logits [T, H, W] of a clip [T, H, W, 3] in [0, 1] (T ≥ 3, static camera).

    The network saw 96-px clips: its receptive field spans an object there, not in a phone's
    1080p frame. A clip whose longer side exceeds ``max_side`` is segmented area-averaged down
    to it and the logits are resampled (bilinear) to the clip's size (docs/usage.md).

    ``track`` (the default) segments frames 0–1 whole to find the object, then every frame (0–1
    again) in a window around where the object's last two frames put it (:func:`tracked_logits`:
    2–3× less work on a 128-px clip; pixels outside a window are background); a frame whose
    object leaves its window, or is not found in it, is segmented whole. Not the same
    arithmetic: GroupNorm's statistics are the window's, so the masks differ from the whole
    frame's (``track=False``, the reference twin) at their edges — IoU 0.97 between the two on
    average over 40 test drops, as close to the truth; up to a seventh of the area on a clip
    where the object meets its shadow — measured in docs/usage.md and compared by a test.
    A clip too small for a window smaller than TRACK_MAX_SHARE of it is segmented whole.

    ``channels_last`` (the fast path) hands the network its inputs pixel-major ([B, H, W, C] in
    memory), the layout the CPU's convolutions run fastest in: the same arithmetic summed in
    another order (logits within ~1e-4 of the reference layout, ``channels_last=False``; a test
    compares them), 1.4–1.7× faster on a 2-core CPU.

    ``bfloat16`` (the second fast path; None: on a CPU that runs it natively, native_bfloat16)
    runs the networks under bfloat16 autocast, the logits returned in float32: the networks 1.8×
    faster again where the CPU has AVX-512 BF16, the logits within ~0.2 of float32's and about
    2 pixels in 10⁵ on the other side of 0 on realistic clips (a test compares them with
    ``bfloat16=False``, the reference twin; docs/usage.md#the-segmenter-in-bfloat16-2026-11-29).

    ``colours`` adds the clip's own colour model's logit near the object (mask_colours.py; at
    the segmented size, before any resampling): what segment_clip does by default.
    """
    frames = _checked(frames)
    height, width = frames.shape[1:3]
    if max(height, width) > max_side:
        small = segmented_size(frames, max_side)
        logits = clip_logits(model, small, max_side, channels_last, bfloat16, track, colours)
        return F.interpolate(logits[:, None], size=(height, width), mode="bilinear")[:, 0]
    references = clip_references(frames)
    times = torch.linspace(0, 1, frames.shape[0])
    layout = torch.channels_last if channels_last else torch.contiguous_format
    if bfloat16 is None:  # the CPU's fast path; on a GPU the networks stay in float32
        bfloat16 = frames.device.type == "cpu" and native_bfloat16()

    def run(indices: list[int], window: Box | list[Box] | None = None) -> Tensor:
        """Logits [n, h, w] of frames ``indices``, each in its window (one size) or whole."""
        windows = window if isinstance(window, list) else [window] * len(indices)
        inputs = []
        for index, box in zip(indices, windows, strict=True):
            rows, cols = (slice(None), slice(None)) if box is None else box.slices()
            inputs.append(
                frame_inputs(
                    frames[index : index + 1, rows, cols],
                    references[..., rows, cols],
                    times[index : index + 1],
                )
            )
        inputs = torch.cat(inputs).contiguous(memory_format=layout)
        with torch.autocast(frames.device.type, dtype=torch.bfloat16, enabled=bfloat16):
            return model(inputs).float()

    if track:
        logits = tracked_logits(run, frames.shape[0], height, width, frames.device)
    else:
        logits = torch.cat(
            [
                run(list(range(start, min(start + FRAMES_PER_CALL, frames.shape[0]))))
                for start in range(0, frames.shape[0], FRAMES_PER_CALL)
            ]
        ).contiguous()
    if colours:
        logits = colour_refined(logits, frames, references, keep_main_blob(logits > 0))
    return logits


@dataclass(frozen=True)
class Box:
    """Rows [top, bottom) and columns [left, right) of a frame, in pixels."""

    top: int
    bottom: int
    left: int
    right: int

    def slices(self) -> tuple[slice, slice]:
        return slice(self.top, self.bottom), slice(self.left, self.right)

    @property
    def centre(self) -> tuple[float, float]:
        return (self.top + self.bottom) / 2, (self.left + self.right) / 2

    def shifted(self, rows: int, cols: int) -> Box:
        return Box(self.top + rows, self.bottom + rows, self.left + cols, self.right + cols)

    @staticmethod
    def of(mask: Tensor) -> Box | None:
        """The bounding box of a mask [H, W] bool; None when it is empty."""
        bounds = pixel_bounds(mask)
        return None if bounds is None else Box(*bounds)


def _window_side(extent: int, frame: int) -> int:
    """A window side (px) holding ``extent`` px and the margins, within a ``frame``-px side."""
    side = max(extent + 2 * TRACK_MARGIN, math.ceil(TRACK_SPAN * extent), TRACK_MIN_SIDE)
    return min(-(-side // TRACK_QUANTUM) * TRACK_QUANTUM, frame)


def _placed(centre: float, side: int, frame: int) -> tuple[int, int]:
    start = min(max(round(centre - side / 2), 0), frame - side)
    return start, start + side


def tracked_logits(
    run: Callable[..., Tensor],
    frames: int,
    height: int,
    width: int,
    device: torch.device | str = "cpu",
) -> Tensor:
    """Logits [T, H, W] of a clip segmented in windows that follow the object (clip_logits'
    ``track``). ``run(indices, window)`` segments frames: whole (window None) or each in its
    window. Frames 0–1 are segmented whole to find the object, then again each in a window about
    its box (one size, as below), so that a held object's masks do not change where the windows
    begin (the window's GroupNorm statistics move its edges: frame 2 would differ from frames 0–1
    as if the object had moved); then TRACK_CHUNK frames at a time, each in a window of the last
    found box's size plus TRACK_MARGIN a side (at least TRACK_MIN_SIDE and TRACK_SPAN times the
    box), centred where the last two boxes' motion carries it. A frame
    whose object (its main blob) is not in its window or touches an edge of it that is not the
    frame's is segmented whole again. The logits are on ``device`` (``run``'s)."""
    logits = torch.full((frames, height, width), OUTSIDE_LOGIT, device=device)
    boxes: list[Box | None] = [None] * frames

    def found(index: int, values: Tensor, box: Box | None) -> bool:
        """Keep frame ``index``'s logits ``values`` (of ``box``, None: whole) if the object is
        inside; its box is then recorded."""
        blob = keep_main_blob((values > 0)[None])[0]
        inner = Box.of(blob)
        if box is not None:
            if inner is None:
                return False
            edges = (
                (inner.top == 0 and box.top > 0)
                or (inner.bottom == box.bottom - box.top and box.bottom < height)
                or (inner.left == 0 and box.left > 0)
                or (inner.right == box.right - box.left and box.right < width)
            )
            if edges:
                return False
            inner = inner.shifted(box.top, box.left)
            logits[index][box.slices()] = values
        else:
            logits[index] = values
        boxes[index] = inner
        return True

    def whole(indices: list[int]) -> None:
        for start in range(0, len(indices), FRAMES_PER_CALL):
            part = indices[start : start + FRAMES_PER_CALL]
            for index, values in zip(part, run(part), strict=True):
                found(index, values, None)

    start = min(2, frames)
    whole(list(range(start)))
    first = _first_windows(boxes[:start], height, width)
    if first is not None:  # frames 0–1 again, in windows as every later frame is segmented
        again = run(list(range(start)), first)
        for index, values, box in zip(range(start), again, first, strict=True):
            kept = logits[index].clone()
            logits[index].fill_(OUTSIDE_LOGIT)
            if not found(index, values, box):
                logits[index] = kept
    while start < frames:
        chunk = list(range(start, min(start + TRACK_CHUNK, frames)))
        windows = _chunk_windows(
            boxes[start - 2] if start >= 2 else None, boxes[start - 1], len(chunk), height, width
        )
        if windows is None:
            whole(chunk)
        else:
            values = run(chunk, windows)
            missed = [
                i for i, v, w in zip(chunk, values, windows, strict=True) if not found(i, v, w)
            ]
            whole(missed)
        start = chunk[-1] + 1
    return logits


def _chunk_windows(
    before: Box | None, last: Box | None, count: int, height: int, width: int
) -> list[Box] | None:
    """Windows (one size) for the ``count`` frames after the one whose object box is ``last``
    (``before``: the box a frame earlier), or None when the whole frame should be segmented: no
    box, or a window over TRACK_MAX_SHARE of the frame."""
    if last is None:
        return None
    rows = _window_side(last.bottom - last.top, height)
    cols = _window_side(last.right - last.left, width)
    if rows * cols > TRACK_MAX_SHARE * height * width:
        return None
    (y, x), (dy, dx) = last.centre, (0.0, 0.0)
    if before is not None:
        dy, dx = y - before.centre[0], x - before.centre[1]
    windows = []
    for step in range(1, count + 1):
        top, bottom = _placed(y + step * dy, rows, height)
        left, right = _placed(x + step * dx, cols, width)
        windows.append(Box(top, bottom, left, right))
    return windows


def _first_windows(boxes: list[Box | None], height: int, width: int) -> list[Box] | None:
    """Windows (one size: the last box's, as :func:`_chunk_windows` sizes them) about each of
    the first frames' own object boxes, or None when a box is missing or the window would be
    the whole frame."""
    if not boxes or any(box is None for box in boxes):
        return None
    sized = _chunk_windows(None, boxes[-1], 1, height, width)
    if sized is None:
        return None
    rows, cols = sized[0].bottom - sized[0].top, sized[0].right - sized[0].left
    windows = []
    for box in boxes:
        (y, x) = box.centre
        top, bottom = _placed(y, rows, height)
        left, right = _placed(x, cols, width)
        windows.append(Box(top, bottom, left, right))
    return windows


def _checked(frames: Tensor) -> Tensor:  # [T ≥ 3, H, W, 3] as float32, else ValueError
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] < 3:
        raise ValueError(f"frames: expected [T ≥ 3, H, W, 3], got {list(frames.shape)}")
    return frames.float()


def segmented_size(frames: Tensor, max_side: int = MAX_SIDE) -> Tensor:
    """A clip [T, H, W, 3] area-averaged to at most ``max_side`` px a side (as it is segmented);
    unchanged when it fits."""
    height, width = frames.shape[1:3]
    if max(height, width) <= max_side:
        return frames
    factor = max_side / max(height, width)
    size = (max(1, round(height * factor)), max(1, round(width * factor)))
    return F.interpolate(frames.permute(0, 3, 1, 2), size=size, mode="area").permute(0, 2, 3, 1)


def segment_clip(
    model: Segmenter,
    frames: Tensor,
    max_side: int = MAX_SIDE,
    bfloat16: bool | None = None,
    track: bool = True,
    colours: bool = True,
) -> Tensor:
    """Masks [T, H, W] in {0, 1} of a clip [T, H, W, 3] in [0, 1] (T ≥ 3, static camera): logits
    above 0 (of the clip at most ``max_side`` px; ``bfloat16``, ``track``, ``colours``: see
    clip_logits; ``colours=False`` is the network's alone), the main blob kept."""
    return rated_segment_clip(model, frames, max_side, bfloat16, track, colours)[0]


def rated_segment_clip(
    model: Segmenter,
    frames: Tensor,
    max_side: int = MAX_SIDE,
    bfloat16: bool | None = None,
    track: bool = True,
    colours: bool = True,
) -> tuple[Tensor, dict]:
    """segment_clip's masks [T, H, W] and how sure they are (:func:`mask_rating`, at the
    segmented size: what its numbers were fitted on), with ``segmented_size`` [width, height]:
    the size the masks were read at (their pixel error is a pixel there)."""
    frames = _checked(frames)
    small = segmented_size(frames, max_side)
    logits = clip_logits(model, small, max_side, bfloat16=bfloat16, track=track, colours=colours)
    masks = keep_main_blob(logits > 0)
    rating = {**mask_rating(logits, masks), "segmented_size": [small.shape[2], small.shape[1]]}
    if small.shape != frames.shape:  # clip_logits' own resampling of a large clip
        size = frames.shape[1:3]
        logits = F.interpolate(logits[:, None], size=size, mode="bilinear")[:, 0]
        masks = keep_main_blob(logits > 0)
    return masks.float(), rating


def mask_rating(
    logits: Tensor,  # [T, H, W] the segmenter's final logits (the colours' look included)
    masks: Tensor,  # [T, H, W] bool: keep_main_blob(logits > 0)
) -> dict:
    """How sure the masks are: ``unsure_share`` (pixels within UNSURE_BAND_PX of the masks whose
    |logit| < UNSURE_LOGIT, over the masks' area), the mask IoU with the object it predicts
    (``expected_iou``, EXPECTED_IOU's line, clamped to [0, 1]) and that IoU's 10–90 % interval
    (± 1.2816 EXPECTED_IOU_SD); ``warning`` below MASKS_WARN_IOU."""
    band = near_object(masks.cpu(), UNSURE_BAND_PX)
    unsure = (logits.cpu().abs() < UNSURE_LOGIT) & band
    share = float(unsure.sum()) / float(masks.sum()) if masks.any() else math.inf  # no object
    expected = min(max(EXPECTED_IOU[0] - EXPECTED_IOU[1] * share, 0.0), 1.0)
    spread = 1.2816 * EXPECTED_IOU_SD
    rating = {
        "unsure_share": round(share, 4) if math.isfinite(share) else None,
        "expected_iou": round(expected, 3),
        "expected_iou_10_90": [
            round(max(expected - spread, 0.0), 3),
            round(min(expected + spread, 1.0), 3),
        ],
    }
    if expected < MASKS_WARN_IOU:
        rating["warning"] = (
            f"the mask segmenter is unsure of this recording's masks (their IoU with the object "
            f"is expected near {expected:.2f}): look at the outline in preview.mp4, and give masks "
            "from a segmentation tool (--masks DIR) if it misses the object or takes in its "
            "shadow"
        )
    return rating


def keep_main_blob(masks: Tensor, share: float = MAIN_BLOB_SHARE) -> Tensor:
    """Per frame [T, H, W] bool, keep the connected regions (8-neighbourhood) at least ``share``
    of the largest one's size: one object, maybe in pieces (a thin link seen edge-on), without
    the specks and strips (a horizon, a shadow's edge) the network marks elsewhere."""
    from scipy import ndimage

    kept = []
    for mask in masks.cpu().numpy():
        rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
        if len(rows):  # labelled on the mask's bounding box: the same regions, less work
            box = np.s_[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
            labels, count = ndimage.label(mask[box], structure=np.ones((3, 3)))
            if count > 1:
                sizes = np.bincount(labels.ravel())[1:]
                mask = mask.copy()
                mask[box] = np.isin(labels, 1 + np.nonzero(sizes >= share * sizes.max())[0])
        kept.append(torch.from_numpy(mask))
    return torch.stack(kept).to(masks.device)


def shipped_fingerprint(path: str | os.PathLike | None = None) -> str:
    """The first 16 hex digits of the SHA-256 of a segmenter's weights (default: the shipped
    ensemble's members' weights, one after the other, then MASKS_RULE: stored masks of an
    earlier rule are not taken for segment_clip's)."""
    import hashlib

    paths = SHIPPED_MASKS_PATHS if path is None else (Path(path),)
    digest = hashlib.sha256()
    for member in paths:
        digest.update(member.read_bytes())
    if path is None:
        digest.update(MASKS_RULE.encode())
    return digest.hexdigest()[:16]


def save_mask_segmenter(model: MaskSegmenter, path: str | os.PathLike, training: dict) -> Path:
    """Weights (safetensors) + ``NAME.json`` (config and how it was trained), atomically."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().float().cpu().contiguous() for k, v in model.state_dict().items()}
    with atomic_file(path) as tmp:
        save_file(tensors, str(tmp), {"format": FORMAT})
    config = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(model.config).items()}
    metadata = {"format": FORMAT, "version": VERSION, "segmenter": config, "training": training}
    with atomic_file(path.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(metadata, indent=1) + "\n")
    return path


def load_mask_segmenter(
    path: str | os.PathLike | list | tuple | None = None,
) -> Segmenter:
    """The segmenter at ``path`` (a .safetensors file or a ``train-masks`` OUT folder), the
    ensemble of several such paths (a list or tuple), or by default the shipped ensemble; in eval
    mode. InputError naming the file when one is missing or corrupt."""
    if path is None or isinstance(path, (list, tuple)):
        members = SHIPPED_MASKS_PATHS if path is None else path
        return SegmenterEnsemble([_load_one(member) for member in members]).eval()
    return _load_one(path)


def _load_one(path: str | os.PathLike) -> MaskSegmenter:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    path = Path(path)
    if path.is_dir():
        path = path / "model.safetensors"
    json_path = path.with_suffix(".json")
    if not path.is_file() or not json_path.is_file():
        raise InputError(
            "mask segmenter not found (weights + .json; train one with `reconphys train-masks`)",
            source=str(path),
        )
    metadata = read_json(json_path, FORMAT, VERSION)
    try:
        model = MaskSegmenter(SegmenterConfig.from_dict(metadata["segmenter"]))
        model.load_state_dict(load_file(str(path)))
    except (KeyError, TypeError, ValueError, RuntimeError, SafetensorError, OSError) as e:
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"cannot load the mask segmenter ({message})", source=str(path)) from None
    return model.eval()
