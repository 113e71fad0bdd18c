"""An open shutter in the realistic look (settings.exposure_range_s): where the anchors are while
it is open, and what it changes in a dataset (the frames of a moving object, nothing else)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from reconphys.data import DropDataset, make_dataset, make_settings
from reconphys.data.generate import shutter_anchors
from reconphys.errors import InputError
from reconphys.physics import GRAVITY

DT = 0.03


def ballistic(x0: torch.Tensor, v0: torch.Tensor, t: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Position and velocity [N, 3] at time t of points launched at x0 with v0 under gravity."""
    g = torch.tensor(GRAVITY, dtype=torch.float64)
    return x0 + v0 * t + 0.5 * g * t**2, v0 + g * t


def still_drops(samples: int, resolution: int):
    """Realistic drops from rest of one object, without sensor noise and at the finest
    compression: two such datasets' frames differ by what the test changes alone."""
    return make_settings(
        scene="realistic", objects=1, test_objects=0, samples_per_object=samples,
        resolution=resolution, num_gaussians=300, num_anchors=64, toss_fraction=0.0,
        max_vertical_speed=0.0, max_horizontal_speed=0.0, noise_range=(0.0, 0.0),
        video_quality_range=(10.0, 10.0),
    )  # fmt: skip


def test_the_shutter_samples_a_free_fall_at_its_own_times():
    """In free fall the carried anchors are the analytic ballistic path at each sample's time
    (the midpoints of equal parts of the exposure, centred on the frame's time); before frame 0
    the object is held where it is let go; an anchor resting on the ground stays on it."""
    x0 = torch.tensor([[0.0, 0.0, 2.0], [0.1, -0.2, 2.3]], dtype=torch.float64)
    v0 = torch.tensor([[0.5, 0.0, 1.0], [0.5, 0.3, 1.0]], dtype=torch.float64)
    frames = [ballistic(x0, v0, k * DT) for k in range(6)]
    anchors = torch.stack([x for x, _ in frames])  # [T, N, 3]
    velocities = torch.stack([v for _, v in frames])
    exposure, samples = 0.02, 4
    moments = shutter_anchors(anchors, velocities, exposure, DT, samples=samples)
    assert moments.shape == (samples, 6, 2, 3)
    offsets = [-0.0075, -0.0025, 0.0025, 0.0075]  # seconds from the frame's time
    for j, offset in enumerate(offsets):
        for k in range(6):
            expected = x0 if k == 0 and offset < 0 else ballistic(x0, v0, k * DT + offset)[0]
            torch.testing.assert_close(moments[j, k], expected, atol=1e-12, rtol=0)
    resting = torch.zeros(3, 1, 3, dtype=torch.float64)  # on the ground, still
    carried = shutter_anchors(resting, torch.zeros_like(resting), DT, DT, samples=3)
    assert float(carried[..., 2].min()) == 0.0
    with pytest.raises(ValueError, match="exposure"):
        shutter_anchors(anchors, velocities, 2 * DT, DT)


def test_an_open_shutter_blurs_the_moving_object_and_changes_nothing_else(tmp_path):
    """--exposure draws the shutter from a stream of its own: every other part of a seed's
    scene and its physics stay; the stored scene says how long the shutter was open (and a sharp
    one says nothing, as before); the frames change where the object moves — frame 0, held still
    until the release, hardly at all, a falling frame more — while the true masks (the blurred
    coverage over ½) keep about the object's size."""
    from reconphys.data.scene import draw_scene

    sharp = still_drops(samples=2, resolution=32)
    blurred = replace(sharp, exposure_range_s=(DT, DT))
    assert sharp.fingerprint() != blurred.fingerprint()
    assert replace(sharp, exposure_range_s=(0.0, 0.0)).fingerprint() == sharp.fingerprint()
    for i in range(20):
        a, b = draw_scene(sharp, f"object-{i}", 0), draw_scene(blurred, f"object-{i}", 0)
        assert a.exposure_s == 0.0 and b.exposure_s == DT
        assert replace(b, exposure_s=0.0) == a
    with pytest.raises(InputError, match=r"--exposure .*frame interval"):
        replace(sharp, exposure_range_s=(0.0, 2 * DT)).validated()
    with pytest.raises(InputError, match=r"--exposure.*realistic look only"):  # not on black
        replace(blurred, scene="plain").validated()
    make_dataset(sharp, tmp_path / "sharp", workers=1, device="cpu")
    make_dataset(blurred, tmp_path / "blurred", workers=1, device="cpu")
    before, after = DropDataset(tmp_path / "sharp"), DropDataset(tmp_path / "blurred")
    assert "exposure_s" not in before.meta(0)["scene"]
    assert after.meta(0)["scene"]["exposure_s"] == DT
    assert after[0]["attributes"].equal(before[0]["attributes"])
    assert torch.equal(after[0]["anchors"], before[0]["anchors"])
    contact = before.meta(0)["contact_frame"]
    assert contact >= 4
    change = (after[0]["frames"] - before[0]["frames"]).abs().mean(dim=(0, 2, 3, 4))  # [T]
    assert float(change[contact - 1]) > 3 * float(change[0])
    masks_before, masks_after = before.masks(0).float(), after.masks(0).float()  # [V, T, H, W]
    ratio = masks_after.sum(dim=(2, 3)) / masks_before.sum(dim=(2, 3)).clamp(min=1)
    assert float(np.median(ratio.numpy())) == pytest.approx(1.0, abs=0.1)


def test_a_shifted_shutter_is_the_free_fall_at_the_shifted_times():
    """A row read later (``shift``, a rolling shutter) sees the fall that much later: the
    analytic ballistic path at t + shift + each exposure sample's offset."""
    x0 = torch.tensor([[0.0, 0.0, 2.0]], dtype=torch.float64)
    v0 = torch.tensor([[0.3, 0.0, 0.5]], dtype=torch.float64)
    frames = [ballistic(x0, v0, k * DT) for k in range(4)]
    anchors, velocities = torch.stack([x for x, _ in frames]), torch.stack([v for _, v in frames])
    moments = shutter_anchors(anchors, velocities, 0.01, DT, samples=2, shift=0.012)
    for j, offset in enumerate((0.0095, 0.0145)):
        for k in range(4):
            expected = ballistic(x0, v0, k * DT + offset)[0]
            torch.testing.assert_close(moments[j, k], expected, atol=1e-12, rtol=0)


def test_a_rolling_readout_catches_the_falling_object_lower_row_by_row(tmp_path):
    """--readout reads each band of rows at its own time, top to bottom: a falling object's
    lower rows are caught later than its upper ones, so its mask in a falling frame is taller
    than the global shutter's (by about its image speed × the readout × its share of the image
    height); frame 0, held still until the release, hardly changes; the physics and the rest of
    the scene are the seed's, and the stored scene says the readout."""
    from reconphys.data.scene import draw_scene

    settings = still_drops(samples=1, resolution=64)
    rolling = replace(settings, readout_range_s=(DT, DT))
    a, b = draw_scene(settings, "object-0", 0), draw_scene(rolling, "object-0", 0)
    assert b.readout_s == DT and replace(b, readout_s=0.0) == a
    with pytest.raises(InputError, match=r"--readout .*frame interval"):
        replace(settings, readout_range_s=(0.0, 2 * DT)).validated()
    make_dataset(settings, tmp_path / "global", workers=1, device="cpu")
    make_dataset(rolling, tmp_path / "rolling", workers=1, device="cpu")
    before, after = DropDataset(tmp_path / "global"), DropDataset(tmp_path / "rolling")
    assert after.meta(0)["scene"]["readout_s"] == DT and "readout_s" not in before.meta(0)["scene"]
    assert after[0]["attributes"].equal(before[0]["attributes"])
    rows = torch.arange(64, dtype=torch.float64)
    contact = before.meta(0)["contact_frame"]
    taller = []
    for view in range(4):
        for k in range(2, contact):  # falling, off the ground
            m0, m1 = before.masks(0)[view, k], after.masks(0)[view, k]
            if not (m0.any() and m1.any()):
                continue
            r0, r1 = rows[m0.any(1)], rows[m1.any(1)]
            taller.append(float((r1.max() - r1.min()) - (r0.max() - r0.min())))
    assert len(taller) > 10 and np.mean(taller) > 0.5
    change = (after[0]["frames"] - before[0]["frames"]).abs().mean(dim=(0, 2, 3, 4))  # [T]
    assert float(change[contact - 1]) > 3 * float(change[0])
