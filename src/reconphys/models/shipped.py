"""The trained physics predictor on disk: ``NAME.safetensors`` (weights) + ``NAME.json`` (config).

``NAME.json`` holds the :class:`~reconphys.models.physics_predictor.PredictorConfig`, what the
network reads (view, frames, resolution, frame interval), the attribute ranges its bounded heads
map into, and how it was trained (data, objective, steps, geometry, time). ``"members": M > 1``
marks an ensemble of M networks of that config (:class:`PredictorEnsemble`; weights
``members.I.…``); absent, one network. ``reconphys train``
writes ``OUT/model.safetensors`` + ``OUT/model.json``; the model shipped with the package lives at
``reconphys/weights/physics_predictor.safetensors`` + ``.json``.

Commands that need a model find it without flags (:func:`default_model_path`): ``$RECONPHYS_MODEL``
(a .safetensors file, or a training output folder), else the shipped file.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from ..errors import InputError
from ..io import atomic_file, read_json
from ..physics.model import ATTRIBUTE_RANGES, ATTRIBUTES
from .model_input import object_crop
from .physics_predictor import (
    DEFAULT_SPREAD_FACTOR,
    LOG_SCALED,
    SCALE_HEAD_SPREAD_FACTOR,
    PhysicsPredictor,
    PredictorConfig,
    PredictorEnsemble,
    resize_frames,
)

FORMAT = "reconphys.physics_predictor"
VERSION = 1
ENV_VAR = "RECONPHYS_MODEL"
SHIPPED_PATH = Path(__file__).resolve().parent.parent / "weights" / "physics_predictor.safetensors"
# The shipped model of object crops (configs/track_realistic.toml): what predict reads a recording
# with when it is not the plain look (the object on black, filmed with a known camera)
SHIPPED_CROP_PATH = SHIPPED_PATH.with_name("physics_predictor_crop.safetensors")
TRAINED_NAME = "model.safetensors"  # what `reconphys train` writes into its output folder
HOW_TO_TRAIN = (
    "train one with `reconphys train configs/cpu_small.toml` (docs/training.md) and pass "
    f"OUT/{TRAINED_NAME} with --model or ${ENV_VAR}"
)


def config_path(weights: Path) -> Path:
    """The JSON beside a weights file: ``NAME.safetensors`` → ``NAME.json``."""
    return weights.with_suffix(".json")


def default_model_path() -> Path:
    """``$RECONPHYS_MODEL`` when set (a file, or a folder holding model.safetensors), else the
    shipped weights (which may not exist: :func:`load_predictor` then says how to train one)."""
    value = os.environ.get(ENV_VAR, "").strip()
    return resolve_model_path(value) if value else SHIPPED_PATH


def model_for_recording(plain_look: bool) -> tuple[Path, str]:
    """The physics predictor for a recording when none is named → (path, why).

    ``$RECONPHYS_MODEL`` when set; else the shipped silhouette-track network for the plain look
    (the object on a black backdrop with a camera file: the data it was trained on, where it is
    best), and the shipped network of object crops for anything else (a floor, a wall, a camera
    read from the video: it reads the same object-sized picture whatever the framing;
    docs/training.md "Object-centric input")."""
    if os.environ.get(ENV_VAR, "").strip():
        return default_model_path(), f"${ENV_VAR}"
    if plain_look:
        return SHIPPED_PATH, "the plain look (object on black, camera given): the track network"
    return SHIPPED_CROP_PATH, "not the plain look: the network of object crops"


def resolve_model_path(path: str | os.PathLike) -> Path:
    """A weights file as given, or ``FOLDER/model.safetensors`` for a training output folder."""
    path = Path(path)
    return path / TRAINED_NAME if path.is_dir() else path


def model_metadata(
    config: PredictorConfig,
    view: int,
    frame_dt: float,
    training: dict | None = None,
    members: int = 1,
) -> dict:
    """The contents of ``NAME.json`` (``members`` > 1: an ensemble of that many networks)."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "predictor": config.to_dict(),
        **({"members": members} if members > 1 else {}),
        "input": {
            "view": view,  # dataset view 0–3 the network was trained on
            "frames": config.num_frames,  # frames 0..frames−1 of the video
            "resolution": config.resolution,  # square, pixels
            "frame_dt": frame_dt,  # seconds between frames
        },
        "attribute_order": list(ATTRIBUTES),
        "attribute_ranges": {n: list(ATTRIBUTE_RANGES[n]) for n in ATTRIBUTES},
        "attribute_scaling": {n: "log" if n in LOG_SCALED else "linear" for n in ATTRIBUTES},
        "training": training or {},
    }


def save_predictor(
    model: PhysicsPredictor | PredictorEnsemble, path: str | os.PathLike, metadata: dict
) -> Path:
    """Write ``path`` (.safetensors, float32 weights) and its JSON, each replaced atomically."""
    from safetensors.torch import save_file

    path = Path(path)
    if path.suffix != ".safetensors":
        raise InputError("expected a .safetensors file name", source=str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().float().cpu().contiguous() for k, v in model.state_dict().items()}
    header = {"format": FORMAT, "version": str(VERSION)}
    with atomic_file(path) as tmp:
        save_file(tensors, str(tmp), metadata=header)
    with atomic_file(config_path(path)) as tmp:
        tmp.write_text(json.dumps(metadata, indent=1) + "\n")
    return path


@dataclass
class LoadedPredictor:
    """A predictor ready for inference, with its metadata."""

    model: PhysicsPredictor | PredictorEnsemble  # in eval mode
    metadata: dict  # the contents of NAME.json
    path: Path
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def view(self) -> int:
        return int(self.metadata["input"]["view"])

    @property
    def num_frames(self) -> int:
        return self.model.config.num_frames

    @property
    def spread_factor(self) -> tuple[float, float, float]:
        """a per observable (log k/m, log d/m, f): the network's belief is a normal at its answer
        with σ = a × its members' spread (and its scale head's, physics_predictor.network_sigma),
        a calibrated on validation meshes (the JSON's "spread_factor"; else
        physics_predictor.DEFAULT_SPREAD_FACTOR, or SCALE_HEAD_SPREAD_FACTOR with a scale head)."""
        default = (
            SCALE_HEAD_SPREAD_FACTOR if self.model.config.scale_head else DEFAULT_SPREAD_FACTOR
        )
        return tuple(self.metadata.get("spread_factor", default))

    @torch.no_grad()
    def predict(self, frames: Tensor) -> dict[str, Tensor]:
        """frames [B, T, H, W, 3] in [0, 1] of the model's view, T ≥ num_frames (the first
        num_frames are read; any square size, resized to the model's or, for a model of object
        crops, cropped) → {"unit" [B, 4],
        "mass", "stiffness", "damping", "friction" [B]}."""
        if frames.dim() != 5 or frames.shape[-1] != 3:
            raise InputError(f"expected frames [B, T, H, W, 3], got {list(frames.shape)}")
        if frames.shape[1] < self.num_frames:
            raise InputError(
                f"the model reads {self.num_frames} frames, the video has {frames.shape[1]}",
                source=str(self.path),
            )
        frames = frames[:, : self.num_frames].to(self.device, torch.float32)
        config = self.model.config
        if config.crop:  # each video cropped around its object (model_input.object_crop)
            return self.model(torch.cat([object_crop(f, config.resolution) for f in frames]))
        return self.model(resize_frames(frames, config.resolution))


def _read_metadata(path: Path) -> dict:
    json_path = config_path(path)
    if not json_path.is_file():
        raise InputError(f"its config {json_path.name} is missing (written beside the weights)",
                         source=str(path))  # fmt: skip
    metadata = read_json(json_path, FORMAT, VERSION)
    for key in ("predictor", "input"):
        if not isinstance(metadata.get(key), dict):
            raise InputError("missing", source=str(json_path), field=key)
    members = metadata.get("members", 1)
    if type(members) is not int or members < 1:
        raise InputError(f"expected a whole number ≥ 1, got {members!r}", str(json_path), "members")
    ranges = metadata.get("attribute_ranges", {})
    for name in ATTRIBUTES:
        if list(ranges.get(name, [])) != list(ATTRIBUTE_RANGES[name]):
            raise InputError(
                f"trained for the range {ranges.get(name)}, this version uses "
                f"{list(ATTRIBUTE_RANGES[name])}",
                source=str(json_path),
                field=f"attribute_ranges.{name}",
            )
    return metadata


def load_predictor(
    path: str | os.PathLike | None = None,
    device: torch.device | str = "cpu",
) -> LoadedPredictor:
    """The predictor at ``path`` (default: :func:`default_model_path`), in eval mode.

    Raises InputError (one line naming the file) for a missing, corrupt or mismatched model.
    """
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    explicit = path is not None or os.environ.get(ENV_VAR, "").strip()
    path = resolve_model_path(path) if path is not None else default_model_path()
    if not path.is_file():
        if not explicit:
            raise InputError(f"no trained physics predictor is shipped yet: {HOW_TO_TRAIN}",
                             source=str(path))  # fmt: skip
        raise InputError("model file not found", source=str(path))
    metadata = _read_metadata(path)
    try:
        config = PredictorConfig.from_dict(metadata["predictor"])
        members = metadata.get("members", 1)
        model = PredictorEnsemble(config, members) if members > 1 else PhysicsPredictor(config)
    except (TypeError, ValueError) as e:
        where = str(config_path(path))
        raise InputError(f"bad predictor config ({e})", where, "predictor") from None
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise InputError(f"not a readable safetensors file ({e})", source=str(path)) from None
    expected = model.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    wrong = sorted(k for k in set(expected) & set(tensors) if expected[k].shape != tensors[k].shape)
    if missing or unexpected or wrong:
        parts = [
            f"{label}: {', '.join(keys[:3])}{' ...' if len(keys) > 3 else ''}"
            for label, keys in (("missing", missing), ("unexpected", unexpected),
                                ("other shape", wrong))
            if keys
        ]  # fmt: skip
        raise InputError(
            f"weights do not match the config in {config_path(path).name} ({'; '.join(parts)})",
            source=str(path),
        )
    factor = metadata.get("spread_factor", DEFAULT_SPREAD_FACTOR)
    if not (
        isinstance(factor, (list, tuple))
        and len(factor) == 3
        and all(isinstance(a, (int, float)) and math.isfinite(a) and a > 0 for a in factor)
    ):
        raise InputError(
            f"spread_factor must be 3 positive numbers, got {factor!r}",
            source=str(config_path(path)),
            field="spread_factor",
        )
    bad = [k for k, v in tensors.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise InputError("non-finite weights", source=str(path), field=bad[0])
    model.load_state_dict(tensors)
    device = torch.device(device)
    return LoadedPredictor(model.to(device).eval(), metadata, path, device)
