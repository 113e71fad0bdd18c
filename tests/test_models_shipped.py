"""The trained predictor on disk: found without flags, loaded with one-line errors.

The weights shipped in the package: found without flags, small, and it reads physics.

The behavioural check is independent of the training data: one procedural object of the cpu_small
kind (32 px, 256 anchors, 2 000 Gaussians) is dropped twice with everything equal but the
stiffness, 30× apart; the model must order the two videos' log k/m correctly, with a margin.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
import torch

from reconphys.data.dataset import GeneratedDropDataset
from reconphys.data.generate import dataset_cameras, generate_sample, render_views
from reconphys.data.settings import make_settings
from reconphys.errors import InputError
from reconphys.models import shipped
from reconphys.models.physics_predictor import (
    DEFAULT_SPREAD_FACTOR,
    PhysicsPredictor,
    PredictorConfig,
    PredictorEnsemble,
    attributes_from_unit,
    observable_spread,
)
from reconphys.models.shipped import (
    ENV_VAR,
    SHIPPED_PATH,
    default_model_path,
    load_predictor,
    model_metadata,
    save_predictor,
)
from reconphys.physics import ATTRIBUTES
from reconphys.physics.model import ATTRIBUTE_RANGES
from reconphys.render.video import to_uint8
from reconphys.threads import set_cpu_threads

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


def test_an_ensemble_answers_the_mean_of_its_members_and_round_trips(tmp_path):
    """members = 3: the unit outputs (log m, log k, log d, f scaled) are the members' mean, so
    log k/m is the mean of theirs; saved with "members" in its JSON, loaded back the same; a
    "members" that is not a whole number ≥ 1 is a one-line error."""
    torch.manual_seed(0)
    ensemble = PredictorEnsemble(TINY, 3).eval()
    frames = torch.rand(2, 3, 16, 16, 3)
    with torch.no_grad():
        out = ensemble(frames)
        singles = [member(frames) for member in ensemble.members]
    assert out["member_unit"].shape == (3, 2, 4)
    ratio = torch.stack([torch.log(o["stiffness"] / o["mass"]) for o in singles]).mean(0)
    assert torch.allclose(torch.log(out["stiffness"] / out["mass"]), ratio, rtol=1e-5)
    mean = torch.stack([o["unit"] for o in singles]).mean(0)
    assert torch.allclose(out["friction"], attributes_from_unit(mean)["friction"])
    path = save_predictor(
        ensemble, tmp_path / "e.safetensors", model_metadata(TINY, 0, 0.03, members=3)
    )
    loaded = load_predictor(path)
    assert isinstance(loaded.model, PredictorEnsemble) and len(loaded.model.members) == 3
    assert torch.allclose(loaded.predict(frames)["unit"], out["unit"], atol=1e-6)
    meta = json.loads(path.with_suffix(".json").read_text())
    for bad in (0, 2.5, "3"):
        path.with_suffix(".json").write_text(json.dumps(dict(meta, members=bad)))
        with pytest.raises(InputError, match=r"e\.json \[members\]: expected a whole number"):
            load_predictor(path)
    with pytest.raises(ValueError, match="at least 2"):
        PredictorEnsemble(TINY, 1)


def test_the_members_spread_is_their_standard_deviation_of_each_observable():
    """observable_spread against numpy's std (ddof 1) of log k/m, log d/m and f computed from
    each member's attributes; identical members spread 0; one member is an error."""
    import numpy as np

    torch.manual_seed(1)
    units = torch.rand(4, 3, 4, dtype=torch.float64)
    spread = observable_spread(units)
    assert spread.shape == (3, 3)
    a = {k: v.numpy() for k, v in attributes_from_unit(units).items()}
    values = np.stack(
        [np.log(a["stiffness"] / a["mass"]), np.log(a["damping"] / a["mass"]), a["friction"]], -1
    )
    assert spread.numpy() == pytest.approx(values.std(0, ddof=1), rel=1e-9)
    assert observable_spread(units[:1].repeat(3, 1, 1)).abs().max() < 1e-12
    with pytest.raises(ValueError, match="M ≥ 2"):
        observable_spread(units[:1])


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
    for factor in ([3.0, 3.0], [3.0, -1.0, 4.0], [3.0, float("nan"), 4.0], "3"):
        meta_path.write_text(json.dumps(dict(meta, spread_factor=factor)))
        with pytest.raises(InputError, match="spread_factor must be 3 positive numbers"):
            load_predictor(path)

    meta_path.unlink()
    with pytest.raises(InputError, match=r"m\.json is missing"):
        load_predictor(path)


def test_the_belief_factor_is_the_models_own(saved):
    """An ensemble's calibrated "spread_factor" is what it reports; without one, the default."""
    _, path = saved
    assert load_predictor(path).spread_factor == DEFAULT_SPREAD_FACTOR
    meta_path = path.with_suffix(".json")
    meta_path.write_text(
        json.dumps(dict(json.loads(meta_path.read_text()), spread_factor=[1, 2, 5]))
    )
    assert load_predictor(path).spread_factor == (1, 2, 5)
    shipped = json.loads(SHIPPED_PATH.with_suffix(".json").read_text())
    assert (
        len(shipped["spread_factor"]) == 3
        and "network_intervals.py" in shipped["spread_factor_how"]
    )


def test_a_scale_heads_belief_joins_the_spread(tmp_path):
    """network_sigma: the members' spread, the scale head's Laplace scale as the normal of the
    same 10–90 % width (ln 5 · b / 1.2816), or their root sum of squares, × the factor; a model
    with a scale head saved without factors gets 1 / 1 / 1, and round-trips its head."""
    from statistics import NormalDist

    from reconphys.models.physics_predictor import SCALE_HEAD_SPREAD_FACTOR, network_sigma

    units = torch.rand(3, 2, 4, dtype=torch.float64)
    spread = observable_spread(units)
    b = torch.tensor([[0.2, 0.5, 0.1], [0.4, 0.3, 0.05]], dtype=torch.float64)
    as_normal = math.log(5) * b / NormalDist().inv_cdf(0.9)
    factor = (2.0, 3.0, 4.0)
    torch.testing.assert_close(
        network_sigma({"member_unit": units}, factor),
        spread * torch.tensor(factor, dtype=torch.float64),
    )
    torch.testing.assert_close(network_sigma({"observable_scale": b}, (1.0, 1.0, 1.0)), as_normal)
    both = network_sigma({"member_unit": units, "observable_scale": b}, factor)
    torch.testing.assert_close(
        both, (spread**2 + as_normal**2).sqrt() * torch.tensor(factor, dtype=torch.float64)
    )
    assert network_sigma({"unit": units[0]}, factor) is None

    config = replace(TINY, scale_head=True)
    torch.manual_seed(1)
    ensemble = PredictorEnsemble(config, 2).eval()
    path = save_predictor(
        ensemble, tmp_path / "s.safetensors", model_metadata(config, 0, 0.03, members=2)
    )
    loaded = load_predictor(path)
    assert loaded.model.config.scale_head and loaded.spread_factor == SCALE_HEAD_SPREAD_FACTOR
    frames = torch.rand(1, 3, 16, 16, 3)
    with torch.no_grad():
        torch.testing.assert_close(
            loaded.predict(frames)["observable_scale"], ensemble(frames)["observable_scale"]
        )


# The shipped weights.
@pytest.fixture(scope="module")
def model():
    return load_predictor(SHIPPED_PATH)


def test_shipped_model_is_found_without_flags(model, monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert load_predictor().path == SHIPPED_PATH
    assert SHIPPED_PATH.stat().st_size < 20 * 2**20  # < 20 MB in the repository
    training = model.metadata["training"]
    assert training["geometry"].startswith("ground truth")  # its scores are labelled †
    assert training["steps"] > 0 and training["skipped_steps"] == 0
    out = model.predict(torch.rand(3, model.num_frames, 48, 48, 3))
    for name in ATTRIBUTES:
        low, high = ATTRIBUTE_RANGES[name]
        assert torch.isfinite(out[name]).all()
        assert ((out[name] >= low) & (out[name] <= high)).all(), name


def _video(asset, settings, model) -> torch.Tensor:  # [1, T, H, W, 3] of the model's view
    trajectory = asset.simulate(model.num_frames - 1, torch.device("cpu"))
    rgb = render_views(asset, trajectory.x[0], dataset_cameras(settings))
    video = torch.from_numpy(to_uint8(rgb)).float() / 255  # [V, T, H, W, 3]
    return video[model.view : model.view + 1]


def test_shipped_model_orders_stiffness(model):
    threads = torch.get_num_threads()
    set_cpu_threads(1)
    try:
        settings = make_settings(
            objects=1, test_objects=0, samples_per_object=1, resolution=32,
            contact_frame_range=(6.0, 8.0), max_horizontal_speed=0.0,
        )  # fmt: skip
        dataset = GeneratedDropDataset(settings, views=[0], frames=range(2))
        generated = generate_sample(dataset.object(0), 0, settings)
        ratios = []
        for stiffness in (30.0, 900.0):
            physics = replace(generated.asset.physics, mass=1.0, stiffness=stiffness,
                              damping=0.5, friction=0.5)  # fmt: skip
            asset = replace(generated.asset, physics=physics)
            out = model.predict(_video(asset, settings, model))
            ratios.append(math.log(float(out["stiffness"][0]) / float(out["mass"][0])))
    finally:
        set_cpu_threads(threads)
    soft, stiff = ratios
    assert stiff - soft > 1.0, ratios  # truth: log 30 ≈ 3.4 apart
