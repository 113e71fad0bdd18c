"""``reconphys_ff``: the whole feed-forward pipeline, as ``predict VIDEO`` runs it without a PLY.

Frame 0 of the physics model's view goes through the 3DGS predictor (its Gaussians on the
object's pixels, placed with the known camera), frames 0–19 through the physics predictor; the
asset is built from the predicted Gaussians (anchors, springs, binding) with the initial linear
velocity estimated from the masks (no spin), exactly as :func:`reconphys.pipeline.predict`
does for a user's video with ``--no-refine``. Nothing of the ground truth is used: compare it with
``reconphys`` (same attributes, true geometry and initial state: an upper bound) and
``springgaus``. ``reconphys_video`` adds the search, as ``predict VIDEO`` does by default.

The 3DGS predictor: ``$RECONPHYS_GS_MODEL`` or the shipped one (see
:mod:`reconphys.models.gaussian_shipped`).
"""

from __future__ import annotations

from ...capture.observation import stored_observation
from ...models.gaussian_shipped import load_gaussian_predictor
from ...pipeline.predict import predict_observation
from ..samples import EvalSample
from .base import PREDICTED_GEOMETRY, Method, MethodOptions, Prediction, input_predictor


class ReconPhysFeedForwardMethod(Method):
    name = "reconphys_ff"
    description = "the feed-forward pipeline: predicted Gaussians (frame 0) + predicted physics"
    geometry = PREDICTED_GEOMETRY
    refine = False  # predict's search after the network (--no-refine: False)

    def __init__(self, options: MethodOptions):
        super().__init__(options)
        self.predictor = input_predictor(options)
        self.gs_predictor = load_gaussian_predictor()  # once, not per sample

    def predict(self, sample: EvalSample) -> Prediction:
        view = self.predictor.view
        observation = stored_observation(
            sample.frames[view],
            sample.cameras.K[view],
            sample.cameras.world_to_cam[view],
            sample.frame_dt,
            f"{sample.id} view {view}",
        )
        result = predict_observation(
            observation,
            self.predictor,
            geometry="predicted",
            gs_model=self.gs_predictor,
            refine=self.refine,
        )
        info = {"gaussians": result.asset.gaussians.num_gaussians, **result.timings}
        return Prediction(asset=result.asset, info=info, intervals=result.intervals)


class ReconPhysVideoMethod(ReconPhysFeedForwardMethod):
    """``predict VIDEO``'s default path: the feed-forward pipeline, then the search of k/m, d/m
    and f on the predicted geometry (:mod:`reconphys.pipeline.search`), with its intervals."""

    name = "reconphys_video"
    description = "predict's default path: predicted Gaussians + predicted physics + search"
    refine = True
