"""Frames at the simulator's times from a recording at another rate (capture/interpolate.py):
where the times fall, and that the frames made between two recorded ones show the object where
an analytic fall puts it, at its size, in its colours."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest
import torch

import reconphys.capture.video as video_module
from reconphys.capture import load_observation
from reconphys.capture.interpolate import frames_between
from reconphys.capture.video import resample_between, resample_indices
from reconphys.render.video import copy_with_metadata, run_ffmpeg

FRAME_DT = 0.03
SIZE = 64


def test_a_recording_at_the_simulators_rate_reads_its_own_frames():
    for fps in (1 / FRAME_DT, 2 / FRAME_DT):  # 33.3 and 66.7 fps: every time on a frame
        before, after, weight = resample_between(60, fps, FRAME_DT)
        assert (weight == 0).all() and (before == after).all()
        assert before.tolist() == list(range(0, 60, round(fps * FRAME_DT)))[: len(before)]


def test_at_30_fps_the_times_fall_between_frames():
    before, after, weight = resample_between(30, 30.0, FRAME_DT)  # 0.03 s = 0.9 frames
    assert len(before) == 33  # 29/30 s of recording / 0.03 s + 1
    assert before[:4].tolist() == [0, 0, 1, 2] and after[:4].tolist() == [0, 1, 2, 3]
    np.testing.assert_allclose(weight[:4], [0.0, 0.9, 0.8, 0.7], atol=1e-9)
    np.testing.assert_allclose(before + weight, np.arange(33) * 0.9, atol=1e-9)  # the times
    assert resample_indices(30, 30.0, FRAME_DT)[:4].tolist() == [0, 1, 2, 3]  # nearest
    # within a millisecond of a recorded frame: that frame as it is
    _, _, weight = resample_between(30, 30.0, FRAME_DT, start=0.0005)
    assert weight[0] == 0 and weight[10] == 0  # t = 0.0005 and 0.3005 s


def _disc(centre_px: np.ndarray, radius_px: float) -> np.ndarray:  # [H, W] bool
    v, u = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    return (u - centre_px[0]) ** 2 + (v - centre_px[1]) ** 2 <= radius_px**2


def _centroid(mask: torch.Tensor) -> np.ndarray:  # [2] px (u, v), pixel centres at +0.5
    v, u = np.nonzero(mask.numpy())
    return np.array([u.mean(), v.mean()]) + 0.5


def _falling_centre(t: float) -> np.ndarray:  # [2] px (u, v): thrown sideways, falling
    return np.array([8.0 + 70.0 * t, 10.0 + 0.5 * 120.0 * t**2])


def test_a_falling_disc_between_frames_is_where_the_fall_puts_it():
    fps, radius = 30.0, 6.0
    recorded_t = np.arange(19) / fps  # 0.6 s, inside the image
    masks = torch.from_numpy(np.stack([_disc(_falling_centre(t), radius) for t in recorded_t]))
    colour = torch.tensor([0.9, 0.3, 0.1])
    frames = masks[..., None].float() * colour  # the object on black
    before, after, weight = resample_between(len(recorded_t), fps, FRAME_DT)
    _, between, objects = frames_between(frames, masks.float(), before, after, weight)
    wanted = np.arange(len(before)) * FRAME_DT
    nearest = resample_indices(len(recorded_t), fps, FRAME_DT)
    errors, nearest_errors, areas = [], [], []
    for j, t in enumerate(wanted):
        v, u = np.nonzero(between[j].numpy())
        centroid = np.array([u.mean(), v.mean()]) + 0.5
        errors.append(np.abs(centroid - _falling_centre(t)).max())
        v, u = np.nonzero(masks[nearest[j]].numpy())
        nearest_errors.append(
            np.abs(np.array([u.mean(), v.mean()]) + 0.5 - _falling_centre(t)).max()
        )
        areas.append(float(between[j].sum()))
    assert max(errors) < 0.35, errors  # the fall between frames: a third of a pixel
    assert max(nearest_errors) > 0.9  # what the nearest recorded frame is off by
    disc_area = float(masks[0].sum())
    assert np.allclose(areas, disc_area, rtol=0.08)  # neither doubled nor thinned
    inside = between.bool()
    assert torch.allclose(objects[inside], colour.expand(int(inside.sum()), 3), atol=1e-6)
    assert float(objects[~inside].abs().max()) == 0.0  # no ghost outside the mask


def test_a_thin_part_moving_across_is_kept():
    masks = torch.zeros(2, SIZE, SIZE)
    masks[0, 10:40, 20] = 1  # a one-pixel-wide rod
    masks[1, 10:40, 23] = 1  # three pixels to the right a frame later
    frames = masks[..., None].expand(-1, -1, -1, 3).clone()
    for w in (0.25, 0.5, 0.75):
        _, mask, _ = frames_between(frames, masks, np.array([0]), np.array([1]), np.array([w]))
        columns = torch.nonzero(mask[0].sum(0)).flatten().tolist()
        assert mask[0].sum() >= 30 and 1 <= len(columns) <= 2
        assert abs(np.mean(columns) - (20 + 3 * w)) <= 0.5


@pytest.mark.parametrize("fps", [30.0, 1 / FRAME_DT])
def test_a_30_fps_video_reads_as_the_fall_at_the_simulators_times(tmp_path, fps):
    radius = 5.0
    t = np.arange(int(0.6 * fps)) / fps
    video = [
        (np.repeat(_disc(_falling_centre(s), radius)[..., None], 3, -1) * 230).astype(np.uint8)
        for s in t
    ]
    path = tmp_path / f"fall_{fps:.0f}.mp4"
    imageio.mimwrite(path, video, fps=fps, codec="libx264", quality=10, macro_block_size=1)
    observation = load_observation(path, camera="dataset")
    assert ("between" in observation.time_resampling) == (fps == 30.0)
    for j, mask in enumerate(observation.masks[:15]):
        assert np.abs(_centroid(mask) - _falling_centre(j * FRAME_DT)).max() < 0.5


def test_a_variable_rate_video_reads_each_frame_at_its_own_time(tmp_path, monkeypatch):
    """A phone that drops to 15 fps part-way (and skips two frames at 30): ffmpeg's frames of
    a variable-rate mp4 are read one for one at their own times (video.decoded_times), so the
    frames at the simulator's times show the disc where the fall puts it. Read at one mean
    rate instead (as before), the same video puts it pixels off, and this test sees it."""
    ticks = np.concatenate([np.arange(0, 8), [9, 10, 12, 13], np.arange(14, 19, 2)])  # 1/30 s
    t = ticks / 30.0
    assert video_module.variable_rate(t)
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(int(ticks.max()) + 1):  # every 1/30 s; the kept ones chosen below
        disc = _disc(_falling_centre(k / 30.0), 5.0)
        imageio.imwrite(
            frames / f"{k:03d}.png", (np.repeat(disc[..., None], 3, -1) * 230).astype(np.uint8)
        )
    keep = "+".join(f"eq(n\\,{k})" for k in ticks)
    path = tmp_path / "variable.mp4"
    command = ["-v", "error", "-framerate", "30", "-i", str(frames / "%03d.png")]
    command += ["-vf", f"select={keep}", "-fps_mode", "passthrough", "-c:v", "libx264"]
    command += ["-qp", "0", "-pix_fmt", "yuv444p", str(path)]
    assert run_ffmpeg(command).returncode == 0
    stamps = video_module.read_video(path)[4]
    assert stamps is not None and np.abs(stamps - t).max() < 1e-3
    observation = load_observation(path, camera="dataset")
    assert "variable frame rate (33–67 ms" in observation.time_resampling
    count = int(t[-1] / FRAME_DT) + 1
    errors = [
        np.abs(_centroid(mask) - _falling_centre(j * FRAME_DT)).max()
        for j, mask in enumerate(observation.masks[:count])
    ]
    assert max(errors) < 0.5
    monkeypatch.setattr(video_module, "variable_rate", lambda times: False)
    before = load_observation(path, camera="dataset")
    assert "variable" not in before.time_resampling
    errors = [
        np.abs(_centroid(mask) - _falling_centre(j * FRAME_DT)).max()
        for j, mask in enumerate(before.masks[:count])
    ]
    assert max(errors) > 2.0


def test_a_slow_motion_video_is_read_at_the_rate_the_phone_filmed_at(tmp_path):
    """Android's slow motion: filmed at 120 fps, written to play at 30 (the fall 4× slower),
    the filmed rate in the metadata (com.android.capture.fps). Read at 120 fps the frames at the
    simulator's times show the disc where the fall puts it, and prediction.json says why;
    without the tag the same file reads a fall 4× too slow."""
    t = np.arange(80) / 120.0
    video = [
        (np.repeat(_disc(_falling_centre(s), 5.0)[..., None], 3, -1) * 230).astype(np.uint8)
        for s in t
    ]
    played = tmp_path / "played.mp4"
    imageio.mimwrite(played, video, fps=30.0, codec="libx264", quality=10, macro_block_size=1)
    tagged = copy_with_metadata(played, tmp_path / "slow.mp4", {"com.android.capture.fps": "120"})
    assert video_module.slow_motion_rate(tagged) == pytest.approx((120.0, 30.0))
    assert video_module.slow_motion_rate(played) is None
    observation = load_observation(tagged, camera="dataset")
    assert "filmed at 120 fps and played at 30 (slow motion" in observation.time_resampling
    for j, mask in enumerate(observation.masks[:20]):
        assert np.abs(_centroid(mask) - _falling_centre(j * FRAME_DT)).max() < 0.5
    slowed = load_observation(played, camera="dataset")
    assert np.abs(_centroid(slowed.masks[19]) - _falling_centre(19 * FRAME_DT)).max() > 10


def test_a_phone_video_stored_sideways_reads_upright(tmp_path, caplog):
    """A phone filming upright stores its sensor's frames sideways and a display rotation in the
    video (a display matrix): read as it is shown — portrait, the disc where it was drawn in
    every frame — without a note about the frame size; the same frames without the rotation read
    sideways."""
    height, width = 64, 48
    v, u = np.mgrid[0:height, 0:width] + 0.5
    centres = [np.array([12.0 + 20.0 * s, 10.0 + 60.0 * s**2]) for s in np.arange(20) / 30.0]
    upright = [((u - c[0]) ** 2 + (v - c[1]) ** 2 <= 25.0) for c in centres]  # [H, W] discs
    stored = [np.ascontiguousarray(np.rot90(d, k=-1)) for d in upright]  # the sensor's frames
    stored = [(np.repeat(d[..., None], 3, -1) * 230).astype(np.uint8) for d in stored]
    sideways = tmp_path / "sideways.mp4"
    imageio.mimwrite(sideways, stored, fps=30.0, codec="libx264", quality=10, macro_block_size=1)
    phone = tmp_path / "phone.mp4"
    arguments = ["-v", "error", "-y", "-display_rotation", "90", "-i", str(sideways)]
    run = run_ffmpeg([*arguments, "-c", "copy", str(phone)])
    assert run.returncode == 0, run.stderr
    with caplog.at_level("WARNING"):
        frames = video_module.read_video(phone)[0]
    assert not caplog.records  # ffmpeg's rotation is expected: no note about the frame size
    assert frames.shape[1:3] == (height, width)
    for frame, centre in zip(frames, centres, strict=True):
        rows, cols = np.nonzero(frame[..., 1] > 115)
        assert np.abs(np.array([cols.mean(), rows.mean()]) + 0.5 - centre).max() < 0.5
    assert video_module.read_video(sideways)[0].shape[1:3] == (width, height)


def test_frames_made_smaller_beside_the_decoding_are_the_ones_made_after_it(tmp_path):
    """read_video's max_side (each frame resized in a thread as the next is decoded) gives the
    frames fit_within gives the whole decoded clip, in order; with ``until`` the same first
    frames."""
    generator = np.random.default_rng(0)
    clip = generator.integers(0, 256, (12, 90, 120, 3), dtype=np.uint8)
    path = tmp_path / "clip.mp4"
    imageio.mimwrite(path, clip, fps=30.0, codec="libx264", quality=10, macro_block_size=1)
    whole = video_module.read_video(path)[0]
    small = video_module.read_video(path, None, 50)[0]
    assert small.shape == (12, 38, 50, 3)
    assert np.array_equal(small, video_module.fit_within(whole, 50))
    first = video_module.read_video(path, 0.1, 50)[0]
    assert 3 <= len(first) < 12 and np.array_equal(first, small[: len(first)])


def test_a_files_listing_is_read_once_until_forgotten(tmp_path, monkeypatch):
    """ffmpeg lists a file's packets once per version of it (predict asks more than once); a
    new version, or forget_listings (a benchmark timing a user's first call), lists it again."""
    clip = np.zeros((4, 16, 16, 3), dtype=np.uint8)
    path = tmp_path / "clip.mp4"
    imageio.mimwrite(path, clip, fps=30.0, codec="libx264", macro_block_size=1)
    calls = []
    listed = video_module.run_ffmpeg

    def counted(arguments, **kwargs):
        calls.append(arguments)
        return listed(arguments, **kwargs)

    monkeypatch.setattr(video_module, "run_ffmpeg", counted)
    video_module.forget_listings()
    first = video_module.packet_times(path)
    assert first is not None and len(first) == 4 and len(calls) == 1
    assert np.array_equal(video_module.packet_times(path), first) and len(calls) == 1
    video_module.forget_listings()
    assert np.array_equal(video_module.packet_times(path), first) and len(calls) == 2
    imageio.mimwrite(path, np.concatenate([clip, clip]), fps=30.0, codec="libx264")
    assert len(video_module.packet_times(path)) == 8 and len(calls) == 3  # a new version
