"""Decoding a recording: a video file (mp4/mov/avi/webm/gif through imageio's ffmpeg and pillow
plugins) or a folder of frames, and resampling it in time to the simulator's ``frame_dt``."""

from __future__ import annotations

import functools
import logging
import math
import os
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..render.video import FOCAL_35MM_KEY, run_ffmpeg

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".gif")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
RESIZE_THREADS = 2  # read_video's frames made smaller beside the decoding


class _RotatedFrameSizeNote(logging.Filter):
    """Drops imageio-ffmpeg's note that the frames read differ in size from the stream's: a
    phone's upright video is stored sideways with a display rotation, which ffmpeg applies as it
    decodes (the frames come out upright, width and height swapped) — expected, not a fault."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "is different from the source frame size" not in record.getMessage()


logging.getLogger("imageio_ffmpeg").addFilter(_RotatedFrameSizeNote())


def _as_rgb_or_rgba(frame: np.ndarray, source: str) -> np.ndarray:
    """[H, W] / [H, W, 1|3|4] uint8 or uint16 → [H, W, 3|4] uint8."""
    frame = np.asarray(frame)
    if frame.dtype == np.uint16:
        frame = (frame >> 8).astype(np.uint8)
    if frame.dtype == np.bool_:
        frame = frame.astype(np.uint8) * 255
    if frame.dtype != np.uint8:
        raise InputError(f"expected 8- or 16-bit images, got {frame.dtype}", source=source)
    if frame.ndim == 2:
        frame = frame[..., None]
    if frame.ndim != 3 or frame.shape[-1] not in (1, 3, 4):
        raise InputError(f"expected [H, W, 1|3|4] images, got {list(frame.shape)}", source=source)
    if frame.shape[-1] == 1:
        frame = np.repeat(frame, 3, axis=-1)
    return frame


def _same_channels(frames: list[np.ndarray]) -> list[np.ndarray]:
    """RGB and RGBA frames mixed (GIF decoders give the first frame without alpha) → all RGBA,
    or all RGB when no frame is transparent anywhere."""
    if all(f.shape[-1] == 3 for f in frames):
        return frames
    if all(f.shape[-1] == 3 or bool((f[..., 3] == 255).all()) for f in frames):
        return [f[..., :3] for f in frames]
    opaque = np.uint8(255)
    return [f if f.shape[-1] == 4 else np.dstack([f, np.full(f.shape[:2], opaque)]) for f in frames]


def _read_gif(path: Path) -> tuple[list[np.ndarray], np.ndarray]:
    """GIF frames (RGBA) and the time each one appears, seconds [T + 1] (the last entry is when
    the clip ends): GIF encoders merge repeated frames into one longer frame, so the frame rate
    is not constant."""
    from PIL import Image, ImageSequence

    frames, durations = [], []
    with Image.open(path) as image:
        for frame in ImageSequence.Iterator(image):
            frames.append(np.asarray(frame.convert("RGBA")))
            durations.append(float(frame.info.get("duration") or 0.0) / 1000.0)
    if frames and not all(d > 0 for d in durations):
        durations = [0.1] * len(frames)  # browsers' default for a missing delay
    return frames, np.concatenate([[0.0], np.cumsum(durations)])


# A video whose frame intervals stray this far from their median is read at its frames' own
# times (a phone that drops its frame rate in low light), not at a constant rate
VARIABLE_RATE_SHARE = 0.25


# What ffmpeg lists of a file without decoding it: its global tags; its video packets (stdout),
# run at the info level so that its stderr also describes the streams (hdr_transfer)
_LISTINGS = {
    "ffmetadata": ["-v", "error", "-i", "{}", "-f", "ffmetadata", "-"],
    "framecrc": ["-v", "info", "-i", "{}", "-map", "0:v:0", "-c", "copy", "-f", "framecrc", "-"],
}


@functools.lru_cache(maxsize=32)
def _cached_listing(kind: str, path: str, version: tuple[int, int]) -> tuple[str, str] | None:
    run = run_ffmpeg([path if a == "{}" else a for a in _LISTINGS[kind]], timeout=60)
    return (run.stdout, run.stderr) if run.returncode == 0 else None


def forget_listings() -> None:
    """Forget every listing read so far: the next call on a file runs ffmpeg again, as a user's
    first ``predict`` on it does (benchmarks time that call, not a cached one)."""
    _cached_listing.cache_clear()


def _listing(kind: str, path: str | os.PathLike, stream: str = "stdout") -> str | None:
    """ffmpeg's ``kind`` listing of a file (:data:`_LISTINGS`; its ``stream``, stdout or
    stderr), or None when it fails: read once per version of the file (predict asks for the tags
    and the packets more than once)."""
    stat = os.stat(path)
    run = _cached_listing(kind, str(path), (stat.st_mtime_ns, stat.st_size))
    return None if run is None else run[0 if stream == "stdout" else 1]


# A phone's HDR video (10-bit HEVC: an iPhone's default since 2020 is HLG, others write PQ) holds
# display light up to ~1000 cd/m². Read as it is stored — the SDR curve and primaries assumed —
# it is dim, grey and desaturated (docs/usage.md#an-hdr-phone-video). It is read as the SDR frames
# every model learnt from instead, by ffmpeg's zscale (zimg; imageio-ffmpeg's binary has it):
# ITU-R BT.2408's SDR white (203 cd/m²) made white, the stream's primaries (BT.2020) turned into
# BT.709's in linear light, the sRGB curve of the training renders (not BT.1886's inverse: 7–10
# levels brighter mid-tones); each channel clipped to [0, 1], so highlights above white and
# colours outside BT.709 clip. HLG is the light of BT.2100's reference display, its OOTF
# (gamma 1.2) by the luminance: ``agamma=0`` (zscale's default raises each channel to the gamma,
# up to ~60 levels too saturated).
SDR_WHITE_NITS = 203.0
HDR_TRANSFERS = {"arib-std-b67": "HLG", "smpte2084": "PQ"}  # ffmpeg's names → the curve's
HDR_DEFAULT_TAGS = {"min": "bt2020nc", "pin": "bt2020"}  # where the stream leaves them unknown


def hdr_to_sdr_filter(curve: str, unknown: tuple[str, ...] = ()) -> str:
    """ffmpeg's filter that turns an HDR ``curve``'s ("HLG", "PQ") frames into SDR (module note),
    with BT.2020's matrix and primaries assumed for the ``unknown`` ones ("min", "pin")."""
    given = "".join(f":{key}={HDR_DEFAULT_TAGS[key]}" for key in unknown)
    ootf = ":agamma=0" if curve == "HLG" else ""
    return (
        f"zscale=t=linear:npl={SDR_WHITE_NITS:g}:p=bt709{ootf}{given},format=gbrpf32le,"
        "zscale=t=iec61966-2-1:r=full,format=gbrp"
    )


@functools.cache
def _has_zscale() -> bool:  # whether this ffmpeg has the zscale filter (hdr_to_sdr_filter)
    run = run_ffmpeg(["-v", "error", "-filters"], timeout=60)
    return run.returncode == 0 and re.search(r"^\s*\S+\s+zscale\s", run.stdout, re.M) is not None


def _ffmpeg_video(path: str | os.PathLike) -> bool:  # a video file ffmpeg reads (GIF: pillow)
    suffix = Path(path).suffix.lower()
    return suffix in VIDEO_SUFFIXES and suffix != ".gif"


def _video_stream_line(path: str | os.PathLike) -> str | None:
    """ffmpeg's description of a video file's first video stream (one line), or None."""
    if not _ffmpeg_video(path):
        return None
    text = _listing("framecrc", path, "stderr")
    inputs = "" if text is None else text.split("\nOutput #")[0]  # the file's, not the output's
    found = re.search(r"Stream #\d+:\d+.*?: Video: .*", inputs)
    return None if found is None else found[0]


def hdr_transfer(path: str | os.PathLike) -> str | None:
    """The HDR transfer curve a video file's (first) video stream is tagged with, "HLG" or "PQ";
    None for SDR, an untagged stream, a file ffmpeg cannot list, a GIF."""
    line = _video_stream_line(path) or ""
    found = [curve for name, curve in HDR_TRANSFERS.items() if re.search(rf"\b{name}\b", line)]
    return found[0] if found else None


def _unknown_colour_tags(line: str) -> tuple[str, ...]:
    """Which of the matrix and primaries ("min", "pin") a stream's description leaves unknown:
    ffmpeg writes them as "(range, matrix/primaries/transfer)", the range left out if unknown."""
    tags = re.search(r"\((?:(?:tv|pc|unknown), )?([\w-]+)/([\w-]+)/([\w-]+)", line)
    if tags is None:  # the transfer alone was named
        return ("min", "pin")
    matrix, primaries = tags.groups()[:2]
    return tuple(key for key, value in (("min", matrix), ("pin", primaries)) if value == "unknown")


def packet_times(path: str | os.PathLike) -> np.ndarray | None:
    """Presentation times (seconds, sorted) of a video file's first video stream's packets, read
    without decoding (ffmpeg's framecrc muxer); None when ffmpeg cannot list them."""
    text = _listing("framecrc", path)
    base = None if text is None else re.search(r"^#tb 0: (\d+)/(\d+)", text, re.MULTILINE)
    if base is None:
        return None
    rows = re.findall(r"^0,\s*-?\d+,\s*(-?\d+),", text, re.MULTILINE)
    return np.sort(np.array([int(r) for r in rows], dtype=np.float64)) * int(base[1]) / int(base[2])


def variable_rate(times: np.ndarray) -> bool:
    """Whether frames at ``times`` [T] (seconds) are not evenly spaced (a variable-rate video):
    some interval differs from the median one by more than :data:`VARIABLE_RATE_SHARE` of it."""
    steps = np.diff(times)
    if steps.size < 2:
        return False
    median = float(np.median(steps))
    return median > 0 and bool(np.any(np.abs(steps - median) > VARIABLE_RATE_SHARE * median))


def decoded_times(path: str | os.PathLike, until: float | None = None) -> np.ndarray:
    """Presentation times (seconds) of a video's frames as ffmpeg decodes them one for one (no
    frame repeated or dropped: ``-fps_mode passthrough``), read by its showinfo filter; with
    ``until``, those of the first ``until`` + 1 seconds."""
    arguments = ["-i", str(path), "-map", "0:v:0", "-fps_mode", "passthrough", "-vf", "showinfo"]
    if until is not None:
        arguments += ["-t", f"{until + 1.0:.6f}"]
    run = run_ffmpeg(["-v", "info", *arguments, "-f", "null", "-"])
    found = re.findall(r"Parsed_showinfo.*?\bpts_time:\s*(-?[\d.]+)", run.stderr)
    if run.returncode != 0 or not found:
        raise InputError("cannot read the frames' times (ffmpeg showinfo)", source=str(path))
    return np.array([float(t) for t in found])


def read_video(
    path: str | os.PathLike, until: float | None = None, max_side: int | None = None
) -> tuple[np.ndarray, float | None, np.ndarray | None, tuple[int, int], np.ndarray | None]:
    """The frames of a video file → ([T, H, W, 3|4] uint8, frames per second or None, display
    times [T + 1] seconds for GIF (a frame held on screen until the next) or None, (width,
    height) as recorded, and for a variable-rate video (:func:`variable_rate`) the time of
    each frame [T], seconds from the first, else None; its frames per second is then their
    mean rate). ``until`` (seconds): stop decoding after the first frame at or past it;
    ``max_side``: each frame area-averaged to at most that many pixels a side as it is decoded
    (:func:`fit_within`) — a long 1080p phone clip is never held in memory whole.

    An HDR video (HLG or PQ: :func:`hdr_transfer`) is read as SDR (:func:`hdr_to_sdr_filter`).
    GIF keeps its alpha channel when it has transparency. Raises InputError (one line naming the
    file) for a missing or unreadable file, a video without frames, and an HDR video where this
    ffmpeg has no zscale filter.
    """
    import imageio.v2 as imageio

    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise InputError("video file not found", source=source)
    fps, times, stamps = None, None, None
    frames, sizes = [], set()
    # frames made smaller in RESIZE_THREADS threads as the next ones are decoded (PIL's resize
    # lets go of the GIL): the same pixels, ~1.3× sooner from a phone's 1080p (docs/benchmarks.md)
    shrink = None if max_side is None else ThreadPoolExecutor(RESIZE_THREADS)

    def keep(frame: np.ndarray) -> None:
        frame = _as_rgb_or_rgba(frame, source)
        sizes.add((frame.shape[1], frame.shape[0]))
        frames.append(frame if shrink is None else shrink.submit(_fit_one, frame, max_side))
        if shrink is not None and len(frames) > 2 * RESIZE_THREADS:  # at most that many waiting
            frames[-2 * RESIZE_THREADS - 1] = frames[-2 * RESIZE_THREADS - 1].result()

    try:
        if path.suffix.lower() == ".gif":
            raw, times = _read_gif(path)
            for frame in raw:
                keep(frame)
        else:
            packets = packet_times(path)
            output = []
            if packets is not None and variable_rate(packets):  # each frame at its own time
                stamps = decoded_times(path, until)
                stamps = stamps - stamps[0]
                output += ["-fps_mode", "passthrough"]
            hdr = hdr_transfer(path)
            if hdr is not None:  # read as SDR (hdr_to_sdr_filter)
                if not _has_zscale():
                    raise InputError(
                        f"an HDR video ({hdr}): reading it needs ffmpeg's zscale filter, which "
                        "this ffmpeg lacks (imageio-ffmpeg's own binary has it: unset "
                        "IMAGEIO_FFMPEG_EXE), or export the clip as SDR",
                        source=source,
                    )
                unknown = _unknown_colour_tags(_video_stream_line(path) or "")
                output += ["-vf", hdr_to_sdr_filter(hdr, unknown)]
            options = {"output_params": output} if output else {}
            with imageio.get_reader(path, format="FFMPEG", **options) as reader:
                fps = reader.get_meta_data().get("fps")
                last = None
                if until is not None and stamps is not None:
                    last = int(np.searchsorted(stamps, until - 1e-6))
                elif until is not None and fps and np.isfinite(fps) and fps > 0:
                    last = math.ceil(until * fps - 1e-6)  # the first frame at or past `until`
                for frame in reader:
                    keep(frame)
                    if last is not None and len(frames) > last:
                        break
        if shrink is not None:
            frames = [
                frame if isinstance(frame, np.ndarray) else frame.result() for frame in frames
            ]
    except InputError:
        raise
    except Exception as e:  # decoders raise many types (OSError, RuntimeError, IndexError, ...)
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"cannot decode the video ({message})", source=source) from None
    finally:
        if shrink is not None:
            shrink.shutdown(cancel_futures=True)
    if not frames:
        raise InputError("the video has no frames", source=source)
    if len(sizes) != 1:
        raise InputError("frames of different sizes", source=source)
    frames = _same_channels(frames)
    fps = float(fps) if fps and np.isfinite(fps) and fps > 0 else None
    if stamps is not None:
        if len(stamps) < len(frames):
            raise InputError(
                f"ffmpeg gave {len(frames)} frames but the times of {len(stamps)}", source=source
            )
        stamps = stamps[: len(frames)]
        if np.any(np.diff(stamps) <= 0):
            raise InputError("frames whose times do not increase", source=source)
        fps = (len(stamps) - 1) / float(stamps[-1]) if stamps[-1] > 0 else None
    return np.stack(frames), fps, times, sizes.pop(), stamps


# The 35 mm-equivalent focal length in a recording's metadata: a phone's video (the QuickTime
# key iPhones write), a frame folder's first image (EXIF FocalLengthIn35mmFilm)
FOCAL_35MM_KEYS = (FOCAL_35MM_KEY,)
# The rate a phone filmed at, where it differs from the rate the file plays at (Android writes it
# for its slow-motion videos); beyond this ratio either way the filmed rate is the real one
CAPTURE_FPS_KEYS = ("com.android.capture.fps",)
SLOW_MOTION_RATIO = 1.5
_EXIF_IFD, _EXIF_FOCAL_35MM = 0x8769, 0xA405


def _ffmetadata_value(text: str, key: str) -> str | None:
    """``key``'s value in ffmpeg's FFMETADATA1 text (global section, escapes undone)."""
    for line in text.splitlines():
        if line.startswith("["):  # a stream's or a chapter's section: the global one is over
            break
        name, sep, value = line.partition("=")
        if sep and name == key:
            return re.sub(r"\\(.)", r"\1", value)
    return None


def _video_tag(path: Path, keys: tuple[str, ...]) -> float | None:
    """The first of ``keys`` in a video file's global metadata (ffmpeg's ffmetadata), as a
    positive number, or None (absent, not a number, or a file ffmpeg cannot read)."""
    if not _ffmpeg_video(path):
        return None
    try:
        values = (_ffmetadata_value(_listing("ffmetadata", path), key) for key in keys)
        number = float(next(v for v in values if v is not None))
    except Exception:  # metadata is a hint: absent or unreadable is None
        return None
    return number if math.isfinite(number) and number > 0 else None


def read_focal_35mm(path: str | os.PathLike) -> float | None:
    """The 35 mm-equivalent focal length (mm) a recording's metadata carries, or None: a video's
    :data:`FOCAL_35MM_KEYS` (read by ffmpeg), a frame folder's first image's EXIF. Never raises:
    metadata that is absent or unreadable is None (the field of view is then assumed)."""
    path = Path(path)
    if not path.is_dir():
        return _video_tag(path, FOCAL_35MM_KEYS)
    try:
        from PIL import Image

        files = list_images(path)
        if not files:
            return None
        with Image.open(files[0]) as image:
            focal = float(image.getexif().get_ifd(_EXIF_IFD).get(_EXIF_FOCAL_35MM))
    except Exception:
        return None
    return focal if math.isfinite(focal) and focal > 0 else None


def slow_motion_rate(path: str | os.PathLike) -> tuple[float, float] | None:
    """(the rate a phone filmed at, the rate its file plays at), frames per second, when a
    video's metadata says it was filmed at another rate than it plays (Android's slow motion,
    :data:`CAPTURE_FPS_KEYS`: filmed at 120 or 240 fps, played at 30) by more than
    :data:`SLOW_MOTION_RATIO`; else None. The file's rate: its packets' median interval."""
    path = Path(path)
    captured = _video_tag(path, CAPTURE_FPS_KEYS)
    if captured is None:
        return None
    packets = packet_times(path)
    if packets is None or len(packets) < 2:
        return None
    played = 1.0 / float(np.median(np.diff(packets)))
    ratio = captured / played
    return (captured, played) if max(ratio, 1 / ratio) > SLOW_MOTION_RATIO else None


ON_FRAME_S = 1e-3  # a wanted time this close to a recorded frame reads that frame as it is
# A recording is read at most this many pixels on its longer side (area-averaged down): every
# model reads far less (the segmenter 128 px, the crops 32–48 px, the search 64 px), and a 1080p
# clip at full size costs gigabytes and minutes (docs/usage.md#the-input).
WORK_MAX_SIDE = 640


def working_size(width: int, height: int, max_side: int = WORK_MAX_SIDE) -> tuple[int, int]:
    """(width, height) of a ``width × height`` image read at most ``max_side`` px a side."""
    scale = max_side / max(width, height)
    if scale >= 1:
        return width, height
    return max(1, round(width * scale)), max(1, round(height * scale))


def _fit_one(image: np.ndarray, max_side: int) -> np.ndarray:  # [H, W, C] → fit_within's
    return fit_within(image[None], max_side)[0]


def fit_within(images: np.ndarray, max_side: int = WORK_MAX_SIDE) -> np.ndarray:
    """[T, H, W, 3|4] uint8 → the same, area-averaged (box filter) to :func:`working_size`;
    unchanged when it fits."""
    from PIL import Image

    height, width = images.shape[1:3]
    size = working_size(width, height, max_side)
    if size == (width, height):
        return images
    return np.stack([np.asarray(Image.fromarray(x).resize(size, Image.BOX)) for x in images])


def resample_times(
    times: np.ndarray, frame_dt: float, start: float = 0.0, end: float | None = None
) -> np.ndarray:
    """Indices of the frames on screen at start, start + frame_dt, ... before the clip ends (or
    ``end``, seconds), for frames that appear at ``times[:-1]`` and a clip that ends at
    ``times[-1]`` (seconds)."""
    stop = float(times[-1]) if end is None else min(end, float(times[-1]))
    _check_span(start, stop - 1e-9)  # a frame must be on screen at the start
    count = int(np.floor((stop - start - 1e-9) / frame_dt)) + 1
    targets = start + np.arange(count) * frame_dt
    return np.searchsorted(times[:-1], targets + 1e-9, side="right") - 1


def _check_span(start: float, stop: float) -> None:
    if start > stop:
        raise InputError(
            f"{start:g} s is after the recording's end ({stop:.2f} s)", field="--start"
        )


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files of a folder in natural order (frame_2 before frame_10)."""
    folder = Path(folder)
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]

    def key(p: Path):
        return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)]

    return sorted(files, key=key)


def read_image(path: Path) -> np.ndarray:
    """One image → [H, W, C] uint8 (C as stored: 1, 3 or 4; greyscale kept as [H, W, 1])."""
    import imageio.v2 as imageio

    try:
        image = np.asarray(imageio.imread(path))
    except Exception as e:
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"cannot read the image ({message})", source=str(path)) from None
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype == np.bool_:
        image = image.astype(np.uint8) * 255
    if image.dtype != np.uint8:
        raise InputError(f"expected 8- or 16-bit images, got {image.dtype}", source=str(path))
    return image if image.ndim == 3 else image[..., None]


def read_frame_folder(
    folder: str | os.PathLike, count: int | None = None, max_side: int | None = None
) -> tuple[np.ndarray, tuple[int, int]]:
    """A folder of frame images (sorted naturally) → ([T, H, W, 3|4] uint8, (width, height) as
    recorded); the first ``count`` of them when given, each at most ``max_side`` px a side
    (:func:`fit_within`) when given."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("frame folder not found", source=str(folder))
    files = list_images(folder)
    if not files:
        kinds = "/".join(IMAGE_SUFFIXES)
        raise InputError(f"no frames ({kinds}) in the folder", source=str(folder))
    frames, sizes = [], set()
    for path in files[:count]:
        frame = _as_rgb_or_rgba(read_image(path), str(path))
        sizes.add((frame.shape[1], frame.shape[0]))
        frames.append(frame if max_side is None else fit_within(frame[None], max_side)[0])
    if len(sizes) != 1:
        shapes = sorted((h, w) for w, h in sizes)
        raise InputError(f"frames of different sizes {shapes}", source=str(folder))
    return np.stack(_same_channels(frames)), sizes.pop()


def resample_between(
    num_frames: int,
    fps: float,
    frame_dt: float,
    start: float = 0.0,
    end: float | None = None,
    stamps: np.ndarray | None = None,  # [num_frames] each frame's time, s (variable rate)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The times start, start + frame_dt, ... (seconds into a recording of ``num_frames`` at
    ``fps``, or at ``stamps`` when given, as long as they lie inside it and before ``end``)
    between recorded frames: ``(before [J], after [J], weight [J])``, the frame at or before
    each time, the one after, and the share of the later one in [0, 1) (the time's share of
    the interval between them). A time within :data:`ON_FRAME_S` of a recorded frame takes it
    alone (before = after, weight 0): a recording at 1 / ``frame_dt`` (or a multiple) reads
    exactly its own frames. At 30 fps the times fall between frames; reading the nearest one
    instead would put each frame up to 17 ms off its time (5 cm at 3 m/s)."""
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"must be a positive frame rate, got {fps}", field="--fps")
    if stamps is None:
        stamps = np.arange(num_frames) / fps
    stamps = np.asarray(stamps, dtype=np.float64)
    if stamps.shape != (num_frames,) or np.any(np.diff(stamps) <= 0):
        raise ValueError(f"stamps: expected {num_frames} increasing times, got {stamps.shape}")
    stop = float(stamps[-1]) if end is None else min(end, float(stamps[-1]))
    _check_span(start, stop + 1e-9)
    count = int(np.floor((stop - start) / frame_dt + 1e-6)) + 1
    targets = start + np.arange(count) * frame_dt  # [J] seconds
    position = np.interp(targets, stamps, np.arange(num_frames, dtype=np.float64))  # in frames
    nearest = np.round(position).astype(np.int64).clip(0, num_frames - 1)
    on_frame = np.abs(targets - stamps[nearest]) < ON_FRAME_S
    before = np.where(on_frame, nearest, np.floor(position)).astype(np.int64)
    before = np.clip(before, 0, num_frames - 1)
    after = np.where(on_frame, before, np.minimum(before + 1, num_frames - 1))
    weight = np.where(on_frame | (after == before), 0.0, position - before)
    return before, after, weight


def resample_indices(
    num_frames: int, fps: float, frame_dt: float, start: float = 0.0, end: float | None = None
) -> np.ndarray:
    """The recorded frame nearest to each time of :func:`resample_between` [J]."""
    before, after, weight = resample_between(num_frames, fps, frame_dt, start, end)
    return np.where(weight < 0.5, before, after)
