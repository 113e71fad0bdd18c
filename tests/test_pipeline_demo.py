"""``reconphys demo``: the shipped recording goes through ``predict``, and the summary reports what
``predict`` computed beside the truth; an unknown example or a foreign OUT is refused."""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from reconphys.assets.asset import read_asset
from reconphys.cli import app
from reconphys.errors import InputError
from reconphys.pipeline.demo import (
    DEFAULT_EXAMPLE,
    EXAMPLES_DIR,
    OBSERVABLE_LABELS,
    example_names,
    load_example,
    prior_centre,
    true_observables,
)

runner = CliRunner()


def test_the_examples_ship_small_and_complete():
    assert DEFAULT_EXAMPLE in example_names() and "duck_toss_scene" in example_names()
    for name in example_names():
        example = load_example(name)
        size = sum(p.stat().st_size for p in example.folder.iterdir())
        assert size < 2_000_000  # the budget for shipped recordings
        assert example.truth["launch"] in ("drop", "toss")
    # the realistic example is the default's toss in a scene: the same physics
    scene = load_example("duck_toss_scene").truth
    assert scene["attributes"] == load_example(DEFAULT_EXAMPLE).truth["attributes"]


def test_unknown_or_incomplete_examples_are_refused(tmp_path):
    with pytest.raises(InputError, match="no such example"):
        load_example("no-such-example")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "truth.json").write_text(
        json.dumps({"format": "reconphys.example", "version": 1, "attributes": {"mass": 1.0}})
    )
    with pytest.raises(InputError, match="four true attributes"):
        load_example("broken", root=tmp_path)


def test_observables_and_the_prior_centre_by_hand():
    got = true_observables({"mass": 2.0, "stiffness": 800.0, "damping": 0.5, "friction": 0.3})
    assert got["log_k_over_m"] == pytest.approx(math.log(400.0))
    assert got["log_d_over_m"] == pytest.approx(math.log(0.25))
    assert got["friction"] == pytest.approx(0.3)
    centre = prior_centre()  # geometric means of the design ranges (docs/design.md)
    assert centre["log_k_over_m"] == pytest.approx(math.log(math.sqrt(10 * 1200) / math.sqrt(1.2)))
    assert centre["log_d_over_m"] == pytest.approx(math.log(math.sqrt(0.5) / math.sqrt(1.2)))
    assert centre["friction"] == pytest.approx(0.5)


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "demo_out"
    result = runner.invoke(app, ["demo", "--out", str(out), "--no-refine", "--device", "cpu"])
    assert result.exit_code == 0, result.output
    return out, result.output


def test_demo_writes_the_asset_preview_sheet_and_summary(demo_out):
    out, printed = demo_out
    for name in ("preview.mp4", "contact_sheet.png", "prediction.json", "summary.md"):
        assert (out / name).stat().st_size > 0, name
    asset = read_asset(out / "asset")
    prediction = json.loads((out / "prediction.json").read_text())
    assert prediction["gaussians"] == asset.gaussians.num_gaussians
    assert "no ground truth" in printed and str(out / "asset") in printed


def test_summary_numbers_are_what_predict_computed(demo_out):
    out, _ = demo_out
    prediction = json.loads((out / "prediction.json").read_text())
    summary = (out / "summary.md").read_text()
    truth = true_observables(load_example(DEFAULT_EXAMPLE).truth["attributes"])
    for name, value in prediction["observables"].items():
        row = next(
            x for x in summary.splitlines() if x.startswith(f"| {OBSERVABLE_LABELS[name]} |")
        )
        cells = [c.strip() for c in row.split("|")[1:-1]]
        assert cells[1] == f"{truth[name]:.2f}"  # true
        assert cells[2] == f"**{value:.2f}**"  # predicted: what the asset holds
        low, high = prediction["intervals"][name]  # --no-refine: the network's own belief
        assert cells[4].startswith(f"[{low:.2f}, {high:.2f}]") and "belief" in cells[5]
    timings = prediction["timings_s"]
    assert f"decode {timings['decode']:.2f}" in summary


def test_summary_gives_the_spin_read_beside_the_true_one(demo_out):
    """With the search (the default) predict reads the spin about the view: the summary puts
    it beside the truth's, the true spin projected on the camera file's viewing axis."""
    from reconphys.pipeline.demo import summary_markdown

    out, _ = demo_out
    prediction = json.loads((out / "prediction.json").read_text())
    example = load_example(DEFAULT_EXAMPLE)
    assert "angular" not in prediction["initial_velocity"]  # --no-refine: not read
    prediction["initial_velocity"]["angular"] = {
        "about_view_rad_s": 0.5, "about_view_sd_rad_s": 0.25, "shown": True
    }  # fmt: skip
    line = next(
        x
        for x in summary_markdown(example, prediction, 1.0, out).splitlines()
        if x.startswith("Spin about the viewing axis")
    )
    view_axis = json.loads(example.camera.read_text())["world_to_cam"][2][:3]
    spin = example.truth["initial_angular_velocity_rad_s"]
    true_roll = sum(a * w for a, w in zip(view_axis, spin, strict=True))
    assert "estimated +0.50 (± 0.25; kept)" in line and f"true {true_roll:+.2f}" in line


def test_summary_says_how_sure_the_masks_are(demo_out):
    """The demo's recording goes through the mask segmenter: prediction.json rates its masks and
    the summary gives the expected IoU and its interval (and a check when it warns)."""
    from reconphys.pipeline.demo import summary_markdown

    out, _ = demo_out
    prediction = json.loads((out / "prediction.json").read_text())
    rating = prediction["input"]["masks_rating"]
    assert 0.0 <= rating["expected_iou_10_90"][0] <= rating["expected_iou"] <= 1.0
    summary = (out / "summary.md").read_text()
    line = next(x for x in summary.splitlines() if x.startswith("Masks:"))
    assert f"expected near {rating['expected_iou']:.2f}" in line
    assert ("check their outline" in line) == ("warning" in rating)
    prediction["input"]["masks_rating"] = {**rating, "warning": "unsure"}
    warned = summary_markdown(load_example(DEFAULT_EXAMPLE), prediction, 1.0, out)
    assert "check their outline in the preview" in warned


def test_demo_refuses_a_folder_it_did_not_write(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    result = runner.invoke(app, ["demo", "--out", str(out), "--no-refine", "--device", "cpu"])
    assert result.exit_code == 2 and "not a demo's output" in result.output
    assert (out / "notes.txt").read_text() == "keep me"
    result = runner.invoke(app, ["demo", "--out", str(tmp_path / "x"), "--example", "nope"])
    assert result.exit_code == 2 and "no such example" in result.output


def test_list_and_the_procedural_example(tmp_path):
    result = runner.invoke(app, ["demo", "--list"])
    assert result.exit_code == 0
    assert all(name in result.output for name in (*example_names(), "procedural"))
    out = tmp_path / "proc"
    args = ["demo", "--example", "procedural", "--out", str(out), "--frames", "3"]
    args += ["--resolution", "32", "--num-gaussians", "300", "--num-anchors", "24"]
    result = runner.invoke(app, [*args, "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert read_asset(out / "asset").num_anchors == 24
    assert (out / "simulation.mp4").is_file()
    # a second run replaces the earlier demo's folder without --overwrite
    assert runner.invoke(app, [*args, "--device", "cpu"]).exit_code == 0


def test_examples_folder_is_package_data():
    assert EXAMPLES_DIR.name == "examples" and (EXAMPLES_DIR / "README.md").is_file()
