"""Test-time refinement: gradient steps on the photometric loss from the feed-forward attributes.

The loss is the training objective's (:func:`reconphys.render.photometric.photometric_loss`): the
asset is simulated from its initial state with self-forcing, rendered into the recording's camera
and compared with the masked frames 1..T−1 by mean squared error. The mass stays as predicted (a
video fixes only k/m and d/m, docs/design.md#physical-model); log k, log d and the friction (through
a logit) are optimised with Adam, inside the attribute ranges. The attributes of the lowest loss
seen are kept.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import torch

from ..assets.asset import Asset
from ..capture import Observation
from ..capture.window import comparison_view
from ..physics.model import ATTRIBUTE_RANGES
from ..render.photometric import SceneBatch, photometric_loss

REFINE_LR = 0.05  # Adam step in log k, log d and logit f
MIN_SUBSTEPS = 25  # as the cpu_small training recipe (configs/cpu_small.toml)


def _logit(p: float) -> float:
    p = min(max(p, 0.02), 0.98)
    return math.log(p / (1 - p))


def refine(
    asset: Asset,
    observation: Observation,
    steps: int,
    resolution: int = 64,  # render size of the loss (frames are area-averaged down to it)
    num_frames: int = 20,  # frames 0..num_frames−1 are compared (frame 0 is the initial state)
    lr: float = REFINE_LR,
    progress: bool = False,
) -> tuple[Asset, dict]:
    """``steps`` Adam steps → (asset with the best attributes, history dict)."""
    frames = observation.frames[:num_frames]  # [T, H, W, 3]
    frames, camera = comparison_view(frames, observation.camera, resolution)
    size = frames.shape[1:3]
    cameras = camera.cameras()
    scenes = SceneBatch.from_assets([asset])
    physics = asset.physics
    mass = torch.tensor([physics.mass])
    params = torch.tensor(
        [math.log(physics.stiffness), math.log(physics.damping), _logit(physics.friction)],
        requires_grad=True,
    )
    (k_low, k_high), (d_low, d_high) = ATTRIBUTE_RANGES["stiffness"], ATTRIBUTE_RANGES["damping"]
    optimizer = torch.optim.Adam([params], lr=lr)

    def attributes(p: torch.Tensor) -> dict[str, torch.Tensor]:
        return {
            "mass": mass,
            "stiffness": p[0:1].clamp(math.log(k_low), math.log(k_high)).exp(),
            "damping": p[1:2].clamp(math.log(d_low), math.log(d_high)).exp(),
            "friction": torch.sigmoid(p[2:3]),
        }

    started = time.perf_counter()
    losses, best = [], (math.inf, None)
    iterator = range(steps + 1)  # the last evaluation scores the final step
    if progress:
        from tqdm.auto import tqdm

        iterator = tqdm(iterator, desc="refine", unit="step")
    for step in iterator:
        optimizer.zero_grad()
        values = attributes(params)
        loss = photometric_loss(
            values,
            scenes,
            frames[None],
            cameras,
            window=1,
            frame_dt=physics.frame_dt,
            min_substeps=MIN_SUBSTEPS,
        )
        losses.append(loss.item())
        if losses[-1] < best[0]:
            best = (losses[-1], {k: v[0].item() for k, v in values.items()})
        if step == steps:
            break
        loss.backward()
        if not bool(torch.isfinite(params.grad).all()):
            break
        optimizer.step()
    chosen = best[1]
    refined = replace(asset, physics=replace(physics, **chosen))
    history = {
        "steps": steps,
        "loss_initial": losses[0],
        "loss_best": best[0],
        "best_step": losses.index(best[0]),
        "loss_curve": [round(x, 7) for x in losses],
        "attributes": chosen,
        "render_size": list(size),
        "seconds": round(time.perf_counter() - started, 2),
    }
    return refined, history
