"""Renderer throughput: images per second of the torch reference beside its fast twins (numba on
CPU, gsplat on CUDA), measured in one run.

One "render" is the 4 dataset views (docs/design.md#conventions) of a random 0.5 m object; the table
reports the time per render and images per second (4 images per render), forward only (no autograd)
and forward + backward (a photometric-style loss back to means, quats, scales, opacities and
colours). The issue-10 CPU target is the 128² × 2,048-Gaussian row: forward + backward ≤ 50 ms.

    python benchmarks/bench_renderer.py                 # CUDA if available, else CPU (~1–2 min)
    python benchmarks/bench_renderer.py --device cpu --quick
"""

from __future__ import annotations

import argparse
import datetime
import math
import time
from collections.abc import Callable

import torch
from common import machine_description

from reconphys.render import RASTERIZERS, available_backends, dataset_views

# (image side in pixels, number of Gaussians)
SIZES = {
    "cuda": [(64, 1_000), (128, 1_000), (256, 1_000), (64, 10_000), (128, 10_000), (256, 10_000)],
    "cpu": [(32, 2_000), (64, 1_000), (128, 1_000), (128, 2_048), (64, 10_000), (128, 10_000)],
}
QUICK_SIZES = {"cuda": [(64, 1_000), (256, 10_000)], "cpu": [(32, 500), (128, 2_048)]}
FAST_TWIN = {"cpu": "numba", "cuda": "gsplat"}


def random_object(
    num_gaussians: int,
    seed: int = 0,
    size: float = 0.5,
    center: tuple[float, float, float] = (0.0, 0.0, 0.3),
    device: torch.device | str = "cpu",
    dtype: torch.dtype = torch.float32,
) -> dict[str, torch.Tensor]:
    """Random Gaussians filling a ball of diameter ``size`` metres around ``center``.

    Scales follow the mean spacing ``size / N^(1/3)`` (log-normal spread) so that the object looks
    about equally dense for any N. Returns means [N, 3], quats [N, 4], scales [N, 3] (metres),
    opacities [N], colors [N, 3].
    """
    generator = torch.Generator().manual_seed(seed)
    n = num_gaussians
    direction = torch.nn.functional.normalize(torch.randn(n, 3, generator=generator), dim=-1)
    radius = 0.5 * size * torch.rand(n, 1, generator=generator) ** (1 / 3)
    spacing = size / n ** (1 / 3)
    scene = {
        "means": direction * radius + torch.tensor(center),
        "quats": torch.randn(n, 4, generator=generator),
        "scales": 0.5 * spacing * torch.exp(0.3 * torch.randn(n, 3, generator=generator)),
        "opacities": 0.1 + 0.9 * torch.rand(n, generator=generator),
        "colors": torch.rand(n, 3, generator=generator),
    }
    return {name: t.to(device=device, dtype=dtype) for name, t in scene.items()}


def synchronize(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def time_call(fn: Callable[[], object], device: str, min_seconds: float, min_repeats: int) -> float:
    """Seconds per call: one warm-up, then repeat until both minimums are reached."""
    fn()
    synchronize(device)
    repeats, start = 0, time.perf_counter()
    while repeats < min_repeats or time.perf_counter() - start < min_seconds:
        fn()
        repeats += 1
    synchronize(device)
    return (time.perf_counter() - start) / repeats


def benchmark(
    backend: str,
    side: int,
    num_gaussians: int,
    device: str,
    min_seconds: float,
    min_repeats: int,
    chunk_pixels: int | None = None,
) -> tuple[float, float]:
    """Seconds per 4-view render: (forward, forward + backward)."""
    scene = random_object(num_gaussians, device=device)
    cameras = dataset_views(side, side, device=device)
    options = {"chunk_pixels": chunk_pixels} if backend == "torch" and chunk_pixels else {}
    rasterize = RASTERIZERS[backend]

    def forward(tensors: dict[str, torch.Tensor]):
        return rasterize(
            **tensors,
            world_to_cam=cameras.world_to_cam,
            K=cameras.K,
            width=side,
            height=side,
            **options,
        )

    def forward_only() -> None:
        with torch.no_grad():
            forward(scene)

    def forward_backward() -> None:
        params = {name: t.clone().requires_grad_(True) for name, t in scene.items()}
        rgb, alpha, _ = forward(params)
        (rgb.square().mean() + alpha.mean()).backward()

    return (
        time_call(forward_only, device, min_seconds, min_repeats),
        time_call(forward_backward, device, min_seconds, min_repeats),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default_device = "cuda" if torch.cuda.is_available() else "cpu"
    parser.add_argument("--device", choices=["cpu", "cuda"], default=default_device)
    parser.add_argument("--quick", action="store_true", help="two small sizes, short timings")
    parser.add_argument("--chunk-pixels", type=int, default=None, help="torch backend tile size")
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device available")

    backends = ["torch"]
    if FAST_TWIN[args.device] in available_backends():
        backends.append(FAST_TWIN[args.device])
    sizes = (QUICK_SIZES if args.quick else SIZES)[args.device]
    min_seconds, min_repeats = (0.2, 1) if args.quick else (1.0, 3)

    torch.set_flush_denormal(True)
    print(f"renderer benchmark on {args.device}, {datetime.date.today()}")
    print(machine_description(args.device))
    print("one render = 4 views; ms per render, images/s in parentheses")
    header = (
        f"{'image':>9} {'gaussians':>9} {'backend':>7} {'forward':>20} {'forward+backward':>20}"
    )
    print(header)
    print("-" * len(header))
    results: dict[tuple[int, int, str], tuple[float, float]] = {}
    for side, num_gaussians in sizes:
        for backend in backends:
            timing = (side, num_gaussians, args.device, min_seconds, min_repeats)
            fwd, fwd_bwd = benchmark(backend, *timing, chunk_pixels=args.chunk_pixels)
            results[side, num_gaussians, backend] = (fwd, fwd_bwd)
            cells = [f"{1e3 * t:9.2f} ({4 / t:7.1f}/s)" for t in (fwd, fwd_bwd)]
            print(
                f"{side:>4}×{side:<4} {num_gaussians:>9} {backend:>7} {cells[0]:>20} {cells[1]:>20}"
            )
    if len(backends) > 1:
        fast = backends[1]
        for i, what in enumerate(("forward", "forward+backward")):
            speedups = [
                results[(*key[:2], "torch")][i] / results[key][i]
                for key in results
                if key[2] == fast
            ]
            geometric_mean = math.exp(sum(math.log(s) for s in speedups) / len(speedups))
            print(f"{fast} speed-up over torch, {what} (geometric mean): {geometric_mean:.1f}×")


if __name__ == "__main__":
    main()
