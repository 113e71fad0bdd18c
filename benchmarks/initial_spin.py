"""How well `predict` reads the spin about the viewing axis from the free fall
(pipeline/spin.py; docs/usage.md "The spin about the viewing axis").

For view 0 of the first N test samples of a realistic dataset, brought in as a user brings them
(`reconphys data video`: the mp4, with or without camera.json; segmenter masks, the 3DGS
predictor's Gaussians), `predict --no-refine` reads the clip, then the spin fit `predict` runs
before its search is run on the same Gaussians, masks, camera and linear velocity. Printed: the
mean |error| of the spin about the viewing axis beside "no spin" (the truth's own size), the
share of clips whose fit was kept, how often ± 1.2816 standard errors held the truth, seconds a
clip. Clips read as released from rest are counted apart (predict reads no spin for them).

    python benchmarks/initial_spin.py data/mval96 --limit 36
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from common import user_bundle

import reconphys
from reconphys.data import DropDataset
from reconphys.errors import InputError
from reconphys.pipeline.predict import spin_estimate

CONFIGS = ("camera_file", "mp4_only")
Z_80 = 1.2816  # ± this many standard errors hold 80 % of a normal


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--limit", type=int, default=40)
    parser.add_argument("--configs", default=",".join(CONFIGS))
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    args = parser.parse_args()
    torch.set_num_threads(2)
    configs = args.configs.split(",")
    dataset = DropDataset(Path(args.data), split="test", views=[0])
    rows, started = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        for index in range(min(args.limit, len(dataset))):
            meta, item = dataset.meta(index), dataset[index]
            bundle = user_bundle(dataset, index, Path(folder), item)
            spin = torch.tensor(meta["initial_state"]["angular_velocity"], dtype=torch.float64)
            true_roll = float(item["world_to_cam"][0, 2, :3].double() @ spin)
            row = {"id": meta["id"], "true_roll": true_roll}
            for config in configs:
                options = {"refine": False}
                if config == "camera_file":
                    options["camera"] = bundle / "camera.json"
                try:
                    result = reconphys.predict(bundle / "video.mp4", **options)
                except InputError as e:
                    row[config] = {"refused": str(e)}
                    continue
                motion = result.details["initial_velocity"]
                velocity = torch.tensor(motion["linear_m_s"])
                _, report = spin_estimate(result.asset.gaussians, result.observation, velocity)
                row[config] = {**report, "at_rest": motion["released_from_rest"]}
            rows.append(row)
            print(
                meta["id"],
                f"true {true_roll:+.2f}",
                " ".join(
                    f"{c}: {row[c]['about_view_rad_s']:+.2f}" if "how" in row[c] else f"{c}: –"
                    for c in configs
                ),
                flush=True,
            )
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))
    print(
        f"\n{len(rows)} test samples of {args.data}, view 0; {platform.machine()}, torch"
        f" {torch.__version__}, {time.perf_counter() - started:.0f} s"
    )
    for config in configs:
        done = [r for r in rows if "how" in r[config]]
        moving = [r for r in done if not r[config]["at_rest"]]
        if not moving:
            print(f"{config}: nothing answered and moving")
            continue
        truth = np.array([r["true_roll"] for r in moving])
        fitted = np.array([r[config]["about_view_rad_s"] for r in moving])
        shown = np.array([r[config]["shown"] for r in moving])
        kept = np.where(shown, fitted, 0.0)
        sd = np.array([r[config]["about_view_sd_rad_s"] or np.inf for r in moving])
        held = np.abs(fitted - truth) <= Z_80 * sd
        seconds = np.mean([r[config]["seconds"] for r in moving])
        print(
            f"{config}: {len(moving)} moving ({len(done) - len(moving)} read at rest, "
            f"{len(rows) - len(done)} refused); spin about the view, mean |error| rad/s: kept "
            f"{np.abs(kept - truth).mean():.3f} (fit {np.abs(fitted - truth).mean():.3f}), "
            f"no spin {np.abs(truth).mean():.3f}; kept on {shown.mean():.0%}; ± {Z_80} SE "
            f"held {held.mean():.0%}; {seconds:.2f} s a clip"
        )


if __name__ == "__main__":
    main()
