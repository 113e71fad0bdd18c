"""An evaluate report's rows split by launch (drop / toss): MAE ratios to trivial, future PSNR.

``reconphys evaluate`` reports all of a split's samples together; issue 22's acceptance is stated on
drops. This reads the report's ``per_sample.csv`` and each sample's ``sample.json`` (its launch)
and prints, per method and launch, the MAE of log k/m, log d/m and friction with trivial's MAE /
the method's (> 1: better than trivial), the mean future PSNR (trivial's beside it), how many
samples are ahead of trivial there, the mean seconds per scene and, for a method with intervals
(reports written since 2026-11-27 hold them per sample), how often its 10–90 % intervals held the
truth:

    python benchmarks/by_launch.py runs/eval_pyb128 data/pyb128

Needs the report to hold a ``trivial`` row (``--methods trivial,...``).
"""

from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

from reconphys.data.storage import read_manifest
from reconphys.physics import ATTRIBUTES
from reconphys.pipeline.search import OBSERVABLES
from reconphys.pipeline.search import observables as observables_of

NAMES = ("log k/m", "log d/m", "friction")


def observables(row: dict, prefix: str) -> list[float]:
    """log k/m, log d/m, f of a per_sample.csv row's ``true_`` or ``predicted_`` attributes."""
    attributes = {name: float(row[f"{prefix}_{name}"]) for name in ATTRIBUTES}
    return observables_of(SimpleNamespace(**attributes)).tolist()


def launches(data: Path) -> dict[str, str]:
    """Sample id → its launch ("drop" or "toss"; samples made before tosses: "drop")."""
    launch_of = {}
    for sample in read_manifest(data)["samples"]:
        meta = json.loads((data / sample["dir"] / "sample.json").read_text())
        launch_of[sample["id"]] = meta["initial_state"].get("launch", "drop")
    return launch_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="folder written by reconphys evaluate --out")
    parser.add_argument("data", type=Path, help="the dataset folder it evaluated")
    args = parser.parse_args()
    launch_of = launches(args.data)
    rows = defaultdict(dict)  # method → sample → row
    with open(args.report / "per_sample.csv", newline="") as file:
        for row in csv.DictReader(file):
            if not row["failure"]:
                rows[row["method"]][row["sample"]] = row
    if "trivial" not in rows:
        raise SystemExit(f"{args.report}: no trivial row (evaluate with --methods trivial,...)")
    trivial = rows["trivial"]
    for kind in ("drop", "toss", "all"):
        chosen = [s for s in trivial if kind == "all" or launch_of[s] == kind]
        if not chosen:
            continue
        print(f"{kind}: {len(chosen)} samples")
        for method, by_sample in rows.items():
            have = [s for s in chosen if s in by_sample]
            errors = [[0.0] * 3, [0.0] * 3]  # method's, trivial's summed |error|
            ahead, psnr, psnr_trivial, seconds = 0, 0.0, 0.0, 0.0
            inside, intervals = [0, 0, 0], 0
            for s in have:
                row, base = by_sample[s], trivial[s]
                true = observables(row, "true")
                if row.get("interval_friction_lo"):
                    intervals += 1
                    for j, key in enumerate(OBSERVABLES):
                        lo, hi = float(row[f"interval_{key}_lo"]), float(row[f"interval_{key}_hi"])
                        inside[j] += lo <= true[j] <= hi
                for j, (mine, theirs) in enumerate(
                    zip(observables(row, "predicted"), observables(base, "predicted"), strict=True)
                ):
                    errors[0][j] += abs(mine - true[j])
                    errors[1][j] += abs(theirs - true[j])
                psnr += float(row["future_psnr"])
                psnr_trivial += float(base["future_psnr"])
                ahead += float(row["future_psnr"]) > float(base["future_psnr"])
                seconds += float(row["seconds"] or 0.0)
            n = max(len(have), 1)
            ratios = " / ".join(
                f"{b / a:.2f}×" if a > 0 else "–" for a, b in zip(*errors, strict=True)
            )
            maes = " / ".join(f"{a / n:.3f}" for a in errors[0])
            print(
                f"  {method:18} MAE {maes} ({' / '.join(NAMES)}), trivial/it {ratios}; future "
                f"PSNR {psnr / n:.2f} ({psnr_trivial / n:.2f}), ahead {ahead}/{len(have)}; "
                f"{seconds / n:.1f} s / scene"
                + (
                    f"; intervals cover {' / '.join(f'{c / intervals:.0%}' for c in inside)}"
                    if intervals
                    else ""
                )
            )


if __name__ == "__main__":
    main()
