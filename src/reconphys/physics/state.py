"""Simulation state: anchor positions and velocities of a batch of scenes."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor


@dataclass
class State:
    x: Tensor  # [B, N_A, 3] positions, metres
    v: Tensor  # [B, N_A, 3] velocities, m/s

    def detach(self) -> State:
        return State(self.x.detach(), self.v.detach())

    def clone(self) -> State:
        return State(self.x.clone(), self.v.clone())

    @property
    def batch_size(self) -> int:
        return self.x.shape[0]

    @property
    def num_anchors(self) -> int:
        return self.x.shape[1]


@dataclass
class Control:
    """External drivers applied during a step (the viewer's grab and push tools use this)."""

    force: Tensor | None = None  # [B, N_A, 3] external force on each anchor, newtons
