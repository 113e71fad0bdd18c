"""``reconphys evaluate``: compare methods on a dataset split (docs/evaluation.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import InputError
from ._common import DEVICE_CHOICES, check_positive, command_line, user_errors

app = typer.Typer()

# How the report states the command: these options always, in this order ...
REPORT_ALWAYS = ("data", "split", "methods", "budget_seconds")
# ... these when they differ from their declared defaults, then --out.
REPORT_IF_CHANGED = (
    "limit",
    "shard",
    "device",
    "seed",
    "chamfer_points",
    "emd_points",
    "threads",
    "model",
)


@app.command("evaluate")
@user_errors
def evaluate(
    ctx: typer.Context,
    data: Path = typer.Option(..., "--data", help="Dataset folder written by make-data."),
    out: Path = typer.Option(..., "--out", help="Report folder to write."),
    split: str = typer.Option("test", help="test, train or all."),
    methods: str = typer.Option(
        "trivial,oracle,springgaus,appearance", help="Comma-separated methods to compare."
    ),
    limit: int = typer.Option(None, help="Evaluate only the first N samples of the split."),
    shard: str = typer.Option(
        None,
        help="I/N: only every N-th of those samples from the I-th, to run N evaluations in "
        "parallel (benchmarks/sharded_evaluate.py joins their per_sample.csv).",
    ),
    budget_seconds: float = typer.Option(
        60.0, help="Seconds per scene for the per-scene fits (springgaus, appearance)."
    ),
    device: str = typer.Option("cpu", help=f"{DEVICE_CHOICES} (fits, simulation, rendering)."),
    seed: int = typer.Option(0, help="Seed of the per-scene fits."),
    chamfer_points: int = typer.Option(8192, help="Points per set for the Chamfer distance."),
    emd_points: int = typer.Option(2048, help="Points per set for the EMD (exact matching)."),
    sheet_samples: int = typer.Option(2, help="Samples shown in the contact sheet."),
    threads: int = typer.Option(0, help="torch CPU threads (0: torch's default)."),
    model: Path = typer.Option(
        None,
        help="Trained predictor of the reconphys method: a .safetensors file or a `reconphys "
        "train` output folder (default: $RECONPHYS_MODEL, else the shipped model).",
    ),
    overwrite: bool = typer.Option(False, help="Replace an existing report folder."),
):
    """Compare methods on a split of a dataset: the paper's Tables 1–3 with the trivial control.

    Writes OUT/metrics.json, OUT/report.md, OUT/summary.csv, OUT/per_sample.csv,
    OUT/per_frame.csv and figures (PSNR per frame, attribute scatter, contact sheet)."""
    from ..data.plan import parse_shard
    from ..devices import resolve_device
    from ..eval.evaluate import EvalSettings, run_evaluation
    from ..eval.methods import parse_methods
    from ..eval.report import check_output, write_report
    from ..eval.samples import EvalSet

    names = parse_methods(methods)
    check_positive(budget_seconds, "--budget-seconds")
    for value, flag in ((chamfer_points, "--chamfer-points"), (emd_points, "--emd-points")):
        if value < 1:
            raise InputError(f"must be ≥ 1, got {value}", field=flag)
    if sheet_samples < 0 or threads < 0:
        flag = "--sheet-samples" if sheet_samples < 0 else "--threads"
        raise InputError("must be ≥ 0", field=flag)
    if model is not None and not {
        "reconphys",
        "reconphys_search",
        "reconphys_ff",
        "reconphys_video",
    } & set(names):
        raise InputError("only the reconphys methods use a model; add one to --methods", "--model")
    torch_device = resolve_device(device)
    check_output(out, overwrite)
    eval_set = EvalSet(data, split, limit, parse_shard(shard))
    if threads:
        from ..threads import set_cpu_threads

        set_cpu_threads(threads)
    settings = EvalSettings(
        methods=tuple(names),
        budget_seconds=budget_seconds,
        device=str(torch_device),
        seed=seed,
        chamfer_points=chamfer_points,
        emd_points=emd_points,
        sheet_samples=sheet_samples,
        model=None if model is None else str(model),
    )
    command = command_line(
        ctx,
        "reconphys evaluate",
        (*REPORT_ALWAYS, *REPORT_IF_CHANGED, "out"),
        (*REPORT_ALWAYS, "out"),
        {"methods": ",".join(names), "budget_seconds": f"{budget_seconds:g}"},
    )
    typer.echo(f"evaluating {len(eval_set)} {split} samples with {', '.join(names)}")
    results = run_evaluation(eval_set, settings, log=typer.echo)
    document = write_report(
        results, out, str(data), split, limit, eval_set.settings, command, overwrite
    )
    for name, entry in document["methods"].items():
        recon, future = entry["reconstruction"]["psnr"], entry["future"]["psnr"]
        typer.echo(
            f"{name:<20} PSNR reconstruction "
            + ("–" if recon is None else f"{recon:.2f}")
            + " dB, future "
            + ("–" if future is None else f"{future:.2f}")
            + " dB"
        )
    typer.echo(f"report: {out / 'report.md'} ({results.seconds:.0f} s)")
