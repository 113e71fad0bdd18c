"""Rendering a sequence of frames of one Gaussian set whose centres move (a simulated clip)."""

from __future__ import annotations

import torch
from torch import Tensor

from ..assets.gaussians import Gaussians
from . import render
from .cameras import Cameras


def render_sequence(
    gaussians: Gaussians,  # [N, ·] the rest-pose Gaussians (their means are replaced per frame)
    means: Tensor,  # [T, N, 3] Gaussian centres per frame, metres
    cameras: Cameras,  # one camera (C = 1), no batch dims
    backend: str = "auto",
    progress: bool = False,
    with_alpha: bool = False,
) -> Tensor:  # [T, H, W, 3] colour in [0, 1], black background; with_alpha: [T, H, W, 4]
    """Render the moved Gaussians frame by frame (bounded memory) on ``means``' device; with
    ``with_alpha`` the accumulated opacity is the fourth channel (the colour stays on black:
    over a background ``b`` the frame is ``rgb + (1 − alpha)·b``)."""
    device = means.device
    gaussians = gaussians.to(device)
    cameras = cameras.to(device)
    frames = range(means.shape[0])
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, desc="render", unit="frame")
    images = []
    with torch.no_grad():
        for t in frames:
            out = render(gaussians.with_means(means[t]), cameras, backend)
            images.append(
                torch.cat([out.rgb[0], out.alpha[0][..., None]], -1) if with_alpha else out.rgb[0]
            )
    return torch.stack(images)
