"""``reconphys``: the trained physics predictor (the project's model) on the true geometry.

It reads frames 0–19 of the view the model was trained on (its ``model.json`` says which, how many
frames and at what size), predicts (m, k, d, f) in one forward pass, and returns the sample's true
Gaussians, anchors, springs, binding and initial state with the predicted attributes. The geometry
is the ground truth — as in training, where the frozen 3DGS predictor is for now the dataset's
canonical Gaussians — so its image and point scores are upper bounds, labelled so in the report;
compare it with ``trivial`` (same geometry, median attributes): the difference is what the
predicted attributes are worth.

The model: ``evaluate --model PATH`` (a .safetensors file or a training output folder), else
``$RECONPHYS_MODEL``, else the model shipped with the package (see
:mod:`reconphys.models.shipped`).
"""

from __future__ import annotations

from dataclasses import replace

from ...physics import ATTRIBUTES
from ..samples import EvalSample
from .base import GROUND_TRUTH_GEOMETRY, Method, MethodOptions, Prediction, input_predictor


class ReconPhysMethod(Method):
    name = "reconphys"
    description = "the trained physics predictor (frames 0–19, one view) on the true geometry"
    geometry = GROUND_TRUTH_GEOMETRY

    def __init__(self, options: MethodOptions):
        super().__init__(options)
        self.predictor = input_predictor(options)
        self.description = f"{self.description} [model: {self.predictor.path}]"

    def predict(self, sample: EvalSample) -> Prediction:
        view = self.predictor.view
        frames = sample.frames[view : view + 1, : self.predictor.num_frames]  # [1, T, H, W, 3]
        out = self.predictor.predict(frames)
        values = {name: float(out[name][0]) for name in ATTRIBUTES}
        truth = sample.true_asset
        asset = replace(truth, physics=replace(truth.physics, **values))
        return Prediction(asset=asset)
