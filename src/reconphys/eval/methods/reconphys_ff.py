"""``reconphys_ff``: the whole feed-forward pipeline, as ``predict VIDEO`` runs it without a PLY.

Frame 0 of the physics model's view goes through the 3DGS predictor (its Gaussians on the
object's pixels, placed with the known camera), frames 0–19 through the physics predictor; the
asset is built from the predicted Gaussians (anchors, springs, binding) with the initial linear
velocity estimated from the masks (no spin), exactly as :func:`reconphys.pipeline.predict`
does for a user's video. Nothing of the ground truth is used: compare it with ``reconphys``
(same attributes, true geometry and initial state: an upper bound) and ``springgaus``.

The 3DGS predictor: ``$RECONPHYS_GS_MODEL`` or the shipped one (see
:mod:`reconphys.models.gaussian_shipped`).
"""

from __future__ import annotations

from ...capture import CameraSpec, Observation
from ...capture.masks import subtract_background
from ...models.shipped import load_predictor
from ...pipeline.predict import predict_observation
from ..samples import EvalSample
from .base import PREDICTED_GEOMETRY, Method, MethodOptions, Prediction


class ReconPhysFeedForwardMethod(Method):
    name = "reconphys_ff"
    description = "the feed-forward pipeline: predicted Gaussians (frame 0) + predicted physics"
    geometry = PREDICTED_GEOMETRY

    def __init__(self, options: MethodOptions):
        super().__init__(options)
        self.predictor = load_predictor(options.model, device=options.device)

    def predict(self, sample: EvalSample) -> Prediction:
        view = self.predictor.view
        frames = sample.frames[view]  # [T, H, W, 3]
        height, width = frames.shape[1:3]
        camera = CameraSpec(
            sample.cameras.K[view].double(),
            sample.cameras.world_to_cam[view].double(),
            width,
            height,
            0.0,
            f"{sample.id} view {view}",
        )
        observation = Observation(
            frames=frames,
            masks=subtract_background(frames),
            camera=camera,
            frame_dt=sample.frame_dt,
            source=sample.id,
            mask_source="background subtraction",
        )
        result = predict_observation(observation, self.predictor, geometry="predicted")
        info = {"gaussians": result.asset.gaussians.num_gaussians, **result.timings}
        return Prediction(asset=result.asset, info=info)
