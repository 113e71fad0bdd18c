"""``reconphys predict``: recording → asset, through the documented video path.

A tiny dataset (1 test object, 32 px, 300 Gaussians, 64 anchors) is made once per module; its
sample is exported with ``data video`` (the encoded mp4, the camera file, the frame-0 Gaussians)
and predicted from there, and compared with the prediction from the stored frames.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from helpers import make_tiny_dataset, rim_noise, train_tiny_gaussian_predictor
from typer.testing import CliRunner

from reconphys.assets.asset import read_asset
from reconphys.capture import default_camera, load_observation
from reconphys.capture.masks import STILL_FRAMES
from reconphys.capture.placement import (
    GRAVITY_MAGNITUDE,
    fit_to_mask,
    linear_velocity_fit,
    velocity_residual,
)
from reconphys.capture.video import resample_indices, resample_times
from reconphys.cli import app
from reconphys.errors import InputError
from reconphys.geometry import rigid_velocity
from reconphys.models.model_input import predictor_frames
from reconphys.models.physics_predictor import resize_frames
from reconphys.pipeline.search import GIVEN_GEOMETRY_TEMPERATURE, network_intervals, temperature_for
from reconphys.render import Cameras, render
from reconphys.render.cameras import dataset_views, intrinsics_from_fov

runner = CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_tiny_dataset(tmp_path_factory.mktemp("predict") / "data", seed=5)


@pytest.fixture(scope="module")
def sample_id(dataset):
    return json.loads((dataset / "manifest.json").read_text())["samples"][0]["id"]


@pytest.fixture(scope="module")
def bundle(dataset, sample_id, tmp_path_factory):
    out = tmp_path_factory.mktemp("bundle") / "b"
    result = runner.invoke(app, ["data", "video", str(dataset), sample_id, str(out)])
    assert result.exit_code == 0, result.output
    return out


def _predict(args, tmp_path, name="asset"):
    out = tmp_path / name
    result = runner.invoke(app, ["predict", *map(str, args), "--out", str(out)])
    return result, out


def test_mp4_path_gives_the_stored_frames_prediction_and_a_full_asset(
    dataset, sample_id, bundle, tmp_path
):
    result, out = _predict(
        [
            bundle / "video.mp4",
            "--camera",
            bundle / "camera.json",
            "--gaussians",
            bundle / "gaussians.ply",
            "--preview-frames",
            "8",
        ],
        tmp_path,
    )
    assert result.exit_code == 0, result.output
    for name in (
        "gaussians.ply",
        "anchors.npz",
        "binding.npz",
        "physics.json",
        "preview.mp4",
        "preview.png",
        "prediction.json",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((out / "prediction.json").read_text())
    assert summary["placement"] == "as-is" and summary["silhouette_iou_given"] > 0.5
    # the plain look (object on black, a camera file): the shipped track network reads it
    assert summary["model"].endswith("physics_predictor.safetensors")
    assert "plain look" in summary["model_choice"]
    assert "physics network: " in result.output and "(the plain look" in result.output
    motion = summary["initial_velocity"]
    assert motion["released_from_rest"] == (not any(motion["linear_m_s"]))
    # the spin about the view is read where the clip moves (pipeline/spin.py), and the asset
    # starts with it: kept, or zero where the frames do not show it
    if not motion["released_from_rest"]:
        spin = motion["angular"]
        assert spin["frames_compared"] >= 0 and "about the viewing axis" in spin["how"]
        assert any(motion["angular_rad_s"]) == spin["shown"]
        asset = read_asset(out)
        centre = asset.gaussians.means.mean(0)
        expected = rigid_velocity(
            asset.x0,
            torch.tensor(motion["linear_m_s"]),
            torch.tensor(motion["angular_rad_s"]),
            centre,
        )
        assert torch.allclose(asset.v0, expected, atol=1e-3)
    steps = ("decode", "gaussians", "physics_network", "asset_build", "search", "write", "preview")
    for step in steps:
        assert summary["timings_s"][step] >= 0
    intervals = summary["intervals"]  # the default path searches and gives an interval each
    assert list(intervals) == ["log_k_over_m", "log_d_over_m", "friction"]
    assert all(low <= high for low, high in intervals.values())
    assert "search:" in result.output and "10–90 %" in result.output
    sheet = imageio.imread(out / "preview.png")  # frames above, the intervals written below
    caption = sheet[-3 * 12 :]
    assert caption.max() > 200 and (caption == 0).mean() > 0.8  # white text on black
    preview = imageio.mimread(out / "preview.mp4")
    assert len(preview) == 30  # at least the observed frames
    assert preview[0].shape[1] > 2 * preview[0].shape[0]  # observed | simulated side by side

    stored, stored_out = _predict(
        [dataset, "--sample", sample_id, "--preview-frames", "0", "--no-refine"], tmp_path, "ff"
    )
    assert stored.exit_code == 0, stored.output
    assert "network's belief" in stored.output
    reference = json.loads((stored_out / "prediction.json").read_text())
    assert reference["geometry"].startswith("ground truth")
    assert "search" not in reference["timings_s"]
    # --no-refine: the shipped ensemble's own interval, ±1.2816 σ around its answer (cut)
    assert "network's belief alone" in reference["intervals_how"]
    sigma = torch.tensor(list(reference["network_sigma"].values()), dtype=torch.float64)
    answer = torch.tensor(list(reference["observables"].values()), dtype=torch.float64)
    assert (sigma > 0).all()
    expected = network_intervals(answer, sigma)
    for name, (low, high) in reference["intervals"].items():
        assert [low, high] == pytest.approx(expected[name], abs=1e-3)
        assert low <= reference["observables"][name] <= high
    # a given PLY: the search's profiles times the network's belief (the initial state is read
    # from the masks, not known), as on a 3DGS predictor's geometry; the dataset's own asset and
    # initial state (--sample, the † path) keep the profiles alone
    assert summary["search"]["network_sigma"] == pytest.approx(
        list(summary["network_sigma"].values()), abs=1e-3
    )
    assert "times the network's belief" in summary["intervals_how"]
    found = summary["search"]
    height, width = found["render_size"]
    # the rebuilt asset's law (the one its factor and the belief were chosen under)
    expected = temperature_for(height * width, found["supersample"], rebuilt=True)
    assert found["temperature"] == pytest.approx(
        [GIVEN_GEOMETRY_TEMPERATURE * t for t in expected], rel=1e-6
    )
    assert reference["attributes"] == reference["feed_forward"]
    a, b = summary["feed_forward"], reference["attributes"]
    # H.264 at 32 px changes the input a little: the prediction may move, not jump
    assert abs(math.log(a["stiffness"] / a["mass"]) - math.log(b["stiffness"] / b["mass"])) < 0.5
    assert abs(a["friction"] - b["friction"]) < 0.2
    physics = json.loads((out / "physics.json").read_text())
    assert physics["stiffness"] == pytest.approx(summary["attributes"]["stiffness"], rel=1e-6)
    assert physics["intervals"] == intervals


def test_refine_from_the_command_line(dataset, sample_id, tmp_path):
    result, out = _predict(
        [
            dataset,
            "--sample",
            sample_id,
            "--no-refine",
            "--refine-steps",
            "2",
            "--refine-resolution",
            "16",
            "--preview-frames",
            "0",
        ],
        tmp_path,
    )
    assert result.exit_code == 0, result.output
    assert "refine: 2 steps" in result.output
    summary = json.loads((out / "prediction.json").read_text())
    history = summary["refine"]
    assert len(history["loss_curve"]) == 3 and history["render_size"] == [16, 16]
    assert history["loss_best"] == pytest.approx(min(history["loss_curve"]), abs=1e-6)
    physics = json.loads((out / "physics.json").read_text())
    assert physics["stiffness"] == pytest.approx(history["attributes"]["stiffness"], rel=1e-6)
    assert summary["feed_forward"]["mass"] == pytest.approx(physics["mass"], rel=1e-6)


def test_ground_from_the_landed_object(bundle, tmp_path):
    result, out = _predict(
        [
            bundle / "video.mp4",
            "--camera",
            bundle / "camera.json",
            "--gaussians",
            bundle / "gaussians.ply",
            "--preview-frames",
            "0",
            "--no-refine",  # the ground is read before the search: no need to run it
            "--ground",
            "landed",
        ],
        tmp_path,
    )
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "prediction.json").read_text())
    physics = json.loads((out / "physics.json").read_text())
    assert physics["ground_height"] == pytest.approx(summary["ground_check_m"], abs=1e-4)
    assert abs(physics["ground_height"]) < 0.25  # the truth is 0; ± a few 32-px pixels' depth


def test_python_api_returns_the_asset(dataset, sample_id):
    import reconphys

    result = reconphys.predict(dataset, sample=sample_id)
    assert result.asset.num_anchors == 64
    assert set(result.timings) >= {"decode", "physics_network", "asset_build"}
    trajectory = result.asset.simulate(3)
    assert trajectory.x.shape[-2:] == (64, 3) and bool(torch.isfinite(trajectory.x).all())


def test_a_dataset_sample_takes_masks_and_refuses_recording_options(dataset, sample_id, tmp_path):
    from reconphys.pipeline.samples import load_input

    stored, _ = load_input(dataset, sample=sample_id)
    # a segmentation tool's masks: the backdrop's, one pixel smaller (so they differ from it)
    given = -torch.nn.functional.max_pool2d(-stored.masks[:, None], 3, 1, 1)[:, 0]
    assert 0 < int(given.sum()) < int(stored.masks.sum())
    folder = tmp_path / "masks"
    folder.mkdir()
    for i, mask in enumerate(given):
        imageio.imwrite(folder / f"{i:03d}.png", (mask.numpy() * 255).astype(np.uint8))
    observation, truth = load_input(dataset, sample=sample_id, masks=folder)
    assert truth is not None and torch.equal(observation.masks, given)
    assert observation.mask_source == f"mask folder {folder}"
    # the frames the network reads are the recording within the given masks
    assert torch.equal(observation.frames, observation.recording * given[..., None])
    (folder / "000.png").unlink()  # one mask short: refused, naming the folder
    with pytest.raises(InputError, match="mask images for"):
        load_input(dataset, sample=sample_id, masks=folder)
    for option in (
        *({"camera": "c.json"}, {"fps": 30.0}, {"fov_deg": 50.0}, {"background": "b"}),
        {"touch": "rigid"},
        {"drop_height": 0.4},
    ):
        with pytest.raises(InputError, match="is for recordings, not dataset samples"):
            load_input(dataset, sample=sample_id, **option)
    with pytest.raises(InputError, match="--camera, --fps are for recordings"):  # all, at once
        load_input(dataset, sample=sample_id, camera="c.json", fps=30.0)
    result, out = _predict([dataset, "--sample", sample_id, "--camera", "c.json"], tmp_path)
    assert result.exit_code != 0 and "--camera is for recordings" in result.output
    assert not out.exists()


def test_the_bundles_truth_holds_the_drop_height_predict_takes(dataset, sample_id, bundle):
    """`data video`'s truth.json: frame 0's lowest anchor above the ground (z = 0), metres, the
    value a user gives `predict --drop-height`; the sample's attributes beside it."""
    from reconphys.data import DropDataset

    truth = json.loads((bundle / "truth.json").read_text())
    stored = DropDataset(dataset, views=[0], verify=False)
    index = stored.index_of(sample_id)
    lowest = float(stored[index]["anchors"][0][:, 2].min())
    assert truth["drop_height_m"] == pytest.approx(lowest, abs=1e-4) and lowest > 0
    assert truth["stiffness"] == stored.meta(index)["attributes"]["stiffness"]


def test_a_recording_refuses_a_dataset_samples_view(bundle, tmp_path):
    result, out = _predict([bundle / "video.mp4", "--view", "1"], tmp_path)
    assert result.exit_code != 0 and "--view is for dataset samples" in result.output
    assert not out.exists()


def test_resampling_picks_the_nearest_frames():
    assert resample_indices(30, 1 / 0.03, 0.03).tolist() == list(range(30))
    assert resample_indices(59, 2 / 0.03, 0.03).tolist() == list(range(0, 59, 2))
    # a GIF: frames appear at 0, 0.03, 0.06 and 0.12 s (the third held twice as long), end 0.15 s
    assert resample_times(np.array([0.0, 0.03, 0.06, 0.12, 0.15]), 0.03).tolist() == [0, 1, 2, 2, 3]
    picks = resample_indices(100, 60.0, 0.03)  # 0.03 s = 1.8 recorded frames
    assert picks[:4].tolist() == [0, 2, 4, 5] and len(picks) == 56  # 99/60 s / 0.03 s + 1


def test_a_double_rate_video_is_resampled_to_frame_dt(bundle, tmp_path):
    frames = imageio.mimread(bundle / "video.mp4")
    doubled = tmp_path / "double.mp4"
    imageio.mimwrite(
        doubled,
        [f for f in frames for _ in (0, 1)],
        fps=2 / 0.03,
        codec="libx264",
        quality=10,
        macro_block_size=1,
    )
    original = load_observation(bundle / "video.mp4", camera=bundle / "camera.json")
    resampled = load_observation(doubled, camera=bundle / "camera.json")
    assert resampled.num_frames == original.num_frames
    assert (resampled.frames - original.frames).abs().mean() < 0.02


def test_a_long_large_recording_is_read_as_a_clip_at_the_working_size(bundle, tmp_path):
    from reconphys.capture.observation import CLIP_FRAMES
    from reconphys.capture.video import WORK_MAX_SIDE

    frames = np.stack(imageio.mimread(bundle / "video.mp4"))  # [30, H, W, 3]
    factor = WORK_MAX_SIDE // frames.shape[1] + 4  # larger than the working size
    large = frames.repeat(factor, 1).repeat(factor, 2)
    still = np.repeat(large[-1:], 40, 0)  # the object at rest for 1.3 s more: a phone clip
    path = tmp_path / "long.mp4"
    imageio.mimwrite(path, list(np.concatenate([large, still])), fps=1 / 0.03, quality=8)
    original = load_observation(bundle / "video.mp4", camera=bundle / "camera.json")
    read = load_observation(path, camera=bundle / "camera.json")
    assert read.num_frames == CLIP_FRAMES and read.recorded_frames <= CLIP_FRAMES + 1
    side = large.shape[1]
    assert read.recorded_size == (side, side) and read.size == (WORK_MAX_SIDE, WORK_MAX_SIDE)
    scale = WORK_MAX_SIDE / frames.shape[1]
    assert torch.allclose(
        read.camera.K, original.camera.K * torch.tensor([scale, scale, 1.0])[:, None]
    )
    for a, b in zip(original.masks, read.masks, strict=True):  # the same object, 20× the pixels
        centre_a = torch.nonzero(a > 0.5).double().mean(0) + 0.5
        centre_b = torch.nonzero(b > 0.5).double().mean(0) + 0.5
        assert (centre_b / scale - centre_a).abs().max() < 0.3


def test_start_and_end_cut_the_recording_to_the_release(bundle, tmp_path, monkeypatch):
    assert resample_indices(100, 1 / 0.03, 0.03, start=0.3).tolist() == list(range(10, 100))
    assert resample_indices(100, 1 / 0.03, 0.03, 0.3, end=0.9).tolist() == list(range(10, 31))
    times = np.array([0.0, 0.03, 0.06, 0.12, 0.15])  # a GIF's display times, end 0.15 s
    assert resample_times(times, 0.03, start=0.06).tolist() == [2, 2, 3]
    with pytest.raises(InputError, match="after the recording's end"):
        resample_indices(30, 1 / 0.03, 0.03, start=1.0)
    # a recording that starts 0.3 s before the release (the object held still) reads, from
    # --start 0.3, as the clip that starts at the release
    frames = imageio.mimread(bundle / "video.mp4")
    held = tmp_path / "held.mp4"
    imageio.mimwrite(
        held,
        [frames[0]] * 10 + frames,
        fps=1 / 0.03,
        codec="libx264",
        quality=10,
        macro_block_size=1,
    )
    original = load_observation(bundle / "video.mp4", camera=bundle / "camera.json")
    cut = load_observation(held, camera=bundle / "camera.json", start=0.3)
    assert cut.num_frames == original.num_frames
    assert (cut.frames - original.frames).abs().mean() < 0.01
    # the hold before a start given is read from the frames before it (masks.read_release, as
    # --start auto reads it), its time in the recording's seconds; not where the start given is
    # more than GIVEN_RELEASE_SLACK_FRAMES off that release, nor where nothing is held
    assert cut.release is not None and cut.release.held_frames >= STILL_FRAMES
    assert cut.release.time_s == pytest.approx(0.3, abs=0.03)
    # ... on the clip's own decoded frames (the video is decoded once)
    import reconphys.capture.observation as observation_module

    decoded = []
    read_video = observation_module.read_video
    monkeypatch.setattr(
        observation_module, "read_video", lambda *a: decoded.append(a) or read_video(*a)
    )
    late = load_observation(held, camera=bundle / "camera.json", start=0.36)
    assert late.release is not None and late.release.time_s == pytest.approx(0.3, abs=0.03)
    assert len(decoded) == 1
    monkeypatch.undo()
    assert load_observation(held, camera=bundle / "camera.json", start=0.45).release is None
    assert load_observation(bundle / "video.mp4", camera=bundle / "camera.json").release is None
    assert (
        load_observation(bundle / "video.mp4", start=0.15, camera=bundle / "camera.json").release
        is None
    )
    # from the recording's start (or too early) the object is still for 11 (6) frames: refused,
    # with the --start to give (two frames before it moves: 0.27 s; 0.3 s is the release)
    for start, release in ((0.0, "0.27"), (0.15, "0.27")):
        with pytest.raises(InputError, match=f"does not move.*about {release} here"):
            load_observation(held, camera=bundle / "camera.json", start=start)
    # --start auto reads the release from the masks: the same clip as --start 0.3 (to a frame),
    # and a clip that is not held stays as it is
    auto = load_observation(held, camera=bundle / "camera.json", start="auto")
    assert auto.start_s == pytest.approx(0.3, abs=0.03)
    assert auto.num_frames >= original.num_frames - 1
    count = min(auto.num_frames, original.num_frames)
    shift = round((auto.start_s - 0.3) / 0.03)
    assert (
        auto.frames[: count - 1] - original.frames[shift : shift + count - 1]
    ).abs().mean() < 0.01
    assert load_observation(bundle / "video.mp4", start="auto").start_s == 0.0
    result, out = _predict([held, "--start", "auto", "--camera", bundle / "camera.json",
                            "--no-refine", "--preview-frames", "0"], tmp_path, "auto")  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "release read from the masks at 0.3" in result.output
    written = json.loads((out / "prediction.json").read_text())
    read = written["input"]
    assert read["start_how"].startswith("read from the masks") and read["start_s"] > 0.25
    # the hold read: let go from rest means at rest (models/reconstruct.held_then_let_go)
    assert read["release"]["held_frames"] >= 9
    if read["release"]["from_rest"]:
        assert written["initial_velocity"]["released_from_rest"]
        assert written["initial_velocity"]["how"].startswith("at rest: the recording shows")
    # a start given a frame after the release: the hold before it read, and a fall from rest
    result, out = _predict([held, "--start", "0.33", "--camera", bundle / "camera.json",
                            "--no-refine", "--preview-frames", "0"], tmp_path, "given")  # fmt: skip
    assert result.exit_code == 0, result.output
    written = json.loads((out / "prediction.json").read_text())
    read = written["input"]
    assert read["start_how"].startswith("given (--start); before it the object is held still")
    assert read["release"]["time_s"] == pytest.approx(0.3, abs=0.03)
    assert "--start 0.33: before it the object is held still" in result.output
    if read["release"]["from_rest"]:
        fallen = 0.33 - read["release"]["time_s"]
        velocity = written["initial_velocity"]["linear_m_s"]
        assert velocity == pytest.approx([0, 0, -GRAVITY_MAGNITUDE * fallen], abs=1e-3)
    result, out = _predict([held, "--start", "2", "--camera", bundle / "camera.json"], tmp_path)
    assert result.exit_code == 2 and "--start" in result.output and not out.exists()
    result, out = _predict([held, "--start", "soon"], tmp_path)
    assert result.exit_code == 2 and "'auto'" in result.output and not out.exists()
    result, out = _predict([held, "--start", "0.3", "--end", "0.1"], tmp_path)
    assert result.exit_code == 2 and "--end" in result.output and not out.exists()
    # a cut shorter than the model reads is refused for its length, before its masks and its
    # camera are read (no mask folder, no camera file: the segmenter would run and the camera's
    # estimate refuse the short fall with the wrong advice)
    with pytest.raises(InputError, match=r"5 frames at 0.03 s .*reads 20 \(0.57 s.*later --end"):
        load_observation(held, start=0.3, end=0.42, segment=_no_segmenter, min_frames=20)
    assert load_observation(held, camera=bundle / "camera.json", start=0.3, min_frames=20)
    result, out = _predict([held, "--start", "0.3", "--end", "0.42"], tmp_path)
    assert result.exit_code == 2 and "5 frames at 0.03 s" in result.output and not out.exists()


def _no_segmenter(frames):
    raise AssertionError("the segmenter ran on a recording too short to read")


def test_transparent_gif_gives_the_masks(bundle, tmp_path):
    frames = np.stack(imageio.mimread(bundle / "video.mp4"))
    alpha = np.where(frames.max(-1) > 40, 255, 0).astype(np.uint8)
    alpha[:, :, :4] = 0  # a transparent stripe that background subtraction would not find
    gif = tmp_path / "drop.gif"
    rgba = list(np.concatenate([frames, alpha[..., None]], -1))
    imageio.mimwrite(gif, rgba, duration=30, disposal=2)  # 2: transparent shows the backdrop
    observation = load_observation(gif, camera=bundle / "camera.json")
    assert observation.mask_source == "alpha channel" and observation.num_frames == 30
    assert torch.equal(observation.masks, torch.from_numpy(alpha > 127).float())
    assert float(observation.frames[:, :, :4].abs().max()) == 0  # background set to black


def test_predictor_input_warps_other_intrinsics_to_the_dataset_camera(dataset, sample_id):
    from reconphys.data.dataset import DropDataset

    data = DropDataset(dataset)
    gaussians = data.asset(0).gaussians
    views = dataset_views(32, 32)
    direct = render(gaussians, Cameras(views.K[:1], views.world_to_cam[:1], 32, 32)).rgb[0]
    # the same pose filmed at 64×48 with a 60° lens and an off-centre principal point
    K = intrinsics_from_fov(60.0, 64, 48)
    K[0, 2] += 3.0
    wide = render(gaussians, Cameras(K[None], views.world_to_cam[:1], 64, 48)).rgb[0]
    warped = predictor_frames(wide[None], K, 32)[0, 0]
    assert float((warped - direct).abs().mean()) < 0.02
    same = predictor_frames(direct[None], views.K[0], 32)
    assert torch.equal(same, resize_frames(direct[None, None], 32))


def test_fit_to_mask_recovers_a_displaced_object(dataset):
    from reconphys.data.dataset import DropDataset

    data = DropDataset(dataset)
    gaussians = data.asset(0).gaussians
    camera = default_camera(64, 64)
    mask = (render(gaussians, camera.cameras()).alpha.reshape(64, 64) > 0.5).float()
    moved = gaussians.with_means(gaussians.means + torch.tensor([0.3, -0.2, 0.25]))
    fitted = fit_to_mask(moved, mask, camera)
    error = fitted.means.mean(0) - gaussians.means.mean(0)  # metres; view 0 looks along −x
    # across the view: a fraction of a pixel (~3 cm at 2 m and 64 px); along it (depth from the
    # apparent size, one pixel of a ~28-px box is ~3.5 % of 2 m): a few pixels' worth
    assert abs(float(error[1])) < 0.03 and abs(float(error[2])) < 0.03
    assert abs(float(error[0])) < 0.15


def _rod(along, length=0.3, radius=0.006, count=120):
    """Opaque Gaussians on a segment through (0, 0, 0.5) m: a thin part (a robot's leg)."""
    from reconphys.assets.gaussians import Gaussians

    means = torch.linspace(-0.5, 0.5, count)[:, None] * length * torch.tensor(along)
    return Gaussians(
        means=means + torch.tensor([0.0, 0.0, 0.5]),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(count, 1),
        log_scales=torch.full((count, 3), math.log(radius)),
        opacity_logits=torch.full((count,), 4.0),
        sh0=torch.zeros(count, 3),
    )


def test_a_thin_parts_true_shape_passes_the_placement_check_and_a_turned_one_does_not():
    from reconphys.capture.placement import silhouette_iou
    from reconphys.pipeline.predict import MIN_PLACED_IOU

    camera = default_camera(128, 128)  # view 0 looks along −x: y across the image, z up it
    lying = _rod((0.0, 1.0, 0.0))
    mask = (render(lying, camera.cameras(), backend="torch").alpha.reshape(128, 128) > 0.5).float()
    assert 40 < float(mask.sum()) < 200  # a few pixels thick
    # compared on the whole frame reduced to 64 px its own silhouette scored 0.30 (refused);
    # on a window around the object it is itself
    assert silhouette_iou(lying, mask, camera) > 0.95
    standing = fit_to_mask(_rod((0.0, 0.0, 1.0)), mask, camera)
    assert silhouette_iou(standing, mask, camera) < MIN_PLACED_IOU
    # the window follows the Gaussians too: moved off the mask, they do not match it
    moved = lying.with_means(lying.means + torch.tensor([0.0, 0.4, 0.0]))
    assert silhouette_iou(moved, mask, camera) < 0.05


def _two_colour_box(colours=((0.9, 0.2, 0.2), (0.2, 0.3, 0.9)), count=10):
    """Opaque Gaussians filling a 0.2 m cube about (0, 0, 0.5) m, the first colour on its −y
    half and the second on its +y half (view 0 sees y across the image)."""
    from reconphys.assets.gaussians import SH_C0, Gaussians

    axis = torch.linspace(-0.1, 0.1, count)
    means = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    rgb = torch.where(means[:, 1:2] < 0, torch.tensor(colours[0]), torch.tensor(colours[1]))
    return Gaussians(
        means=means + torch.tensor([0.0, 0.0, 0.5]),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(len(means), 1),
        log_scales=torch.full((len(means), 3), math.log(0.012)),
        opacity_logits=torch.full((len(means),), 4.0),
        sh0=(rgb - 0.5) / SH_C0,
    )


def test_a_shape_turned_about_its_symmetry_shows_its_colours_in_the_wrong_place():
    """The silhouette check cannot see a cube turned half a turn about the vertical; its colours
    can: the chromaticity of the render and of frame 0 — lit unevenly, with another white
    balance — correlate for the true pose, anti-correlate for the turned one; one colour, or a
    frame without colour, cannot tell (None)."""
    from reconphys.capture.placement import colour_agreement, silhouette_iou
    from reconphys.geometry import axis_angle_to_matrix
    from reconphys.pipeline.predict import MIN_COLOUR_AGREEMENT, MIN_PLACED_IOU

    camera = default_camera(64, 64)
    box = _two_colour_box()
    drawn = render(box, camera.cameras(), backend="torch")
    mask = (drawn.alpha.reshape(64, 64) > 0.5).float()
    light = torch.linspace(0.5, 1.0, 64)[None, :, None]  # brighter to the right
    frame = drawn.rgb.reshape(64, 64, 3) * light * torch.tensor([1.1, 1.0, 0.85])
    turn = axis_angle_to_matrix(torch.tensor([0.0, 0.0, math.pi]))
    centre = box.means.mean(0)
    turned = box.with_means((box.means - centre) @ turn.T + centre)
    assert silhouette_iou(turned, mask, camera) > MIN_PLACED_IOU  # the silhouette is the same
    assert colour_agreement(box, frame, mask, camera) > 0.9
    assert colour_agreement(turned, frame, mask, camera) < -0.5 < MIN_COLOUR_AGREEMENT
    plain = _two_colour_box(colours=((0.7, 0.5, 0.3), (0.7, 0.5, 0.3)))
    assert colour_agreement(plain, frame, mask, camera) is None
    grey = frame.mean(-1, keepdim=True).expand(-1, -1, 3)
    assert colour_agreement(box, grey, mask, camera) is None


def test_a_shape_whose_colours_agree_is_kept_where_it_is_on_a_poor_mask(tmp_path):
    """A mask that took in the shadow below the object lowers the true shape's silhouette IoU
    under MIN_PLACED_IOU; its colours, where the pattern lies, still agree, so --placement auto
    keeps it where it is (moving it onto the poor mask would move it off) — and the same shape
    turned half a turn, whose colours do not agree, is refused."""
    from reconphys.assets.ply import write_ply
    from reconphys.capture.observation import Observation
    from reconphys.geometry import axis_angle_to_matrix
    from reconphys.pipeline.predict import MIN_COLOURED_IOU, MIN_PLACED_IOU, _given_gaussians

    camera = default_camera(64, 64)
    box = _two_colour_box()
    drawn = render(box, camera.cameras(), backend="torch")
    mask = (drawn.alpha.reshape(64, 64) > 0.5).float()
    rows = torch.nonzero(mask.any(1))[:, 0]
    low = int(rows.max()) + 1
    mask[low : low + 8, mask.any(0)] = 1.0  # the shadow's pixels below the box
    frame = drawn.rgb.reshape(64, 64, 3) * mask[..., None]
    observation = Observation(frames=frame[None], masks=mask[None], camera=camera, frame_dt=0.03,
                              source="test", mask_source="test")  # fmt: skip
    write_ply(tmp_path / "box.ply", box)
    placed, details = _given_gaussians(tmp_path / "box.ply", observation, "auto")
    assert MIN_COLOURED_IOU <= details["silhouette_iou_given"] < MIN_PLACED_IOU
    assert details["placement"] == "as-is" and details["colour_agreement"] > 0.9
    assert torch.allclose(placed.means, box.means)
    turn = axis_angle_to_matrix(torch.tensor([0.0, 0.0, math.pi]))
    centre = box.means.mean(0)
    write_ply(tmp_path / "turned.ply", box.with_means((box.means - centre) @ turn.T + centre))
    with pytest.raises(InputError, match=r"its colours do not match|does not match the object"):
        _given_gaussians(tmp_path / "turned.ply", observation, "auto")


def _rendered_fall(gaussians, velocity, size=96, frames=4, spin=None):
    """Masks of ``gaussians`` falling freely with ``velocity`` (m/s) and, given, ``spin``
    (rad/s, about their centroid) from frame 0, seen by view 0's default camera."""
    from reconphys.geometry import axis_angle_to_matrix

    camera = default_camera(size, size)
    centre = gaussians.means.mean(0)
    masks = []
    for t in range(frames):
        time = 0.03 * t
        shift = velocity * time + torch.tensor([0.0, 0.0, -4.9 * time**2])
        means = gaussians.means
        if spin is not None:
            means = (means - centre) @ axis_angle_to_matrix(spin * time).T + centre
        g = gaussians.with_means(means + shift)
        masks.append((render(g, camera.cameras()).alpha.reshape(size, size) > 0.5).float())
    return torch.stack(masks), camera


def test_linear_velocity_from_a_rendered_free_fall(dataset):
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians  # in view at frame 0, as in the dataset
    velocity = torch.tensor([0.0, 0.3, 0.8])  # view 0 looks along −x: y is lateral, z vertical
    masks, camera = _rendered_fall(gaussians, velocity)
    fitted, error = linear_velocity_fit(gaussians.means, masks, camera, 0.03)
    assert abs(float(fitted[1]) - 0.3) < 0.1 and abs(float(fitted[2]) - 0.8) < 0.15
    # its standard error, in the camera's axes (x right, y down, along the view): the truth is
    # within 3 of them on each axis, and the view's axis (read from the mask's growth) is the
    # least certain
    assert (error > 0).all()
    rotation = camera.world_to_cam[:3, :3].float()
    off = (rotation @ (fitted - velocity)).abs()
    assert (off <= 3 * error).all(), (off, error)
    assert float(error[2]) > float(error[:2].max())


def test_the_velocity_fits_jacobian_is_autograds():
    """The Gauss–Newton fit of the initial velocity uses its residual's Jacobian written out
    (placement.velocity_residual); autograd's of the same residual, for two views, a velocity
    towards, across and down, and an object near and far."""
    generator = torch.Generator().manual_seed(3)
    times = torch.arange(7, dtype=torch.float64) * 0.03
    drop = -4.905 * times**2
    for view, distance in ((0, 1.0), (1, 3.0)):
        camera = default_camera(96, 72, view)
        centre = torch.randn(3, generator=generator, dtype=torch.float64) * 0.1 * distance
        centre[2] += 0.4
        target = torch.rand(7, 2, generator=generator, dtype=torch.float64) * 60
        growth = 1 + 0.05 * torch.rand(7, generator=generator, dtype=torch.float64)
        arguments = (centre, times, drop, camera, target, growth, 11.0, 2.5, 0.5)
        velocity = torch.tensor([0.8, -0.3, 1.1], dtype=torch.float64)
        residual, jacobian = velocity_residual(velocity, *arguments)
        reference = torch.autograd.functional.jacobian(
            lambda v, given=arguments: velocity_residual(v, *given)[0], velocity
        )
        assert residual.shape == (7 * 3 + 3,) and jacobian.shape == (7 * 3 + 3, 3)
        torch.testing.assert_close(jacobian, reference, rtol=1e-10, atol=1e-10)


def test_velocity_along_the_view_is_read_from_the_growing_mask(dataset):
    """Motion towards the camera barely moves the centroid; the mask's growth shows it. Released
    from rest, the estimate stays at rest (issue 23: |v0| ≤ 0.1 m/s)."""
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    towards = torch.tensor([1.0, 0.0, 0.0])  # +x: towards view 0's camera
    masks, camera = _rendered_fall(gaussians, towards, size=128, frames=5)
    estimate = linear_velocity_fit(gaussians.means, masks, camera, 0.03, frames=5)[0]
    assert 0.6 < float(estimate[0]) < 1.4, estimate
    masks, camera = _rendered_fall(gaussians, torch.zeros(3), size=128, frames=5)
    estimate = linear_velocity_fit(gaussians.means, masks, camera, 0.03, frames=5)[0]
    assert float(estimate.norm()) < 0.1, estimate


def test_a_segmenters_growing_rim_is_not_read_as_motion_towards_the_camera(dataset):
    """A mask segmenter's masks of an object released from rest that gain a rim as it falls
    (a pixel from frame 1, two from frame 4: the area 11 % larger): weighed as exact masks'
    the growth reads as ~1 m/s towards the camera; with the segmenter's weight
    (placement.SEGMENTED_SIZE_WEIGHT) the rest test holds. A true motion towards the camera
    still shows in the size at that weight."""
    from scipy import ndimage

    from reconphys.capture.placement import SEGMENTED_SIZE_WEIGHT
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    masks, camera = _rendered_fall(gaussians, torch.zeros(3), size=96, frames=8)
    rims = [0, 1, 1, 1, 2, 2, 2, 2]
    grown = torch.stack(
        [
            torch.from_numpy(ndimage.binary_dilation(m > 0.5, iterations=k) if k else m > 0.5)
            for m, k in zip(masks.numpy(), rims, strict=True)
        ]
    ).float()
    assert float(grown[-1].sum() / grown[0].sum()) > 1.1
    exact = linear_velocity_fit(gaussians.means, grown, camera, 0.03, fall=8)[0]
    assert float(exact.norm()) > 0.5  # read as a toss
    weighed = linear_velocity_fit(
        gaussians.means, grown, camera, 0.03, fall=8, size_weight=SEGMENTED_SIZE_WEIGHT
    )[0]
    assert torch.equal(weighed, torch.zeros(3))
    towards = torch.tensor([1.0, 0.0, 0.0])  # +x: towards view 0's camera
    masks, camera = _rendered_fall(gaussians, towards, size=128, frames=5)
    estimate = linear_velocity_fit(
        gaussians.means, masks, camera, 0.03, frames=5, size_weight=SEGMENTED_SIZE_WEIGHT
    )[0]
    assert 0.6 < float(estimate[0]) < 1.4, estimate


def test_a_hold_then_a_release_from_rest_is_read_at_rest(dataset):
    """--start auto's hold (``observation.release``, capture.masks.read_release): an object held
    still, then let go from rest, comes back at rest even where its masks grow as it leaves the
    hand (a hand's fingers taken for it) and the fit alone reads them as a toss; a release read
    as a throw keeps the fit's velocity."""
    from scipy import ndimage

    from reconphys.capture import Observation
    from reconphys.capture.masks import Release
    from reconphys.data.dataset import DropDataset
    from reconphys.models.reconstruct import initial_velocity_fit

    gaussians = DropDataset(dataset).asset(0).gaussians
    masks, camera = _rendered_fall(gaussians, torch.zeros(3), size=96, frames=8)
    grown = torch.stack(
        [
            torch.from_numpy(ndimage.binary_dilation(m > 0.5, iterations=k) if k else m > 0.5)
            for m, k in zip(masks.numpy(), [0, 1, 1, 1, 2, 2, 2, 2], strict=True)
        ]
    ).float()
    observation = Observation(
        frames=grown[..., None].expand(-1, -1, -1, 3), masks=grown, camera=camera,
        frame_dt=0.03, source="held", mask_source="a hand's fingers in them",
    )  # fmt: skip
    read = initial_velocity_fit(gaussians, observation)[0]
    assert float(read.norm()) > 0.5  # read as a toss
    held = replace(observation, release=Release(0.3, 10, 0.02))
    assert torch.equal(initial_velocity_fit(gaussians, held)[0], torch.zeros(3))
    # a start given after the release (--start SECONDS, the hold read before it): falling from
    # rest by then, g × the time since the release, downwards; at rest from a start before it
    late = replace(held, start_s=0.36)
    expected = torch.tensor([0.0, 0.0, -GRAVITY_MAGNITUDE * 0.06])
    assert torch.allclose(initial_velocity_fit(gaussians, late)[0], expected, atol=1e-6)
    early = replace(held, start_s=0.27)
    assert torch.equal(initial_velocity_fit(gaussians, early)[0], torch.zeros(3))
    thrown = replace(observation, release=Release(0.3, 10, 0.6))
    assert torch.equal(initial_velocity_fit(gaussians, thrown)[0], read)


def test_a_release_from_rest_comes_back_at_rest_and_a_slow_toss_does_not(dataset, monkeypatch):
    """The rest test (placement.REST_CHI2): a drop from rest is read as exactly at rest, where
    the fit alone reads a few cm/s of mask noise as motion; a toss of 0.3 m/s sideways is
    motion the masks show, and keeps its velocity."""
    from reconphys.capture import placement
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    masks, camera = _rendered_fall(gaussians, torch.zeros(3))
    assert torch.equal(linear_velocity_fit(gaussians.means, masks, camera, 0.03)[0], torch.zeros(3))
    with monkeypatch.context() as patch:
        patch.setattr(placement, "REST_CHI2", 0.0)
        free = linear_velocity_fit(gaussians.means, masks, camera, 0.03)[0]
    assert 0 < float(free.norm()) < 0.1
    sideways = torch.tensor([0.0, 0.3, 0.0])  # across view 0, which looks along −x
    masks, camera = _rendered_fall(gaussians, sideways)
    fitted = linear_velocity_fit(gaussians.means, masks, camera, 0.03)[0]
    assert abs(float(fitted[1]) - 0.3) < 0.1 and abs(float(fitted[2])) < 0.1


def test_the_velocity_is_read_in_the_masks_own_pixels(dataset):
    """A segmenter's masks read at 48 px and brought to 240 (each pixel 5 of the image's, the
    camera's K ×5): with ``pixel=5`` the same velocity and standard error as the 48-px masks',
    a toss and a release from rest alike. Weighed in the image's pixels instead, the prior and
    the noise floors count 25× less against the same errors, and the reading moves."""
    from dataclasses import replace

    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    for velocity, seed in ((torch.tensor([0.4, 0.3, 0.5]), 0), (torch.zeros(3), 1)):
        masks, camera = _rendered_fall(gaussians, velocity, size=48, frames=8)
        masks = rim_noise(masks, np.random.default_rng(seed))
        large = masks.repeat_interleave(5, 1).repeat_interleave(5, 2)
        K = camera.K.clone()
        K[:2] *= 5
        enlarged = replace(camera, K=K, width=240, height=240)
        small = linear_velocity_fit(gaussians.means, masks, camera, 0.03, fall=8)
        read = linear_velocity_fit(gaussians.means, large, enlarged, 0.03, fall=8, pixel=5)
        for a, b in zip(small, read, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
        image = linear_velocity_fit(gaussians.means, large, enlarged, 0.03, fall=8)
        assert float((image[1] - small[1]).abs().max()) > 1e-3


def test_noisy_masks_are_read_closer_over_the_whole_fall(dataset):
    """Masks that gain or lose a pixel's rim at random per frame (as the segmenter's do): four
    frames read that noise as velocity, the whole free fall (``fall``, placement.FALL_WINDOW_LESS)
    averages it out — in every axis, for a toss, and for a release from rest that the rest test
    (still on the first four frames) does not catch; those it catches stay exactly at rest."""
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    seeds = range(8)
    velocity = torch.tensor([0.0, 0.4, 0.5])  # across view 0 (which looks along −x) and up
    masks, camera = _rendered_fall(gaussians, velocity, size=64, frames=12)
    rotation = camera.world_to_cam[:3, :3].float()

    def mean_error(fall):  # [3] m/s, camera axes, over the noise draws
        errors = []
        for seed in seeds:
            noisy = rim_noise(masks, np.random.default_rng(seed))
            fitted = linear_velocity_fit(gaussians.means, noisy, camera, 0.03, fall=fall)[0]
            errors.append((rotation @ (fitted - velocity)).abs())
        return torch.stack(errors).mean(0)

    four, whole = mean_error(None), mean_error(12)
    assert (whole < 0.5 * four).all(), (whole, four)
    masks, camera = _rendered_fall(gaussians, torch.zeros(3), size=64, frames=12)
    speeds = {}
    for fall in (None, 12):
        speeds[fall] = [
            float(linear_velocity_fit(gaussians.means, noisy, camera, 0.03, fall=fall)[0].norm())
            for noisy in (rim_noise(masks, np.random.default_rng(seed)) for seed in seeds)
        ]
    moving = [i for i, speed in enumerate(speeds[None]) if speed > 0]
    assert 0 < len(moving) < len(seeds)  # the rest test catches some draws, not all
    assert all(speeds[12][i] == 0 for i in seeds if i not in moving)
    assert max(speeds[12]) < 0.5 * max(speeds[None])


def test_a_release_from_rest_placed_at_the_wrong_depth_still_comes_back_at_rest(
    dataset, monkeypatch
):
    """A camera read from the video (or a predicted shape) puts the centre at another depth than
    the fall's pixels imply; a fall from rest then looks like one with a velocity unless the rest
    hypothesis may move the centre along its ray (placement.REST_DEPTH_FACTORS)."""
    from reconphys.capture import placement
    from reconphys.data.dataset import DropDataset

    gaussians = DropDataset(dataset).asset(0).gaussians
    masks, camera = _rendered_fall(gaussians, torch.zeros(3), size=256)
    w2c = camera.world_to_cam.float()
    eye = -(w2c[:3, :3].T @ w2c[:3, 3])
    farther = eye + 1.4 * (gaussians.means - eye)  # 40 % too far, on the same rays
    assert torch.equal(linear_velocity_fit(farther, masks, camera, 0.03)[0], torch.zeros(3))
    with monkeypatch.context() as patch:
        patch.setattr(placement, "REST_DEPTH_FACTORS", (1.0, 1.0))
        fixed = linear_velocity_fit(farther, masks, camera, 0.03)[0]
    assert float(fixed.norm()) > 0.1


def test_refine_lowers_the_photometric_loss(dataset, sample_id):
    from dataclasses import replace

    from reconphys.pipeline.refine import refine
    from reconphys.pipeline.samples import load_sample

    observation, sample = load_sample(dataset, sample_id)
    truth = sample.asset
    wrong = replace(truth, physics=replace(truth.physics, stiffness=truth.physics.stiffness / 8))
    refined, history = refine(wrong, observation, steps=3, resolution=32, num_frames=20)
    assert history["loss_best"] < history["loss_initial"]
    assert refined.physics.stiffness > wrong.physics.stiffness  # moved towards the truth


# --- bad input: one line, exit 2, no OUT ------------------------------------------------------


def _fails(args, tmp_path, expected):
    result, out = _predict(args, tmp_path)
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: ") and expected in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".asset")]  # no staging left


def test_unreadable_video(bundle, tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"\x00\x01 not a video" * 50)
    _fails([bad, "--gaussians", bundle / "gaussians.ply"], tmp_path, "cannot decode the video")


def test_zero_frames(bundle, tmp_path):
    empty = tmp_path / "frames"
    empty.mkdir()
    _fails([empty, "--gaussians", bundle / "gaussians.ply"], tmp_path, "no frames")


def _frame_folder(bundle, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for t, frame in enumerate(imageio.mimread(bundle / "video.mp4")):
        imageio.imwrite(folder / f"frame_{t}.png", frame)
    return folder


def test_a_clip_that_fades_in_is_refused_with_the_start_after_the_fade(bundle, tmp_path):
    """The drop's frames with a black frame 0 and frame 1 at a third of its brightness (a
    fade-in): refused before its masks are read, naming --start 0.06 (frame 2, the first at full
    brightness), and no asset; check_fade_in passes a clip whose exposure settles (frame 0 at
    60 %) and one of uniform brightness."""
    from reconphys.capture.observation import check_fade_in

    frames = _frame_folder(bundle, tmp_path)
    first = imageio.imread(frames / "frame_0.png")
    imageio.imwrite(frames / "frame_0.png", np.zeros_like(first))
    second = imageio.imread(frames / "frame_1.png")
    imageio.imwrite(frames / "frame_1.png", (second // 3).astype(np.uint8))
    _fails(
        [frames, "--fps", "33.3333", "--gaussians", bundle / "gaussians.ply"],
        tmp_path,
        "frame 0 is dark against the rest of the clip (0% of its median brightness): a fade-in "
        "or a cut before it, not the release; give --start 0.06 (its first frame at full "
        "brightness)",
    )
    check_fade_in(np.array([0.6, 0.9, 1.0, 1.0, 1.0]), "settling", 0.0, 0.03)  # no error
    check_fade_in(np.ones(5), "uniform", 0.0, 0.03)  # no error


def test_mismatched_mask_count(bundle, tmp_path):
    frames = _frame_folder(bundle, tmp_path)
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in range(5):
        imageio.imwrite(masks / f"{t}.png", np.full((32, 32), 255, np.uint8))
    _fails(
        [frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply"],
        tmp_path,
        "5 mask images for 30 frames",
    )


def test_empty_mask(bundle, tmp_path):
    frames = _frame_folder(bundle, tmp_path)
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in range(30):
        imageio.imwrite(masks / f"{t:03d}.png", np.zeros((32, 32), np.uint8))
    _fails(
        [frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply"],
        tmp_path,
        "mask is empty in frame 0",
    )


def _square(t: int, top: int = 4) -> np.ndarray:  # a 6-px object at row `top` (32 × 32)
    mask = np.zeros((32, 32), np.uint8)
    mask[top : top + 6, 13:19] = 255
    return mask


@pytest.mark.parametrize(
    "mask_of, expected",
    [
        (lambda t: np.full((32, 32), 255, np.uint8), "covers 100% of frame 0: that is background"),
        (lambda t: np.pad(np.full((4, 32), 255, np.uint8), ((26, 2), (0, 0))),
         "spans frame 0 from edge to edge"),
        (lambda t: _square(t), "does not move (every frame overlaps frame 0 by IoU ≥ 1.00)"),
        (lambda t: _square(t) if t < 3 else np.zeros((32, 32), np.uint8),
         "the object is found in only 3 of 30 frames"),
        (lambda t: _square(t, top=min(2 * t, 24)) if t < 25 else np.zeros((32, 32), np.uint8),
         "empty from frame 25 (0.75 s after the release): the object leaves the view or the "
         "masks lose it; cut the recording before it with --end 0.73, or give"),
        (lambda t: _square(t, top=24) if t < 4 else _square(t, top=min(2 * (t - 4), 24)),
         "the object's mask jumps at frame 4 (its centroid leaves its track by 4.3× the "
         "object's size in one frame; no falling body does): frames 0–3 follow something else"),
        (lambda t: _square(t, top=min(2 * t, 24)) | (_square(t, top=20) if t == 0 else 0),
         "the object's mask in frame 0 is not the one of frame 2 (area ×2.00, overlap IoU 0.00"),
        (lambda t: _square(t, top=min(4 + 2 * max(0, t - 7), 24)),  # held for 8 frames
         "does not move in frames 0–7 (0.24 s): frame 0 must be the release; give --start SECONDS "
         "(about 0.18 here"),
    ],
)  # fmt: skip
def test_implausible_masks_are_refused(bundle, tmp_path, mask_of, expected):
    """Masks that cannot be one released object (background, a static region, an object that is
    not there, one that leaves the view, masks on a shadow until the object drops into view, a
    frame 0 with a second object where it will land, one held still before its release) are
    refused with what to give instead, and no asset; a square that falls 2 px a frame (then
    rests) passes the same checks."""
    from reconphys.capture.masks import check_first_frames_track, check_masks, check_release

    frames = _frame_folder(bundle, tmp_path)
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in range(30):
        imageio.imwrite(masks / f"{t:03d}.png", mask_of(t))
    _fails([frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply"], tmp_path, expected)
    result, _ = _predict([frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply"],
                         tmp_path)  # fmt: skip
    if "--start" not in expected:  # masks that are wrong, not a recording that starts early
        assert (
            "--masks DIR (one image per frame) or a clean plate with --background" in result.output
        )
    falling = np.stack([_square(t, top=min(2 * t, 24)) for t in range(30)]) / 255.0
    check_masks(torch.from_numpy(falling).float(), "falling")  # no error
    check_release(torch.from_numpy(falling).float(), "falling")
    check_first_frames_track(torch.from_numpy(falling).float(), "falling")


def test_an_object_that_leaves_the_view_names_the_end_that_keeps_it():
    """check_in_view: masks empty from frame 25 of a clip started 1.2 s into the recording name
    --end 1.94 (between frames 24 and 25, at 1.92 and 1.95 s: 0–24 kept, enough for a reader of
    20); empty from frame 12, too early to cut for 20 frames; in view throughout, no error."""
    from reconphys.capture.masks import check_in_view

    masks = torch.ones(30, 4, 4)
    check_in_view(masks, "clip", 1.2, 0.03, 20)  # no error
    masks[25:] = 0
    with pytest.raises(InputError, match=r"empty from frame 25 .* --end 1\.94, or give"):
        check_in_view(masks, "clip", 1.2, 0.03, 20)
    masks[12:] = 0
    with pytest.raises(InputError, match=r"too early to cut the recording there .*reads 20 "):
        check_in_view(masks, "clip", 1.2, 0.03, 20)


def test_a_hold_without_a_fall_is_refused_with_start_auto(bundle, tmp_path):
    """--start auto on an object held for 8 frames that then slides sideways (no fall to read
    the release from) is refused with the --start to give, not with "--start auto" again."""
    frames = _frame_folder(bundle, tmp_path)
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in range(30):
        imageio.imwrite(masks / f"{t:03d}.png", np.roll(_square(t), min(max(0, t - 7), 12), 1))
    _fails(
        [frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply", "--start", "auto"],
        tmp_path,
        "give --start SECONDS (about 0.18 here, the time in the recording where it is let go); "
        "--start auto found no fall from the hold",
    )


def test_a_hidden_top_in_the_first_frames_is_flagged(bundle, tmp_path):
    """The drop's masks with the object's top rows hidden in frames 0–1, a fifth of its area (a
    hand over it: the mask grows as the object leaves it), are answered with the velocity
    flagged, in prediction.json and printed; the drop's own masks are not flagged."""
    from reconphys.capture.masks import FIRST_FRAMES_AREA_CHANGE, first_frames_area_change

    frames = _frame_folder(bundle, tmp_path)
    whole = load_observation(bundle / "video.mp4", camera=bundle / "camera.json").masks > 0.5
    hidden = whole.clone()
    for t in (0, 1):
        while hidden[t].sum() > 0.8 * whole[t].sum():
            hidden[t, torch.nonzero(hidden[t].any(1))[0, 0]] = False
    assert first_frames_area_change(whole.float()) < FIRST_FRAMES_AREA_CHANGE
    assert first_frames_area_change(hidden.float()) > FIRST_FRAMES_AREA_CHANGE
    assert first_frames_area_change(torch.zeros(4, 8, 8)) == float("inf")
    for name, masks_of in (("hidden", hidden), ("whole", whole)):
        masks = tmp_path / f"masks_{name}"
        masks.mkdir()
        for t, mask in enumerate(masks_of.numpy()):
            imageio.imwrite(masks / f"{t:03d}.png", mask.astype(np.uint8) * 255)
        result, out = _predict(
            [frames, "--masks", masks, "--gaussians", bundle / "gaussians.ply", "--camera",
             bundle / "camera.json", "--no-refine"],
            tmp_path,
            name,
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        velocity = json.loads((out / "prediction.json").read_text())["initial_velocity"]
        flagged = "warning" in velocity
        assert flagged == (name == "hidden"), velocity
        assert ("warning: initial velocity: the object's mask changes size by up to"
                in result.output) == flagged  # fmt: skip
        assert not flagged or velocity["warning"].endswith("are read at rest)")


def test_first_frames_agreement():
    """Frame 0's mask against frame 2's: a moved copy agrees exactly (IoU 1, area ×1) wherever
    it is; half of it overlaps by 0.5 at ×2 the area; an empty frame 2 does not agree."""
    from reconphys.capture.masks import first_frames_agreement

    masks = torch.zeros(3, 32, 32)
    masks[0, 3:9, 4:12] = 1
    masks[2, 20:26, 17:25] = 1  # the same 6 × 8 block, moved 17 px down and 13 right
    assert first_frames_agreement(masks) == (1.0, 1.0)
    masks[2] = 0
    masks[2, 20:23, 17:25] = 1  # its top half
    overlap, ratio = first_frames_agreement(masks)
    assert ratio == 2.0 and abs(overlap - 0.5) < 1e-9
    masks[2] = 0
    assert first_frames_agreement(masks) == (0.0, float("inf"))


@pytest.mark.parametrize(
    "change, expected",
    [
        ({"K": [[40, 0, 16], [0, 40, 16]]}, "[K]: expected shape [3, 3]"),
        ({"world_to_cam": [[1, 0, 0, 0]] * 4}, "[world_to_cam]: its 3×3 block is not a rotation"),
        ({"width": -3}, "[width]: expected a positive integer"),
        ({"K": [[1000, 0, 960], [0, 1000, 540], [0, 0, 1]]},  # a 1080p camera's, size not given
         "[K]: its principal point (960, 540) is outside the 32×32 image"),
        ({"K": [[40, 0, 32], [0, 40, 18], [0, 0, 1]], "width": 64, "height": 36},  # 16:9
         "[width]: K was made for 64×36 frames and the video's are 32×32, another shape"),
    ],
)  # fmt: skip
def test_camera_file_with_wrong_shapes(bundle, tmp_path, change, expected):
    camera = json.loads((bundle / "camera.json").read_text())
    camera.update(change)
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(camera))
    _fails(
        [bundle / "video.mp4", "--camera", path, "--gaussians", bundle / "gaussians.ply"],
        tmp_path,
        expected,
    )


def test_a_camera_file_of_another_shape_is_refused_not_stretched(tmp_path):
    """A 1080p camera file read for an encoder's 1920×1088 frames is K scaled to them (the shape
    within 1 %); for the same clip on its side (1080×1920: a phone's clip that lost its rotation)
    or cropped to 4:3 it is refused, where scaling K per axis would stretch the lens ×3.2 or
    ×1.3, for read_camera and read_intrinsics alike."""
    from reconphys.capture.camera import read_camera, read_intrinsics

    K = [[1400.0, 0.0, 960.0], [0.0, 1400.0, 540.0], [0.0, 0.0, 1.0]]
    pose = {"world_to_cam": np.eye(4).tolist()}
    for extra in (pose, {}):
        path = tmp_path / f"cam{len(extra)}.json"
        path.write_text(json.dumps({"K": K, "width": 1920, "height": 1080, **extra}))
        read = read_camera if extra else read_intrinsics
        padded = read(path, 1920, 1088)
        padded_K = padded.K if extra else padded
        assert float(padded_K[1, 1]) == pytest.approx(1400.0 * 1088 / 1080)
        for size in ((1080, 1920), (1440, 1080)):
            with pytest.raises(InputError, match=r"\[width\]: K was made for 1920×1080 frames"):
                read(path, *size)


def test_a_camera_file_in_another_convention_is_refused(bundle, tmp_path):
    """The bundle's camera written the OpenGL way (y up, z backwards: its second and third rows
    negated): the object then falls up in its image — refused, naming the file's field, before
    anything is written (a pybullet drop given so was answered with the object 2,000 km away)."""
    camera = json.loads((bundle / "camera.json").read_text())
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    camera["world_to_cam"] = (flip @ np.array(camera["world_to_cam"])).tolist()
    path = tmp_path / "opengl.json"
    path.write_text(json.dumps(camera))
    _fails(
        [bundle / "video.mp4", "--camera", path, "--gaussians", bundle / "gaussians.ply"],
        tmp_path,
        "opengl.json [world_to_cam]: in this camera the object falls",
    )


def _hull(bundle, tmp_path, stretch=(1.0, 1.0, 1.0)):
    """The convex hull of the true Gaussians' visible extent (each centre ± 1.5 σ along the axes:
    these 300 Gaussians are large), in frame 0's pose (optionally stretched about its centre): a
    mesh a user could give."""
    import trimesh

    from reconphys.assets.ply import read_ply

    gaussians = read_ply(bundle / "gaussians.ply")
    sigma = gaussians.scales.double().numpy()[:, None, :]
    axes = np.concatenate([np.eye(3), -np.eye(3)])[None]  # [1, 6, 3]
    points = (gaussians.means.double().numpy()[:, None, :] + 1.5 * sigma * axes).reshape(-1, 3)
    centre = points.mean(0)
    points = centre + (points - centre) * np.array(stretch)
    path = tmp_path / f"hull-{'-'.join(map(str, stretch))}.obj"
    trimesh.convex.convex_hull(points).export(path)
    return path


def test_a_mesh_in_frame_0s_pose_is_used_as_it_is(bundle, tmp_path):
    """predict --mesh: a mesh in frame 0's pose is kept where it is (placement as-is, its
    silhouette matches; the hull has no colours of its own, and the checker it gets is not
    compared with frame 0's); make-asset --keep-pose keeps it where it is too (no centring,
    scaling, rotation or lifting), while the default puts its lowest point at --height."""
    from reconphys.assets.asset import read_asset

    hull = _hull(bundle, tmp_path)
    result, out = _predict([bundle / "video.mp4", "--camera", bundle / "camera.json",
                            "--mesh", hull, "--no-refine", "--preview-frames", "0"],
                           tmp_path)  # fmt: skip
    assert result.exit_code == 0, result.output
    details = json.loads((out / "prediction.json").read_text())
    assert details["placement"] == "as-is" and details["silhouette_iou_given"] >= 0.6
    assert details["geometry"].endswith("(mesh)") and details["colour_agreement"] is None
    import trimesh

    bounds = trimesh.load(hull).bounds
    kept = tmp_path / "kept"
    made = runner.invoke(app, ["make-asset", str(kept), "--mesh", str(hull), "--keep-pose",
                               "--num-gaussians", "500", "--num-anchors", "32"])  # fmt: skip
    assert made.exit_code == 0, made.output
    means = read_asset(kept).gaussians.means.double().numpy()
    assert np.allclose(means.min(0), bounds[0], atol=0.02)
    assert np.allclose(means.max(0), bounds[1], atol=0.02)
    moved = tmp_path / "moved"
    made = runner.invoke(app, ["make-asset", str(moved), "--mesh", str(hull), "--no-rotate",
                               "--num-gaussians", "500", "--num-anchors", "32"])  # fmt: skip
    assert made.exit_code == 0, made.output
    assert read_asset(moved).gaussians.means[:, 2].min() == pytest.approx(0.3, abs=0.02)
    shape = runner.invoke(app, ["make-asset", str(tmp_path / "s"), "--shape", "torus",
                                "--keep-pose"])  # fmt: skip
    assert shape.exit_code == 2 and "a procedural shape has no pose" in shape.output
    import trimesh as tm

    sunk = tmp_path / "sunk.obj"
    tm.creation.box(extents=(0.2, 0.2, 0.2)).export(sunk)  # centred on z = 0: half below ground
    result = runner.invoke(app, ["make-asset", str(tmp_path / "k"), "--mesh", str(sunk),
                                 "--keep-pose"])  # fmt: skip
    assert result.exit_code == 2 and "0.100 m below the ground" in result.output


def test_a_geometry_that_does_not_match_frame_0_is_refused(bundle, tmp_path):
    """A mesh or PLY whose silhouette cannot be made to match frame 0's mask (here the object
    squashed into a pancake: 4× wider, 10× flatter) is refused — as given and after moving it
    onto the mask — with no asset, instead of being kept silently."""
    from reconphys.pipeline.predict import MIN_PLACED_IOU

    bad = _hull(bundle, tmp_path, stretch=(4.0, 4.0, 0.1))
    common = [bundle / "video.mp4", "--camera", bundle / "camera.json", "--mesh", bad,
              "--no-refine", "--preview-frames", "0"]  # fmt: skip
    _fails([*common, "--placement", "as-is"], tmp_path, "does not match the object in frame 0")
    _fails(common, tmp_path, f"after moving it onto the mask, needs ≥ {MIN_PLACED_IOU}")
    _fails([*common, "--gaussians", bundle / "gaussians.ply"], tmp_path, "not both")


def test_a_ply_turned_half_a_turn_is_refused_by_its_colours(bundle, tmp_path):
    """The sample's own PLY turned half a turn about the vertical keeps a silhouette that passes
    (IoU ≥ MIN_PLACED_IOU) but shows frame 0 the other side of its pattern: refused with one
    line naming the colours, no asset; the PLY as given is kept, its colours agreeing."""
    from dataclasses import replace

    from reconphys.assets.ply import read_ply, write_ply
    from reconphys.geometry import axis_angle_to_matrix, matrix_to_quaternion, quaternion_multiply
    from reconphys.pipeline.predict import MIN_COLOUR_AGREEMENT

    gaussians = read_ply(bundle / "gaussians.ply")
    turn = axis_angle_to_matrix(torch.tensor([0.0, 0.0, math.pi]))
    centre = gaussians.means.mean(0)
    spun = quaternion_multiply(matrix_to_quaternion(turn).expand_as(gaussians.quats),
                               gaussians.quats)  # fmt: skip
    turned = replace(gaussians, means=(gaussians.means - centre) @ turn.T + centre, quats=spun)
    write_ply(tmp_path / "turned.ply", turned)
    common = [bundle / "video.mp4", "--camera", bundle / "camera.json", "--no-refine",
              "--preview-frames", "0"]  # fmt: skip
    _fails([*common, "--gaussians", tmp_path / "turned.ply"], tmp_path,
           "its colours do not match the object's in frame 0")  # fmt: skip
    result, out = _predict([*common, "--gaussians", bundle / "gaussians.ply"], tmp_path)
    assert result.exit_code == 0, result.output
    details = json.loads((out / "prediction.json").read_text())
    assert details["colour_agreement"] >= MIN_COLOUR_AGREEMENT


def test_video_without_geometry_or_3dgs_predictor(bundle, tmp_path):
    missing = tmp_path / "nowhere.safetensors"
    _fails([bundle / "video.mp4", "--gs-model", missing], tmp_path, "3DGS predictor not found")


def test_predicted_geometry_from_the_first_frame(bundle, dataset, sample_id, tmp_path):
    train_tiny_gaussian_predictor(dataset, tmp_path / "gs", steps=2)
    result, out = _predict(
        [
            bundle / "video.mp4",
            "--camera",
            bundle / "camera.json",
            "--gs-model",
            tmp_path / "gs",
            "--preview-frames",
            "0",
        ],
        tmp_path,
    )
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "prediction.json").read_text())
    assert summary["geometry"].startswith("predicted by the 3DGS predictor")
    # on predicted geometry the search's fit is multiplied by the ensemble's own belief
    assert summary["search"]["network_sigma"] == pytest.approx(
        list(summary["network_sigma"].values()), abs=1e-3
    )
    assert "times the network's belief" in summary["intervals_how"]
    mask_pixels = int(
        (load_observation(bundle / "video.mp4", camera="dataset").masks[0] > 0.5).sum()
    )
    assert 0 < summary["gaussians"] <= mask_pixels  # one per object pixel at most
    stored, _ = _predict(
        [
            dataset,
            "--sample",
            sample_id,
            "--geometry",
            "predicted",
            "--gs-model",
            tmp_path / "gs",
            "--preview-frames",
            "0",
            "--no-refine",
        ],
        tmp_path,
        "stored",
    )
    assert stored.exit_code == 0, stored.output


def test_an_implausible_launch_is_refused_not_answered():
    """A launch read faster than MAX_INITIAL_SPEED_M_S (a fall from 5 m lands at 10 m/s) is a
    misread, not a toss: refused with one line naming the recording and what to give; a toss
    at a few m/s and a drop from rest pass."""
    from reconphys.pipeline.predict import MAX_INITIAL_SPEED_M_S, check_initial_speed

    assert (2 * 9.81 * 5.0) ** 0.5 < MAX_INITIAL_SPEED_M_S + 0.1
    check_initial_speed(torch.tensor([1.5, -0.5, 2.0]), "clip.mp4")
    check_initial_speed(torch.zeros(3), "clip.mp4")
    for bad in ([0.5, -14.7, -12.9], [float("nan"), 0.0, 0.0]):
        with pytest.raises(InputError, match=r"clip\.mp4.*m/s.*--masks DIR"):
            check_initial_speed(torch.tensor(bad), "clip.mp4")
