"""The trained predictor on disk: found without flags, loaded with one-line errors."""

from __future__ import annotations

import json

import pytest
import torch

from reconphys.errors import InputError
from reconphys.models import shipped
from reconphys.models.physics_predictor import PhysicsPredictor, PredictorConfig
from reconphys.models.shipped import (
    ENV_VAR,
    SHIPPED_PATH,
    default_model_path,
    load_predictor,
    model_metadata,
    save_predictor,
)

TINY = PredictorConfig(
    encoder_channels=(4,), token_channels=8, trunk_blocks=1, attention_heads=2,
    mlp_hidden=(8,), num_frames=3, resolution=16,
)  # fmt: skip


@pytest.fixture
def saved(tmp_path):
    torch.manual_seed(0)
    model = PhysicsPredictor(TINY)
    path = save_predictor(model, tmp_path / "m.safetensors", model_metadata(TINY, 2, 0.03))
    return model.eval(), path


def test_round_trip_gives_the_same_predictions(saved):
    model, path = saved
    loaded = load_predictor(path)
    assert loaded.view == 2 and loaded.num_frames == 3 and not loaded.model.training
    frames = torch.rand(2, 5, 32, 32, 3)  # more frames and a larger size than the model reads
    with torch.no_grad():
        expected = model(torch.nn.functional.interpolate(
            frames[:, :3].reshape(6, 32, 32, 3).permute(0, 3, 1, 2), size=16, mode="area"
        ).permute(0, 2, 3, 1).reshape(2, 3, 16, 16, 3))["unit"]  # fmt: skip
    torch.testing.assert_close(loaded.predict(frames)["unit"], expected, rtol=0, atol=1e-6)
    with pytest.raises(InputError, match="reads 3 frames, the video has 2"):
        loaded.predict(frames[:, :2])


def test_default_path_follows_the_environment(saved, monkeypatch):
    _, path = saved
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert default_model_path() == SHIPPED_PATH
    assert SHIPPED_PATH.name == "physics_predictor.safetensors"
    monkeypatch.setenv(ENV_VAR, str(path))
    assert default_model_path() == path
    assert load_predictor().path == path
    (path.parent / "model.safetensors").write_bytes(path.read_bytes())
    (path.parent / "model.json").write_text(path.with_suffix(".json").read_text())
    monkeypatch.setenv(ENV_VAR, str(path.parent))  # a training output folder
    assert default_model_path() == path.parent / "model.safetensors"


def test_a_missing_shipped_model_says_how_to_train_one(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.setattr(shipped, "SHIPPED_PATH", tmp_path / "physics_predictor.safetensors")
    with pytest.raises(InputError) as error:
        load_predictor()
    message = str(error.value)
    assert "no trained physics predictor" in message and "reconphys train" in message
    assert ENV_VAR in message and "\n" not in message
    with pytest.raises(InputError, match="model file not found"):
        load_predictor(tmp_path / "other.safetensors")


def test_bad_files_are_one_line_errors(saved):
    _, path = saved
    meta_path = path.with_suffix(".json")
    meta = json.loads(meta_path.read_text())

    bigger = dict(meta, predictor=dict(meta["predictor"], token_channels=16))
    meta_path.write_text(json.dumps(bigger))
    with pytest.raises(InputError, match=r"weights do not match the config in m.json \(.*shape"):
        load_predictor(path)

    ranges = dict(meta, attribute_ranges=dict(meta["attribute_ranges"], stiffness=[1, 10]))
    meta_path.write_text(json.dumps(ranges))
    with pytest.raises(InputError, match=r"attribute_ranges.stiffness.*trained for the range"):
        load_predictor(path)

    meta_path.write_text(json.dumps(meta))
    good = path.read_bytes()
    path.write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError, match="not a readable safetensors file"):
        load_predictor(path)

    path.write_bytes(good)
    meta_path.unlink()
    with pytest.raises(InputError, match=r"m\.json is missing"):
        load_predictor(path)
