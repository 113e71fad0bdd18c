"""The interface every evaluated method implements: ``predict(sample) → Prediction``.

A physics method returns a simulation-ready :class:`~reconphys.assets.asset.Asset` (Gaussians,
anchors, springs, binding, initial velocity, attributes); the evaluator simulates it for the clip's
frames and renders the same views, exactly as a user would run the exported asset. A method
without physics (the appearance-only baseline) instead returns Gaussian centres for the frames it
fitted; it has no future and no attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from ...assets.asset import Asset
from ...assets.gaussians import Gaussians
from ...errors import InputError
from ...models.shipped import LoadedPredictor, load_predictor
from ..samples import EvalSample, TrivialAttributes

INPUT_FRAMES = 20  # frames 0–19: what a method may see; 20–29 are the future window
# (docs/design.md#conventions)

GROUND_TRUTH_GEOMETRY = "ground truth"  # the true Gaussians, anchors and initial state
FITTED_GEOMETRY = "fitted to the 4 views"
PREDICTED_GEOMETRY = "predicted from frame 0 of one view (the 3DGS predictor)"


@dataclass
class Prediction:
    asset: Asset | None = None  # physics methods: the asset, evaluated by simulating it
    gaussians: Gaussians | None = None  # no-physics methods: the Gaussians (colours, scales)...
    means: Tensor | None = None  # ...and their centres per fitted frame [T_fit, N, 3], metres
    initial_guess: Asset | None = None  # the method's starting asset, evaluated beside it
    info: dict = field(default_factory=dict)  # diagnostics (iterations, losses) for the CSVs
    # 10–90 % intervals {log_k_over_m, log_d_over_m, friction: [lo, hi]} (methods that give them)
    intervals: dict[str, list[float]] | None = None
    reused_seconds: float = 0.0  # work done earlier by another method (a shared fit) that
    # counts in this method's time: the evaluator adds it to the measured predict time

    @property
    def attributes(self) -> dict[str, float] | None:
        """Predicted mass, stiffness, damping and friction (None without physics)."""
        if self.asset is None:
            return None
        p = self.asset.physics
        return {
            "mass": p.mass,
            "stiffness": p.stiffness,
            "damping": p.damping,
            "friction": p.friction,
        }


@dataclass
class MethodOptions:
    """What the evaluation run gives every method."""

    trivial: TrivialAttributes  # the control's attributes (and the per-scene fits' prior)
    budget_seconds: float = 60.0  # per scene, for the per-scene optimisation baselines
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    seed: int = 0
    cache: dict = field(default_factory=dict)  # work shared between methods on one sample
    model: str | None = None  # the trained predictor of ``reconphys`` (None: the default one)


class Method:
    """Base class. Subclasses set the class attributes and implement :meth:`predict`."""

    name: str = ""
    description: str = ""  # one line for the report
    geometry: str = FITTED_GEOMETRY  # where the Gaussians and initial state come from
    has_physics: bool = True  # False: no attributes, no future prediction

    def __init__(self, options: MethodOptions):
        self.options = options

    @property
    def uses_ground_truth(self) -> bool:
        """True when the method reads the true geometry: its results are upper bounds."""
        return self.geometry == GROUND_TRUTH_GEOMETRY

    def predict(self, sample: EvalSample) -> Prediction:
        raise NotImplementedError


def input_predictor(options: MethodOptions) -> LoadedPredictor:
    """The physics predictor of ``options`` (see :func:`load_predictor`), refused when it reads
    more than the :data:`INPUT_FRAMES` a method may see (it would see the future window)."""
    predictor = load_predictor(options.model, device=options.device)
    if predictor.num_frames > INPUT_FRAMES:
        raise InputError(
            f"the model reads {predictor.num_frames} frames; evaluate lets a method see frames "
            f"0–{INPUT_FRAMES - 1} (from {INPUT_FRAMES} on is the future it is scored on)",
            source=str(predictor.path),
        )
    return predictor
