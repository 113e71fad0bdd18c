"""``reconphys simulate --script / --push``: scripted interaction (interact/script.py) driving an
offline run through the viewer's controller."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from reconphys.cli import app

runner = CliRunner()
QUIET = ["--no-render", "--device", "cpu"]


@pytest.fixture(scope="module")
def asset_dir(small_asset_dir):
    return small_asset_dir


def simulate(asset_dir, out, *args) -> np.ndarray:
    """Run ``reconphys simulate`` and return the anchors [T+1, N_A, 3] it wrote."""
    result = runner.invoke(app, ["simulate", str(asset_dir), "--out", str(out), *QUIET, *args])
    assert result.exit_code == 0, result.output
    with np.load(out / "trajectory.npz") as data:
        return data["anchors"]


def write_script(path, steps) -> str:
    path.write_text(json.dumps(steps))
    return str(path)


@pytest.fixture(scope="module")
def plain(asset_dir, tmp_path_factory):
    return simulate(asset_dir, tmp_path_factory.mktemp("plain"), "--frames", "30")


@pytest.fixture(scope="module")
def pushed(asset_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("push")
    return simulate(asset_dir, out, "--frames", "30", "--push", "0.1,0,0"), out


def test_push_moves_the_centroid_in_the_push_direction(plain, pushed):
    anchors, _ = pushed
    assert anchors.shape == plain.shape == (31, 48, 3)
    shift = anchors.mean(1) - plain.mean(1)  # [T+1, 3] metres
    # Nothing happens before the grab at frame 30 // 3 = 10.
    np.testing.assert_array_equal(anchors[:11], plain[:11])
    # During the 10 frames of the move the object follows the grip towards +x.
    assert shift[20, 0] > 0.05, shift[20]
    assert shift[-1, 0] > 0.05 and shift[-1, 0] > 2 * abs(shift[-1, 1]), shift[-1]


def test_push_equals_the_explicit_script(asset_dir, pushed, tmp_path):
    anchors, out = pushed
    steps = [
        {"run": 10},
        {"grab": {"name": "push", "at": "-x"}},
        {"move": {"grip": "push", "by": [0.1, 0, 0], "frames": 10}},
        {"release": "push"},
        {"run": 10},
    ]
    script = write_script(tmp_path / "push.json", steps)
    scripted = simulate(asset_dir, tmp_path / "o", "--script", script)
    np.testing.assert_array_equal(scripted, anchors)
    info = json.loads((tmp_path / "o" / "interaction.json").read_text())
    assert info == json.loads((out / "interaction.json").read_text())
    held = [row for row in info["grip_positions_m"] if "push" in row]
    assert len(held) == 10  # frames 11–20 record the grip
    np.testing.assert_allclose(
        np.array(held[-1]["push"]) - np.array(held[0]["push"]), [0.09, 0, 0], atol=1e-6
    )


def test_a_run_only_script_is_plain_simulate(asset_dir, tmp_path):
    reference = simulate(asset_dir, tmp_path / "plain", "--frames", "12")
    script = write_script(tmp_path / "run.json", [{"run": 12}])
    scripted = simulate(asset_dir, tmp_path / "script", "--script", script)
    assert scripted.shape == reference.shape
    np.testing.assert_allclose(scripted, reference, atol=1e-5)
    # --frames continues a shorter script with free frames up to the total.
    padded = simulate(asset_dir, tmp_path / "pad", "--script", write_script(
        tmp_path / "short.json", [{"run": 5}]), "--frames", "12")  # fmt: skip
    np.testing.assert_allclose(padded, reference, atol=1e-5)


def test_script_renders_the_video_and_preview(asset_dir, tmp_path):
    script = write_script(tmp_path / "s.json", [{"grab": {"at": "+z"}}, {"run": 3}])
    out = tmp_path / "o"
    args = ["simulate", str(asset_dir), "--out", str(out), "--script", script]
    result = runner.invoke(app, [*args, "--resolution", "32", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert '"frames": 3,' in result.output
    import imageio.v2 as imageio

    frames = imageio.mimread(out / "simulation.mp4")
    assert len(frames) == 4 and frames[0].shape == (32, 32, 3)
    assert (out / "preview.png").is_file() and (out / "interaction.json").is_file()


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "file not found"),
        ("{not json", "not valid JSON"),
        ('{"run": 3}', "expected a JSON list"),
        ('[{"run": 2}, {"jump": 1}]', "script[1]"),
        ('[{"move": {"grip": "nobody", "by": [0, 0, 1]}}]', "no such grip"),
        ('[{"run": 20}]', "more than the 5 asked for"),
    ],
)
def test_bad_script_is_a_one_line_error_and_writes_nothing(asset_dir, tmp_path, content, message):
    script = tmp_path / "bad.json"
    if content is not None:
        script.write_text(content)
    out = tmp_path / "o"
    args = ["simulate", str(asset_dir), "--out", str(out), "--script", str(script), *QUIET]
    result = runner.invoke(app, [*args, "--frames", "5"])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0], lines
    assert not out.exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--push", "0.1,0"], "--push"),
        (["--push", "a,b,c"], "--push"),
        (["--push", "0,0,0"], "must not be zero"),
        (["--push", "0.1,0,0", "--script", "x.json"], "not both"),
        (["--push", "0.1,0,0", "--frames", "0"], "--frames"),
    ],
)
def test_bad_push_is_a_one_line_error(asset_dir, tmp_path, args, message):
    out = tmp_path / "o"
    result = runner.invoke(app, ["simulate", str(asset_dir), "--out", str(out), *QUIET, *args])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
    assert not out.exists()


def test_push_in_a_negative_direction_grabs_the_other_side():
    from reconphys.interact.script import push_script

    steps = push_script(7, (0.0, -0.05, 0.02))
    assert steps[0] == {"run": 2}
    assert steps[1] == {"grab": {"name": "push", "at": "+y"}}
    assert steps[2]["move"]["frames"] == 5 and steps[4] == {"run": 0}
