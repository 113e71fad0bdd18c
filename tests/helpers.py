"""Small deterministic geometry shared by the tests."""

from __future__ import annotations

import numpy as np
import torch


def ball_points(count: int, radius: float, seed: int = 0) -> torch.Tensor:
    """``count`` points uniformly in a ball of ``radius`` around the origin, [count, 3]."""
    g = torch.Generator().manual_seed(seed)
    direction = torch.randn(count, 3, generator=g, dtype=torch.float64)
    direction = direction / direction.norm(dim=1, keepdim=True)
    r = radius * torch.rand(count, 1, generator=g, dtype=torch.float64) ** (1 / 3)
    return direction * r


def box_grid(nx: int, ny: int, nz: int, spacing: float) -> torch.Tensor:
    """Anchors on a regular grid with the lowest layer at z = 0, centred in x and y, [N, 3]."""
    axes = [torch.arange(n, dtype=torch.float64) * spacing for n in (nx, ny, nz)]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return grid - torch.tensor([(nx - 1) * spacing / 2, (ny - 1) * spacing / 2, 0.0])


# A small procedural asset for the command-line tests: 400 Gaussians, 48 anchors, K = 8, ≥ 10
# substeps per frame (dropped from 0.3 m, it lands before frame 10).
SMALL_ASSET = ["--num-gaussians", "400", "--num-anchors", "48", "--neighbors", "8"]
SMALL_ASSET += ["--min-substeps", "10"]


def make_small_asset(out, *options):
    """``reconphys make-asset OUT --shape sphere`` with :data:`SMALL_ASSET` (``options`` after it
    win); returns ``out``."""
    from typer.testing import CliRunner

    from reconphys.cli import app

    args = ["make-asset", str(out), "--shape", "sphere", *SMALL_ASSET, *options]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    return out


def make_tiny_dataset(folder, **overrides):
    """A generated dataset in ``folder`` (32 px, 300 Gaussians, 64 anchors, K = 12; no training
    split unless overridden), made with torch on one thread; returns ``folder``."""
    from reconphys.data import make_dataset, make_settings

    settings = dict(
        objects=0,
        test_objects=1,
        test_samples_per_object=1,
        resolution=32,
        num_gaussians=300,
        num_anchors=64,
        num_neighbors=12,
        seed=0,
    )
    settings.update(overrides)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        make_dataset(make_settings(**settings), folder, workers=1, device="cpu")
    finally:
        torch.set_num_threads(threads)
    return folder


def train_tiny_gaussian_predictor(data, out, steps: int = 1, split: str = "test"):
    """A 3DGS predictor trained ``steps`` steps on ``split`` of ``data`` (U-Net widths 8, 16):
    a model file for the code paths, not a useful model. Returns the output folder."""
    from reconphys.train.gaussians import GaussianTrainSettings, train_gaussian_predictor

    settings = GaussianTrainSettings(
        data=str(data),
        out=str(out),
        split=split,
        steps=steps,
        batch_size=1,
        predictor={"channels": [8, 16]},
    )
    return train_gaussian_predictor(settings, progress=False, log=lambda line: None)


def rim_noise(masks: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """Masks [T, H, W] that gain or lose a pixel's rim on one side at random per frame (as the
    mask segmenter's do)."""
    noisy = []
    for mask in masks.numpy() > 0.5:
        axis, step = [(0, 1), (0, -1), (1, 1), (1, -1)][rng.integers(4)]
        moved = np.roll(mask, step, axis=axis)
        noisy.append(mask | moved if rng.uniform() < 0.5 else mask & moved)
    return torch.from_numpy(np.stack(noisy)).float()
