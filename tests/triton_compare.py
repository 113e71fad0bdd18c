"""Run the Triton engine and the PyTorch engine on the same small rollouts; print JSON.

Used by tests/test_physics_triton_backend.py in a subprocess with TRITON_INTERPRET=1 (Triton reads
it at import), and usable by hand on a GPU machine:
``python tests/triton_compare.py --device cuda``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
from test_physics_adjoint import small_system

from reconphys.physics import SpringMassModel, State, rollout

CASES = {
    "float64-shared": dict(dtype=torch.float64, per_scene=False, exponent=0.5, restitution=0.0),
    "float64-per-scene": dict(dtype=torch.float64, per_scene=True, exponent=0.5, restitution=0.3),
    "float32-hooke": dict(dtype=torch.float32, per_scene=False, exponent=0.0, restitution=0.0),
}


def run(method, case, device, frames, substeps):
    springs, rest, x0, v0, attributes = small_system(
        num_anchors=16, per_scene_topology=case["per_scene"], dtype=case["dtype"]
    )
    inputs = {"x0": x0, "v0": v0, "rest": rest, **attributes}
    inputs = {n: t.to(device).clone().requires_grad_(True) for n, t in inputs.items()}
    names = ("mass", "stiffness", "damping", "friction")
    model = SpringMassModel(
        springs.to(device),
        inputs["rest"],
        *(inputs[n] for n in names),
        spring_exponent=case["exponent"],
        restitution=case["restitution"],
        dtype=case["dtype"],
    )
    state = State(inputs["x0"], inputs["v0"])
    traj = rollout(model, state, frames, substeps=substeps, method=method)
    g = torch.Generator().manual_seed(1)
    weights = torch.randn(traj.x.shape, generator=g, dtype=torch.float64).to(traj.x)
    loss = (traj.x * weights).sum() + (traj.v * weights.flip(1)).sum()
    grads = torch.autograd.grad(loss, list(inputs.values()))
    return traj, dict(zip(inputs, grads, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--substeps", type=int, default=3)
    args = parser.parse_args()
    results = {}
    for name, case in CASES.items():
        reference, grads_ref = run("adjoint", case, args.device, args.frames, args.substeps)
        fused, grads_fused = run("fused", case, args.device, args.frames, args.substeps)
        results[name] = {
            "contacts": int((reference.x[..., 2] <= 1e-9).sum()),
            "x": float((fused.x - reference.x).abs().max().detach()),
            "v": float((fused.v - reference.v).abs().max().detach()),
            "grads": {
                n: float((grads_fused[n] - g).abs().max() / g.abs().max().clamp(min=1e-30))
                for n, g in grads_ref.items()
            },
        }
    print(json.dumps(results))


if __name__ == "__main__":
    main()
