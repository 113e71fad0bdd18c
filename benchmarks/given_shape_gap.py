"""What separates ``predict`` with the true shape from evaluate's † search: the initial motion or
the anchor layout? (docs/usage.md "A given shape: what the gap is made of").

For the first test samples of a plain dataset (view 0), the sample is brought in as a user would
(its mp4, camera file and true Gaussians as a PLY) and ``predict`` builds its asset and reads the
network (``refine=False``). Its search is then run as ``predict`` runs it (the fit times the
network's belief at ``GIVEN_GEOMETRY_TEMPERATURE``; ``--fit-alone``: the profiles alone, τ × 1)
from three starts that differ in one thing each:

- ``masks_motion``: predict's asset as it is (its anchors, the velocity read from the masks, no
  spin) — what a user gets;
- ``true_motion``: predict's anchors with the sample's true initial velocity and spin;
- ``own_layout``: the sample's own asset (the anchors the data were simulated with) with the
  true initial motion, the network's attributes;
- ``joint_motion`` (``--joint``): predict's asset, its initial motion searched with the physics
  (``search(motion=…)``, from the masks' velocity and no spin).

Printed: MAE of log k/m, log d/m and friction against the truth, and their ratios to the
trivial predictor (the attribute ranges' midpoints).

    python benchmarks/given_shape_gap.py data/val128 --limit 16
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from common import predict_bundle, user_bundle

from reconphys.data import DropDataset
from reconphys.geometry import rigid_velocity
from reconphys.physics import ATTRIBUTE_RANGES, ATTRIBUTES
from reconphys.pipeline.demo import true_observables
from reconphys.pipeline.search import (
    GIVEN_GEOMETRY_TEMPERATURE,
    OBSERVABLES,
    observables,
    search,
)

STARTS = ("masks_motion", "true_motion", "own_layout")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="a plain dataset folder written by make-data")
    parser.add_argument("--limit", type=int, default=16)
    parser.add_argument("--fit-alone", action="store_true", help="no belief, τ × 1")
    parser.add_argument("--joint", action="store_true", help="also joint_motion")
    parser.add_argument("--starts", default=",".join(STARTS), help="comma-separated")
    args = parser.parse_args()
    torch.set_num_threads(2)
    dataset = DropDataset(args.data, split="test", views=[0])
    midpoints = {k: 0.5 * (lo + hi) for k, (lo, hi) in ATTRIBUTE_RANGES.items()}
    trivial = np.array(list(true_observables(midpoints).values()))
    chosen = args.starts.split(",") + (["joint_motion"] if args.joint else [])
    errors = {name: [] for name in chosen}
    seconds = {name: [] for name in chosen}
    base = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        for i in range(min(args.limit, len(dataset))):
            own, meta = dataset.asset(i), dataset.meta(i)
            bundle = user_bundle(dataset, i, Path(folder))
            result = predict_bundle(bundle, refine=False)
            observation, network = result.observation, result.asset.physics
            sigma = result.details.get("network_sigma")
            prior = None
            if sigma is not None and not args.fit_alone:
                prior = torch.tensor([sigma[name] for name in OBSERVABLES], dtype=torch.float64)
            attributes = {name: getattr(network, name) for name in ATTRIBUTES}
            state = meta["initial_state"]
            linear, angular = state["linear_velocity"], state["angular_velocity"]
            starts = {
                "masks_motion": result.asset,
                "true_motion": replace(
                    result.asset, v0=rigid_velocity(result.asset.x0, linear, angular).float()
                ),
                "own_layout": replace(own, physics=replace(own.physics, **attributes)),
                "joint_motion": result.asset,  # its motion searched too (below)
            }
            truth = np.array(list(true_observables(meta["attributes"]).values()))
            base.append(np.abs(trivial - truth))
            row = [f"{meta['id'][:28]} |ω| {np.linalg.norm(angular):.2f}"]
            masks_velocity = result.details["initial_velocity"]["linear_m_s"]
            for name in chosen:
                asset = starts[name]
                motion = None
                if name == "joint_motion":
                    motion = torch.tensor([*masks_velocity, 0.0, 0.0, 0.0], dtype=torch.float64)
                tic = time.perf_counter()
                found, _ = search(
                    asset,
                    observation.frames[:20],
                    observation.camera,
                    masks=observation.masks[:20],
                    temperature_scale=1.0 if args.fit_alone else GIVEN_GEOMETRY_TEMPERATURE,
                    rebuilt=True,  # as predict: the law the given path was chosen under
                    prior_sigma=prior,
                    motion=motion,
                )
                seconds[name].append(time.perf_counter() - tic)
                errors[name].append(np.abs(observables(found.physics).numpy() - truth))
                row.append(f"{name}: {' '.join(f'{e:.2f}' for e in errors[name][-1])}")
            print(" | ".join(row), flush=True)
    how = "the fit alone (τ × 1)" if args.fit_alone else "the fit × the network's belief"
    print(
        f"\n{len(base)} test samples of {args.data}, view 0, {how}; {platform.machine()}, "
        f"torch {torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    trivial_mae = np.mean(base, 0)
    for name, rows in errors.items():
        mae = np.mean(rows, 0)
        print(f"{name:13} MAE {mae[0]:.3f} / {mae[1]:.3f} / {mae[2]:.3f}  ratios "
              + " / ".join(f"{r:.2f}×" for r in trivial_mae / mae)
              + f"; search {np.mean(seconds[name]):.1f} s a scene")  # fmt: skip
    print(f"{'trivial':13} MAE {trivial_mae[0]:.3f} / {trivial_mae[1]:.3f} / {trivial_mae[2]:.3f}")


if __name__ == "__main__":
    main()
