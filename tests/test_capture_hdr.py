"""A phone's HDR video (HLG or PQ, 10-bit, BT.2020) is read as the SDR frames the models know.

The clips are written here from sRGB frames by ITU-R BT.2100's and BT.2408's formulas, in numpy
(independent of the zimg conversion that reads them): SDR white at 203 cd/m², BT.709 → BT.2020
in linear light, the PQ curve, or HLG on the 1000 cd/m² reference display (system gamma 1.2,
by the luminance), then Y'CbCr (non-constant luminance, 10-bit narrow range, 4:4:4), stored
losslessly (FFV1) with the stream's colour tags.
"""

from __future__ import annotations

import json
import subprocess

import imageio_ffmpeg
import numpy as np
import pytest
from typer.testing import CliRunner

import reconphys.capture.video as video_module
from reconphys.capture import load_observation
from reconphys.cli import app
from reconphys.render.video import run_ffmpeg

needs_zscale = pytest.mark.skipif(
    not video_module._has_zscale(), reason="this ffmpeg has no zscale (IMAGEIO_FFMPEG_EXE)"
)
BT709_TO_BT2020 = np.array(
    [[0.6274, 0.3293, 0.0433], [0.0691, 0.9195, 0.0114], [0.0164, 0.0880, 0.8956]]
)
LUMA = {"bt2020": np.array([0.2627, 0.6780, 0.0593]), "bt709": np.array([0.2126, 0.7152, 0.0722])}


def _pq(nits: np.ndarray) -> np.ndarray:  # SMPTE ST 2084 inverse EOTF: cd/m² → signal
    m1, m2 = 2610 / 16384, 2523 / 4096 * 128
    c1, c2, c3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
    y = (np.clip(nits, 0, None) / 10000.0) ** m1
    return ((c1 + c2 * y) / (1 + c3 * y)) ** m2


def _hlg(nits: np.ndarray) -> np.ndarray:  # display light [..., 3] → HLG signal (Lw 1000, γ 1.2)
    gamma, peak = 1.2, 1000.0
    luminance = np.clip(nits @ LUMA["bt2020"], 1e-9, None)[..., None]
    scene = (luminance / peak) ** ((1 - gamma) / gamma) * np.clip(nits, 0, None) / peak
    a, b, c = 0.17883277, 0.28466892, 0.55991073
    low = np.sqrt(3 * scene)
    high = a * np.log(np.clip(12 * scene - b, 1e-12, None)) + c
    return np.where(scene <= 1 / 12, low, high)


def bt2100_codes(frames: np.ndarray, curve: str, primaries: str = "bt2020") -> np.ndarray:
    """[T, H, W, 3] sRGB uint8 → [T, 3, H, W] uint16 Y'CbCr codes of the HDR signal of ``curve``
    ("HLG", "PQ") in ``primaries`` ("bt2020"; "bt709" for PQ: the colours as they are)."""
    c = frames.astype(np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    nits = 203.0 * (linear @ BT709_TO_BT2020.T if primaries == "bt2020" else linear)
    signal = _pq(nits) if curve == "PQ" else _hlg(nits)
    kr, _, kb = LUMA[primaries]
    luma = signal @ LUMA[primaries]
    cb = (signal[..., 2] - luma) / (2 * (1 - kb))
    cr = (signal[..., 0] - luma) / (2 * (1 - kr))
    codes = np.stack([64 + 876 * luma, 512 + 896 * cb, 512 + 896 * cr], axis=1)
    return np.clip(np.rint(codes), 0, 1023).astype("<u2")


def _write_hdr(
    path, frames: np.ndarray, curve: str | None, primaries: str = "bt2020", tags: str = "all"
) -> None:
    """An FFV1 clip of ``frames`` (sRGB) as the HDR signal of ``curve``, its stream tagged with
    its matrix, primaries and curve (``tags`` "all"), the curve alone ("transfer"), or — with
    curve None — nothing (the same HLG codes: a clip that does not say it is HDR)."""
    codes = bt2100_codes(frames, curve or "HLG", primaries)
    height, width = frames.shape[1:3]
    given = []
    if curve is not None:
        given = ["-color_trc", {"HLG": "arib-std-b67", "PQ": "smpte2084"}[curve]]
        if tags == "all":
            matrix = "bt2020nc" if primaries == "bt2020" else "bt709"
            given += ["-color_primaries", primaries, "-colorspace", matrix]
    raw = path.with_suffix(".yuv")
    raw.write_bytes(codes.tobytes())
    arguments = ["-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "yuv444p10le"]
    arguments += ["-s", f"{width}x{height}", "-r", "33.333", *given, "-color_range", "tv"]
    run = run_ffmpeg([*arguments, "-i", str(raw), "-c:v", "ffv1", str(path)])
    assert run.returncode == 0, run.stderr


def test_the_clips_codes_are_bt2100s():
    """This file's encoder against codes worked out by hand from BT.2100: SDR white (203 cd/m²)
    is HLG's 75 % (code 721) and PQ's 58.07 % (573); sRGB grey 128 (43.8 cd/m²) 476 and 439."""
    greys = np.array([255, 128], np.uint8)[:, None, None, None].repeat(3, axis=-1)
    assert bt2100_codes(greys, "HLG")[:, 0, 0, 0].tolist() == [721, 476]
    assert bt2100_codes(greys, "PQ")[:, 0, 0, 0].tolist() == [573, 439]
    assert (bt2100_codes(greys, "PQ")[:, 1:] == 512).all()  # no colour in a grey


def _patches(colours: np.ndarray) -> np.ndarray:  # [16, 3] → [2, 32, 32, 3] 8-px patches
    frame = np.repeat(np.repeat(colours.reshape(4, 4, 3), 8, axis=0), 8, axis=1)
    return np.stack([frame, frame[::-1]])


# Colours inside BT.709's gamut (every channel ≥ 20): greys, skin, sky, and random ones
INNER = np.array(
    [
        *([255, 255, 255], [128, 128, 128], [40, 40, 40], [230, 160, 120], [20, 120, 200]),
        *([200, 40, 30], [40, 180, 60], [50, 60, 210]),
    ],
    dtype=np.uint8,
)


@pytest.mark.parametrize("curve", ["HLG", "PQ"])
@needs_zscale
def test_an_hdr_video_reads_as_its_sdr_frames(tmp_path, curve):
    generator = np.random.default_rng(3)
    colours = np.concatenate([INNER, generator.integers(20, 256, (8, 3), dtype=np.uint8)])
    frames = _patches(colours)
    path = tmp_path / "phone.mkv"
    _write_hdr(path, frames, curve)
    assert video_module.hdr_transfer(path) == curve
    read = video_module.read_video(path)[0].astype(int)
    assert np.abs(read - frames).max() <= 3  # the SDR frames back, to the 10-bit signal's rounding
    # read at most 16 px a side: the SDR frames made smaller (fit_within), to rounding
    small = video_module.read_video(path, None, 16)[0].astype(int)
    assert np.abs(small - video_module.fit_within(frames, 16)).max() <= 3
    # BT.709's pure primaries: a channel at 0 is a difference of large BT.2020 values, so the
    # 10-bit signal's rounding shows there (~10 levels on the sRGB curve's steep foot)
    primaries = _patches(np.eye(3, dtype=np.uint8)[np.arange(16) % 3] * 255)
    _write_hdr(path, primaries, curve)
    assert np.abs(video_module.read_video(path)[0].astype(int) - primaries).max() <= 16
    # told nothing (the same codes untagged), the frames are read as stored: dim and grey
    untagged = tmp_path / "untagged.mkv"
    _write_hdr(untagged, frames, None)
    assert video_module.hdr_transfer(untagged) is None
    stored = video_module.read_video(untagged)[0].astype(int)
    assert np.abs(stored - frames).mean() > 10


@needs_zscale
def test_an_hdr_videos_colour_tags_are_followed(tmp_path):
    """PQ in BT.709's primaries and matrix, so tagged, reads in them; a stream that names its
    curve alone is taken as BT.2020 (BT.2100's), as a phone writes it."""
    generator = np.random.default_rng(5)
    frames = _patches(np.concatenate([INNER, generator.integers(20, 256, (8, 3), np.uint8)]))
    path = tmp_path / "bt709.mkv"
    _write_hdr(path, frames, "PQ", primaries="bt709")
    assert np.abs(video_module.read_video(path)[0].astype(int) - frames).max() <= 3
    path = tmp_path / "curve_alone.mkv"
    _write_hdr(path, frames, "PQ", tags="transfer")
    assert video_module.hdr_transfer(path) == "PQ"
    assert np.abs(video_module.read_video(path)[0].astype(int) - frames).max() <= 3
    line = "Stream #0:0: Video: hevc (Main 10), yuv420p10le(tv, {}, progressive), 64x64"
    assert video_module._unknown_colour_tags(line.format("bt2020nc/bt2020/arib-std-b67")) == ()
    assert video_module._unknown_colour_tags(line.format("unknown/bt2020/smpte2084")) == ("min",)
    assert video_module._unknown_colour_tags(line.format("arib-std-b67")) == ("min", "pin")


def test_a_video_with_tags_that_are_not_utf8_reads(tmp_path):
    """A title in Latin-1 (bytes that are not UTF-8) in ffmpeg's description of the file is
    replaced, not raised on: the clip reads as before."""
    path = tmp_path / "latin1.avi"
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi", "-i"]
    command += ["testsrc=size=32x32:rate=30:duration=0.2", "-metadata", b"title=Caf\xe9 drop"]
    subprocess.run([*command, "-c:v", "mjpeg", str(path)], check=True, capture_output=True)
    assert b"Caf\xe9" in path.read_bytes()
    assert video_module.hdr_transfer(path) is None
    assert video_module.read_video(path)[0].shape == (6, 32, 32, 3)


@needs_zscale
def test_an_hdr_recording_says_so(tmp_path):
    """predict reads an HLG drop as SDR and says so (prediction.json's input.dynamic_range, a
    printed line); an SDR clip of the same frames says nothing."""
    height = width = 64
    v, u = np.mgrid[0:height, 0:width] + 0.5
    frames = np.full((24, height, width, 3), 25, np.uint8)  # a dark backdrop
    for j, frame in enumerate(frames):
        centre = (32.0, 8.0 + 0.5 * 9.81 * (j * 0.03) ** 2 * 20.0)  # falling, 20 px/m
        frame[(u - centre[0]) ** 2 + (v - centre[1]) ** 2 <= 25.0] = (230, 90, 40)
    path = tmp_path / "drop.mkv"
    _write_hdr(path, frames, "HLG")
    observation = load_observation(path, camera="dataset")
    assert observation.hdr == "HLG"
    inside = observation.recording[0, 8, 32].numpy() * 255
    assert np.abs(inside - (230, 90, 40)).max() <= 2
    out = tmp_path / "asset"
    options = ["--camera", "dataset", "--no-refine", "--preview-frames", "0", "--out", str(out)]
    result = CliRunner().invoke(app, ["predict", str(path), *options])
    assert result.exit_code == 0, result.output
    assert "colours: HDR (HLG) read as SDR" in result.output
    read = json.loads((out / "prediction.json").read_text())["input"]
    assert read["dynamic_range"].startswith("HDR (HLG) read as SDR")
    sdr = tmp_path / "drop_sdr.mkv"
    raw = tmp_path / "drop.rgb"
    raw.write_bytes(frames.tobytes())
    arguments = ["-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", "64x64"]
    run = run_ffmpeg([*arguments, "-r", "33.333", "-i", str(raw), "-c:v", "ffv1", str(sdr)])
    assert run.returncode == 0, run.stderr
    assert load_observation(sdr, camera="dataset").hdr is None


def test_without_zscale_an_hdr_video_is_refused_in_one_line(tmp_path, monkeypatch):
    path = tmp_path / "phone.mkv"
    _write_hdr(path, np.full((2, 16, 16, 3), 128, np.uint8), "PQ")
    monkeypatch.setattr(video_module, "_has_zscale", lambda: False)
    with pytest.raises(video_module.InputError, match=r"an HDR video \(PQ\).*zscale"):
        video_module.read_video(path)


@needs_zscale
def test_an_upright_hdr_phone_video_reads_upright(tmp_path):
    """An iPhone filming upright in HDR: HLG frames stored sideways with a display rotation read
    as shown, in their SDR colours (the rotation is applied before the HDR conversion)."""
    upright = np.zeros((2, 48, 32, 3), np.uint8)
    upright[:, :10, :8] = (230, 90, 40)  # a corner patch tells the orientation
    upright[:, 10:] = (40, 120, 200)
    sideways = tmp_path / "sideways.mkv"
    _write_hdr(sideways, np.ascontiguousarray(np.rot90(upright, k=-1, axes=(1, 2))), "HLG")
    phone = tmp_path / "phone.mov"
    arguments = ["-v", "error", "-y", "-display_rotation", "90", "-i", str(sideways)]
    run = run_ffmpeg([*arguments, "-c", "copy", str(phone)])
    assert run.returncode == 0, run.stderr
    frames, _, _, recorded_size, _ = video_module.read_video(phone)
    assert recorded_size == (32, 48)
    assert np.abs(frames.astype(int) - upright).max() <= 3
