"""Pretrained image encoders for the physics predictor, loaded from local files only.

Two registry entries beside the default ``small_cnn`` (:mod:`reconphys.models.physics_predictor`);
their options live in ``PredictorConfig.extra`` (``model.extra.*`` in a training config):

- ``timm`` — any timm model by name: ``extra = {"name": "resnet18", "weights": "PATH"}``.
  ``weights`` is a local ``.safetensors`` / ``.pth`` / ``.bin`` file of that model (as timm or
  the Hugging Face Hub store it); empty means random initialisation. Needs the ``timm`` package
  (extra ``pretrained``; it pulls torchvision, so it is not part of ``dev``).
- ``transformers`` — a local Hugging Face model folder (``config.json`` + weights), e.g. a ViT,
  DINOv2 or InternViT checkpoint: ``extra = {"path": "FOLDER", "trust_remote_code": false}``.
  InternViT ships its modelling code in the folder and needs ``trust_remote_code = true``.

Nothing is ever downloaded: timm is created with ``pretrained=False`` and fed the file,
transformers runs with ``local_files_only=True`` and ``HF_HUB_OFFLINE=1``. A missing package,
file or folder is a one-line :class:`~reconphys.errors.InputError` naming it.

Both encoders map images [N, 3, H, W] in [0, 1] to feature maps [N, C, h, w]: inputs are
normalised with ``extra.mean`` / ``extra.std`` (default ImageNet's), and token outputs of vision
transformers drop their prefix (class / register) tokens and are folded back to the patch grid.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch
from torch import Tensor, nn

from ..errors import InputError
from .encoders import register_encoder
from .physics_predictor import PredictorConfig

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def _require(package: str):
    try:
        return __import__(package)
    except ImportError:
        raise InputError(
            f"the {package!r} package is not installed (pip install 'reconphys[pretrained]')",
            field="model.encoder",
        ) from None


def tokens_to_map(tokens: Tensor, prefix: int) -> Tensor:
    """Transformer tokens [N, P + h·w, C] (P prefix tokens first) → feature map [N, C, h, w]."""
    n, length, c = tokens.shape
    side = math.isqrt(length - prefix)
    if side * side != length - prefix:
        raise ValueError(f"{length - prefix} patch tokens do not form a square grid")
    return tokens[:, prefix:].transpose(1, 2).reshape(n, c, side, side)


class _Normalised(nn.Module):
    """Shared by both encoders: per-channel normalisation, then the backbone's feature map."""

    def __init__(self, extra: dict):
        super().__init__()
        mean = torch.tensor(extra.get("mean", IMAGENET_MEAN), dtype=torch.float32)
        std = torch.tensor(extra.get("std", IMAGENET_STD), dtype=torch.float32)
        self.register_buffer("mean", mean.view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", std.view(1, 3, 1, 1), persistent=False)

    def normalise(self, images: Tensor) -> Tensor:
        return (images - self.mean) / self.std


class TimmEncoder(_Normalised):
    def __init__(self, extra: dict):
        super().__init__(extra)
        timm = _require("timm")
        name = extra.get("name")
        if not name:
            raise InputError("the timm encoder needs a model name", field="model.extra.name")
        weights = str(extra.get("weights", "") or "")
        if weights and not Path(weights).is_file():
            raise InputError("weights file not found", source=weights, field="model.extra.weights")
        overlay = {"file": weights} if weights else None
        try:
            self.backbone = timm.create_model(
                name, pretrained=bool(weights), pretrained_cfg_overlay=overlay, num_classes=0
            )
        except RuntimeError as e:  # timm's "Unknown model" and weight mismatches
            raise InputError(f"timm cannot build {name!r} ({e})", field="model.extra") from None
        self.prefix = int(getattr(self.backbone, "num_prefix_tokens", 0))
        self.out_channels = int(self.backbone.num_features)

    def forward(self, images: Tensor) -> Tensor:
        features = self.backbone.forward_features(self.normalise(images))
        if features.dim() == 3:  # a vision transformer's tokens
            features = tokens_to_map(features, self.prefix)
        elif features.shape[1] != self.out_channels:  # channels-last feature maps
            features = features.permute(0, 3, 1, 2)
        return features


class TransformersEncoder(_Normalised):
    def __init__(self, extra: dict):
        super().__init__(extra)
        transformers = _require("transformers")
        path = str(extra.get("path", "") or "")
        if not path:
            raise InputError("the transformers encoder needs a model folder",
                             field="model.extra.path")  # fmt: skip
        if not (Path(path) / "config.json").is_file():
            raise InputError("not a local model folder (no config.json)", source=path,
                             field="model.extra.path")  # fmt: skip
        os.environ["HF_HUB_OFFLINE"] = "1"  # belt and braces: never reach the network
        trust = bool(extra.get("trust_remote_code", False))
        try:
            model = transformers.AutoModel.from_pretrained(
                path, local_files_only=True, trust_remote_code=trust
            )
        except (OSError, ValueError) as e:
            message = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise InputError(f"cannot load the model ({message})", source=path) from None
        self.backbone = getattr(model, "vision_model", model)  # CLIP-style wrappers
        config = self.backbone.config
        self.out_channels = int(getattr(config, "hidden_size", 0) or config.hidden_sizes[-1])
        self.prefix = 0  # class/register tokens before the patches, set by each call

    def forward(self, images: Tensor) -> Tensor:
        output = self.backbone(pixel_values=self.normalise(images))
        hidden = output.last_hidden_state
        if hidden.dim() == 4:  # convolutional backbones: already [N, C, h, w]
            return hidden
        patch = self.backbone.config.patch_size
        patch = patch[0] if isinstance(patch, (tuple, list)) else patch
        grid = (images.shape[-2] // patch) * (images.shape[-1] // patch)
        self.prefix = hidden.shape[1] - grid  # from this call's size, never a stale one
        return tokens_to_map(hidden, self.prefix)


@register_encoder("timm")
def _timm(config: PredictorConfig) -> nn.Module:
    return TimmEncoder(config.extra)


@register_encoder("transformers")
def _transformers(config: PredictorConfig) -> nn.Module:
    return TransformersEncoder(config.extra)
