"""Per-frame image encoders of the physics predictor, by name.

:data:`ENCODERS` holds the encoders registered with :func:`register_encoder`: here ``small_cnn``
(trained from scratch). The pretrained ones (``timm``, ``transformers``) live in
:mod:`reconphys.models.pretrained`, which needs optional packages, so it is imported only when
such an encoder is asked for (:data:`LAZY_ENCODERS`, :func:`build_encoder`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import torch
from torch import Tensor, nn

MOTION_CHANNEL_GROUPS = 3  # the frame, its change from the previous frame, its change from frame 0

# name → factory(config: PredictorConfig) -> module, for the encoders registered so far.
ENCODERS: dict[str, Callable[..., nn.Module]] = {}
# Encoders that need optional packages: the module that registers them, imported on first use.
LAZY_ENCODERS = {
    "timm": "reconphys.models.pretrained",
    "transformers": "reconphys.models.pretrained",
}


def register_encoder(name: str):
    """Decorator: ``ENCODERS[name] = factory(config) -> module``; the module maps images
    [N, 3, H, W] to feature maps [N, C, h, w] and has an ``out_channels`` attribute."""

    def wrap(factory):
        ENCODERS[name] = factory
        return factory

    return wrap


def group_norm(channels: int) -> nn.GroupNorm:
    """GroupNorm with up to 8 groups (fewer for narrow layers)."""
    return nn.GroupNorm(min(8, channels), channels)


class SmallCNN(nn.Module):
    """Stride-2 conv stages with GroupNorm and SiLU: [N, 3, H, W] → [N, C, H/2^S, W/2^S].

    ``coords=True`` appends two channels holding the pixel's x and y in [−1, 1] to the input
    (CoordConv): the trunk averages its maps over space, and without them the features say
    little about *where* the object is — e.g. how far it slides (friction).
    """

    def __init__(self, channels: tuple[int, ...], coords: bool = False, in_channels: int = 3):
        super().__init__()
        self.coords = coords
        layers, previous = [], in_channels + (2 if coords else 0)
        for c in channels:
            layers += [
                nn.Conv2d(previous, c, 3, stride=2, padding=1),
                group_norm(c),
                nn.SiLU(),
                nn.Conv2d(c, c, 3, padding=1),
                group_norm(c),
                nn.SiLU(),
            ]
            previous = c
        self.layers = nn.Sequential(*layers)
        self.out_channels = previous

    def forward(self, images: Tensor) -> Tensor:
        if self.coords:
            n, _, h, w = images.shape
            y = torch.linspace(-1, 1, h, device=images.device, dtype=images.dtype)
            x = torch.linspace(-1, 1, w, device=images.device, dtype=images.dtype)
            grid = torch.stack(torch.meshgrid(x, y, indexing="xy"))  # [2, H, W]: x, y
            images = torch.cat([images, grid.expand(n, 2, h, w)], 1)
        return self.layers(images)


@register_encoder("small_cnn")
def _small_cnn(config) -> nn.Module:  # config: PredictorConfig
    unknown = set(config.extra) - {"coords"}
    if unknown:
        raise ValueError(f"extra: small_cnn takes only 'coords', got {sorted(unknown)}")
    return SmallCNN(
        config.encoder_channels,
        coords=bool(config.extra.get("coords", False)),
        in_channels=3 * MOTION_CHANNEL_GROUPS if config.motion else 3,
    )


def encoder_names() -> list[str]:
    """Every encoder name a config may use (registered or loadable), sorted."""
    return sorted(set(ENCODERS) | set(LAZY_ENCODERS))


def build_encoder(config) -> nn.Module:  # config: PredictorConfig
    """The encoder ``config.encoder``, importing its module first when it is a lazy one."""
    if config.encoder not in ENCODERS and config.encoder in LAZY_ENCODERS:
        importlib.import_module(LAZY_ENCODERS[config.encoder])
    if config.encoder not in ENCODERS:
        raise ValueError(f"encoder: unknown {config.encoder!r}; known: {encoder_names()}")
    return ENCODERS[config.encoder](config)
