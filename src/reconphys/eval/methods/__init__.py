"""The methods ``reconphys evaluate`` compares, all behind ``predict(sample) → Prediction``.

- ``trivial``: training-median attributes on the true geometry (the control; upper bound on
  geometry);
- ``oracle``: true attributes on the true geometry (re-simulates the truth: the pipeline's ceiling);
- ``springgaus``: per-scene optimisation from the 4 views in the Spring-Gaus protocol;
- ``springgaus_gt``: its attribute fit alone, on the true geometry (upper bound on geometry);
- ``appearance``: per-frame position fit, no physics, no future (4DGS-like);
- ``reconphys``: the trained physics predictor's attributes on the true geometry (upper bound on
  geometry; compare with ``trivial``);
- ``reconphys_search``: ``reconphys``, then log k/m, log d/m and f fitted to the video by batched
  re-simulation (:mod:`reconphys.pipeline.search`; upper bound on geometry);
- ``reconphys_ff``: the whole feed-forward pipeline (3DGS predictor + physics predictor, estimated
  initial velocity): what ``predict VIDEO --no-refine`` does without a PLY;
- ``reconphys_video``: ``reconphys_ff`` then the search, with intervals: ``predict VIDEO``'s
  default path.

A new method (the project's model, next issues) subclasses :class:`Method` and is added to
``METHODS``; nothing else changes.
"""

from __future__ import annotations

from ...errors import InputError
from .appearance import AppearanceMethod
from .base import FITTED_GEOMETRY, GROUND_TRUTH_GEOMETRY, Method, MethodOptions, Prediction
from .oracle import OracleMethod
from .reconphys import ReconPhysMethod
from .reconphys_ff import ReconPhysFeedForwardMethod, ReconPhysVideoMethod
from .reconphys_search import ReconPhysSearchMethod
from .springgaus import SpringGausMethod, SpringGausTruthMethod
from .trivial import TrivialMethod

METHODS: dict[str, type[Method]] = {
    "trivial": TrivialMethod,
    "oracle": OracleMethod,
    "springgaus": SpringGausMethod,
    "springgaus_gt": SpringGausTruthMethod,
    "appearance": AppearanceMethod,
    "reconphys": ReconPhysMethod,
    "reconphys_search": ReconPhysSearchMethod,
    "reconphys_ff": ReconPhysFeedForwardMethod,
    "reconphys_video": ReconPhysVideoMethod,
}


def parse_methods(text: str) -> list[str]:
    """ "a,b,c" → ["a", "b", "c"], checked against METHODS (duplicates dropped, order kept)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(f"expected a comma-separated list of {', '.join(METHODS)}", "--methods")
    unknown = [n for n in names if n not in METHODS]
    if unknown:
        raise InputError(
            f"unknown method {unknown[0]!r} (known: {', '.join(METHODS)})", field="--methods"
        )
    return list(dict.fromkeys(names))


__all__ = [
    "FITTED_GEOMETRY",
    "GROUND_TRUTH_GEOMETRY",
    "METHODS",
    "Method",
    "MethodOptions",
    "Prediction",
    "parse_methods",
]
