"""``reconphys export``: the Newton/Warp .npz and the MuJoCo MJCF against independent numbers."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
from helpers import make_small_asset
from typer.testing import CliRunner

from reconphys.assets.asset import read_asset, write_asset
from reconphys.assets.export import (
    _write_atomically,
    export_mjcf,
    export_newton,
    spring_coefficients,
)
from reconphys.cli import app
from reconphys.physics import spring_forces

runner = CliRunner()
# 64 anchors, set attributes and a spinning, sliding start (tests/helpers.py for the rest).
OPTIONS = ["--num-anchors", "64", "--stiffness", "250", "--damping", "0.8", "--friction", "0.4"]
OPTIONS += ["--linear-velocity", "0.5", "0", "0", "--angular-velocity", "0", "0", "3"]


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory):
    return make_small_asset(tmp_path_factory.mktemp("export") / "asset", *OPTIONS)


@pytest.fixture(scope="module")
def per_element_asset(asset_dir, tmp_path_factory):
    """The same asset with per-anchor mass/friction and per-spring stiffness/damping arrays."""
    asset = read_asset(asset_dir)
    g = torch.Generator().manual_seed(3)
    n, e = asset.num_anchors, asset.springs.shape[0]
    asset.per_element = {
        "mass": 0.5 + torch.rand(n, generator=g),
        "friction": 0.2 + 0.5 * torch.rand(n, generator=g),
        "stiffness": 100 + 400 * torch.rand(e, generator=g),
        "damping": 0.1 + 2 * torch.rand(e, generator=g),
    }
    folder = write_asset(asset, tmp_path_factory.mktemp("per_element") / "asset")
    return read_asset(folder)


def newton_force(data, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Spring forces [N_A, 3] as Warp/Newton's semi-implicit solver forms them from the exported
    arrays: f = dir (ke (l − rest) + kd (dir · v_ij)), dir = x_ij / l, on i minus and j plus."""
    i, j = data["spring_indices"].T
    xij, vij = x[i] - x[j], v[i] - v[j]
    length = np.linalg.norm(xij, axis=1)
    direction = xij / length[:, None]
    c = length - data["spring_rest_length"].astype(np.float64)
    dcdt = (direction * vij).sum(1)
    fs = direction * (data["spring_ke"] * c + data["spring_kd"] * dcdt)[:, None]
    force = np.zeros_like(x)
    np.add.at(force, i, -fs)
    np.add.at(force, j, fs)
    return force


def test_newton_npz_fields_in_si_units(asset_dir, tmp_path):
    asset = read_asset(asset_dir)
    path = export_newton(asset, tmp_path / "a.npz")
    with np.load(path, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    n, e = 64, asset.springs.shape[0]
    expected = {
        "particle_q": ((n, 3), np.float32),
        "particle_qd": ((n, 3), np.float32),
        "particle_mass": ((n,), np.float32),
        "spring_indices": ((e, 2), np.int32),
        "spring_rest_length": ((e,), np.float32),
        "spring_ke": ((e,), np.float32),
        "spring_kd": ((e,), np.float32),
        "gravity": ((3,), np.float64),
        "gaussian_means": ((400, 3), np.float32),
        "binding_index": ((400, 16), np.int32),
        "binding_weight": ((400, 16), np.float32),
    }
    for name, (shape, dtype) in expected.items():
        assert data[name].shape == shape and data[name].dtype == dtype, name
    assert str(data["format"]) == "reconphys.newton" and int(data["version"]) == 1
    np.testing.assert_array_equal(data["particle_q"], asset.x0.numpy())
    np.testing.assert_array_equal(data["particle_qd"], asset.v0.numpy())
    assert np.abs(data["particle_qd"]).max() > 0.1  # the sampled spin and drift
    np.testing.assert_array_equal(data["spring_indices"], asset.springs.numpy())
    np.testing.assert_array_equal(data["spring_rest_length"], asset.rest_length.numpy())
    # One shared k, d (physics.json): the spring constants are k / l and d / l per spring.
    rest = asset.rest_length.double().numpy()
    np.testing.assert_allclose(data["spring_ke"], 250.0 / rest, rtol=1e-6)
    np.testing.assert_allclose(data["spring_kd"], 0.8 / rest, rtol=1e-6)
    np.testing.assert_allclose(data["particle_mass"], 1.0)
    assert float(data["ground_friction"]) == pytest.approx(0.4)
    assert float(data["spring_exponent"]) == 0.5 and float(data["restitution"]) == 0.0
    np.testing.assert_array_equal(data["gravity"], [0.0, 0.0, -9.8])
    assert float(data["frame_dt"]) == 0.03
    inspected = json.loads(runner.invoke(app, ["inspect", str(asset_dir)]).output)
    assert int(data["substeps"]) == inspected["substeps_used"]
    np.testing.assert_array_equal(data["gaussian_means"], asset.gaussians.means.numpy())
    np.testing.assert_array_equal(data["binding_index"], asset.binding_index.numpy())
    np.testing.assert_array_equal(data["binding_weight"], asset.binding_weight.numpy())


def test_newton_coefficients_are_the_simulators_per_spring_values(per_element_asset, tmp_path):
    asset = per_element_asset
    with np.load(export_newton(asset, tmp_path / "a.npz")) as f:
        data = {k: f[k] for k in f.files}
    # Independently from the simulator's model object: its per-spring k, d over its rest lengths.
    model = asset.model(dtype=torch.float64)
    assert model.stiffness.shape == (1, asset.springs.shape[0])
    ke = (model.stiffness[0] / model.rest_length).numpy()
    kd = (model.damping[0] / model.rest_length).numpy()
    np.testing.assert_allclose(data["spring_ke"], ke, rtol=1e-6)
    np.testing.assert_allclose(data["spring_kd"], kd, rtol=1e-6)
    np.testing.assert_allclose(data["particle_mass"], model.mass[0].numpy(), rtol=1e-6)
    np.testing.assert_allclose(data["particle_friction"], model.friction[0].numpy(), rtol=1e-6)
    assert float(data["ground_friction"]) == pytest.approx(float(model.friction.mean()))
    # The scalars of physics.json are not what the simulator uses here.
    assert not np.allclose(data["spring_ke"], asset.physics.stiffness / model.rest_length.numpy())

    # Force level: with Hooke's law (p_k = 0) a Newton/Warp spring with the exported ke, kd gives
    # our simulator's spring + dashpot force on a deformed, moving state.
    g = torch.Generator().manual_seed(0)
    x = asset.x0.double() * (1 + 0.1 * torch.rand(asset.num_anchors, 3, generator=g))
    v = torch.randn(asset.num_anchors, 3, generator=g, dtype=torch.float64)
    hooke = model.with_attributes(spring_exponent=0.0)
    ours = spring_forces(hooke, x[None], v[None])[0].numpy()
    theirs = newton_force(data, x.numpy(), v.numpy())
    np.testing.assert_allclose(theirs, ours, rtol=1e-5, atol=1e-6 * np.abs(ours).max())
    # With p_k = 0.5, ke is the small-strain stiffness: equal forces at 1e-4 strain, ~5 % apart
    # at 10 % strain.
    x_small = asset.x0.double() * (1 + 1e-4)
    zero = torch.zeros_like(x_small)
    nonlinear = spring_forces(model, x_small[None], zero[None])[0].numpy()
    linear = newton_force(data, x_small.numpy(), zero.numpy())
    assert np.abs(linear - nonlinear).max() < 1e-3 * np.abs(nonlinear).max()
    x_big = asset.x0.double() * 1.1
    nonlinear = spring_forces(model, x_big[None], zero[None])[0].numpy()
    linear = newton_force(data, x_big.numpy(), zero.numpy())
    ratio = np.linalg.norm(nonlinear) / np.linalg.norm(linear)
    assert ratio == pytest.approx(1.1**0.5, rel=2e-3)


def mjcf(path):
    root = ET.parse(path).getroot()
    flex = root.find("worldbody/flexcomp")
    return root, flex


def test_mjcf_structure_and_numbers(per_element_asset, tmp_path):
    asset = per_element_asset
    path = export_mjcf(asset, tmp_path / "a.xml")
    text = path.read_text()
    assert text.startswith("<!--") and "What does not map" in text
    assert "--" not in text.split("<!--", 1)[1].split("-->", 1)[0]  # a valid XML comment
    root, flex = mjcf(path)
    n, e = asset.num_anchors, asset.springs.shape[0]
    assert flex.get("type") == "direct" and flex.get("dim") == "1"
    point = np.array(flex.get("point").split(), dtype=np.float64)
    element = np.array(flex.get("element").split(), dtype=np.int64)
    assert point.size == 3 * n and element.size == 2 * e
    np.testing.assert_array_equal(point.reshape(n, 3).astype(np.float32), asset.x0.numpy())
    np.testing.assert_array_equal(element.reshape(e, 2), asset.springs.numpy())
    # One stiffness / damping for all edges: the medians of k / l and d / l (N/m, N·s/m).
    k = asset.per_element["stiffness"].double().numpy()
    d = asset.per_element["damping"].double().numpy()
    rest = asset.rest_length.double().numpy()
    edge = flex.find("edge")
    assert float(edge.get("stiffness")) == pytest.approx(np.median(k / rest), rel=1e-7)
    assert float(edge.get("damping")) == pytest.approx(np.median(d / rest), rel=1e-7)
    total = asset.per_element["mass"].double().sum().item()
    assert float(flex.get("mass")) == pytest.approx(total, rel=1e-7)
    friction = asset.per_element["friction"].double().mean().item()
    assert float(flex.find("contact").get("friction")) == pytest.approx(friction, rel=1e-6)
    ground = root.find("worldbody/geom")
    assert ground.get("type") == "plane"
    assert float(ground.get("friction").split()[0]) == pytest.approx(friction, rel=1e-6)
    option = root.find("option")
    substeps = asset.simulate(1).substeps  # what our simulator uses per 0.03 s frame
    assert float(option.get("timestep")) == pytest.approx(0.03 / substeps, rel=1e-8)
    assert option.get("gravity") == "0 0 -9.8"
    qvel = np.array(root.find("keyframe/key").get("qvel").split(), dtype=np.float64)
    np.testing.assert_array_equal(qvel.reshape(n, 3).astype(np.float32), asset.v0.numpy())
    # The comment states the chosen values and our spread.
    ke = k / rest
    assert f"[{ke.min():.4g}, {ke.max():.4g}]" in text


def test_mjcf_loads_and_steps_in_mujoco(asset_dir, tmp_path):
    mujoco = pytest.importorskip("mujoco")
    asset = read_asset(asset_dir)
    model = mujoco.MjModel.from_xml_path(str(export_mjcf(asset, tmp_path / "a.xml")))
    assert (model.nflexvert, model.nflexedge) == (64, asset.springs.shape[0])
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    ours = asset.simulate(30).x[0].double().numpy()  # [31, N_A, 3]
    substeps = round(0.03 / model.opt.timestep)
    positions = []
    for _ in range(30):
        for _ in range(substeps):
            mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)  # flexvert_xpos is computed before the integration
        positions.append(data.flexvert_xpos.copy())
    positions = np.stack(positions)  # [30, N_A, 3]
    assert 30 * substeps >= 300 and np.isfinite(positions).all()
    # Before the contact (free flight, spinning) both simulators agree: same gravity, substep,
    # initial velocities and (to the median-stiffness approximation) springs.
    before = int(np.argmax(ours[1:, :, 2].min(1) < 0.01))  # frames before the first contact
    assert before >= 3
    np.testing.assert_allclose(positions[:before].mean(1), ours[1 : before + 1].mean(1), atol=2e-4)
    assert np.abs(positions[:before] - ours[1 : before + 1]).max() < 3e-3
    # Afterwards it rests on the plane (soft contact: within a few mm) instead of falling through.
    assert positions[-1, :, 2].min() > -0.01
    assert positions[-1, :, 2].mean() < ours[0, :, 2].mean() - 0.1


def test_cli_export_and_one_line_errors(asset_dir, tmp_path):
    for fmt, name in (("newton", "a.npz"), ("mjcf", "a.xml")):
        out = tmp_path / name
        result = runner.invoke(app, ["export", str(asset_dir), "--format", fmt, "--out", str(out)])
        assert result.exit_code == 0, result.output
        assert json.loads(result.output)["out"] == str(out) and out.stat().st_size > 1000
    before = (tmp_path / "a.xml").read_bytes()

    def fails(args, message):
        result = runner.invoke(app, ["export", *args])
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], lines

    fails([str(asset_dir), "--format", "usd", "--out", str(tmp_path / "b")], "--format")
    fails([str(tmp_path / "nope"), "--format", "mjcf", "--out", str(tmp_path / "c.xml")], "nope")
    fails([str(asset_dir), "--format", "mjcf", "--out", str(tmp_path / "a.xml")], "--overwrite")
    assert (tmp_path / "a.xml").read_bytes() == before
    assert not (tmp_path / "b").exists() and not (tmp_path / "c.xml").exists()
    args = ["export", str(asset_dir), "--format", "newton", "--out", str(tmp_path / "a.xml")]
    result = runner.invoke(app, [*args, "--overwrite"])
    assert result.exit_code == 0 and (tmp_path / "a.xml").read_bytes()[:2] == b"PK"  # a zip


def test_failed_write_leaves_no_file(tmp_path):
    def broken(f):
        f.write(b"partial")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        _write_atomically(tmp_path / "out.npz", broken)
    assert list(tmp_path.iterdir()) == []


def test_spring_coefficients_broadcast_a_shared_value(asset_dir):
    asset = read_asset(asset_dir)
    ke, kd = spring_coefficients(asset)
    assert ke.shape == kd.shape == (asset.springs.shape[0],) and ke.dtype == np.float64
    np.testing.assert_allclose(ke * asset.rest_length.double().numpy(), 250.0, rtol=1e-12)


def test_newton_loader_of_the_docs_runs_in_newton(asset_dir, tmp_path):
    """The loader of docs/export.md (skipped without Newton: pip install newton, CPU is enough).
    Before the first contact Newton's semi-implicit solver reproduces our trajectory."""
    newton = pytest.importorskip("newton")
    wp = pytest.importorskip("warp")
    asset = read_asset(asset_dir)
    data = np.load(export_newton(asset, tmp_path / "a.npz"))

    builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=tuple(data["gravity"]))
    for q, qd, m in zip(
        data["particle_q"], data["particle_qd"], data["particle_mass"], strict=True
    ):
        builder.add_particle(wp.vec3(*q), wp.vec3(*qd), float(m), radius=0.002)
    springs = zip(data["spring_indices"], data["spring_ke"], data["spring_kd"], strict=True)
    for (i, j), ke, kd in springs:
        builder.add_spring(int(i), int(j), float(ke), float(kd), 0.0)
    builder.spring_rest_length = data["spring_rest_length"].tolist()
    builder.add_ground_plane(height=float(data["ground_height"]))
    model = builder.finalize(device="cpu")
    solver = newton.solvers.SolverSemiImplicit(model)
    state_0, state_1, control = model.state(), model.state(), model.control()
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    substeps = int(data["substeps"])
    dt = float(data["frame_dt"]) / substeps
    ours = asset.simulate(4).x[0].numpy()
    for frame in range(1, 5):
        for _ in range(substeps):
            state_0.clear_forces()
            pipeline.collide(state_0, contacts)
            solver.step(state_0, state_1, control, contacts, dt)
            state_0, state_1 = state_1, state_0
        np.testing.assert_allclose(state_0.particle_q.numpy(), ours[frame], atol=1e-4)
