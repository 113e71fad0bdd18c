"""The field of view without a camera file (capture/lens.py): a 35 mm-equivalent focal length
against the textbook angles of 35 mm film, the assumed 45° across the shorter side (a phone held
either way), the order given → the video's metadata → assumed, and the metadata read from a
phone-style mp4 (QuickTime key) and a frame folder's EXIF, through predict's reading of the
recording (load_observation)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from reconphys.capture import load_observation
from reconphys.capture.lens import (
    DEFAULT_SHORT_SIDE_FOV_DEG,
    default_fov_deg,
    focal_35mm_from_pixels,
    fov_from_focal_35mm,
    recording_fov,
)
from reconphys.capture.video import read_focal_35mm
from reconphys.errors import InputError
from reconphys.render.video import FOCAL_35MM_KEY, copy_with_metadata, write_mp4


def _horizontal(vertical_deg: float, width: int, height: int) -> float:
    return math.degrees(2 * math.atan(math.tan(math.radians(vertical_deg) / 2) * width / height))


def test_a_lens_on_35mm_film_gives_the_textbook_angles():
    """A 50 mm lens on 36 × 24 mm film: 2·atan(12/50) = 27.0° vertical, 2·atan(18/50) = 39.6°
    horizontal (any pixel count of that shape); a 28 mm one: 46.4° / 65.5°. The inverse gives
    the focal length back from a camera's focal length in pixels."""
    for focal in (50.0, 28.0):
        for width, height in ((360, 240), (1500, 1000)):
            vertical = fov_from_focal_35mm(focal, width, height)
            assert vertical == pytest.approx(math.degrees(2 * math.atan(12 / focal)), abs=1e-9)
            assert _horizontal(vertical, width, height) == pytest.approx(
                math.degrees(2 * math.atan(18 / focal)), abs=1e-9
            )
            focal_px = 0.5 * height / math.tan(math.radians(vertical) / 2)
            assert focal_35mm_from_pixels(focal_px, width, height) == pytest.approx(focal)
    with pytest.raises(ValueError):
        fov_from_focal_35mm(0.0, 100, 100)


def test_the_assumed_field_of_view_is_45_degrees_across_the_shorter_side():
    """Landscape and square frames keep 45° vertical; a portrait one gets 45° across its width
    (72.7° vertical at 9:16), near what a phone's 26 mm main camera gives held upright
    (71.9°), where 45° vertical would be a 26° wide telephoto view."""
    assert default_fov_deg(1920, 1080) == pytest.approx(DEFAULT_SHORT_SIDE_FOV_DEG)
    assert default_fov_deg(96, 96) == pytest.approx(DEFAULT_SHORT_SIDE_FOV_DEG)
    portrait = default_fov_deg(1080, 1920)
    assert _horizontal(portrait, 1080, 1920) == pytest.approx(DEFAULT_SHORT_SIDE_FOV_DEG)
    assert portrait == pytest.approx(72.7, abs=0.05)
    assert abs(portrait - fov_from_focal_35mm(26.0, 1080, 1920)) < 1.5
    assert abs(default_fov_deg(1920, 1080) - fov_from_focal_35mm(26.0, 1920, 1080)) < 1.5


def test_the_given_fov_comes_first_then_the_lens_then_the_assumption():
    assert recording_fov(30.0, 26.0, 1080, 1920) == (30.0, "given (--fov)")
    fov, source = recording_fov(None, 26.0, 1080, 1920)
    assert fov == pytest.approx(fov_from_focal_35mm(26.0, 1080, 1920))
    assert "metadata" in source and "26 mm" in source
    for not_a_lens in (None, 2.0, 5000.0):  # absent, or no phone's lens: the assumption
        fov, source = recording_fov(None, not_a_lens, 1080, 1920)
        assert fov == pytest.approx(default_fov_deg(1080, 1920)) and source.startswith("assumed")


WIDTH, HEIGHT, FRAME_DT = 36, 64, 0.03  # a portrait (9:16) clip


def _falling_disc() -> np.ndarray:
    """A white disc falling on black (pitch 0, 1.5 m away, a 72°-vertical camera: 288 px/s²),
    then resting: [30, HEIGHT, WIDTH, 3] uint8."""
    focal_px = 0.5 * HEIGHT / math.tan(math.radians(36.0))
    acceleration = 9.81 * focal_px / 1.5
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH] + 0.5
    frames = []
    for t in range(30):
        centre = min(12 + 0.5 * acceleration * (t * FRAME_DT) ** 2, 44.0)
        disc = (rows - centre) ** 2 + (cols - WIDTH / 2) ** 2 <= 16
        frames.append(np.repeat(disc[..., None] * 255, 3, axis=-1).astype(np.uint8))
    return np.stack(frames)


def test_predict_reads_the_lens_from_a_phone_video_and_a_frame_folders_exif(tmp_path):
    """An mp4 with the QuickTime key an iPhone writes: its lens's field of view is the
    estimated camera's (prediction.json says so); the same mp4 without it: 45° across the
    shorter side; ``--fov`` wins over both. A folder of JPEG frames carries it as EXIF
    FocalLengthIn35mmFilm. Missing or unreadable metadata is None, never an error."""
    frames = _falling_disc()
    plain = write_mp4(tmp_path / "plain.mp4", frames, fps=1 / FRAME_DT)
    phone = copy_with_metadata(plain, tmp_path / "phone.mp4", {FOCAL_35MM_KEY: "24"})
    assert read_focal_35mm(phone) == 24.0 and read_focal_35mm(plain) is None
    estimate = load_observation(phone).camera_estimate
    assert estimate["fov_deg"] == pytest.approx(fov_from_focal_35mm(24.0, WIDTH, HEIGHT), abs=1e-3)
    assert "metadata" in estimate["fov_from"] and "24 mm" in estimate["fov_from"]
    estimate = load_observation(plain).camera_estimate
    assert estimate["fov_deg"] == pytest.approx(default_fov_deg(WIDTH, HEIGHT), abs=1e-3)
    assert estimate["fov_from"].startswith("assumed")
    estimate = load_observation(phone, fov_deg=40.0).camera_estimate
    assert estimate["fov_deg"] == 40.0 and estimate["fov_from"] == "given (--fov)"

    folder = tmp_path / "jpegs"
    folder.mkdir()
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 28  # FocalLengthIn35mmFilm
    for t, frame in enumerate(frames):
        Image.fromarray(frame).save(folder / f"{t:03d}.jpg", exif=exif if t == 0 else b"")
    assert read_focal_35mm(folder) == 28.0
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video")
    assert read_focal_35mm(broken) is None and read_focal_35mm(tmp_path / "missing.mov") is None


def test_a_camera_file_with_only_k_gives_the_field_of_view_and_the_pose_is_read(tmp_path):
    """A checkerboard calibration gives K but no pose: such a camera file sets the estimate's
    intrinsics (a 60° lens whose principal point is 3 px off the centre, written for a frame
    twice the clip's size), and the pose and ground are still read from the fall."""
    frames = _falling_disc()
    clip = write_mp4(tmp_path / "clip.mp4", frames, fps=1 / FRAME_DT)
    focal = HEIGHT / math.tan(math.radians(30.0))  # at 2× the clip's size: a 60° vertical view
    K = [[focal, 0.0, WIDTH + 3.0], [0.0, focal, HEIGHT], [0.0, 0.0, 1.0]]
    intrinsics = tmp_path / "intrinsics.json"
    intrinsics.write_text(json.dumps({"K": K, "width": 2 * WIDTH, "height": 2 * HEIGHT}))
    observation = load_observation(clip, camera=intrinsics)
    estimate = observation.camera_estimate
    assert estimate["fov_deg"] == pytest.approx(60.0, abs=1e-3)
    assert "camera file's K" in estimate["fov_from"]
    assert float(observation.camera.K[0, 2]) == pytest.approx(WIDTH / 2 + 1.5)
    assert estimate["distance_m"] > 0 and estimate["camera_height_m"] > 0
    with pytest.raises(InputError, match="principal point"):
        intrinsics.write_text(json.dumps({"K": K}))  # K for 72 × 128 read at 36 × 64
        load_observation(clip, camera=intrinsics)
