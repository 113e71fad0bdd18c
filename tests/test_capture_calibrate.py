"""The camera and ground read from a video (capture/calibrate.py), on exact silhouettes of a ball
that falls under gravity and lands, filmed by a known camera: the scale comes from g alone, the
ground from the first touch (or from where the ball rests); too short a fall is refused."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from helpers import rim_noise

from reconphys.capture.calibrate import (
    BELOW_DEPTH_SHARE,
    DROP_HEIGHT_ERROR_FLOOR_M,
    estimate_camera,
    object_depth,
)
from reconphys.capture.masks import read_release
from reconphys.errors import InputError
from reconphys.render.cameras import intrinsics_from_fov, look_at

G = 9.81


def ball_heights(
    drop: float, radius: float, braking_g: float | None, dt: float = 0.03, up: float = 0.0
):
    """Centre heights [30] of a ball released from rest (or thrown up at ``up`` m/s) ``drop`` m
    above the ground: it stops dead at the touch (``braking_g`` None) or, like a soft object
    squashing, its centre slows at a constant ``braking_g``·g after it (its silhouette sinks
    through the floor, which the masks do not draw) and then rests."""
    touch = (up + math.sqrt(up**2 + 2 * G * drop)) / G
    heights = []
    for k in range(30):
        t = k * dt
        if t <= touch or braking_g is None:
            heights.append(radius + max(drop + up * t - 0.5 * G * t**2, 0.0))
            continue
        speed, braking = G * touch - up, braking_g * G
        s = min(t - touch, speed / braking)
        heights.append(radius - (speed * s - 0.5 * braking * s**2))
    return heights


def ball_masks(
    pitch_deg: float,
    distance: float,
    drop: float,
    radius: float,
    size: int = 96,
    fov=45.0,
    braking_g: float | None = None,
    dt: float = 0.03,
    up: float = 0.0,
):
    """Masks [30, size, size] of a ball released from rest ``drop`` m above the ground, landing
    as :func:`ball_heights` says, seen by a camera pitched down by ``pitch_deg`` aimed at its
    landing point from ``distance`` m; returns the masks, the camera's world_to_cam and the
    ball's path."""
    heights = ball_heights(drop, radius, braking_g, dt, up)
    centres = np.array([[0.0, 0.0, z] for z in heights])
    pitch = math.radians(pitch_deg)
    target = np.array([0.0, 0.0, radius + 0.5 * drop])
    eye = target + distance * np.array([math.cos(pitch), 0.0, math.sin(pitch)])
    w2c = look_at(torch.tensor(eye), torch.tensor(target)).numpy()
    K = intrinsics_from_fov(fov, size, size, dtype=torch.float64).numpy()
    v, u = np.mgrid[0:size, 0:size] + 0.5
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    masks = []
    for c in centres:
        cam = w2c[:3, :3] @ c + w2c[:3, 3]
        along = rays @ cam
        closest = np.linalg.norm(rays * along[..., None] - cam, axis=-1)
        masks.append((closest <= radius) & (along > 0))
    return torch.from_numpy(np.stack(masks)).float(), w2c, centres


@pytest.mark.parametrize("pitch_deg", [8.0, 25.0])
def test_the_pitch_is_weakly_observed_and_costs_scale_within_ten_percent(pitch_deg):
    """A fall barely shows the camera's pitch (a prior of 15° ± 30° holds it): 8° and 25° come
    back near 15°, which costs the distance (∝ cos θ) a few per cent."""
    masks, w2c, centres = ball_masks(pitch_deg, 2.0, 0.45, 0.1)
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
    true_distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
    assert abs(estimate.pitch_deg - 15.0) < abs(pitch_deg - 15.0)
    assert estimate.distance == pytest.approx(true_distance, rel=0.1)


def _frame0_bottom_height(estimate, w2c, centres, radius) -> float:
    """The ball's frame-0 bottom seen through the estimated camera at the estimated depth: its
    height above the estimated ground (the drop height the asset gets), metres."""
    true_distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
    cam = w2c[:3, :3] @ (centres[0] - [0, 0, radius]) + w2c[:3, 3]
    cam = cam * estimate.distance / true_distance
    est = estimate.camera.world_to_cam.double().numpy()
    return float((est[:3, :3].T @ (cam - est[:3, 3]))[2])


def test_scale_and_ground_of_a_falling_ball_that_lands_softly():
    """A soft landing (the centre slows at 5 g after the touch): the touch is found to a sixth
    of a frame, and the ground through the lowest point at the touch puts the frame-0 bottom
    ``drop`` above it, to a couple of centimetres. (The camera's height is read less well: it
    goes with the pitch, which the fall barely shows.)"""
    radius, drop, distance = 0.1, 0.45, 2.0
    masks, w2c, centres = ball_masks(15.0, distance, drop, radius, braking_g=5.0)
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
    assert estimate.fall_frames >= 8 and estimate.residual_px < 0.2
    true_distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
    assert estimate.distance == pytest.approx(true_distance, rel=0.02)  # the scale, from g
    assert estimate.pitch_deg == pytest.approx(15.0, abs=3.0)
    touch = math.sqrt(2 * drop / G)
    assert estimate.contact_s == pytest.approx(touch, abs=0.005)
    camera_height = float(-(w2c[:3, :3].T @ w2c[:3, 3])[2])
    assert estimate.height == pytest.approx(camera_height, abs=0.08)
    # a ball's near bottom edge is its lowest point: the lean taken off for a box's costs it
    lean = BELOW_DEPTH_SHARE * radius * math.sin(math.radians(estimate.pitch_deg))  # 1.3 cm
    bottom = _frame0_bottom_height(estimate, w2c, centres, radius)
    assert bottom == pytest.approx(drop - lean, abs=0.015)
    # the object starts above the origin, and the camera looks at it from the +x side
    est = estimate.camera.world_to_cam.double().numpy()
    centre = est[:3, :3].T @ (
        (w2c[:3, :3] @ centres[0] + w2c[:3, 3]) * estimate.distance / true_distance - est[:3, 3]
    )
    assert abs(centre[0]) < 0.05 and abs(centre[1]) < 0.05
    assert float(-(est[:3, :3].T @ est[:3, 3])[0]) > 0
    assert "first touch" in estimate.to_json()["ground_from"]


def box_masks(pitch_deg: float, distance: float, drop: float, half: tuple, size: int = 96):
    """Masks [30, size, size] of an axis-aligned box (half extents ``half`` = x, y, z metres)
    released from rest ``drop`` m above the ground and slowing at 5 g after its touch (as
    :func:`ball_masks`, ray–box slabs), seen from the +x side pitched down by ``pitch_deg``;
    returns the masks, world_to_cam and the box's centres."""
    half = np.array(half, dtype=np.float64)
    heights = ball_heights(drop, half[2], 5.0)
    centres = np.array([[0.0, 0.0, z] for z in heights])
    pitch = math.radians(pitch_deg)
    target = np.array([0.0, 0.0, half[2] + 0.5 * drop])
    eye = target + distance * np.array([math.cos(pitch), 0.0, math.sin(pitch)])
    w2c = look_at(torch.tensor(eye), torch.tensor(target)).numpy()
    K = intrinsics_from_fov(45.0, size, size, dtype=torch.float64).numpy()
    v, u = np.mgrid[0:size, 0:size] + 0.5
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays = rays @ w2c[:3, :3]  # world directions [H, W, 3]
    rays = np.where(np.abs(rays) < 1e-12, 1e-12, rays)
    masks = []
    for c in centres:
        t1, t2 = (c - half - eye) / rays, (c + half - eye) / rays
        near = np.minimum(t1, t2).max(-1)
        far = np.maximum(t1, t2).min(-1)
        masks.append(far >= np.maximum(near, 0.0))
    return torch.from_numpy(np.stack(masks)).float(), w2c, centres


def test_a_box_seen_from_above_shows_its_near_bottom_edge(monkeypatch):
    """A flat box (0.3 × 0.3 × 0.1 m) filmed from 15° above: its silhouette's lowest point is
    its near bottom edge, below its lowest point by about its half-depth × sin 15° on the image
    (3.9 cm), which read as its extent below the centre puts the ground too low (the drop 3.5
    cm too high); half the lean taken off (BELOW_DEPTH_SHARE) leaves 1.4 cm, and costs a ball
    r/2 · sin θ (the test above). (From 30° the pitch is read near the prior's 15° and so is
    the lean: 7.5 → 5.1 cm.)"""
    from reconphys.capture import calibrate

    drop, half = 0.45, (0.15, 0.15, 0.05)
    masks, w2c, centres = box_masks(15.0, 2.0, drop, half)
    errors = {}
    for share in (0.0, BELOW_DEPTH_SHARE):
        monkeypatch.setattr(calibrate, "BELOW_DEPTH_SHARE", share)
        estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
        assert "first touch" in estimate.to_json()["ground_from"]
        errors[share] = _frame0_bottom_height(estimate, w2c, centres, half[2]) - drop
    assert 0.025 < errors[0.0] < 0.05  # the whole lean kept: the drop read too high
    assert abs(errors[BELOW_DEPTH_SHARE]) < 0.5 * errors[0.0]


def test_a_ball_that_stops_dead_reads_its_touch_early():
    """The touch's model is a push that builds (a soft object): a ball that stops dead leaves
    the parabola in a straight line, and the fit puts the touch early, within a frame: the
    ground comes out high, the drop short, by less than the ball's radius."""
    radius, drop = 0.1, 0.45
    masks, w2c, centres = ball_masks(15.0, 2.0, drop, radius)
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
    touch = math.sqrt(2 * drop / G)
    assert touch - 0.03 < estimate.contact_s < touch
    bottom = _frame0_bottom_height(estimate, w2c, centres, radius)
    assert drop - radius < bottom < drop - 0.01


def test_each_touch_model_reads_its_own_kind_of_landing():
    """``touch="rigid"`` lets the push stop the fall at once: a ball that stops dead is read to a
    fifth of a frame and its drop to a few centimetres, where the soft model reads it most of a
    frame early; a ball that squashes (5 g after the touch) is read better by the soft model,
    which the rigid one reads late. The default stays "soft"."""
    radius, drop = 0.1, 0.45
    touch = math.sqrt(2 * drop / G)
    errors = {}
    for braking_g in (None, 5.0):
        masks, w2c, centres = ball_masks(15.0, 2.0, drop, radius, braking_g=braking_g)
        for model in ("soft", "rigid"):
            estimate = estimate_camera(masks, 0.03, fov_deg=45.0, touch=model)
            assert estimate.to_json()["touch"] == model
            bottom = _frame0_bottom_height(estimate, w2c, centres, radius)
            lean = BELOW_DEPTH_SHARE * radius * math.sin(math.radians(estimate.pitch_deg))
            errors[braking_g, model] = (abs(estimate.contact_s - touch), abs(bottom + lean - drop))
    assert errors[None, "rigid"][0] < 0.006 and errors[None, "rigid"][1] < 0.03
    assert all(r < s for r, s in zip(errors[None, "rigid"], errors[None, "soft"], strict=True))
    assert all(s < r for s, r in zip(errors[5.0, "soft"], errors[5.0, "rigid"], strict=True))
    with pytest.raises(InputError, match="soft, rigid"):
        estimate_camera(masks, 0.03, fov_deg=45.0, touch="hard")


def test_a_clip_that_ends_before_the_touch_reads_the_ground_from_the_rest():
    """Without frames after the fall's end the touch is not shown: the ground comes from where
    the ball rests (the silhouette's bottom moved nearer by the half-width: a box's near edge,
    chosen on held-out pybullet meshes; a ball's bottom is not nearer, so its ground comes out
    about r/2 high, its drop that much short)."""
    radius, drop = 0.1, 0.45
    masks, w2c, centres = ball_masks(15.0, 2.0, drop, radius)
    count = estimate_camera(masks, 0.03, fov_deg=45.0).fall_frames
    short = masks[: count + 1]  # the fall and one frame after it
    estimate = estimate_camera(short, 0.03, fov_deg=45.0)
    assert estimate.contact_s is None and "rests" in estimate.to_json()["ground_from"]
    bottom = _frame0_bottom_height(estimate, w2c, centres, radius)
    assert bottom == pytest.approx(drop - 0.5 * radius, abs=0.02)


def test_a_touch_whose_ground_is_above_frame_0_is_set_aside(monkeypatch):
    """A ball thrown up at 1.2 m/s (it rises 7 cm, then falls 45 cm): a touch read at 0.15 s,
    near the top (as on a rising stick whose turn the centroid took for a touch), puts the
    ground above the ball's frame 0, where it is in the air: the estimate sets the touch aside,
    reads the ground from the rest (as a clip without the touch does, the test above) and says
    so; kept (the rule before), the drop height reads below zero."""
    from reconphys.capture import calibrate

    radius, drop = 0.1, 0.45
    masks, w2c, centres = ball_masks(15.0, 2.0, drop, radius, up=1.2)
    monkeypatch.setattr(calibrate, "contact_time", lambda *args, **kwargs: 0.15)
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
    assert estimate.contact_s is None and estimate.contact_set_aside_s == 0.15
    assert "a touch read at 0.150 s put the ground above" in estimate.to_json()["ground_from"]
    assert estimate.to_json()["contact_set_aside_s"] == 0.15
    # within a radius, as the dead stop's own touch reads it (a test above): 0.35 m, 0.36 m
    bottom = _frame0_bottom_height(estimate, w2c, centres, radius)
    assert drop - radius < bottom < drop - 0.01 and estimate.drop_height > 0.3
    monkeypatch.setattr(calibrate, "CLEARANCE_SLACK_PX", math.inf)  # the rule before: kept
    kept = estimate_camera(masks, 0.03, fov_deg=45.0)
    assert kept.contact_s == 0.15 and kept.drop_height < -0.03
    assert kept.drop_height_10_90[1] >= 0.0  # an interval never below the ground
    assert dataclasses.replace(kept, drop_height=-0.2).drop_height_10_90 == (0.0, 0.0)


def test_a_rest_above_frame_0_is_refused(monkeypatch):
    """Masks that show the ball falling for 14 frames and then resting 12 px higher than its
    frame 0 (a fall and a rest that cannot both be right) give no touch, and a ground read from
    that rest lies above the ball's frame 0: refused, with what to give, not answered. A soft
    landing's rest (the silhouette sinks below where it rests, under its fall's fit) is read."""
    from reconphys.capture import calibrate

    radius, drop = 0.1, 0.45
    masks = ball_masks(15.0, 2.0, drop, radius, braking_g=5.0)[0]
    raised = torch.roll(masks[:1], -12, dims=1).expand(8, -1, -1)
    mixed = torch.cat([masks[:14], raised])
    monkeypatch.setattr(calibrate, "contact_time", lambda *args, **kwargs: None)
    with pytest.raises(InputError, match=r"cm above the falling object.*--camera FILE"):
        estimate_camera(mixed, 0.03, fov_deg=45.0)
    assert estimate_camera(masks, 0.03, fov_deg=45.0).drop_height > 0.3  # its own rest: read
    monkeypatch.setattr(calibrate, "CLEARANCE_SLACK_PX", math.inf)  # the rule before: answered
    assert estimate_camera(mixed, 0.03, fov_deg=45.0).drop_height < 0


def test_a_wrong_focal_length_moves_the_camera_not_the_object():
    radius, drop = 0.1, 0.45
    masks, *_ = ball_masks(15.0, 2.0, drop, radius, fov=45.0)
    right = estimate_camera(masks, 0.03, fov_deg=45.0)
    wrong = estimate_camera(masks, 0.03, fov_deg=60.0)
    f_right, f_wrong = float(right.camera.K[1, 1]), float(wrong.camera.K[1, 1])
    assert wrong.distance < 0.85 * right.distance  # wider view: the object is nearer
    size_right = right.distance / f_right  # metres per pixel at the object
    size_wrong = wrong.distance / f_wrong
    assert size_wrong == pytest.approx(size_right, rel=0.05)


def test_masks_that_make_the_object_metres_across_are_refused():
    """A fall read eight times slower than it was (as masks that do not follow the object can
    read: a segmenter on a scene it does not know) puts a 0.2 m ball 64 times as far and as
    large: more than MAX_READ_SIZE_M across, so refused with what to give instead; the same
    masks at their own frame rate pass."""
    from reconphys.capture.calibrate import MAX_READ_SIZE_M

    masks, *_ = ball_masks(15.0, 2.0, 0.45, 0.1)
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0)  # at its own rate: passes
    assert estimate.distance == pytest.approx(2.0, rel=0.1)
    assert 0.2 * 64 > MAX_READ_SIZE_M > 10 * 0.2  # a ten times larger object would pass
    with pytest.raises(InputError, match=r"m across.*--camera FILE"):
        estimate_camera(masks, 8 * 0.03, fov_deg=45.0)


def test_a_fall_too_short_to_show_the_scale_is_refused():
    """Refused naming the camera file, and no turn of the video: nothing falls sideways or up."""
    masks, *_ = ball_masks(15.0, 2.0, 0.004, 0.1)  # released 4 mm above the ground
    with pytest.raises(InputError, match="--camera FILE") as refused:
        estimate_camera(masks, 0.03)
    assert "upright" not in str(refused.value)
    still = masks[-1:].expand(30, -1, -1).clone()  # nothing falls at all
    with pytest.raises(InputError, match="--camera FILE") as refused:
        estimate_camera(still, 0.03)
    assert "upright" not in str(refused.value)


def test_the_segmenters_masks_need_a_fall_of_five_frames():
    """A 4-frame fall (8 cm) is read from exact masks (the true distance, 2.03 m, to 2 %); with
    the mask segmenter's tolerance the same fall is refused, naming the frames it needs: its
    errors come in runs of frames that one check per axis cannot see."""
    from reconphys.capture.calibrate import SEGMENTER_FALL_FIT_PX, min_fall_frames

    masks, w2c, centres = ball_masks(15.0, 2.0, 0.08, 0.1)
    exact = estimate_camera(masks, 0.03, fov_deg=45.0)
    true_distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
    assert exact.fall_frames == 4 and abs(exact.distance / true_distance - 1) < 0.02
    assert min_fall_frames(SEGMENTER_FALL_FIT_PX) == 5
    with pytest.raises(InputError, match=r"in 4 frame\(s\) \(fewer than 5 with the mask segm"):
        estimate_camera(masks, 0.03, fov_deg=45.0, fit_px=SEGMENTER_FALL_FIT_PX)


def test_a_fall_read_past_a_soft_landing_is_cut_at_the_touch():
    """A ball that lands softly (braking at 1.5 g after its touch, 8.24 frames in): at the
    segmenter's one-pixel tolerance a parabola runs 2 frames past the touch and reads the fall
    slower, the ball 6 % too far; the touch read inside that window ends the fall there, and
    the fit on the frames before it reads the distance to 2 %."""
    from reconphys.capture.calibrate import (
        SEGMENTER_FALL_FIT_PX,
        _fit_fall,
        fall_frames,
        mask_track,
    )

    masks, w2c, centres = ball_masks(15.0, 2.0, 0.3, 0.1, braking_g=1.5)
    distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
    track = mask_track(masks)
    assert fall_frames(track, 0.03, SEGMENTER_FALL_FIT_PX) == 11
    K = intrinsics_from_fov(45.0, 96, 96, dtype=torch.float64).numpy()
    uncut = float(np.linalg.norm(_fit_fall(track, 11, 0.03, K)[0][:3]))
    assert uncut / distance - 1 > 0.05
    estimate = estimate_camera(masks, 0.03, fov_deg=45.0, fit_px=SEGMENTER_FALL_FIT_PX)
    assert estimate.fall_frames == 9 and abs(estimate.contact_s / 0.03 - 8.24) < 0.3
    assert abs(estimate.distance / distance - 1) < 0.02


def test_a_size_read_to_worse_than_a_factor_of_three_is_refused():
    """A short fall (0.1 m, 5 frames), its masks a pixel's rim off at random as a segmenter's
    can be: the size's 10–90 % interval spans ×0.03–×29 (a guess, not a reading), so it is
    refused with what to give; the same fall with exact masks is read to within ×1.5."""
    from reconphys.capture.calibrate import MAX_SIZE_FACTOR, SEGMENTER_FALL_FIT_PX

    masks, *_ = ball_masks(15.0, 2.0, 0.1, 0.1)
    exact = estimate_camera(masks, 0.03, fov_deg=45.0)
    assert exact.size_factor_10_90[1] < 1.5 < MAX_SIZE_FACTOR
    noisy = rim_noise(masks, np.random.default_rng(1))
    with pytest.raises(InputError, match=r"size only to ×0\.\d+–×\d.*--camera FILE"):
        estimate_camera(noisy, 0.03, fov_deg=45.0, fit_px=SEGMENTER_FALL_FIT_PX)


def test_a_pixel_of_mask_noise_needs_the_segmenters_tolerance(monkeypatch):
    """Masks that gain or lose a pixel's rim on one side at random (as the mask segmenter's do)
    break a half-pixel parabola early, and a short fall reads the scale badly; at the segmenter's
    tolerance (a pixel) the fall is read to its landing and the distance comes back (20 draws:
    6 frames and 29 % off against 10 frames and 10 % off)."""
    from reconphys.capture import calibrate
    from reconphys.capture.calibrate import FALL_FIT_PX, SEGMENTER_FALL_FIT_PX

    # the half-pixel tolerance's short falls are read at all here (predict refuses the widest)
    monkeypatch.setattr(calibrate, "MAX_SIZE_FACTOR", math.inf)
    masks, _, _ = ball_masks(15.0, 2.0, 0.45, 0.1)
    exact = estimate_camera(masks, 0.03, fov_deg=45.0)
    frames = {FALL_FIT_PX: [], SEGMENTER_FALL_FIT_PX: []}
    errors = {fit: [] for fit in frames}
    for seed in range(20):
        noisy = rim_noise(masks, np.random.default_rng(seed))
        for fit in frames:
            estimate = estimate_camera(noisy, 0.03, fov_deg=45.0, fit_px=fit)
            frames[fit].append(estimate.fall_frames)
            errors[fit].append(abs(estimate.distance / exact.distance - 1))
    tight, loose = FALL_FIT_PX, SEGMENTER_FALL_FIT_PX
    assert np.mean(frames[loose]) >= np.mean(frames[tight]) + 2
    assert np.mean(errors[loose]) < 0.5 * np.mean(errors[tight])
    assert exact.fall_frames >= np.mean(frames[loose]) - 1  # not past the landing


@pytest.mark.parametrize("braking_g, found", [(5.0, True), (0.5, False)])
def test_a_touch_must_brake_the_fall_by_at_least_g(braking_g, found):
    """The centroid leaving the fall's path as −c·(t − t_c)²: found to the grid's step when it
    brakes like a landing (5 g); a slow drift (0.5 g, a fall misread) is not taken for a touch,
    though it moves the centroid by more than CONTACT_MIN_PX."""
    from reconphys.capture.calibrate import CONTACT_MIN_PX, _Track, contact_time

    dt, count, frames, touch = 0.03, 10, 16, 9.4 * 0.03
    metres_per_px = 0.005
    c = braking_g * G / (2 * metres_per_px)  # px/s²
    t = np.arange(frames) * dt
    height = -c * np.clip(t - touch, 0, None) ** 2
    track = _Track(
        centroid=np.stack([np.zeros(frames), height], 1),
        bottom=np.zeros(frames),
        width=np.ones(frames),
        area=np.ones(frames),
    )
    assert -height[count + 2] > CONTACT_MIN_PX
    read = contact_time(track, count, dt, np.zeros(frames), metres_per_px)
    if found:
        assert read == pytest.approx(touch, abs=0.001)
    else:
        assert read is None


def test_a_touch_is_read_in_the_masks_own_pixels():
    """The same landing seen 5× larger, in masks whose own pixel is 5 image pixels (the
    segmenter's 128-px reading brought to 640): read at the same time. A push of 6 image pixels,
    a touch in exact masks, is a rim's flicker in those masks (under CONTACT_MIN_PX of their
    pixels): not taken."""
    from reconphys.capture.calibrate import (
        CONTACT_MIN_PX,
        FALL_FIT_PX,
        SEGMENTER_FALL_FIT_PX,
        _Track,
        contact_time,
        mask_pixel,
    )

    assert mask_pixel(FALL_FIT_PX) == mask_pixel(SEGMENTER_FALL_FIT_PX) == 1.0
    assert mask_pixel(5 * SEGMENTER_FALL_FIT_PX) == 5.0
    dt, count, frames, touch = 0.03, 10, 16, 9.4 * 0.03

    def track(scale: float, push_px: float) -> _Track:  # a push of push_px by count + 2
        t = np.arange(frames) * dt
        height = -push_px * np.clip(t - touch, 0, None) ** 2 / ((count + 2) * dt - touch) ** 2
        return _Track(
            centroid=scale * np.stack([np.zeros(frames), height], 1),
            bottom=np.zeros(frames),
            width=np.ones(frames),
            area=np.ones(frames),
        )

    metres_per_px = 0.005  # 6 px by 2.6 frames after the touch: a brake of ~4 g
    found = contact_time(track(1, 6.0), count, dt, np.zeros(frames), metres_per_px)
    assert found == pytest.approx(touch, abs=0.001)
    enlarged = contact_time(track(5, 6.0), count, dt, np.zeros(frames), metres_per_px / 5, pixel=5)
    assert enlarged == pytest.approx(found, abs=1e-9)
    assert 6.0 < CONTACT_MIN_PX * 5
    assert contact_time(track(1, 6.0), count, dt, np.zeros(frames), metres_per_px, pixel=5) is None


def test_the_size_interval_holds_the_truth_and_widens_with_a_shorter_fall():
    """The object's size read from the fall comes with a 10–90 % interval (prediction.json's
    size_factor_10_90): it holds the true size over the read one for cameras near the pitch
    prior, a camera 10° off it (whose cost the fit cannot see: an interval misses one time in
    five) is within twice it, and a shorter fall (fewer frames to read g from) reads it less
    well."""
    widths = {}
    for pitch_deg, drop in ((8.0, 0.45), (15.0, 0.45), (15.0, 0.15), (25.0, 0.45)):
        masks, w2c, centres = ball_masks(pitch_deg, 2.0, drop, 0.1)
        estimate = estimate_camera(masks, 0.03, fov_deg=45.0)
        true_distance = float(np.linalg.norm(w2c[:3, :3] @ centres[0] + w2c[:3, 3]))
        low, high = estimate.size_factor_10_90
        error = abs(math.log(true_distance / estimate.distance))
        assert error < (2 if pitch_deg == 25.0 else 1) * math.log(high)
        assert low == pytest.approx(1 / high) and high < 1.3
        written = estimate.to_json()
        assert written["size_factor_10_90"] == [round(low, 3), round(high, 3)]
        lo_m, hi_m = written["distance_m_10_90"]  # the same interval in metres: holds the truth
        assert lo_m < estimate.distance < hi_m and lo_m == pytest.approx(
            estimate.distance * low, abs=1e-4
        )
        if pitch_deg != 25.0:
            assert lo_m <= true_distance <= hi_m
        assert written["camera_height_m_10_90"][1] == pytest.approx(estimate.height * high, 1e-3)
        widths[(pitch_deg, drop)] = (high, estimate.fall_frames)
    (long_high, long_frames), (short_high, short_frames) = (
        widths[(15.0, 0.45)],
        widths[(15.0, 0.15)],
    )
    assert short_frames < long_frames and short_high > long_high


def test_the_drop_height_is_read_with_an_interval_that_holds_it():
    """prediction.json's ``drop_height_m``: frame 0's lowest silhouette point above the ground
    read (with a touch, the fall's length until it). The soft ball dropped 0.45 m comes back to
    2 cm; read from the rest (no touch in the clip), r/2 short, as the rest rule places a ball's
    ground. Its 10–90 % interval is the size's relative error times the height beside a floor
    of DROP_HEIGHT_ERROR_FLOOR_M, and holds both; it never goes below the ground."""
    radius, drop = 0.1, 0.45
    touched = estimate_camera(ball_masks(15.0, 2.0, drop, radius, braking_g=5.0)[0], 0.03, 45.0)
    masks = ball_masks(15.0, 2.0, drop, radius)[0]  # stops dead: at rest after the fall
    count = estimate_camera(masks, 0.03, fov_deg=45.0).fall_frames
    rested = estimate_camera(masks[: count + 1], 0.03, fov_deg=45.0)
    assert touched.contact_s is not None and rested.contact_s is None
    assert touched.drop_height == pytest.approx(drop, abs=0.02)
    assert rested.drop_height == pytest.approx(drop - 0.5 * radius, abs=0.02)
    for estimate in (touched, rested):
        low, high = estimate.drop_height_10_90
        half = 1.2816 * math.hypot(
            estimate.drop_height * estimate.scale_spread, DROP_HEIGHT_ERROR_FLOOR_M
        )
        assert high - estimate.drop_height == pytest.approx(half, rel=1e-3)
        assert low == pytest.approx(max(estimate.drop_height - half, 0.0), abs=1e-4)
        assert low <= drop <= high
        written = estimate.to_json()
        assert written["drop_height_m"] == round(estimate.drop_height, 4)
        assert written["drop_height_m_10_90"] == [round(low, 4), round(high, 4)]
    low_drop = ball_masks(15.0, 2.0, 0.05, radius, braking_g=5.0)[0]
    assert estimate_camera(low_drop, 0.03, fov_deg=45.0).drop_height_10_90[0] == 0.0


def test_a_drop_height_given_puts_the_ground_there_and_keeps_the_videos_read_beside():
    """``--drop-height``: the ground goes that far below frame 0's lowest point (seen through the
    estimated camera: the frame-0 bottom moves up by exactly the difference to the read), the
    fall's scale and pitch unchanged, the video's own read kept beside; a value outside the
    read's 10–90 % interval is kept with a warning; one shorter than the free fall the video
    shows is refused; the larger copy of the masks reads it alike."""
    radius, drop = 0.1, 0.45
    masks, w2c, centres = ball_masks(15.0, 2.0, drop, radius, braking_g=5.0)
    read = estimate_camera(masks, 0.03, fov_deg=45.0)
    given = estimate_camera(masks, 0.03, fov_deg=45.0, drop_height=0.40)
    assert given.drop_height == pytest.approx(0.40, abs=1e-9)
    assert given.drop_height_10_90 == (given.drop_height, given.drop_height)
    for name in ("distance", "pitch_deg", "scale_spread", "contact_s"):
        assert getattr(given, name) == pytest.approx(getattr(read, name), rel=1e-9), name
    assert given.drop_height_read == pytest.approx(read.drop_height, rel=1e-9)
    moved = _frame0_bottom_height(given, w2c, centres, radius)
    assert moved - _frame0_bottom_height(read, w2c, centres, radius) == pytest.approx(
        0.40 - read.drop_height, abs=1e-9
    )
    written = given.to_json()
    assert "--drop-height 0.4 m" in written["ground_from"] and written["drop_height_m"] == 0.4
    assert written["drop_height_read_m"] == round(read.drop_height, 4)
    assert "drop_height_warning" not in written and "drop_height_read_m" not in read.to_json()
    assert written["drop_height_given"] and not read.to_json()["drop_height_given"]
    far = estimate_camera(masks, 0.03, fov_deg=45.0, drop_height=0.9)
    assert "not the 0.90 m given" in far.to_json()["drop_height_warning"]
    with pytest.raises(InputError, match=r"falls freely \d+ cm in the video") as refused:
        estimate_camera(masks, 0.03, fov_deg=45.0, drop_height=0.2)
    assert refused.value.field == "--drop-height"
    large = masks.repeat_interleave(2, 1).repeat_interleave(2, 2)  # read at the rules' size
    twice = estimate_camera(large, 0.03, fov_deg=45.0, drop_height=0.40)
    assert twice.drop_height == pytest.approx(0.40, abs=1e-9) and twice.drop_height_given


def _held_disc(
    release: float,
    held_row: float = 12.0,
    accel: float = 900.0,
    count: int = 30,
    across: float = 0.0,  # m/s to the right from the release (accel / 9.8 px a metre)
):
    """[T, 64, 64] masks of a disc (radius 9 px) held at ``held_row`` until ``release`` seconds,
    then falling from rest, ½ accel (t − release)² pixels (rows down), frames 0.03 s apart."""
    rows, cols = torch.meshgrid(torch.arange(64.0) + 0.5, torch.arange(64.0) + 0.5, indexing="ij")
    masks = []
    for k in range(count):
        since = max(0.0, k * 0.03 - release)
        centre = min(held_row + 0.5 * accel * since**2, 50.0)
        col = 24.0 + across * accel / 9.8 * since
        masks.append(((rows - centre) ** 2 + (cols - col) ** 2 <= 81.0).float())
    return torch.stack(masks)


def test_the_release_of_a_held_object_is_read_from_its_fall():
    """An object held still, then falling from rest: the release time comes back to a fraction of
    a frame wherever it falls between frames; an object moving from frame 0, or never, gives
    None."""
    for release in (0.21, 0.2475, 0.3333):
        found = read_release(_held_disc(release), 0.03)
        assert found.time_s == pytest.approx(release, abs=0.3 * 0.03), release
        assert found.from_rest
    assert read_release(_held_disc(-0.05), 0.03) is None  # falling from the start: not held
    assert read_release(_held_disc(5.0), 0.03) is None  # never released


def test_a_held_object_is_let_go_at_rest_or_thrown():
    """read_release's ``from_rest``: a disc held, then falling from rest, is let go at rest, also
    when its column wanders by a fraction of a pixel (a hand's fingers in its masks); the same
    disc leaving sideways at 0.5 m/s (the slowest throw of the data) or 0.3 m/s is thrown, and
    its speed across is read in metres from the fall's own pixels per metre."""
    assert read_release(_held_disc(0.25), 0.03).across_m_s == pytest.approx(0.0, abs=0.02)
    for speed in (0.3, 0.5, 1.0):
        read = read_release(_held_disc(0.25, across=speed), 0.03)
        assert not read.from_rest and read.across_m_s == pytest.approx(speed, rel=0.15), speed
    assert read_release(_held_disc(0.25, across=0.1), 0.03).from_rest


def test_the_release_is_read_in_the_masks_own_pixels():
    """A held disc whose centroid jitters by a pixel as it falls, and the same masks enlarged ×5
    (a 128-px segmentation brought to 640): read with ``pixel=5`` the same release as the small
    one; weighed in the image's pixels the noise allowance is 25× smaller, and on two of 60 such
    clips that chooses the other fall model (clip 12 here: the release 65 ms apart)."""
    rng = np.random.default_rng(12)
    release = rng.uniform(0.2, 0.35)
    small = _held_disc(release, accel=400.0)
    for k in range(len(small)):  # after the release the disc is a pixel lower half the time
        if k * 0.03 > release and rng.uniform() < 0.5:
            small[k] = torch.roll(small[k], 1, 0)
    large = small.repeat_interleave(5, 1).repeat_interleave(5, 2)
    read = read_release(small, 0.03).time_s
    assert read_release(large, 0.03, 5.0).time_s == pytest.approx(read, abs=1e-9)
    assert abs(read_release(large, 0.03).time_s - read) > 0.03


def _ball_and_its_camera():
    """A ball's exact masks [30, 96, 96] dropped 0.45 m, 2 m from a camera 15° down, and that
    camera (45° field of view) as a camera file's."""
    from reconphys.capture.camera import CameraSpec

    masks, w2c, _ = ball_masks(15.0, 2.0, 0.45, 0.1)
    K = intrinsics_from_fov(45.0, 96, 96, dtype=torch.float64)
    return masks, CameraSpec(K, torch.from_numpy(w2c), 96, 96, 0.0, "cam.json")


def test_a_camera_file_must_fit_the_fall():
    """check_camera_file: a ball's exact masks pass with their own camera (the fall within a few
    degrees of gravity's image direction); the same camera in OpenGL's convention (y up, z
    backwards) sees the object fall away from gravity, a camera under the ground is refused, and
    a clip filmed from below that ends before the landing has no ground under the object."""
    from reconphys.capture.calibrate import (
        FALL_CHECK_PX,
        SEGMENTER_FALL_FIT_PX,
        check_camera_file,
        fall_direction,
        rule_size_masks,
    )
    from reconphys.capture.camera import CameraSpec

    masks, camera = _ball_and_its_camera()
    angle, moved, across = fall_direction(masks, 0.03, camera)
    assert angle < 3.0 and moved > 10.0 and across > 0.9
    check_camera_file(masks, 0.03, camera, 0.5)  # no error
    # a phone's larger frames are read at the rules' size, as estimate_camera reads them: the
    # same answer as the masks brought down to it, the pixels moved in the large masks' own
    large = masks.repeat_interleave(3, 1).repeat_interleave(3, 2)  # [T, 288, 288]
    small = rule_size_masks(large)
    read = fall_direction(large, 0.03, camera.resized(288, 288))
    expected = fall_direction(small, 0.03, camera.resized(128, 128))
    assert read[0] == expected[0] and read[1] == pytest.approx(expected[1] * 288 / 128)
    assert read[0] < 3.0 and read[1] == pytest.approx(3 * moved, rel=0.05)
    flipped = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
    opengl = CameraSpec(camera.K, flipped @ camera.world_to_cam, 96, 96, 0.0, "cam.json")
    assert fall_direction(masks, 0.03, opengl)[0] > 177.0
    with pytest.raises(InputError, match=r"cam.json \[world_to_cam\]: in this camera the object "):
        check_camera_file(masks, 0.03, opengl, 0.5)
    # the fall's direction is read once it moves FALL_CHECK_PX of the masks' own pixels: not in
    # masks whose pixel is more than moved / FALL_CHECK_PX image pixels (calibrate.mask_pixel)
    coarse = (moved / FALL_CHECK_PX + 1) * SEGMENTER_FALL_FIT_PX
    with pytest.raises(InputError) as refused:
        check_camera_file(masks, 0.03, opengl, coarse)
    assert "falls" not in str(refused.value)
    under = CameraSpec(camera.K, camera.world_to_cam, 96, 96, 3.0, "cam.json")  # the ground 3 m up
    with pytest.raises(InputError, match="below the ground"):
        check_camera_file(masks, 0.03, under, 0.5)
    masks, w2c, _ = ball_masks(-40.0, 3.0, 5.0, 0.1, fov=60.0)  # from below; lands after 1 s
    K = intrinsics_from_fov(60.0, 96, 96, dtype=torch.float64)
    below = CameraSpec(K, torch.from_numpy(w2c), 96, 96, 0.0, "cam.json")
    assert fall_direction(masks, 0.03, below)[0] < 5.0
    with pytest.raises(InputError, match="does not end on a ground this camera sees"):
        check_camera_file(masks, 0.03, below, 0.5)


def test_a_video_on_its_side_or_upside_down_is_refused_with_the_turn_that_fixes_it():
    """A ball's fall turned upside down or a quarter either way (a phone's clip that lost its
    display rotation): the camera file's check reads no fall down the image (fall_frames) but one
    along another of its directions, 90–180° from gravity's, and refuses naming the ffmpeg turn
    that sets it upright (the way the centroid accelerates says which); without a camera file
    the fall down the image is too short and the same turn is named. Upright, the fall read in
    any direction is gravity's, and the check passes."""
    from reconphys.capture.calibrate import (
        TURNED_FALL_ANGLE_DEG,
        check_camera_file,
        fall_direction,
        fall_frames,
        mask_track,
    )

    masks, camera = _ball_and_its_camera()
    assert fall_direction(masks, 0.03, camera, image_down=False)[0] < 3.0
    turns = {  # torch.rot90's k over (H, W): the turn the video took → the filter that undoes it
        2: ("upside down", "hflip,vflip"),
        1: ("on its side", "transpose=1"),  # turned anticlockwise: gravity points right
        -1: ("on its side", "transpose=2"),
    }
    for k, (state, undo) in turns.items():
        turned = torch.rot90(masks, k, (1, 2))
        assert fall_frames(mask_track(turned), 0.03) < 4  # no fall down the image
        angle = fall_direction(turned, 0.03, camera, image_down=False)[0]
        assert TURNED_FALL_ANGLE_DEG < angle and abs(angle - (180 if k == 2 else 90)) < 5
        with pytest.raises(InputError, match=rf"{state} .*-vf {undo} OUT"):
            check_camera_file(turned, 0.03, camera, 0.5)
        with pytest.raises(InputError, match=rf"falls freely .*{state} .*-vf {undo} OUT"):
            estimate_camera(turned, 0.03, fov_deg=45.0)
        back = {"hflip,vflip": 2, "transpose=1": -1, "transpose=2": 1}[undo]  # clockwise: k −1
        upright = torch.rot90(turned, back, (1, 2))
        assert torch.equal(upright, masks)
        check_camera_file(upright, 0.03, camera, 0.5)  # no error


def test_rest_depth_is_where_the_ray_meets_the_ground():
    """The ray through the last mask's lowest pixel edge at the image centre of a camera aimed
    at the origin from (4, 0, 1) meets the ground at the origin: √17 m along the view; above
    the horizon (14° up from the centre row: row 13) no ray does."""
    from reconphys.capture.calibrate import rest_depth
    from reconphys.capture.camera import CameraSpec

    K = intrinsics_from_fov(45.0, 64, 64, dtype=torch.float64)
    w2c = look_at(torch.tensor([4.0, 0.0, 1.0]), torch.zeros(3)).double()
    masks = torch.zeros(3, 64, 64)
    masks[-1, 26:32, 28:36] = 1  # lowest row 31: its bottom edge is the centre row; columns ↔ 32
    assert rest_depth(masks, CameraSpec(K, w2c, 64, 64)) == pytest.approx(math.sqrt(17), rel=1e-6)
    masks[-1] = 0
    masks[-1, 0:4, 28:36] = 1  # above the horizon
    assert rest_depth(masks, CameraSpec(K, w2c, 64, 64)) is None


def test_a_slow_motion_video_is_refused_with_its_cause_and_read_with_its_real_rate():
    """A drop filmed at 4 × 0.03 s⁻¹ and played at 1 / 0.03 s (slow motion, 4× slower) shows
    gravity 16× weaker: its 0.24-m ball reads as 3.8 m across and is refused with a message that
    names slow motion and --fps; read at the real 0.0075 s a frame it comes back at its distance
    (to 30 %: its 30 frames hold only 0.22 s of the fall, against 16× read slowed)."""
    radius, distance = 0.12, 2.0
    masks, w2c, _ = ball_masks(15.0, distance, 1.5, radius, dt=0.03 / 4)
    with pytest.raises(InputError, match="slow-motion video: its real frame rate with --fps"):
        estimate_camera(masks, 0.03, fov_deg=45.0)
    estimate = estimate_camera(masks, 0.03 / 4, fov_deg=45.0, ground_from_touch=False)
    centre_0 = w2c[:3, :3] @ np.array([0.0, 0.0, radius + 1.5]) + w2c[:3, 3]
    assert estimate.distance == pytest.approx(float(np.linalg.norm(centre_0)), rel=0.3)


def test_the_overlap_with_frame_0_is_each_frames_iou_with_it():
    """still_frames' and check_masks' overlap, counted on the masks' bounding box, is the IoU of
    each whole frame's mask with frame 0's (an empty frame: 0; every frame empty: 0)."""
    from reconphys.capture.masks import _overlap_with_first

    generator = torch.Generator().manual_seed(0)
    masks = torch.zeros(12, 90, 70)
    for t in range(12):
        masks[t, 10 + 4 * t : 30 + 4 * t, 20 + t : 44 + t] = 1.0
    masks *= (torch.rand(masks.shape, generator=generator) > 0.1).float()  # holes
    masks[5] = 0.0
    seen = masks > 0.5
    whole = [float((s & seen[0]).sum()) / max(float((s | seen[0]).sum()), 1.0) for s in seen]
    assert _overlap_with_first(masks).tolist() == pytest.approx(whole, abs=1e-7)
    assert _overlap_with_first(masks)[5] == 0.0 and 0.0 < whole[1] < 1.0
    assert _overlap_with_first(torch.zeros(4, 8, 8)).tolist() == [0.0] * 4


def test_the_track_on_the_masks_bounding_box_is_the_whole_frames():
    """mask_track finds each frame's pixels on the bounding box of all the masks: its centroid,
    bottom edge, width and area are those counted over the whole frame."""
    from reconphys.capture.calibrate import mask_track

    generator = torch.Generator().manual_seed(1)
    masks = torch.zeros(8, 70, 90)
    for t in range(8):
        masks[t, 12 + 5 * t : 25 + 5 * t, 30 + 2 * t : 47 + 2 * t] = 1.0
    masks *= (torch.rand(masks.shape, generator=generator) > 0.15).float()
    track = mask_track(masks)
    for t, mask in enumerate(masks):
        v, u = torch.nonzero(mask > 0.5, as_tuple=True)
        v, u = v.double(), u.double()
        assert track.centroid[t].tolist() == [float(u.mean()) + 0.5, float(v.mean()) + 0.5]
        assert track.bottom[t] == float(torch.quantile(v, 0.98)) + 1.0
        spread = torch.quantile(u, torch.tensor([0.02, 0.98], dtype=torch.float64))
        assert track.width[t] == float(spread[1] - spread[0]) + 1.0
        assert track.area[t] == len(v)
    masks[3] = 0.0
    with pytest.raises(InputError, match="empty in frame 3"):
        mask_track(masks)


def _segmented_disc_fall(size: int = 32, scale: int = 5, seed: int = 1) -> torch.Tensor:
    """[30, size·scale, size·scale] masks of a disc falling then resting, drawn at ``size`` px
    with a random rim (about a pixel there, as the segmenter's) and enlarged ``scale`` times (as
    its logits are brought to a larger recording's size)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size] + 0.5
    masks = np.zeros((30, size, size), np.float32)
    for t in range(30):
        fallen = min(t, 9) * 0.03  # seconds of fall: it lands at frame 9
        centre_y, centre_x = 6.0 + 0.5 * 392.0 * fallen**2, 16.0 + 10.0 * fallen
        radius = 4.0 + rng.uniform(-0.6, 0.6)
        masks[t] = (yy - centre_y) ** 2 + (xx - centre_x) ** 2 <= radius**2
    return torch.from_numpy(masks).repeat_interleave(scale, 1).repeat_interleave(scale, 2)


def test_the_segmenters_masks_are_read_to_its_own_pixel(tmp_path):
    """A recording larger than the segmenter's size gets its masks enlarged from it: their error
    is a pixel there, ``scale`` of theirs. The fall is read to that (``segmented_pixel``): a clip
    whose fall the rule before cut to 3 frames and refused is read over 9 of the 10 on its
    parabola (the landing frame is left out: the bottom is within a pixel of its lowest)."""
    from reconphys.capture.calibrate import SEGMENTER_FALL_FIT_PX
    from reconphys.capture.observation import load_observation, segmented_pixel
    from reconphys.render.video import write_mp4

    masks = _segmented_disc_fall()
    assert segmented_pixel(masks, {"segmented_size": [32, 32]}) == 5.0
    assert segmented_pixel(masks, {"segmented_size": [160, 160]}) == 1.0
    assert segmented_pixel(masks, None) == segmented_pixel(masks, {"expected_iou": 0.9}) == 1.0
    floor = np.random.default_rng(0).uniform(60, 200, (1, 160, 160, 3)).astype(np.uint8)
    write_mp4(tmp_path / "drop.mp4", np.repeat(floor, 30, 0), fps=1 / 0.03)  # a static camera

    def read(rating: dict):
        return load_observation(tmp_path / "drop.mp4", segment=lambda rgb: (masks.clone(), rating))

    observation = read({"segmented_size": [32, 32]})
    assert observation.fall_fit_px == 5 * SEGMENTER_FALL_FIT_PX
    assert observation.camera_estimate["fall_frames"] == 9
    with pytest.raises(InputError, match="falls freely in 3 frame"):
        read({})  # the masks' own pixel: the rule before


def test_a_drop_height_is_refused_beside_a_camera_file_that_places_the_ground(tmp_path):
    """A camera file with a pose sets the ground (its ground_height): ``--drop-height`` beside it
    is refused, naming the option; with a file of K alone (the pose read from the video) the
    drop height given is where the estimate puts its ground."""
    import json

    from reconphys.capture.observation import load_observation
    from reconphys.render.video import write_mp4

    masks, w2c, _ = ball_masks(15.0, 2.0, 0.45, 0.1, braking_g=5.0)
    floor = np.random.default_rng(0).uniform(60, 200, (1, 96, 96, 3)).astype(np.uint8)
    write_mp4(tmp_path / "drop.mp4", np.repeat(floor, 30, 0), fps=1 / 0.03)
    K = intrinsics_from_fov(45.0, 96, 96, dtype=torch.float64).tolist()
    posed, bare = tmp_path / "posed.json", tmp_path / "bare.json"
    posed.write_text(json.dumps({"K": K, "world_to_cam": w2c.tolist(), "size": [96, 96]}))
    bare.write_text(json.dumps({"K": K, "size": [96, 96]}))

    def read(camera, drop_height):
        return load_observation(
            tmp_path / "drop.mp4",
            camera=camera,
            drop_height=drop_height,
            segment=lambda rgb: (masks.clone(), {"segmented_size": [96, 96]}),
        )

    with pytest.raises(InputError, match="place the ground already") as refused:
        read(posed, 0.4)
    assert refused.value.field == "--drop-height"
    estimate = read(bare, 0.4).camera_estimate
    assert estimate["drop_height_m"] == 0.4 and "--drop-height" in estimate["ground_from"]


def test_a_larger_copy_of_the_masks_reads_the_same_camera():
    """The rules were chosen on 96–128-px clips: masks larger than CAMERA_MAX_SIDE are read at
    that size. The same masks three times larger (each pixel 3 × 3) read the same fall, touch,
    scale and drop height, with K three times the pixels; the rule before read them at 384 px
    otherwise (its tolerances, and the pitch prior's weight, in the larger masks' pixels)."""
    from reconphys.capture.calibrate import CAMERA_MAX_SIDE

    masks, _, _ = ball_masks(15.0, 2.0, 0.45, 0.1, size=CAMERA_MAX_SIDE, braking_g=5.0, up=0.5)
    large = masks.repeat_interleave(3, 1).repeat_interleave(3, 2)
    small, big = (estimate_camera(m, 0.03, fov_deg=45.0) for m in (masks, large))
    for name in ("distance", "drop_height", "pitch_deg", "height", "contact_s", "scale_spread"):
        assert getattr(big, name) == pytest.approx(getattr(small, name), rel=1e-9), name
    assert big.fall_frames == small.fall_frames
    assert big.residual_px == pytest.approx(3 * small.residual_px)
    assert (big.camera.width, big.camera.height) == (3 * CAMERA_MAX_SIDE, 3 * CAMERA_MAX_SIDE)
    assert torch.allclose(big.camera.K[:2], 3 * small.camera.K[:2].double())
    assert torch.equal(big.camera.world_to_cam, small.camera.world_to_cam)
    # a camera file's K (no pose) is brought to the smaller masks and back the same way
    K = big.camera.K.double()
    given = estimate_camera(large, 0.03, intrinsics=K)
    assert torch.allclose(given.camera.K.double(), K)
    assert given.distance == pytest.approx(big.distance, rel=1e-6)
    # the object's depth under a known camera (reconstruct.object_distance) reads them alike
    depth = object_depth(masks, 0.03, small.camera)
    assert object_depth(large, 0.03, big.camera) == pytest.approx(depth, rel=1e-9)


def test_masks_are_read_at_the_rules_size_unless_the_object_would_vanish():
    from reconphys.capture.calibrate import CAMERA_MAX_SIDE, rule_size_masks

    masks = torch.zeros(4, 2 * CAMERA_MAX_SIDE, 3 * CAMERA_MAX_SIDE)
    masks[:, 100:140, 200:260] = 1.0
    small = rule_size_masks(masks)
    assert small.shape == (4, round(2 * CAMERA_MAX_SIDE / 3), CAMERA_MAX_SIDE)
    assert float(small.sum(dim=(1, 2))[0]) == pytest.approx(40 * 60 / 9, rel=0.15)  # the area
    assert rule_size_masks(masks[:, :CAMERA_MAX_SIDE, :CAMERA_MAX_SIDE]) is None  # small enough
    masks[2] = 0.0
    masks[2, 10, 10] = 1.0  # a pixel: gone at a third of the size
    assert rule_size_masks(masks) is None
