"""``reconphys_search``: the trained physics predictor, then the observables fitted to the video by
batched re-simulation (:mod:`reconphys.pipeline.search`), on the true geometry.

Same input and geometry as ``reconphys`` (the predictor's view, frames 0–19, the sample's true
Gaussians, anchors and initial state: an upper bound on geometry, labelled so in the report); the
search then moves log k/m, log d/m and the friction to the values whose simulation, rendered into
that view, matches frames 1–19 best, and gives a 10–90 % interval for each from its profiles
(evaluate reports their coverage). Its time column includes the search's cost per scene.
"""

from __future__ import annotations

from ...capture import CameraSpec
from ...pipeline.search import search
from ..metrics import foreground_mask
from ..samples import EvalSample
from .base import Prediction
from .reconphys import ReconPhysMethod


class ReconPhysSearchMethod(ReconPhysMethod):
    name = "reconphys_search"
    description = "the trained physics predictor + search of k/m, d/m, f on the true geometry"

    def predict(self, sample: EvalSample) -> Prediction:
        start = super().predict(sample).asset
        view = self.predictor.view
        cameras = sample.cameras
        camera = CameraSpec(
            cameras.K[view], cameras.world_to_cam[view], cameras.width, cameras.height
        )
        frames = sample.frames[view, : self.predictor.num_frames]  # [T, H, W, 3]
        masks = foreground_mask(frames)  # the black backdrop's complement
        asset, history = search(start, frames, camera, masks=masks)
        info = {"search_seconds": history["seconds"], "rollouts": len(history["rounds"])}
        return Prediction(asset=asset, intervals=history["intervals"], info=info)
