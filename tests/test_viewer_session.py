"""The viewer's headless controller: playback, drop, attributes, grips, script, recording, CLI."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from reconphys.assets.asset import PhysicsSettings, write_asset
from reconphys.assets.build import build_asset
from reconphys.assets.normalize import place_on_ground
from reconphys.assets.procedural import make_procedural_gaussians
from reconphys.cli import app
from reconphys.errors import InputError
from reconphys.interact import interaction as interaction_module
from reconphys.interact.recording import write_recording
from reconphys.interact.script import run_script
from reconphys.physics import stable_substeps
from reconphys.physics.control import simulate_frame
from reconphys.viewer import ViewerSession


def make_small_asset(num_gaussians: int = 800, num_anchors: int = 96, height: float = 0.05):
    """A 0.3 m box resting ``height`` above the ground: fast enough for many frames on CPU."""
    gaussians = make_procedural_gaussians("box", num_gaussians, seed=2, size=0.3)
    gaussians = place_on_ground(gaussians, height)
    physics = PhysicsSettings(
        num_anchors=num_anchors, num_neighbors=12, substeps=10, stiffness=400.0, object_id="vbox"
    )
    return build_asset(gaussians, physics)


@pytest.fixture(scope="module")
def asset():
    return make_small_asset()


def test_step_reset_and_drop(asset):
    session = ViewerSession(asset)
    assert session.substeps == max(10, stable_substeps(asset.model(), asset.x0[None], 0.03, 1))
    assert session.advance(5) == 5
    status = session.status()
    assert status.frame == 5 and status.time == pytest.approx(0.15)
    assert torch.all(session.anchor_positions()[:, 2] < asset.x0[:, 2])  # it falls
    session.reset()
    assert torch.equal(session.anchor_positions(), asset.x0)
    assert session.status().frame == 0

    session.drop(0.4)
    means = session.gaussian_means()
    assert float(means[:, 2].min()) == pytest.approx(0.4, abs=1e-5)
    assert torch.allclose(means[:, :2], asset.gaussians.means[:, :2], atol=1e-5)
    assert float(session.state().v.abs().max()) == 0.0
    session.advance(12)  # 0.36 s: a fall of 0.4 m takes 0.29 s
    status = session.status()
    assert status.lowest_z >= -1e-6 and status.lowest_z < 0.01
    with pytest.raises(InputError, match="height"):
        session.drop(-1.0)


def test_attributes_and_substeps_respect_the_stability_bound(asset):
    session = ViewerSession(asset)
    bound = session.status().stable_substeps
    assert session.set_substeps(1) == bound  # never below the bound
    assert session.set_substeps(bound + 7) == bound + 7
    session.set_attributes(stiffness=4000.0, mass=0.5)
    stiffer = session.status().stable_substeps
    assert stiffer > bound and session.substeps >= stiffer
    assert session.attributes["stiffness"] == 4000.0 and session.attributes["mass"] == 0.5
    for bad in ({"mass": 0.0}, {"damping": -1.0}, {"friction": float("nan")}, {"color": 1.0}):
        with pytest.raises(InputError):
            session.set_attributes(**bad)
    with pytest.raises(InputError):
        session.set_substeps(0)


@pytest.mark.parametrize("simulator", ["auto", "autograd"])  # compiled substeps / torch step
def test_grab_lifts_the_held_anchors_without_exploding(asset, simulator, monkeypatch):
    monkeypatch.setenv("RECONPHYS_SIMULATOR", simulator)
    session = ViewerSession(asset)
    session.drop(0.0)
    session.advance(3)
    means = session.gaussian_means()
    top = means[int(torch.argmax(means[:, 2]))]
    # A click from straight above lands on the top of the object.
    picked = session.pick(top + torch.tensor([0.0, 0.0, 1.0]), [0.0, 0.0, -1.0])
    assert picked is not None and float(picked[2]) == pytest.approx(float(top[2]), abs=0.02)
    name = session.grab(picked, count=8)
    held = session.grips()[name]["anchors"]
    assert held.shape == (8,)
    before = session.anchor_positions()[held].mean(0)
    session.move_grip(name, picked + torch.tensor([0.0, 0.0, 0.1]))
    session.advance(15)
    after = session.anchor_positions()[held].mean(0)
    assert float(after[2] - before[2]) == pytest.approx(0.1, abs=0.02)
    assert float(torch.linalg.vector_norm(after[:2] - before[:2])) < 0.02
    status = session.status()
    assert torch.isfinite(session.state().x).all() and status.max_speed < 2.0
    session.release(name)
    assert session.grips() == {}
    with pytest.raises(InputError, match="no such grip"):
        session.move_grip(name, [0.0, 0.0, 0.0])


def test_grip_speed_is_capped(asset):
    session = ViewerSession(asset, max_grip_speed=1.0)
    name = session.grab(asset.x0[0])
    session.move_grip(name, asset.x0[0] + torch.tensor([1.0, 0.0, 0.0]))
    session.advance(2)
    travelled = session.grips()[name]["position"] - asset.x0[0]
    assert float(travelled[0]) == pytest.approx(2 * 1.0 * 0.03, rel=1e-4)


def test_two_grips_stretch_the_object(asset):
    script = [
        {"drop": 0.0},
        {"run": 2},
        {"grab": {"name": "left", "at": "-x", "anchors": 12}},
        {"grab": {"name": "right", "at": "+x", "anchors": 12}},
        {"move": {"grip": "left", "by": [-0.05, 0.0, 0.05], "frames": 10}},
        {"move": {"grip": "right", "by": [0.05, 0.0, 0.05], "frames": 10}},
        {"run": 5},
    ]
    session = ViewerSession(asset)
    recording = run_script(session, script)
    grips = session.grips()
    x = session.anchor_positions()
    left, right = x[grips["left"]["anchors"]].mean(0), x[grips["right"]["anchors"]].mean(0)
    # Rows: the state at the start, the dropped state, then one per frame.
    x_start = recording.anchors[1 + 1 + 2]  # state when the grips were made
    left0 = x_start[grips["left"]["anchors"]].mean(0)
    right0 = x_start[grips["right"]["anchors"]].mean(0)
    stretch = float(right[0] - left[0]) - float(right0[0] - left0[0])
    assert stretch == pytest.approx(0.1, abs=0.03)
    assert torch.isfinite(recording.anchors).all()
    assert recording.anchors.shape == (1 + 1 + 2 + 10 + 10 + 5, asset.num_anchors, 3)
    assert recording.grip_positions[-1].keys() == {"left", "right"}


def test_script_errors_name_the_step(asset):
    session = ViewerSession(asset)
    for steps, where in (
        ([{"run": 1}, {"jump": 1}], "script[1]"),
        ([{"grab": {"name": "a", "at": "sideways"}}], "script[0].grab"),
        ([{"move": {"grip": "nobody", "by": [0, 0, 1]}}], "script[0].move"),
        ([{"set": {"substeps": 0}}], "substeps"),
    ):
        with pytest.raises(InputError, match=where.replace("[", r"\[")):
            run_script(session, steps)
        session.stop_recording()


def test_background_loop_runs_and_never_blocks_callers(asset, monkeypatch):
    def slow_frame(*args):  # a simulation far slower than the UI: calls must not wait for it
        time.sleep(0.5)
        return simulate_frame(*args)

    monkeypatch.setattr(interaction_module, "simulate_frame", slow_frame)
    session = ViewerSession(asset, realtime=False)
    session.start()
    try:
        session.play()
        deadline = time.perf_counter() + 20
        while session.status().frame < 1 and time.perf_counter() < deadline:
            time.sleep(0.01)
        assert session.status().frame >= 1
        slowest = 0.0
        for _ in range(5):
            started = time.perf_counter()
            session.status()
            session.gaussian_means()
            name = session.grab(asset.x0[0])
            session.move_grip(name, asset.x0[0] + 0.01)
            session.set_attributes(damping=2.0)
            session.release(name)
            slowest = max(slowest, time.perf_counter() - started)
        assert slowest < 0.25, f"a UI call waited {slowest:.2f} s for the simulation"
        session.pause()
        frame = session.status().frame
        time.sleep(0.1)
        session.request_step(1)
        deadline = time.perf_counter() + 20
        while session.status().frame < frame + 1 and time.perf_counter() < deadline:
            time.sleep(0.01)
        assert session.status().frame >= frame + 1
    finally:
        session.close()


def test_recording_writes_trajectory_and_video(asset, tmp_path):
    session = ViewerSession(asset)
    session.start_recording()
    session.advance(4)
    recording = session.stop_recording()
    assert recording.anchors.shape == (5, asset.num_anchors, 3)
    paths = write_recording(asset, recording, tmp_path / "rec", resolution=32)
    with np.load(paths["trajectory"]) as data:
        assert data["anchors"].shape == (5, asset.num_anchors, 3)
        assert int(data["substeps_used"]) == session.substeps
    assert paths["video"].stat().st_size > 0
    info = json.loads(paths["interaction"].read_text())
    assert info["frames"] == 4 and len(info["substeps_per_frame"]) == 5


runner = CliRunner()


@pytest.fixture(scope="module")
def asset_dir(asset, tmp_path_factory):
    folder = tmp_path_factory.mktemp("viewer") / "asset"
    write_asset(asset, folder)
    return folder


def test_cli_view_script_and_benchmark(asset_dir, tmp_path):
    script = tmp_path / "grab.json"
    script.write_text(
        json.dumps(
            [
                {"grab": {"name": "top", "at": "+z"}},
                {"move": {"grip": "top", "by": [0, 0, 0.05], "frames": 3}},
                {"release": "all"},
                {"run": 2},
            ]
        )
    )
    out = tmp_path / "out"
    args = ["view", str(asset_dir), "--script", str(script), "--out", str(out)]
    result = runner.invoke(app, [*args, "--resolution", "32", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output.strip().splitlines()[-1])
    assert summary["frames"] == 5
    assert (out / "trajectory.npz").exists() and (out / "interaction.mp4").exists()

    result = runner.invoke(app, ["view", str(asset_dir), "--benchmark", "2", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in result.output.strip().splitlines()]
    assert [r["grip"] for r in rows] == [False, True]
    assert all(r["frames"] == 2 and r["frames_per_second"] > 0 for r in rows)


def test_cli_view_errors_are_one_line(asset_dir, tmp_path, monkeypatch):
    result = runner.invoke(app, ["view", str(asset_dir), "--script", str(tmp_path / "no.json")])
    assert result.exit_code == 2 and result.output.startswith("error:")
    bad = tmp_path / "bad.json"
    bad.write_text('{"run": 1}')
    result = runner.invoke(app, ["view", str(asset_dir), "--script", str(bad), "--out", "x"])
    assert result.exit_code == 2 and "JSON list" in result.output
    result = runner.invoke(app, ["view", str(tmp_path / "missing")])
    assert result.exit_code == 2 and result.output.startswith("error:")
    monkeypatch.setitem(sys.modules, "viser", None)  # as if viser were not installed
    result = runner.invoke(app, ["view", str(asset_dir), "--port", "0"])
    assert result.exit_code == 2
    assert "pip install 'reconphys[viewer]'" in result.output
    assert len(result.output.strip().splitlines()) == 1
