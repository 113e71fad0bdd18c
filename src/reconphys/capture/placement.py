"""Where the object is: given Gaussians placed on the first frame's mask, its initial velocity
and the ground, from the camera and the masks alone (no optimisation through the renderer).

- :func:`projected_box` / :func:`mask_box`: pixel bounding boxes (robust: 1st–99th percentile).
- :func:`fit_to_mask`: keep the Gaussians' orientation and size, move them so their rendered
  silhouette covers the first frame's mask box (depth from the apparent size, then the ray
  through the box centre); :func:`silhouette_iou` says how well a placement matches, and
  :func:`colour_agreement` whether its colours are where frame 0 shows them. They compare on a
  window around the object (window.comparison_view), not the frame.
- :func:`linear_velocity_fit`: the free-fall motion of the mask
  centroid over the first frames (before any contact) → a linear velocity in m/s by least squares
  (and its standard error); exactly 0 when the first four frames need none, else read again
  over the whole free fall when its length is given; the angular velocity is
  not estimated (0). The component along the viewing direction is weakly observed (it only
  changes the apparent size) and is damped towards 0 by a small ridge term.
- :func:`estimate_ground_height`: the world z of the landed silhouette's bottom (last frame)
  near the object's position — a rough check on the camera's ground.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..assets.gaussians import Gaussians
from ..physics import GRAVITY
from .camera import CameraSpec
from .window import comparison_view, pixel_bounds

GRAVITY_MAGNITUDE = -GRAVITY[2]  # m/s², along −z (docs/design.md#conventions)
# The initial velocity's prior, per component (m/s), against a pixel of mask noise: about the
# largest toss (0.5–1.5 m/s sideways). Chosen on 60 videos of the validation meshes (32 px): mean
# error 0.20 m/s on drops and 0.36 on tosses, against 0.21 / 0.45 without the size term and the
# prior, and 0.21 / 0.45 with a 1 m/s prior (docs/usage.md "Initial state").
VELOCITY_PRIOR_M_S = 2.0
# The masks' centroid and size noise, at least (pixels), in the velocity's standard error: with
# it, ± 1.2816 standard errors held the true velocity on 77 / 70 / 91 % (across the view right,
# down; along it) of 56 realistic validation drops and tosses read from their mp4 alone (camera
# estimated; meshes no network trained on), 95 / 84 / 93 % with the size's error added as
# predict adds it; the velocity's mean error was 0.11 / 0.16 / 0.33 m/s against 0.37 / 0.61 /
# 0.43 for "at rest" (docs/usage.md "Initial state").
VELOCITY_NOISE_PX = 0.5
# Released from rest? The masks' motion is explained at rest (v = 0) unless the fitted velocity
# lowers the pixel residuals' sum of squares by more than this many times their noise (a χ²-like
# test, 3 degrees of freedom): then the velocity is 0, not the few cm/s that mask noise and the
# silhouette's own changes (it is seen from a little higher as it falls) read as motion along
# the view. Chosen on validation clips released from rest (docs/usage.md "Initial state"): the
# smallest of 1, 2, 3, 5 that brought every one of 40 realistic ones, read with the mask
# segmenter, under 0.1 m/s (21 of 40 were over without the test); it costs nothing at 96–128 px
# and 0.02–0.06 m/s across the view on 32-px drops. 0: no test.
REST_CHI2 = 5.0
# The rest hypothesis may place the object anywhere along its ray between these factors of its
# depth: a centre read at another depth than the fall's pixels imply (a camera read from the
# video, a predicted shape) predicts another fall in pixels, which a velocity would make up.
# Chosen on the same validation clips through predict with the mp4 alone: 6 of 40 over 0.1 m/s
# with the depth fixed, 1 with 0.8–1.25, 0 with 0.67–1.5 (and 0.5–2); 32-px drops lose across
# the view as the range widens (down 0.116 / 0.140 / 0.145 / 0.206 m/s).
REST_DEPTH_FACTORS = (0.67, 1.5)
# A clip not read at rest is read again over its free fall (calibrate.fall_frames) less this many
# frames (the fall's read end is a frame or two past the touch), with this noise floor (pixels):
# masks that gain or lose a rim from frame to frame (the segmenter's) move the centroid and the
# area, which four frames read as velocity. Chosen on validation drops and tosses, realistic and
# plain (docs/usage.md "The whole fall after the rest test"); clips from rest are unchanged.
FALL_WINDOW_LESS = 2
FALL_NOISE_PX = 1.0
# The size term's weight for a mask segmenter's masks (1 for exact ones): the rim a segmenter
# gains or loses goes round the whole object, which moves the area by a lot and the centroid by
# little, and a growing area reads as motion towards the camera. Chosen on two validation sets
# of 36 realistic pybullet drops and tosses at 128 px (mean |v − truth| 0.267 / 0.424 m/s at 1,
# 0.255 / 0.351 at 0.5, 0.283 / 0.297 at 0.25) and 40 drops from rest (none over 0.1 m/s at any
# of them): docs/usage.md "The segmenter's area is weighed less".
SEGMENTED_SIZE_WEIGHT = 0.5


def project(points: Tensor, camera: CameraSpec) -> tuple[Tensor, Tensor]:
    """World points [N, 3] → (pixels [N, 2] (u right, v down), depth [N] metres)."""
    w2c = camera.world_to_cam.to(points)
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    depth = cam[:, 2]
    uv = cam[:, :2] / depth.clamp_min(1e-6)[:, None]
    K = camera.K.to(points)
    return uv * torch.stack([K[0, 0], K[1, 1]]) + torch.stack([K[0, 2], K[1, 2]]), depth


def camera_centre(camera: CameraSpec) -> Tensor:  # [3] world frame, float64
    """Where the camera is: −Rᵀ t of its world_to_cam."""
    w2c = camera.world_to_cam.double()
    return -w2c[:3, :3].T @ w2c[:3, 3]


def ray(pixel: Tensor, camera: CameraSpec) -> tuple[Tensor, Tensor]:
    """Pixel [2] → (camera centre [3], unit direction [3]) in the world frame."""
    K = camera.K.double()
    w2c = camera.world_to_cam.double()
    direction_cam = torch.stack(
        [
            (pixel[0] - K[0, 2]) / K[0, 0],
            (pixel[1] - K[1, 2]) / K[1, 1],
            torch.tensor(1.0, dtype=torch.float64),
        ]
    )
    direction = w2c[:3, :3].T @ direction_cam
    return camera_centre(camera), direction / direction.norm()


def _box(u: Tensor, v: Tensor) -> Tensor:
    q = torch.tensor([0.01, 0.99], dtype=u.dtype)
    return torch.cat([torch.quantile(u, q), torch.quantile(v, q)])  # [u0, u1, v0, v1]


def projected_box(means: Tensor, camera: CameraSpec) -> Tensor:
    """[4] (u_min, u_max, v_min, v_max) of the projected centres (1st–99th percentile)."""
    uv, _ = project(means.double(), camera)
    return _box(uv[:, 0], uv[:, 1])


def mask_box(mask: Tensor) -> Tensor:
    """[4] (u_min, u_max, v_min, v_max) of a [H, W] mask's pixels (centres at +0.5)."""
    v, u = torch.nonzero(mask > 0.5, as_tuple=True)
    return _box(u.double() + 0.5, v.double() + 0.5)


# Silhouettes are compared on a window around the object, not on the whole frame: reduced to
# 64 px as a whole frame, a small or thin object spans a few pixels, and the true geometry of a
# robot's leg filmed at 128 px scored IoU 0.49 against its own exact mask (the check's bar was
# 0.6). On the window (its longer side ≤ max_size, never enlarged) the true Gaussians of 72
# realistic validation drops score 0.74–0.99 against the segmenter's masks where the whole frame
# gave 0.61–0.93, and the same turned by 90° or 180° about as before (median 0.63 against 0.64),
# so the bar could rise (docs/usage.md "The placement check on the object's window").
WINDOW_MARGIN = 0.15  # the silhouette check's window: the boxes' union, widened by this share
FIT_WINDOW_MARGIN = 1.0  # fit_to_mask's: the mask's box, widened by its size each way


def _window_around(
    camera: CameraSpec,
    boxes: list[Tensor],  # each [4] (u_min, u_max, v_min, v_max) in pixels
    margin: float,  # the union widened by this share of its longer side each way, + 2 px
) -> tuple[int, int, int, int] | None:
    """(left, top, width, height) in the camera's pixels of the window around the union of
    ``boxes`` (inside the image); None when it lies outside the image."""
    u0, v0 = min(float(b[0]) for b in boxes), min(float(b[2]) for b in boxes)
    u1, v1 = max(float(b[1]) for b in boxes), max(float(b[3]) for b in boxes)
    pad = margin * max(u1 - u0, v1 - v0) + 2.0
    left, top = max(0, math.floor(u0 - pad)), max(0, math.floor(v0 - pad))
    right = min(camera.width, math.ceil(u1 + pad))
    bottom = min(camera.height, math.ceil(v1 + pad))
    if right <= left or bottom <= top:
        return None
    return left, top, right - left, bottom - top


def _mask_box(mask: Tensor) -> Tensor | None:  # [4] (u_min, u_max, v_min, v_max), pixel edges
    bounds = pixel_bounds(mask > 0.5)
    if bounds is None:
        return None
    top, bottom, left, right = bounds
    return torch.tensor([left, right, top, bottom], dtype=torch.float64)


def _splats_extent(gaussians: Gaussians, camera: CameraSpec) -> Tensor | None:
    """[4] box of the Gaussians in front of the camera, each its centre ± 1.5 σ of its largest
    axis (an opaque Gaussian's alpha passes one half within 1.18 σ), clamped to the image."""
    uv, depth = project(gaussians.means.double(), camera)
    front = depth > 1e-3
    if not bool(front.any()):
        return None
    focal = float(camera.K[:2, :2].diagonal().max())
    sigma = torch.exp(gaussians.log_scales.double().amax(-1))[front]
    radius = 1.5 * focal * sigma / depth[front]
    uv = uv[front]
    u0 = (uv[:, 0] - radius).clamp(0, camera.width).min()
    u1 = (uv[:, 0] + radius).clamp(0, camera.width).max()
    v0 = (uv[:, 1] - radius).clamp(0, camera.height).min()
    v1 = (uv[:, 1] + radius).clamp(0, camera.height).max()
    return torch.stack([u0, u1, v0, v1])


def _windowed(
    mask: Tensor, camera: CameraSpec, window: tuple[int, int, int, int], max_size: int
) -> tuple[Tensor, CameraSpec]:
    """The mask [H, W] cropped to ``window`` and area-averaged to at most ``max_size`` px a side
    (window.comparison_view), thresholded at one half → ([h, w] in {0, 1}, that camera)."""
    small_mask, small = comparison_view(mask.float()[None, :, :, None], camera, max_size, window)
    return (small_mask[0, :, :, 0] > 0.5).float(), small


def _comparison_window(
    gaussians: Gaussians, mask: Tensor, camera: CameraSpec
) -> tuple[int, int, int, int] | None:
    """The window both checks compare on: the mask's pixels and the Gaussians' projected extent,
    WINDOW_MARGIN around them (None: both empty or off the image)."""
    boxes = [b for b in (_splats_extent(gaussians, camera), _mask_box(mask)) if b is not None]
    return _window_around(camera, boxes, WINDOW_MARGIN) if boxes else None


def silhouette_iou(
    gaussians: Gaussians,
    mask: Tensor,  # [H, W]
    camera: CameraSpec,
    max_size: int = 64,  # the object's window rendered at most this many pixels on its long side
) -> float:
    """IoU of the rendered silhouette (alpha > 0.5) and the mask on a window around both (the
    mask's pixels and the Gaussians' projected extent, WINDOW_MARGIN around them)."""
    return placement_scores(gaussians, mask, camera, max_size=max_size)[0]


# Colours are compared by their chromaticity (r, g, b over their sum): the light's brightness,
# the shading across the object and a mix with black at the outline scale all three channels
# alike and leave it; its correlation over the pixels both cover does not see a white balance's
# offset either. Measured on 72 realistic validation drops at 128 px (frame 0, the segmenter's
# masks): the true Gaussians 0.68–0.97 (5th percentile 0.71), the same turned by 90° or 180° and
# moved onto the mask −0.4–0.35 (docs/usage.md "The colours of a given shape").
# Below this chromaticity std (the mean of r, g, b's) in the render or in the frame, no judgement
MIN_CHROMA_SPREAD = 0.03
MIN_COLOUR_PIXELS = 16  # pixels both cover on the window, at least


def chromaticity(rgb: Tensor) -> Tensor:  # [..., 3] → [..., 3], each row summing to 1
    """r, g, b over their sum (black reads as grey)."""
    total = rgb.sum(-1, keepdim=True)
    return torch.where(total > 1e-6, rgb / total.clamp_min(1e-6), torch.full_like(rgb, 1 / 3))


def colour_agreement(
    gaussians: Gaussians,
    frame: Tensor,  # [H, W, 3] in [0, 1]: frame 0 (masked or not)
    mask: Tensor,  # [H, W] frame 0's object mask
    camera: CameraSpec,
    max_size: int = 64,
) -> float | None:
    """Correlation of the rendered colours' chromaticity with frame 0's over the pixels both the
    silhouette (alpha > 0.5) and the mask cover, on the silhouette check's window: near 1 when
    the Gaussians show the side of the object the camera sees, near 0 when they are turned (a
    pattern in the wrong place). None when it cannot tell: the rendered or the recorded
    chromaticity varies by less than MIN_CHROMA_SPREAD (one colour, greys only, or colours the
    video does not resolve: H.264 keeps colour at half the resolution) or fewer than
    MIN_COLOUR_PIXELS pixels are shared."""
    return placement_scores(gaussians, mask, camera, frame, max_size)[1]


def placement_scores(
    gaussians: Gaussians,
    mask: Tensor,  # [H, W] frame 0's object mask
    camera: CameraSpec,
    frame: Tensor | None = None,  # [H, W, 3] in [0, 1]: frame 0; None: no colours compared
    max_size: int = 64,
) -> tuple[float, float | None]:
    """(:func:`silhouette_iou`, :func:`colour_agreement`) from one render of the window; the
    colours None without ``frame``. (0, None) when the window is off the image."""
    window = _comparison_window(gaussians, mask, camera)
    if window is None:
        return 0.0, None
    target, small = _windowed(mask, camera, window, max_size)
    target = target > 0.5
    from ..render import render

    with torch.no_grad():
        drawn = render(gaussians.map(lambda t: t.float()), small.cameras(), backend="torch")
    alpha = drawn.alpha.reshape(small.height, small.width)
    silhouette = alpha > 0.5
    union = float((silhouette | target).sum())
    iou = float((silhouette & target).sum()) / union if union > 0 else 0.0
    shared = silhouette & target
    if frame is None or int(shared.sum()) < MIN_COLOUR_PIXELS:
        return iou, None
    seen, _ = comparison_view(frame.float()[None], camera, max_size, window)
    colours = drawn.rgb.reshape(small.height, small.width, 3)[shared] / alpha[shared, None]
    drawn_chroma = chromaticity(colours.double())  # [P, 3]
    seen_chroma = chromaticity(seen[0][shared].double())
    if min(float(c.std(0).mean()) for c in (drawn_chroma, seen_chroma)) < MIN_CHROMA_SPREAD:
        return iou, None
    x = drawn_chroma - drawn_chroma.mean(0)
    y = seen_chroma - seen_chroma.mean(0)
    scale = float(((x**2).sum() * (y**2).sum()).sqrt())
    return iou, float((x * y).sum()) / scale if scale > 0 else 0.0


def rendered_mask(gaussians: Gaussians, camera: CameraSpec) -> Tensor:  # [H, W] alpha > 0.5
    from ..render import render

    with torch.no_grad():
        alpha = render(gaussians.map(lambda t: t.float()), camera.cameras(), backend="torch").alpha
    return (alpha.reshape(camera.height, camera.width) > 0.5).float()


def fit_to_mask(
    gaussians: Gaussians,  # world-frame orientation and size kept
    mask: Tensor,  # [H, W] the first frame's object mask
    camera: CameraSpec,
    iterations: int = 8,
    max_size: int = 64,  # the mask's window rendered at most this many pixels on its long side
) -> Gaussians:
    """Translate the Gaussians so that their rendered silhouette's box matches the mask's box
    (same orientation and size; the depth follows from the apparent size), on a window around
    the mask (FIT_WINDOW_MARGIN). An empty mask or an empty or off-screen silhouette returns
    the Gaussians unchanged."""
    box = _mask_box(mask)
    window = None if box is None else _window_around(camera, [box], FIT_WINDOW_MARGIN)
    if window is None:
        return gaussians
    target_mask, small = _windowed(mask, camera, window, max_size)
    if float(target_mask.sum()) == 0:
        return gaussians
    target = mask_box(target_mask)
    target_centre = torch.stack([(target[0] + target[1]) / 2, (target[2] + target[3]) / 2])
    target_size = torch.sqrt((target[1] - target[0]) * (target[3] - target[2])).clamp_min(1.0)
    means = gaussians.means.double()
    centre = means.mean(0)
    eye, _ = ray(target_centre, small)
    depth = float((centre - eye).norm())
    position, aim = centre, target_centre.clone()
    for _ in range(iterations):
        origin, direction = ray(aim, small)
        candidate = origin + direction * depth
        placed = gaussians.with_means((means - centre + candidate).to(gaussians.means))
        silhouette = rendered_mask(placed, small)
        if float(silhouette.sum()) == 0:
            break
        position = candidate
        box = mask_box(silhouette)
        size = torch.sqrt((box[1] - box[0]) * (box[3] - box[2])).clamp_min(1.0)
        box_centre = torch.stack([(box[0] + box[1]) / 2, (box[2] + box[3]) / 2])
        depth = depth * float(size / target_size)
        aim = aim + (target_centre - box_centre)  # move the box centre onto the mask's
    shift = (position - centre).to(gaussians.means)
    return gaussians.with_means(gaussians.means + shift)


def _centroid(mask: Tensor) -> Tensor:
    v, u = torch.nonzero(mask > 0.5, as_tuple=True)
    return torch.stack([u.double().mean() + 0.5, v.double().mean() + 0.5])


def linear_velocity_fit(
    means: Tensor,  # [N, 3] the object at frame 0, world frame
    masks: Tensor,  # [T, H, W]
    camera: CameraSpec,
    frame_dt: float,
    frames: int = 4,  # frames 0..frames−1 are used (before contact for the dataset's drops)
    prior_speed: float = VELOCITY_PRIOR_M_S,  # m/s: a weakly observed component shrinks to 0
    fall: int | None = None,  # frames of free fall read from the masks (calibrate.fall_frames)
    size_weight: float = 1.0,  # the size term's weight (SEGMENTED_SIZE_WEIGHT: segmented masks)
    pixel: float = 1.0,  # the masks' own pixel in image pixels (calibrate.mask_pixel)
) -> tuple[Tensor, Tensor]:  # [3] m/s (world), [3] m/s standard error in the camera's axes
    """Linear velocity whose ballistic motion moves the projected centroid like the masks' and
    changes the apparent size like theirs, and its standard error along the camera's axes (x
    right, y down, z along the view): the least-squares covariance with the residuals as the
    pixel noise (at least VELOCITY_NOISE_PX).

    With ``fall``: a clip that frames 0..frames−1 do not show at rest (:data:`REST_CHI2`) is
    read again over the free fall less :data:`FALL_WINDOW_LESS` frames (at least ``frames``),
    with a noise floor of :data:`FALL_NOISE_PX`: the longer window averages out the masks'
    frame-to-frame noise (:data:`FALL_WINDOW_LESS`).

    The centroid shows motion across the view; motion along it only through perspective (a
    fraction of a pixel over a few frames), so on its own a tenth of a pixel of noise reads as
    tenths of m/s towards or away from the camera. The masks' size shows it directly:
    √(area_t / area_0) = depth_0 / depth_t, weighed in pixels of the object's radius. A Gaussian
    prior of ``prior_speed`` per component, against one pixel of centroid noise, keeps what
    neither shows at 0 (a drop from rest comes back at rest).

    Pixels here are the masks' own (``pixel`` image pixels each: a 128-px reading brought to
    640 px is no surer of the motion than at 128): the prior weighs ``pixel`` times more against
    the image's pixels, and the noise floors are ``pixel`` times theirs."""
    velocity, error = _velocity_fit(
        means, masks, camera, frame_dt, frames, prior_speed, VELOCITY_NOISE_PX * pixel,
        REST_CHI2, size_weight, pixel,
    )  # fmt: skip
    if fall is None or not velocity.any() or fall - FALL_WINDOW_LESS <= frames:
        return velocity, error
    frames = fall - FALL_WINDOW_LESS
    return _velocity_fit(
        means, masks, camera, frame_dt, frames, prior_speed, FALL_NOISE_PX * pixel, 0.0,
        size_weight, pixel,
    )  # fmt: skip


def _velocity_fit(
    means: Tensor,  # [N, 3]
    masks: Tensor,  # [T, H, W]
    camera: CameraSpec,
    frame_dt: float,  # s
    frames: int,
    prior_speed: float,  # m/s
    noise_px: float,  # the pixel noise floor of the standard error
    rest_chi2: float,  # the test for a release from rest (0: none)
    size_weight: float,  # the size term's weight
    pixel: float,  # the masks' own pixel in image pixels
) -> tuple[Tensor, Tensor]:  # [3] m/s (world), [3] m/s standard error in the camera's axes
    """:func:`linear_velocity_fit` over frames 0..frames−1."""
    used = [t for t in range(min(frames, masks.shape[0])) if float(masks[t].sum()) > 0]
    if len(used) < 2:  # nothing to read: the prior (at rest, ± prior_speed)
        return torch.zeros(3), torch.full((3,), float(prior_speed))
    points = means.double()
    observed = torch.stack([_centroid(masks[t]) for t in used])  # [F, 2]
    areas = torch.stack([masks[t].double().sum() for t in used])  # [F] pixels
    growth = (areas / areas[0]).sqrt()  # apparent size relative to frame 0
    radius = size_weight * float((areas[0] / math.pi).sqrt())  # pixels: weighs the size term
    times = torch.tensor([t * frame_dt for t in used], dtype=torch.float64)
    centre0, depth0 = project(points.mean(0, keepdim=True), camera)
    offset = observed[0] - centre0[0]
    fall = torch.zeros(len(used), 3, dtype=torch.float64)
    fall[:, 2] = -0.5 * GRAVITY_MAGNITUDE * times**2

    def residual(velocity: Tensor) -> tuple[Tensor, Tensor]:  # [2F + F + 3], its Jacobian
        # the prior v · pixel / prior_speed against image pixels: v / prior_speed against the
        # masks' own
        return velocity_residual(
            velocity, points.mean(0), times, fall[:, 2], camera, observed - offset,
            growth, radius, float(depth0[0]), prior_speed / pixel,
        )  # fmt: skip

    velocity = torch.zeros(3, dtype=torch.float64)
    for _ in range(10):  # Gauss–Newton (the model is nearly linear in v over a few frames)
        r, J = residual(velocity)
        step = torch.linalg.lstsq(J, -r[:, None]).solution[:, 0]
        velocity = velocity + step
        if float(step.norm()) < 1e-6:
            break
    r, J = residual(velocity)
    pixels = r[:-3]  # the centroid's and the size's residuals (the last 3: the prior)
    noise = max(float((pixels**2).sum()) / max(len(pixels) - 3, 1), noise_px**2)
    covariance = noise * torch.linalg.inv(J.T @ J)  # [3, 3] world axes, (m/s)²
    eye = camera_centre(camera)

    def at_rest(factor: float) -> float:  # the pixels' sum of squares, at rest at factor × depth
        centres = eye + factor * (points.mean(0) - eye) + fall  # [F, 3]: the same ray at frame 0
        uv, depth = project(centres, camera)
        size = radius * (growth - depth[0] / depth)
        return float((uv + offset - observed).square().sum() + size.square().sum())

    low, high = REST_DEPTH_FACTORS
    factors = torch.logspace(math.log10(low), math.log10(high), 41).tolist() if low < high else [1]
    if (
        rest_chi2 > 0
        and min(at_rest(f) for f in factors) - float((pixels**2).sum()) < rest_chi2 * noise
    ):
        velocity = torch.zeros(3, dtype=torch.float64)  # the video is explained at rest
    rotation = camera.world_to_cam[:3, :3].double()
    across = (rotation @ covariance @ rotation.T).diagonal().sqrt()
    return velocity.float(), across.float()


def velocity_residual(
    velocity: Tensor,  # [3] m/s, world frame, float64
    centre: Tensor,  # [3] the object's centre at frame 0, world frame
    times: Tensor,  # [F] s after frame 0
    drop: Tensor,  # [F] m: the fall's z offset at those times (−g t² / 2)
    camera: CameraSpec,
    target: Tensor,  # [F, 2] px: where the projected centre should be
    growth: Tensor,  # [F] the masks' apparent size relative to frame 0
    radius: float,  # px: weighs the size residual
    depth0: float,  # m: the centre's depth at frame 0
    prior_speed: float,  # m/s
) -> tuple[Tensor, Tensor]:  # [3F + 3] residual, [3F + 3, 3] its Jacobian in the velocity
    """:func:`linear_velocity_fit`'s residual — the projected centre against ``target`` [2F,
    px], the apparent size radius · (growth − depth0 / depth) [F, px] and the prior v /
    prior_speed [3] — with its Jacobian, written out (a test checks it against autograd): the
    centre at t is c + t v + (0, 0, drop), in the camera p = R (·) + T, so ∂p/∂v = t R and
    ∂(f p_xy / p_z)/∂v = f (t R_xy − (p_xy / p_z) t R_z) / p_z, ∂(−depth0 / p_z)/∂v =
    depth0 t R_z / p_z²."""
    w2c = camera.world_to_cam.double()
    rotation, translation = w2c[:3, :3], w2c[:3, 3]
    K = camera.K.double()
    focal = torch.stack([K[0, 0], K[1, 1]])  # [2]
    principal = torch.stack([K[0, 2], K[1, 2]])
    centres = centre + times[:, None] * velocity  # [F, 3]
    centres = centres + torch.stack([torch.zeros_like(drop), torch.zeros_like(drop), drop], -1)
    cam = centres @ rotation.T + translation  # [F, 3]
    depth = cam[:, 2].clamp_min(1e-6)
    ratio = cam[:, :2] / depth[:, None]  # [F, 2]
    uv = ratio * focal + principal
    size = radius * (growth - depth0 / depth)
    r = torch.cat([(uv - target).reshape(-1), size, velocity / prior_speed])
    d_cam = times[:, None, None] * rotation  # [F, 3, 3]: ∂cam_i / ∂v_j
    d_ratio = (d_cam[:, :2] - ratio[..., None] * d_cam[:, 2:3]) / depth[:, None, None]
    d_uv = (focal[:, None] * d_ratio).reshape(-1, 3)  # [2F, 3]
    d_size = radius * depth0 * d_cam[:, 2] / depth[:, None] ** 2  # [F, 3]
    d_prior = torch.eye(3, dtype=torch.float64) / prior_speed
    return r, torch.cat([d_uv, d_size, d_prior])


def estimate_ground_height(
    means: Tensor,  # [N, 3] the object at frame 0 (its x, y locate it), world frame
    mask: Tensor,  # [H, W] a frame after landing (the last one)
    camera: CameraSpec,
) -> float | None:
    """World z where the ray through the landed silhouette's bottom (last frame) meets a vertical
    plane facing the camera at the object's position, moved half its horizontal radius towards
    the camera (the lowest visible point of a resting object is on its near side). A rough check
    of the camera's ground: ± (radius / 2) · tan(elevation) plus a pixel's depth. None for an
    empty mask or a camera looking straight down."""
    if float(mask.sum()) == 0:
        return None
    v, u = torch.nonzero(mask > 0.5, as_tuple=True)
    lowest = float(torch.quantile(v.double(), 0.99)) + 1.0  # bottom edge of the lowest rows
    columns = u[v.double() >= lowest - 2.0]
    pixel = torch.tensor([float(columns.double().mean()) + 0.5, lowest], dtype=torch.float64)
    origin, direction = ray(pixel, camera)
    points = means.double()
    centre = points.mean(0)
    normal = torch.tensor([origin[0] - centre[0], origin[1] - centre[1], 0.0], dtype=torch.float64)
    if float(normal.norm()) < 1e-9:
        return None
    normal = normal / normal.norm()
    radius = float((points[:, :2] - centre[:2]).norm(dim=1).max())
    anchor = centre + normal * (0.5 * radius)
    denominator = float(direction @ normal)
    if abs(denominator) < 1e-9:
        return None
    distance = float((anchor - origin) @ normal) / denominator
    return float((origin + distance * direction)[2])
