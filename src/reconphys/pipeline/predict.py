"""``reconphys predict``: one recording → a simulation-ready asset (DESIGN §2, §6).

Steps, each timed (``PredictResult.timings``, seconds):

- ``decode``: read the video / frames / dataset sample, masks, camera (:mod:`..capture`);
- ``gaussians``: the canonical Gaussians — a given PLY placed on the first frame's mask (or kept
  where it is when it already projects onto it), the 3DGS predictor's from frame 0 (no PLY), or
  a dataset sample's own (ground truth, an upper bound); the initial linear velocity from the
  masks' free fall;
- ``physics_network``: the physics predictor on frames 0..T−1 → (m, k, d, f);
- ``asset_build``: anchors (seeded by the object id), kNN springs, binding;
- ``refine`` (optional): test-time photometric refinement (:mod:`.refine`).

The asset is written by :func:`write_outputs` (``write`` and ``preview`` timings).
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from ..assets.asset import Asset, PhysicsSettings
from ..capture import Observation, load_observation
from ..capture.placement import (
    estimate_ground_height,
    estimate_linear_velocity,
    fit_to_mask,
    silhouette_iou,
)
from ..errors import InputError
from ..physics import ATTRIBUTES
from .model_input import predictor_frames
from .settings import DEFAULT_NUM_ANCHORS

PLACEMENTS = ("auto", "as-is", "fit")
GROUNDS = ("camera", "landed")
GEOMETRIES = ("auto", "predicted")
GT_GEOMETRY = "ground truth (the dataset sample's Gaussians and initial state): an upper bound"


@dataclass
class PredictResult:
    asset: Asset  # the simulation-ready asset (predicted or refined attributes)
    observation: Observation
    attributes: dict[str, float]  # the feed-forward prediction (before any refinement)
    timings: dict[str, float] = field(default_factory=dict)  # seconds per step
    details: dict = field(default_factory=dict)  # geometry, placement, velocity, model, refine

    def summary(self) -> dict:
        physics = self.asset.physics
        return {
            "attributes": {n: getattr(physics, n) for n in ATTRIBUTES},
            "feed_forward": self.attributes,
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            **self.details,
        }


def _object_id(path: Path) -> str:
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    return f"{path.stem}-{digest}"


def _model_data_settings(predictor) -> dict:
    return predictor.metadata.get("training", {}).get("data", {}).get("settings", {}) or {}


def _given_gaussians(ply: Path, observation: Observation, placement: str):
    from ..assets.ply import read_ply

    gaussians = read_ply(ply)
    if not bool(torch.isfinite(gaussians.means).all()):
        raise InputError("non-finite Gaussian centres", source=str(ply), field="means")
    first_mask = observation.masks[0]
    iou = silhouette_iou(gaussians, first_mask, observation.camera)
    how = placement
    if placement == "auto":
        how = "as-is" if iou >= 0.5 else "fit"
    if how == "fit":
        gaussians = fit_to_mask(gaussians, first_mask, observation.camera)
    after = silhouette_iou(gaussians, first_mask, observation.camera) if how == "fit" else iou
    lowest = float(gaussians.means[:, 2].min())
    ground = observation.camera.ground_height
    if lowest < ground:  # the fit put it into the ground: lift it onto the ground
        shift = torch.tensor([0.0, 0.0, ground - lowest + 1e-3])
        gaussians = gaussians.with_means(gaussians.means + shift)
    return gaussians, {
        "placement": how,
        "silhouette_iou_given": round(iou, 3),
        "silhouette_iou_placed": round(after, 3),
    }


def lifted_above(gaussians, ground_height: float):
    """The Gaussians moved up just above ``ground_height`` (metres) where their lowest centre is
    below it: an object must start above its ground."""
    lowest = float(gaussians.means[:, 2].min())
    if lowest >= ground_height:
        return gaussians
    return gaussians.with_means(
        gaussians.means + torch.tensor([0.0, 0.0, ground_height - lowest + 1e-3])
    )


def physics_settings(
    attributes: dict[str, float],
    data: dict,  # a dataset's settings (anchors, springs, binding, contact), as in model.json
    frame_dt: float,
    ground_height: float,
    object_id: str,
    num_anchors: int | None = None,
) -> PhysicsSettings:
    """The settings of an asset built from new Gaussians: the attributes, and the spring-mass
    settings of the data the physics network was trained on."""
    return PhysicsSettings(
        **attributes,
        num_anchors=num_anchors or int(data.get("num_anchors", DEFAULT_NUM_ANCHORS)),
        num_neighbors=int(data.get("num_neighbors", 32)),
        binding_neighbors=int(data.get("binding_neighbors", 16)),
        binding_power=float(data.get("binding_power", 2.0)),
        spring_exponent=float(data.get("spring_exponent", 0.5)),
        restitution=float(data.get("restitution", 0.0)),
        substeps=int(data.get("min_substeps", 100)),
        frame_dt=frame_dt,
        ground_height=ground_height,
        object_id=object_id,
    )


def feed_forward_asset(
    observation: Observation, attributes: dict[str, float], data: dict, gs_model=None
) -> Asset:
    """What the feed-forward pipeline builds without a PLY: the 3DGS predictor's Gaussians from
    frame 0, the initial linear velocity from the masks, anchors/springs/binding by the settings
    ``data`` (see :func:`physics_settings`), on the camera's ground. Used to train the physics
    network on predicted geometry (``data.geometry = "predicted"``)."""
    from ..assets.build import build_asset

    placed, _ = predicted_gaussians(observation, gs_model)
    velocity = estimate_linear_velocity(
        placed.means, observation.masks, observation.camera, observation.frame_dt
    )
    ground_height = observation.camera.ground_height
    physics = physics_settings(
        attributes,
        data,
        observation.frame_dt,
        ground_height,
        f"predicted-{Path(observation.source).stem}",
    )
    placed = lifted_above(placed, ground_height)
    return build_asset(placed, physics, linear_velocity=velocity.tolist())


def predicted_gaussians(observation: Observation, gs_model=None):
    """Frame 0 → the 3DGS predictor's Gaussians on the object's pixels (world frame), and the
    model's path. ``gs_model``: a path, a loaded predictor, or None (the default one). The frame
    and its mask are resampled to the dataset's intrinsics at the model's size (as the physics
    network's input), so the camera's pose places them."""
    from ..models.gaussian_predictor import prune_gaussians
    from ..models.gaussian_shipped import LoadedGaussianPredictor, load_gaussian_predictor
    from .model_input import virtual_intrinsics

    if isinstance(gs_model, LoadedGaussianPredictor):
        loaded = gs_model
    else:
        loaded = load_gaussian_predictor(gs_model)
    size = loaded.model.config.resolution
    frame = predictor_frames(observation.frames[:1], observation.camera.K, size)[0, 0]
    mask = (
        predictor_frames(
            observation.masks[:1, ..., None].expand(-1, -1, -1, 3), observation.camera.K, size
        )[0, 0, ..., 0]
        > 0.5
    )
    K = virtual_intrinsics(size).float()
    w2c = observation.camera.world_to_cam.float()
    with torch.no_grad():
        g = loaded.model(frame[None], mask[None].float(), K[None], w2c[None])
    try:
        pruned = prune_gaussians(g.map(lambda t: t[0]), mask.reshape(-1).float())
    except ValueError as e:
        raise InputError(str(e), source=observation.source) from None
    return pruned.map(lambda t: t.detach().float()), loaded.path


def predict(
    input: str | os.PathLike,
    *,
    gaussians: str | os.PathLike | None = None,
    masks: str | os.PathLike | None = None,
    background: str | os.PathLike | None = None,
    camera: str | os.PathLike | None = None,
    fps: float | None = None,
    sample: str | None = None,
    view: int | None = None,
    model: str | os.PathLike | None = None,
    geometry: str = "auto",
    gs_model: str | os.PathLike | None = None,
    placement: str = "auto",
    ground: str = "camera",
    num_anchors: int | None = None,
    refine_steps: int = 0,
    refine_resolution: int = 64,
    device: str | torch.device = "cpu",
    progress: bool = False,
) -> PredictResult:
    """Predict a simulation-ready asset from one recording (see module doc and docs/usage.md).

    Raises :class:`~reconphys.errors.InputError` (one line naming the input) for bad input.
    Turns on ``torch.set_flush_denormal`` (as the CLI does): settling objects and far Gaussian
    tails otherwise produce float32 denormals that slow CPUs down several times.
    """
    from ..models.shipped import load_predictor

    if geometry not in GEOMETRIES:
        raise InputError(f"expected auto or predicted, got {geometry!r}", field="--geometry")
    if placement not in PLACEMENTS:
        raise InputError(
            f"expected one of {', '.join(PLACEMENTS)}, got {placement!r}", field="--placement"
        )
    if ground not in GROUNDS:
        raise InputError(f"expected camera or landed, got {ground!r}", field="--ground")
    if refine_steps < 0:
        raise InputError(f"must be ≥ 0, got {refine_steps}", field="--refine")
    torch.set_flush_denormal(True)
    timings: dict[str, float] = {}
    details: dict = {}

    started = time.perf_counter()
    predictor = load_predictor(model, device=device)
    timings["model_load"] = time.perf_counter() - started
    details["model"] = str(predictor.path)

    started = time.perf_counter()
    observation = load_observation(
        input,
        masks=masks,
        background=background,
        camera=camera,
        fps=fps,
        frame_dt=float(predictor.metadata["input"].get("frame_dt", 0.03)),
        sample=sample,
        view=predictor.view if view is None else view,
    )
    if observation.num_frames < predictor.num_frames:
        raise InputError(
            f"{observation.num_frames} frames at {observation.frame_dt} s after resampling; the "
            f"model reads {predictor.num_frames} ({predictor.num_frames * observation.frame_dt:.2f}"
            " s of video)",
            source=observation.source,
        )
    timings["decode"] = time.perf_counter() - started
    details["input"] = {
        "source": observation.source,
        "frames": observation.num_frames,
        "recorded_frames": observation.recorded_frames,
        "recorded_fps": observation.recorded_fps,
        "size": list(observation.size),
        "masks": observation.mask_source,
        "camera": observation.camera.source,
        "ground_height": observation.camera.ground_height,
    }

    return predict_observation(
        observation,
        predictor,
        timings,
        details,
        gaussians=gaussians,
        geometry=geometry,
        gs_model=gs_model,
        placement=placement,
        ground=ground,
        num_anchors=num_anchors,
        refine_steps=refine_steps,
        refine_resolution=refine_resolution,
        progress=progress,
    )


def predict_observation(
    observation: Observation,
    predictor,  # a LoadedPredictor (reconphys.models.shipped)
    timings: dict[str, float] | None = None,
    details: dict | None = None,
    *,
    gaussians: str | os.PathLike | None = None,
    geometry: str = "auto",
    gs_model: str | os.PathLike | None = None,
    placement: str = "auto",
    ground: str = "camera",
    num_anchors: int | None = None,
    refine_steps: int = 0,
    refine_resolution: int = 64,
    progress: bool = False,
) -> PredictResult:
    """The steps after decoding (see :func:`predict`), for an observation already in memory
    (e.g. a dataset sample in ``evaluate``)."""
    from ..assets.build import build_asset

    timings = {} if timings is None else timings
    details = {} if details is None else details
    started = time.perf_counter()
    dataset_asset = observation.sample.get("asset")
    build_new = True  # a new asset from given or predicted Gaussians (not the dataset's own)
    if gaussians is not None:
        placed, placement_info = _given_gaussians(Path(gaussians), observation, placement)
        details["geometry"] = f"given: {gaussians}"
        details.update(placement_info)
        object_id = _object_id(Path(gaussians))
    elif dataset_asset is not None and geometry != "predicted":
        details["geometry"] = GT_GEOMETRY
        details["initial_velocity"] = {"how": "the dataset sample's (ground truth)"}
        build_new = False
    else:
        placed, gs_path = predicted_gaussians(observation, gs_model)
        details["geometry"] = f"predicted by the 3DGS predictor {gs_path} from frame 0"
        object_id = f"predicted-{Path(observation.source).stem}"
    if build_new:
        velocity = estimate_linear_velocity(
            placed.means, observation.masks, observation.camera, observation.frame_dt
        )
        details["initial_velocity"] = {
            "linear_m_s": [round(float(x), 4) for x in velocity],
            "angular_rad_s": [0.0, 0.0, 0.0],
            "how": "free fall of the mask centroid over frames 0–3 (angular velocity not "
            "estimated)",
        }
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
    if build_new:
        placed = lifted_above(placed, ground_height)
    details["ground_height_m"] = round(ground_height, 4)
    timings["gaussians"] = time.perf_counter() - started

    started = time.perf_counter()
    with torch.no_grad():
        frames = predictor_frames(
            observation.frames[: predictor.num_frames],
            observation.camera.K,
            predictor.model.config.resolution,
        )
        out = predictor.model(frames.to(predictor.device))
    attributes = {name: float(out[name][0]) for name in ATTRIBUTES}
    timings["physics_network"] = time.perf_counter() - started

    started = time.perf_counter()
    if build_new:
        physics = physics_settings(
            attributes,
            _model_data_settings(predictor),
            observation.frame_dt,
            ground_height,
            object_id,
            num_anchors,
        )
        asset = build_asset(placed, physics, linear_velocity=velocity.tolist())
    else:
        asset = replace(dataset_asset, physics=replace(dataset_asset.physics, **attributes))
    timings["asset_build"] = time.perf_counter() - started
    details["anchors"] = asset.num_anchors
    details["springs"] = int(asset.springs.shape[0])
    details["gaussians"] = asset.gaussians.num_gaussians

    if refine_steps:
        from .refine import refine

        started = time.perf_counter()
        asset, history = refine(
            asset,
            observation,
            refine_steps,
            resolution=refine_resolution,
            num_frames=predictor.num_frames,
            progress=progress,
        )
        timings["refine"] = time.perf_counter() - started
        details["refine"] = history
    if observation.sample:
        details["truth"] = observation.sample["attributes"]
    return PredictResult(asset, observation, attributes, timings, details)


def write_outputs(
    result: PredictResult,
    out: str | os.PathLike,
    overwrite: bool = False,
    preview_frames: int = 60,
    device: str | torch.device = "cpu",
) -> dict:
    """Write the asset folder (DESIGN §6) plus ``preview.mp4`` / ``preview.png`` (observed |
    simulated) and ``prediction.json`` (attributes, timings, details) atomically into ``out``."""
    import json
    import shutil
    import tempfile

    from ..assets.asset import write_asset
    from ..render.video import write_image, write_mp4
    from .preview import contact_sheet, side_by_side, simulate_and_render

    out = Path(out)
    if out.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        started = time.perf_counter()
        write_asset(result.asset, staging, overwrite=True)
        result.timings["write"] = time.perf_counter() - started
        if preview_frames > 0:
            started = time.perf_counter()
            count = max(preview_frames, result.observation.num_frames)
            simulated = simulate_and_render(result.asset, result.observation, count, device)
            video = side_by_side(result.observation.frames, simulated)
            write_mp4(staging / "preview.mp4", video, fps=1.0 / result.asset.physics.frame_dt)
            observed = result.observation.frames
            write_image(staging / "preview.png", contact_sheet(observed, simulated))
            result.timings["preview"] = time.perf_counter() - started
        summary = result.summary()
        (staging / "prediction.json").write_text(json.dumps(summary, indent=2) + "\n")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(staging, 0o777 & ~umask)  # mkdtemp makes it 0700
        if out.exists():
            shutil.rmtree(out)
        os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return summary
