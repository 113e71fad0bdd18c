"""``oracle``: true attributes on the true geometry — the ceiling of the whole pipeline.

Re-simulating and re-rendering the sample's own asset must reproduce the stored video and
trajectory up to float round-off and the frames' 8-bit quantisation (PSNR ≳ 55 dB, Chamfer
≈ 0); anything less points at a bug in the evaluation itself.
"""

from __future__ import annotations

from ..samples import EvalSample
from .base import GROUND_TRUTH_GEOMETRY, Method, Prediction


class OracleMethod(Method):
    name = "oracle"
    description = "true attributes on the true geometry and initial state (re-simulates the truth)"
    geometry = GROUND_TRUTH_GEOMETRY

    def predict(self, sample: EvalSample) -> Prediction:
        return Prediction(asset=sample.true_asset)
