"""The photometric loss of a self-forced rollout (docs/design.md#models, paper §3.4), shared by
training (:mod:`reconphys.train.objective`) and test-time refinement
(:mod:`reconphys.pipeline.refine`).

Predicted attributes drive the spring-mass rollout from the scenes' initial state; the rollout
continues from its own predicted state (self-forcing) and is detached every ``window`` frames
(truncated back-propagation; 1 = every frame, as in the paper); Gaussian centres follow the
anchors through the binding; the input view is rendered and compared with the video by mean
squared error over frames 1..T−1. Gradients reach the attributes through the exact adjoint of the
simulator (``rollout(method="auto")``) and the differentiable renderer.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ..assets.asset import Asset
from ..physics import SpringMassModel, State, deform_means, rollout, stable_substeps
from . import render
from .cameras import Cameras


@dataclass
class SceneBatch:
    """B scenes with the same anchor count, springs padded to a common E (pads: k = d = 0)."""

    assets: list[Asset]
    springs: Tensor  # [B, E, 2] int64
    rest_length: Tensor  # [B, E] metres
    active: Tensor  # [B, E] 1 for real springs, 0 for padding
    x0: Tensor  # [B, N_A, 3] metres
    v0: Tensor  # [B, N_A, 3] m/s

    @staticmethod
    def from_assets(assets: list[Asset], device=None) -> SceneBatch:
        counts = {a.num_anchors for a in assets}
        if len(counts) != 1:
            raise ValueError(f"scenes in one batch need the same anchor count, got {counts}")
        num_springs = max(a.springs.shape[0] for a in assets)
        springs = torch.zeros(len(assets), num_springs, 2, dtype=torch.int64)
        rest = torch.ones(len(assets), num_springs)
        active = torch.zeros(len(assets), num_springs)
        for b, asset in enumerate(assets):
            e = asset.springs.shape[0]
            springs[b, :e] = asset.springs
            rest[b, :e] = asset.rest_length
            active[b, :e] = 1.0
            # Pads repeat the scene's first spring with k = d = 0: a spring between two distinct
            # anchors has a direction, so the stability bound and the forces stay finite (a
            # zero-length pad (0, 0) made them 0/0).
            springs[b, e:] = asset.springs[0]
            rest[b, e:] = asset.rest_length[0]
        x0 = torch.stack([a.x0 for a in assets]).float()
        v0 = torch.stack([a.v0 for a in assets]).float()
        return SceneBatch(
            assets, springs.to(device), rest.to(device), active.to(device), x0.to(device),
            v0.to(device),
        )  # fmt: skip

    def model(self, attributes: dict[str, Tensor]) -> SpringMassModel:
        """The batch's simulator with per-scene attributes ``{name: [B]}``."""
        physics = self.assets[0].physics
        return SpringMassModel(
            self.springs,
            self.rest_length,
            mass=attributes["mass"],
            stiffness=attributes["stiffness"][:, None] * self.active,
            damping=attributes["damping"][:, None] * self.active,
            friction=attributes["friction"],
            spring_exponent=physics.spring_exponent,
            restitution=physics.restitution,
            gravity=tuple(physics.gravity),
            ground_height=physics.ground_height,
        )


def photometric_loss(
    attributes: dict[str, Tensor],  # name → [B] predicted attributes
    scenes: SceneBatch,
    frames: Tensor,  # [B, T, H, W, 3] the input view's video, frame 0 = initial state
    cameras: Cameras,  # K [B, 3, 3], world_to_cam [B, 4, 4]: the input view of each scene
    window: int = 1,  # frames between detaches of the simulated state
    frame_dt: float = 0.03,
    min_substeps: int = 100,
    backend: str = "auto",  # the renderer (reconphys.render.render)
) -> Tensor:  # scalar
    """Mean squared photometric error of the self-forced rollout over frames 1..T−1."""
    if window < 1:
        raise ValueError(f"window: must be ≥ 1 frame, got {window}")
    model = scenes.model(attributes)
    with torch.no_grad():
        detached = scenes.model({k: v.detach() for k, v in attributes.items()})
        substeps = stable_substeps(detached, scenes.x0, frame_dt, min_substeps)
    state = State(scenes.x0, scenes.v0)
    num_frames = frames.shape[1]
    losses = []
    for t in range(1, num_frames):
        if (t - 1) % window == 0:
            state = state.detach()
        trajectory = rollout(model, state, 1, frame_dt, substeps=substeps)
        state = State(trajectory.x[:, -1], trajectory.v[:, -1])
        for b, asset in enumerate(scenes.assets):
            g = asset.gaussians.to(state.x.device)
            means = deform_means(
                g.means, scenes.x0[b], state.x[b], asset.binding_index, asset.binding_weight
            )
            camera = cameras.select(slice(b, b + 1))
            image = render(g.with_means(means), camera, backend=backend).rgb[0]
            losses.append(F.mse_loss(image, frames[b, t]))
    return torch.stack(losses).mean()
