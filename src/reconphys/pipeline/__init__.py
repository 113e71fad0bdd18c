"""The user's path (docs/design.md#data-flow, docs/usage.md): recording → asset (:mod:`.predict`),
test-time refinement (:mod:`.refine`) and the side-by-side preview (:mod:`.preview`)."""

from .predict import PredictResult, predict

__all__ = ["PredictResult", "predict"]
