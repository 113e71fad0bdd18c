"""LPIPS (AlexNet, v0.1) from local weights only; unavailable (None) when they are missing.

LPIPS needs two files that are normally downloaded at run time, which this project never does:

- torchvision's ImageNet AlexNet, ``alexnet-owt-7be5be79.pth`` (the ``features.*`` tensors);
- the LPIPS v0.1 linear heads, ``alex.pth`` (``lin0..4.model.1.weight``), shipped in the ``lpips``
  wheel under ``lpips/weights/v0.1/``.

They are looked for in ``$RECONPHYS_LPIPS_DIR``, then torch's hub cache
(``~/.cache/torch/hub/checkpoints``) and the installed ``lpips`` package. When either is missing,
:func:`load_lpips` returns None and reports say "unavailable" — no other network stands in for it.

The network is re-implemented here (torchvision is not importable beside the CPU torch wheel):
inputs in [0, 1] are mapped to [-1, 1], shifted and scaled per channel, passed through AlexNet's
five conv+ReLU stages; each stage's features are unit-normalised over channels, their squared
difference weighted by the linear head and averaged over space; the five terms are summed.
Images smaller than 64 px on a side are bilinearly upsampled to 64 px first (AlexNet's pooling
needs at least that); say so when reporting LPIPS at such sizes.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
HEADS_FILE = "alex.pth"
CHANNELS = (64, 192, 384, 256, 256)
TAPS = (1, 4, 7, 9, 11)  # indices of the ReLUs after conv1..conv5 in ``features``
MIN_SIDE = 64


class AlexLPIPS(nn.Module):
    def __init__(self):
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, stride=4, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(64, 192, 5, padding=2),
            nn.ReLU(),
            nn.MaxPool2d(3, 2),
            nn.Conv2d(192, 384, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(384, 256, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(256, 256, 3, padding=1),
            nn.ReLU(),
        )
        self.heads = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in CHANNELS)
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))

    def _taps(self, x: Tensor) -> list[Tensor]:
        x = ((2 * x - 1) - self.shift) / self.scale
        taps = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in TAPS:
                taps.append(x / (x.norm(dim=1, keepdim=True) + 1e-10))
        return taps

    @torch.no_grad()
    def forward(self, prediction: Tensor, target: Tensor) -> Tensor:
        """prediction, target [..., H, W, 3] in [0, 1] → LPIPS [...]."""
        batch_shape = prediction.shape[:-3]
        h, w = prediction.shape[-3:-1]
        x = prediction.reshape(-1, h, w, 3).permute(0, 3, 1, 2).float()
        y = target.reshape(-1, h, w, 3).permute(0, 3, 1, 2).float()
        if min(h, w) < MIN_SIDE:
            size = (
                max(MIN_SIDE, h * MIN_SIDE // min(h, w)),
                max(MIN_SIDE, w * MIN_SIDE // min(h, w)),
            )
            x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
            y = F.interpolate(y, size=size, mode="bilinear", align_corners=False)
        total = 0.0
        for head, fx, fy in zip(self.heads, self._taps(x), self._taps(y), strict=True):
            total = total + head((fx - fy) ** 2).mean((-2, -1))[:, 0]
        return total.reshape(batch_shape)


def _candidates() -> list[Path]:
    folders = []
    if os.environ.get("RECONPHYS_LPIPS_DIR"):
        folders.append(Path(os.environ["RECONPHYS_LPIPS_DIR"]))
    folders.append(Path(torch.hub.get_dir()) / "checkpoints")
    spec = importlib.util.find_spec("lpips")
    if spec is not None and spec.origin is not None:
        folders.append(Path(spec.origin).parent / "weights" / "v0.1")
    return folders


def find_lpips_weights() -> tuple[Path, Path] | None:
    """(AlexNet file, heads file) if both are found locally, else None."""
    found = {}
    for folder in _candidates():
        for name in (ALEXNET_FILE, HEADS_FILE):
            if name not in found and (folder / name).is_file():
                found[name] = folder / name
    if len(found) < 2:
        return None
    return found[ALEXNET_FILE], found[HEADS_FILE]


def load_lpips(device: torch.device | str = "cpu") -> AlexLPIPS | None:
    """The LPIPS network with its published weights, or None when they are not on this machine."""
    paths = find_lpips_weights()
    if paths is None:
        return None
    alexnet = torch.load(paths[0], map_location="cpu", weights_only=True)
    heads = torch.load(paths[1], map_location="cpu", weights_only=True)
    model = AlexLPIPS()
    features = {
        k.removeprefix("features."): v for k, v in alexnet.items() if k.startswith("features.")
    }
    model.features.load_state_dict(features)
    for i, head in enumerate(model.heads):
        head.weight.data.copy_(heads[f"lin{i}.model.1.weight"])
    return model.eval().to(device)
