"""Differentiable Gaussian renderer: Gaussians + cameras → colour, alpha and depth images.

Three interchangeable backends with the same semantics (gsplat's "classic" 3DGS rasterisation):
``"torch"`` (pure PyTorch, any device and dtype, the reference), ``"numba"`` (the same projection,
compiled CPU compositing with a hand-written backward) and ``"gsplat"`` (CUDA kernels).
The object is rendered on a black background (docs/design.md#conventions); ``rgb`` is the
premultiplied colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from reconphys._optional import gsplat_available, numba_available
from reconphys.assets.gaussians import Gaussians
from reconphys.names import RENDER_BACKENDS
from reconphys.render.cameras import Cameras, dataset_views, intrinsics_from_fov, look_at
from reconphys.render.gsplat_backend import rasterize_gsplat
from reconphys.render.numba_backend import rasterize_numba
from reconphys.render.torch_backend import rasterize_torch

__all__ = [
    "Cameras",
    "RenderOutput",
    "available_backends",
    "dataset_views",
    "intrinsics_from_fov",
    "look_at",
    "render",
]

RASTERIZERS = {"torch": rasterize_torch, "numba": rasterize_numba, "gsplat": rasterize_gsplat}


@dataclass
class RenderOutput:
    rgb: Tensor  # [..., C, H, W, 3] premultiplied colour in [0, 1] on black
    alpha: Tensor  # [..., C, H, W] accumulated opacity in [0, 1]
    depth: Tensor  # [..., C, H, W] expected camera-space z, metres (0 where alpha is 0)


def available_backends() -> list[str]:
    """Backends that can render on this machine: always "torch", "numba" with Numba, "gsplat"
    with gsplat + CUDA."""
    backends = ["torch"]
    if numba_available():
        backends.append("numba")
    if torch.cuda.is_available() and gsplat_available():
        backends.append("gsplat")
    return backends


def auto_backend(device: torch.device) -> str:
    """The backend ``render(..., backend="auto")`` picks for tensors on ``device``."""
    if device.type == "cuda" and gsplat_available():
        return "gsplat"
    if device.type == "cpu" and numba_available():
        return "numba"
    return "torch"


def render(
    gaussians: Gaussians,  # tensors [..., N, ·]
    cameras: Cameras,  # tensors [..., C, ·, ·] or [C, ·, ·] (shared by every batch element)
    backend: str = "auto",
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    antialiased: bool = False,
) -> RenderOutput:
    """Render a (batch of) Gaussian set(s) into C cameras.

    ``backend``: "torch", "numba", "gsplat", or "auto": gsplat when it is importable and the
    Gaussians are on a CUDA device, numba when Numba is installed and they are on the CPU, the torch
    renderer otherwise. Cameras without batch dims are shared by every
    element of a batch of Gaussians. ``near_plane`` is in metres, ``eps2d`` in pixels². gsplat
    computes in float32 whatever the input dtype; use backend="torch" for float64 (e.g. gradcheck).
    ``antialiased``: gsplat's antialiased mode (each opacity × √(det Σ₂ / det(Σ₂ + eps2d·I))), for
    images smaller than the ones the Gaussians were made for: a Gaussian below a pixel then adds
    its area's share of the pixel, as area-averaging the full-size image would, instead of a
    pixel-sized blob at full opacity (docs/rendering.md).
    """
    if backend not in RENDER_BACKENDS:
        raise ValueError(f"backend: expected one of {RENDER_BACKENDS}, got {backend!r}")
    batch_shape = gaussians.means.shape[:-2]
    if cameras.batch_shape != batch_shape:
        if len(cameras.batch_shape) > 0:
            raise ValueError(
                f"cameras: batch dims {list(cameras.batch_shape)} do not match the Gaussians' "
                f"{list(batch_shape)}"
            )
        cameras = cameras.expand(batch_shape)
    if backend == "auto":
        backend = auto_backend(gaussians.means.device)
    rgb, alpha, depth = RASTERIZERS[backend](
        gaussians.means,
        gaussians.quats,
        gaussians.scales,
        gaussians.opacities,
        gaussians.colors,
        cameras.world_to_cam.to(gaussians.means),
        cameras.K.to(gaussians.means),
        cameras.width,
        cameras.height,
        near_plane=near_plane,
        eps2d=eps2d,
        antialiased=antialiased,
    )
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth)
