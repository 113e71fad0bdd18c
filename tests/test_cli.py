"""The command line as a user runs it: outputs, help, and one-line errors with exit code 2."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from reconphys import __version__
from reconphys.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def asset_dir(small_asset_dir):
    return small_asset_dir


def test_version_and_help():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output
    for command in ("demo", "make-asset", "simulate", "inspect"):
        result = runner.invoke(app, [command, "--help"])
        assert result.exit_code == 0 and "Usage" in result.output, command


def test_simulate_writes_trajectory_without_render(asset_dir, tmp_path):
    result = runner.invoke(
        app,
        [
            "simulate",
            str(asset_dir),
            "--frames",
            "7",
            "--out",
            str(tmp_path / "o"),
            "--no-render",
            "--device",
            "cpu",
        ],
    )
    assert result.exit_code == 0, result.output
    with np.load(tmp_path / "o" / "trajectory.npz") as data:
        assert data["anchors"].shape == (8, 48, 3)
        assert data["anchors"].dtype == np.float32
        assert int(data["substeps_used"]) >= 10
        assert np.isfinite(data["anchors"]).all()
    assert not (tmp_path / "o" / "simulation.mp4").exists()


def test_simulate_renders_an_mp4(asset_dir, tmp_path):
    result = runner.invoke(
        app,
        [
            "simulate",
            str(asset_dir),
            "--frames",
            "3",
            "--out",
            str(tmp_path / "o"),
            "--resolution",
            "32",
            "--save-gaussians",
        ],
    )
    assert result.exit_code == 0, result.output
    import imageio.v2 as imageio

    frames = imageio.mimread(tmp_path / "o" / "simulation.mp4")
    assert len(frames) == 4 and frames[0].shape == (32, 32, 3)
    assert max(f.max() for f in frames) > 50, "the object must be visible"
    with np.load(tmp_path / "o" / "trajectory.npz") as data:
        assert data["gaussian_means"].shape == (4, 400, 3)


def test_inspect_reports_the_physics(asset_dir):
    result = runner.invoke(app, ["inspect", str(asset_dir)])
    assert result.exit_code == 0, result.output
    assert '"total_mass_kg": 48.0' in result.output and "substeps_for_stability" in result.output


def test_missing_asset_is_one_line_error_and_writes_nothing(tmp_path):
    result = runner.invoke(app, ["simulate", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert result.output.strip().startswith("error:") and "nope" in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_negative_mass_in_physics_json_is_rejected(asset_dir, tmp_path):
    import json
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(asset_dir, bad)
    physics = json.loads((bad / "physics.json").read_text())
    physics["mass"] = -2.0
    (bad / "physics.json").write_text(json.dumps(physics))
    result = runner.invoke(app, ["simulate", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "physics.json [mass]" in result.output
    assert not (tmp_path / "o").exists()


def test_bad_arguments_are_one_line_errors(tmp_path):
    result = runner.invoke(app, ["make-asset", str(tmp_path / "a"), "--shape", "dodecahedron"])
    assert result.exit_code == 2 and "shape" in result.output and "sphere" in result.output
    result = runner.invoke(
        app, ["make-asset", str(tmp_path / "a"), "--shape", "box", "--mass", "-1"]
    )
    assert result.exit_code == 2 and "--mass" in result.output
    result = runner.invoke(
        app, ["make-asset", str(tmp_path / "a"), "--mesh", str(tmp_path / "x.obj")]
    )
    assert result.exit_code == 2 and "x.obj" in result.output
    assert not (tmp_path / "a").exists()


def test_real_process_prints_no_traceback(tmp_path):
    process = subprocess.run(
        [sys.executable, "-m", "reconphys.cli", "inspect", str(tmp_path / "missing")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert process.returncode == 2
    assert "Traceback" not in process.stderr
    assert process.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'missing'}: asset folder not found"
    ]
