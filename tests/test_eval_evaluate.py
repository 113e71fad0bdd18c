"""Evaluation end to end on a tiny generated dataset: oracle, trivial, springgaus, the command.

The dataset (2 test objects × 1 sample, no training split, 32 px, 300 Gaussians, 64 anchors) is
made once per module; torch runs on one thread meanwhile (CPU-only machines shared with other
jobs slow down badly with more).
"""

from __future__ import annotations

import json
import math
import statistics

import pytest
import torch
from helpers import make_tiny_dataset
from typer.testing import CliRunner

from reconphys.cli import app
from reconphys.eval.evaluate import EvalSettings, evaluate_prediction
from reconphys.eval.lpips import find_lpips_weights
from reconphys.eval.methods import METHODS, MethodOptions, Prediction, springgaus
from reconphys.eval.methods.springgaus import (
    SpringGausMethod,
    SpringGausSettings,
    SpringGausTruthMethod,
)
from reconphys.eval.samples import FALLBACK_MEDIANS, EvalSet, TrivialAttributes

runner = CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("eval") / "data", test_objects=2, seed=3)


@pytest.fixture(scope="module")
def eval_set(dataset):
    return EvalSet(dataset, "test")


def test_shards_split_the_samples_without_overlap(dataset, eval_set):
    """evaluate --shard I/N: every N-th sample from the I-th; together, each sample once."""
    assert len(eval_set) >= 2
    shards = [EvalSet(dataset, "test", shard=(i, 2)).ids for i in range(2)]
    assert sorted(shards[0] + shards[1]) == sorted(eval_set.ids)
    assert shards[1] == eval_set.ids[1::2]
    assert EvalSet(dataset, "test", limit=2, shard=(1, 2)).ids == eval_set.ids[1:2]


def test_samples_carry_frames_cameras_and_true_geometry(eval_set):
    assert len(eval_set) == 2
    sample = eval_set.load(0)
    v, t, h, w, c = sample.frames.shape
    assert (v, t, h, w, c) == (4, 30, 32, 32, 3)
    assert sample.cameras.num_cameras == 4
    assert sample.gaussian_means.shape == (30, sample.true_asset.gaussians.num_gaussians, 3)
    assert torch.equal(sample.anchors[0], sample.true_asset.x0)
    assert torch.allclose(sample.gaussian_means[0], sample.true_asset.gaussians.means)
    assert set(sample.attributes) == {"mass", "stiffness", "damping", "friction"}


def test_oracle_reproduces_the_truth(eval_set):
    options = MethodOptions(trivial=eval_set.trivial_attributes())
    settings = EvalSettings()
    for position in range(len(eval_set)):
        sample = eval_set.load(position)
        prediction = METHODS["oracle"](options).predict(sample)
        result = evaluate_prediction("oracle", sample, prediction, 0.0, settings, None, False)
        assert result.failure is None
        assert min(result.psnr) >= 40.0, result.psnr  # 8-bit frames: ≈ 59 dB
        assert max(result.cd) < 1e-6, result.cd
        assert max(result.emd) < 1e-3  # 300 Gaussians < 2048: no subsampling, exact matching
        assert result.predicted_attributes == pytest.approx(sample.attributes)


def test_trivial_uses_training_medians_or_the_documented_fallback(eval_set):
    fallback = eval_set.trivial_attributes()  # this folder has no training split
    assert fallback.values == FALLBACK_MEDIANS
    assert FALLBACK_MEDIANS == {"mass": 3.1, "stiffness": 605.0, "damping": 2.55, "friction": 0.5}
    assert "no training split" in fallback.source

    manifest = eval_set.dataset.manifest
    saved = list(manifest["samples"])
    train = [
        {"split": "train", "attributes": {"mass": m, "stiffness": k, "damping": d, "friction": f}}
        for m, k, d, f in [(1.0, 100.0, 0.5, 0.1), (2.0, 900.0, 4.0, 0.9), (5.0, 300.0, 1.0, 0.3)]
    ]
    try:
        manifest["samples"] = saved + train
        medians = eval_set.trivial_attributes()
    finally:
        manifest["samples"] = saved
    for name in FALLBACK_MEDIANS:
        assert medians.values[name] == statistics.median(a["attributes"][name] for a in train)
    assert medians.source == "median of the 3 training samples"

    sample = eval_set.load(0)
    asset = METHODS["trivial"](MethodOptions(trivial=medians)).predict(sample).asset
    assert asset.physics.stiffness == 300.0 and asset.physics.mass == 2.0
    assert torch.equal(asset.x0, sample.true_asset.x0)  # true geometry: labelled an upper bound
    assert METHODS["trivial"].geometry == "ground truth"


@pytest.mark.parametrize("position", [0, 1])
def test_springgaus_improves_on_its_initial_guess(eval_set, monkeypatch, position):
    """A simple case: a perfect frame-0 reconstruction (the true Gaussians stand in for the
    static fit, which the command test exercises) and a prior 20× too stiff, so that the object
    bounces where it should squash. Three epochs of the dynamic stage must move log(k/m) well
    towards the truth and fit the input frames better than the prior on the same geometry."""
    sample = eval_set.load(position)
    truth = sample.attributes
    perfect = (sample.true_asset.gaussians, {"static_iterations": 0}, 0.0, False)
    monkeypatch.setattr(springgaus, "cached_static_fit", lambda *args: perfect)
    prior = {**truth, "stiffness": truth["stiffness"] * 20}
    options = MethodOptions(trivial=TrivialAttributes(prior, "test prior"), budget_seconds=1e4)
    settings = SpringGausSettings(
        velocity_iterations=10, dynamic_epochs=3, lr_attributes=0.15, min_substeps=20
    )
    prediction = SpringGausMethod(options, settings).predict(sample)
    assert prediction.info["dynamic_epochs"] == 3
    assert prediction.initial_guess.physics.stiffness == pytest.approx(prior["stiffness"])
    assert prediction.attributes["mass"] == prior["mass"]  # unobservable: kept at the prior

    def log_k_over_m(a):
        return math.log(a["stiffness"] / a["mass"])

    start_error = abs(log_k_over_m(prior) - log_k_over_m(truth))  # log(20) ≈ 3
    final_error = abs(log_k_over_m(prediction.attributes) - log_k_over_m(truth))
    assert final_error < start_error - 1.0, (start_error, final_error)
    eval_settings = EvalSettings(emd_points=64)
    final = evaluate_prediction("s", sample, prediction, 0.0, eval_settings, None, False)
    start = Prediction(asset=prediction.initial_guess)
    initial = evaluate_prediction("i", sample, start, 0.0, eval_settings, None, False)
    assert final.psnr[:20].mean() > initial.psnr[:20].mean() + 0.5, (final.psnr, initial.psnr)


def test_springgaus_gt_fits_attributes_on_the_true_geometry(eval_set):
    """springgaus_gt starts where trivial is (the prior on the true asset) and only fits the
    attributes: with a prior 20× too stiff, two epochs move log(k/m) well towards the truth."""
    sample = eval_set.load(0)
    truth = sample.attributes
    prior = {**truth, "stiffness": truth["stiffness"] * 20}
    options = MethodOptions(trivial=TrivialAttributes(prior, "test prior"), budget_seconds=1e4)
    method = SpringGausTruthMethod(
        options, SpringGausSettings(dynamic_epochs=2, lr_attributes=0.15, min_substeps=20)
    )
    assert method.uses_ground_truth
    prediction = method.predict(sample)
    assert prediction.initial_guess is None  # its starting point is the trivial row itself
    assert prediction.info["dynamic_epochs"] == 2
    assert torch.equal(prediction.asset.x0, sample.true_asset.x0)
    assert torch.equal(prediction.asset.v0, sample.true_asset.v0)
    assert prediction.attributes["mass"] == prior["mass"]

    def log_k_over_m(a):
        return math.log(a["stiffness"] / a["mass"])

    start_error = abs(log_k_over_m(prior) - log_k_over_m(truth))
    final_error = abs(log_k_over_m(prediction.attributes) - log_k_over_m(truth))
    assert final_error < start_error - 1.0, (start_error, final_error)


def _invoke(args):
    return runner.invoke(app, ["evaluate", *args])


def test_evaluate_command_writes_the_report(dataset, tmp_path):
    out = tmp_path / "report"
    result = _invoke(
        [
            "--data",
            str(dataset),
            "--out",
            str(out),
            "--limit",
            "1",
            "--budget-seconds",
            "3",
            "--emd-points",
            "256",
            "--device",
            "cpu",
        ]
    )
    assert result.exit_code == 0, result.output
    names = (
        "metrics.json",
        "report.md",
        "summary.csv",
        "per_sample.csv",
        "per_frame.csv",
        "psnr_per_frame.png",
        "attributes_scatter.png",
        "contact_sheet.png",
    )
    for name in names:
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["samples"] == 1
    assert set(metrics["settings"]) >= {"split", "methods", "budget_seconds", "windows", "trivial"}
    expected_rows = ["trivial", "oracle", "springgaus", "springgaus_initial", "appearance"]
    assert list(metrics["methods"]) == expected_rows
    lpips_available = find_lpips_weights() is not None
    for entry in metrics["methods"].values():
        for window in ("reconstruction", "future"):
            assert set(entry[window]) == {"psnr", "ssim", "lpips", "cd", "emd"}
            assert (entry[window]["lpips"] is None) != lpips_available
        assert set(entry["attribute_mae"]) == {
            "mass",
            "stiffness",
            "damping",
            "friction",
            "log_k_over_m",
            "log_d_over_m",
        }
        assert "seconds_per_scene" in entry
    oracle = metrics["methods"]["oracle"]
    assert oracle["reconstruction"]["psnr"] >= 40 and oracle["future"]["cd"] < 1e-6
    assert oracle["upper_bound"] and metrics["methods"]["trivial"]["upper_bound"]
    assert not metrics["methods"]["springgaus"]["upper_bound"]
    appearance = metrics["methods"]["appearance"]
    assert appearance["reconstruction"]["psnr"] is not None
    assert all(v is None for v in appearance["future"].values())
    assert all(v is None for v in appearance["attribute_mae"].values())
    assert metrics["methods"]["springgaus_initial"]["seconds_per_scene"] is None
    assert metrics["methods"]["springgaus"]["seconds_per_scene"] > 0
    report = (out / "report.md").read_text()
    assert "Table 1" in report and "Table 3" in report and "trivial †" in report
    assert "ground-truth geometry" in report


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--data", "{missing}"], "dataset folder not found"),
        (["--data", "{data}", "--split", "train"], "no samples in split 'train'"),
        (["--data", "{data}", "--methods", "trivial,magic"], "unknown method 'magic'"),
        (["--data", "{data}", "--split", "dev"], "expected one of test, train, all"),
        (["--data", "{data}", "--budget-seconds", "0"], "--budget-seconds"),
        (["--data", "{data}", "--shard", "2/2"], "expected I/N with 0 ≤ I < N"),
        (["--data", "{data}", "--shard", "7/9"], "shard 7/9 holds no sample"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(dataset, tmp_path, args, message):
    out = tmp_path / "report"
    args = [a.format(data=dataset, missing=tmp_path / "nope") for a in args]
    result = _invoke([*args, "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert not out.exists()
    assert not list(tmp_path.glob(".report*"))


def test_an_existing_report_is_kept_without_overwrite(dataset, tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    result = _invoke(["--data", str(dataset), "--out", str(out), "--methods", "oracle"])
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert (out / "keep.txt").read_text() == "mine"
