"""Does a stiffness found on one anchor layout hold on another? (docs/usage.md "Searching the
initial motion with the physics").

For the first test samples of a dataset (view 0), the sample is brought in as a user would
(its mp4, camera file and true Gaussians as a PLY) and ``predict`` builds its asset without the
search: the same Gaussians, the same placement, its own anchors (seeded by the PLY's name, where
the dataset seeded them by the object's id). Both assets start from the **true** attributes and
the true initial motion and are searched on the decoded frames (temperature × 0.1): the sample's
own asset stays at the truth; how far predict's moves is what the layout changes.

    python benchmarks/anchor_layout.py data/pyb1 --limit 10
"""

from __future__ import annotations

import argparse
import platform
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from common import predict_bundle, user_bundle

from reconphys.data import DropDataset
from reconphys.geometry import rigid_velocity
from reconphys.pipeline.search import observables, search


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=10)
    parser.add_argument("--temperature-scale", type=float, default=0.1)
    args = parser.parse_args()
    torch.set_num_threads(2)
    root = Path(args.data)
    dataset = DropDataset(root, split="test", views=[0])
    shifts = {"own": [], "predict": []}
    with tempfile.TemporaryDirectory() as folder:
        for i in range(min(args.limit, len(dataset))):
            own = dataset.asset(i)
            state = dataset.meta(i)["initial_state"]
            bundle = user_bundle(dataset, i, Path(folder))
            result = predict_bundle(bundle, refine=False)
            observation = result.observation
            motion = torch.tensor(state["linear_velocity"] + state["angular_velocity"])
            true = observables(own.physics)
            row = [dataset.samples[i]["id"][:28]]
            for name, asset in (("own", own), ("predict", result.asset)):
                v0 = rigid_velocity(asset.x0, motion[:3], motion[3:]).float()
                started = replace(asset, physics=own.physics, v0=v0)
                found, _ = search(
                    started,
                    observation.frames[:20],
                    observation.camera,
                    masks=observation.masks[:20],
                    temperature_scale=args.temperature_scale,
                )
                shift = (observables(found.physics) - true).abs().numpy()
                shifts[name].append(shift)
                row.append(f"{name}: {' '.join(f'{s:.2f}' for s in shift)}")
            print(*row, flush=True)
    print(
        f"\n{len(shifts['own'])} test samples of {root}, view 0; {platform.machine()}, "
        f"torch {torch.__version__}; |found − true| of log k/m, log d/m, f from the truth"
    )
    for name, rows in shifts.items():
        mean, top = np.mean(rows, 0), np.max(rows, 0)
        print(f"{name} anchors: mean {mean[0]:.3f} / {mean[1]:.3f} / {mean[2]:.3f}, "
              f"max {top[0]:.2f} / {top[1]:.2f} / {top[2]:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
