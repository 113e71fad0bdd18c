"""Training checkpoints: everything a run needs to continue bit for bit, written atomically.

``OUT/checkpoint.pt`` holds the model, optimiser, scheduler and gradient-scaler states, the step,
the random-number states (torch CPU and CUDA, numpy, python), the config and the data fingerprint.
It is written to a temporary file and renamed over the previous one, so a run killed at any moment
leaves the last complete checkpoint. Only tensors and plain Python values are stored, so it loads
with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..io import atomic_file

CHECKPOINT = "checkpoint.pt"
FORMAT = "reconphys.train_checkpoint"
VERSION = 1


def rng_state() -> dict:
    """The states of every random-number generator the training touches."""
    kind, keys, position, has_gauss, cached = np.random.get_state()  # noqa: NPY002
    version, internal, gauss = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": {
            "kind": kind,
            "keys": torch.from_numpy(keys.astype(np.int64)),
            "position": int(position),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
        "python": {"version": version, "internal": list(internal), "gauss": gauss},
    }


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    if state["cuda"] and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    n = state["numpy"]
    np.random.set_state(  # noqa: NPY002
        (
            n["kind"],
            n["keys"].numpy().astype(np.uint32),
            n["position"],
            n["has_gauss"],
            n["cached_gaussian"],
        )
    )
    p = state["python"]
    random.setstate((p["version"], tuple(p["internal"]), p["gauss"]))


def save_checkpoint(path: Path, payload: dict) -> None:
    """``torch.save`` to a temporary file beside ``path``, then rename it into place."""
    try:
        with atomic_file(path) as tmp:
            torch.save({"format": FORMAT, "version": VERSION, **payload}, tmp)
    except OSError as e:
        raise InputError(f"cannot write ({e.strerror or e})", source=str(path)) from None


def load_checkpoint(path: Path) -> dict:
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many kinds for a damaged file
        raise InputError(
            f"not a readable checkpoint ({type(e).__name__}); remove it or pass --overwrite",
            source=str(path),
        ) from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise InputError(f"expected format {FORMAT!r}", source=str(path), field="format")
    if payload.get("version") != VERSION:
        raise InputError(f"version {payload.get('version')!r} is not supported", str(path))
    return payload


def save_step(path: Path, model, optimizer, step: int, settings: dict) -> None:
    """A small run's checkpoint (``train-gs``, ``train-masks``): model and optimiser states, the
    step and the run's settings."""
    payload = {"model": model.state_dict(), "optimizer": optimizer.state_dict()}
    save_checkpoint(path, {**payload, "step": step, "settings": settings})


def resume_step(path: Path, model, optimizer, settings: dict, log=print) -> int:
    """Load a :func:`save_step` checkpoint at ``path`` into ``model`` and ``optimizer`` when there
    is one (refusing a run with other settings); returns the first step to run."""
    if not path.is_file():
        return 1
    state = load_checkpoint(path)
    if state["settings"] != settings:
        raise InputError(
            "a run with other settings is in this folder (use another --out)",
            source=str(path.parent),
        )
    model.load_state_dict(state["model"])
    optimizer.load_state_dict(state["optimizer"])
    log(f"resuming from step {state['step']}")
    return state["step"] + 1
