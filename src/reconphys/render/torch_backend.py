"""Pure-PyTorch 3D Gaussian splatting rasteriser: the reference twin of gsplat
(docs/design.md#compute).

It reproduces ``gsplat.rasterization(..., packed=False, rasterize_mode="classic", sh_degree=None,
render_mode="RGB+ED")`` of gsplat 1.5.3 on any device and dtype, with autograd for the backward:

- projection: camera-space covariance ``R Σ Rᵀ`` pushed to pixels with the EWA Jacobian of the
  pinhole model (the Jacobian's x/y is clamped to 1.3× the half field of view, as in gsplat, which
  only matters for Gaussians centred off-screen); ``eps2d`` is added to the 2D covariance diagonal;
- ``antialiased=True`` reproduces ``rasterize_mode="antialiased"`` instead (Mip-Splatting's 2D
  filter): each opacity is also multiplied by ``√(det Σ₂ / det(Σ₂ + eps2d·I))``, so a Gaussian much
  smaller than a pixel keeps its integrated coverage instead of being dilated to a pixel's blob at
  full opacity — what an image rendered at a lower resolution than its Gaussians were made for
  needs to look like the full-size image area-averaged down;
- culling: camera depth ``z < near_plane`` or ``z > 1e10``, opacity ``< 1/255``, or a screen box
  (``ceil(min(3.33, √(2 ln(255·opacity))) · σ_x|y)`` pixels) that misses the image;
- per pixel (centre at ``(x + 0.5, y + 0.5)``), front to back by camera depth:
  ``alpha = min(0.999, opacity · exp(−½ dᵀ Σ₂⁻¹ d))``; a Gaussian with ``alpha < 1/255``
  contributes nothing; compositing stops before the Gaussian that would bring the transmittance to
  ``≤ 1e-4``; colours are accumulated premultiplied on a black background;
- depth: the expected camera z, ``Σ wᵢ zᵢ / max(Σ wᵢ, 1e-10)`` (0 where nothing was hit).

The screen box bounds every pixel with ``alpha ≥ 1/255`` (outside it the Mahalanobis distance along
x or y alone exceeds the box's extent), so culling Gaussians per pixel tile by their box is exact.

Memory: pixels are processed in tiles of about ``chunk_pixels`` and each tile's depth-sorted
Gaussians in blocks of ``chunk_gaussians``, so the dense per-(pixel, Gaussian) tensors never exceed
``chunk_pixels × chunk_gaussians`` elements. With autograd on, each block is checkpointed (its
intermediates are recomputed in the backward pass), so a backward pass holds only per-Gaussian and
per-pixel tensors, not the per-pair ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from ..geometry import quaternion_to_matrix

ALPHA_THRESHOLD = 1.0 / 255.0  # a Gaussian whose alpha at a pixel is below this is skipped there
MAX_ALPHA = 0.999  # gsplat 1.5.3 clamps the per-Gaussian alpha to this
MIN_TRANSMITTANCE = 1e-4  # compositing stops before the transmittance would drop to this
FAR_PLANE = 1e10  # metres, gsplat's default far plane
MAX_BOX_SIGMAS = 3.33  # half-size of the screen box in standard deviations, at most
JACOBIAN_FOV_MARGIN = 0.3  # the EWA Jacobian is evaluated within 1.3× the half field of view
# Floors for exponents, one unit below what can still contribute (see _composite_block).
LOG_ALPHA_FLOOR = math.log(ALPHA_THRESHOLD) - 1.0
LOG_TRANSMITTANCE_FLOOR = math.log(MIN_TRANSMITTANCE) - 1.0
DEFAULT_CHUNK_PIXELS_CPU = 256  # pixels per tile: small tiles cull more Gaussians per tile
DEFAULT_CHUNK_PIXELS_GPU = 4096  # large tiles launch fewer kernels


@dataclass
class ProjectedGaussians:
    """Gaussians projected into C cameras (output of :func:`project_gaussians`)."""

    means2d: Tensor  # [..., C, N, 2] centres, pixels
    conics: Tensor  # [..., C, N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]], 1/px²
    depths: Tensor  # [..., C, N] camera-space z, metres
    opacities: Tensor  # [..., C, N] opacity per camera (× the antialiasing compensation if any)
    radii: Tensor  # [..., C, N, 2] half-sizes of the screen bounding box, pixels (0 = culled)


def project_gaussians(
    means: Tensor,  # [..., N, 3] world frame, metres
    quats: Tensor,  # [..., N, 4] wxyz, normalised here
    scales: Tensor,  # [..., N, 3] standard deviations along the local axes, metres
    opacities: Tensor,  # [..., N] in [0, 1]
    world_to_cam: Tensor,  # [..., C, 4, 4]
    K: Tensor,  # [..., C, 3, 3] pixels
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    antialiased: bool = False,
) -> ProjectedGaussians:
    """EWA projection of 3D Gaussians to 2D image-plane Gaussians, with gsplat's culling
    (``antialiased``: opacities × the 2D filter's compensation, as gsplat's antialiased mode)."""
    rotation = world_to_cam[..., :3, :3].unsqueeze(-3)  # [..., C, 1, 3, 3]
    translation = world_to_cam[..., :3, 3].unsqueeze(-2)  # [..., C, 1, 3]
    means_cam = (rotation @ means.unsqueeze(-1).unsqueeze(-4)).squeeze(-1) + translation
    x, y, z = means_cam.unbind(-1)  # [..., C, N]

    # Substitute a harmless depth where the Gaussian is culled anyway, so that no inf/NaN enters
    # the graph (a zero gradient times an infinite partial derivative would be NaN).
    in_front = (z >= near_plane) & (z > 0) & (z <= FAR_PLANE)
    z_safe = torch.where(in_front, z, torch.ones_like(z))

    fx, fy = K[..., 0, 0, None], K[..., 1, 1, None]  # [..., C, 1]
    cx, cy = K[..., 0, 2, None], K[..., 1, 2, None]
    lim_x_neg = cx / fx + JACOBIAN_FOV_MARGIN * 0.5 * width / fx
    lim_x_pos = (width - cx) / fx + JACOBIAN_FOV_MARGIN * 0.5 * width / fx
    lim_y_neg = cy / fy + JACOBIAN_FOV_MARGIN * 0.5 * height / fy
    lim_y_pos = (height - cy) / fy + JACOBIAN_FOV_MARGIN * 0.5 * height / fy
    x_clamped = torch.minimum(torch.maximum(x / z_safe, -lim_x_neg), lim_x_pos)
    y_clamped = torch.minimum(torch.maximum(y / z_safe, -lim_y_neg), lim_y_pos)

    zero = torch.zeros_like(z)
    jacobian = torch.stack(
        [fx / z_safe, zero, -fx * x_clamped / z_safe, zero, fy / z_safe, -fy * y_clamped / z_safe],
        dim=-1,
    ).reshape(*z.shape, 2, 3)  # [..., C, N, 2, 3]

    # Σ₂ = (J R_cam) (R_q S)(R_q S)ᵀ (J R_cam)ᵀ
    local_to_world = quaternion_to_matrix(quats) * scales.unsqueeze(-2)  # [..., N, 3, 3]
    factor = jacobian @ rotation @ local_to_world.unsqueeze(-4)  # [..., C, N, 2, 3]
    cov2d = factor @ factor.transpose(-1, -2)  # [..., C, N, 2, 2]
    c00 = cov2d[..., 0, 0] + eps2d
    c11 = cov2d[..., 1, 1] + eps2d
    c01 = 0.5 * (cov2d[..., 0, 1] + cov2d[..., 1, 0])
    det = c00 * c11 - c01 * c01
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    conics = torch.stack([c11 / det_safe, -c01 / det_safe, c00 / det_safe], dim=-1)
    opacity = opacities.unsqueeze(-2).expand_as(z)  # [..., C, N]
    if antialiased:  # the filter's area ratio: √(det Σ₂ / det(Σ₂ + eps2d·I)), 0 if degenerate
        ratio = (cov2d[..., 0, 0] * cov2d[..., 1, 1] - c01 * c01) / det_safe
        inside = ratio > 0  # (the sqrt's gradient is kept finite where it is 0)
        opacity = opacity * torch.sqrt(torch.where(inside, ratio, torch.ones_like(ratio))) * inside

    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)

    with torch.no_grad():
        # Largest Mahalanobis radius at which alpha can still reach 1/255 (capped like gsplat).
        extent = torch.sqrt(2.0 * torch.log(opacity.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD))
        extent = extent.clamp_max(MAX_BOX_SIGMAS)
        radius_x = torch.ceil(extent * torch.sqrt(c00.clamp_min(0)))
        radius_y = torch.ceil(extent * torch.sqrt(c11.clamp_min(0)))
        u, v = means2d.unbind(-1)
        on_screen = (
            (u + radius_x > 0)
            & (u - radius_x < width)
            & (v + radius_y > 0)
            & (v - radius_y < height)
        )
        visible = in_front & (det > 0) & (opacity >= ALPHA_THRESHOLD) & on_screen
        radii = torch.stack([radius_x, radius_y], dim=-1) * visible.unsqueeze(-1)

    return ProjectedGaussians(
        means2d=means2d, conics=conics, depths=z, opacities=opacity, radii=radii
    )


def _composite_block(
    pixels: Tensor,  # [P, 2] pixel centres, pixels
    means2d: Tensor,  # [M, 2] depth-sorted, front first
    conics: Tensor,  # [M, 3]
    opacities: Tensor,  # [M]
    features: Tensor,  # [M, F] what to accumulate (colours, depth, 1 for alpha)
    log_transmittance: Tensor,  # [P] before this block, counting every Gaussian in front of it
) -> tuple[Tensor, Tensor]:  # [P, F] accumulated Σ wᵢ fᵢ, [P] log-transmittance after the block
    """Front-to-back alpha compositing of one block of Gaussians over a set of pixels.

    The transmittance multiplies ``1 − alpha`` of every Gaussian, including those past the
    stopping point: it is monotone, so "transmittance after Gaussian i > 1e-4" selects exactly the
    Gaussians that gsplat composites before it stops, also across blocks. It is kept as a logarithm
    and every exponent is floored just below what can still contribute, so that no float ever
    becomes subnormal (deep opaque stacks and far tails otherwise slow CPUs down ~20×); the floors
    only touch values that the 1/255 and 1e-4 rules discard anyway.
    """
    dx = pixels[:, 0:1] - means2d[:, 0]  # [P, M]
    dy = pixels[:, 1:2] - means2d[:, 1]
    a, b, c = conics.unbind(-1)
    # ½ dᵀ Σ₂⁻¹ d = dx (½a dx + b dy) + ½c dy², in few passes over the [P, M] tensors (the cost).
    power = dx * torch.addcmul(b * dy, 0.5 * a, dx)
    power = torch.addcmul(power, 0.5 * c * dy, dy)
    # Σ₂⁻¹ is positive definite (det > 0 was checked), so power ≥ 0 up to rounding; gsplat's
    # extra "power < 0" skip only matters at rounding level and is left out.
    log_alpha = (torch.log(opacities) - power).clamp_min(LOG_ALPHA_FLOOR)
    alpha = torch.exp(log_alpha).clamp_max(MAX_ALPHA)
    alpha = alpha * (alpha >= ALPHA_THRESHOLD)  # (a product with the mask beats torch.where)

    log_after = log_transmittance.unsqueeze(-1) + torch.cumsum(torch.log1p(-alpha), dim=-1)
    log_before = torch.cat([log_transmittance.unsqueeze(-1), log_after[:, :-1]], dim=-1)
    before = torch.exp(log_before.clamp_min(LOG_TRANSMITTANCE_FLOOR))
    weights = alpha * before * (log_after > math.log(MIN_TRANSMITTANCE))
    # clone: a view would keep the whole [P, M] tensor alive as the next block's input
    return weights @ features, log_after[:, -1].clone()


def _composite_tile(
    pixels: Tensor,  # [P, 2] pixel centres, pixels
    ids: Tensor,  # [M] indices of the Gaussians that may touch the tile, front to back
    sorted_gaussians: tuple[Tensor, Tensor, Tensor, Tensor],  # means2d, conics, opacities, features
    chunk_gaussians: int,
    use_checkpoint: bool,
) -> Tensor:  # [P, F]
    """Accumulate features over one tile, ``chunk_gaussians`` Gaussians at a time."""
    means2d, conics, opacities, features = sorted_gaussians
    num_pixels = pixels.shape[0]
    accumulated = pixels.new_zeros(num_pixels, features.shape[-1])
    log_transmittance = pixels.new_zeros(num_pixels)
    for block in ids.split(chunk_gaussians) if ids.numel() > 0 else ():
        args = (pixels, means2d[block], conics[block], opacities[block], features[block])
        if use_checkpoint:  # recompute the [P, M] intermediates in backward instead of storing them
            block_sum, log_transmittance = checkpoint(
                _composite_block,
                *args,
                log_transmittance,
                use_reentrant=False,
                preserve_rng_state=False,  # nothing random inside
            )
        else:
            block_sum, log_transmittance = _composite_block(*args, log_transmittance)
        accumulated = accumulated + block_sum
    return accumulated


def _rasterize_image(
    means2d: Tensor,  # [N, 2] pixels
    conics: Tensor,  # [N, 3] 1/px²
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, F]
    depths: Tensor,  # [N] metres, the sort key
    radii: Tensor,  # [N, 2] pixels, 0 = culled
    width: int,
    height: int,
    chunk_pixels: int,
    chunk_gaussians: int,
) -> Tensor:  # [H, W, F]
    """Composite the visible Gaussians of one image, tile by tile."""
    visible = (radii > 0).all(dim=-1).nonzero().squeeze(-1)
    visible = visible[torch.sort(depths[visible].detach(), stable=True).indices]  # front first
    sorted_gaussians = (means2d[visible], conics[visible], opacities[visible], features[visible])
    box_min = means2d[visible].detach() - radii[visible]
    box_max = means2d[visible].detach() + radii[visible]
    use_checkpoint = torch.is_grad_enabled() and any(t.requires_grad for t in sorted_gaussians)

    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=means2d.dtype, device=means2d.device) + 0.5,
        torch.arange(width, dtype=means2d.dtype, device=means2d.device) + 0.5,
        indexing="ij",
    )
    pixel_centres = torch.stack([xs, ys], dim=-1)  # [H, W, 2]
    tile_width = min(width, max(1, math.isqrt(chunk_pixels)))
    tile_height = min(height, max(1, chunk_pixels // tile_width))

    rows = []
    for y0 in range(0, height, tile_height):
        y1 = min(y0 + tile_height, height)
        row = []
        for x0 in range(0, width, tile_width):
            x1 = min(x0 + tile_width, width)
            # Keep a Gaussian if its box contains the centre of any pixel of the tile.
            hit = (
                (box_max[:, 0] >= x0 + 0.5)
                & (box_min[:, 0] <= x1 - 0.5)
                & (box_max[:, 1] >= y0 + 0.5)
                & (box_min[:, 1] <= y1 - 0.5)
            )
            tile = _composite_tile(
                pixel_centres[y0:y1, x0:x1].reshape(-1, 2),
                hit.nonzero().squeeze(-1),
                sorted_gaussians,
                chunk_gaussians,
                use_checkpoint,
            )
            row.append(tile.reshape(y1 - y0, x1 - x0, -1))
        rows.append(torch.cat(row, dim=1))
    return torch.cat(rows, dim=0)


def _check_shapes(means, quats, scales, opacities, colors, world_to_cam, K) -> None:
    batch = tuple(means.shape[:-2])
    n = means.shape[-2] if means.dim() >= 2 else -1
    expected = {
        "means": (means, (*batch, n, 3)),
        "quats": (quats, (*batch, n, 4)),
        "scales": (scales, (*batch, n, 3)),
        "opacities": (opacities, (*batch, n)),
    }
    for name, (tensor, shape) in expected.items():
        if tuple(tensor.shape) != shape:
            raise ValueError(f"{name}: expected shape {list(shape)}, got {list(tensor.shape)}")
    if colors.dim() != means.dim() or tuple(colors.shape[:-1]) != (*batch, n):
        raise ValueError(f"colors: expected shape {[*batch, n, 'D']}, got {list(colors.shape)}")
    c = world_to_cam.shape[-3] if world_to_cam.dim() >= 3 else -1
    if tuple(world_to_cam.shape) != (*batch, c, 4, 4):
        raise ValueError(
            f"world_to_cam: expected shape {[*batch, 'C', 4, 4]} (batch dims of the Gaussians), "
            f"got {list(world_to_cam.shape)}"
        )
    if tuple(K.shape) != (*batch, c, 3, 3):
        raise ValueError(f"K: expected shape {[*batch, c, 3, 3]}, got {list(K.shape)}")


def rasterize_torch(
    means: Tensor,  # [..., N, 3] world frame, metres
    quats: Tensor,  # [..., N, 4] wxyz rotations, normalised here
    scales: Tensor,  # [..., N, 3] standard deviations, metres
    opacities: Tensor,  # [..., N] in [0, 1]
    colors: Tensor,  # [..., N, D] e.g. RGB in [0, 1]
    world_to_cam: Tensor,  # [..., C, 4, 4] OpenCV convention
    K: Tensor,  # [..., C, 3, 3] pixels
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    chunk_pixels: int | None = None,
    chunk_gaussians: int = 4096,
    antialiased: bool = False,
) -> tuple[Tensor, Tensor, Tensor]:
    """Render Gaussians into C cameras: premultiplied colour, alpha and expected depth.

    Matches ``gsplat.rasterization`` (see the module docstring for the exact rules) and is
    differentiable w.r.t. means, quats, scales, opacities and colors (not w.r.t. the cameras'
    culling decisions, which are piecewise constant). The leading dims ``...`` of the Gaussians and
    of the cameras must be equal. ``near_plane`` is in metres, ``eps2d`` in pixels² (added to the
    projected covariance diagonal; ``antialiased``: gsplat's antialiased mode, module docstring).
    Pixels are processed in square tiles of about
    ``chunk_pixels`` pixels (default: 256 on CPU, where finer culling pays, and 4096 on GPUs, where
    fewer kernel launches pay) and each tile's Gaussians in blocks of ``chunk_gaussians``; their
    product bounds the size of the dense per-(pixel, Gaussian) tensors.

    Returns:
        rgb ``[..., C, H, W, D]`` (black background), alpha ``[..., C, H, W]`` and depth
        ``[..., C, H, W]`` (expected camera z in metres, 0 where alpha is 0).
    """
    _check_shapes(means, quats, scales, opacities, colors, world_to_cam, K)
    if chunk_pixels is None:
        chunk_pixels = DEFAULT_CHUNK_PIXELS_GPU if means.is_cuda else DEFAULT_CHUNK_PIXELS_CPU
    images = project_images(
        means, quats, scales, opacities, colors, world_to_cam, K, width, height, near_plane, eps2d,
        antialiased,
    )  # fmt: skip
    composited = [
        _rasterize_image(
            images.means2d[i],
            images.conics[i],
            images.opacities[i],
            images.features[i],
            images.depths[i],
            images.radii[i],
            width=width,
            height=height,
            chunk_pixels=chunk_pixels,
            chunk_gaussians=chunk_gaussians,
        )
        for i in range(images.num_images)
    ]
    return images.split_outputs(torch.stack(composited))


@dataclass
class ImageInputs:
    """Per-image inputs of the compositing stage, every image of the batch flattened into I.

    What each image accumulates per pixel is ``features = (colour, camera z, 1)``: the weighted
    sums give the premultiplied colour, the depth numerator and alpha.
    """

    means2d: Tensor  # [I, N, 2] pixels
    conics: Tensor  # [I, N, 3] 1/px²
    opacities: Tensor  # [I, N] in [0, 1]
    features: Tensor  # [I, N, D + 2]
    depths: Tensor  # [I, N] camera z, metres (the front-to-back sort key)
    radii: Tensor  # [I, N, 2] screen-box half-sizes, pixels (0 = culled)
    image_shape: tuple[int, ...]  # (..., C): I = their product
    num_channels: int  # D

    @property
    def num_images(self) -> int:
        return self.means2d.shape[0]

    def split_outputs(
        self,
        composited: Tensor,  # [I, H, W, D + 2] accumulated features
    ) -> tuple[Tensor, Tensor, Tensor]:  # rgb [..., C, H, W, D], alpha, depth [..., C, H, W]
        stacked = composited.reshape(*self.image_shape, *composited.shape[1:])
        rgb = stacked[..., : self.num_channels]
        alpha = stacked[..., -1]
        depth = stacked[..., -2] / alpha.clamp_min(1e-10)
        return rgb, alpha, depth


def project_images(
    means: Tensor,  # [..., N, 3] world frame, metres
    quats: Tensor,  # [..., N, 4] wxyz
    scales: Tensor,  # [..., N, 3] metres
    opacities: Tensor,  # [..., N]
    colors: Tensor,  # [..., N, D]
    world_to_cam: Tensor,  # [..., C, 4, 4]
    K: Tensor,  # [..., C, 3, 3]
    width: int,
    height: int,
    near_plane: float,
    eps2d: float,
    antialiased: bool = False,
) -> ImageInputs:
    """Project every Gaussian into every camera and gather what each image composites."""
    projected = project_gaussians(
        means, quats, scales, opacities, world_to_cam, K, width, height, near_plane, eps2d,
        antialiased,
    )  # fmt: skip
    image_shape = (*means.shape[:-2], world_to_cam.shape[-3])
    features = torch.cat(
        [
            colors.unsqueeze(-3).expand(*image_shape, *colors.shape[-2:]),
            projected.depths.unsqueeze(-1),
            torch.ones_like(projected.depths).unsqueeze(-1),
        ],
        dim=-1,
    )  # [..., C, N, D + 2]
    per_image = {
        "means2d": projected.means2d,
        "conics": projected.conics,
        "opacities": projected.opacities,
        "features": features,
        "depths": projected.depths,
        "radii": projected.radii,
    }
    flat = {name: t.reshape(-1, *t.shape[len(image_shape) :]) for name, t in per_image.items()}
    return ImageInputs(**flat, image_shape=image_shape, num_channels=colors.shape[-1])
