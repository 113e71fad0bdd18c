"""A hand-held camera's shake (capture/stabilize.py), on synthetic clips whose shake is known: a
textured background filmed by a camera that moves by a random walk of sub-pixel steps, with a
disc falling in front of it. The shake is read to a fraction of a pixel, a static camera's clip
is left as it is, a plain background says nothing, and predict's reading of the recording
(load_observation) takes the shake out before the masks and the camera."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from reconphys.capture import load_observation, stabilize
from reconphys.capture.stabilize import (
    MAX_SHAKE_SHARE,
    READ_MAX_SIDE,
    STILL_PX,
    crop_margin,
    read_shake,
    steady,
    warp,
)
from reconphys.errors import InputError

SIZE, PAD, FRAMES = 96, 8, 30


def _walk(step: float, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    steps = torch.randn(FRAMES, 2, generator=generator) * step
    steps[0] = 0
    return steps.cumsum(0).clamp(-PAD + 1, PAD - 1)


def _scene(shifts: torch.Tensor, textured: bool = True, zoom: int = 1):
    """Frames [T, SIZE, SIZE, 3] of a disc falling (then resting) before a background, the
    camera moved so that the picture shifts by ``shifts`` [T, 2] px; the disc's true masks in
    the same frames, and the background alone as frame 0 sees it (a clean plate). ``zoom``: the
    same scene filmed with ``zoom`` times the pixels a side (``shifts`` in those pixels)."""
    side = (SIZE + 2 * PAD) * zoom
    generator = torch.Generator().manual_seed(1)
    if textured:  # smooth blotches, 4-px grain: a floor and a wall of a real room
        noise = torch.rand(1, 3, side // (4 * zoom), side // (4 * zoom), generator=generator)
        background = F.interpolate(noise, size=(side, side), mode="bicubic", align_corners=False)
        background = (0.2 + 0.6 * background[0].permute(1, 2, 0)).clamp(0, 1)
    else:
        background = torch.full((side, side, 3), 0.45)
    rows, cols = torch.meshgrid(torch.arange(side) + 0.5, torch.arange(side) + 0.5, indexing="ij")
    frames, masks = [], []
    for t in range(FRAMES):
        centre_row = zoom * min(PAD + 16 + 900 * (t * 0.03) ** 2, PAD + 70)
        disc = ((rows - centre_row) ** 2 + (cols - side / 2) ** 2 <= 64 * zoom**2).float()
        frames.append(
            background * (1 - disc[..., None]) + disc[..., None] * torch.tensor([0.9, 0.15, 0.1])
        )
        masks.append(disc)
    pad = PAD * zoom
    frames = warp(torch.stack(frames), shifts)[:, pad:-pad, pad:-pad]
    masks = warp(torch.stack(masks)[..., None], shifts)[:, pad:-pad, pad:-pad, 0]
    return frames, masks, background[pad:-pad, pad:-pad]


def test_warp_moves_the_content_by_the_shift():
    """Whole-pixel shifts move the picture exactly (the border repeated), and a shift there and
    back again returns it."""
    images = torch.rand(2, 20, 24, 3)
    moved = warp(images, torch.tensor([[2.0, -1.0], [0.0, 3.0]]))
    assert torch.allclose(moved[0, 1:-1, 2:], images[0, 2:, :-2], atol=1e-6)
    assert torch.allclose(moved[1, 3:], images[1, :-3], atol=1e-6)
    back = warp(moved, -torch.tensor([[2.0, -1.0], [0.0, 3.0]]))
    assert torch.allclose(back[0, 2:-2, 3:-3], images[0, 2:-2, 3:-3], atol=1e-6)


def test_the_shake_is_read_to_a_fifth_of_a_pixel_and_the_falling_object_is_not_it():
    shifts = _walk(0.6)
    frames, _, _ = _scene(shifts)
    shake = read_shake(frames)
    assert shake.shifts is not None and shake.tiles_read >= 12
    assert float((shake.shifts - shifts).norm(dim=1).max()) < 0.2
    assert crop_margin(shake) == int(np.ceil(float(shake.shifts.abs().max())))
    still, _, _ = _scene(torch.zeros(FRAMES, 2))  # a static camera: the disc alone moves
    calm = read_shake(still)
    assert calm.shifts is not None and calm.largest_px < 0.1 < STILL_PX
    assert crop_margin(calm) == 0 and steady(still, calm) is still


def test_a_large_clip_is_read_at_the_size_the_thresholds_are_for():
    """A phone's frame read at 384 px (4× the pixels a side): its texture per pixel is a
    sixteenth, below the threshold in every tile at full size; read area-averaged to
    READ_MAX_SIDE, the shake is found to a fifth of a (small) pixel, and a still camera's stays
    under STILL_PX."""
    zoom = 4
    shifts = _walk(0.6, seed=7) * zoom
    frames, _, _ = _scene(shifts, zoom=zoom)
    assert frames.shape[1] == SIZE * zoom > READ_MAX_SIDE
    shake = read_shake(frames)
    assert shake.shifts is not None and shake.tiles_read >= 12
    assert float((shake.shifts - shifts).norm(dim=1).max()) < 0.2 * zoom
    with pytest.MonkeyPatch.context() as patch:  # the whole frame read as it is: nothing found
        patch.setattr(stabilize, "READ_MAX_SIDE", 10**6)
        assert read_shake(frames).shifts is None
    still, _, _ = _scene(torch.zeros(FRAMES, 2), zoom=zoom)
    calm = read_shake(still)
    assert calm.shifts is not None and calm.largest_px < STILL_PX and crop_margin(calm) == 0


def test_a_plain_background_does_not_say_how_the_camera_moved():
    """Nor does a textured object on it: a patterned box sliding half a pixel a frame across a plain
    floor, still camera, covers two by two tiles at most and is not read as the camera."""
    frames, _, _ = _scene(_walk(0.6), textured=False)
    shake = read_shake(frames)
    assert shake.shifts is None and shake.tiles_read < 4
    assert crop_margin(shake) == 0 and steady(frames, shake) is frames
    assert shake.to_json()["readable"] is False
    pattern = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(2))
    sliding = torch.full((FRAMES, SIZE, SIZE, 3), 0.45)
    for t in range(FRAMES):
        sliding[t, 28:60, 26 + t // 2 : 58 + t // 2] = pattern
    boxed = read_shake(sliding)
    assert boxed.shifts is None and boxed.tiles_read >= 4  # textured tiles, all around the box


def test_steady_puts_every_frame_back_on_frame_0():
    shifts = _walk(0.6, seed=3)
    frames, _, _ = _scene(shifts)
    still, _, _ = _scene(torch.zeros(FRAMES, 2))
    shake = read_shake(frames)
    margin = crop_margin(shake)
    steadied = steady(frames, shake)
    assert steadied.shape == (FRAMES, SIZE - 2 * margin, SIZE - 2 * margin, 3)
    inner = still[:, margin:-margin, margin:-margin]
    before = (frames[:, margin:-margin, margin:-margin] - inner).abs().mean()
    after = (steadied - inner).abs().mean()
    assert after < 0.01 < before / 3


def _write_frames(folder, frames: torch.Tensor):
    folder.mkdir()
    for t, frame in enumerate(frames):
        iio.imwrite(folder / f"{t:03d}.png", (frame.numpy() * 255).round().astype(np.uint8))
    return folder


def test_predict_takes_the_shake_out_before_the_plate_and_the_camera(tmp_path, monkeypatch):
    """A shaken recording (lossless frames) with a clean plate: without the shake taken out the
    plate's subtraction marks the background's edges as the object; with it, the masks are the
    disc's. The dataset camera is cropped with the frames (its principal point moves), and
    prediction.json's ``camera_shake`` says what was done. A camera that pans by a third of the
    frame is refused with a one-line error."""
    frames, _, plate = _scene(_walk(0.6, seed=5))
    clip = _write_frames(tmp_path / "shaken", frames)
    plate_file = tmp_path / "plate.png"
    iio.imwrite(plate_file, (plate.numpy() * 255).round().astype(np.uint8))
    observation = load_observation(clip, background=plate_file, camera="dataset")
    report = observation.camera_shake
    assert report["readable"] and report["taken_out"] and report["crop_px"] >= 1
    margin = report["crop_px"]
    side = SIZE - 2 * margin
    assert observation.masks.shape[1:] == (side, side)
    truth = _scene(torch.zeros(FRAMES, 2))[1][:, margin:-margin, margin:-margin]
    union = ((observation.masks + truth) > 0).sum()
    assert float((observation.masks * truth).sum() / union) > 0.8
    assert observation.camera.width == side and observation.camera.height == side
    assert float(observation.camera.K[0, 2]) == pytest.approx(side / 2, abs=1e-6)
    with monkeypatch.context() as patch:  # the shake left in: the plate no longer matches
        patch.setattr(stabilize, "STILL_PX", 1e9)
        with pytest.raises(InputError, match="do not find one object"):
            load_observation(clip, background=plate_file, camera="dataset")
    pan = torch.stack([torch.tensor([t * 1.0, 0.0]) for t in range(FRAMES)])  # 29 px by the end
    assert 29 > MAX_SHAKE_SHARE * SIZE
    panned = _write_frames(tmp_path / "panned", _scene(pan)[0])
    with pytest.raises(InputError, match="the camera moves"):
        load_observation(panned, background=plate_file, camera="dataset")
