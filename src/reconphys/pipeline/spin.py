"""The initial spin from the free fall: a rigid render-and-compare fit of the angular velocity.

Until it touches the ground a dropped object moves rigidly: its springs are at rest and gravity
pulls every anchor alike. Frame i of the free fall is then frame 0's Gaussians turned by ω·t_i
about their centre and carried by v·t_i + ½·g·t_i² (t_i = i·frame_dt). Starting from the linear
velocity read from the masks (capture.placement) and no spin, the motion whose renders best match
the recording's object (the frames cut out by their masks) and its silhouettes over the free-fall
frames is found by a coordinate search over the chosen ``axes`` (the linear velocity and the
angular velocity in the camera's right, down and viewing axes), coarse to fine, each round one
batched render (as the physics search, pipeline/search.py).

``predict`` searches the spin about the viewing axis, with the velocity across the view beside it
(:data:`ROLL_AXES`; that velocity is not kept: the masks' own fit stays). The turns about the
image's axes need the object's hidden side and came out further from the truth than no spin on
validation clips, even with the true shape (docs/usage.md "The spin about the viewing axis").

A spin the frames do not show (a fall of a few frames, a turn about a symmetric object's axis)
hardly moves the error: the fit is kept only where it explains the frames better than the best
fit without spin by :data:`MIN_GAIN`, otherwise the spin stays zero and the result says it was
not shown. Its standard error comes from the error's curvature along the axis
(:data:`SD_FACTOR`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..assets.gaussians import Gaussians
from ..assets.normalize import rotate_gaussians
from ..capture import CameraSpec
from ..capture.window import comparison_view, object_window
from ..geometry import axis_angle_to_matrix
from ..physics.model import GRAVITY
from .search import lighting_gain, render_compared, scaled_colours, supersampling

SPIN_FRAMES = 10  # at most this many free-fall frames after frame 0 are compared
MIN_FRAMES = 3  # fewer free-fall frames after frame 0: the spin is not read
SPANS = (2.0, 0.8, 0.3, 0.1)  # rad/s, half-widths of the candidate grids, coarse to fine
LINEAR_SPANS = (0.5, 0.2, 0.07, 0.025)  # m/s, the same for the linear velocity (axes 0–2)
CANDIDATES = 5  # values per axis and round (one batched render)
MAX_SPIN = 8.0  # rad/s per axis (the data's spins are at most 2 rad/s)
SILHOUETTE_WEIGHT = 1.0  # × the silhouettes' mean squared error, added to the colours'
# The fit is kept where it lowers the error of the best fit without spin by at least this share.
# On 36 realistic validation clips (data/mval96, predicted shape) the roll's mean |error| was
# 0.298 / 0.272 / 0.281 / 0.305 rad/s at 0 / 0.01 / 0.02 / 0.05 (no spin: 0.459), and with the
# camera read from the video 0.277 / 0.276 / 0.268 / 0.292: a wash, the middle one kept.
MIN_GAIN = 0.02
PROFILE = (-0.6, -0.3, 0.0, 0.3, 0.6)  # rad/s around the best: the error's curvature
# Only the spin about the viewing axis is read by default (with the velocity across the view
# searched beside it, not kept): on validation drops the turns about the image's axes came out
# further from the truth than no spin, even with the true shape (docs/usage.md "The spin").
ROLL_AXES = (0, 1, 5)
# The standard error = this × √(best error / curvature). First 0.15, from the same 36 clips (±1.28
# of it held the true roll on 80 % of them); on two more validation sets of held-out meshes
# (configs/masks_held_out.txt's camera sets, seeds 53 and 61, 96 px) 0.15 held only 61–74 %, so
# it was calibrated again on the three pooled (219 clip readings, camera file and from the
# video): ±1.28 SE holds 80 % at 0.187 (docs/usage.md "The spin about the viewing axis").
SD_FACTOR = 0.19


@dataclass
class SpinFit:
    angular: Tensor  # [3] rad/s, world frame (zero where not shown)
    fitted: Tensor  # [3] rad/s, world frame: the best fit, kept or not
    error: float  # mean squared error of the best fit (colours + silhouettes)
    error_at_rest: float  # without spin (at the start's velocity or the best fit's, the lower)
    frames: int  # free-fall frames compared after frame 0
    shown: bool  # the fit is kept (its gain ≥ MIN_GAIN)
    seconds: float
    sd_camera_axes: Tensor | None = None  # [3] rad/s about right, down, view (nan: not searched)

    @property
    def gain(self) -> float:  # share of the error without spin that the fit removes
        return 1.0 - self.error / max(self.error_at_rest, 1e-12)


def turned(
    gaussians: Gaussians,  # [N] frame 0, world frame
    angular: Tensor,  # [B, 3] rad/s, world frame
    linear: Tensor,  # [3] or [B, 3] m/s, world frame, of the Gaussians' centre
    times: Tensor,  # [F] seconds after frame 0
) -> Gaussians:  # [B·F, N]: candidate b at time f is row b·F + f
    """Frame 0's Gaussians in rigid free fall: turned by ω·t about their centre, carried by
    v·t + ½·g·t² (their rotations turned with them)."""
    dtype = gaussians.means.dtype
    centred = gaussians.map(lambda x: x.double())
    centre = centred.means.mean(0)
    centred = centred.with_means(centred.means - centre)
    rotation = axis_angle_to_matrix(angular.double()[:, None] * times.double()[None, :, None])
    rotation = rotation.reshape(-1, 3, 3)  # [B·F, 3, 3]
    t = times.double().repeat(len(angular))[:, None]  # [B·F, 1]
    gravity = torch.as_tensor(GRAVITY, dtype=torch.float64)
    linear = linear.double().expand(len(angular), 3).repeat_interleave(len(times), 0)
    shift = centre + linear * t + 0.5 * gravity * t**2  # [B·F, 3]
    batch = rotate_gaussians(centred.map(lambda x: x.expand(len(rotation), *x.shape)), rotation)
    return batch.with_means(batch.means + shift[:, None]).map(lambda x: x.to(dtype))


@torch.no_grad()
def spin_fit(
    gaussians: Gaussians,  # [N] the object at frame 0, world frame
    frames: Tensor,  # [T, H, W, 3] in [0, 1], the object cut out by its masks (background black)
    masks: Tensor,  # [T, H, W] in {0, 1}
    camera: CameraSpec,  # the frames' camera
    frame_dt: float,  # seconds
    linear: Tensor,  # [3] m/s, world frame: the initial linear velocity
    fall: int | None,  # frames of free fall from frame 0 (calibrate.fall_frames); None: unknown
    resolution: int = 64,  # longest side of the comparison
    axes: tuple[int, ...] = (3, 4, 5),  # searched: 0–2 linear, 3–5 angular (right, down, view)
) -> SpinFit:
    """The initial angular velocity that best explains the free-fall frames (see the module)."""
    started = time.perf_counter()
    count = 0 if fall is None else min(fall - 1, SPIN_FRAMES, frames.shape[0] - 1)
    zero = torch.zeros(3, dtype=torch.float64)
    if count < MIN_FRAMES:
        seconds = time.perf_counter() - started
        return SpinFit(zero, zero, 0.0, 0.0, max(count, 0), False, seconds)
    frames, masks = frames[: count + 1], masks[: count + 1].to(frames)
    window = object_window(masks)
    both = torch.cat([frames * masks[..., None], masks[..., None]], -1)
    both, view = comparison_view(both, camera, resolution, window)
    target, silhouettes = both[1:, ..., :3], both[1:, ..., 3]  # frames 1..count
    recorded_scale = (window[2] if window else frames.shape[2]) / both.shape[2]
    supersample = supersampling(gaussians, view, recorded_scale)
    gain = lighting_gain(gaussians, both[0, ..., :3], view, supersample)
    compared = scaled_colours(gaussians, gain)
    times = torch.arange(1, count + 1, dtype=torch.float64) * frame_dt
    to_cam = view.world_to_cam[:3, :3].double()

    def errors(motion_cam: Tensor) -> Tensor:  # [B, 6] (linear, angular) camera axes → [B]
        rgb, alpha = [], []
        for chunk in motion_cam.split(CANDIDATES):
            batch = turned(compared, chunk[:, 3:] @ to_cam, chunk[:, :3] @ to_cam, times)
            c, a = render_compared(batch, view, supersample)
            rgb.append(c.reshape(len(chunk), count, *c.shape[1:]))
            alpha.append(a.reshape(len(chunk), count, *a.shape[1:]))
        rgb, alpha = torch.cat(rgb), torch.cat(alpha)
        colour = ((rgb - target[None]) ** 2).mean((1, 2, 3, 4))
        outline = ((alpha - silhouettes[None]) ** 2).mean((1, 2, 3))
        return (colour + SILHOUETTE_WEIGHT * outline).double()

    current = torch.cat([to_cam @ linear.double(), zero])
    at_rest = float(errors(current[None])[0])
    best = at_rest
    grid = torch.linspace(-1.0, 1.0, CANDIDATES, dtype=torch.float64)
    for linear_span, span in zip(LINEAR_SPANS, SPANS, strict=True):
        for axis in axes:
            width, bound = (linear_span, 3.0) if axis < 3 else (span, MAX_SPIN)
            trial = current.repeat(CANDIDATES, 1)
            trial[:, axis] = (current[axis] + grid * width).clamp(-bound, bound)
            scores = errors(trial)
            pick = int(scores.argmin())
            if float(scores[pick]) < best:
                current, best = trial[pick].clone(), float(scores[pick])
    # the error's curvature along each searched spin axis at the best → its standard error
    curvature = torch.full((3,), float("nan"), dtype=torch.float64)
    for axis in (a for a in axes if a >= 3):
        trial = current.repeat(len(PROFILE), 1)
        trial[:, axis] = current[axis] + torch.tensor(PROFILE, dtype=torch.float64)
        scores = errors(trial)
        x = trial[:, axis]
        design = torch.stack([x**2, x, torch.ones_like(x)], 1)  # a·x² + b·x + c
        curvature[axis - 3] = float(torch.linalg.lstsq(design, scores[:, None]).solution[0, 0])
    still = current.clone()
    still[3:] = 0.0  # without spin: at the start or at the best velocity, whichever fits better
    at_rest = min(at_rest, float(errors(still[None])[0]))
    fitted = current[3:] @ to_cam  # camera axes → world
    sd = SD_FACTOR * (best / curvature.clamp_min(1e-12)).sqrt()
    sd = torch.where(curvature > 0, sd, torch.full_like(sd, float("inf")))
    sd = torch.where(curvature.isnan(), curvature, sd)
    fit = SpinFit(zero, fitted, best, at_rest, count, False, 0.0, sd)
    shown = fit.gain >= MIN_GAIN
    return replace(
        fit,
        angular=fitted if shown else zero,
        shown=shown,
        seconds=time.perf_counter() - started,
    )
