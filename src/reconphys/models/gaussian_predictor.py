"""Feed-forward 3DGS predictor: one masked image → one Gaussian per pixel (Splatter-Image style).

The paper's 3DGS branch is a frozen image-to-3D model (TRELLIS) whose weights cannot be had here;
this is the project's own small replacement (docs/design.md#models (b)). A U-Net reads the image,
its mask and each pixel's viewing ray and predicts per pixel:

- the depth of the Gaussian along the pixel's ray, ``reference_depth + depth_range · tanh(·)``
  (metres, camera z), and a small 3D offset ``offset_range · tanh(·)`` (metres, camera frame);
- log-scales in ``[log min_scale, log max_scale]``, a rotation quaternion, an opacity logit and
  an RGB colour (stored as the SH degree-0 coefficient).

The camera is known (K, world_to_cam), so every Gaussian is placed in the world frame. Pixels
outside the mask are dropped by :func:`prune_gaussians` (with the low-opacity ones), which also
caps the count, so the result is a clean object to sample anchors from.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..assets.gaussians import SH_C0, Gaussians
from ..geometry import matrix_to_quaternion, quaternion_multiply

OUTPUT_CHANNELS = 1 + 3 + 3 + 4 + 1 + 3  # depth, offset, log-scale, quaternion, opacity, colour
# On a finer crop (forward's detail) each Gaussian is this many fine pixels' worth of the
# model's size (R/S of it, never more than 1×): a little more than its pixel, so neighbours
# overlap as the springs bend the asset. Chosen between 1 and 1.5 on validation drops (4-view
# PSNR 16.85 / 17.00 dB; docs/usage.md#the-object-in-detail-2026-11-29)
DETAIL_OVERLAP = 1.5


@dataclass
class GaussianPredictorConfig:
    resolution: int = 32  # input and output size (square), pixels: resolution² Gaussians
    channels: list[int] = field(default_factory=lambda: [32, 64, 128])  # U-Net widths per level
    reference_depth: float = 2.0  # metres: the dataset cameras' distance to the drop region
    depth_range: float = 0.6  # metres around the reference depth
    offset_range: float = 0.05  # metres
    min_scale: float = 0.002  # metres
    max_scale: float = 0.08  # metres
    # object-centric (frame_crop's input): depth around a reference depth given per image (the
    # object's centre), and depth_range, offset_range, min_scale and max_scale read as shares of
    # the crop's width at that depth, so one network serves any object size and distance; the
    # colour is the input pixel's plus a learned correction (logits)
    crop: bool = False
    crop_margin: float = 0.15  # frame_crop's margin

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> GaussianPredictorConfig:
        return cls(**data)


def _block(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, 3, padding=1),
        nn.GroupNorm(min(8, out_channels), out_channels),
        nn.SiLU(),
        nn.Conv2d(out_channels, out_channels, 3, padding=1),
        nn.GroupNorm(min(8, out_channels), out_channels),
        nn.SiLU(),
    )


class UNet(nn.Module):
    """Encoder–decoder with skip connections: [B, C_in, H, W] → [B, C_out, H, W] (H, W divisible
    by 2^(levels−1))."""

    def __init__(self, in_channels: int, out_channels: int, channels: list[int]):
        super().__init__()
        self.down = nn.ModuleList()
        previous = in_channels
        for width in channels:
            self.down.append(_block(previous, width))
            previous = width
        self.up = nn.ModuleList()
        for width in reversed(channels[:-1]):
            self.up.append(_block(previous + width, width))
            previous = width
        self.head = nn.Conv2d(previous, out_channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        skips = []
        for level, block in enumerate(self.down):
            if level > 0:
                x = F.avg_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1]), strict=True):
            x = F.interpolate(x, size=skip.shape[-2:], mode="nearest")
            x = block(torch.cat([x, skip], dim=1))
        return self.head(x)


def pixel_rays(K: Tensor, size: int) -> Tensor:  # K [B, 3, 3] at `size` → [B, size, size, 3]
    """Camera-frame ray directions with z = 1 through each pixel centre."""
    centres = torch.arange(size, dtype=K.dtype, device=K.device) + 0.5
    v, u = torch.meshgrid(centres, centres, indexing="ij")
    x = (u[None] - K[:, 0, 2, None, None]) / K[:, 0, 0, None, None]
    y = (v[None] - K[:, 1, 2, None, None]) / K[:, 1, 1, None, None]
    return torch.stack([x, y, torch.ones_like(x)], dim=-1)


class GaussianPredictor(nn.Module):
    def __init__(self, config: GaussianPredictorConfig | None = None):
        super().__init__()
        self.config = config or GaussianPredictorConfig()
        levels = len(self.config.channels)
        if self.config.resolution % 2 ** (levels - 1):
            raise ValueError(
                f"resolution {self.config.resolution} must be divisible by 2^{levels - 1}"
            )
        self.unet = UNet(3 + 1 + 3, OUTPUT_CHANNELS, list(self.config.channels))
        with torch.no_grad():  # start as a sheet at the reference depth, mid-size, opaque
            self.unet.head.weight.mul_(0.1)
            self.unet.head.bias.zero_()
            self.unet.head.bias[7] = 1.0  # quaternion w
            self.unet.head.bias[11] = 2.0  # opacity logit

    def forward(
        self,
        images: Tensor,  # [B, R, R, 3] in [0, 1], background black, at config.resolution
        masks: Tensor,  # [B, R, R] in {0, 1}
        K: Tensor,  # [B, 3, 3] pixels at config.resolution
        world_to_cam: Tensor,  # [B, 4, 4]
        reference_depth: Tensor | None = None,  # [B] metres (camera z of the object's centre)
        detail: tuple[Tensor, Tensor] | None = None,  # crop models: the same crop at S ≥ R px,
        # ([B, S, S, 3] image, [B, S, S] mask): one Gaussian per pixel of it (upsampled_outputs)
    ) -> Gaussians:  # [B, R², ·] world frame ([B, S², ·] with detail)
        """Per pixel one Gaussian. ``reference_depth`` is required by a crop model (its depths
        and sizes are relative to it) and ignored by the others (config.reference_depth).

        ``detail``: the network still reads the R-px crop, but its per-pixel outputs are
        resampled to S px (:func:`upsampled_outputs`) and each S-px pixel gets a Gaussian on its
        own ray, with its own colour and sizes × min(1, DETAIL_OVERLAP · R / S) — the appearance
        at the recording's resolution on the geometry the network predicts at R (S = R gives
        the plain forward)."""
        c = self.config
        batch, size = images.shape[0], images.shape[1]
        if size != c.resolution or images.shape[2] != c.resolution:
            raise ValueError(f"images: expected {c.resolution}² pixels, got {list(images.shape)}")
        rays = pixel_rays(K.to(images.dtype), size)  # [B, R, R, 3]
        x = torch.cat([images, masks[..., None], rays], dim=-1).permute(0, 3, 1, 2)
        out = self.unet(x).permute(0, 2, 3, 1)  # [B, R, R, C]
        shrink = 0.0  # log of the Gaussians' size factor
        if detail is not None:
            if not c.crop:
                raise ValueError("detail: only a crop 3DGS predictor reads a finer crop")
            images, fine_masks = detail
            fine = images.shape[1]
            if (
                fine < size
                or images.shape[1:] != (fine, fine, 3)
                or fine_masks.shape[1:] != images.shape[1:3]
            ):
                raise ValueError(
                    f"detail: expected [B, S, S, 3] and [B, S, S] with S ≥ {size}, got "
                    f"{list(images.shape)} and {list(fine_masks.shape)}"
                )
            out = upsampled_outputs(out, masks, fine)
            K = K.clone()
            K[:, :2] = K[:, :2] * (fine / size)  # the same crop at S px: K scales with it
            rays = pixel_rays(K.to(images.dtype), fine)
            shrink = min(0.0, math.log(DETAIL_OVERLAP * size / fine))
            size = fine
        out = out.reshape(batch, size * size, OUTPUT_CHANNELS)
        if c.crop:
            if reference_depth is None:
                raise ValueError("a crop 3DGS predictor needs reference_depth (metres)")
            centre = reference_depth.to(images.dtype).reshape(batch, 1, 1)
            unit = centre * size / K[:, 0, 0].to(images.dtype).reshape(batch, 1, 1)  # crop width
        else:
            centre = torch.full((batch, 1, 1), c.reference_depth, dtype=images.dtype)
            unit = torch.ones_like(centre)
        depth = centre + c.depth_range * unit * torch.tanh(out[..., 0:1])
        offset = c.offset_range * unit * torch.tanh(out[..., 1:4])
        points_cam = rays.reshape(batch, -1, 3) * depth + offset  # [B, R², 3]
        rotation = world_to_cam[:, :3, :3].to(images.dtype)
        translation = world_to_cam[:, :3, 3].to(images.dtype)
        means = (points_cam - translation[:, None]) @ rotation  # Rᵀ (x − t), row vectors
        low = math.log(c.min_scale) + torch.log(unit)
        high = math.log(c.max_scale) + torch.log(unit)
        log_scales = low + (high - low) * torch.sigmoid(out[..., 4:7]) + shrink
        # quaternions are in the camera frame: rotate them to the world frame (q_w = q_R⁻¹ ⊗ q)
        quats = _rotate_quaternions(F.normalize(out[..., 7:11], dim=-1), rotation)
        if c.crop:  # the pixel's own colour, corrected: the input view stays sharp
            seen = images.reshape(batch, -1, 3).clamp(0.01, 0.99)
            rgb = torch.sigmoid(torch.logit(seen) + out[..., 12:15])
        else:
            rgb = torch.sigmoid(out[..., 12:15])
        return Gaussians(
            means=means,
            quats=quats,
            log_scales=log_scales,
            opacity_logits=out[..., 11],
            sh0=(rgb - 0.5) / SH_C0,
        )


def upsampled_outputs(
    out: Tensor,  # [B, R, R, C] the network's raw per-pixel outputs
    masks: Tensor,  # [B, R, R] in {0, 1}: the object's pixels at R
    size: int,  # S ≥ R
) -> Tensor:  # [B, S, S, C]
    """The outputs resampled to S px (bilinear), weighted by the mask: an S-px pixel at the
    object's edge takes its neighbours on the object, not the background pixels' outputs (whose
    depths nothing trained: a Gaussian there would fly off the surface). Where no object pixel
    is near, the plain bilinear value."""
    if size == out.shape[1]:
        return out
    channels_first = out.permute(0, 3, 1, 2)
    weight = masks[:, None].to(out.dtype)
    up = dict(size=(size, size), mode="bilinear", align_corners=False)
    weighted = F.interpolate(channels_first * weight, **up)
    total = F.interpolate(weight, **up)
    plain = F.interpolate(channels_first, **up)
    result = torch.where(total > 1e-3, weighted / total.clamp_min(1e-3), plain)
    return result.permute(0, 2, 3, 1)


def _rotate_quaternions(quats: Tensor, world_to_cam_rotation: Tensor) -> Tensor:
    """Camera-frame rotations [B, N, 4] (wxyz) → world frame, given R = world_to_cam [B, 3, 3]."""
    cam_to_world = matrix_to_quaternion(world_to_cam_rotation.transpose(-1, -2))  # [B, 4]
    return quaternion_multiply(cam_to_world[:, None].expand_as(quats), quats)


def prune_gaussians(
    gaussians: Gaussians,  # [N, ·] one image's Gaussians
    mask: Tensor,  # [N] 1 where the pixel is on the object
    min_opacity: float = 0.05,
    max_count: int | None = None,
) -> Gaussians:
    """Keep the Gaussians of object pixels whose opacity is at least ``min_opacity``, at most
    ``max_count`` of them (the most opaque). Raises ValueError when none is left."""
    keep = (mask.reshape(-1) > 0.5) & (gaussians.opacities >= min_opacity)
    index = keep.nonzero().squeeze(-1)
    if max_count is not None and index.numel() > max_count:
        order = torch.argsort(gaussians.opacities[index], descending=True)[:max_count]
        index = index[order.sort().values]
    if index.numel() == 0:
        raise ValueError("no Gaussian is left after pruning (empty mask or all transparent)")
    return gaussians.select(index)


def billboard_gaussians(
    image: Tensor,  # [R, R, 3] in [0, 1]
    mask: Tensor,  # [R, R]
    K: Tensor,  # [3, 3] at R
    world_to_cam: Tensor,  # [4, 4]
    depth: float = 2.0,  # metres along the camera z
) -> Gaussians:  # [M, ·], M = object pixels
    """The trivial geometry: a flat cut-out — one opaque, isotropic Gaussian (σ = 0.4 px) per object
    pixel, with the pixel's colour, on the plane ``z_cam = depth``."""
    rays = pixel_rays(K[None].to(image.dtype), image.shape[0])[0].reshape(-1, 3)
    keep = mask.reshape(-1) > 0.5
    points_cam = rays[keep] * depth
    rotation, translation = world_to_cam[:3, :3].to(image.dtype), world_to_cam[:3, 3]
    count = int(keep.sum())
    scale = 0.4 * depth / float(K[0, 0])  # 0.4 px: neighbours barely overlap, metres
    rgb = image.reshape(-1, 3)[keep]
    return Gaussians(
        means=(points_cam - translation.to(image.dtype)) @ rotation,
        quats=torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(count, 4).clone(),
        log_scales=torch.full((count, 3), math.log(scale)),
        opacity_logits=torch.full((count,), 4.0),
        sh0=(rgb - 0.5) / SH_C0,
    )
