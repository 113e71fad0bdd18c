"""The camera and the ground from the recording itself, when no camera file is given.

Assumptions (say so to the user): a static pinhole camera without roll, the principal point at
the image centre, a vertical field of view ``fov_deg`` (the user's ``--fov``, the phone's lens
from the video's metadata, else 45° across the shorter side: lens.py), and an object that falls
freely for a few frames before it lands.

1. **Scale from gravity.** While the object falls, its masks' centroid follows the projection of
   ``P(t) = P0 + V0·t + ½·g·t²`` in the camera frame, with ``g = 9.81 m/s² · (0, cos θ, sin θ)``
   (world down seen by a camera pitched down by θ). Gravity is known in metres, so the fit
   gives P0 and V0 in metres: the object's distance, its size, its speed. The masks' growth
   (``√(area_t / area_0) = z_0 / z_t``) adds the motion along the view; a prior on θ
   (:data:`PITCH_PRIOR_DEG` ± :data:`PITCH_PRIOR_SPREAD_DEG`, against a residual of one of the
   masks' own pixels: :func:`mask_pixel`) keeps what the fall does not show.
   A wrong focal length scales the distance, not the object: the size and the motion in metres
   follow from gravity and the pixels alone. The fit's standard error of the depth (widened,
   :data:`SCALE_ERROR_FACTOR`, :data:`SCALE_ERROR_FLOOR`) gives the size's 10–90 % interval.
2. **Ground from the first touch.** The centroid leaves the free fall's path when the object
   touches the ground, as ``−c·(t − t_c)²`` while the ground's push builds (``touch="soft"``,
   the default), or also ``−a·(t − t_c)`` when a rigid object stops or bounces at once
   (``touch="rigid"``); :func:`contact_time` fits t_c between frames. A touch read before the
   fall's last frame ends the fall there, and step 1 is fitted again on the frames before it
   (:func:`_fit_to_touch`: a parabola within a pixel can run past a soft landing). The
   centre's position at t_c (the fall's fit, metres) plus the object's extent below its centre
   (frame 0's silhouette, from the centroid down to its bottom edge) puts the ground: the
   lowest point is on it at the touch. Without a clear touch (a clip
   that ends first, a fall cut short by mask errors), or with ``ground_from_touch=False``, the
   ground is read from where the object rests: in the last frame its lowest silhouette point
   is on (a box's near bottom edge) or just above (a ball's) the ground, nearer than its centre
   by about its half-depth (taken as the mask's half-width). A ground either way must lie
   below the object's lowest point in frame 0, which is in the air (within
   :data:`CLEARANCE_SLACK_PX`): a touch whose ground does not is set aside for the rest's.
   A user who knows the drop height (frame 0's lowest point above the ground: a tape measure)
   gives it instead (``drop_height``, ``--drop-height``): the ground is put there, the video's
   own read kept beside it, with a warning where the given value lies outside its 2.5–97.5 %
   interval; refused where the video shows the object's centre falling freely through it.
3. **The world frame** follows the dataset's conventions (z up, ground z = 0): the camera on the
   +x side looking towards −x, pitched down by θ, and the object's frame-0 centre above the origin.

The masks are read area-averaged to at most :data:`CAMERA_MAX_SIDE` px a side (the size the
rules' pixel tolerances were chosen at), the camera then brought back to their own size.

Errors: ``InputError`` when the fall shows in fewer than :data:`MIN_FALL_FRAMES` frames
(:data:`SEGMENTER_MIN_FALL_FRAMES` with the mask segmenter's masks; a drop from near the ground,
or a clip that starts after the release): then the video does not show the scale, and the user
must give ``--camera``; and when the ground read from the rest lies above the object's lowest
point in frame 0 (the fall, the touch and the rest contradict each other).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from statistics import NormalDist

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..render.cameras import intrinsics_from_fov, look_at
from .camera import CameraSpec
from .lens import recording_fov
from .placement import GRAVITY_MAGNITUDE, camera_centre, ray
from .window import pixel_bounds

PITCH_PRIOR_DEG = 15.0  # filmed from a little above the drop
# Chosen on 40 realistic videos of held-out pybullet meshes (true masks, docs/usage.md): mean
# scale error 5.6 / 5.0 / 5.4 % with a spread of 15 / 30 / 90°.
PITCH_PRIOR_SPREAD_DEG = 30.0
MIN_FALL_FRAMES = 4  # frames of free fall (three intervals: an acceleration and its check)
# With the mask segmenter's masks (fit_px above FALL_FIT_PX) one frame more: its errors come in
# runs of frames (the first frames, where its reference is the object itself, are its weakest),
# and one check per image axis cannot see a run of two. On 72 validation drops at 128 px two
# showed a 4-frame fall (10 and 6 in the true masks): one read 29 % small inside a ×0.84–×1.19
# interval, one 2.5 % small (docs/usage.md#the-fall-ends-at-the-touch-2026-11-29)
SEGMENTER_MIN_FALL_FRAMES = 5
LANDED_PIXELS = 1.0  # the bottom within this of its lowest: the object has landed
# A parabola fits a free fall's track to this many pixels (plus 2 % of the radius): exact masks
# (a file's, a clean backdrop's) to half a pixel, the mask segmenter's to a pixel, the rim its
# masks gain or lose. Chosen on validation drops (docs/usage.md#camera-and-ground-from-the-video).
FALL_FIT_PX = 0.5
SEGMENTER_FALL_FIT_PX = 1.0
# The touch is fitted to the centroid over the fall's last 3 frames and this many after it, and
# taken when the fitted push has moved the centroid at least CONTACT_MIN_PX by then and brakes
# it by at least CONTACT_MIN_G·g (the ground stops a fall; a fall cut short by mask errors
# leaves a slow drift, not a touch: the ground is then read from the rest). All chosen on
# validation drops (docs/usage.md#the-ground-from-the-first-touch-2026-11-26-third-session)
CONTACT_FRAMES_AFTER = 2
CONTACT_MIN_PX = 2.0
CONTACT_MIN_G = 1.0
# The share of a box's lean (its half-depth × sin θ: the near bottom edge of an object seen
# from above shows below its lowest point) taken off the silhouette's extent below the centre
# for the ground at the touch: 0 is right for a ball, 1 for a box. Chosen among 0, ½, 1 on 186
# validation drops (true masks: |ground error| 4.7 / 4.0 / 4.4 cm, mean signed +2.2 / +0.1 /
# −2.0 cm; docs/usage.md#the-near-bottom-edge-2026-11-29)
BELOW_DEPTH_SHARE = 0.5
# How the object meets the ground (``--touch``): "soft", a push that builds as it squashes
# (−c·Δt²); "rigid", one that can also stop or bounce it at once (−a·Δt − c·Δt², a, c ≥ 0). A
# quadratic reads a rigid stop ~40 ms early: on pybullet's rigid drops the ground came out 7.0
# cm high on average with "soft", 2.9 cm off with "rigid"; on this project's squashing drops
# "rigid" is 1–3 cm worse (docs/usage.md "A rigid object's touch is read a frame early")
TOUCHES = ("soft", "rigid")
# The object's size read from the fall, 10–90 %: the fit's own standard error of the depth
# (relative) times SCALE_ERROR_FACTOR, beside SCALE_ERROR_FLOOR for what the fit does not see
# (the field of view, the pitch, an object that turns), in log; calibrated to cover 80 % on
# validation drops (docs/usage.md#camera-and-ground-from-the-video)
SCALE_ERROR_FACTOR = 2.5
SCALE_ERROR_FLOOR = 0.05
Z_10_90 = NormalDist().inv_cdf(0.9)  # 1.2816
# A fall read as an object this many metres across is not a fall: masks that do not follow the
# object (a segmenter's on a scene it does not know) can imply one kilometres away
MAX_READ_SIZE_M = 3.0
# A size whose 10–90 % interval reaches beyond this factor either way is not read: the fall
# shown is too short or its masks too noisy (a clip that starts just before the landing); the
# validation drops of this look never went past ×2.6 (docs/usage.md, camera and ground)
MAX_SIZE_FACTOR = 3.0
# A ground read above the object's lowest point in frame 0 (in the air: the clip starts in its
# fall) by more than this many pixels (at the object's depth) contradicts the fall: a touch read
# then is set aside for the rest, and a rest read then is refused; within it, the masks' rim
CLEARANCE_SLACK_PX = 1.0
# The drop height's 10–90 % interval: the size's relative error times the height, beside this
# floor (metres, one standard deviation) for what the scale does not carry: the touch's timing,
# the rest rule, an object that turns. Chosen on validation drops of both looks as the smallest
# of 2–8 cm whose intervals held the truth on 80 % (docs/usage.md "How well the drop height is
# known"); a pixel-based floor held less on another engine's drops at the same width
DROP_HEIGHT_ERROR_FLOOR_M = 0.06
# A drop height given (--drop-height) outside the video's own read by more than this many
# standard deviations (its 2.5–97.5 % interval) is warned of: the 10–90 % interval would warn
# one correct value in five (docs/usage.md#a-drop-height-you-measured)
DROP_HEIGHT_WARN_Z = NormalDist().inv_cdf(0.975)
# The masks the camera is read from, area-averaged to at most this many pixels a side first: the
# rules' tolerances and thresholds (FALL_FIT_PX, LANDED_PIXELS, CONTACT_MIN_PX, ...) were chosen
# on 96–128-px clips, and read a larger clip's fall unlike its own at 128 px. On the two
# validation sets rendered at 384 px, exact masks read at 384 px: drop height 3.6 / 5.3 cm, at
# 128 px 2.3 / 4.9 cm (docs/usage.md#the-camera-read-at-the-rules-size)
CAMERA_MAX_SIDE = 128
# What a user can give when the fall does not show the scale. A slow-motion video played at 30
# fps shows gravity k² times weaker (k× slower): its object reads k² times its size, or no fall
GIVE_CAMERA = (
    "give the camera with --camera FILE (a slow-motion video: its real frame rate with --fps)"
)


@dataclass
class CameraEstimate:
    """A camera read from the video, with what it was read from."""

    camera: CameraSpec
    fov_deg: float  # vertical field of view used (assumed or given)
    pitch_deg: float  # downward tilt of the optical axis
    height: float  # camera above the ground, metres
    distance: float  # camera to the object's centre at frame 0, metres
    fall_frames: int  # frames of free fall fitted
    residual_px: float  # RMS of the fall's centroid fit, pixels
    contact_s: float | None = None  # first touch of the ground (None: ground from the rest)
    # a touch read but set aside: its ground was above the falling object (then from the rest)
    contact_set_aside_s: float | None = None
    touch: str = "soft"  # how the touch was modelled (TOUCHES)
    scale_spread: float = 0.0  # the size's (and distance's) error, log, one standard deviation
    drop_height: float = 0.0  # frame 0's lowest silhouette point above the ground read, metres
    fov_from: str = "given (--fov)"  # where fov_deg came from (lens.recording_fov)
    drop_height_given: bool = False  # drop_height is the user's (--drop-height), not read
    # with a drop height given: the video's own read of it beside (None: not read, refused)
    drop_height_read: float | None = None

    def _read_interval(self, height: float, z: float = Z_10_90) -> tuple[float, float]:
        """A drop height read from the video, metres: its interval of ``z`` standard deviations
        either way (10–90 % by default; not below the ground), one deviation being the size's
        relative error times it beside :data:`DROP_HEIGHT_ERROR_FLOOR_M`."""
        half = z * math.hypot(height * self.scale_spread, DROP_HEIGHT_ERROR_FLOOR_M)
        return max(height - half, 0.0), max(height + half, 0.0)

    @property
    def drop_height_10_90(self) -> tuple[float, float]:
        """The true drop height, metres: 10–90 % interval (not below the ground); a given one
        is taken as it is."""
        if self.drop_height_given:
            return self.drop_height, self.drop_height
        return self._read_interval(self.drop_height)

    @property
    def drop_height_warning(self) -> str | None:
        """Where a given drop height lies outside the 2.5–97.5 % interval of the video's own read
        of it (:data:`DROP_HEIGHT_WARN_Z`): a line that says so (the value is kept: the read is
        the less sure of the two)."""
        if not self.drop_height_given or self.drop_height_read is None:
            return None
        low, high = self._read_interval(self.drop_height_read, DROP_HEIGHT_WARN_Z)
        if low <= self.drop_height <= high:
            return None
        return (
            f"the video reads the drop height {self.drop_height_read:.2f} m ({low:.2f}–"
            f"{high:.2f} m, 2.5–97.5 %), not the {self.drop_height:.2f} m given: check "
            "--drop-height (frame 0's lowest point above the ground, metres)"
        )

    @property
    def size_factor_10_90(self) -> tuple[float, float]:
        """The true size (distance, speeds) over the one read: 10–90 % interval."""
        half = Z_10_90 * self.scale_spread
        return math.exp(-half), math.exp(half)

    @property
    def ground_from(self) -> str:
        """What the ground was read from, in words (prediction.json's ``ground_from``)."""
        if self.drop_height_given:
            return f"the drop height given (--drop-height {self.drop_height:g} m)"
        if self.contact_s is not None:
            return f"the first touch of the ground ({self.touch}), {self.contact_s:.3f} s"
        if self.contact_set_aside_s is not None:
            return (
                f"where the object rests (a touch read at {self.contact_set_aside_s:.3f} s put "
                "the ground above the falling object)"
            )
        return "where the object rests"

    def to_json(self) -> dict:
        return {
            "source": "estimated from the video (gravity, and where the object lands)",
            "fov_deg": round(self.fov_deg, 3),
            "fov_from": self.fov_from,
            "pitch_deg": round(self.pitch_deg, 3),
            "camera_height_m": round(self.height, 4),
            "distance_m": round(self.distance, 4),
            # every length read from the fall scales with the one depth: the size's interval
            "camera_height_m_10_90": [round(self.height * f, 4) for f in self.size_factor_10_90],
            "distance_m_10_90": [round(self.distance * f, 4) for f in self.size_factor_10_90],
            "fall_frames": self.fall_frames,
            "fall_fit_rms_px": round(self.residual_px, 3),
            "size_factor_10_90": [round(x, 3) for x in self.size_factor_10_90],
            "drop_height_m": round(self.drop_height, 4),
            "drop_height_m_10_90": [round(x, 4) for x in self.drop_height_10_90],
            "drop_height_given": self.drop_height_given,  # --drop-height: not read
            "ground_from": self.ground_from,
            "contact_s": None if self.contact_s is None else round(self.contact_s, 4),
            "contact_set_aside_s": None
            if self.contact_set_aside_s is None
            else round(self.contact_set_aside_s, 4),
            "touch": self.touch,
        } | (self._given_json() if self.drop_height_given else {})

    def _given_json(self) -> dict:
        """With a drop height given: the video's own read of it, and a warning where they part."""
        read = self.drop_height_read
        written = {
            "drop_height_read_m": None if read is None else round(read, 4),
            "drop_height_read_m_10_90": None
            if read is None
            else [round(x, 4) for x in self._read_interval(read)],
        }
        warning = self.drop_height_warning
        return written | ({"drop_height_warning": warning} if warning else {})


@dataclass
class _Track:
    centroid: np.ndarray  # [T, 2] pixels (u, v), pixel centres at +0.5
    bottom: np.ndarray  # [T] v of the lowest object pixels' bottom edge
    width: np.ndarray  # [T] pixels between the mask's 2nd and 98th percentile columns
    area: np.ndarray  # [T] pixels


def mask_track(masks: Tensor) -> _Track:
    """Centroid, bottom edge and area of every frame's mask [T, H, W] (all non-empty)."""
    centroid, bottom, width, area = [], [], [], []
    seen = masks > 0.5
    box = pixel_bounds(seen.any(0))  # (top, bottom, left, right)
    top, left = (box[0], box[2]) if box is not None else (0, 0)
    if box is not None:  # found on the bounding box of every frame's mask: the same pixels
        seen = seen[:, box[0] : box[1], box[2] : box[3]]
    for t, mask in enumerate(seen):
        v, u = torch.nonzero(mask, as_tuple=True)
        if len(v) == 0:
            raise InputError(f"the object's mask is empty in frame {t}", source="masks")
        v, u = v + top, u + left
        centroid.append([float(u.double().mean()) + 0.5, float(v.double().mean()) + 0.5])
        bottom.append(float(torch.quantile(v.double(), 0.98)) + 1.0)
        columns = torch.quantile(u.double(), torch.tensor([0.02, 0.98], dtype=torch.float64))
        width.append(float(columns[1] - columns[0]) + 1.0)
        area.append(float(len(v)))
    return _Track(*(np.array(x) for x in (centroid, bottom, width, area)))


def mask_pixel(fit_px: float) -> float:
    """The masks' own pixel in the image's pixels, read from their fall tolerance ``fit_px``
    (SEGMENTER_FALL_FIT_PX × observation.segmented_pixel for the mask segmenter's): 1 for exact
    masks and for the segmenter's at its own size, 5 for its masks of a 128-px reading brought to
    640 px. The rules' pixel thresholds (LANDED_PIXELS, CONTACT_MIN_PX, CLEARANCE_SLACK_PX,
    FALL_CHECK_PX) are in these pixels, and the fall's and the velocity's fits weigh their
    priors against them: a pixel's rim at 128 px is five at 640."""
    return max(1.0, fit_px / SEGMENTER_FALL_FIT_PX)


def fall_frames(
    track: _Track, frame_dt: float, fit_px: float = FALL_FIT_PX, image_down: bool = True
) -> int:
    """How many frames from frame 0 the centroid (per image axis) and the bottom edge each follow
    one parabola (free fall): the longest run whose fits stay within ``fit_px`` + 2 % of the
    object's radius (the bottom edge stops at contact while the centroid goes on as the object
    squashes), ending before the bottom first comes within LANDED_PIXELS of its lowest.

    ``image_down=False``: a fall in any direction of the image (a video on its side or upside
    down) — the centroid alone, the whole clip, no landing read from the bottom edge."""
    radius = math.sqrt(track.area[0] / math.pi)
    tolerance = fit_px + 0.02 * radius
    landed = len(track.area)
    if image_down:
        lowest = track.bottom.max()
        near = track.bottom >= lowest - LANDED_PIXELS * mask_pixel(fit_px)
        landed = int(np.nonzero(near)[0][0])
    count = min(3, landed)
    for n in range(4, landed + 1):
        times = np.arange(n) * frame_dt
        worst = 0.0
        edges = (track.bottom[:n],) if image_down else ()
        for series in (track.centroid[:n, 0], track.centroid[:n, 1], *edges):
            fit = np.polyval(np.polyfit(times, series, 2), times)
            worst = max(worst, float(np.abs(fit - series).max()))
        if worst > tolerance:
            break
        count = n
    return count


MAX_DROP_HEIGHT_M = 10.0  # a drop height given above this is a slip of the unit, not a drop


def check_drop_height(drop_height: float | None) -> None:
    """InputError (``--drop-height``) unless None or metres in (0, MAX_DROP_HEIGHT_M]."""
    if drop_height is not None and not (
        math.isfinite(drop_height) and 0 < drop_height <= MAX_DROP_HEIGHT_M
    ):
        raise InputError(
            f"must be in (0, {MAX_DROP_HEIGHT_M:g}] metres, got {drop_height}",
            field="--drop-height",
        )


def check_touch(touch: str) -> None:
    """InputError (``--touch``) unless ``touch`` is one of :data:`TOUCHES`."""
    if touch not in TOUCHES:
        raise InputError(f"expected one of {', '.join(TOUCHES)}, got {touch!r}", field="--touch")


def contact_time(
    track: _Track,
    count: int,  # frames of free fall
    frame_dt: float,
    falling: np.ndarray,  # [T] px: the fall's model of the centroid's image height, every frame
    metres_per_px: float,  # at the object's depth (its distance / the focal length in pixels)
    touch: str = "soft",  # TOUCHES: how the ground's push starts
    pixel: float = 1.0,  # the masks' own pixel in image pixels (mask_pixel)
) -> float | None:
    """Seconds from frame 0 to the object's first touch of the ground, between frames: the
    centroid's image height minus the free fall's (``falling``, the fall's fit carried on) is
    modelled as ``−c·max(t − t_c, 0)²`` (``touch="soft"``: a push that builds as the object
    squashes) or ``−a·max(t − t_c, 0) − c·max(t − t_c, 0)²`` (``"rigid"``: the fall's speed can
    also be lost at once) over the fall's last 3 frames and :data:`CONTACT_FRAMES_AFTER` after
    it; least squares with a, c ≥ 0, t_c on a grid from 3 frames before the fall's end to 1
    after it. None when the clip ends before it shows the touch, or when the fitted push moves
    the centroid less than :data:`CONTACT_MIN_PX` of the masks' own pixels (``pixel`` image
    pixels each) by the window's last frame or less than a brake of :data:`CONTACT_MIN_G`·g
    would over the same time (for the soft push: 2c px/s² × ``metres_per_px`` ≥
    CONTACT_MIN_G·g): a drift of a badly read fall."""
    check_touch(touch)
    frames = len(track.area)
    if frames < count + CONTACT_FRAMES_AFTER:
        return None
    used = np.arange(max(0, count - 3), min(frames, count + CONTACT_FRAMES_AFTER + 1))
    times = used * frame_dt
    residual = track.centroid[used, 1] - falling[used]  # [F] px, ≤ 0 once the ground pushes
    candidates = np.linspace((count - 3) * frame_dt, (count + 1) * frame_dt, 161)
    linear = np.clip(times[None, :] - candidates[:, None], 0.0, None)  # [C, F] seconds after
    terms = [linear**2] if touch == "soft" else [linear, linear**2]
    best = (math.inf, 0, [0.0] * len(terms))
    for index in range(len(candidates)):
        for coefficients in _non_negative_fits([t[index] for t in terms], -residual):
            pushed = sum(k * t[index] for k, t in zip(coefficients, terms, strict=True))
            error = float(((residual + pushed) ** 2).sum())
            if error < best[0]:
                best = (error, index, coefficients)
    _, index, coefficients = best
    after = linear[index, -1]  # seconds from the touch to the window's last frame
    push = sum(k * t[index, -1] for k, t in zip(coefficients, terms, strict=True))  # px by then
    brake = 0.5 * CONTACT_MIN_G * GRAVITY_MAGNITUDE * after**2  # metres a 1-g brake takes
    if push < CONTACT_MIN_PX * pixel or push * metres_per_px < brake:
        return None
    return float(candidates[index])


def _non_negative_fits(columns: list[np.ndarray], target: np.ndarray) -> list[list[float]]:
    """Candidate least-squares fits of ``target`` by non-negative multiples of ``columns`` (1 or
    2 of them): each column alone (clipped at 0) and, where both come out ≥ 0, both together —
    the non-negative optimum is among them."""
    fits = []
    for k, column in enumerate(columns):
        weight = max(float(column @ target) / max(float(column @ column), 1e-12), 0.0)
        fits.append([weight if j == k else 0.0 for j in range(len(columns))])
    if len(columns) == 2 and int((columns[0] > 0).sum()) >= 2:
        both = np.linalg.lstsq(np.stack(columns, 1), target, rcond=None)[0]
        if (both >= 0).all():
            fits.append([float(x) for x in both])
    return fits


def _world_to_cam(pitch: float, height: float) -> Tensor:
    """Camera at (0, 0, height) looking towards −x, pitched down by ``pitch`` radians."""
    eye = torch.tensor([0.0, 0.0, height], dtype=torch.float64)
    forward = torch.tensor([-math.cos(pitch), 0.0, -math.sin(pitch)], dtype=torch.float64)
    return look_at(eye, eye + forward)


def _fit_fall(
    track: _Track,
    count: int,  # frames of free fall
    frame_dt: float,
    K: np.ndarray,  # [3, 3]
    gravity: np.ndarray | None = None,  # [3] m/s² in the camera frame; None: pitch fitted
    pixel: float = 1.0,  # the masks' own pixel in image pixels (mask_pixel)
):
    """Least-squares fit of the free fall to the masks' centroid and growth (module doc, 1).
    Returns ``(params, positions, rms_px, depth_error)``: params = P0 [3], V0 [3] (camera frame,
    metres, m/s) and the pitch (radians; the prior's where ``gravity`` is given), positions(params,
    t) → [F, 3], and the depth's standard error relative to it (the residuals as the noise).

    The residuals are weighed in the masks' own pixels (image pixels / ``pixel``) against the
    pitch prior's one standard deviation: a 128-px reading brought to 640 px is no surer of its
    fall than at 128, though each of its errors is 5 image pixels."""
    from scipy.optimize import least_squares

    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    times = np.arange(count) * frame_dt
    uv = track.centroid[:count]
    growth = np.sqrt(track.area[:count] / track.area[0])
    radius_px = math.sqrt(track.area[0] / math.pi)
    # start: a parabola through v(t) gives the acceleration in pixels → the depth
    c2, c1, _ = np.polyfit(times, uv[:, 1], 2)
    if not 2 * c2 > 0.2 * fy * GRAVITY_MAGNITUDE / 100.0:  # slower than g at 100 m: no fall seen
        advice = _or_turned(GIVE_CAMERA, track, frame_dt, pixel, count)
        raise InputError(
            "the object does not accelerate downwards in the first frames: the video does not "
            f"show a free fall to read the scale from; {advice}",
            source="camera from the video",
        )
    pitch0 = math.radians(PITCH_PRIOR_DEG)
    down_v = math.cos(pitch0) if gravity is None else float(gravity[1]) / GRAVITY_MAGNITUDE
    z0 = fy * GRAVITY_MAGNITUDE * max(down_v, 0.1) / max(2 * c2, 1e-6)
    b1 = np.polyfit(times, uv[:, 0], 1)[0]
    start = np.array(
        [(uv[0, 0] - cx) / fx * z0, (uv[0, 1] - cy) / fy * z0, z0, b1 * z0 / fx, c1 * z0 / fy, 0.0]
    )
    free_pitch = gravity is None
    if free_pitch:
        start = np.append(start, pitch0)

    def positions(params: np.ndarray, t: np.ndarray) -> np.ndarray:  # [F, 3] camera frame
        p0, v0 = params[:3], params[3:6]
        if free_pitch:
            g = GRAVITY_MAGNITUDE * np.array([0.0, math.cos(params[6]), math.sin(params[6])])
        else:
            g = gravity
        return p0 + v0 * t[:, None] + 0.5 * g * t[:, None] ** 2

    def residual(params: np.ndarray) -> np.ndarray:
        p = positions(params, times)
        z = np.maximum(p[:, 2], 1e-3)
        projected = np.stack([fx * p[:, 0] / z + cx, fy * p[:, 1] / z + cy], 1)
        size = radius_px * (growth - p[0, 2] / z)
        parts = [(projected - uv).ravel() / pixel, size / pixel]
        if free_pitch:
            parts.append([(params[6] - pitch0) / math.radians(PITCH_PRIOR_SPREAD_DEG)])
        return np.concatenate(parts)

    lower = [-np.inf, -np.inf, 1e-2, -np.inf, -np.inf, -np.inf]
    upper = [np.inf] * 6
    if free_pitch:
        lower, upper = [*lower, math.radians(-10.0)], [*upper, math.radians(80.0)]
    fit = least_squares(residual, start, bounds=(lower, upper), x_scale="jac")
    params = fit.x if free_pitch else np.append(fit.x, pitch0)
    rms = pixel * float(np.sqrt(np.mean(fit.fun[: 2 * count] ** 2)))  # image pixels
    # the depth's standard error relative to it (the fit's residuals as the noise, linearised):
    # the object's size, distance and speeds read from the video scale with it
    noise = float(fit.fun @ fit.fun) / max(len(fit.fun) - len(fit.x), 1)
    covariance = noise * np.linalg.pinv(fit.jac.T @ fit.jac)
    depth_error = math.sqrt(max(float(covariance[2, 2]), 0.0)) / float(params[2])
    return params, positions, rms, depth_error


def min_fall_frames(fit_px: float) -> int:
    """Frames of free fall the scale needs: MIN_FALL_FRAMES with exact masks (``fit_px`` ≤
    FALL_FIT_PX), SEGMENTER_MIN_FALL_FRAMES with the mask segmenter's."""
    return MIN_FALL_FRAMES if fit_px <= FALL_FIT_PX else SEGMENTER_MIN_FALL_FRAMES


def _free_fall_frames(track: _Track, frame_dt: float, fit_px: float) -> int:
    count, needed = fall_frames(track, frame_dt, fit_px), min_fall_frames(fit_px)
    if count < needed:
        any_way = fall_frames(track, frame_dt, fit_px, image_down=False)  # turned video?
        masks = " with the mask segmenter's masks" if needed > MIN_FALL_FRAMES else ""
        raise InputError(
            f"the object falls freely in {count} frame(s) (fewer than {needed}{masks}): the "
            "video does not show the scale; "
            f"{_or_turned(GIVE_CAMERA, track, frame_dt, mask_pixel(fit_px), any_way)}",
            source="camera from the video",
        )
    return count


def _acceleration(track: _Track, count: int, frame_dt: float) -> np.ndarray:
    """px/s² [2] (u, v): the centroid's acceleration over frames 0 … count − 1, a parabola per
    image axis."""
    times = np.arange(count) * frame_dt
    return np.array([2 * np.polyfit(times, track.centroid[:count, i], 2)[0] for i in (0, 1)])


def _or_turned(
    advice: str,
    track: _Track,
    frame_dt: float,
    pixel: float,  # the masks' own pixel in image pixels (mask_pixel)
    count: int,  # frames of the fall: the centroid's acceleration is read over them
) -> str:
    """``advice``, after a hint where the object falls towards a side or the top of the image,
    not its bottom (gravity's direction in the image of any camera filming upright): a video on
    its side or upside down — a phone's clip that lost its display rotation, frames exported
    without it. No hint for a fall of fewer than MIN_FALL_FRAMES frames or one that moves the
    centroid less than FALL_CHECK_PX of the masks' own pixels."""
    if count < MIN_FALL_FRAMES:
        return advice
    acceleration = _acceleration(track, count, frame_dt)  # px/s², image u and v
    moved = 0.5 * float(np.linalg.norm(acceleration)) * ((count - 1) * frame_dt) ** 2
    if moved < FALL_CHECK_PX * pixel or acceleration[1] > abs(acceleration[0]):
        return advice
    across, down = acceleration.tolist()
    if abs(across) >= abs(down):
        side, turn = ("right", "transpose=1") if across > 0 else ("left", "transpose=2")
        where, state = f"towards the image's {side} side", "on its side"
    else:
        where, turn, state = "towards the image's top", "hflip,vflip", "upside down"
    return (
        f"the object falls {where}: if the video is {state} (a phone's clip that lost its "
        f"rotation), turn it upright first (e.g. ffmpeg -i IN -vf {turn} OUT); else {advice}"
    )


def fall_direction(
    masks: Tensor,  # [T, H, W] in {0, 1}, every frame non-empty
    frame_dt: float,  # seconds between frames
    camera: CameraSpec,  # a known camera (a file's)
    fit_px: float = FALL_FIT_PX,
    image_down: bool = True,  # False: a fall along any direction of the image (fall_frames)
) -> tuple[float, float, float] | None:
    """How the fall seen in the masks agrees with the camera's gravity: (the angle in degrees
    between the centroid's acceleration over the free fall and the image direction in which
    world-down moves a point at frame 0's centroid; how far that acceleration moves the centroid
    over the fall, px; the share of gravity across the view there, 0–1). None when the fall
    shows in fewer than :data:`MIN_FALL_FRAMES` frames.

    Across the view gravity moves a point at pixel (x, y) (normalised) towards
    ``(g_x − x·g_z, g_y − y·g_z)``, g the camera frame's world-down: a direction that does not
    depend on the point's depth. Read at the rules' size (:func:`rule_size_masks`), as
    :func:`estimate_camera` reads the fall; the pixels moved are given in the masks' own."""
    at_rules = _at_rules_size(masks, fit_px, camera)
    if at_rules is not None:
        small, small_fit_px, small_camera = at_rules
        found = fall_direction(small, frame_dt, small_camera, small_fit_px, image_down)
        if found is None:
            return None
        return found[0], found[1] * masks.shape[2] / small.shape[2], found[2]
    track = mask_track(masks)
    count = fall_frames(track, frame_dt, fit_px, image_down)
    if count < MIN_FALL_FRAMES:
        return None
    times = np.arange(count) * frame_dt
    acceleration = _acceleration(track, count, frame_dt)
    K = camera.K.double().numpy()
    down = camera.world_to_cam[:3, :3].double().numpy() @ np.array([0.0, 0.0, -1.0])
    x = (track.centroid[0, 0] - K[0, 2]) / K[0, 0]
    y = (track.centroid[0, 1] - K[1, 2]) / K[1, 1]
    expected = np.array([K[0, 0] * (down[0] - x * down[2]), K[1, 1] * (down[1] - y * down[2])])
    across = float(np.hypot(down[0] - x * down[2], down[1] - y * down[2]))
    cosine = float(acceleration @ expected) / max(
        float(np.linalg.norm(acceleration) * np.linalg.norm(expected)), 1e-12
    )
    moved = 0.5 * float(np.linalg.norm(acceleration)) * float(times[-1]) ** 2
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine)))), moved, across


# A camera file must agree with the fall: the masks' acceleration within 90° of where gravity
# moves a point in its image (exact masks of 1,051 clips with a fall, with their true cameras:
# all but 2 within 28°; an OpenGL camera, y up and z backwards, reads 166–180° on 99 %), once
# it moves the centroid FALL_CHECK_PX or more. docs/usage.md "Recordings from another engine".
MAX_FALL_ANGLE_DEG = 90.0
FALL_CHECK_PX = 3.0
# Where no fall runs down the image (fall_frames), one along any of its directions (a video on
# its side or upside down) must lie within 70° of gravity's: of the upright validation clips
# read that way with their true cameras, 7 of 8 came out at 11–59° (one whose segmenter masks
# missed the object, 179°); where it applied to the same clips turned, a quarter turn read
# 55–126°, upside down mostly 150–180°. docs/usage.md#a-video-on-its-side.
TURNED_FALL_ANGLE_DEG = 70.0


def check_camera_file(masks: Tensor, frame_dt: float, camera: CameraSpec, fit_px: float) -> None:
    """Refuse a camera file that cannot be the recording's (one-line InputError naming it): a
    camera at or below the ground, one in whose image the object falls away from gravity (see
    :func:`fall_direction`), or one that does not see the ground where the object rests (see
    :func:`rest_depth`) — most often a camera in another convention (OpenGL: y up, z
    backwards) or the camera-to-world matrix given as world_to_cam."""
    height = float(camera_centre(camera)[2]) - camera.ground_height
    if not height > 0:
        raise InputError(
            f"puts the camera {-height:.3g} m below the ground (at or under ground_height "
            f"{camera.ground_height:g}): {CAMERA_CONVENTION}",
            source=camera.source,
            field="world_to_cam",
        )
    fall, limit = fall_direction(masks, frame_dt, camera, fit_px), MAX_FALL_ANGLE_DEG
    if fall is None:  # no fall down the image: one along any of its directions
        fall = fall_direction(masks, frame_dt, camera, fit_px, image_down=False)
        limit = TURNED_FALL_ANGLE_DEG
    moved = FALL_CHECK_PX * mask_pixel(fit_px)  # the masks' own pixels
    if fall is not None and fall[0] > limit and fall[1] >= moved:
        track = mask_track(masks)
        any_way = fall_frames(track, frame_dt, fit_px, image_down=False)
        turned = _or_turned("", track, frame_dt, mask_pixel(fit_px), any_way)
        raise InputError(
            f"in this camera the object falls {fall[0]:.0f}° away from gravity's direction in "
            f"the image; {turned}{CAMERA_CONVENTION}; or the masks do not follow the object "
            "(give them with --masks DIR)",
            source=camera.source,
            field="world_to_cam",
        )
    if rest_depth(masks, camera) is None:
        raise InputError(
            "the object does not end on a ground this camera sees (the ray through the last "
            "frame's lowest object pixel does not meet the ground in front of it): record "
            f"until it rests, or check the camera file: {CAMERA_CONVENTION}",
            source=camera.source,
            field="world_to_cam",
        )


def rest_depth(masks: Tensor, camera: CameraSpec) -> float | None:
    """Metres: the camera z where the ray through the last frame's lowest object pixel (at its
    columns' mean) meets the camera's ground, the object resting on it; None when that ray does
    not meet the ground in front of the camera (or the last mask is empty)."""
    rows, cols = torch.nonzero(masks[-1] > 0.5, as_tuple=True)
    if not len(rows):
        return None
    pixel = torch.tensor([float(cols.double().mean()) + 0.5, float(rows.max()) + 1.0])
    centre, direction = ray(pixel.double(), camera)
    ground = camera.ground_height
    if not (float(direction[2]) < -1e-6 and float(centre[2]) > ground):
        return None
    point = centre + direction * (ground - centre[2]) / direction[2]
    w2c = camera.world_to_cam.double()
    depth = float((w2c[:3, :3] @ point + w2c[:3, 3])[2])
    return depth if depth > 0 else None


CAMERA_CONVENTION = (
    "world_to_cam must take a world with z up to an OpenCV camera (x right, y down, z forward; "
    "an OpenGL or Blender camera has y up and z backwards: negate its second and third rows), "
    "not the camera's pose (camera to world)"
)


def object_depth(
    masks: Tensor,  # [T, H, W] in {0, 1}, every frame non-empty
    frame_dt: float,  # seconds between frames
    camera: CameraSpec,  # a known camera (file or estimate)
    fit_px: float = FALL_FIT_PX,  # the masks' pixel error: FALL_FIT_PX, SEGMENTER_FALL_FIT_PX
) -> float:  # metres: the camera z of the object's centre in frame 0
    """How far the object is, from its free fall seen by a known camera: gravity's direction in
    the camera frame is the camera's, its size is known, so the fall's pixels give the depth
    (module doc, 1, with the pitch known), at the rules' size as :func:`estimate_camera` reads
    it (:func:`rule_size_masks`). InputError when the video shows no free fall."""
    at_rules = _at_rules_size(masks, fit_px, camera)
    if at_rules is not None:
        small, small_fit_px, small_camera = at_rules
        return object_depth(small, frame_dt, small_camera, small_fit_px)
    track = mask_track(masks)
    count = _free_fall_frames(track, frame_dt, fit_px)
    rotation = camera.world_to_cam[:3, :3].double().numpy()
    gravity = rotation @ np.array([0.0, 0.0, -GRAVITY_MAGNITUDE])
    K = camera.K.double().numpy()
    params, *_ = _fit_fall(track, count, frame_dt, K, gravity, mask_pixel(fit_px))
    return float(params[2])


def _fit_to_touch(
    track: _Track,
    count: int,  # frames of free fall (fall_frames)
    frame_dt: float,
    K: np.ndarray,  # [3, 3]
    fit_px: float,
    touch: str,
):
    """The fall's fit (_fit_fall) on a window that ends at the first touch: where contact_time
    reads the touch before the window's last frame, the frames after it are the ground's push,
    not free fall (a parabola within a pixel runs a frame or two past a soft landing, and reads
    the fall slower: the object larger), so the fit is done again on the frames up to the
    touch — at most twice, never on fewer than min_fall_frames. Returns ``(count, fit,
    contact)``: the frames kept, _fit_fall's tuple and the touch (seconds, or None) read
    with that fit."""
    fy, cy = float(K[1, 1]), float(K[1, 2])
    f = math.sqrt(float(K[0, 0]) * fy)
    pixel = mask_pixel(fit_px)
    for _ in range(3):
        fit = _fit_fall(track, count, frame_dt, K, pixel=pixel)
        params, positions = fit[0], fit[1]
        path = positions(params, np.arange(len(track.area)) * frame_dt)  # [T, 3] still falling
        falling = fy * path[:, 1] / path[:, 2] + cy
        contact = contact_time(track, count, frame_dt, falling, float(params[2]) / f, touch, pixel)
        if contact is None:
            break
        up_to_touch = int(contact // frame_dt) + 1  # frames 0 .. the last before the touch
        if not min_fall_frames(fit_px) <= up_to_touch < count:
            break
        count = up_to_touch
    return count, fit, contact


def _given_ground(
    drop_height: float,  # metres: frame 0's lowest point above the ground (--drop-height)
    params: np.ndarray,  # the fall's fit (_fit_fall)
    positions,  # the fall's path: positions(params, t [F]) → [F, 3] camera frame, metres
    down: np.ndarray,  # [3] world down in the camera frame
    below: float,  # metres: frame 0's extent below its centre
    count: int,  # frames of free fall
    frame_dt: float,
    slack: float,  # metres: the masks' rim at the object's depth
) -> float:
    """The camera's height above a ground ``drop_height`` below frame 0's lowest point. Refused
    (InputError) where the camera would lie below it, or where the object's centre falls freely
    further than its frame-0 height over that ground (``drop_height`` + ``below``) in the video:
    a centre never passes through the ground, whether the object turns or the fall's frames run
    a frame past a soft landing."""
    times = np.arange(count) * frame_dt
    start = float(params[:3] @ down)
    fallen = float((positions(params, times) @ down).max()) - start  # metres, down
    if fallen > drop_height + below + slack:
        raise InputError(
            f"the object's centre falls freely {fallen * 100:.0f} cm in the video (frames 0–"
            f"{count - 1}), through a ground {drop_height * 100:.0f} cm below its lowest point "
            f"(and {(drop_height + below) * 100:.0f} cm below its centre) in frame 0: check the "
            "value (metres), or leave it out to read the ground from the video",
            field="--drop-height",
        )
    camera_height = start + below + drop_height
    if not camera_height > 0:
        raise InputError(
            f"{drop_height:g} m below the object puts the camera {-camera_height:.2f} m under "
            "the ground: check the value (metres)",
            field="--drop-height",
        )
    return camera_height


def rule_size_masks(masks: Tensor, max_side: int = CAMERA_MAX_SIDE) -> Tensor | None:
    """Masks [T, H, W] area-averaged to at most ``max_side`` px a side (≥ half covered: object),
    the size the camera's rules were chosen at; None when they are that small already or when
    the object would vanish from a frame there (a small object in a large frame: read as it is)."""
    height, width = masks.shape[1:3]
    factor = max_side / max(height, width)
    if factor >= 1:
        return None
    size = (max(1, round(height * factor)), max(1, round(width * factor)))
    small = torch.nn.functional.interpolate(masks.float()[:, None], size=size, mode="area")
    small = (small[:, 0] >= 0.5).float()
    return small if bool(small.flatten(1).any(1).all()) else None


def _at_rules_size(
    masks: Tensor, fit_px: float, camera: CameraSpec | None = None
) -> tuple[Tensor, float, CameraSpec | None] | None:
    """The masks brought to the rules' size (:func:`rule_size_masks`), their pixel error
    ``fit_px`` there (it shrinks with them, not below the exact masks' FALL_FIT_PX) and
    ``camera`` at their size; None where the masks are read as they are."""
    small = rule_size_masks(masks)
    if small is None:
        return None
    small_fit_px = max(FALL_FIT_PX, fit_px * small.shape[2] / masks.shape[2])
    resized = None if camera is None else camera.resized(small.shape[2], small.shape[1])
    return small, small_fit_px, resized


def estimate_camera(
    masks: Tensor,  # [T, H, W] in {0, 1}, every frame non-empty
    frame_dt: float,  # seconds between frames
    fov_deg: float | None = None,  # vertical; None: assumed (lens.recording_fov)
    fit_px: float = FALL_FIT_PX,  # the masks' pixel error: FALL_FIT_PX, SEGMENTER_FALL_FIT_PX
    ground_from_touch: bool = True,  # False: from the rest only (the rule before the touch)
    touch: str = "soft",  # TOUCHES: how the object meets the ground (contact_time)
    intrinsics: Tensor | None = None,  # [3, 3] pixels at the masks' size: K known (a camera
    # file without a pose); then fov_deg is not used
    drop_height: float | None = None,  # metres: frame 0's lowest point above the ground, known
    # (--drop-height); the ground is put there, the video's own read kept beside it
) -> CameraEstimate:
    """The camera (intrinsics from ``fov_deg`` or given, pose and ground from the video; module
    doc), read from the masks area-averaged to CAMERA_MAX_SIDE (:func:`rule_size_masks`; their
    pixel error ``fit_px`` shrinks with them, not below FALL_FIT_PX) and brought back to their
    size: the same camera, its K in the masks' pixels.

    With ``drop_height`` given the ground lies that far below frame 0's lowest silhouette point
    (the fall still gives the scale and the pitch; :func:`_given_ground` says when it is
    refused)."""
    height_px, width_px = masks.shape[1:3]
    known = None
    if intrinsics is not None:
        known = CameraSpec(
            intrinsics.double(), torch.eye(4, dtype=torch.float64), width_px, height_px
        )
    at_rules = _at_rules_size(masks, fit_px, known)
    if at_rules is not None:  # read there, the camera brought back (CameraSpec.resized both ways)
        small, small_fit_px, small_known = at_rules
        given = None if small_known is None else small_known.K
        read = estimate_camera(
            small, frame_dt, fov_deg, small_fit_px, ground_from_touch, touch, given, drop_height
        )
        factor = small.shape[2] / width_px
        camera = read.camera.resized(width_px, height_px)
        return replace(read, camera=camera, residual_px=read.residual_px / factor)
    if intrinsics is None:
        fov, fov_from = recording_fov(fov_deg, None, width_px, height_px)
        K = intrinsics_from_fov(fov, width_px, height_px, dtype=torch.float64)
    else:
        K = intrinsics.double()
        fov = math.degrees(2 * math.atan(0.5 * height_px / float(K[1, 1])))
        fov_from = "the camera file's K; the pose read from the video"
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    f = math.sqrt(fx * fy)  # for lengths in any direction (square pixels: fx = fy)
    track = mask_track(masks)
    count = _free_fall_frames(track, frame_dt, fit_px)
    count, fit, touch_s = _fit_to_touch(track, count, frame_dt, K.numpy(), fit_px, touch)
    params, positions, rms, depth_error = fit
    pitch = float(params[6])
    down = np.array([0.0, math.cos(pitch), math.sin(pitch)])  # world down in the camera frame
    metres_per_px = float(params[2]) / f  # at the object's frame-0 depth
    size = max(track.width[0], 2 * math.sqrt(track.area[0] / math.pi)) * metres_per_px
    if not size <= MAX_READ_SIZE_M:
        raise InputError(
            f"the fall read from the masks makes the object {size:.3g} m across, "
            f"{float(params[2]):.3g} m away (more than {MAX_READ_SIZE_M:g} m across): the masks "
            "do not follow a falling object, or the video plays slower than it was filmed; "
            f"{_or_turned(GIVE_CAMERA, track, frame_dt, mask_pixel(fit_px), count)}, or the "
            "masks with --masks DIR",
            source="camera from the video",
        )
    # frame 0: the object's extent below its centre. The image's down leans towards the camera
    # by the pitch, so the silhouette's lowest point is the near bottom edge, which lies below
    # a box's centre by h·cos θ + d·sin θ on the image (d its half-depth: the mask's half-width)
    # and a ball's by its radius: taken halfway between the two (BELOW_DEPTH_SHARE)
    lean = BELOW_DEPTH_SHARE * 0.5 * track.width[0] * math.sin(pitch)
    below = (track.bottom[0] - track.centroid[0, 1] - lean) * metres_per_px

    def clearance(camera_height: float) -> float:
        """Metres from the ground read up to the object's lowest point in frame 0 (the drop
        height): the clip starts in the air, so it is above the ground then. (Not at the fall's
        last frame: a parabola's fit can run a frame or two past a soft landing. With a touch
        at t_c this is also the lowest the object comes over [0, t_c], a parabola's ends.)"""
        return camera_height - float(params[:3] @ down) - below

    def from_touch(contact: float) -> float:
        """The camera's height above the ground (module doc, 2): the centre at the touch plus
        the object's extent below its centre (frame 0's silhouette at frame 0's depth)."""
        return float(positions(params, np.array([contact]))[0] @ down) + below

    def from_rest() -> float:
        """The camera's height above the ground: the object at rest (last frame) at the depth
        of its landing point; its lowest silhouette point is on (a box's near bottom edge) or
        just above (a ball's) the ground, nearer than its centre by about its half-depth (the
        mask's half-width) seen at cos θ."""
        landing = positions(params, np.array([count * frame_dt]))[0]
        depth = float(landing[2])
        half_width = 0.5 * track.width[-1] * depth / fx
        near = depth - half_width * math.cos(pitch)
        bottom = np.array([(track.centroid[-1, 0] - cx) / fx, (track.bottom[-1] - cy) / fy, 1.0])
        return float(near * bottom @ down)

    slack = CLEARANCE_SLACK_PX * mask_pixel(fit_px) * metres_per_px

    def read_ground() -> tuple[float, float | None, float | None]:
        """The camera's height read from the video (module doc, 2), the touch it was read from
        (None: the rest) and a touch set aside (its ground above the object in frame 0)."""
        contact = touch_s if ground_from_touch else None
        set_aside = None
        if contact is not None and not clearance(from_touch(contact)) > -slack:
            contact, set_aside = None, contact
        camera_height = from_touch(contact) if contact is not None else from_rest()
        if not camera_height > 0:
            raise InputError(
                f"the ground read from the video is above the camera ({camera_height:.2f} m): "
                "the fall or the rest position is not read well; give the camera with --camera "
                "FILE",
                source="camera from the video",
            )
        if not clearance(camera_height) > -slack:
            raise InputError(
                f"the ground read from the video is {-clearance(camera_height) * 100:.1f} cm "
                "above the falling object's lowest point in frame 0 (from where it "
                f"{'rests' if set_aside is None else 'rests and where it first touches'}): the "
                "fall, the touch or the rest is not read well; give the camera with --camera "
                "FILE",
                source="camera from the video",
            )
        return camera_height, contact, set_aside

    drop_height_read = None
    if drop_height is None:
        camera_height, contact, set_aside = read_ground()
    else:
        try:  # the video's own read, kept beside the one given
            read_height, contact, set_aside = read_ground()
            drop_height_read = clearance(read_height)
        except InputError:
            contact, set_aside = None, None
        camera_height = _given_ground(
            drop_height, params, positions, down, below, count, frame_dt, slack
        )
    world_to_cam = _world_to_cam(pitch, camera_height)
    # shift the world so the object's frame-0 centre is above the origin (dataset convention)
    rotation = world_to_cam[:3, :3]
    start_world = rotation.T @ (torch.from_numpy(params[:3]) - world_to_cam[:3, 3])
    shift = torch.tensor([float(start_world[0]), float(start_world[1]), 0.0], dtype=torch.float64)
    world_to_cam = world_to_cam.clone()
    world_to_cam[:3, 3] = world_to_cam[:3, 3] + rotation @ shift
    camera = CameraSpec(K, world_to_cam, width_px, height_px, 0.0, "estimated from the video")
    estimate = CameraEstimate(
        camera=camera,
        fov_deg=fov,
        fov_from=fov_from,
        pitch_deg=math.degrees(pitch),
        height=camera_height,
        distance=float(np.linalg.norm(params[:3])),
        fall_frames=count,
        residual_px=rms,
        contact_s=contact,
        contact_set_aside_s=set_aside,
        touch=touch,
        scale_spread=math.hypot(SCALE_ERROR_FACTOR * depth_error, SCALE_ERROR_FLOOR),
        drop_height=clearance(camera_height),
        drop_height_given=drop_height is not None,
        drop_height_read=drop_height_read,
    )
    low, high = estimate.size_factor_10_90
    if not high <= MAX_SIZE_FACTOR:
        raise InputError(
            f"the fall shown ({count} frames) reads the object's size only to ×{low:.2f}–"
            f"×{high:.3g} (wider than ×{MAX_SIZE_FACTOR:g} either way): too short or too noisy a "
            "fall to read the scale from; give the camera with --camera FILE",
            source="camera from the video",
        )
    return estimate
