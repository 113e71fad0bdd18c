"""Everything ``predict`` reads from the user's input, in one object.

INPUT is one of:

- a video file (mp4/mov/avi/mkv/webm/gif): decoded, its frame rate from the file (or ``fps``);
- a folder of frame images (png/jpg/...): frame rate ``fps`` (default ``1 / frame_dt``).

A dataset sample (its stored frames, camera and truth) is read by
:func:`reconphys.pipeline.samples.load_sample`; :func:`stored_observation` wraps its frames.

Frames are resampled in time to ``frame_dt`` (a recorded frame where one falls on the time, else
made between the two nearest: :mod:`.interpolate`) from ``start`` seconds into
the recording (the release: frame 0; the frames before it are dropped) to ``end``, masked
(background set to black, as in the synthetic renders the models were trained on) and kept at
their size. The frames before the start are read for one thing: an object held still there,
then let go (``start="auto"``: the release read from the hold; a start given: the hold before
it, :func:`_release_before`), which ``Observation.release`` holds.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from .calibrate import (
    FALL_FIT_PX,
    SEGMENTER_FALL_FIT_PX,
    check_camera_file,
    estimate_camera,
    mask_pixel,
)
from .camera import CameraSpec, default_camera, read_camera, read_intrinsics
from .interpolate import frames_between
from .lens import recording_fov
from .masks import (
    STILL_FRAMES,
    Release,
    alpha_masks,
    backdrop_colour,
    border_is_uniform,
    check_first_frames_track,
    check_in_view,
    check_masks,
    check_release,
    read_background,
    read_mask_folder,
    read_release,
    subtract_background,
)
from .stabilize import MAX_SHAKE_SHARE, Shake, crop_margin, read_shake, steady
from .video import (
    VIDEO_SUFFIXES,
    WORK_MAX_SIDE,
    hdr_transfer,
    read_focal_35mm,
    read_frame_folder,
    read_video,
    resample_between,
    resample_times,
    slow_motion_rate,
)

DATASET_CAMERA = "dataset"  # --camera dataset: the dataset's view 0 (docs/design.md#conventions)
AUTO_START = "auto"  # --start auto: the release read from the masks (masks.read_release)
CLIP_FRAMES = 30  # frames read from the release when no end is given: the data's clips (0.87 s)
AUTO_SEARCH_S = 10.0  # --start auto looks for the release in this many seconds from the start
AUTO_MAX_SIDE = 256  # ... at most this many pixels a side (only the masks' centroids are read)
# --start SECONDS: the hold before it is read from the masks of the clip read again from up to
# this many frames before the start (masks.read_release needs STILL_FRAMES still ones), and
# counts where its release lies within GIVEN_RELEASE_SLACK_FRAMES of the start given (a user
# scrubbing to the release is a frame or two off; further, the start is not this release)
HOLD_LOOKBACK_FRAMES = 10
GIVEN_RELEASE_SLACK_FRAMES = 3


@dataclass
class Observation:
    """The recording as the models read it."""

    frames: Tensor  # [T, H, W, 3] float32 in [0, 1], background black
    masks: Tensor  # [T, H, W] float32 in {0, 1}
    camera: CameraSpec  # at (W, H)
    frame_dt: float  # seconds between frames (after resampling)
    source: str  # what was read
    mask_source: str  # where the masks came from
    recorded_fps: float | None = None  # the file's frame rate (None: not stored / not a video)
    recorded_frames: int = 0  # frames before resampling
    camera_estimate: dict | None = None  # how the camera was read from the video (no file)
    black_backdrop: bool = False  # the object on black, as the plain look of our data
    recording: Tensor | None = None  # [T, H, W, 3] the frames before masking (None: = frames)
    fall_fit_px: float = FALL_FIT_PX  # the masks' pixel error, for reading the fall (calibrate)
    start_s: float = 0.0  # seconds into the recording of frame 0 (given, or read: --start auto)
    time_resampling: str = "the recorded frames"  # how frames at frame_dt were made (video.py)
    recorded_size: tuple[int, int] | None = None  # (width, height) as filmed (None: = size)
    camera_shake: dict | None = None  # the camera's shake read and taken out (stabilize.py)
    mask_rating: dict | None = None  # how sure the segmenter is of its masks (None: not segmented)
    hdr: str | None = None  # an HDR video's transfer curve ("HLG", "PQ"), read as SDR; None: SDR
    # the hold and the release read (--start auto; or before a --start SECONDS), its time_s in
    # seconds into the recording (None: no hold read)
    release: Release | None = None

    @property
    def unmasked(self) -> Tensor:  # [T, H, W, 3] what was recorded, background included
        return self.frames if self.recording is None else self.recording

    @property
    def plain_look(self) -> bool:
        """The object on a black backdrop and a camera that was given, not estimated: what the
        plain look of our data shows (models/shipped.model_for_recording)."""
        return self.black_backdrop and self.camera_estimate is None

    @property
    def num_frames(self) -> int:
        return self.frames.shape[0]

    @property
    def size(self) -> tuple[int, int]:  # (width, height)
        return self.frames.shape[2], self.frames.shape[1]


def stored_observation(
    frames: Tensor,  # [T, H, W, 3] in [0, 1], black background (a dataset view)
    K: Tensor,  # [3, 3] pixels at (W, H)
    world_to_cam: Tensor,  # [4, 4]
    frame_dt: float,
    source: str,
    masks: Tensor | None = None,  # [T, H, W] in {0, 1}; None: the black backdrop subtracted
    mask_source: str | None = None,
    fall_fit_px: float = FALL_FIT_PX,  # the masks' pixel error (SEGMENTER_FALL_FIT_PX: segmented)
    mask_rating: dict | None = None,  # how sure a segmenter is of ``masks``
) -> Observation:
    """An observation of frames already in memory (a dataset view, ground z = 0): on a black
    backdrop, or with ``masks`` from elsewhere (a realistic scene), checked as any recording's."""
    height, width = frames.shape[1:3]
    camera = CameraSpec(K.double(), world_to_cam.double(), width, height, 0.0, source)
    black, recording = masks is None, frames
    if black:  # the frames are already object-on-black
        masks = subtract_background(frames)
        mask_source = "background subtraction (black backdrop)"
    else:
        check_masks(masks, source)
        frames = frames * masks[..., None]
    return Observation(
        recording=recording,
        frames=frames,
        masks=masks,
        camera=camera,
        frame_dt=frame_dt,
        source=source,
        mask_source=mask_source,
        recorded_frames=frames.shape[0],
        black_backdrop=black,
        fall_fit_px=fall_fit_px,
        mask_rating=mask_rating,
    )


BLACK_LEVEL = 0.05  # a border colour whose channels all stay below this is a black backdrop


# The border colour's masks must be one object: in each of frames 0–2 the largest connected
# region (8-neighbourhood) holds at least this share of the mask's pixels. Every clip of 20
# plain drops (4 views, 64 px) and the tests' procedural ones: 1.0; the four realistic clips
# whose grey floor passed for a backdrop (a floor patch larger than the object): 0.56–0.83
# (docs/usage.md#the-acceptance-run)
MIN_MAIN_REGION_SHARE = 0.9


def _plausible(masks: Tensor) -> bool:
    """Whether the border colour's masks (of a one-colour border) can stand: masks that pass
    :func:`check_masks` and show one object in the first frames (:data:`MIN_MAIN_REGION_SHARE`;
    a floor near the border's colour makes a one-colour border, not these)."""
    try:
        check_masks(masks, "border colour")
    except InputError:
        return False
    return all(main_region_share(mask) >= MIN_MAIN_REGION_SHARE for mask in masks[:3])


def segmented_pixel(masks: Tensor, rating: dict | None) -> float:
    """How many pixels of ``masks`` [T, H, W] one pixel spans at the size they were segmented at
    (the rating's ``segmented_size``, [width, height]; 1 without it): the segmenter's masks are
    right to about a pixel there, so the fall is read to that many of their own pixels (a phone's
    1080p clip is read at 640 px and segmented at 128: 5)."""
    size = (rating or {}).get("segmented_size")
    if not size:
        return 1.0
    return max(1.0, masks.shape[2] / size[0], masks.shape[1] / size[1])


def main_region_share(mask: Tensor) -> float:  # [H, W] → share in [0, 1]; 0 when empty
    """The share of a mask's pixels in its largest connected region (8-neighbourhood)."""
    from scipy import ndimage

    labels, count = ndimage.label(mask.detach().cpu().numpy() > 0.5, structure=np.ones((3, 3)))
    if count == 0:
        return 0.0
    sizes = np.bincount(labels.ravel())[1:]
    return float(sizes.max() / sizes.sum())


def too_short(count: int, frame_dt: float, needed: int) -> str:
    """The refusal of a recording with ``count`` frames at ``frame_dt`` s where ``needed`` are
    read."""
    return (
        f"{count} frames at {frame_dt} s after resampling; the model reads {needed} "
        f"({(needed - 1) * frame_dt:.2f} s of video from the release): give a longer "
        "recording, or a later --end"
    )


# Frame 0 darker than this share of the clip's median brightness is not the release: a fade-in
# or a cut before the clip (the fall read from it is wrong, and frame 0 gives the asset its
# colours). A phone's exposure settling at the start changes far less.
FADE_IN_SHARE = 0.5


def check_fade_in(brightness: np.ndarray, source: str, start: float, frame_dt: float) -> None:
    """Refuse a clip whose frame 0 is dark against the rest (``brightness`` [T], each frame's
    mean, frames at ``frame_dt`` from ``start`` seconds into the recording): a fade-in or a black
    frame before the clip. The refusal names the --start of its first frame at 90 % of the
    median brightness or more."""
    usual = float(np.median(brightness))
    if not usual > 0 or brightness[0] >= FADE_IN_SHARE * usual:
        return
    bright = np.nonzero(brightness >= 0.9 * usual)[0]
    after = f"--start {start + bright[0] * frame_dt:.2f} (its first frame at full brightness)"
    raise InputError(
        f"frame 0 is dark against the rest of the clip ({brightness[0] / usual:.0%} of its "
        f"median brightness): a fade-in or a cut before it, not the release; give {after} or "
        "--start SECONDS at the release",
        source=source,
    )


class _Decoded(NamedTuple):
    """A stretch of the recording decoded (:func:`_decode`)."""

    raw: np.ndarray  # [T, H, W, 3|4] uint8, at most the read's side
    recorded_fps: float | None
    times: np.ndarray | None  # a GIF's display times [T + 1], seconds
    recorded_size: tuple[int, int]  # (width, height) as filmed
    stamps: np.ndarray | None  # a variable-rate video's frame times [T], seconds
    slowed: tuple[float, float] | None  # slow motion: (filmed at, plays at) fps
    hdr: str | None  # an HDR video's curve, read as SDR
    fps: float | None  # the rate to read it at (given, or slow motion's filmed rate)


@dataclass
class _Clip:
    """A stretch of the recording at frame_dt, masked: what :func:`_read_clip` read."""

    rgb: Tensor  # [T, H, W, 3] in [0, 1] (steadied, cropped by ``margin``)
    masks: Tensor  # [T, H, W] in {0, 1}
    objects: Tensor  # [T, H, W, 3] the object on black
    mask_source: str
    fit_px: float  # the masks' pixel error (calibrate)
    rating: dict | None  # how sure the segmenter is (None: not segmented)
    black: bool  # a black backdrop (the plain look)
    shake: Shake
    margin: int  # pixels cropped off each side (the shake taken out)
    read_fov: float | None  # vertical, of the cropped frame (None: a camera file gives it)
    fov_from: str
    time_resampling: str
    decoded: _Decoded  # the recording as decoded (also for another read of the same stretch)


def _decode(
    path: Path,
    *,
    masks: str | os.PathLike | None,
    fps: float | None,
    frame_dt: float,
    read_end: float,
    side: int,
) -> _Decoded:
    """The recording decoded up to ``read_end`` (all of it with a mask folder, which must match
    it frame for frame), at most ``side`` pixels a side: video.read_video's, or a frame
    folder's."""
    until = None if masks is not None else read_end
    times = stamps = slowed = hdr = None
    if path.is_dir():
        count = None if until is None else math.ceil(until * (fps or 1.0 / frame_dt)) + 1
        (raw, recorded_size), recorded_fps = read_frame_folder(path, count, side), None
    elif path.suffix.lower() in VIDEO_SUFFIXES:
        slowed = None if fps else slow_motion_rate(path)  # (filmed at, plays at) fps
        if slowed is not None:  # the phone's slow motion: read at the rate it filmed at
            fps = slowed[0]
            until = None if until is None else until * slowed[0] / slowed[1]
        raw, recorded_fps, times, recorded_size, stamps = read_video(
            path, None if fps and slowed is None else until, side
        )
        hdr = hdr_transfer(path)  # read as SDR by read_video (video.hdr_to_sdr_filter)
    else:
        raise InputError(
            f"expected a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of frames",
            source=str(path),
        )
    return _Decoded(raw, recorded_fps, times, recorded_size, stamps, slowed, hdr, fps)


def _read_clip(
    path: Path,
    *,
    masks: str | os.PathLike | None,
    background: str | os.PathLike | None,
    camera: str | os.PathLike | None,
    fov_deg: float | None,
    fps: float | None,
    frame_dt: float,
    start: float,  # seconds into the recording of frame 0
    read_end: float,  # seconds into the recording: no frame after it
    side: int,  # decoded at most this many pixels a side
    segment: Callable[[Tensor], Tensor | tuple[Tensor, dict]] | None,
    min_frames: int,
    decoded: _Decoded | None = None,  # the same read_end's and side's (None: decoded here)
) -> _Clip:
    """The frames from ``start`` to ``read_end`` at ``frame_dt``, steadied and masked
    (load_observation's reading, before the release and the camera are read)."""
    if decoded is None:
        decoded = _decode(
            path, masks=masks, fps=fps, frame_dt=frame_dt, read_end=read_end, side=side
        )
    raw, recorded_fps, times, recorded_size, stamps, slowed, _, fps = decoded
    if times is not None and fps is None:  # variable frame rate (GIF): the display times
        before = resample_times(times, frame_dt, start, read_end)
        after, weight = before, np.zeros(len(before))
    else:  # between two recorded frames where the rates differ (30 fps: interpolate.py)
        rate = fps or recorded_fps or 1.0 / frame_dt
        stamps = None if fps else stamps  # a variable-rate video: each frame at its own time
        before, after, weight = resample_between(
            raw.shape[0], rate, frame_dt, start, read_end, stamps
        )
    if len(before) < min_frames:
        raise InputError(too_short(len(before), frame_dt, min_frames), source=str(path))
    between = weight > 0
    # the recorded frames used: each wanted one's, or the pairs it lies between
    picks = np.unique(np.concatenate([before, after])) if between.any() else before
    height, width = raw.shape[1:3]
    black = False  # the object on a black backdrop (the plain look): read from the border below
    if masks is not None:
        all_masks = read_mask_folder(masks, raw.shape[0], height, width)
        mask_source = f"mask folder {masks}"
    elif raw.shape[-1] == 4:
        all_masks = alpha_masks(raw)
        mask_source = "alpha channel"
    else:
        all_masks = None
        mask_source = ""
    recorded = raw.shape[0]
    fit_px, rating = FALL_FIT_PX, None
    if not np.array_equal(picks, np.arange(recorded)):  # else every frame: no copy
        raw = raw[picks]
    rgb = torch.from_numpy(raw[..., :3]).float().div_(255.0)  # as numpy's float32 / 255
    brightness = rgb.mean((1, 2, 3)).numpy()[np.searchsorted(picks, before)]  # [T] wanted
    check_fade_in(brightness, str(path), start, frame_dt)
    # a hand-held camera: its shake read from the background and taken out (stabilize.py); a
    # one-colour border (a plain backdrop) shows no shake, and an object on it is not one
    shake = Shake(None, 0) if border_is_uniform(rgb) else read_shake(rgb)
    margin = crop_margin(shake)
    filmed_width, filmed_height = width, height  # before the crop (camera files, plates)
    read_fov, fov_from = None, ""  # vertical, of the filmed frame: --fov, the lens, else assumed
    if camera is None:
        lens = read_focal_35mm(path) if fov_deg is None else None
        read_fov, fov_from = recording_fov(fov_deg, lens, filmed_width, filmed_height)
    if shake.largest_px > MAX_SHAKE_SHARE * min(height, width):
        raise InputError(
            f"the camera moves: the background shifts by {shake.largest_px:.0f} px over the "
            f"clip (more than {MAX_SHAKE_SHARE:.0%} of the frame), which the masks and the "
            "camera cannot follow; hold the camera still or put it on a stand",
            source=str(path),
        )
    if margin:
        rgb = steady(rgb, shake)
        if read_fov is not None:  # the field of view is the whole frame's
            half = math.tan(math.radians(read_fov) / 2) * (height - 2 * margin) / height
            read_fov = math.degrees(2 * math.atan(half))
        height, width = rgb.shape[1:3]
    if all_masks is not None:
        chosen = all_masks[torch.from_numpy(picks)]
        if margin:
            chosen = (steady(chosen[..., None], shake)[..., 0] > 0.5).float()
    elif background is not None:
        plate = read_background(background, filmed_height, filmed_width, recorded_size)
        plate = plate[margin : margin + height, margin : margin + width]
        chosen = subtract_background(rgb, plate)
        mask_source = f"background subtraction (clean plate {background})"
    else:
        uniform = border_is_uniform(rgb)
        if segment is None or uniform:  # a border of many colours: no backdrop colour to try
            colour = backdrop_colour(rgb)
            chosen = subtract_background(rgb, colour)
            mask_source = "background subtraction (border colour)"
            black = float(colour.max()) <= BLACK_LEVEL
        if segment is not None and not (uniform and _plausible(chosen)):
            chosen = segment(rgb)  # a floor, a wall in view: the background read from the clip
            if isinstance(chosen, tuple):
                chosen, rating = chosen
            mask_source = (
                "mask segmenter and the clip's own colours (no clean plate; the border colour is "
                "not the backdrop)"
            )
            black = False
            fit_px = SEGMENTER_FALL_FIT_PX * segmented_pixel(chosen, rating)
    time_resampling = "the recorded frames"
    if between.any():  # picks is sorted: each wanted frame's pair by its place in it
        rgb, chosen, objects = frames_between(
            rgb, chosen, np.searchsorted(picks, before), np.searchsorted(picks, after), weight
        )
        time_resampling = (
            f"between the two nearest recorded frames ({int(between.sum())} of {len(weight)}: "
            "motion-compensated)"
        )
    else:
        objects = rgb * chosen[..., None]
    if slowed is not None:
        time_resampling += (
            f"; filmed at {slowed[0]:g} fps and played at {slowed[1]:g} (slow motion, the "
            f"video's metadata): read at {slowed[0]:g} fps"
        )
    if stamps is not None:  # say so: a phone that changed its frame rate while filming
        steps = 1000 * np.diff(stamps)
        time_resampling += (
            f"; a variable frame rate ({steps.min():.0f}–{steps.max():.0f} ms between frames): "
            "each recorded frame at its own time"
        )
    check_masks(chosen, str(masks) if masks is not None else str(path))
    return _Clip(
        rgb=rgb,
        masks=chosen,
        objects=objects,
        mask_source=mask_source,
        fit_px=fit_px,
        rating=rating,
        black=black,
        shake=shake,
        margin=margin,
        read_fov=read_fov,
        fov_from=fov_from,
        time_resampling=time_resampling,
        decoded=decoded,
    )


def _release_before(
    read: Callable[..., _Clip],
    start: float,  # seconds into the recording: the release given (--start SECONDS)
    read_end: float,  # the clip's
    frame_dt: float,
) -> Release | None:
    """The hold before a start given and the release that ends it, where STILL_FRAMES or more
    frames come before the start: read (masks.read_release, as --start auto reads them) from
    the masks of the clip read again (``read``: :func:`_read_clip`, on the clip's own decoded
    frames: the same end and size) from up to HOLD_LOOKBACK_FRAMES before the start to the
    clip's end — to its end, not a few frames past
    the start: the segmenter's windows are sized on the whole read, and a read that ends in
    the fall segments the hold unlike the fall (validation: releases read up to 90 ms early).
    Its ``time_s`` in seconds into the recording; None where the frames show no hold, where the
    release lies more than GIVEN_RELEASE_SLACK_FRAMES from ``start`` (the start given is not
    this hold's release), or where the earlier frames cannot be read. The clip's own masks are
    read from ``start`` as before (a read from earlier frames moves them: docs/usage.md)."""
    lead = max(0.0, start - HOLD_LOOKBACK_FRAMES * frame_dt)
    if start - lead < (STILL_FRAMES - 0.5) * frame_dt:  # too few frames before it to be held
        return None
    try:
        before = read(start=lead, read_end=read_end, side=WORK_MAX_SIDE, min_frames=0)
    except InputError:  # the frames before the start are not the clip: theirs is no refusal
        return None
    found = read_release(before.masks, frame_dt, mask_pixel(before.fit_px))
    if found is None or abs(lead + found.time_s - start) > GIVEN_RELEASE_SLACK_FRAMES * frame_dt:
        return None
    return replace(found, time_s=lead + found.time_s)


def load_observation(
    input: str | os.PathLike,
    *,
    masks: str | os.PathLike | None = None,  # folder of mask images
    background: str | os.PathLike | None = None,  # clean plate image
    camera: str | os.PathLike | None = None,  # camera JSON (.camera), "dataset", None: estimate
    fov_deg: float | None = None,  # vertical field of view for the estimate (None: default)
    touch: str = "soft",  # how the object meets the ground, for the estimate (calibrate.TOUCHES)
    drop_height: float | None = None,  # metres: frame 0's lowest point above the ground, known
    # (the estimate puts its ground there); refused with a camera file that has a pose
    fps: float | None = None,  # frame rate of a frame folder / override of the file's
    frame_dt: float = 0.03,
    start: float | str = 0.0,  # seconds into the recording: the release (frame 0); before it
    # dropped. "auto": read from the masks (an object held still, then falling from rest)
    end: float | None = None,  # seconds into the recording: frames after it dropped (None:
    # CLIP_FRAMES frames from the start, as long as the data's clips; the rest is not decoded)
    segment: Callable[[Tensor], Tensor | tuple[Tensor, dict]] | None = None,  # frames [T, H, W,
    # 3] → masks [T, H, W], or the masks and how sure they are (the Observation's mask_rating)
    min_frames: int = 0,  # fewer frames after resampling: refused before masks and camera
) -> Observation:
    """Read INPUT (see module doc) → :class:`Observation`. Raises InputError naming the input;
    a recording with fewer than ``min_frames`` frames at ``frame_dt`` (from ``start`` to
    ``end``) is refused as too short (:func:`too_short`) before its masks are read; one whose
    object does not move in its first STILL_FRAMES frames, as not starting at the release
    (masks.check_release)."""
    auto = start == AUTO_START
    if auto:
        start = 0.0
    elif isinstance(start, str):
        raise InputError(f"expected seconds or {AUTO_START!r}, got {start!r}", field="--start")
    path = Path(input)
    if not path.exists():
        raise InputError("not found", source=str(path))
    if path.is_dir() and (path / "manifest.json").is_file():
        raise InputError("a dataset folder: give the sample with --sample ID", source=str(path))
    read = partial(
        _read_clip, path, masks=masks, background=background, camera=camera, fov_deg=fov_deg,
        fps=fps, frame_dt=frame_dt, segment=segment,
    )  # fmt: skip
    release = None
    if auto:  # held still first: the clip is read again from the release (or the start)
        read_end = AUTO_SEARCH_S if end is None else end
        first = read(start=0.0, read_end=read_end, side=AUTO_MAX_SIDE, min_frames=0)
        release = read_release(first.masks, frame_dt, mask_pixel(first.fit_px))
        if release is None:  # held, then not a fall: say so, not "give --start auto"
            check_release(first.masks, str(path), 0.0, frame_dt, auto=True)
        start = 0.0 if release is None else release.time_s
    # a phone clip runs on for seconds after the object rests: not read
    read_end = start + (CLIP_FRAMES - 0.5) * frame_dt if end is None else end
    clip = read(start=start, read_end=read_end, side=WORK_MAX_SIDE, min_frames=min_frames)
    chosen, fit_px = clip.masks, clip.fit_px
    recorded_size, margin = clip.decoded.recorded_size, clip.margin
    filmed_height, filmed_width = clip.decoded.raw.shape[1:3]  # decoded, before the crop
    height, width = chosen.shape[1:3]
    check_release(chosen, str(path), start, frame_dt)
    masks_source = str(masks) if masks is not None else str(path)
    check_in_view(chosen, masks_source, start, frame_dt, max(min_frames, 1))
    check_first_frames_track(chosen, masks_source)
    if not auto and start > 0:  # a start given: the hold before it
        release = _release_before(partial(read, decoded=clip.decoded), start, read_end, frame_dt)
    estimate, intrinsics = None, None
    dataset_camera = str(camera) == DATASET_CAMERA and not Path(camera).exists()
    if camera is not None and not dataset_camera:  # K alone (no pose): the pose from the video
        intrinsics = read_intrinsics(camera, *recorded_size)
        if intrinsics is not None:
            known = CameraSpec(intrinsics, torch.eye(4, dtype=torch.float64), *recorded_size)
            intrinsics = (
                known.resized(filmed_width, filmed_height).cropped(margin, margin, width, height).K
            )
    if drop_height is not None and camera is not None and intrinsics is None:
        raise InputError(
            "the camera file's pose and ground_height place the ground already: give "
            "--drop-height with a camera file of K alone, or without --camera",
            field="--drop-height",
        )
    if camera is None or intrinsics is not None:  # from the video: gravity's scale, the ground
        found = estimate_camera(
            chosen,
            frame_dt,
            clip.read_fov,
            fit_px,
            touch=touch,
            intrinsics=intrinsics,
            drop_height=drop_height,
        )
        if intrinsics is None:
            found.fov_from = clip.fov_from + (" (narrowed to the steadied crop)" if margin else "")
        spec, estimate = found.camera, found.to_json()
    elif dataset_camera:
        spec = default_camera(filmed_width, filmed_height).cropped(margin, margin, width, height)
    else:
        spec = read_camera(camera, *recorded_size).resized(filmed_width, filmed_height)
        spec = spec.cropped(margin, margin, width, height)
        check_camera_file(chosen, frame_dt, spec, fit_px)
    return Observation(
        recording=clip.rgb,
        frames=clip.objects,
        masks=chosen,
        camera=spec,
        frame_dt=frame_dt,
        source=str(path),
        mask_source=clip.mask_source,
        recorded_fps=clip.decoded.recorded_fps,
        recorded_frames=clip.decoded.raw.shape[0],
        camera_estimate=estimate,
        camera_shake=clip.shake.to_json(),
        black_backdrop=clip.black,
        fall_fit_px=fit_px,
        start_s=start,
        time_resampling=clip.time_resampling,
        recorded_size=recorded_size,
        mask_rating=clip.rating,
        hdr=clip.decoded.hdr,
        release=release,
    )
