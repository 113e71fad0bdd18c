"""``trivial``: the training set's median attributes on the true geometry — the control.

Every attribute error and every image score of a model is shown beside this row
(docs/design.md#identifiability): a model that does not beat it has learnt nothing about the
physics. It uses the true Gaussians, anchors and initial velocity, so its image scores isolate the
effect of the attributes; they are upper bounds for a method that must also reconstruct the
geometry.
"""

from __future__ import annotations

from dataclasses import replace

from ..samples import EvalSample
from .base import GROUND_TRUTH_GEOMETRY, Method, Prediction


class TrivialMethod(Method):
    name = "trivial"
    description = "median training attributes on the true geometry and initial state"
    geometry = GROUND_TRUTH_GEOMETRY

    def predict(self, sample: EvalSample) -> Prediction:
        truth = sample.true_asset
        physics = replace(truth.physics, **self.options.trivial.values)
        return Prediction(asset=replace(truth, physics=physics))
