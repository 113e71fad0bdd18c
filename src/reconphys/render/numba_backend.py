"""Compiled CPU compositing (Numba): the fast twin of the torch renderer on CPU.

Projection stays in PyTorch (:func:`torch_backend.project_images`, autograd for its backward);
the per-pixel front-to-back compositing, which costs almost all of the torch renderer's time on a
CPU (dense [pixels × Gaussians] tensors, a cumulative sum and their autograd), runs here as
compiled loops with a hand-written backward, the way gsplat's CUDA kernels do it:

- binning: the image is cut into 8 × 8 tiles; each tile lists the depth-sorted Gaussians whose
  screen box holds one of its pixel centres (counted, prefix-summed and filled per image: CSR
  lists in depth order, the same culling as the reference's tiles);
- forward: each pixel walks its tile's list front to back with the rules of the torch reference
  (``alpha = min(0.999, o · exp(−power))``, skip ``alpha < 1/255``, stop before the
  transmittance would reach ``≤ 1e-4``), skipping without an ``exp`` the Gaussians whose screen
  box misses the pixel (their alpha is below 1/255 there by the box's construction), and keeps
  its final transmittance and how far along the list it got;
- backward: each pixel walks the same list back to front from where it stopped, recovering the
  transmittance before each Gaussian by division by ``1 − alpha`` (``alpha ≤ 0.999``) and the sum
  of what lies behind it, which gives ∂/∂alpha and from it the gradients of the 2D means, conics,
  opacities and features. Work is split into one interleaved share of (image, tile) tasks per
  thread, each accumulating into its own gradient buffer (no atomics), summed at the end.

Same semantics as the torch reference; results differ from it by float round-off (the reference
keeps the transmittance as a logarithm). Scalars are computed in float64 whatever the input
dtype. ``tests/test_render_numba.py`` compares values and gradients with the reference and runs
gradcheck; ``benchmarks/bench_renderer.py`` times both in one run.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .._optional import numba_available
from .torch_backend import (
    ALPHA_THRESHOLD,
    MAX_ALPHA,
    MIN_TRANSMITTANCE,
    _check_shapes,
    project_images,
)

if numba_available():  # Numba is optional: the torch renderer is used wherever it is missing.
    import numba

TILE = 8  # pixels per tile side: small tiles keep the per-pixel lists short


def _tile_range_py(centre, radius, size):
    """First and last tile (inclusive) along one axis whose pixel centres the box [centre ±
    radius] holds (last < first: none)."""
    first = max(0, int(np.ceil(centre - radius - 0.5)))
    last = min(size - 1, int(np.floor(centre + radius - 0.5)))
    if last < first:
        return 0, -1
    return first // TILE, last // TILE


def _count_py(means2d, radii, order, counts, width, height, per_tile):
    """per_tile [I, tiles]: how many Gaussians each tile lists."""
    tiles_x = (width + TILE - 1) // TILE
    for image in numba.prange(means2d.shape[0]):
        for r in range(counts[image]):
            g = order[image, r]
            tx0, tx1 = _tile_range(means2d[image, g, 0], radii[image, g, 0], width)
            ty0, ty1 = _tile_range(means2d[image, g, 1], radii[image, g, 1], height)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    per_tile[image, ty * tiles_x + tx] += 1


def _fill_py(means2d, radii, order, counts, width, height, offsets, ids):
    """ids[offsets[i, t] : offsets[i, t + 1]] = the depth-sorted Gaussians of tile t of image i
    (those whose screen box holds one of its pixel centres)."""
    tiles_x = (width + TILE - 1) // TILE
    for image in numba.prange(means2d.shape[0]):
        cursor = offsets[image, :-1].copy()
        for r in range(counts[image]):
            g = order[image, r]
            tx0, tx1 = _tile_range(means2d[image, g, 0], radii[image, g, 0], width)
            ty0, ty1 = _tile_range(means2d[image, g, 1], radii[image, g, 1], height)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    t = ty * tiles_x + tx
                    ids[cursor[t]] = g
                    cursor[t] += 1


def _gaussian_at_py(means2d, conics, opacities, radii, image, g, px, py):
    """(dx, dy, vis, alpha) of Gaussian g at pixel centre (px, py): vis = exp(−power); alpha = 0
    outside its screen box, where it is below 1/255 anyway (the box is drawn so)."""
    dx = px - means2d[image, g, 0]
    dy = py - means2d[image, g, 1]
    if abs(dx) > radii[image, g, 0] or abs(dy) > radii[image, g, 1]:
        return dx, dy, 0.0, 0.0
    power = 0.5 * conics[image, g, 0] * dx * dx + conics[image, g, 1] * dx * dy
    power += 0.5 * conics[image, g, 2] * dy * dy
    vis = np.exp(-power)
    alpha = min(MAX_ALPHA, opacities[image, g] * vis)
    return dx, dy, vis, alpha


def _forward_py(means2d, conics, opacities, features, radii, offsets, ids, out, final_t, last):
    """Composite every image: out [I, H, W, F], final_t [I, H, W] (float64), last [I, H, W]
    (how many entries of the pixel's tile list were walked, for the backward)."""
    num_images, height, width = out.shape[0], out.shape[1], out.shape[2]
    num_features = features.shape[2]
    tiles_x = (width + TILE - 1) // TILE
    tiles = tiles_x * ((height + TILE - 1) // TILE)
    for task in numba.prange(num_images * tiles):
        image, t = task // tiles, task % tiles
        x0, y0 = (t % tiles_x) * TILE, (t // tiles_x) * TILE
        begin, end = offsets[image, t], offsets[image, t + 1]
        acc = np.zeros(num_features, np.float64)
        for y in range(y0, min(y0 + TILE, height)):
            for x in range(x0, min(x0 + TILE, width)):
                acc[:] = 0.0
                transmittance = 1.0
                walked = 0
                for r in range(begin, end):
                    g = ids[r]
                    _, _, _, alpha = _gaussian_at(
                        means2d, conics, opacities, radii, image, g, x + 0.5, y + 0.5
                    )
                    if alpha < ALPHA_THRESHOLD:
                        continue
                    after = transmittance * (1.0 - alpha)
                    if after <= MIN_TRANSMITTANCE:
                        break
                    weight = alpha * transmittance
                    for f in range(num_features):
                        acc[f] += weight * features[image, g, f]
                    transmittance = after
                    walked = r + 1 - begin
                for f in range(num_features):
                    out[image, y, x, f] = acc[f]
                final_t[image, y, x] = transmittance
                last[image, y, x] = walked


def _backward_py(
    means2d, conics, opacities, features, radii, offsets, ids, final_t, last, grad_out,
    grad_means2d, grad_conics, grad_opacities, grad_features,
):  # fmt: skip
    """Accumulate the gradients of every image into the per-thread buffers grad_* [T, I, N, ·]."""
    num_images, height, width = grad_out.shape[0], grad_out.shape[1], grad_out.shape[2]
    num_features = features.shape[2]
    tiles_x = (width + TILE - 1) // TILE
    tiles = tiles_x * ((height + TILE - 1) // TILE)
    chunks = grad_means2d.shape[0]
    for c in numba.prange(chunks):
        behind = np.zeros(num_features, np.float64)
        for task in range(c, num_images * tiles, chunks):
            image, t = task // tiles, task % tiles
            x0, y0 = (t % tiles_x) * TILE, (t // tiles_x) * TILE
            begin = offsets[image, t]
            for y in range(y0, min(y0 + TILE, height)):
                for x in range(x0, min(x0 + TILE, width)):
                    transmittance = final_t[image, y, x]
                    behind[:] = 0.0
                    for r in range(begin + last[image, y, x] - 1, begin - 1, -1):
                        g = ids[r]
                        dx, dy, vis, alpha = _gaussian_at(
                            means2d, conics, opacities, radii, image, g, x + 0.5, y + 0.5
                        )
                        if alpha < ALPHA_THRESHOLD:
                            continue
                        one_minus = 1.0 - alpha
                        transmittance /= one_minus  # the transmittance in front of g
                        weight = alpha * transmittance
                        grad_alpha = 0.0
                        for f in range(num_features):
                            upstream = grad_out[image, y, x, f]
                            feature = features[image, g, f]
                            grad_alpha += upstream * (
                                feature * transmittance - behind[f] / one_minus
                            )
                            grad_features[c, image, g, f] += weight * upstream
                            behind[f] += feature * weight
                        opacity = opacities[image, g]
                        if opacity * vis > MAX_ALPHA:  # clamped: no gradient through alpha
                            continue
                        grad_opacities[c, image, g] += vis * grad_alpha
                        grad_power = -opacity * vis * grad_alpha
                        a = conics[image, g, 0]
                        b = conics[image, g, 1]
                        cc = conics[image, g, 2]
                        grad_means2d[c, image, g, 0] -= grad_power * (a * dx + b * dy)
                        grad_means2d[c, image, g, 1] -= grad_power * (b * dx + cc * dy)
                        grad_conics[c, image, g, 0] += grad_power * 0.5 * dx * dx
                        grad_conics[c, image, g, 1] += grad_power * dx * dy
                        grad_conics[c, image, g, 2] += grad_power * 0.5 * dy * dy


if numba_available():
    _tile_range = numba.njit(cache=True, inline="always")(_tile_range_py)
    _gaussian_at = numba.njit(cache=True, inline="always")(_gaussian_at_py)
    _count = numba.njit(parallel=True, cache=True)(_count_py)
    _fill = numba.njit(parallel=True, cache=True)(_fill_py)
    _forward = numba.njit(parallel=True, cache=True)(_forward_py)
    _backward = numba.njit(parallel=True, cache=True)(_backward_py)


def _tile_lists(means2d, radii, order, counts, width, height) -> tuple[np.ndarray, np.ndarray]:
    """Per image and tile, the depth-sorted Gaussians that may touch it (CSR: offsets, ids)."""
    tiles = ((width + TILE - 1) // TILE) * ((height + TILE - 1) // TILE)
    per_tile = np.zeros((means2d.shape[0], tiles), np.int64)
    _count(means2d, radii, order, counts, width, height, per_tile)
    ends = np.cumsum(per_tile.reshape(-1))
    offsets = np.zeros((means2d.shape[0], tiles + 1), np.int64)
    offsets[:, 1:] = ends.reshape(per_tile.shape)
    offsets[1:, 0] = ends.reshape(per_tile.shape)[:-1, -1]
    ids = np.empty(int(ends[-1]) if ends.size else 0, np.int64)
    _fill(means2d, radii, order, counts, width, height, offsets, ids)
    return offsets, ids


def _numpy(t: Tensor, dtype: torch.dtype) -> np.ndarray:
    return t.detach().to(dtype).contiguous().numpy()


class _Composite(torch.autograd.Function):
    """[I, N, ·] per-image Gaussians → [I, H, W, F] accumulated features, with its backward."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, radii, order, counts, width, height):
        dtype = features.dtype
        arrays = [_numpy(t, dtype) for t in (means2d, conics, opacities, features, radii)]
        lists = _tile_lists(arrays[0], arrays[4], order.numpy(), counts.numpy(), width, height)
        num_images = means2d.shape[0]
        out = np.empty((num_images, height, width, features.shape[-1]), arrays[0].dtype)
        final_t = np.empty((num_images, height, width), np.float64)
        last = np.empty((num_images, height, width), np.int64)
        _forward(*arrays, *lists, out, final_t, last)
        ctx.arrays = (*arrays, *lists, final_t, last)
        ctx.dtype = dtype
        return torch.from_numpy(out)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        arrays = ctx.arrays
        means2d, features = arrays[0], arrays[3]
        chunks = numba.get_num_threads()
        shape = (chunks, *means2d.shape[:2])
        buffers = [
            np.zeros((*shape, 2), means2d.dtype),
            np.zeros((*shape, 3), means2d.dtype),
            np.zeros(shape, means2d.dtype),
            np.zeros((*shape, features.shape[2]), means2d.dtype),
        ]
        grad = grad_out.detach().to(ctx.dtype).contiguous().numpy()
        _backward(*arrays, grad, *buffers)
        grads = [torch.from_numpy(b.sum(axis=0)) for b in buffers]
        return (*grads, None, None, None, None, None)


def rasterize_numba(
    means: Tensor,  # [..., N, 3] world frame, metres
    quats: Tensor,  # [..., N, 4] wxyz rotations, normalised here
    scales: Tensor,  # [..., N, 3] standard deviations, metres
    opacities: Tensor,  # [..., N] in [0, 1]
    colors: Tensor,  # [..., N, D]
    world_to_cam: Tensor,  # [..., C, 4, 4] OpenCV convention
    K: Tensor,  # [..., C, 3, 3] pixels
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
    antialiased: bool = False,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`torch_backend.rasterize_torch` with the compositing compiled: same inputs, outputs
    (rgb ``[..., C, H, W, D]``, alpha and depth ``[..., C, H, W]``) and gradients; CPU tensors,
    float32 or float64."""
    if not numba_available():
        raise RuntimeError(
            "the numba renderer needs numba (pip install numba); use backend='torch'"
        )
    if means.device.type != "cpu":
        raise ValueError(f"the numba renderer runs on CPU tensors, got device {means.device}")
    _check_shapes(means, quats, scales, opacities, colors, world_to_cam, K)
    images = project_images(
        means, quats, scales, opacities, colors, world_to_cam, K, width, height, near_plane, eps2d,
        antialiased,
    )  # fmt: skip
    with torch.no_grad():
        visible = (images.radii > 0).all(dim=-1)
        keys = torch.where(visible, images.depths, torch.full_like(images.depths, float("inf")))
        order = torch.sort(keys, dim=-1, stable=True).indices.contiguous()  # front first
        counts = visible.sum(dim=-1).to(torch.int64)
    composited = _Composite.apply(
        images.means2d,
        images.conics,
        images.opacities,
        images.features,
        images.radii,
        order,
        counts,
        width,
        height,
    )
    return images.split_outputs(composited)
