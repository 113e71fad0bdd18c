"""Simulator throughput: substeps per second of each rollout method, measured in one run.

Objects are balls of volume anchors (0.5 m across) with K-nearest-neighbour springs, falling onto
the ground with mid-range attributes. "forward" runs substeps without autograd; "fwd+bwd" runs the
same substeps with gradients on (m, k, d, f, initial velocity) and back-propagates a loss on the
final positions. Methods (see ``reconphys.physics.rollout``): ``autograd`` (the plain reference),
``adjoint`` (same forward, hand-written backward), ``numba`` (compiled CPU substeps and
compiled adjoint), ``fused`` (Triton kernels, CUDA only). The
forward of ``autograd`` and ``adjoint`` is the same code, so it is timed once ("torch"). One row
per (B scenes, N_A anchors, K neighbours); substeps/s count substeps of the whole batch.

    python benchmarks/bench_simulator.py                   # CPU, and CUDA if available
    python benchmarks/bench_simulator.py --device cpu --quick
"""

from __future__ import annotations

import argparse
import datetime
import math

import torch
from common import machine_description, timed

from reconphys._optional import numba_available
from reconphys.physics import SpringMassModel, State, knn_springs, rollout, sample_volume_anchors
from reconphys.physics.triton_backend import fused_usable

GRID = [(b, n, k) for b in (1, 8, 32) for n in (512, 2048) for k in (16, 32)]
CONFIGS = {"cpu": GRID, "cuda": GRID}
QUICK = {"cpu": [(1, 2048, 32)], "cuda": [(1, 2048, 32), (8, 2048, 32)]}
# Autograd keeps every substep's intermediates: cap its backward timing to this many substeps.
AUTOGRAD_BACKWARD_SUBSTEPS = {"cpu": 10, "cuda": 50}


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


def substeps_per_second(config, device, substeps, method, backward) -> float:
    batch, num_anchors, neighbors = config
    model, state, *_ = make_system(batch, num_anchors, neighbors, device, backward)

    def rollout_once():
        with torch.set_grad_enabled(backward):
            traj = rollout(model, state, 1, substeps=substeps, method=method)
            if backward:
                traj.x[:, -1, :, 2].sum().backward()

    return substeps / timed(rollout_once, device, repeats=2)


def run(device: str, configs, substeps: int) -> list[dict]:
    fused = fused_usable(torch.device(device))
    rows = []
    for config in configs:
        batch, num_anchors, neighbors = config
        row = {"B": batch, "N_A": num_anchors, "K": neighbors}
        row["E"] = knn_springs(ball(num_anchors), neighbors)[0].shape[0]
        row["fwd torch"] = substeps_per_second(config, device, substeps, "autograd", False)
        if device == "cpu" and numba_available():
            row["fwd numba"] = substeps_per_second(config, device, substeps, "numba", False)
        autograd_substeps = min(substeps, AUTOGRAD_BACKWARD_SUBSTEPS[device])
        row["bwd autograd"] = substeps_per_second(
            config, device, autograd_substeps, "autograd", True
        )
        row["bwd adjoint"] = substeps_per_second(config, device, substeps, "adjoint", True)
        if device == "cpu" and numba_available():
            row["bwd numba"] = substeps_per_second(config, device, substeps, "numba", True)
        if fused:
            row["fwd fused"] = substeps_per_second(config, device, substeps, "fused", False)
            row["bwd fused"] = substeps_per_second(config, device, substeps, "fused", True)
        rows.append(row)
        cells = "  ".join(f"{k} {v:>9,.0f}/s" for k, v in row.items() if isinstance(v, float))
        print(f"  B={batch:<3d} N_A={num_anchors:<5d} K={neighbors:<3d} {cells}", flush=True)
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
        substeps = args.substeps or (20 if device == "cpu" else 200)
        print(f"\n## simulator, {device}: {machine_description(device)}")
        print(f"{datetime.date.today()}, {substeps} substeps per timing, best of 2, float32")
        print(f"(autograd fwd+bwd timed over {AUTOGRAD_BACKWARD_SUBSTEPS[device]} substeps)")
        rows = run(device, configs, substeps)
        names = ("fwd torch", "fwd numba", "fwd fused", "bwd autograd", "bwd adjoint", "bwd numba")
        names += ("bwd fused",)
        columns = [c for c in names if c in rows[0]]
        titles = {
            "fwd torch": "forward, torch",
            "fwd numba": "forward, numba",
            "fwd fused": "forward, fused",
            "bwd autograd": "fwd+bwd, autograd",
            "bwd adjoint": "fwd+bwd, adjoint",
            "bwd numba": "fwd+bwd, numba",
            "bwd fused": "fwd+bwd, fused",
        }
        print("\nsubsteps/s (whole batch); ratios against the autograd reference of the same run")
        print("| B | N_A | K | springs | " + " | ".join(titles[c] for c in columns) + " |")
        print("|---|---|---|---|" + "---|" * len(columns))
        for r in rows:
            cells = []
            for c in columns:
                base = r["fwd torch"] if c.startswith("fwd") else r["bwd autograd"]
                ratio = "" if c in ("fwd torch", "bwd autograd") else f" ({r[c] / base:.1f}×)"
                cells.append(f"{r[c]:,.0f}{ratio}")
            print(f"| {r['B']} | {r['N_A']} | {r['K']} | {r['E']} | " + " | ".join(cells) + " |")
        assert all(math.isfinite(r["fwd torch"]) for r in rows)


if __name__ == "__main__":
    main()
