"""Assets from predicted geometry (docs/design.md#data-flow, docs/design.md#asset-format): the 3DGS
predictor's Gaussians from frame 0, the initial linear velocity from the masks' free fall, and the
asset built from them.

Below both training (``data.geometry = "predicted"``, :mod:`reconphys.train.data`) and the user's
path (:mod:`reconphys.pipeline.predict`), so that neither imports the other.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from ..assets.asset import Asset
from ..assets.build import build_from_gaussians
from ..assets.gaussians import Gaussians
from ..capture import Observation
from ..capture.calibrate import (
    CAMERA_CONVENTION,
    MAX_READ_SIZE_M,
    SEGMENTER_FALL_FIT_PX,
    fall_frames,
    mask_pixel,
    mask_track,
    object_depth,
    rest_depth,
)
from ..capture.placement import GRAVITY_MAGNITUDE, SEGMENTED_SIZE_WEIGHT, linear_velocity_fit
from ..errors import InputError
from ..geometry import rigid_velocity
from .model_input import frame_crop, predictor_frames, virtual_intrinsics


def initial_velocity(gaussians: Gaussians, observation: Observation) -> Tensor:  # [3] m/s
    """The initial linear velocity of ``gaussians`` (world frame) from the masks' free fall."""
    return initial_velocity_fit(gaussians, observation)[0]


def initial_velocity_fit(gaussians: Gaussians, observation: Observation) -> tuple[Tensor, Tensor]:
    """(velocity [3] m/s world frame, its standard error [3] m/s along the camera's x right,
    y down and viewing axes) from the masks' free fall (capture.placement.linear_velocity_fit);
    when the recording showed the object held still, then let go from rest
    (``observation.release``: --start auto, or the hold before a --start SECONDS;
    capture.masks.read_release), :func:`release_velocity` instead, whatever the first frames'
    masks show (the hand that let go is in them)."""
    segmented = observation.fall_fit_px >= SEGMENTER_FALL_FIT_PX  # the segmenter's masks
    velocity, error = linear_velocity_fit(
        gaussians.means,
        observation.masks,
        observation.camera,
        observation.frame_dt,
        fall=observed_fall_frames(observation),
        size_weight=SEGMENTED_SIZE_WEIGHT if segmented else 1.0,
        pixel=mask_pixel(observation.fall_fit_px),
    )
    if held_then_let_go(observation):
        velocity = release_velocity(observation).to(velocity)
    return velocity, error


def held_then_let_go(observation: Observation) -> bool:
    """The recording shows the object held still, then let go from rest (--start auto, or the
    hold before a --start SECONDS)."""
    return observation.release is not None and observation.release.from_rest


def fallen_since_release(observation: Observation) -> float:
    """Seconds from the release read (``observation.release``) to frame 0: 0 with --start auto
    (frame 0 is the release) and for a start given at or before it."""
    if observation.release is None:
        return 0.0
    return max(0.0, observation.start_s - observation.release.time_s)


def release_velocity(observation: Observation) -> Tensor:  # [3] m/s, world frame (z up)
    """The velocity at frame 0 of an object let go from rest (:func:`held_then_let_go`): at rest
    at the release, then falling freely — ``g · t`` downwards, t the seconds since the release
    (:func:`fallen_since_release`; a start given a frame after it finds the object at ~0.3
    m/s)."""
    fallen = fallen_since_release(observation)
    return torch.tensor([0.0, 0.0, 0.0 - GRAVITY_MAGNITUDE * fallen], dtype=torch.float64)  # no −0


def observed_fall_frames(observation: Observation) -> int | None:
    """Frames of free fall the masks show from frame 0 (calibrate.fall_frames; the camera
    estimate's when the camera was read from the video), None when they cannot be read."""
    if observation.camera_estimate is not None:
        return int(observation.camera_estimate["fall_frames"])
    try:
        track = mask_track(observation.masks)
    except InputError:  # a frame without the object
        return None
    return fall_frames(track, observation.frame_dt, observation.fall_fit_px)


def observed_asset(
    placed: Gaussians,  # world frame, on the first frame's object
    observation: Observation,
    attributes: Mapping[str, float],  # mass (kg/anchor), stiffness, damping, friction
    data: Mapping,  # a dataset's settings (anchors, springs, binding, contact), as in model.json
    object_id: str,  # seeds the anchors
    ground_height: float,  # metres
    num_anchors: int | None = None,  # None: the data's
    velocity: Tensor | None = None,  # [3] m/s; None: initial_velocity(placed, observation)
    angular: Tensor | None = None,  # [3] rad/s about the Gaussians' centre; None: no spin
) -> Asset:
    """New Gaussians of a recording → asset: the initial linear velocity (of the Gaussians'
    centre, with ``angular`` about it), the settings of the data the physics network was trained
    on (see :meth:`~reconphys.assets.asset.PhysicsSettings.from_data_settings`), lifted above the
    ground, anchors/springs/binding built."""
    if velocity is None:
        velocity = initial_velocity(placed, observation)
    asset = build_from_gaussians(
        placed,
        attributes,
        data,
        object_id,
        linear_velocity=velocity.tolist(),
        lift=True,
        frame_dt=observation.frame_dt,
        ground_height=ground_height,
        num_anchors=num_anchors or None,
    )
    if angular is None or not bool(angular.any()):
        return asset
    centre = asset.gaussians.means.mean(0)  # what the spin was read about (pipeline/spin.py)
    v0 = rigid_velocity(asset.x0, velocity.to(asset.x0), angular.to(asset.x0), centre)
    return replace(asset, v0=v0)


def feed_forward_asset(
    observation: Observation, attributes: dict[str, float], data: dict, gs_model=None
) -> Asset:
    """What the feed-forward pipeline builds without a PLY: the 3DGS predictor's Gaussians from
    frame 0, the initial linear velocity from the masks, anchors/springs/binding by the settings
    ``data`` (see :func:`observed_asset`), on the camera's ground. Used to train the physics
    network on predicted geometry (``data.geometry = "predicted"``): the Gaussians at the model's
    own size (``detail=0``), the geometry predict reads the physics on."""
    placed, _ = predicted_gaussians(observation, gs_model, detail=0)
    return observed_asset(
        placed,
        observation,
        attributes,
        data,
        f"predicted-{Path(observation.source).stem}",
        observation.camera.ground_height,
    )


# With a known camera, the fall's distance and the rest's on its ground (exact masks, true
# cameras: ×0.72–1.51 apart, 1–99 %) agree within this factor, else the fall was misread and the
# rest is taken: mean |log error| of the distance 0.601 → 0.137 on the pybullet validation drops
# with the segmenter's masks, 0.104 → 0.095 and 0.045 → 0.039 on two of this project's, the
# others the same (docs/usage.md "Recordings from another engine").
FALL_REST_AGREEMENT = 2.0


def object_distance(observation: Observation) -> tuple[float, str, str | None]:
    """How far the object is in frame 0 (metres, the camera z of its centre), how that was
    read, and a warning or None: from its free fall
    (:func:`~reconphys.capture.calibrate.object_depth`), else from where it rests on the
    camera's ground (:func:`~reconphys.capture.calibrate.rest_depth`). With a known camera (a
    file's) the rest is also the check on the fall: more than :data:`FALL_REST_AGREEMENT` times
    apart, the masks misread the fall or the video plays at another speed than it was filmed
    (:func:`_fall_rest_warning`), and the rest is taken. InputError when neither is there (no
    fall seen and the resting object not on the ground)."""
    masks, camera = observation.masks, observation.camera
    rest = rest_depth(masks, camera)
    try:
        fall = object_depth(masks, observation.frame_dt, camera, observation.fall_fit_px)
    except InputError:
        fall = None
    known = observation.camera_estimate is None  # a file's (or the dataset's) camera
    misread = known and fall is not None and rest is not None
    misread = misread and not 1 / FALL_REST_AGREEMENT <= fall / rest <= FALL_REST_AGREEMENT
    warning = None
    if fall is not None and not misread:
        distance, how = fall, "fall"
    elif rest is not None:
        distance, how = rest, "rest on the ground"
        if fall is not None:
            how += f" (the fall read {fall:.3g} m: more than ×{FALL_REST_AGREEMENT:g} off)"
            warning = _fall_rest_warning(fall, rest, observation.recorded_fps)
    else:
        raise InputError(
            "cannot tell how far the object is (no free fall in the first frames and the resting "
            "object is not on the camera's ground): give its geometry with --gaussians or --mesh",
            source=observation.source,
        )
    rows, cols = torch.nonzero(masks[0] > 0.5, as_tuple=True)
    pixels = max(float(cols.max() - cols.min()), float(rows.max() - rows.min())) + 1
    size = pixels * distance / float(camera.K[1, 1])
    if known and not size <= MAX_READ_SIZE_M:
        raise InputError(
            f"the object would be {size:.3g} m across, {distance:.3g} m away (read from its "
            f"{how}; more than {MAX_READ_SIZE_M:g} m): {CAMERA_CONVENTION}",
            source=camera.source,
            field="world_to_cam",
        )
    return distance, how, warning


def _fall_rest_warning(fall: float, rest: float, recorded_fps: float | None) -> str:
    """What a fall read ``fall`` metres away, against ``rest`` metres where the object rests on
    a known camera's ground, may mean: masks that misread the fall, or a video that plays at
    another speed than it was filmed — played ×s slower, gravity shows s² weaker and the fall
    reads the object s² farther, so it was filmed at about ``recorded_fps``·√(fall / rest) (named
    for a rate ×0.25–×8 the one it plays at)."""
    ratio = fall / rest
    speed = "slower (slow motion?)" if ratio > 1 else "faster"
    plausible = 1 / 16 <= ratio <= 64  # filmed at ×0.25–×8 the rate it plays at
    filmed = (
        f"about {recorded_fps * math.sqrt(ratio):.0f} fps"
        if recorded_fps and plausible
        else "its real frame rate"
    )
    return (
        f"the fall reads the object {fall:.2f} m away, ×{ratio:.2g} where it rests on the "
        f"camera's ground ({rest:.2f} m, taken): the masks misread the fall (check preview.mp4, "
        f"or give them with --masks DIR), or the video plays {speed} than it was filmed — then "
        f"the physics' time is off too: give the rate it was filmed at with --fps ({filmed})"
    )


# The crop the Gaussians are put on, in multiples of the model's own (3: 48 → 144 px, 9 times
# the Gaussians; docs/usage.md#the-object-in-detail-2026-11-29)
DETAIL_FACTOR = 3


def predicted_gaussians(
    observation: Observation,
    gs_model=None,
    distance: float | None = None,  # crop models: the object's distance, metres (None: read it)
    detail: int | None = None,  # crop models: Gaussians on a crop of this many px a side
    # (≥ the model's; None: DETAIL_FACTOR times the model's, 0: the model's own size)
):
    """Frame 0 → the 3DGS predictor's Gaussians on the object's pixels (world frame), and the
    model's path. ``gs_model``: a path, a loaded predictor, or None (the default one). A crop
    model reads the object's crop of frame 0 (:func:`~reconphys.models.model_input.frame_crop`)
    and the object's distance (:func:`object_distance`), and puts its Gaussians on the pixels of
    a finer crop of the same square (``detail``; see GaussianPredictor.forward); the others read
    the frame and its mask
    resampled to the dataset's intrinsics at the model's size (as the physics network's input),
    so the camera's pose places them."""
    from .gaussian_predictor import prune_gaussians
    from .gaussian_shipped import LoadedGaussianPredictor, load_gaussian_predictor

    if isinstance(gs_model, LoadedGaussianPredictor):
        loaded = gs_model
    else:
        loaded = load_gaussian_predictor(gs_model)
    config = loaded.model.config
    size = config.resolution
    w2c = observation.camera.world_to_cam.float()
    if config.crop:
        first = observation.frames[0].float(), observation.masks[0].float()
        K_frame = observation.camera.K.float()
        frame, mask, K = frame_crop(*first, K_frame, size, config.crop_margin)
        if distance is None:
            distance = object_distance(observation)[0]
        depth = torch.tensor([float(distance)])
        detail = DETAIL_FACTOR * size if detail is None else detail
        fine = None
        if detail > size:  # the same square, finer: the Gaussians' pixels
            fine_frame, fine_mask, _ = frame_crop(*first, K_frame, detail, config.crop_margin)
            fine = (fine_frame[None], fine_mask[None])
    else:
        frame = predictor_frames(observation.frames[:1], observation.camera.K, size)[0, 0]
        mask = predictor_frames(
            observation.masks[:1, ..., None].expand(-1, -1, -1, 3), observation.camera.K, size
        )[0, 0, ..., 0]
        mask = (mask > 0.5).float()
        K = virtual_intrinsics(size).float()
        depth = fine = None
    with torch.no_grad():
        g = loaded.model(frame[None], mask[None], K[None], w2c[None], depth, detail=fine)
    keep = mask if fine is None else fine[1][0]
    try:
        pruned = prune_gaussians(g.map(lambda t: t[0]), keep.reshape(-1))
    except ValueError as e:
        raise InputError(str(e), source=observation.source) from None
    return pruned.map(lambda t: t.detach().float()), loaded.path
