"""Run ``reconphys evaluate`` as N processes over shards of one split, then join their results.

A large evaluation (the paper's 512-px protocol, say) is one process per scene after another; on a
machine with many cores (or a GPU beside them) N processes of ``evaluate --shard I/N`` finish N
times sooner. Each shard writes its own report folder OUT/shard-I (and OUT/shard-I.log); this
script then writes OUT/per_sample.csv (every shard's rows) and OUT/summary.md: per method, the
samples scored, reconstruction and future PSNR, the MAE of log k/m, log d/m and friction beside
the trivial predictor's (ratio = trivial's MAE / the method's), how many samples' future PSNR is
above trivial's, the intervals' coverage and mean width (the shards' metrics.json, weighted by
their samples), and seconds per scene. Everything after ``--`` goes to every evaluate as it is.

    python benchmarks/sharded_evaluate.py --data data/paper512 --out ev_paper512 --shards 16 \\
        --threads 1 -- --methods trivial,reconphys,reconphys_search --device cuda --emd-points 256
    python benchmarks/sharded_evaluate.py --out ev_paper512 --merge-only   # join existing shards
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

OBSERVABLES = ("log_k_over_m", "log_d_over_m", "friction")


def observables(row: dict, prefix: str) -> tuple[float, float, float]:
    m = float(row[f"{prefix}_mass"])
    k, d = float(row[f"{prefix}_stiffness"]), float(row[f"{prefix}_damping"])
    return math.log(k / m), math.log(d / m), float(row[f"{prefix}_friction"])


def run_shards(data: Path, out: Path, shards: int, threads: int, extra: list[str]) -> None:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.setdefault("NUMBA_NUM_THREADS", str(threads))
    started, procs = time.perf_counter(), []
    out.mkdir(parents=True, exist_ok=True)
    for i in range(shards):
        command = [sys.executable, "-m", "reconphys.cli", "evaluate", "--data", str(data)]
        command += ["--shard", f"{i}/{shards}", "--threads", str(threads)]
        command += ["--out", str(out / f"shard-{i}"), *extra]
        log = open(out / f"shard-{i}.log", "w")  # closed below
        procs.append(
            (subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env), log)
        )
    failed = []
    for i, (proc, log) in enumerate(procs):
        if proc.wait() != 0:
            failed.append(i)
        log.close()
    print(f"{shards} shards in {time.perf_counter() - started:.0f} s", flush=True)
    for i in failed:
        tail = (out / f"shard-{i}.log").read_text().strip().splitlines()[-3:]
        print(f"shard {i} failed: " + " | ".join(tail), file=sys.stderr)


def merge(out: Path) -> str:
    folders = sorted(
        (p for p in out.glob("shard-*") if p.is_dir() and (p / "per_sample.csv").exists()),
        key=lambda p: int(p.name.split("-")[1]),
    )
    if not folders:
        raise SystemExit(f"{out}: no shard-I/per_sample.csv to join")
    rows, intervals, settings = [], {}, None
    for folder in folders:
        with open(folder / "per_sample.csv", newline="") as f:
            rows += list(csv.DictReader(f))
        document = json.loads((folder / "metrics.json").read_text())
        settings = settings or document["settings"]
        for name, entry in document["methods"].items():
            for key, value in (entry.get("intervals") or {}).items():
                acc = intervals.setdefault(name, {}).setdefault(key, [0.0, 0.0, 0])
                acc[0] += value["coverage"] * value["samples"]
                acc[1] += value["mean_width"] * value["samples"]
                acc[2] += value["samples"]
    with open(out / "per_sample.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    scored = [r for r in rows if not r["failure"]]
    by = {m: {r["sample"]: r for r in scored if r["method"] == m} for m in methods}

    def mean(values):
        values = [v for v in values if v == v]
        return sum(values) / len(values) if values else float("nan")

    def mae(method, j):
        return mean(
            abs(observables(r, "predicted")[j] - observables(r, "true")[j])
            for r in by[method].values()
        )

    trivial = by.get("trivial", {})
    lines = [
        f"# {len(folders)} shards of `{settings['data']}` ({settings['split']}), "
        f"{settings['resolution']} px; {settings['machine']}",
        "",
        "| method | samples | recon. PSNR | future PSNR | future > trivial | MAE log k/m | "
        "MAE log d/m | MAE f | ratio to trivial | coverage (width) | s / scene |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in methods:
        got = by[m]
        if not got:
            lines.append(f"| {m} | 0 | | | | | | | | | |")
            continue
        errors = [mae(m, j) for j in range(3)]
        ratio, ahead = "", ""
        if trivial and m != "trivial":
            base = [mae("trivial", j) for j in range(3)]
            ratio = " / ".join(
                f"{b / e:.2f}×" if e > 0 else "–" for b, e in zip(base, errors, strict=True)
            )
            pairs = [(r, trivial[s]) for s, r in got.items() if s in trivial]
            ahead = f"{sum(float(r['future_psnr']) > float(t['future_psnr']) for r, t in pairs)}"
            ahead += f"/{len(pairs)}"
        cover = intervals.get(m)
        cover_text = (
            " / ".join(f"{c / n:.0%} ({w / n:.2f})" for c, w, n in cover.values()) if cover else ""
        )
        recon = mean(float(r["reconstruction_psnr"]) for r in got.values())
        future = mean(float(r["future_psnr"]) for r in got.values())
        lines.append(
            f"| {m} | {len(got)} | {recon:.2f} | {future:.2f} | {ahead} | "
            + " | ".join(f"{e:.3f}" for e in errors)
            + f" | {ratio} | {cover_text} | {mean(float(r['seconds']) for r in got.values()):.1f} |"
        )
    failures = [r for r in rows if r["failure"]]
    if failures:
        lines += ["", f"{len(failures)} failures: " + "; ".join(r["failure"] for r in failures[:5])]
    text = "\n".join(lines) + "\n"
    (out / "summary.md").write_text(text)
    return text


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="dataset folder (make-data)")
    parser.add_argument("--out", type=Path, required=True, help="folder of the shards' reports")
    parser.add_argument("--shards", type=int, default=max(1, (os.cpu_count() or 2) // 2))
    parser.add_argument("--threads", type=int, default=1, help="torch/numba threads per shard")
    parser.add_argument("--merge-only", action="store_true", help="join existing shards only")
    args = parser.parse_args(argv)
    if not args.merge_only:
        if args.data is None:
            parser.error("--data is needed unless --merge-only")
        run_shards(args.data, args.out, args.shards, args.threads, extra)
    print(merge(args.out), end="")


if __name__ == "__main__":
    main()
