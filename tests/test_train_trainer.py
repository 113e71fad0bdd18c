"""The training loop at tiny size (configs/tiny.toml: 16 px, 24 anchors, 4 frames, batch 2).

Exact resume after an interruption and after SIGKILL, skipped non-finite steps, the three
objectives, the exported model, and the command's one-line errors.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import train_tiny_gaussian_predictor
from safetensors.torch import load_file
from typer.testing import CliRunner

from reconphys.cli import app
from reconphys.data import make_dataset
from reconphys.data.dataset import DropDataset
from reconphys.data.storage import read_manifest
from reconphys.errors import InputError
from reconphys.models.model_input import object_crop
from reconphys.models.shipped import load_predictor
from reconphys.threads import set_cpu_threads
from reconphys.train import trainer as trainer_module
from reconphys.train.config import load_config
from reconphys.train.data import TrainingSamples
from reconphys.train.trainer import Trainer, train

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "configs" / "tiny.toml"
runner = CliRunner()


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """torch and Numba on one thread (as tiny.toml's train.threads): on a 2-core machine shared
    with other jobs, more threads than free cores slow the simulation many times over."""
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    yield
    set_cpu_threads(threads)


def tiny(out: Path, *overrides: str):
    return load_config(TINY, [f"train.out={out}", *overrides])


def read_log(out: Path) -> dict[int, dict]:
    return {r["step"]: r for r in map(json.loads, (out / "log.jsonl").read_text().splitlines())}


def same_course(a: dict, b: dict) -> bool:
    keys = ("loss", "photometric", "attribute_error", "grad_norm", "lr", "skipped")
    return all(a[k] == b[k] for k in keys if k in a)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted 6-step run."""
    out = tmp_path_factory.mktemp("reference")
    result = train(tiny(out), progress=False, log=lambda line: None)
    assert result.step == 6 and result.first_step == 1
    return out


class Killed(Exception):
    pass


def test_resume_after_an_interruption_repeats_the_run(reference, tmp_path):
    def kill_at_5(step, record):
        if step == 5:  # after the checkpoint of step 3, with steps 4 and 5 already logged
            raise Killed

    with pytest.raises(Killed):
        train(tiny(tmp_path), progress=False, callback=kill_at_5, log=lambda line: None)
    assert sorted(read_log(tmp_path)) == [1, 2, 3, 4, 5]
    lines = []
    result = train(tiny(tmp_path), progress=False, log=lines.append)
    assert result.first_step == 4 and result.step == 6
    assert any("from step 3" in line for line in lines)
    expected, resumed = read_log(reference), read_log(tmp_path)
    assert sorted(resumed) == list(range(1, 7))  # steps 4–5 of the killed run were dropped
    assert all(same_course(expected[s], resumed[s]) for s in range(1, 7)), (expected, resumed)
    assert expected[6]["loss"] != expected[4]["loss"]  # the run moves: the comparison can fail
    a, b = load_file(reference / "model.safetensors"), load_file(tmp_path / "model.safetensors")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resume_after_sigkill(reference, tmp_path):
    """A real kill: the command is killed once step 3 is logged; the run resumes from its last
    checkpoint (every 2 steps) and reproduces the uninterrupted losses."""
    command = [
        sys.executable, "-m", "reconphys.cli", "train", str(TINY), f"train.out={tmp_path}",
        "train.steps=1000", "train.checkpoint_every=2", "--no-progress",
    ]  # fmt: skip
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    log = tmp_path / "log.jsonl"
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and process.poll() is None:
            if log.is_file() and len(log.read_text().splitlines()) >= 3:
                break
            time.sleep(0.05)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        _, stderr = process.communicate()
    assert process.returncode == -signal.SIGKILL, stderr.decode()
    assert (tmp_path / "checkpoint.pt").is_file()
    assert not list(tmp_path.glob(".*.tmp"))  # or only a temporary file that is never read
    result = train(tiny(tmp_path, "train.steps=6"), progress=False, log=lambda line: None)
    expected, resumed = read_log(reference), read_log(tmp_path)
    assert result.first_step >= 3  # after the checkpoint of step 2 (or a later one)
    assert all(same_course(expected[s], resumed[s]) for s in range(1, 7))


def test_a_non_finite_loss_skips_the_step(tmp_path, monkeypatch):
    original = trainer_module.compute_losses
    calls = []

    def nan_at_step_2(*args, **kwargs):
        terms = original(*args, **kwargs)
        calls.append(1)
        if len(calls) == 2:
            terms["loss"] = terms["loss"] * float("nan")
        return terms

    monkeypatch.setattr(trainer_module, "compute_losses", nan_at_step_2)
    weights = {}
    config = tiny(tmp_path, "objective.kind=supervised", "train.steps=3")
    run = Trainer(config, progress=False, log=lambda line: None)
    threads = []

    def snapshot(step, record):
        weights[step] = [p.detach().clone() for p in run.model.parameters()]
        threads.append(torch.get_num_threads())

    run.callback = snapshot
    before = torch.get_num_threads()
    with pytest.warns(UserWarning, match="step 2: non-finite loss"):
        run.run()
    assert threads == [1, 1, 1] and torch.get_num_threads() == before  # train.threads = 1
    log = read_log(tmp_path)
    assert [log[s]["skipped_step"] for s in (1, 2, 3)] == [False, True, False]
    assert log[3]["skipped"] == 1
    assert all(torch.equal(a, b) for a, b in zip(weights[1], weights[2], strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(weights[2], weights[3], strict=True))
    assert all(torch.isfinite(t).all() for t in load_file(tmp_path / "model.safetensors").values())


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A tiny dataset on disk made with the same settings as tiny.toml's generated one."""
    config = load_config(TINY)
    root = tmp_path_factory.mktemp("data") / "tiny"
    make_dataset(TrainingSamples(config.data).settings, root, workers=1, device="cpu")
    return root


def test_supervised_training_from_a_folder_learns_and_exports(folder, tmp_path):
    config = tiny(
        tmp_path, f"data.source={folder}", "data.num_workers=1", "objective.kind=supervised",
        "train.steps=20", "optim.lr=1e-2",
    )  # fmt: skip
    result = train(config, progress=False, log=lambda line: None)
    log = read_log(tmp_path)
    first, last = (log[1]["loss"] + log[2]["loss"]) / 2, (log[19]["loss"] + log[20]["loss"]) / 2
    assert last < 0.5 * first, (first, last)  # each pair of steps sees all 4 samples
    assert "photometric" not in log[1]
    loaded = load_predictor(tmp_path)  # a training output folder is a model path
    meta = loaded.metadata
    assert meta["input"] == {"view": 0, "frames": 4, "resolution": 16, "frame_dt": 0.03}
    training = meta["training"]
    assert training["objective"] == "supervised" and training["steps"] == 20
    assert training["geometry"].startswith("ground truth")
    assert training["data"]["source"] == str(folder.resolve()) and training["data"]["samples"] == 4
    assert set(training["attribute_medians"]) == {"mass", "stiffness", "damping", "friction"}
    frames = torch.rand(2, 4, 16, 16, 3)
    with torch.no_grad():
        expected = result.model.eval()(frames)["unit"]
    torch.testing.assert_close(loaded.predict(frames)["unit"], expected, rtol=0, atol=1e-6)


def test_mixed_objective_adds_both_terms(tmp_path):
    config = tiny(tmp_path, "objective.kind=mixed", "objective.supervised_weight=0.5",
                  "train.steps=1")  # fmt: skip
    train(config, progress=False, log=lambda line: None)
    record = read_log(tmp_path)[1]
    assert record["photometric"] > 0 and record["supervised"] > 0
    total = record["photometric"] + 0.5 * record["supervised"]
    assert record["loss"] == pytest.approx(total, rel=1e-6)
    assert json.loads((tmp_path / "model.json").read_text())["training"]["objective"] == "mixed"


def test_init_starts_from_a_trained_model(reference, tmp_path):
    """train.init loads a model's weights (fine-tuning); a mismatched network is refused."""
    config = tiny(tmp_path / "tuned", f"train.init={reference}", "objective.kind=supervised",
                  "train.steps=1", "optim.lr=1e-30")  # fmt: skip
    result = train(config, progress=False, log=lambda line: None)
    start = load_file(str(reference / "model.safetensors"))
    for name, value in result.model.state_dict().items():  # one step of lr 1e-30 moves nothing
        torch.testing.assert_close(value, start[name], rtol=1e-6, atol=1e-12)
    init = load_predictor(tmp_path / "tuned").metadata["training"]["init"]
    assert init["objective"] == "self_supervised" and init["steps"] == 6
    other = tiny(tmp_path / "other", f"train.init={reference}", "model.trunk_blocks=2")
    with pytest.raises(InputError, match="predictor config differs"):
        train(other, progress=False, log=lambda line: None)
    assert not (tmp_path / "other").exists()  # checked before the output folder is made


# --- the command ------------------------------------------------------------------------------


def test_train_command_runs_resumes_and_logs(tmp_path):
    out = tmp_path / "run"
    args = ["train", str(TINY), f"train.out={out}", "train.steps=2", "train.tensorboard=true"]
    result = runner.invoke(app, [*args, "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "trained 2 steps" in result.output and "model.safetensors" in result.output
    for name in ("checkpoint.pt", "log.jsonl", "config.json", "model.safetensors", "model.json"):
        assert (out / name).is_file(), name
    record = read_log(out)[2]
    assert {"loss", "lr", "grad_norm", "samples_per_s", "seconds", "skipped"} <= set(record)
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        pass
    else:
        assert list((out / "tensorboard").glob("events.out.tfevents.*"))

    again = runner.invoke(app, [*args, "--no-progress"])
    assert again.exit_code == 0 and "nothing to do" in again.output
    other = runner.invoke(app, [*args, "optim.lr=0.5", "--no-progress"])
    assert other.exit_code == 2 and "optim.lr" in other.output and "--overwrite" in other.output
    fresh = runner.invoke(app, [*args, "optim.lr=0.5", "--overwrite", "--no-progress"])
    assert fresh.exit_code == 0, fresh.output
    assert read_log(out)[1]["lr"] == 0.5


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{tmp}/missing.toml"], "config file not found"),
        (["{tiny}", "optim.learning_rate=1"], "optim.learning_rate: unknown key"),
        (["{tiny}", "train.steps=many"], "train.steps: expected an integer, got 'many'"),
        (["{tiny}", "data.source={tmp}/no"], "no [data.source]: dataset folder not found"),
        (["{tiny}", "data.generate.num_anchors=2"], "data.generate: --num-anchors: must be"),
        (["{tiny}", "data.geometry=guessed"], "data.geometry: expected one of true, predicted"),
        (["{tiny}", "data.gs_model=gs.safetensors"], "data.gs_model: a 3DGS predictor is only"),
        (
            ["{tiny}", "data.geometry=predicted", "data.gs_model={tmp}/gs.safetensors"],
            "gs.safetensors: 3DGS predictor not found",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    args = [a.format(tmp=tmp_path, tiny=TINY) for a in args]
    result = runner.invoke(app, ["train", *args, f"train.out={tmp_path}/out", "--no-progress"])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert not (tmp_path / "out").exists()  # nothing written


def test_plot_training_draws_the_curves(reference, tmp_path):
    import importlib.util

    from PIL import Image

    spec = importlib.util.spec_from_file_location(
        "plot_training", ROOT / "benchmarks" / "plot_training.py"
    )
    plot_training = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(plot_training)
    records = plot_training.read_log(reference)
    assert [r["step"] for r in records] == list(range(1, 7))
    path = tmp_path / "curves.png"
    plot_training.plot([("tiny", records), ("again", records)], path, "step", 3)
    with Image.open(path) as image:
        assert image.size == (60 + 480 * len(plot_training.PANELS), 520)
        assert len(image.getcolors(1 << 16)) > 10


def test_all_views_makes_each_view_its_own_video(tmp_path):
    one = TrainingSamples(tiny(tmp_path).data)
    four = TrainingSamples(tiny(tmp_path, "data.all_views=true").data)
    assert len(four) == 4 * len(one)
    items = [four[i] for i in range(4)]  # sample 0 from views 0..3
    assert torch.equal(items[0]["frames"], one[0]["frames"])
    assert torch.equal(items[0]["attributes"], items[3]["attributes"])
    poses = [item["world_to_cam"][0] for item in items]
    assert all(not torch.allclose(poses[0], p) for p in poses[1:])
    assert not torch.equal(items[0]["frames"], items[1]["frames"])
    assert [four.sample_id(i).split("/")[-1] for i in range(4)] == [f"view{v}" for v in range(4)]
    assert four.fingerprint() != one.fingerprint()  # a resumed run cannot switch silently


def test_data_objects_keeps_the_first_objects_and_supervised_skips_assets(folder, tmp_path):
    """data.objects = 1 keeps the samples of the split's first object only (a smaller training
    set held out the same way); a supervised run builds no assets; a track network trains."""
    every = TrainingSamples(tiny(tmp_path, f"data.source={folder}").data)
    first = TrainingSamples(tiny(tmp_path, f"data.source={folder}", "data.objects=1").data)
    objects = [s["object_dir"] for s in every.dataset.samples]
    assert len(set(objects)) == 2 and len(first) == objects.count(objects[0]) < len(every)
    assert {s["object_dir"] for s in first.dataset.samples} == {objects[0]}
    assert first[0]["asset"] is not None
    no_assets = TrainingSamples(tiny(tmp_path, f"data.source={folder}").data, assets=False)
    assert no_assets[0]["asset"] is None
    cached = TrainingSamples(
        tiny(tmp_path, f"data.source={folder}", "data.cache=true", "data.num_workers=0").data
    )
    again = [cached[1], cached[1]]  # decoded, then from memory (stored as uint8: exact)
    assert list(cached.cache) == [1] and cached.cache[1]["frames"].dtype == torch.uint8
    for item in again:
        assert torch.equal(item["frames"], every[1]["frames"])
        assert torch.equal(item["world_to_cam"], every[1]["world_to_cam"])
    with pytest.raises(InputError, match="num_workers = 0"):
        tiny(tmp_path, f"data.source={folder}", "data.cache=true", "data.num_workers=1")
    with pytest.raises(InputError, match="for a folder only"):
        tiny(tmp_path, "data.objects=1")  # generated data: data.generate.objects instead
    config = tiny(
        tmp_path / "track", f"data.source={folder}", "objective.kind=supervised",
        "model.inputs=track", "model.track_channels=8", "train.steps=2",
    )  # fmt: skip
    train(config, progress=False, log=lambda line: None)
    assert load_predictor(tmp_path / "track").model.config.inputs == "track"


def test_members_train_one_run_per_seed_and_write_their_ensemble(folder, tmp_path):
    """train.members = 2: OUT/member-0 and member-1 are ordinary runs with seeds s and s + 1
    (different weights); OUT/model.safetensors is their ensemble and answers their mean; a second
    call resumes both members (nothing to train) and writes the same ensemble."""
    config = tiny(
        tmp_path / "ens", f"data.source={folder}", "objective.kind=supervised",
        "model.inputs=track", "model.track_channels=8", "train.steps=2", "train.seed=5",
        "train.members=2",
    )  # fmt: skip
    result = train(config, progress=False, log=lambda line: None)
    members = [load_predictor(tmp_path / "ens" / f"member-{i}") for i in range(2)]
    assert [m.metadata["training"]["seed"] for m in members] == [5, 6]
    first, second = (m.model.state_dict() for m in members)
    assert any(not torch.equal(first[k], second[k]) for k in first)
    ensemble = load_predictor(tmp_path / "ens")
    assert ensemble.metadata["members"] == 2 and result.step == 2
    assert [m["seed"] for m in ensemble.metadata["training"]["members"]] == [5, 6]
    frames = torch.rand(1, members[0].num_frames, 32, 32, 3)
    mean = torch.stack([m.predict(frames)["unit"] for m in members]).mean(0)
    assert torch.allclose(ensemble.predict(frames)["unit"], mean, atol=1e-6)
    again = train(config, progress=False, log=lambda line: None)
    assert again.records == [] and torch.allclose(
        load_predictor(tmp_path / "ens").predict(frames)["unit"], mean, atol=1e-6
    )
    fine_tune = tiny(
        tmp_path / "fine", f"data.source={folder}", f"train.init={tmp_path / 'ens'}",
        "objective.kind=supervised", "model.inputs=track", "model.track_channels=8",
    )  # fmt: skip
    with pytest.raises(InputError, match="an ensemble; start from one of its members"):
        train(fine_tune, progress=False, log=lambda line: None)


def test_predicted_geometry_trains_on_the_3dgs_predictors_assets(folder, tmp_path):
    """data.geometry = predicted: each video's asset is what `predict` builds from its frame 0
    with the frozen 3DGS predictor (built once per video), and a mixed step runs through it."""
    gs_model = train_tiny_gaussian_predictor(folder, tmp_path / "gs", split="train")
    config = tiny(
        tmp_path / "out", f"data.source={folder}", "data.geometry=predicted",
        f"data.gs_model={gs_model}", "objective.kind=mixed", "train.steps=1",
    )  # fmt: skip
    samples = TrainingSamples(config.data)
    item, truth = samples[1], samples.asset(1)
    predicted = item["asset"]
    assert samples[1]["asset"] is predicted  # cached, not rebuilt every epoch
    assert predicted.num_anchors == truth.num_anchors  # the data's settings
    assert predicted.gaussians.num_gaussians != truth.gaussians.num_gaussians
    assert not torch.allclose(predicted.x0.mean(0), truth.x0.mean(0), atol=1e-4)
    assert (predicted.x0.mean(0) - truth.x0.mean(0)).norm() < 0.3  # about where the object is
    train(config, progress=False, log=lambda line: None)
    record = read_log(tmp_path / "out")[1]
    assert math.isfinite(record["photometric"]) and record["photometric"] > 0
    meta = json.loads((tmp_path / "out" / "model.json").read_text())
    assert meta["training"]["geometry"].startswith("predicted: the frozen 3DGS predictor")


def test_object_crops_read_the_realistic_look_and_train(tmp_path):
    """model.crop: each video is the square crop around the object (models/model_input.
    object_crop) of its frames times its true masks, so a realistic-look dataset trains (the
    object on black, outside the masks exactly black); without crops it is refused, and crops
    are supervised only. The trained model predicts from a crop of any framing."""
    realistic = ("data.generate.scene=realistic", "data.generate.resolution=32")
    crop = ("objective.kind=supervised", "model.inputs=track", "model.crop=true")
    with pytest.raises(InputError, match="realistic-look"):
        TrainingSamples(tiny(tmp_path, *realistic).data)
    with pytest.raises(InputError, match="supervised"):
        tiny(tmp_path, *realistic, "model.crop=true")
    config = tiny(tmp_path / "crop", *realistic, *crop, "model.track_channels=8", "train.steps=2")
    samples = TrainingSamples(config.data, assets=False, crop=True)
    item = samples[0]
    assert item["frames"].shape == (1, 4, 16, 16, 3)
    generated = samples.per_view[0]
    frames = generated[0]["frames"][0] * generated.masks(0)[0, ..., None]
    assert torch.allclose(item["frames"], object_crop(frames, 16))
    assert float(generated[0]["frames"][0].amin(-1).mean()) > 0.1  # the scene is not black
    outside = object_crop(generated.masks(0)[0, ..., None].float().expand(-1, -1, -1, 3), 16)
    assert float(item["frames"][outside == 0].abs().max()) == 0.0  # outside the masks: black
    train(config, progress=False, log=lambda line: None)
    predictor = load_predictor(tmp_path / "crop")
    assert predictor.model.config.crop
    out = predictor.predict(torch.nn.functional.pad(frames, (0, 0, 0, 20, 10, 0))[None])
    assert torch.isfinite(out["unit"]).all()


def test_object_crops_train_on_the_masks_segment_data_wrote(tmp_path):
    """`reconphys segment-data` writes the shipped segmenter's masks of every view beside a
    realistic folder's frames (the masks predict makes of a recording, from all its frames),
    keeps them on a second run, refuses a plain folder; data.masks = "segmenter" cuts the object
    out with them, and refuses masks that are missing or from another segmenter."""
    from reconphys.data.dataset import SEGMENTER_MASKS
    from reconphys.models.mask_segmenter import load_mask_segmenter, segment_clip

    realistic = ("data.generate.scene=realistic", "data.generate.resolution=24")
    crop = ("objective.kind=supervised", "model.inputs=track", "model.crop=true")
    settings = TrainingSamples(tiny(tmp_path, *realistic, *crop).data, crop=True).settings
    folder = tmp_path / "real"
    make_dataset(replace(settings, objects=1), folder, workers=1, device="cpu")
    with pytest.raises(InputError, match="model of object crops"):
        tiny(tmp_path, *realistic, *crop, "data.masks=segmenter")  # generated data: none stored
    config = tiny(tmp_path, *crop, f"data.source={folder}", "data.masks=segmenter")
    with pytest.raises(InputError, match="segment-data"):
        TrainingSamples(config.data, assets=False, crop=True)
    result = runner.invoke(app, ["segment-data", str(folder), "--workers", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    stored = DropDataset(folder, split=None)
    model = load_mask_segmenter()
    for index in range(len(stored)):
        frames, masks = stored[index]["frames"], stored.masks(index, "segmenter")
        for view in range(4):
            assert torch.equal(masks[view], segment_clip(model, frames[view]).bool())
    path = folder / stored.samples[0]["dir"] / SEGMENTER_MASKS
    written = path.stat().st_mtime_ns
    assert runner.invoke(app, ["segment-data", str(folder), "--no-progress"]).exit_code == 0
    assert path.stat().st_mtime_ns == written  # kept
    samples = TrainingSamples(config.data, assets=False, crop=True)
    view0 = DropDataset(folder, "train", views=[0], frames=range(4))
    frames = view0[0]["frames"][0] * view0.masks(0, "segmenter")[0, ..., None]
    assert torch.allclose(samples[0]["frames"][0], object_crop(frames, 16))
    truth = view0[0]["frames"][0] * view0.masks(0)[0, ..., None]
    assert not torch.allclose(frames, truth)  # the segmenter's masks are not the true ones
    cached = TrainingSamples(replace(config.data, cache=True), assets=False, crop=True)
    decoded, again = cached[0]["frames"], cached[0]["frames"]  # resampled crops: half precision
    assert cached.cache[0]["frames"].dtype == torch.float16 and again.dtype == torch.float32
    assert torch.allclose(decoded, again, atol=1e-3) and torch.equal(decoded, samples[0]["frames"])
    both = TrainingSamples(replace(config.data, masks="both"), assets=False, crop=True)
    assert len(both) == 2 * len(samples)  # every video twice: cut out by each kind of masks
    assert torch.allclose(both[0]["frames"][0], object_crop(truth, 16))
    assert torch.equal(both[1]["frames"], samples[0]["frames"])
    assert both.sample_id(1) == samples.sample_id(0) + "/segmenter-masks"
    assert (
        len(
            {
                both.fingerprint(),
                samples.fingerprint(),
                TrainingSamples(
                    replace(config.data, masks="true"), assets=False, crop=True
                ).fingerprint(),
            }
        )
        == 3
    )
    arrays = dict(np.load(path))
    np.savez(path, **{**arrays, "segmenter_sha256": np.array("0" * 16)})
    with pytest.raises(InputError, match="another mask segmenter"):
        TrainingSamples(config.data, assets=False, crop=True)
    plain = tmp_path / "plain"
    make_dataset(replace(settings, scene="plain", objects=1), plain, workers=1, device="cpu")
    result = runner.invoke(app, ["segment-data", str(plain), "--no-progress"])
    assert result.exit_code != 0 and "plain-look" in result.output
    with pytest.raises(InputError, match="no masks to choose"):
        plain_config = tiny(tmp_path, *crop, f"data.source={plain}", "data.masks=both")
        TrainingSamples(plain_config.data, assets=False, crop=True)


def test_more_sources_add_the_same_objects_drops_from_other_seeds(folder, tmp_path):
    """data.more_sources: a folder made with the same settings but another seed adds its samples
    of the objects data.source (and data.objects) select — never others (a validation split
    held out by object stays held out); a folder made otherwise is refused by name."""
    settings = TrainingSamples(tiny(tmp_path).data).settings
    other = tmp_path / "other"
    make_dataset(
        replace(settings, seed=settings.seed + 1, objects=6), other, workers=1, device="cpu"
    )
    first = TrainingSamples(tiny(tmp_path, f"data.source={folder}", "data.objects=1").data)
    both = TrainingSamples(
        tiny(
            tmp_path, f"data.source={folder}", "data.objects=1", f"data.more_sources=['{other}']"
        ).data
    )
    objects = {s["object"] for s in first.dataset.samples}
    theirs = [s for s in read_manifest(other)["samples"] if s["split"] == "train"]
    added = [s for s in theirs if s["object"] in objects]
    assert 0 < len(added) < len(theirs)  # the other seed's split has the object, and more
    assert len(both) == len(first) + len(added)
    assert {s["object"] for s in both.dataset.samples} == objects
    ids = [both.sample_id(i) for i in range(len(both))]
    assert len(set(ids)) == len(ids)
    stored = DropDataset(other, "train", views=[0], frames=range(4), resolution=16)
    assert torch.equal(both[len(first)]["frames"], stored[theirs.index(added[0])]["frames"])
    bigger = tmp_path / "bigger"
    make_dataset(replace(settings, resolution=20), bigger, workers=1, device="cpu")
    with pytest.raises(InputError, match="resolution"):
        TrainingSamples(
            tiny(tmp_path, f"data.source={folder}", f"data.more_sources=['{bigger}']").data
        )
    # a model of object crops resamples every folder to its crop: another resolution is more data
    crop = ("objective.kind=supervised", "model.inputs=track", "model.crop=true")
    config = tiny(tmp_path, *crop, f"data.source={folder}", f"data.more_sources=['{bigger}']")
    mixed = TrainingSamples(config.data, assets=False, crop=True)
    alone = TrainingSamples(replace(config.data, more_sources=()), assets=False, crop=True)
    assert len(mixed) == 2 * len(alone)  # the same objects and samples, at 20 px
    view = mixed.views[0]
    stored = DropDataset(bigger, "train", views=[view], frames=range(config.data.frames))
    last = len(mixed) - len(mixed.views)  # the first view of the added folder's last sample
    side = config.data.resolution
    expected = object_crop(stored[len(stored) - 1]["frames"][0], side)  # plain look: on black
    assert mixed[last]["frames"].shape[-3:-1] == (side, side)
    assert torch.allclose(mixed[last]["frames"][0], expected, atol=1e-6)


def test_a_scale_head_trains_beside_the_answer_without_changing_it(folder, tmp_path):
    """model.scale_head = true: the same run's answer weights are those of the run without it,
    to rounding (the head reads detached features, learns from the detached error and is clipped
    by its own norm), the head's Laplace term is logged, and the exported model carries it."""
    common = (
        f"data.source={folder}", "objective.kind=supervised", "model.inputs=track",
        "model.track_channels=8", "train.steps=4", "optim.grad_clip=0.05",
    )  # fmt: skip
    plain = train(tiny(tmp_path / "plain", *common), progress=False, log=lambda line: None)
    scaled = train(
        tiny(tmp_path / "scaled", *common, "model.scale_head=true"),
        progress=False,
        log=lambda line: None,
    )
    answer = plain.model.state_dict()
    weights = scaled.model.state_dict()
    assert set(weights) - set(answer) and all(
        k.startswith("scale.") for k in set(weights) - set(answer)
    )
    for key, value in answer.items():  # to rounding: float sums may group differently
        torch.testing.assert_close(weights[key], value, rtol=1e-5, atol=1e-7, msg=key)
    log = read_log(tmp_path / "scaled")
    assert all(math.isfinite(r["scale"]) for r in log.values())
    assert any(r["grad_norm"] > 0.05 for r in read_log(tmp_path / "plain").values())  # clipped
    loaded = load_predictor(tmp_path / "scaled")
    assert loaded.model.config.scale_head
    frames = torch.rand(1, 4, 16, 16, 3)
    assert loaded.predict(frames)["observable_scale"].shape == (1, 3)
