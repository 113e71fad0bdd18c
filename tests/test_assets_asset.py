"""Asset folder: exact round trips, identical simulation after reading, and bad-input errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from reconphys.assets.asset import PhysicsSettings, read_asset, write_asset
from reconphys.assets.build import build_asset, with_gaussians
from reconphys.assets.normalize import place_on_ground
from reconphys.assets.procedural import make_procedural_gaussians
from reconphys.errors import InputError
from reconphys.physics import rollout


@pytest.fixture(scope="module")
def small_asset():
    gaussians = place_on_ground(make_procedural_gaussians("box", 600, seed=1, size=0.3), 0.05)
    physics = PhysicsSettings(num_anchors=64, num_neighbors=8, substeps=20, object_id="box-test")
    return build_asset(gaussians, physics, angular_velocity=(0.0, 0.0, 3.0))


def test_round_trip_is_exact(small_asset, tmp_path):
    write_asset(small_asset, tmp_path / "a")
    back = read_asset(tmp_path / "a")
    for name in ("x0", "v0", "springs", "rest_length", "binding_index", "binding_weight"):
        assert torch.equal(getattr(small_asset, name), getattr(back, name)), name
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh0"):
        assert torch.equal(getattr(small_asset.gaussians, name), getattr(back.gaussians, name))
    assert back.physics == small_asset.physics
    physics = json.loads((tmp_path / "a" / "physics.json").read_text())
    assert physics["format"] == "reconphys.asset" and physics["version"] == 1
    assert physics["derived"]["total_mass_kg"] == pytest.approx(64 * small_asset.physics.mass)


def test_written_asset_simulates_identically(small_asset, tmp_path):
    write_asset(small_asset, tmp_path / "a")
    back = read_asset(tmp_path / "a")
    runs = [
        rollout(a.model(), a.initial_state(), 10, min_substeps=a.physics.substeps)
        for a in (small_asset, back)
    ]
    assert runs[0].x[..., 2].min() == 0.0, "the run must reach the ground"
    assert torch.equal(runs[0].x, runs[1].x)


def test_other_gaussians_on_the_same_anchors(small_asset):
    """with_gaussians binds as build_asset does: the asset's own Gaussians come back bound
    exactly as built; finer ones of the same box move with the same anchors (the physics is
    untouched), each weighted over its nearest anchors."""
    same = with_gaussians(small_asset, small_asset.gaussians)
    assert torch.equal(same.binding_index, small_asset.binding_index)
    assert torch.equal(same.binding_weight, small_asset.binding_weight)
    finer = place_on_ground(make_procedural_gaussians("box", 2400, seed=2, size=0.3), 0.05)
    other = with_gaussians(small_asset, finer)
    assert other.gaussians.num_gaussians == 2400
    assert torch.equal(other.x0, small_asset.x0) and torch.equal(other.springs, small_asset.springs)
    assert other.physics == small_asset.physics
    assert other.binding_index.shape[0] == 2400
    assert torch.allclose(other.binding_weight.sum(-1), torch.ones(2400), atol=1e-5)
    nearest = torch.cdist(finer.means, small_asset.x0).argmin(-1)  # [2400]
    assert bool((other.binding_index == nearest[:, None]).any(-1).all())


def test_per_element_attributes_round_trip_and_are_used(small_asset, tmp_path):
    n = small_asset.num_anchors
    heavy = torch.linspace(0.5, 2.0, n)
    asset = small_asset.__class__(**{**vars(small_asset), "per_element": {"mass": heavy}})
    write_asset(asset, tmp_path / "a")
    back = read_asset(tmp_path / "a")
    assert torch.equal(back.per_element["mass"], heavy)
    assert torch.equal(back.model().mass, heavy[None])


def test_existing_folder_is_not_replaced_without_overwrite(small_asset, tmp_path):
    write_asset(small_asset, tmp_path / "a")
    with pytest.raises(InputError, match="already exists"):
        write_asset(small_asset, tmp_path / "a")
    write_asset(small_asset, tmp_path / "a", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"], "no staging folders left"


def corrupt(folder, filename, **changes):
    """Rewrite one array file of an asset folder with some entries replaced (None = removed)."""
    path = folder / filename
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    np.savez(path, **arrays)


BAD_ARRAYS = [
    ("anchors.npz", "x0", lambda a: a["x0"][:, :2]),
    ("anchors.npz", "x0", lambda a: a["x0"].astype(np.int32)),
    (
        "anchors.npz",
        "v0",
        lambda a: np.where(np.arange(len(a["v0"]))[:, None] == 3, np.nan, a["v0"]),
    ),
    ("anchors.npz", "springs", lambda a: a["springs"] + len(a["x0"])),
    ("anchors.npz", "springs", lambda a: a["springs"].astype(np.float32)),
    ("anchors.npz", "rest_length", lambda a: -a["rest_length"]),
    ("anchors.npz", "springs", lambda a: None),
    ("binding.npz", "index", lambda a: a["index"] * 0 + 10_000),
    ("binding.npz", "weight", lambda a: a["weight"][:-1]),
    ("binding.npz", "weight", lambda a: a["weight"] * 2),
]


@pytest.mark.parametrize("filename, field, change", BAD_ARRAYS)
def test_bad_arrays_name_file_and_field(small_asset, tmp_path, filename, field, change):
    write_asset(small_asset, tmp_path / "a")
    with np.load(tmp_path / "a" / filename) as data:
        arrays = {k: data[k] for k in data.files}
    corrupt(tmp_path / "a", filename, **{field: change(arrays)})
    with pytest.raises(InputError) as error:
        read_asset(tmp_path / "a")
    assert filename in str(error.value) and field in str(error.value)
    assert "\n" not in str(error.value)


@pytest.mark.parametrize(
    "field, value",
    [
        ("mass", -1.0),
        ("mass", "heavy"),
        ("friction", float("nan")),
        ("substeps", 2.5),
        ("format", "other"),
        ("version", 99),
        ("gravity", [0, 0]),
        ("num_anchors", 3),
    ],
)
def test_bad_physics_json_names_field(small_asset, tmp_path, field, value):
    write_asset(small_asset, tmp_path / "a")
    path = tmp_path / "a" / "physics.json"
    physics = json.loads(path.read_text())
    physics[field] = value
    path.write_text(json.dumps(physics))
    with pytest.raises(InputError) as error:
        read_asset(tmp_path / "a")
    assert "physics.json" in str(error.value) and field in str(error.value)


@pytest.mark.parametrize(
    "filename", ["gaussians.ply", "anchors.npz", "binding.npz", "physics.json"]
)
def test_missing_or_garbage_files_are_reported(small_asset, tmp_path, filename):
    write_asset(small_asset, tmp_path / "a")
    (tmp_path / "a" / filename).unlink()
    with pytest.raises(InputError, match=filename):
        read_asset(tmp_path / "a")
    (tmp_path / "a" / filename).write_bytes(b"\x00garbage")
    with pytest.raises(InputError, match=filename):
        read_asset(tmp_path / "a")
