"""``reconphys predict``: one recording → a simulation-ready asset (docs/design.md#data-flow,
docs/design.md#asset-format).

Steps, each timed (``PredictResult.timings``, seconds):

- ``decode``: read the video / frames / dataset sample, masks, camera (:mod:`..capture`);
- ``gaussians``: the canonical Gaussians — a given PLY placed on the first frame's mask (or kept
  where it is when it already projects onto it), the 3DGS predictor's from frame 0 (no PLY), or
  a dataset sample's own (ground truth, an upper bound); the initial linear velocity from the
  masks' free fall;
- ``spin`` (with the search, where the clip is not read as at rest): the spin about the viewing
  axis from the free-fall frames, rendered and compared (:mod:`.spin`); the asset starts with it;
- ``physics_network``: the physics predictor on frames 0..T−1 → (m, k, d, f);
- ``asset_build``: anchors (seeded by the object id), kNN springs, binding;
- ``search`` (the default; ``refine=False`` skips it): log k/m, log d/m and the friction fitted to
  the recording by batched re-simulation, with a 10–90 % interval for each (:mod:`.search`);
- ``refine`` (optional, ``refine_steps``): gradient steps on the photometric loss (:mod:`.refine`).

The asset is written by :func:`write_outputs` (``write`` and ``preview`` timings).
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch
from torch import Tensor

from ..assets.asset import Asset
from ..assets.build import lifted_above, with_gaussians
from ..assets.gaussians import Gaussians
from ..capture import Observation
from ..capture.calibrate import check_drop_height, check_touch
from ..capture.masks import FIRST_FRAMES_AREA_CHANGE, first_frames_area_change
from ..capture.observation import too_short
from ..capture.placement import estimate_ground_height, fit_to_mask, placement_scores
from ..capture.video import SDR_WHITE_NITS
from ..errors import InputError
from ..models.gaussian_shipped import (
    LoadedGaussianPredictor,
    gs_model_for_recording,
    load_gaussian_predictor,
)
from ..models.model_input import network_input
from ..models.physics_predictor import network_sigma
from ..models.reconstruct import (
    DETAIL_FACTOR,
    fallen_since_release,
    held_then_let_go,
    initial_velocity_fit,
    object_distance,
    observed_asset,
    observed_fall_frames,
    predicted_gaussians,
)
from ..physics import ATTRIBUTES
from .samples import SampleTruth, is_dataset, load_input
from .search import (
    OBSERVABLES,
    Z_10_90,
    network_intervals,
    observables,
)
from .settings import PREVIEW_FRAMES

PLACEMENTS = ("auto", "as-is", "fit")
GROUNDS = ("camera", "landed")
GEOMETRIES = ("auto", "predicted")
GT_GEOMETRY = "ground truth (the dataset sample's Gaussians and initial state): an upper bound"
INTERVALS_HOW = (
    "10–90 % of the posterior along each observable's profile (the others at their best): "
    "pipeline/search.py; a wide interval means the recording does not show that observable"
)
WITH_NETWORK_HOW = (
    "10–90 % of the posterior along each observable's profile (the others at their best) times "
    "the network's belief (normal, σ = 3–5 × its members' spread): pipeline/search.py; the "
    "search's 'undetermined' lists what the recording alone does not show"
)
NETWORK_HOW = (
    "10–90 % of the network's belief alone (normal at its answer, σ = 3–5 × its members' spread; "
    "--no-refine): how far its answer is from the truth on objects it never saw, not what this "
    "recording shows"
)
NO_INTERVALS = "none: this network is not an ensemble (run without --no-refine for intervals)"


@dataclass
class PredictResult:
    asset: Asset  # the simulation-ready asset (predicted or refined attributes)
    observation: Observation
    attributes: dict[str, float]  # the feed-forward prediction (before any refinement)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per step
    details: dict = field(default_factory=dict)  # geometry, placement, velocity, model, refine
    # 10–90 % interval of each observable (log_k_over_m, log_d_over_m: natural logs of the SI
    # ratios; friction) from the search's profiles; None without the search (--no-refine)
    intervals: dict[str, list[float]] | None = None

    @property
    def observables(self) -> dict[str, float]:  # log_k_over_m, log_d_over_m, friction
        return dict(zip(OBSERVABLES, observables(self.asset.physics).tolist(), strict=True))

    @property
    def intervals_how(self) -> str:
        if not self.intervals:
            return NO_INTERVALS
        search = self.details.get("search")
        if search is None:
            return NETWORK_HOW
        return INTERVALS_HOW if search.get("network_sigma") is None else WITH_NETWORK_HOW

    def summary(self) -> dict:
        physics = self.asset.physics
        return {
            "attributes": {n: getattr(physics, n) for n in ATTRIBUTES},
            "observables": self.observables,
            "intervals": self.intervals,
            "intervals_how": self.intervals_how,
            "feed_forward": self.attributes,
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            **self.details,
        }


def _object_id(path: Path) -> str:
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    return f"{path.stem}-{digest}"


def _model_data_settings(predictor) -> dict:
    return predictor.metadata.get("training", {}).get("data", {}).get("settings", {}) or {}


# A given geometry's silhouette must overlap frame 0's mask at least this much once placed
# (compared on a window around the object: capture.placement.silhouette_iou). Chosen on 72
# realistic validation drops at 128 px with the mask segmenter's masks: their true Gaussians
# score 0.74–0.99 (5th percentile 0.84), the same turned by 90° or 180° and moved onto the mask
# pass 0.6 on 55 % of the tries, 0.7 on 28 %, 0.75 on 14 % (one true geometry refused there;
# on the whole frame at 0.6, the check before: 60 %).
# A margin below the true geometry's: a correct geometry refused is worse than a wrong one let
# by (docs/usage.md "The placement check on the object's window").
MIN_PLACED_IOU = 0.7
# Where its colours and frame 0's both vary, their chromaticities must correlate at least this
# much once placed (capture.placement.colour_agreement): a shape turned about an axis it is
# symmetric about keeps its silhouette but shows another side of its pattern. Chosen on 72
# realistic validation drops at 128 px: the true Gaussians 0.68–0.97, turned ones at most 0.35
# (none of those passing the silhouette check let by at any bar from 0.25); a margin below the
# true ones' (docs/usage.md "The colours of a given shape").
MIN_COLOUR_AGREEMENT = 0.4
# A shape whose colours agree (≥ MIN_COLOUR_AGREEMENT) needs only this silhouette IoU: a mask's
# error (a rim lost, a shadow taken in) costs the silhouette, not where the pattern lies, and
# moving a shape that is where it should be onto a poor mask moves it off (a motor cover's true
# Gaussians: IoU 0.66 and colours 0.68 as given; moved 25 cm by the fit, IoU 0.72 and colours
# −0.09). No turned shape of the validation drops reached 0.4 at any IoU.
MIN_COLOURED_IOU = 0.5
# A launch faster than this is not a drop or a toss filmed on a floor (a fall from 5 m lands at
# 10 m/s): the first frames' masks do not follow the object, or its distance is misread
MAX_INITIAL_SPEED_M_S = 10.0
MESH_GAUSSIANS = 4000  # Gaussians sampled from a given mesh (--mesh)


def placement_matches(iou: float, colours: float | None) -> bool:
    """Whether a placed shape's silhouette matches frame 0's mask: IoU ≥ MIN_PLACED_IOU, or ≥
    MIN_COLOURED_IOU where its colours agree (≥ MIN_COLOUR_AGREEMENT; None: not judged). Its
    colours, where judged, must agree as well (checked apart, for its own message)."""
    coloured = colours is not None and colours >= MIN_COLOUR_AGREEMENT
    return iou >= MIN_PLACED_IOU or (coloured and iou >= MIN_COLOURED_IOU)


def _given_gaussians(path: Path, observation: Observation, placement: str, mesh: bool = False):
    """The given geometry (a 3DGS PLY, or a mesh whose coordinates are frame 0's pose in
    metres) placed on frame 0's mask as ``placement`` says; InputError when its silhouette
    does not match the mask (IoU < MIN_PLACED_IOU; < MIN_COLOURED_IOU where its colours agree)
    or, where both vary, its colours do not match frame 0's (MIN_COLOUR_AGREEMENT): a wrong
    orientation, shape or size is refused, not kept silently. ``auto`` keeps it where it is when
    it matches so, else moves it onto the mask (fit_to_mask). A mesh without colours of its own
    gets a checker, which is not compared."""
    own_colours = True
    if mesh:
        from ..assets.mesh import mesh_to_gaussians

        try:  # the mesh's own colours, even one flat colour (not a checker in its place)
            gaussians = mesh_to_gaussians(path, MESH_GAUSSIANS, size=None, texture="mesh")
        except InputError as error:
            if error.field != "texture":
                raise
            gaussians = mesh_to_gaussians(path, MESH_GAUSSIANS, size=None)
            own_colours = False
    else:
        from ..assets.ply import read_ply

        gaussians = read_ply(path)
    if not bool(torch.isfinite(gaussians.means).all()):
        raise InputError("non-finite Gaussian centres", source=str(path), field="means")
    first_mask = observation.masks[0]
    where = ""  # a shape given with the camera read from the video: in whose world frame
    if observation.camera_estimate is not None:
        where = (
            "; without --camera its pose is read in the estimated camera's world frame (the "
            "camera on +x looking towards −x, frame 0's centre above the origin): give --camera"
        )
    frame = observation.frames[0] if own_colours else None  # a checker is not compared
    iou, colours = placement_scores(gaussians, first_mask, observation.camera, frame)
    how = placement
    if placement == "auto":
        how = "as-is" if placement_matches(iou, colours) else "fit"
    after = iou
    if how == "fit":
        gaussians = fit_to_mask(gaussians, first_mask, observation.camera)
        after, colours = placement_scores(gaussians, first_mask, observation.camera, frame)
    if not placement_matches(after, colours):
        raise InputError(
            f"does not match the object in frame 0 (silhouette IoU {after:.2f} with its mask "
            f"{'after moving it onto the mask' if how == 'fit' else 'as given'}, needs ≥ "
            f"{MIN_PLACED_IOU}, ≥ {MIN_COLOURED_IOU} where its colours match frame 0's): give "
            f"it in frame 0's orientation and real size, or leave it out to predict the "
            f"geometry{where}",
            source=str(path),
        )
    if colours is not None and colours < MIN_COLOUR_AGREEMENT:
        raise InputError(
            f"its colours do not match the object's in frame 0 (chromaticity correlation "
            f"{colours:.2f}, needs ≥ {MIN_COLOUR_AGREEMENT}; the silhouette matches, IoU "
            f"{after:.2f}): it is turned, or another object; give it in frame 0's "
            f"orientation, or leave it out to predict the geometry{where}",
            source=str(path),
        )
    # the fit may put it into the ground: lift it onto the ground
    gaussians = lifted_above(gaussians, observation.camera.ground_height)
    return gaussians, {
        "placement": how,
        "silhouette_iou_given": round(iou, 3),
        "silhouette_iou_placed": round(after, 3),
        "colour_agreement": None if colours is None else round(colours, 3),
    }


def predict(
    input: str | os.PathLike,
    *,
    gaussians: str | os.PathLike | None = None,
    mesh: str | os.PathLike | None = None,
    masks: str | os.PathLike | None = None,
    background: str | os.PathLike | None = None,
    camera: str | os.PathLike | None = None,
    fov: float | None = None,
    touch: str | None = None,  # how the object meets the ground, for the camera read from the
    # video: "soft" (None) or "rigid"
    drop_height: float | None = None,  # metres: frame 0's lowest point above the ground, known
    fps: float | None = None,
    start: float | str = 0.0,  # seconds into a recording, or "auto" (read from the masks)
    end: float | None = None,
    sample: str | None = None,
    view: int | None = None,
    model: str | os.PathLike | None = None,
    geometry: str = "auto",
    gs_model: str | os.PathLike | None = None,
    placement: str = "auto",
    ground: str = "camera",
    num_anchors: int | None = None,
    refine: bool = True,
    refine_steps: int = 0,
    refine_resolution: int = 64,
    search_ground: bool = False,  # the search moves a ground read from the video too (measured,
    # not the default: docs/usage.md#searching-the-ground-with-the-physics)
    device: str | torch.device = "cpu",
    progress: bool = False,
) -> PredictResult:
    """Predict a simulation-ready asset from one recording (see module doc and docs/usage.md).

    Raises :class:`~reconphys.errors.InputError` (one line naming the input) for bad input.
    Turns on ``torch.set_flush_denormal`` (as the CLI does): settling objects and far Gaussian
    tails otherwise produce float32 denormals that slow CPUs down several times.
    """
    from ..models.shipped import load_predictor, model_for_recording

    if geometry not in GEOMETRIES:
        raise InputError(f"expected auto or predicted, got {geometry!r}", field="--geometry")
    if placement not in PLACEMENTS:
        raise InputError(
            f"expected one of {', '.join(PLACEMENTS)}, got {placement!r}", field="--placement"
        )
    check_touch(touch or "soft")
    check_drop_height(drop_height)
    if view is not None and not is_dataset(input):
        raise InputError("--view is for dataset samples (a recording has one view)", field="--view")
    if ground not in GROUNDS:
        raise InputError(f"expected camera or landed, got {ground!r}", field="--ground")
    if refine_steps < 0:
        raise InputError(f"must be ≥ 0, got {refine_steps}", field="--refine-steps")
    torch.set_flush_denormal(True)
    timings: dict[str, float] = {}
    details: dict = {}

    started = time.perf_counter()
    predictor = load_predictor(model, device=device)
    timings["model_load"] = time.perf_counter() - started
    details["model"] = str(predictor.path)

    started = time.perf_counter()
    observation, truth = load_input(
        input,
        masks=masks,
        background=background,
        camera=camera,
        fps=fps,
        fov_deg=fov,
        touch=touch,
        drop_height=drop_height,
        frame_dt=float(predictor.metadata["input"].get("frame_dt", 0.03)),
        sample=sample,
        view=predictor.view if view is None else view,
        start=start,
        end=end,
        min_frames=predictor.num_frames,
    )
    timings["decode"] = time.perf_counter() - started
    if model is None:  # the network for this recording's look (models/shipped.py)
        chosen, why = model_for_recording(observation.plain_look)
        if chosen != predictor.path:
            started = time.perf_counter()
            predictor = load_predictor(chosen, device=device)
            timings["model_load"] += time.perf_counter() - started
            details["model"] = str(predictor.path)
        details["model_choice"] = why
    if observation.num_frames < predictor.num_frames:
        raise InputError(
            too_short(observation.num_frames, observation.frame_dt, predictor.num_frames),
            source=observation.source,
        )
    details["input"] = {
        "source": observation.source,
        "frames": observation.num_frames,
        "recorded_frames": observation.recorded_frames,
        "recorded_fps": observation.recorded_fps,
        "time_resampling": observation.time_resampling,
        "start_s": round(observation.start_s, 4),
        "start_how": _start_how(start, observation),
        "end_s": end,
        "size": list(observation.size),  # as read (at most WORK_MAX_SIDE a side)
        "recorded_size": list(observation.recorded_size or observation.size),
        "masks": observation.mask_source,
        "camera": observation.camera.source,
        "ground_height": observation.camera.ground_height,
    }
    if observation.release is not None:  # the hold read (capture/masks.read_release)
        details["input"]["release"] = {
            "time_s": round(observation.release.time_s, 4),  # into the recording
            "held_frames": observation.release.held_frames,
            "from_rest": observation.release.from_rest,
            "across_m_s": round(observation.release.across_m_s, 4)
            if math.isfinite(observation.release.across_m_s)
            else None,
        }
    if observation.camera_estimate is not None:
        details["input"]["camera_estimate"] = observation.camera_estimate
    if observation.camera_shake is not None:
        details["input"]["camera_shake"] = observation.camera_shake
    if observation.mask_rating is not None:  # how sure the segmenter is of its masks
        details["input"]["masks_rating"] = observation.mask_rating
    if observation.hdr is not None:  # an HDR phone video, read as SDR (capture/video.py)
        details["input"]["dynamic_range"] = (
            f"HDR ({observation.hdr}) read as SDR: {SDR_WHITE_NITS:g} cd/m² made white, BT.2020 "
            "turned into BT.709, the sRGB curve; brighter highlights and colours outside BT.709 "
            "clipped"
        )

    return predict_observation(
        observation,
        predictor,
        timings,
        details,
        gaussians=gaussians,
        mesh=mesh,
        geometry=geometry,
        gs_model=gs_model,
        placement=placement,
        ground=ground,
        num_anchors=num_anchors,
        refine=refine,
        refine_steps=refine_steps,
        refine_resolution=refine_resolution,
        search_ground=search_ground,
        progress=progress,
        truth=truth,
    )


def _start_how(start: float | str, observation: Observation) -> str:
    """How frame 0's time in the recording was chosen (prediction.json's input.start_how)."""
    release = observation.release
    if release is None:
        if start == "auto":
            return "--start auto: the object moves from frame 0 (not held), kept"
        return "given (--start)" if start else "frame 0 of the recording"
    how = "let go from rest" if release.from_rest else "launched (moving when let go)"
    if start == "auto":
        held = f"held still for {release.held_frames} frames"
        return f"read from the masks: {held}, then {how} (--start auto)"
    return (
        f"given (--start); before it the object is held still, then {how} at "
        f"{release.time_s:.3f} s (read from the masks)"
    )


def _let_go_how(observation: Observation) -> str:
    """initial_velocity.how for an object held still, then let go from rest (models/reconstruct
    .release_velocity)."""
    release = observation.release
    held = f"the recording shows the object held still for {release.held_frames} frames"
    if observation.start_s == release.time_s:  # --start auto: frame 0 is the release
        return f"at rest: {held}, then let go from rest (--start auto)"
    fallen = fallen_since_release(observation)
    if not fallen:
        return f"at rest: {held}, then let go from rest at {release.time_s:.3f} s (--start given)"
    return (
        f"falling from rest: {held}, then let go from rest at {release.time_s:.3f} s, "
        f"{fallen * 1000:.0f} ms before --start: g × that, downwards"
    )


def spin_estimate(
    placed: Gaussians, observation: Observation, velocity: Tensor
) -> tuple[Tensor, dict]:
    """The spin about the viewing axis read from the free fall (:mod:`.spin`) → (angular
    velocity [3] rad/s world frame, zero where not shown; what prediction.json says of it)."""
    from .spin import MIN_GAIN, ROLL_AXES, spin_fit

    fall = observed_fall_frames(observation)
    fit = spin_fit(
        placed,
        observation.frames,
        observation.masks,
        observation.camera,
        observation.frame_dt,
        velocity,
        fall,
        axes=ROLL_AXES,
    )
    sd = float("inf") if fit.sd_camera_axes is None else float(fit.sd_camera_axes[2])
    report = {
        "shown": fit.shown,
        "frames_compared": fit.frames,
        "error_explained": round(fit.gain, 4),
        "about_view_rad_s": round(
            float(observation.camera.world_to_cam[2, :3].double() @ fit.fitted), 4
        ),
        # None where not read or the error has no minimum along the axis (a flat profile)
        "about_view_sd_rad_s": round(sd, 4) if math.isfinite(sd) else None,
        "how": "the frame-0 Gaussians turned about the viewing axis and carried in free fall, "
        f"rendered and compared with the free-fall frames (pipeline/spin.py); kept where it "
        f"explains ≥ {MIN_GAIN:.0%} more of them than no spin; the turns about the image's axes "
        "are not read",
        "seconds": fit.seconds,
    }
    return fit.angular.float(), report


def check_initial_speed(velocity: torch.Tensor, source: str) -> None:  # velocity [3] m/s
    """InputError (naming the recording) when the initial velocity read is faster than
    :data:`MAX_INITIAL_SPEED_M_S`: a confident wrong launch is worse than a refusal."""
    speed = float(velocity.norm())
    if not speed <= MAX_INITIAL_SPEED_M_S:
        raise InputError(
            f"the first frames read as a launch at {speed:.3g} m/s (more than "
            f"{MAX_INITIAL_SPEED_M_S:g}): the masks do not follow a falling object, its "
            "distance is misread, or the video plays slower than it was filmed (gravity then "
            "shows weaker, read as a throw); give the masks with --masks DIR (or its shape with "
            "--gaussians), or a slow-motion video's real frame rate with --fps",
            source=source,
        )


def predict_observation(
    observation: Observation,
    predictor,  # a LoadedPredictor (reconphys.models.shipped)
    timings: dict[str, float] | None = None,
    details: dict | None = None,
    *,
    gaussians: str | os.PathLike | None = None,
    mesh: str | os.PathLike | None = None,  # instead of gaussians: a mesh in frame 0's pose
    geometry: str = "auto",
    gs_model: str | os.PathLike | None = None,
    placement: str = "auto",
    ground: str = "camera",
    num_anchors: int | None = None,
    refine: bool = True,
    refine_steps: int = 0,
    refine_resolution: int = 64,
    search_ground: bool = False,  # a ground read from the video searched too (see predict)
    progress: bool = False,
    truth: SampleTruth | None = None,
) -> PredictResult:
    """The steps after decoding (see :func:`predict`), for an observation already in memory
    (e.g. a dataset sample in ``evaluate``). ``truth``: a dataset sample's (see
    :func:`.samples.load_sample`): its geometry and initial state are used unless ``gaussians``
    is given or ``geometry="predicted"`` (an upper bound), and its attributes are reported."""
    timings = {} if timings is None else timings
    details = {} if details is None else details
    started = time.perf_counter()
    dataset_asset = None if truth is None else truth.asset
    build_new = True  # a new asset from given or predicted Gaussians (not the dataset's own)
    object_centric = False  # the geometry is the object-centric 3DGS predictor's
    detailed = None  # its Gaussians on the finer crop: the asset's appearance (after the search)
    if gaussians is not None and mesh is not None:
        raise InputError("give either --gaussians or --mesh, not both", field="--mesh")
    given = gaussians if gaussians is not None else mesh
    if given is not None:
        placed, placement_info = _given_gaussians(
            Path(given), observation, placement, mesh=mesh is not None
        )
        details["geometry"] = f"given: {given}" + (" (mesh)" if mesh is not None else "")
        details.update(placement_info)
        object_id = _object_id(Path(given))
    elif dataset_asset is not None and geometry != "predicted":
        details["geometry"] = GT_GEOMETRY
        details["initial_velocity"] = {"how": "the dataset sample's (ground truth)"}
        build_new = False
    else:
        if gs_model is None:  # the 3DGS predictor for this recording's look
            gs_model, why = gs_model_for_recording(observation.plain_look)
            details["gs_model_choice"] = why
        if not isinstance(gs_model, LoadedGaussianPredictor):
            gs_model = load_gaussian_predictor(gs_model)
        object_centric = gs_model.model.config.crop
        distance = None
        if object_centric:  # the object-centric predictor places the object at its distance
            distance, how, warning = object_distance(observation)
            details["object_distance"] = {"m": round(distance, 4), "how": how}
            if warning is not None:
                details["object_distance"]["warning"] = warning
        # the physics is read on the Gaussians at the model's size (as the search was tuned);
        # the asset carries those on the finer crop (reconstruct.DETAIL_FACTOR), on its anchors
        placed, gs_path = predicted_gaussians(observation, gs_model, distance, detail=0)
        if object_centric and DETAIL_FACTOR > 1:
            detailed = predicted_gaussians(observation, gs_model, distance)[0]
        details["geometry"] = f"predicted by the 3DGS predictor {gs_path} from frame 0"
        object_id = f"predicted-{Path(observation.source).stem}"
    if build_new:
        velocity, error = initial_velocity_fit(placed, observation)
        estimate = observation.camera_estimate
        if estimate is not None:  # metres per second scale with the depth read from the fall
            spread = math.log(estimate["size_factor_10_90"][1]) / Z_10_90
            across = observation.camera.world_to_cam[:3, :3].to(velocity) @ velocity
            error = (error**2 + (spread * across) ** 2).sqrt()
        check_initial_speed(velocity, observation.source)
        at_rest = not bool(velocity.any())
        area_change = first_frames_area_change(observation.masks)
        details["initial_velocity"] = {
            "linear_m_s": [round(float(x), 4) for x in velocity],
            # its standard error along the camera's x (right), y (down) and viewing axes (with
            # the size's when the camera is read from the video)
            "linear_sd_camera_axes_m_s": [round(float(x), 4) for x in error],
            "angular_rad_s": [0.0, 0.0, 0.0],
            # the masks' motion is explained without a velocity (placement.REST_CHI2)
            "released_from_rest": at_rest,
            "how": (
                _let_go_how(observation)
                if held_then_let_go(observation)
                else "free fall of the mask's centroid and growth of its area over frames 0–3"
                + (
                    "; at rest: no motion beyond the masks' noise"
                    if at_rest
                    else ", then again over the whole free fall where it shows more frames"
                )
            )
            + (
                " (angular velocity: not estimated at rest nor without the search)"
                if at_rest or not refine
                else ""
            ),
            # |log(area_t / area_0)| over frames 0–3 (capture.masks.FIRST_FRAMES_AREA_CHANGE)
            "first_frames_area_change": round(area_change, 4),
        }
        if area_change > FIRST_FRAMES_AREA_CHANGE and not held_then_let_go(observation):
            details["initial_velocity"]["warning"] = (
                f"the object's mask changes size by up to {math.exp(area_change) - 1:.0%} in "
                "frames 0–3, more than a released object's: something in view (the hand that "
                "let it go?) hides it or is taken for it, and the velocity read from those "
                "frames may be wrong; check preview.mp4, or give the masks with --masks DIR"
                + (
                    ", or, if the recording shows the object held still before it is let go, "
                    "--start auto (a hold and a fall from rest are read at rest)"
                    if observation.release is None
                    else ""
                )
            )
    angular = None
    if build_new and refine and not at_rest:  # the spin about the view, from the free fall
        angular, details["initial_velocity"]["angular"] = spin_estimate(
            placed, observation, velocity
        )
        details["initial_velocity"]["angular_rad_s"] = [round(float(x), 4) for x in angular]
        timings["spin"] = details["initial_velocity"]["angular"].pop("seconds")
    means = placed.means if build_new else dataset_asset.gaussians.means
    landed = estimate_ground_height(means, observation.masks[-1], observation.camera)
    details["ground_check_m"] = None if landed is None else round(landed, 4)
    ground_height = observation.camera.ground_height
    if ground == "landed":
        if landed is None:
            raise InputError(
                "cannot estimate the ground from the last frame's mask",
                source=observation.source,
                field="--ground",
            )
        if not build_new:
            raise InputError("a dataset sample's ground is known (z = 0)", field="--ground")
        ground_height = landed
    details["ground_height_m"] = round(ground_height, 4)
    timings["gaussians"] = time.perf_counter() - started - timings.get("spin", 0.0)

    started = time.perf_counter()
    with torch.no_grad():
        config = predictor.model.config
        frames = network_input(
            observation.frames[: predictor.num_frames],
            observation.camera.K,
            config.resolution,
            config.crop,
        )
        out = predictor.model(frames.to(predictor.device))
    attributes = {name: float(out[name][0]) for name in ATTRIBUTES}
    # [3] the network's belief: its calibrated spread_factor × its members' spread (⊕ its scale)
    sigma = network_sigma({k: v.cpu() for k, v in out.items()}, predictor.spread_factor)
    if sigma is not None:
        sigma = sigma[0]
        pairs = zip(OBSERVABLES, sigma.tolist(), strict=True)
        details["network_sigma"] = {name: round(value, 4) for name, value in pairs}
    timings["physics_network"] = time.perf_counter() - started

    started = time.perf_counter()
    if build_new:
        asset = observed_asset(
            placed,
            observation,
            attributes,
            _model_data_settings(predictor),
            object_id,
            ground_height,
            num_anchors,
            velocity,
            angular,
        )
    else:
        asset = replace(dataset_asset, physics=replace(dataset_asset.physics, **attributes))
    if detailed is not None:  # how the asset's Gaussians were moved (lifted_above)
        shift = asset.gaussians.means[0] - placed.means[0]
    timings["asset_build"] = time.perf_counter() - started
    details["anchors"] = asset.num_anchors
    details["springs"] = int(asset.springs.shape[0])
    details["gaussians"] = asset.gaussians.num_gaussians

    intervals = None
    if refine:
        from .search import GIVEN_GEOMETRY_TEMPERATURE, PREDICTED_GEOMETRY_TEMPERATURE, search

        started = time.perf_counter()
        count = predictor.num_frames
        estimate = observation.camera_estimate  # the ground read from the video, not given
        ground_read = (
            estimate is not None and not estimate.get("drop_height_given") and ground == "camera"
        )
        # the object-centric 3DGS predictor's geometry is not the object's, and a given shape
        # starts from the masks' velocity without spin: wider profiles
        scale = 1.0
        if object_centric:
            scale = PREDICTED_GEOMETRY_TEMPERATURE
        elif given is not None:
            scale = GIVEN_GEOMETRY_TEMPERATURE
        asset, history = search(
            asset,
            observation.frames[:count],
            observation.camera,
            resolution=refine_resolution,
            masks=observation.masks[:count],
            temperature_scale=scale,
            # that factor was chosen on such geometry as it is compared (supersampled or not)
            fine_temperature=not object_centric,
            # on a recording's own geometry (predicted or given) and initial state (read from the
            # masks) the fit alone is not to be trusted: times the network's belief
            prior_sigma=sigma if build_new else None,
            rebuilt=build_new,  # τ by the law the belief and the factors were chosen under
            ground=search_ground and ground_read,
        )
        timings["search"] = time.perf_counter() - started
        intervals = history["intervals"]
        details["search"] = {k: v for k, v in history.items() if k not in ("rounds", "intervals")}
        details["search"]["rollouts"] = len(history["rounds"])
    elif sigma is not None:  # --no-refine: the network's own interval
        intervals = network_intervals(observables(asset.physics), sigma)
    if refine_steps:
        from .refine import refine as gradient_refine

        started = time.perf_counter()
        asset, history = gradient_refine(
            asset,
            observation,
            refine_steps,
            resolution=refine_resolution,
            num_frames=predictor.num_frames,
            progress=progress,
        )
        timings["refine"] = time.perf_counter() - started
        details["refine"] = history
    if detailed is not None:  # the finer Gaussians, moved as the asset's were (lifted_above)
        started = time.perf_counter()
        asset = with_gaussians(asset, detailed.with_means(detailed.means + shift))
        timings["asset_build"] += time.perf_counter() - started
        details["gaussians"] = asset.gaussians.num_gaussians
        details["geometry"] += (
            f" (the physics read on its {placed.num_gaussians} Gaussians of the model's "
            f"{gs_model.model.config.resolution}-px crop; the asset's on the "
            f"{DETAIL_FACTOR * gs_model.model.config.resolution}-px crop)"
        )
    if truth is not None:
        details["truth"] = truth.attributes
    return PredictResult(asset, observation, attributes, timings, details, intervals)


def write_outputs(
    result: PredictResult,
    out: str | os.PathLike,
    overwrite: bool = False,
    preview_frames: int = PREVIEW_FRAMES,
    device: str | torch.device = "cpu",
) -> dict:
    """Write the asset folder (docs/design.md#asset-format) plus ``preview.mp4`` / ``preview.png``
    (observed | simulated) and ``prediction.json`` (attributes, timings, details) atomically into
    ``out``."""
    import json

    from ..assets.asset import write_asset
    from ..io import atomic_folder, check_new_output
    from ..render.video import write_image, write_mp4
    from .preview import (
        contact_sheet,
        interval_lines,
        outlined,
        preview_view,
        side_by_side,
        simulate_and_render,
        with_caption,
    )

    out = check_new_output(out, overwrite)
    with atomic_folder(out, overwrite=True) as staging:
        started = time.perf_counter()
        notes = {"intervals": result.intervals, "intervals_how": result.intervals_how}
        write_asset(result.asset, staging, overwrite=True, notes=notes)
        result.timings["write"] = time.perf_counter() - started
        if preview_frames > 0:
            started = time.perf_counter()
            count = max(preview_frames, result.observation.num_frames)
            frames, masks, camera = preview_view(result.observation)
            simulated = simulate_and_render(result.asset, frames, masks, camera, count, device)
            observed = outlined(frames, masks)  # the masks as read
            video = side_by_side(observed, simulated)
            write_mp4(staging / "preview.mp4", video, fps=1.0 / result.asset.physics.frame_dt)
            sheet = contact_sheet(observed, simulated)
            caption = interval_lines(result.observables, result.intervals)
            write_image(staging / "preview.png", with_caption(sheet, caption))
            result.timings["preview"] = time.perf_counter() - started
        summary = result.summary()
        (staging / "prediction.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
