"""Training configuration: files, typed dotted overrides, one-line errors; data order; schedule."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from reconphys.errors import InputError
from reconphys.train.config import (
    TrainConfig,
    apply_overrides,
    differing_keys,
    load_config,
)
from reconphys.train.data import epoch_permutation, step_indices
from reconphys.train.trainer import lr_factor

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


@pytest.mark.parametrize("name", ["tiny.toml", "cpu_small.toml", "paper.toml"])
def test_shipped_configs_load(name):
    config = load_config(CONFIGS / name)
    predictor = config.predictor_config()
    assert predictor.num_frames == config.data.frames
    assert predictor.resolution == config.data.resolution
    assert config.objective.kind == "self_supervised" and config.objective.detach_window == 1
    # the saved form loads back to the same config
    assert TrainConfig.from_dict(config.to_dict()).to_dict() == config.to_dict()


def test_paper_config_is_the_paper_protocol():
    config = load_config(CONFIGS / "paper.toml")
    assert config.data.frames == 20 and config.train.amp
    small = load_config(CONFIGS / "cpu_small.toml")
    assert small.data.resolution == 32 and small.data.source != "generate"


def test_json_and_toml_give_the_same_config(tmp_path):
    toml = tmp_path / "c.toml"
    toml.write_text("[optim]\nlr = 0.002\n[data.generate]\nobjects = 3\n[model]\nmlp_hidden = [8]")
    data = {
        "optim": {"lr": 0.002},
        "data": {"generate": {"objects": 3}},
        "model": {"mlp_hidden": [8]},
    }
    (tmp_path / "c.json").write_text(json.dumps(data))
    a, b = load_config(toml), load_config(tmp_path / "c.json")
    assert a.to_dict() == b.to_dict()
    assert a.optim.lr == 0.002 and a.data.generate == {"objects": 3} and a.model.mlp_hidden == (8,)


def test_overrides_are_typed():
    config = apply_overrides(
        TrainConfig(),
        [
            "optim.lr=3e-4",
            "train.steps=7",
            "train.amp=true",
            "model.encoder_channels=[4, 8]",
            "data.source=/some/folder",
            "train.out=123",  # a string key keeps the text
            "data.generate.objects=3",
            "data.generate.contact_frame_range=[2, 4]",
            "optim.grad_clip=2",  # an integer is a valid float
        ],
    )
    assert config.optim.lr == 3e-4 and config.train.steps == 7 and config.train.amp is True
    assert config.model.encoder_channels == (4, 8)
    assert config.data.source == "/some/folder" and config.train.out == "123"
    assert config.data.generate == {"objects": 3, "contact_frame_range": (2.0, 4.0)}
    assert isinstance(config.optim.grad_clip, float)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("optim.lrr=1", "optim.lrr: unknown key"),
        ("optimizer.lr=1", "optimizer: unknown key"),
        ("optim.lr=fast", "optim.lr: expected a number, got 'fast'"),
        ("train.steps=2.5", "train.steps: expected an integer"),
        ("train.amp=yes", "train.amp: expected true or false"),
        ("train.steps=0", "train.steps: must be ≥ 1"),
        ("objective.kind=magic", "objective.kind: expected one of self_supervised"),
        ("objective.supervised_target=pixels", "objective.supervised_target: expected one of"),
        ("data.generate.colour=3", "data.generate.colour: not a make-data setting"),
        ("data.generate.objects=many", "data.generate.objects: expected an integer"),
        ("model.num_frames=8", "model.num_frames: set data.frames instead"),
        ("model.attention_heads=3", "model.attention_heads: must be ≥ 1 and divide"),
        ("lr=1", "lr: expected SECTION.KEY"),
        ("optim.lr", "expected KEY=VALUE"),
    ],
)
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(InputError) as error:
        apply_overrides(TrainConfig(), [override])
    assert message in str(error.value) and "\n" not in str(error.value)


def test_bad_files_name_the_file_and_key(tmp_path):
    with pytest.raises(InputError, match="config file not found"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text('[train]\nsteps = "many"\n')
    with pytest.raises(InputError, match=r"bad.toml \[train.steps\]: expected an integer"):
        load_config(bad)
    bad.write_text("[train\n")
    with pytest.raises(InputError, match="not valid TOML"):
        load_config(bad)
    bad.write_text("[train]\nsteps = 0\n")
    with pytest.raises(InputError, match=r"bad.toml.*train.steps: must be ≥ 1"):
        load_config(bad)
    other = tmp_path / "config.yaml"
    other.write_text("train: {}\n")
    with pytest.raises(InputError, match=r"expected a \.toml or \.json file"):
        load_config(other)


def test_resume_compares_everything_but_the_free_keys():
    a = TrainConfig().to_dict()
    b = apply_overrides(TrainConfig(), ["train.steps=5000", "data.num_workers=3"]).to_dict()
    assert differing_keys(a, b) == []
    c = apply_overrides(TrainConfig(), ["optim.lr=1e-3", "data.generate.objects=2"]).to_dict()
    assert differing_keys(a, c) == ["data.generate", "optim.lr"]
    # A checkpoint written before a key existed matches a config at the key's default only.
    older = TrainConfig().to_dict()
    del older["model"]["silhouette"]
    assert differing_keys(older, a) == []
    d = apply_overrides(TrainConfig(), ["model.silhouette=true"]).to_dict()
    assert differing_keys(older, d) == ["model.silhouette"]


def test_data_order_is_a_function_of_seed_and_step():
    n, batch = 7, 4
    first = [step_indices(s, n, batch, seed=3) for s in range(1, 8)]
    assert first == [step_indices(s, n, batch, seed=3) for s in range(1, 8)]
    assert first != [step_indices(s, n, batch, seed=4) for s in range(1, 8)]
    stream = [i for indices in first for i in indices]
    # every epoch visits every sample once, in a new order
    epochs = [stream[e * n : (e + 1) * n] for e in range(len(stream) // n)]
    assert all(sorted(e) == list(range(n)) for e in epochs)
    assert epochs[0] != epochs[1]
    assert list(epoch_permutation(n, 3, 0)) == epochs[0]
    # DDP ranks split each global batch into disjoint parts whose union is that batch
    for step in range(1, 8):
        ranks = [step_indices(step, n, batch, 3, rank, 2) for rank in range(2)]
        assert len(ranks[0]) == len(ranks[1]) == 2
        assert sorted(ranks[0] + ranks[1]) == sorted(first[step - 1])


def test_learning_rate_schedule():
    config = apply_overrides(
        TrainConfig(), ["train.steps=100", "optim.warmup_steps=10", "optim.min_lr_ratio=0.1"]
    )
    assert lr_factor(0, config) == pytest.approx(0.1)
    assert lr_factor(9, config) == pytest.approx(1.0)
    assert lr_factor(10, config) == pytest.approx(1.0)
    assert lr_factor(100, config) == pytest.approx(0.1)
    assert lr_factor(55, config) == pytest.approx(0.55)
    constant = apply_overrides(TrainConfig(), ["optim.schedule=constant"])
    assert lr_factor(500, constant) == 1.0
