"""The field of view of a recording without a camera file
(docs/usage.md#the-field-of-view-2026-11-28).

In order: the user's ``--fov`` (vertical, degrees); the lens a phone writes into its video
(the 35 mm-equivalent focal length, :func:`..video.read_focal_35mm`); else
:data:`DEFAULT_SHORT_SIDE_FOV_DEG` across the frame's shorter side — a phone's main camera, held
either way (45° vertical in landscape, about 73° vertical in portrait).

A 35 mm-equivalent focal length ``f35`` is the focal length that gives the same angle of view
on 36 × 24 mm film, compared along the diagonal (:data:`FULL_FRAME_DIAGONAL_MM`): the diagonal
angle is ``2·atan(43.27 / (2·f35))`` whatever the frame's shape, and the vertical one follows
from the frame's aspect. A phone may crop the sensor further for video (stabilization): the
field of view is then a little narrower than its lens's.
"""

from __future__ import annotations

import math

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # 43.27 mm: 35 mm film's frame
DEFAULT_SHORT_SIDE_FOV_DEG = 45.0  # across the shorter side: a phone's main camera
FOCAL_35MM_RANGE = (8.0, 800.0)  # mm: a value outside is not a lens (ignored)


def _vertical(half_tan: float, side: float, width: int, height: int) -> float:
    """The vertical angle, degrees, of a frame whose ``side`` (px) spans ``2·atan(half_tan)``."""
    return math.degrees(2 * math.atan(half_tan * height / side))


def fov_from_focal_35mm(focal_mm: float, width: int, height: int) -> float:
    """The vertical field of view, degrees, of a ``width × height`` frame filmed through a lens
    of 35 mm-equivalent focal length ``focal_mm`` (diagonal convention, module doc)."""
    if not (math.isfinite(focal_mm) and focal_mm > 0 and width > 0 and height > 0):
        raise ValueError(
            f"expected a positive focal length and size, got {focal_mm}, {width}×{height}"
        )
    half_tan = FULL_FRAME_DIAGONAL_MM / (2 * focal_mm)  # over half the diagonal
    return _vertical(half_tan, math.hypot(width, height), width, height)


def focal_35mm_from_pixels(focal_px: float, width: int, height: int) -> float:
    """The 35 mm-equivalent focal length, mm, of a pinhole camera of focal length ``focal_px``
    (square pixels) and a ``width × height`` frame: the inverse of :func:`fov_from_focal_35mm`."""
    return FULL_FRAME_DIAGONAL_MM * focal_px / math.hypot(width, height)


def default_fov_deg(width: int, height: int) -> float:
    """The assumed vertical field of view, degrees: :data:`DEFAULT_SHORT_SIDE_FOV_DEG` across the
    shorter side (45° for a landscape or square frame, wider for a portrait one)."""
    half_tan = math.tan(math.radians(DEFAULT_SHORT_SIDE_FOV_DEG) / 2)
    return _vertical(half_tan, min(width, height), width, height)


def recording_fov(
    fov_deg: float | None,  # the user's, vertical (None: not given)
    focal_35mm: float | None,  # the recording's metadata (None: none)
    width: int,  # the frame as filmed, pixels
    height: int,
) -> tuple[float, str]:
    """The vertical field of view, degrees, for a ``width × height`` recording and where it came
    from (written to prediction.json as ``camera_estimate.fov_from``)."""
    if fov_deg is not None:
        return float(fov_deg), "given (--fov)"
    low, high = FOCAL_35MM_RANGE
    if focal_35mm is not None and low <= focal_35mm <= high:
        fov = fov_from_focal_35mm(focal_35mm, width, height)
        return fov, f"from the video's metadata: a {focal_35mm:g} mm (35 mm-equivalent) lens"
    return default_fov_deg(width, height), (
        f"assumed: {DEFAULT_SHORT_SIDE_FOV_DEG:g}° across the shorter side; give --fov when known"
    )
