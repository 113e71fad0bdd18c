"""``appearance``: per-frame fit of Gaussian positions to frames 0–19, no physics (4DGS-like).

Frame 0's Gaussians come from the same static fit as ``springgaus`` (:mod:`.fitting`). For each
later frame the centres start from the previous frame's, shifted by the motion of the triangulated
silhouette centre between the two frames, and Adam fits them to the frame's 4 views; colours,
scales, rotations and opacities stay those of frame 0. Without a model of the motion it cannot say
anything about frames 20–29: its future is reported as unavailable, as the paper does for 4DGS,
and it has no attributes. Time: ``budget_seconds`` per scene, 30 % for the static fit, the rest
spread evenly over the frames, each frame also capped at ``iterations_per_frame``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch

from ...render import render
from ..samples import EvalSample
from .base import FITTED_GEOMETRY, Method, Prediction
from .fitting import StaticFitSettings, cached_static_fit, photometric_loss, silhouette_centre
from .springgaus import INPUT_FRAMES, STATIC_SHARE


@dataclass(frozen=True)
class AppearanceSettings:
    static: StaticFitSettings = field(default_factory=StaticFitSettings)
    iterations_per_frame: int = 15
    lr_means: float = 0.002  # metres per step


class AppearanceMethod(Method):
    name = "appearance"
    description = "per-frame fit of Gaussian positions to frames 0–19, no physics (4DGS-like)"
    geometry = FITTED_GEOMETRY
    has_physics = False

    def __init__(self, options, settings: AppearanceSettings | None = None):
        super().__init__(options)
        self.settings = settings or AppearanceSettings()

    def predict(self, sample: EvalSample) -> Prediction:
        s, options = self.settings, self.options
        device = options.device
        gaussians, static_info, static_seconds, reused = cached_static_fit(
            options.cache,
            sample.id,
            sample.frames[:, 0],
            sample.cameras,
            s.static,
            STATIC_SHARE * options.budget_seconds,
            options.seed,
            device,
        )
        started = time.perf_counter() - static_seconds  # a reused fit still counts
        frames = sample.frames[:, :INPUT_FRAMES].to(device)  # frames 20+ are never seen
        cameras = sample.cameras.to(device)
        gaussians = gaussians.to(device)
        last_frame = min(INPUT_FRAMES, frames.shape[1]) - 1
        fit_start = time.perf_counter()
        deadline = started + options.budget_seconds
        means = [gaussians.means]
        iterations = []
        silhouette = [silhouette_centre(frames[:, t], sample.cameras) for t in range(2)]
        for t in range(1, last_frame + 1):
            if t > 1:
                silhouette.append(silhouette_centre(frames[:, t], sample.cameras))
            shift = (silhouette[t] - silhouette[t - 1]).to(device)
            centres = (means[-1] + shift).clone().requires_grad_(True)
            optimizer = torch.optim.Adam([centres], lr=s.lr_means)
            frame_deadline = fit_start + t / last_frame * (deadline - fit_start)
            count = 0
            while count < s.iterations_per_frame and (
                count == 0 or time.perf_counter() < frame_deadline
            ):
                optimizer.zero_grad(set_to_none=True)
                rendered = render(gaussians.with_means(centres), cameras).rgb
                loss = photometric_loss(rendered, frames[:, t])
                loss.backward()
                optimizer.step()
                count += 1
            means.append(centres.detach())
            iterations.append(count)
        info = {
            **static_info,
            "frame_iterations_mean": sum(iterations) / max(len(iterations), 1),
        }
        return Prediction(
            gaussians=gaussians.to("cpu"),
            means=torch.stack(means).cpu(),
            info=info,
            reused_seconds=static_seconds if reused else 0.0,
        )
