"""The command line's options come from the package: choices from its tuples, defaults that match
the settings dataclasses, config files beside the flags, a fast ``--help``."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import typer
from typer.testing import CliRunner

from reconphys.cli import app
from reconphys.cli.data import SETTINGS_OPTIONS
from reconphys.cli.train import GS_SETTINGS
from reconphys.names import RENDER_BACKENDS

runner = CliRunner()
CONFIGS = Path(__file__).resolve().parent.parent / "configs"
SMALL = [
    "--num-gaussians",
    "300",
    "--num-anchors",
    "32",
    "--neighbors",
    "8",
    "--min-substeps",
    "10",
]


def _params(name: str) -> dict:
    command = typer.main.get_command(app)
    for part in name.split():
        command = command.commands[part]
    return {p.name: p for p in command.params}


def test_help_does_not_import_torch():
    code = (
        "import sys\n"
        "from reconphys.cli import main\n"
        "sys.argv = ['reconphys', '--help']\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        "assert 'torch' not in sys.modules, 'reconphys --help imported torch'\n"
    )
    process = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert process.returncode == 0, process.stderr
    assert "make-asset" in process.stdout


def test_simulate_accepts_every_renderer_backend(tmp_path):
    import reconphys.render  # noqa: F401  (the renderer's choices are names.RENDER_BACKENDS)

    asset = tmp_path / "asset"
    result = runner.invoke(app, ["make-asset", str(asset), "--shape", "box", *SMALL])
    assert result.exit_code == 0, result.output
    for backend in RENDER_BACKENDS:
        out = tmp_path / backend
        args = ["simulate", str(asset), "--frames", "1", "--out", str(out), "--no-render"]
        result = runner.invoke(app, [*args, "--device", "cpu", "--backend", backend])
        assert result.exit_code == 0, (backend, result.output)
    result = runner.invoke(app, [*args, "--backend", "opengl"])
    assert result.exit_code == 2
    assert "--backend: expected auto, torch, numba or gsplat, got 'opengl'" in result.output


def test_make_data_options_name_data_settings_fields():
    from reconphys.data.settings import DataSettings

    fields = {f.name for f in dataclasses.fields(DataSettings)}
    assert set(SETTINGS_OPTIONS.values()) <= fields
    assert set(SETTINGS_OPTIONS) <= set(_params("make-data"))


def test_train_gs_defaults_are_the_settings_defaults():
    from reconphys.train.gaussians import GaussianTrainSettings

    params = _params("train-gs")
    for field in dataclasses.fields(GaussianTrainSettings):
        if field.name in GS_SETTINGS and field.default is not dataclasses.MISSING:
            assert params[field.name].default == field.default, field.name


def test_predict_preview_default_is_the_pipelines():
    from reconphys.pipeline.settings import PREVIEW_FRAMES

    assert _params("predict")["preview_frames"].default == PREVIEW_FRAMES


def _capture_make_dataset(monkeypatch) -> list:
    seen = []

    def fake(settings, out, **kwargs):
        seen.append(settings)
        manifest = {"samples": []}
        return SimpleNamespace(manifest=manifest, generated=0, skipped=0, seconds=0.0)

    monkeypatch.setattr("reconphys.data.make.make_dataset", fake)
    return seen


def test_make_data_config_file_is_the_makefile_flags(monkeypatch, tmp_path):
    seen = _capture_make_dataset(monkeypatch)
    flags = ["--objects", "40", "--test-objects", "6", "--samples-per-object", "6"]
    flags += ["--test-samples-per-object", "2", "--resolution", "32", "--toss-fraction", "0"]
    for args in (flags, ["--config", str(CONFIGS / "data_small.toml")]):
        result = runner.invoke(app, ["make-data", *args, "--out", str(tmp_path / "d")])
        assert result.exit_code == 0, result.output
    assert seen[0] == seen[1] and seen[0].fingerprint() == seen[1].fingerprint()
    # a flag given beside the file wins; one left at its default does not override the file
    config = tmp_path / "c.toml"
    config.write_text('seed = 4\nobjects = 3\nsource = "meshes"\n')
    args = ["make-data", "--config", str(config), "--objects", "5", "--out", str(tmp_path / "d")]
    assert runner.invoke(app, args).exit_code == 0
    assert (seen[2].seed, seen[2].objects, seen[2].resolution) == (4, 5, 128)
    assert seen[2].source == str(Path("meshes").resolve())
    config.write_text("objects = many\n")
    result = runner.invoke(app, ["make-data", "--config", str(config), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "not valid TOML" in result.output
    config.write_text('objects = "many"\n')
    result = runner.invoke(app, ["make-data", "--config", str(config), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "c.toml [objects]: expected an integer" in result.output


def test_train_gs_config_file_and_flags(monkeypatch, tmp_path):
    seen = []
    monkeypatch.setattr(
        "reconphys.train.gaussians.train_gaussian_predictor",
        lambda settings, **kwargs: seen.append(settings),
    )
    monkeypatch.setattr("reconphys.threads.set_cpu_threads", lambda n: None)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data" / "cpu_small").mkdir(parents=True)
    makefile_flags = ["--data", "data/cpu_small", "--out", "runs/gs_cpu_small", "--steps", "1500"]
    config = ["--config", str(CONFIGS / "gs_cpu_small.toml")]
    for args in ([*makefile_flags, "--batch-size", "4"], config, [*config, "--steps", "7"]):
        result = runner.invoke(app, ["train-gs", *args, "--threads", "1", "--no-progress"])
        assert result.exit_code == 0, result.output
    assert seen[0] == seen[1]
    assert dataclasses.replace(seen[1], steps=7) == seen[2]
    result = runner.invoke(app, ["train-gs", "--out", "o"])
    assert result.exit_code == 2 and "--data: missing" in result.output
    result = runner.invoke(app, ["train-gs", *config, "--shape-weight", "0.5"])
    assert result.exit_code == 0 and seen[-1].shape_weight == 0.5, result.output
    result = runner.invoke(app, ["train-gs", *config, "--shape-weight", "-1"])
    assert result.exit_code == 2 and "--shape-weight: must be ≥ 0" in result.output
    args = ["train-gs", *config, "--depth-weight", "0.2", "--init", "runs/a/model.safetensors"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert (seen[-1].depth_weight, seen[-1].init) == (0.2, "runs/a/model.safetensors")
    assert (seen[1].depth_weight, seen[1].init) == (0.0, "")
    result = runner.invoke(app, ["train-gs", *config, "--depth-weight", "nan"])
    assert result.exit_code == 2 and "--depth-weight: must be ≥ 0" in result.output
    # the shipped crop predictor's two stages: the second starts from the first's model, with
    # the same predictor and the true distance (no scatter)
    (tmp_path / "data" / "gs_realistic").mkdir(parents=True)
    for name in ("gs_crop.toml", "gs_crop_tune.toml"):
        args = ["train-gs", "--config", str(CONFIGS / name), "--threads", "1", "--no-progress"]
        assert runner.invoke(app, args).exit_code == 0
    base, tune = seen[-2:]
    assert tune.init == f"{base.out}/model.safetensors" and tune.predictor == base.predictor
    assert (base.depth_noise, tune.depth_noise) == (0.1, 0.0)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        ([], "--split test --methods trivial --budget-seconds 60 --out {out}"),
        (
            ["--seed", "3", "--methods", "trivial,trivial", "--budget-seconds", "2.5"],
            "--split test --methods trivial --budget-seconds 2.5 --seed 3 --out {out}",
        ),
        (
            ["--device", "auto", "--limit", "2", "--emd-points", "16", "--sheet-samples", "1"],
            "--split test --methods trivial --budget-seconds 60 --limit 2 --device auto "
            "--emd-points 16 --out {out}",
        ),
    ],
)
def test_evaluate_report_states_the_command(monkeypatch, tmp_path, args, expected):
    seen = {}

    def fake_report(results, out, data, split, limit, settings, command, overwrite):
        seen["command"] = command
        return {"methods": {}}

    class FakeEvalSet:
        def __init__(self, *args):
            self.settings = {}

        def __len__(self):
            return 1

    monkeypatch.setattr("reconphys.eval.samples.EvalSet", FakeEvalSet)
    monkeypatch.setattr(
        "reconphys.eval.evaluate.run_evaluation", lambda *a, **k: SimpleNamespace(seconds=0)
    )
    monkeypatch.setattr("reconphys.eval.report.write_report", fake_report)
    out, data = tmp_path / "report", tmp_path / "data"
    base = ["evaluate", "--data", str(data), "--out", str(out), "--methods", "trivial"]
    result = runner.invoke(app, [*base, *args])
    assert result.exit_code == 0, result.output
    assert seen["command"] == f"reconphys evaluate --data {data} " + expected.format(out=out)
