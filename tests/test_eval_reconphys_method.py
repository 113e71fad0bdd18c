"""The ``reconphys`` method of ``evaluate``: a trained predictor's attributes on the true geometry.

A random tiny predictor (not the shipped model) on a one-sample dataset at 16 px. The module runs
torch and Numba on one thread: on a 2-core machine shared with other jobs, more threads than free
cores slow the simulation many times over.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace

import pytest
import torch
from helpers import train_tiny_gaussian_predictor
from typer.testing import CliRunner

from reconphys.cli import app
from reconphys.data import make_dataset, make_settings
from reconphys.eval.methods import METHODS, MethodOptions
from reconphys.eval.methods.base import INPUT_FRAMES
from reconphys.eval.samples import EvalSet
from reconphys.models import shipped
from reconphys.models.physics_predictor import PhysicsPredictor, PredictorConfig
from reconphys.models.shipped import ENV_VAR, load_predictor, model_metadata, save_predictor
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.threads import set_cpu_threads

runner = CliRunner()
TINY = PredictorConfig(
    encoder_channels=(4,),
    token_channels=8,
    trunk_blocks=1,
    attention_heads=2,
    mlp_hidden=(8,),
    num_frames=4,
    resolution=16,
)


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    yield
    set_cpu_threads(threads)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("method") / "data"
    settings = make_settings(
        objects=0,
        test_objects=1,
        test_samples_per_object=1,
        resolution=16,
        num_gaussians=200,
        num_anchors=24,
        num_neighbors=6,
        min_substeps=20,
        seed=5,
    )
    make_dataset(settings, root, workers=1, device="cpu")
    return root


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    torch.manual_seed(3)
    path = tmp_path_factory.mktemp("model") / "tiny.safetensors"
    return save_predictor(PhysicsPredictor(TINY), path, model_metadata(TINY, 1, 0.03))


def test_predicts_from_the_model_view_on_the_true_geometry(dataset, model_path):
    sample = EvalSet(dataset, "test").load(0)
    options = MethodOptions(trivial=EvalSet(dataset, "test").trivial_attributes(), model=model_path)
    method = METHODS["reconphys"](options)
    assert method.uses_ground_truth  # reported as an upper bound, beside trivial
    prediction = method.predict(sample)
    expected = load_predictor(model_path).predict(sample.frames[1:2])  # view 1, as trained
    for name, value in prediction.attributes.items():
        assert value == pytest.approx(float(expected[name][0]), rel=1e-6)
    assert prediction.attributes != sample.attributes
    truth = sample.true_asset
    assert torch.equal(prediction.asset.x0, truth.x0) and torch.equal(prediction.asset.v0, truth.v0)
    assert prediction.asset.gaussians is truth.gaussians


def test_feed_forward_method_uses_no_ground_truth(dataset, model_path, tmp_path, monkeypatch):
    gs = train_tiny_gaussian_predictor(dataset, tmp_path / "gs")
    monkeypatch.setenv("RECONPHYS_GS_MODEL", str(gs))
    sample = EvalSet(dataset, "test").load(0)
    options = MethodOptions(trivial=EvalSet(dataset, "test").trivial_attributes(), model=model_path)
    method = METHODS["reconphys_ff"](options)
    assert not method.uses_ground_truth  # reported without the upper-bound mark
    prediction = method.predict(sample)
    expected = load_predictor(model_path).predict(sample.frames[1:2])
    for name, value in prediction.attributes.items():  # same physics network, same view
        assert value == pytest.approx(float(expected[name][0]), rel=1e-5)
    asset, truth = prediction.asset, sample.true_asset
    assert asset.gaussians.num_gaussians <= 16 * 16  # one per object pixel of the 16-px view
    assert asset.gaussians.num_gaussians != truth.gaussians.num_gaussians
    assert not torch.equal(asset.v0, truth.v0)  # estimated, not the truth
    assert prediction.intervals is None  # one network alone gives none (an ensemble would)

    video = METHODS["reconphys_video"](options)  # predict's default: then the search
    assert not video.uses_ground_truth
    searched = video.predict(sample)
    assert set(searched.intervals) == {"log_k_over_m", "log_d_over_m", "friction"}
    assert torch.equal(searched.asset.x0, asset.x0)  # the same predicted geometry
    assert searched.info["search"] > 0  # predict's timing of the search


def test_evaluate_command_reports_reconphys_beside_trivial(dataset, model_path, tmp_path):
    out = tmp_path / "report"
    args = [
        "evaluate",
        "--data",
        str(dataset),
        "--out",
        str(out),
        "--methods",
        "trivial,reconphys,reconphys_search",
        "--model",
        str(model_path),
        "--emd-points",
        "32",
        "--chamfer-points",
        "64",
        "--sheet-samples",
        "0",
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert list(metrics["methods"]) == ["trivial", "reconphys", "reconphys_search"]
    # per_sample.csv carries each sample's intervals: the summary's coverage follows from them
    with open(out / "per_sample.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    searched = [r for r in rows if r["method"] == "reconphys_search"]
    assert searched and all(r["interval_friction_hi"] == "" for r in rows if r not in searched)
    for i, key in enumerate(("log_k_over_m", "log_d_over_m", "friction")):
        inside = []
        for r in searched:
            mass = float(r["true_mass"])
            true = (
                math.log(float(r["true_stiffness"]) / mass),
                math.log(float(r["true_damping"]) / mass),
                float(r["true_friction"]),
            )[i]
            lo, hi = float(r[f"interval_{key}_lo"]), float(r[f"interval_{key}_hi"])
            assert lo <= hi
            inside.append(lo <= true <= hi)
        coverage = metrics["methods"]["reconphys_search"]["intervals"][key]["coverage"]
        assert sum(inside) / len(inside) == pytest.approx(coverage)
    entry = metrics["methods"]["reconphys"]
    assert entry["upper_bound"] and str(model_path) in entry["description"]
    assert entry["reconstruction"]["psnr"] is not None and entry["future"]["psnr"] is not None
    assert "beats_trivial" in entry
    assert "reconphys †" in (out / "report.md").read_text()


def test_evaluate_model_errors_are_one_line(dataset, tmp_path, monkeypatch):
    def run(*extra):
        out = tmp_path / "report"
        result = runner.invoke(app, ["evaluate", "--data", str(dataset), "--out", str(out), *extra])
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert result.exit_code == 2, result.output
        return lines[-1]

    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setattr(shipped, "SHIPPED_PATH", tmp_path / "physics_predictor.safetensors")
    line = run("--methods", "trivial,reconphys")
    assert line.startswith("error: ") and "no trained physics predictor" in line
    assert "reconphys train" in line
    line = run("--methods", "reconphys", "--model", str(tmp_path / "none.safetensors"))
    assert "model file not found" in line
    line = run("--methods", "trivial", "--model", str(tmp_path / "none.safetensors"))
    assert "--model: only the reconphys methods use a model" in line
    long = replace(TINY, num_frames=INPUT_FRAMES + 1)  # it would read the future window
    path = save_predictor(PhysicsPredictor(long), tmp_path / "long.safetensors",
                          model_metadata(long, 1, 0.03))  # fmt: skip
    line = run("--methods", "reconphys_search", "--model", str(path))
    assert f"the model reads {INPUT_FRAMES + 1} frames" in line and "future" in line


def test_search_method_starts_from_the_network_on_the_true_geometry(dataset, model_path):
    """``reconphys_search``: the network's attributes, then the search (pipeline/search.py, tested
    against the truth in test_pipeline_search.py); mass and geometry as ``reconphys``."""
    sample = EvalSet(dataset, "test").load(0)
    options = MethodOptions(trivial=EvalSet(dataset, "test").trivial_attributes(), model=model_path)
    network = METHODS["reconphys"](options).predict(sample)
    method = METHODS["reconphys_search"](options)
    assert method.uses_ground_truth
    prediction = method.predict(sample)
    found = prediction.attributes
    if found["mass"] != network.attributes["mass"]:  # only to hold k/m or d/m inside the ranges
        ends = [(n, v) for n in ("stiffness", "damping") for v in ATTRIBUTE_RANGES[n]]
        assert any(found[n] == pytest.approx(v) for n, v in ends)
    assert set(prediction.intervals) == {"log_k_over_m", "log_d_over_m", "friction"}
    assert prediction.asset.gaussians is sample.true_asset.gaussians
    assert torch.equal(prediction.asset.v0, sample.true_asset.v0)


def test_interval_coverage_and_width_in_the_summary():
    """evaluate's interval columns: the share of samples whose interval holds the true observable
    (log k/m, log d/m from the true attributes) and the mean width."""
    import math

    import numpy as np

    from reconphys.eval.evaluate import SampleResult
    from reconphys.eval.summary import interval_summary

    truth = {"mass": 2.0, "stiffness": 200.0, "damping": 1.0, "friction": 0.4}
    k, d = math.log(100.0), math.log(0.5)

    def result(name, intervals, failure=None):
        nan = np.full(3, math.nan)
        return SampleResult(name, "s", "o", nan, nan, None, nan, nan, truth, truth, 1.0,
                            failure=failure, intervals=intervals)  # fmt: skip

    rows = [
        result(
            "a",
            {
                "log_k_over_m": [k - 0.1, k + 0.1],
                "log_d_over_m": [d + 0.1, d + 0.3],
                "friction": [0.3, 0.5],
            },
        ),
        result(
            "b",
            {
                "log_k_over_m": [k + 0.1, k + 0.5],
                "log_d_over_m": [d - 1.0, d + 1.0],
                "friction": [0.0, 0.2],
            },
        ),
        result(
            "c",
            {"log_k_over_m": [0.0, 0.0], "log_d_over_m": [0.0, 0.0], "friction": [0.0, 0.0]},
            failure="simulation failed",
        ),
        result("d", None),
    ]
    summary = interval_summary(rows)
    assert summary["log_k_over_m"] == {"coverage": 0.5, "mean_width": pytest.approx(0.3),
                                       "samples": 2}  # fmt: skip
    assert summary["log_d_over_m"]["coverage"] == 0.5
    assert summary["friction"]["coverage"] == 0.5
    assert summary["friction"]["mean_width"] == pytest.approx(0.2)
    assert interval_summary([result("d", None)]) is None
