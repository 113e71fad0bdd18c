"""Frames at the simulator's times from a recording at another rate (capture/interpolate.py):
where the times fall, and that the frames made between two recorded ones show the object where
an analytic fall puts it, at its size, in its colours."""

from __future__ import annotations

import imageio.v2 as imageio
import numpy as np
import pytest
import torch

from reconphys.capture import load_observation
from reconphys.capture.interpolate import frames_between
from reconphys.capture.video import resample_between, resample_indices

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
