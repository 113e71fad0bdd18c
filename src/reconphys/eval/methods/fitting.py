"""Per-scene fitting of Gaussians to the 4 views, shared by ``springgaus`` and ``appearance``.

The static stage reconstructs the object at one frame from its V calibrated views, as a 3DGS
optimisation would: a visual hull gives the starting points (the foreground of every view, cut out
of a voxel grid around the point the cameras look at), Gaussians are placed in it with the colour
seen at their projection, and Adam fits centres, scales, rotations, opacities and colours to the
images with the 3DGS loss ``L1 + 0.2 (1 − SSIM)``. Gaussians that end almost transparent are
dropped, so that anchors and point metrics see only the object.

Everything here reads only frames and cameras — never the ground truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch import Tensor

from ...assets.gaussians import Gaussians
from ...errors import InputError
from ...render import Cameras, render
from ..metrics import foreground_mask, ssim_map

HULL_RESOLUTION = 64  # voxels per side of the grid carved by the views
SSIM_WEIGHT = 0.2  # 3DGS loss: (1 − w) L1 + w (1 − SSIM)... with w as in Spring-Gaus' static stage
MIN_OPACITY = 0.05  # Gaussians fainter than this after the fit are dropped


@dataclass(frozen=True)
class StaticFitSettings:
    num_gaussians: int = 500
    max_iterations: int = 300
    lr_means: float = 0.004  # metres per step (Adam's step size)
    lr_log_scales: float = 0.02
    lr_quats: float = 0.01
    lr_opacity: float = 0.05
    lr_sh0: float = 0.1


def photometric_loss(
    rendered: Tensor,  # [..., H, W, 3]
    target: Tensor,  # [..., H, W, 3]
) -> Tensor:  # scalar
    """The 3DGS image loss over whole images: (1 − w)·L1 + w·(1 − SSIM), w = SSIM_WEIGHT."""
    l1 = (rendered - target).abs().mean()
    structural = 1.0 - ssim_map(rendered, target).mean()
    return (1.0 - SSIM_WEIGHT) * l1 + SSIM_WEIGHT * structural


def look_at_point(cameras: Cameras) -> Tensor:  # [3] metres
    """The point closest (least squares) to every camera's optical axis."""
    rotation = cameras.world_to_cam[..., :3, :3].double()
    centres = cameras.centers.double()  # [V, 3]
    forward = rotation[:, 2, :]  # camera z axis in world coordinates, [V, 3]
    projector = torch.eye(3, dtype=torch.float64) - forward[:, :, None] * forward[:, None, :]
    lhs = projector.sum(0)
    rhs = (projector @ centres[:, :, None]).sum(0)[:, 0]
    return torch.linalg.solve(lhs, rhs).float()


def triangulate(
    pixels: Tensor,  # [V, 2] one pixel position per view (x right, y down), pixels
    cameras: Cameras,  # V cameras
) -> Tensor:  # [3] metres
    """The point closest (least squares) to the V viewing rays through ``pixels``."""
    rotation = cameras.world_to_cam[:, :3, :3].double()
    homogeneous = torch.cat([pixels.double(), torch.ones_like(pixels[:, :1]).double()], -1)
    rays = torch.linalg.solve(cameras.K.double(), homogeneous[..., None])[..., 0]  # camera frame
    direction = (rotation.transpose(-1, -2) @ rays[..., None])[..., 0]
    direction = direction / direction.norm(dim=-1, keepdim=True)
    projector = torch.eye(3, dtype=torch.float64) - direction[:, :, None] * direction[:, None, :]
    centres = cameras.centers.double()
    lhs = projector.sum(0)
    rhs = (projector @ centres[:, :, None]).sum(0)[:, 0]
    return torch.linalg.solve(lhs, rhs).float()


def silhouette_centre(
    images: Tensor,  # [V, H, W, 3] one frame of every view
    cameras: Cameras,
) -> Tensor:  # [3] metres
    """The point triangulated from the centroids of the V foreground masks (≈ object centre)."""
    masks = foreground_mask(images.float().cpu()).double()  # [V, H, W]
    height, width = masks.shape[1:]
    rows = torch.arange(height, dtype=torch.float64)[:, None] + 0.5
    columns = torch.arange(width, dtype=torch.float64)[None, :] + 0.5
    area = masks.sum((1, 2)).clamp(min=1.0)
    u = (masks * columns).sum((1, 2)) / area
    v = (masks * rows).sum((1, 2)) / area
    return triangulate(torch.stack([u, v], -1), cameras.to("cpu"))


def project(points: Tensor, cameras: Cameras) -> tuple[Tensor, Tensor]:
    """points [M, 3] → pixel coordinates [V, M, 2] and camera depth [V, M]."""
    rotation = cameras.world_to_cam[:, :3, :3]
    translation = cameras.world_to_cam[:, :3, 3]
    camera_points = torch.einsum("vij,mj->vmi", rotation, points) + translation[:, None]
    depth = camera_points[..., 2]
    z = depth.clamp(min=1e-6)
    u = cameras.K[:, None, 0, 0] * camera_points[..., 0] / z + cameras.K[:, None, 0, 2]
    v = cameras.K[:, None, 1, 1] * camera_points[..., 1] / z + cameras.K[:, None, 1, 2]
    return torch.stack([u, v], -1), depth


def _lookup(images: Tensor, pixels: Tensor) -> tuple[Tensor, Tensor]:
    """images [V, H, W, C] at pixels [V, M, 2] → values [V, M, C], inside-image flag [V, M]."""
    height, width = images.shape[1:3]
    column = pixels[..., 0].floor().long()
    row = pixels[..., 1].floor().long()
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    column, row = column.clamp(0, width - 1), row.clamp(0, height - 1)
    view = torch.arange(images.shape[0], device=images.device)[:, None].expand_as(row)
    return images[view, row, column], inside


def visual_hull(
    images: Tensor,  # [V, H, W, 3] one frame of every view, black background
    cameras: Cameras,  # V cameras
    resolution: int = HULL_RESOLUTION,
    ground_height: float | None = 0.0,  # metres; points below it are dropped (None: keep)
) -> tuple[Tensor, float]:  # points [M, 3] metres, voxel size metres
    """Centres of the voxels whose centre projects into a foreground pixel of every view.

    Foreground is the metrics' mask (any channel ≥ 10/255); dilating it by a pixel, or taking
    fainter pixels, makes a looser hull (measured: Chamfer to the truth about doubles at 32 px).
    """
    images, cameras = images.float().cpu(), cameras.to("cpu", torch.float32)
    masks = foreground_mask(images)[..., None]  # [V, H, W, 1]
    centre = look_at_point(cameras)
    distance = (cameras.centers - centre).norm(dim=-1)  # [V]
    half_view = torch.maximum(
        cameras.K[:, 0, 2] / cameras.K[:, 0, 0], cameras.K[:, 1, 2] / cameras.K[:, 1, 1]
    )
    half = float((distance * half_view).max())
    axis = torch.linspace(-half, half, resolution)
    grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3) + centre
    pixels, depth = project(grid, cameras)
    inside_mask, inside_image = _lookup(masks, pixels)
    keep = (inside_mask[..., 0] & inside_image & (depth > 0)).all(0)
    if ground_height is not None:
        keep &= grid[:, 2] >= ground_height
    if not keep.any():
        raise InputError("the object is not visible in every view of the first frame")
    return grid[keep], 2 * half / (resolution - 1)


def initial_gaussians(
    images: Tensor,  # [V, H, W, 3]
    cameras: Cameras,
    count: int,
    generator: torch.Generator,
) -> Gaussians:
    """``count`` Gaussians spread through the visual hull, coloured by what the views see there."""
    hull, voxel = visual_hull(images, cameras)
    pick = torch.randint(0, hull.shape[0], (count,), generator=generator)
    jitter = (torch.rand(count, 3, generator=generator) - 0.5) * voxel
    means = hull[pick] + jitter
    pixels, _ = project(means, cameras.to("cpu", torch.float32))
    colours, _ = _lookup(images.float().cpu(), pixels)
    return Gaussians.from_activated(
        means=means,
        scales=torch.full((count, 3), 0.6 * voxel),
        opacities=torch.full((count,), 0.5),
        colors=colours.mean(0).clamp(0.02, 0.98),
    )


def fit_static(
    images: Tensor,  # [V, H, W, 3] one frame of every view
    cameras: Cameras,
    settings: StaticFitSettings,
    deadline: float,  # time.perf_counter() value at which to stop
    seed: int = 0,
    device: torch.device | str = "cpu",
) -> tuple[Gaussians, dict]:
    """Gaussians reproducing the V images (see the module docstring); returns them and
    diagnostics (iterations run, first and last loss, Gaussians kept)."""
    generator = torch.Generator().manual_seed(seed)
    start = initial_gaussians(images, cameras, settings.num_gaussians, generator).to(device)
    images, cameras = images.to(device), cameras.to(device)
    parameters = {
        "means": start.means.clone().requires_grad_(True),
        "log_scales": start.log_scales.clone().requires_grad_(True),
        "quats": start.quats.clone().requires_grad_(True),
        "opacity_logits": start.opacity_logits.clone().requires_grad_(True),
        "sh0": start.sh0.clone().requires_grad_(True),
    }
    rates = {
        "means": settings.lr_means,
        "log_scales": settings.lr_log_scales,
        "quats": settings.lr_quats,
        "opacity_logits": settings.lr_opacity,
        "sh0": settings.lr_sh0,
    }
    optimizer = torch.optim.Adam([{"params": [parameters[k]], "lr": rates[k]} for k in parameters])
    losses = []
    iteration = 0
    while iteration < settings.max_iterations and (
        iteration == 0 or time.perf_counter() < deadline
    ):
        optimizer.zero_grad(set_to_none=True)
        loss = photometric_loss(render(Gaussians(**parameters), cameras).rgb, images)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        iteration += 1
    with torch.no_grad():
        fitted = Gaussians(**{k: v.detach() for k, v in parameters.items()})
        keep = fitted.opacities >= MIN_OPACITY
        if int(keep.sum()) < 8:  # keep the most opaque few rather than nothing
            keep = fitted.opacities >= fitted.opacities.topk(8).values[-1]
        fitted = fitted.select(keep)
    info = {
        "static_iterations": iteration,
        "static_loss_first": losses[0],
        "static_loss_last": losses[-1],
        "gaussians": int(fitted.num_gaussians),
    }
    return fitted.to("cpu"), info


def cached_static_fit(
    cache: dict,
    sample_id: str,
    images: Tensor,  # [V, H, W, 3] frame 0
    cameras: Cameras,
    settings: StaticFitSettings,
    budget_seconds: float,
    seed: int,
    device: torch.device | str,
) -> tuple[Gaussians, dict, float, bool]:
    """:func:`fit_static` of frame 0, computed once per sample and settings for all methods.

    Returns the Gaussians, diagnostics, the seconds the fit took when it was computed, and
    whether it was reused from ``cache``: a method reusing the fit counts those seconds in its
    own time (:attr:`Prediction.reused_seconds`).
    """
    key = ("static-fit", sample_id, settings, round(budget_seconds, 6), seed, str(device))
    reused = key in cache
    if not reused:
        cache.clear()  # one sample at a time: drop the previous sample's fit
        started = time.perf_counter()
        gaussians, info = fit_static(
            images, cameras, settings, started + budget_seconds, seed, device
        )
        cache[key] = (gaussians, info, time.perf_counter() - started)
    return (*cache[key], reused)
