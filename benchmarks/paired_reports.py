"""Two evaluate reports of the same samples, paired: did the change move a method's numbers?

For each pair BEFORE AFTER of report folders (``reconphys evaluate --out``, same dataset and
split), the method's future PSNR difference per sample (after − before): its mean, how many
samples moved by more than 0.5 dB either way and, pooled over all pairs, a 90 % bootstrap
interval of the mean difference. With ``--data`` (one dataset folder per pair, in order) each
pair also gets its drops' MAE ratios to trivial (trivial's MAE / the method's, log k/m / log d/m
/ friction) with 90 % bootstrap intervals over the drops, as issue 22's acceptance states them:

    python benchmarks/paired_reports.py runs/ev2_pyb runs/ev3_pyb runs/ev2_other100 \\
        runs/ev3_other100 --data data/pyb data/other100

Samples the two reports do not both hold (or that failed in either) are left out and counted.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
from by_launch import launches, observables

BOOTSTRAP = 4000


def read_rows(report: Path) -> dict[tuple[str, str], dict]:
    """(method, sample) → the report's per_sample.csv row, failures left out."""
    path = report / "per_sample.csv"
    if not path.is_file():
        raise SystemExit(f"{report}: no per_sample.csv (not a report folder written by evaluate)")
    with open(path, newline="") as file:
        return {(r["method"], r["sample"]): r for r in csv.DictReader(file) if not r["failure"]}


def bootstrap_interval(samples: np.ndarray, statistic, rng: np.random.Generator) -> np.ndarray:
    """5th and 95th percentiles of ``statistic`` over resamples of ``samples``' first axis."""
    draws = [
        statistic(samples[rng.integers(0, len(samples), len(samples))]) for _ in range(BOOTSTRAP)
    ]
    return np.percentile(np.array(draws), [5, 95], axis=0)


def drop_ratios(rows: dict, method: str, launch: dict[str, str], rng: np.random.Generator) -> str:
    """The method's drops' MAE ratios to trivial (``launch``: sample id → launch, from
    by_launch.launches), each with its 90 % bootstrap interval."""
    drops = [
        s
        for (m, s) in rows
        if m == method and ("trivial", s) in rows and launch.get(s, "drop") == "drop"
    ]
    if not drops:
        return "no drops with a trivial row"
    errors = np.array(  # [N, 2, 3]: the method's and trivial's |error| per observable
        [
            [
                np.abs(np.subtract(observables(rows[(who, s)], "predicted"), truth))
                for who in (method, "trivial")
            ]
            for s in drops
            for truth in [observables(rows[(method, s)], "true")]
        ]
    )

    def ratio(e: np.ndarray) -> np.ndarray:
        return e[:, 1].mean(0) / np.maximum(e[:, 0].mean(0), 1e-12)

    low, high = bootstrap_interval(errors, ratio, rng)
    return f"{len(drops)} drops: " + " / ".join(
        f"{r:.2f}× [{lo:.2f}, {hi:.2f}]" for r, lo, hi in zip(ratio(errors), low, high, strict=True)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", type=Path, nargs="+", help="BEFORE AFTER [BEFORE AFTER ...]")
    parser.add_argument("--method", default="reconphys_search")
    parser.add_argument("--data", type=Path, nargs="*", default=[], help="one per pair")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if len(args.reports) % 2:
        raise SystemExit("reports: expected pairs BEFORE AFTER, got an odd number of folders")
    pairs = list(zip(args.reports[::2], args.reports[1::2], strict=True))
    if args.data and len(args.data) != len(pairs):
        raise SystemExit(
            f"--data: expected one dataset per pair ({len(pairs)}), got {len(args.data)}"
        )
    rng = np.random.default_rng(args.seed)
    pooled = []
    for index, (before_dir, after_dir) in enumerate(pairs):
        before, after = read_rows(before_dir), read_rows(after_dir)
        samples = sorted(s for (m, s) in after if m == args.method and (m, s) in before)
        dropped = sum(m == args.method for (m, _) in after) - len(samples)
        if not samples:
            raise SystemExit(f"{before_dir}, {after_dir}: no {args.method} sample in both")
        diff = np.array(
            [
                float(after[(args.method, s)]["future_psnr"])
                - float(before[(args.method, s)]["future_psnr"])
                for s in samples
            ]
        )
        pooled.append(diff)
        print(
            f"{before_dir} → {after_dir}: {args.method} future PSNR {diff.mean():+.2f} dB over "
            f"{len(samples)} samples (better by > 0.5 dB on {(diff > 0.5).sum()}, worse on "
            f"{(diff < -0.5).sum()}; {dropped} not in both)"
        )
        if args.data:
            launch = launches(args.data[index])
            for name, rows in (("before", before), ("after", after)):
                print(f"  {name}: {drop_ratios(rows, args.method, launch, rng)}")
    everything = np.concatenate(pooled)
    low, high = bootstrap_interval(everything, np.mean, rng)
    print(
        f"pooled over {len(everything)} samples: {everything.mean():+.2f} dB "
        f"[{low:+.2f}, {high:+.2f}] (90 % bootstrap), better by > 0.5 dB on "
        f"{(everything > 0.5).sum()}, worse on {(everything < -0.5).sum()}"
    )


if __name__ == "__main__":
    main()
