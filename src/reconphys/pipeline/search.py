"""Gradient-free refinement: fit the observables to a recording by batched re-simulation.

Only k/m, d/m and the friction are observable (docs/design.md#identifiability), so the search moves
those three and keeps the mass. It is a coordinate search: for each span (coarse to fine) and each
observable, ``candidates`` values around the current one (the other two fixed) are simulated as
one batch from the asset's initial state, rendered into the recording's camera and compared with
frames 1..T−1 by mean squared error; the best is kept. Each round is one batched rollout and one
batched render, so a whole search (3 spans × 3 observables × 7 candidates = 63 rollouts) costs a
few seconds at 32 px and 256 anchors on two cores (docs/training.md "Refinement by batched
search"), against minutes for gradient steps, and it needs no gradient through contact, which is
what moves friction. The photometric error of every candidate is kept in the history.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.asset import Asset
from ..capture import CameraSpec
from ..physics import SpringMassModel, State, deform_means, rollout, stable_substeps
from ..physics.model import ATTRIBUTE_RANGES
from ..render import render

SPANS = (2.0, 0.7, 0.25)  # half-widths of the candidate grids in natural log of k/m and d/m
FRICTION_SPAN_SCALE = 0.25  # friction's half-width = span × this
CANDIDATES = 7  # values per observable and round (one batched rollout)
MIN_SUBSTEPS = 25  # as the cpu_small training recipe and pipeline/refine.py
# A candidate replaces the current value only if its error is lower by this fraction: where the
# video does not show an observable (all errors alike), the start is kept, not a grid end.
TIE = 1e-6
OBSERVABLES = ("log_k_over_m", "log_d_over_m", "friction")


def observables(physics) -> Tensor:  # [3] (log k/m, log d/m, f)
    return torch.tensor(
        [
            math.log(physics.stiffness / physics.mass),
            math.log(physics.damping / physics.mass),
            physics.friction,
        ],
        dtype=torch.float64,
    )


def attributes_of(values: Tensor, mass: float) -> dict[str, Tensor]:
    """(log k/m, log d/m, f) [B, 3] → stiffness, damping, friction [B], inside the attribute ranges
    (the mass is kept: only the ratios are observable)."""
    ranges = ATTRIBUTE_RANGES
    return {
        "stiffness": (values[:, 0].exp() * mass).clamp(*ranges["stiffness"]),
        "damping": (values[:, 1].exp() * mass).clamp(*ranges["damping"]),
        "friction": values[:, 2].clamp(0.0, 1.0),
    }


@torch.no_grad()
def photometric_errors(
    asset: Asset,
    frames: Tensor,  # [T, H, W, 3] in [0, 1], frame 0 = the initial state
    camera: CameraSpec,  # the frames' camera, at their size
    candidates: Tensor,  # [B, 3] (log k/m, log d/m, f)
    min_substeps: int = MIN_SUBSTEPS,
) -> Tensor:  # [B] mean squared error over frames 1..T−1
    """Simulate the asset with each candidate's attributes (mass kept) and score its video."""
    count, physics = len(candidates), asset.physics
    values = attributes_of(candidates, physics.mass)
    model = SpringMassModel(
        asset.springs,
        asset.rest_length,
        torch.full((count,), physics.mass),
        values["stiffness"].float(),
        values["damping"].float(),
        values["friction"].float(),
        spring_exponent=physics.spring_exponent,
        restitution=physics.restitution,
        gravity=tuple(physics.gravity),
        ground_height=physics.ground_height,
    )
    x0 = asset.x0[None].expand(count, -1, -1)
    substeps = stable_substeps(model, x0, physics.frame_dt, min_substeps)
    state = State(x0, asset.v0[None].expand(count, -1, -1))
    steps = frames.shape[0] - 1
    trajectory = rollout(model, state, steps, physics.frame_dt, substeps=substeps)
    x = trajectory.x[:, 1:].reshape(count * steps, -1, 3)  # [B·(T−1), N_A, 3]
    g = asset.gaussians
    means = deform_means(g.means, asset.x0[None], x, asset.binding_index, asset.binding_weight)
    batch = g.map(lambda t: t.expand(len(x), *t.shape)).with_means(means)
    images = render(batch, camera.cameras()).rgb[:, 0].reshape(count, steps, *frames.shape[1:])
    return ((images - frames[1:][None]) ** 2).mean((1, 2, 3, 4))


def search(
    asset: Asset,
    frames: Tensor,  # [T, H, W, 3] in [0, 1] (T ≥ 2), the recording's frames 0..T−1
    camera: CameraSpec,  # the recording's camera
    resolution: int = 64,  # longest side of the comparison (frames are area-averaged down)
    spans: tuple[float, ...] = SPANS,
    candidates: int = CANDIDATES,
) -> tuple[Asset, dict]:
    """Coordinate search from the asset's attributes → (asset with the best, history dict)."""
    if frames.dim() != 4 or frames.shape[0] < 2 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected [T ≥ 2, H, W, 3], got {list(frames.shape)}")
    if candidates < 3 or candidates % 2 == 0:
        raise ValueError(f"candidates: expected an odd number ≥ 3, got {candidates}")
    started = time.perf_counter()
    height, width = frames.shape[1:3]
    scale = min(1.0, resolution / max(height, width))
    size = (max(8, round(height * scale)), max(8, round(width * scale)))
    if size != (height, width):
        frames = F.interpolate(frames.permute(0, 3, 1, 2), size=size, mode="area")
        frames = frames.permute(0, 2, 3, 1)
    camera = camera.resized(size[1], size[0])
    current = observables(asset.physics)
    start = current.clone()
    half = candidates // 2  # offsets −1..1 with an exact 0 at the centre (the current value)
    grid = torch.arange(-half, half + 1, dtype=torch.float64) / half
    rounds = []
    best_error = math.inf
    for span in spans:
        for i, name in enumerate(OBSERVABLES):
            trial = current.repeat(candidates, 1)
            half_width = span if i < 2 else span * FRICTION_SPAN_SCALE
            trial[:, i] = current[i] + grid * half_width
            trial[:, 2] = trial[:, 2].clamp(0.0, 1.0)
            errors = photometric_errors(asset, frames, camera, trial)
            pick = int(errors.argmin())
            if not errors[pick] < errors[half] * (1.0 - TIE):
                pick = half  # the current value: kept unless another is clearly better
            current, best_error = trial[pick], float(errors[pick])
            rounds.append(
                {"observable": name, "values": trial[:, i].tolist(), "errors": errors.tolist()}
            )
    # only what moved: exp(log(k/m))·m would not give back k to the last bit
    values = attributes_of(current[None], asset.physics.mass)
    names = ("stiffness", "damping", "friction")
    found = {name: float(values[name][0]) for i, name in enumerate(names) if current[i] != start[i]}
    history = {
        "method": "coordinate search (pipeline/search.py)",
        "start": dict(zip(OBSERVABLES, start.tolist(), strict=True)),
        "found": dict(zip(OBSERVABLES, current.tolist(), strict=True)),
        "error": best_error,
        "rounds": rounds,
        "render_size": list(size),
        "seconds": round(time.perf_counter() - started, 2),
    }
    return replace(asset, physics=replace(asset.physics, **found)), history
