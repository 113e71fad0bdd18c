"""Shared benchmark helpers: a description of the machine, CUDA-aware timing, the mean mask IoU
of a clip, and a dataset's samples after its first objects (a validation split)."""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable

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
