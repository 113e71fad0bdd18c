"""Fused Triton simulator vs the PyTorch reference: trajectories, gradients and the training cost.

Drops B objects (balls of N_A anchors, K-nearest-neighbour springs) with different attributes
from the docs/design.md#attribute-ranges ranges, so that they hit the ground and bounce/slide within
the clip; runs the rollout with ``method="adjoint"`` (PyTorch forward, exact hand-written backward;
itself checked against autograd in tests/test_physics_adjoint.py) and ``method="fused"``; prints the
largest trajectory difference (metres) and relative gradient differences for m, k, d, f, v0, x0 and
rest lengths, and the time of a 20-frame × 100-substep rollout with its backward (issue 3's
training-sample cost).

    python benchmarks/check_fused_vs_reference.py                       # CUDA: 8 × 2048, 30 frames
    TRITON_INTERPRET=1 python benchmarks/check_fused_vs_reference.py --device cpu --anchors 24 \\
        --neighbors 6 --batch 2 --frames 6 --substeps 5 --no-timing    # CPU smoke test (~1 min)
"""

from __future__ import annotations

import argparse
import datetime
import time

import torch
from bench_simulator import ball
from common import machine_description

from reconphys.physics import SpringMassModel, State, knn_springs, rollout, stable_substeps


def make_inputs(batch: int, num_anchors: int, neighbors: int, device: str, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    anchors = ball(num_anchors)
    springs, rest = knn_springs(anchors, neighbors)
    x0 = anchors + torch.tensor([0.0, 0.0, 0.3])  # lowest anchor ≈ 5 cm above the ground
    x0 = x0.expand(batch, -1, -1).clone()

    def uniform(low, high):
        return low + (high - low) * torch.rand(batch, generator=g)

    attributes = {
        "mass": uniform(0.2, 6.0),
        "stiffness": uniform(10.0, 1200.0),
        "damping": uniform(0.1, 5.0),
        "friction": uniform(0.0, 1.0),
    }
    v0 = torch.tensor([0.5, 0.2, -1.0]) + 0.1 * torch.randn(batch, 1, 3, generator=g)
    v0 = v0.expand(-1, num_anchors, -1).clone()
    inputs = {"x0": x0, "v0": v0, "rest": rest, **attributes}
    inputs = {name: t.to(device).requires_grad_(True) for name, t in inputs.items()}
    return springs.to(device), inputs


def run(method, springs, inputs, frames, substeps):
    model = SpringMassModel(
        springs,
        inputs["rest"],
        inputs["mass"],
        inputs["stiffness"],
        inputs["damping"],
        inputs["friction"],
    )
    traj = rollout(
        model, State(inputs["x0"], inputs["v0"]), frames, substeps=substeps, method=method
    )
    weights = torch.linspace(0.0, 1.0, traj.x.shape[1], device=traj.x.device)[None, :, None, None]
    loss = (traj.x * weights).square().sum() + (traj.v * weights).sum()
    grads = torch.autograd.grad(loss, list(inputs.values()))
    return traj, dict(zip(inputs, grads, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--anchors", type=int, default=2048)
    parser.add_argument("--neighbors", type=int, default=32)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--substeps", type=int, default=0, help="0: from the stability bound")
    parser.add_argument("--no-timing", action="store_true")
    args = parser.parse_args()
    torch.set_flush_denormal(True)
    print(f"fused vs reference on {args.device}, {datetime.date.today()}")
    print(machine_description(args.device))
    springs, inputs = make_inputs(args.batch, args.anchors, args.neighbors, args.device)
    substeps = args.substeps
    if substeps == 0:
        probe = SpringMassModel(springs, inputs["rest"].detach(), inputs["mass"].detach(),
                                inputs["stiffness"].detach(), inputs["damping"].detach(),
                                inputs["friction"].detach())  # fmt: skip
        substeps = stable_substeps(probe, inputs["x0"].detach(), min_substeps=100)
    print(f"B={args.batch}, N_A={args.anchors}, K={args.neighbors}, E={springs.shape[0]}, "
          f"{args.frames} frames × {substeps} substeps, float32")  # fmt: skip
    reference, grads_ref = run("adjoint", springs, inputs, args.frames, substeps)
    fused, grads_fused = run("fused", springs, inputs, args.frames, substeps)
    contacts = (reference.x[..., 2] <= 1e-6).any(-1).float().mean().item()
    print(f"frames with ground contact: {100 * contacts:.0f} %")
    dx = (fused.x - reference.x).abs().max().item()
    dv = (fused.v - reference.v).abs().max().item()
    print(f"trajectory: max |Δx| {dx:.2e} m [{'ok' if dx < 1e-4 else 'FAIL'} < 1e-4], "
          f"max |Δv| {dv:.2e} m/s")  # fmt: skip
    for name, g in grads_ref.items():
        error = ((grads_fused[name] - g).abs().max() / g.abs().max().clamp(min=1e-30)).item()
        verdict = "ok" if error < 1e-3 else "FAIL"
        print(f"  d/d{name:<9}: max relative difference {error:.2e} [{verdict} < 1e-3]")
    if args.no_timing:
        return
    for method in ("adjoint", "fused"):
        times = []
        for _ in range(3):
            torch.cuda.synchronize() if args.device == "cuda" else None
            start = time.perf_counter()
            run(method, springs, inputs, 20, 100)
            torch.cuda.synchronize() if args.device == "cuda" else None
            times.append(time.perf_counter() - start)
        print(f"20 frames × 100 substeps, B={args.batch}, forward + backward, {method}: "
              f"{min(times):.3f} s ({2000 / min(times):,.0f} substeps/s)")  # fmt: skip


if __name__ == "__main__":
    main()
