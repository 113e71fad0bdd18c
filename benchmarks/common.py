"""Shared benchmark helpers: a description of the machine, CUDA-aware timing, the mean mask IoU
of a clip, a dataset's samples after its first objects (a validation split), and a sample
written as a user brings it to ``predict``."""

from __future__ import annotations

import os
import platform
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import torch


def machine_description(device: str) -> str:
    """CPU model, core count, torch version and GPU name, for the benchmark record."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    parts = [
        f"CPU: {cpu} ({os.cpu_count()} cores, torch threads {torch.get_num_threads()})",
        f"torch {torch.__version__}",
    ]
    if device.startswith("cuda"):
        parts.append(f"GPU: {torch.cuda.get_device_name()} (CUDA {torch.version.cuda})")
        try:
            import gsplat

            parts.append(f"gsplat {gsplat.__version__}")
        except ImportError:
            parts.append("gsplat not installed")
    return "; ".join(parts)


def timed(fn: Callable[[], object], device: str, repeats: int = 3) -> float:
    """Best wall-clock seconds of ``repeats`` calls after one warm-up (synchronising CUDA)."""

    def sync():
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    fn()
    sync()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        best = min(best, time.perf_counter() - start)
    return best


def mean_mask_iou(prediction: torch.Tensor, truth: torch.Tensor) -> float:
    """IoU of two [T, H, W] masks (> 0.5), per frame, averaged over the frames."""
    p, t = prediction > 0.5, truth > 0.5
    return float(((p & t).sum((1, 2)) / (p | t).sum((1, 2)).clamp_min(1)).mean())


def after_first_objects(
    samples: list[dict], count: int, order: list[dict] | None = None
) -> list[dict]:
    """``samples`` less those of the first ``count`` objects of ``order`` (default: of
    ``samples`` itself), in the order they are listed: the meshes a model trained on the first
    ``count`` (``data.objects``) never saw."""
    listed = samples if order is None else order
    first = set(list(dict.fromkeys(s["object"] for s in listed))[:count])
    return [s for s in samples if s["object"] not in first]


def user_bundle(dataset, index: int, folder: Path, item: dict | None = None) -> Path:
    """View 0 of sample ``index`` of a ``DropDataset`` (of view 0) written into ``folder``/ID as a
    user brings it to ``predict``: ``video.mp4`` (the stored mp4), ``camera.json`` and the true
    Gaussians as ``gaussians.ply`` → that folder. ``item``: ``dataset[index]`` when already
    decoded."""
    from reconphys.assets.ply import write_ply
    from reconphys.capture import CameraSpec, write_camera
    from reconphys.data.storage import video_name

    item = dataset[index] if item is None else item
    entry = dataset.samples[index]
    bundle = Path(folder) / entry["id"]
    bundle.mkdir()
    shutil.copyfile(dataset.root / entry["dir"] / video_name(0), bundle / "video.mp4")
    height, width = item["frames"].shape[2:4]
    K, w2c = item["K"][0].double(), item["world_to_cam"][0].double()
    write_camera(bundle / "camera.json", CameraSpec(K, w2c, width, height))
    write_ply(bundle / "gaussians.ply", dataset.asset(index).gaussians)
    return bundle


def enlarged_video(video: Path, out: Path, side: int = 1080) -> Path:
    """The frames of ``video`` resized to ``side`` × ``side`` (PIL's bicubic: a phone's size, the
    clip's own detail), written as the mp4 ``out`` at the clip's rate → ``out``."""
    import numpy as np
    from PIL import Image

    from reconphys.capture.video import read_video
    from reconphys.render.video import write_mp4

    frames, fps = read_video(video)[:2]
    large = np.stack([np.asarray(Image.fromarray(f).resize((side, side))) for f in frames])
    write_mp4(out, large[..., :3], fps=fps or 1 / 0.03)
    return out


def predict_bundle(bundle: Path, **options):
    """``reconphys.predict`` on a :func:`user_bundle` (mp4 + camera file + the true Gaussians)."""
    import reconphys

    return reconphys.predict(
        bundle / "video.mp4",
        camera=bundle / "camera.json",
        gaussians=bundle / "gaussians.ply",
        **options,
    )


def camera_read_errors(estimate, K_true, w2c_true, centre, lowest) -> dict:
    """Errors of a camera read from the video (capture.calibrate's CameraEstimate) against the
    true one (K [3, 3], world_to_cam [4, 4]), for an object whose frame-0 centre and lowest
    point (world, metres [3]) are known: scale error = the object's metric size read / the
    truth − 1 (size = pixels · distance / f); ground error = the height above the estimated
    ground of the true lowest point at its pixel and the depth the estimate gives the object,
    minus the true height (metres): what decides when the simulated object lands."""
    K_true, w2c_true = K_true.double(), w2c_true.double()
    centre, lowest = centre.double(), lowest.double()
    true_distance = float((w2c_true[:3, :3] @ centre + w2c_true[:3, 3]).norm())
    f_true, f_est = float(K_true[1, 1]), float(estimate.camera.K[1, 1])
    scale = (estimate.distance / f_est) / (true_distance / f_true)
    cam = w2c_true[:3, :3] @ lowest + w2c_true[:3, 3]
    pixel = (K_true @ cam)[:2] / cam[2]
    depth = float(cam[2]) * estimate.distance / true_distance
    K_est = estimate.camera.K.double()
    ray = torch.stack(
        [(pixel[0] - K_est[0, 2]) / K_est[0, 0], (pixel[1] - K_est[1, 2]) / K_est[1, 1]]
    )
    point_cam = depth * torch.cat([ray, torch.ones(1, dtype=torch.float64)])
    w2c = estimate.camera.world_to_cam.double()
    point_world = w2c[:3, :3].T @ (point_cam - w2c[:3, 3])
    return {
        "scale_error": scale - 1,
        "ground_error_m": float(point_world[2]) - float(lowest[2]),
        "pitch_deg": estimate.pitch_deg,
        "fall_frames": estimate.fall_frames,
    }


def rating_line(ratings: list[dict], ious: list[float]) -> str:
    """How the segmenter's own rating of its masks (models/mask_segmenter.mask_rating) compares
    with their true IoU over clips: the mean expected and true, the mean per-clip error, the
    rank correlation, how often the 10–90 % interval holds the truth, and the clips it warns of
    (expected < MASKS_WARN_IOU) with their true IoU."""
    import numpy as np
    from scipy.stats import spearmanr

    from reconphys.models.mask_segmenter import MASKS_WARN_IOU

    expected = np.array([r["expected_iou"] for r in ratings])
    true = np.array(ious)
    held = np.mean(
        [
            lo <= t <= hi
            for (lo, hi), t in zip([r["expected_iou_10_90"] for r in ratings], true, strict=True)
        ]
    )
    warned = expected < MASKS_WARN_IOU
    line = (
        f"masks' rating: expected IoU mean {expected.mean():.3f} (true {true.mean():.3f}), "
        f"|expected − true| {np.abs(expected - true).mean():.3f} a clip, Spearman "
        f"{spearmanr(expected, true).correlation:.2f}, the 10–90 % interval holds the truth on "
        f"{held:.0%}; warned of {warned.mean():.0%}"
    )
    if warned.any():
        line += (
            f" (their true IoU {true[warned].mean():.3f}, the others' {true[~warned].mean():.3f})"
        )
    return line
