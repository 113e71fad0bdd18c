"""Simulator throughput: substeps per second of the plain PyTorch stepping (DESIGN §4).

Objects are balls of volume anchors (0.5 m across) with K-nearest-neighbour springs, falling onto
the ground with mid-range attributes. "forward" runs substeps without autograd; "fwd+bwd" runs the
same substeps with gradients on (m, k, d, f, initial velocity) and back-propagates a loss on the
final positions. One row per (B scenes, N_A anchors, K neighbours); substeps/s counts substeps of
the whole batch (a batch of 8 doing 1 substep counts 1).

    python benchmarks/bench_simulator.py                   # CPU, and CUDA if available
    python benchmarks/bench_simulator.py --device cpu --quick
"""

from __future__ import annotations

import argparse
import datetime
import math

import torch
from common import machine_description, timed

from reconphys.physics import SpringMassModel, State, knn_springs, sample_volume_anchors, step

CONFIGS = {
    "cpu": [(1, 512, 16), (1, 2048, 16), (1, 2048, 32), (8, 2048, 32)],
    "cuda": [(b, n, k) for b in (1, 8, 32) for n in (512, 2048) for k in (16, 32)],
}
QUICK = {"cpu": [(1, 2048, 32)], "cuda": [(1, 2048, 32), (8, 2048, 32)]}


def ball(num_anchors: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    points = torch.randn(20 * num_anchors, 3, generator=g)
    radius = 0.25 * torch.rand(len(points), 1, generator=g) ** (1 / 3)
    return sample_volume_anchors(points / points.norm(dim=1, keepdim=True) * radius, num_anchors)


def make_system(batch: int, num_anchors: int, neighbors: int, device: str, grad: bool):
    anchors = ball(num_anchors)
    springs, rest = knn_springs(anchors, neighbors)
    x0 = (anchors + torch.tensor([0.0, 0.0, 0.26])).expand(batch, -1, -1).contiguous()
    params = {
        "mass": torch.full((batch,), 1.0),
        "stiffness": torch.full((batch,), 300.0),
        "damping": torch.full((batch,), 1.0),
        "friction": torch.full((batch,), 0.5),
    }
    params = {k: v.to(device).requires_grad_(grad) for k, v in params.items()}
    v0 = torch.zeros_like(x0).to(device).requires_grad_(grad)
    model = SpringMassModel(springs.to(device), rest.to(device), **params)
    return model, State(x0.to(device), v0), params, springs.shape[0]


def run(device: str, configs, substeps: int) -> list[dict]:
    rows = []
    h = 0.03 / 100
    for batch, num_anchors, neighbors in configs:
        row = {"B": batch, "N_A": num_anchors, "K": neighbors}
        for mode in ("forward", "fwd+bwd"):
            grad = mode == "fwd+bwd"
            model, state, params, num_springs = make_system(
                batch, num_anchors, neighbors, device, grad
            )
            row["E"] = num_springs

            def rollout_once(model=model, state=state, params=params, grad=grad):
                s = state
                with torch.set_grad_enabled(grad):
                    for _ in range(substeps):
                        s = step(model, s, h)
                    if grad:
                        s.x[..., 2].sum().backward()

            seconds = timed(rollout_once, device, repeats=2)
            row[mode] = substeps / seconds
        rows.append(row)
        print(
            f"  B={batch:<3d} N_A={num_anchors:<5d} K={neighbors:<3d} E={row['E']:<7d} "
            f"forward {row['forward']:>10,.0f}/s   fwd+bwd {row['fwd+bwd']:>10,.0f}/s",
            flush=True,
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", choices=["cpu", "cuda", "all"], default="all")
    parser.add_argument("--quick", action="store_true", help="one or two sizes only")
    parser.add_argument("--substeps", type=int, default=0, help="substeps per timing (0: auto)")
    args = parser.parse_args()
    torch.set_flush_denormal(True)
    devices = ["cpu", "cuda"] if args.device == "all" else [args.device]
    if "cuda" in devices and not torch.cuda.is_available():
        devices.remove("cuda")
        print("(no CUDA device: CPU only)")
    for device in devices:
        configs = (QUICK if args.quick else CONFIGS)[device]
        substeps = args.substeps or (100 if device == "cpu" else 400)
        print(f"\n## simulator, {device}: {machine_description(device)}")
        print(f"{datetime.date.today()}, {substeps} substeps per timing, best of 2, float32")
        rows = run(device, configs, substeps)
        print(
            "\n| B | N_A | K | springs | forward substeps/s | fwd+bwd substeps/s | fwd/bwd ratio |"
        )
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            ratio = r["forward"] / r["fwd+bwd"]
            print(
                f"| {r['B']} | {r['N_A']} | {r['K']} | {r['E']} | {r['forward']:,.0f} | "
                f"{r['fwd+bwd']:,.0f} | {ratio:.1f} |"
            )
        assert all(math.isfinite(r["forward"]) for r in rows)


if __name__ == "__main__":
    main()
