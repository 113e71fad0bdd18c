"""A set of 3D Gaussians in the raw parameterisation of 3DGS (the PLY layout).

Parameters are stored raw (log-scales, opacity logits, SH DC coefficients) so that a PLY round trip
is bit-exact; the activated values used by the renderer are properties. Any number of leading batch
dimensions is allowed (``[..., N, 3]``), e.g. ``[B, N, 3]`` for a batch of scenes of equal size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from reconphys.errors import InputError

SH_C0 = 0.28209479177387814  # Y_0^0, maps the SH DC coefficient to an RGB offset around 0.5
MIN_GAUSSIANS = 16


@dataclass
class Gaussians:
    means: Tensor  # [..., N, 3] world-frame centres, metres
    quats: Tensor  # [..., N, 4] rotations as (w, x, y, z) quaternions, not necessarily unit
    log_scales: Tensor  # [..., N, 3] natural log of the standard deviations, log(metres)
    opacity_logits: Tensor  # [..., N] logit of the opacity
    sh0: Tensor  # [..., N, 3] SH degree-0 coefficients (PLY f_dc_0..2)
    sh_rest: Tensor | None = None  # [..., N, R, 3] higher SH coefficients (PLY f_rest_*), optional

    @property
    def num_gaussians(self) -> int:
        return self.means.shape[-2]

    @property
    def scales(self) -> Tensor:  # [..., N, 3] metres
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> Tensor:  # [..., N] in (0, 1)
        return torch.sigmoid(self.opacity_logits)

    @property
    def colors(self) -> Tensor:  # [..., N, 3] RGB from the DC term, clamped to [0, 1]
        return (0.5 + SH_C0 * self.sh0).clamp(0.0, 1.0)

    @staticmethod
    def from_activated(
        means: Tensor,  # [..., N, 3] metres
        scales: Tensor,  # [..., N, 3] standard deviations, metres (> 0)
        opacities: Tensor,  # [..., N] in (0, 1)
        colors: Tensor,  # [..., N, 3] RGB in [0, 1]
        quats: Tensor | None = None,  # [..., N, 4] wxyz; identity when None
    ) -> Gaussians:
        """Build from physical values; opacities are clamped into (1e-6, 1 - 1e-6)."""
        if quats is None:
            quats = torch.zeros(*means.shape[:-1], 4, dtype=means.dtype, device=means.device)
            quats[..., 0] = 1.0
        return Gaussians(
            means=means,
            quats=quats,
            log_scales=torch.log(scales),
            opacity_logits=torch.logit(opacities.clamp(1e-6, 1.0 - 1e-6)),
            sh0=(colors - 0.5) / SH_C0,
        )

    def map(self, fn) -> Gaussians:
        """Apply ``fn`` to every tensor field (e.g. ``lambda t: t.to(device)``)."""
        return replace(
            self,
            **{f.name: fn(v) for f in fields(self) if (v := getattr(self, f.name)) is not None},
        )

    def to(self, *args, **kwargs) -> Gaussians:
        return self.map(lambda t: t.to(*args, **kwargs))

    def with_means(self, means: Tensor) -> Gaussians:
        """Same Gaussians with new centres (e.g. deformed by the binding); shape ``[..., N, 3]``."""
        return replace(self, means=means)

    def select(self, index) -> Gaussians:
        """Select Gaussians along the N dimension (boolean mask, index tensor or slice)."""
        n_dim_from_end = {"opacity_logits": 1, "sh_rest": 3}

        def take(name: str, t: Tensor) -> Tensor:
            dim = t.dim() - n_dim_from_end.get(name, 2)
            return t[(slice(None),) * dim + (index,)]

        return replace(
            self,
            **{
                f.name: take(f.name, v)
                for f in fields(self)
                if (v := getattr(self, f.name)) is not None
            },
        )


def check_sampling_args(num_gaussians: int, size: float, interior_fraction: float) -> None:
    """The arguments shared by the samplers of a shape into Gaussians (procedural shapes, meshes):
    ``num_gaussians`` an integer ≥ ``MIN_GAUSSIANS``, ``size`` a positive number of metres,
    ``interior_fraction`` in [0, 1). Raises ``InputError`` naming the first bad one."""
    if int(num_gaussians) != num_gaussians or num_gaussians < MIN_GAUSSIANS:
        raise InputError(
            f"must be an integer ≥ {MIN_GAUSSIANS}, got {num_gaussians}", field="num_gaussians"
        )
    if not (math.isfinite(size) and size > 0):
        raise InputError(f"must be a positive number of metres, got {size}", field="size")
    if not 0.0 <= interior_fraction < 1.0:
        raise InputError(f"must be in [0, 1), got {interior_fraction}", field="interior_fraction")
