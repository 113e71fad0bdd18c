"""Acceptance check of the renderer twins: gsplat (CUDA) against the pure-PyTorch reference.

Renders a random 0.5 m object (≥ 10k Gaussians around (0, 0, 0.3)) into the 4 dataset views at
256×256 with both backends, prints the mean and max absolute differences of rgb, alpha and depth,
both timings, and the relative difference of the gradients of a photometric-style loss w.r.t. means,
scales, quats, opacities and colours. Exits with status 1 if the mean absolute rgb or alpha
difference is at or above the threshold (default 1e-2).

    python benchmarks/check_gsplat_vs_torch.py                      # on the GPU machine
    python benchmarks/check_gsplat_vs_torch.py --device cpu --skip-gsplat --gaussians 2000 --size 64
"""

from __future__ import annotations

import argparse
import sys
import time

import torch
from bench_renderer import random_object
from common import machine_description

from reconphys.render import Cameras, dataset_views
from reconphys.render.gsplat_backend import rasterize_gsplat
from reconphys.render.torch_backend import rasterize_torch

GRADIENT_NAMES = ("means", "scales", "quats", "opacities", "colors")


def render_views(rasterize, scene: dict[str, torch.Tensor], cameras: Cameras):
    """(rgb [C, H, W, 3], alpha [C, H, W], depth [C, H, W]) of ``scene`` seen by ``cameras``."""
    return rasterize(
        **scene,
        world_to_cam=cameras.world_to_cam,
        K=cameras.K,
        width=cameras.width,
        height=cameras.height,
    )


def render_and_time(rasterize, scene, cameras: Cameras, device: str, repeats: int = 3):
    """(rgb, alpha, depth) without autograd, and the mean seconds per 4-view render."""
    with torch.no_grad():
        outputs = render_views(rasterize, scene, cameras)
        if device == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        for _ in range(repeats):
            render_views(rasterize, scene, cameras)
        if device == "cuda":
            torch.cuda.synchronize()
    return outputs, (time.perf_counter() - start) / repeats


def loss_gradients(rasterize, scene, cameras: Cameras, seed: int = 0) -> dict[str, torch.Tensor]:
    """Gradients of Σ w·rgb + Σ v·alpha with fixed random pixel weights w, v."""
    params = {name: t.clone().requires_grad_(True) for name, t in scene.items()}
    rgb, alpha, _ = render_views(rasterize, params, cameras)
    generator = torch.Generator().manual_seed(seed)
    rgb_weights = torch.rand(rgb.shape, generator=generator).to(rgb.device)
    alpha_weights = torch.rand(alpha.shape, generator=generator).to(alpha.device)
    loss = (rgb * rgb_weights).sum() + (alpha * alpha_weights).sum()
    loss.backward()
    return {name: params[name].grad for name in GRADIENT_NAMES}


def describe(name: str, image: torch.Tensor) -> str:
    return f"{name}: mean {image.mean().item():.4f}, max {image.max().item():.4f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cuda")
    parser.add_argument("--gaussians", type=int, default=20_000)
    parser.add_argument("--size", type=int, default=256, help="image side, pixels")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threshold", type=float, default=1e-2, help="max mean |Δ| of rgb/alpha")
    parser.add_argument("--skip-gsplat", action="store_true", help="only run the torch backend")
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device available")
    if args.device == "cpu" and not args.skip_gsplat:
        parser.error("gsplat needs --device cuda (or pass --skip-gsplat)")

    print(machine_description(args.device))
    scene = random_object(args.gaussians, seed=args.seed, device=args.device)
    cameras = dataset_views(args.size, args.size, device=args.device)
    print(f"{args.gaussians} Gaussians, 4 views of {args.size}×{args.size}")

    reference, torch_seconds = render_and_time(rasterize_torch, scene, cameras, args.device)
    print(f"torch : {1e3 * torch_seconds:9.2f} ms per 4-view render")
    print("  " + describe("alpha", reference[1]))
    if args.device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    torch_gradients = loss_gradients(rasterize_torch, scene, cameras)
    if args.device == "cuda":
        peak = torch.cuda.max_memory_allocated() / 2**30
        print(f"  peak GPU memory of a torch forward + backward: {peak:.2f} GiB")
    for name, grad in torch_gradients.items():
        assert torch.isfinite(grad).all(), f"non-finite torch gradient w.r.t. {name}"
    if args.skip_gsplat:
        print("gsplat: skipped (--skip-gsplat); torch gradients are finite")
        return 0

    fast, gsplat_seconds = render_and_time(rasterize_gsplat, scene, cameras, args.device)
    speedup = torch_seconds / gsplat_seconds
    print(f"gsplat: {1e3 * gsplat_seconds:9.2f} ms per 4-view render ({speedup:.1f}× torch)")

    failed = False
    for name, ours, theirs in zip(("rgb", "alpha"), reference[:2], fast[:2], strict=True):
        difference = (ours - theirs).abs()
        verdict = "ok" if difference.mean() < args.threshold else "FAIL"
        failed |= verdict == "FAIL"
        mean, largest = difference.mean().item(), difference.max().item()
        print(f"{name:>5}: mean |Δ| {mean:.2e}, max |Δ| {largest:.2e}  [{verdict}]")
    both_opaque = (reference[1] > 0.5) & (fast[1] > 0.5)
    depth_difference = (reference[2] - fast[2])[both_opaque].abs()
    mean, largest = depth_difference.mean().item(), depth_difference.max().item()
    print(f"depth: mean |Δ| {mean:.2e} m, max |Δ| {largest:.2e} m (where both alphas > 0.5)")

    gsplat_gradients = loss_gradients(rasterize_gsplat, scene, cameras)
    print("gradients of a random-weighted loss, ‖g_torch − g_gsplat‖ / ‖g_torch‖ (cosine):")
    for name in GRADIENT_NAMES:
        ours, theirs = torch_gradients[name], gsplat_gradients[name]
        relative = (ours - theirs).norm() / ours.norm().clamp_min(1e-30)
        cosine = torch.nn.functional.cosine_similarity(ours.flatten(), theirs.flatten(), dim=0)
        print(f"  {name:>9}: {relative.item():.2e} ({cosine.item():.5f})")

    print("FAIL" if failed else "PASS", f"(threshold {args.threshold:g} on mean |Δ| of rgb, alpha)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
