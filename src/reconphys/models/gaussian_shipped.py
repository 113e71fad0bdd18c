"""The trained 3DGS predictor on disk: ``NAME.safetensors`` + ``NAME.json`` (its config, the
camera convention it was trained with, how it was trained). ``reconphys train-gs`` writes
``OUT/model.safetensors``; the shipped one is ``reconphys/weights/gaussian_predictor.*``.
Found without flags: ``$RECONPHYS_GS_MODEL`` (a file or a training OUT), else the shipped file.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..io import atomic_file, read_json
from .gaussian_predictor import GaussianPredictor, GaussianPredictorConfig
from .shipped import TRAINED_NAME, config_path

FORMAT = "reconphys.gaussian_predictor"
VERSION = 1
ENV_VAR = "RECONPHYS_GS_MODEL"
SHIPPED_GS_PATH = (
    Path(__file__).resolve().parent.parent / "weights" / "gaussian_predictor.safetensors"
)
# the object-centric one (GaussianPredictorConfig.crop), trained on the realistic look
SHIPPED_GS_CROP_PATH = SHIPPED_GS_PATH.with_name("gaussian_predictor_crop.safetensors")


def default_gs_model_path() -> Path:
    value = os.environ.get(ENV_VAR, "").strip()
    if not value:
        return SHIPPED_GS_PATH
    path = Path(value)
    return path / TRAINED_NAME if path.is_dir() else path


def gs_model_for_recording(plain_look: bool) -> tuple[Path, str]:
    """The 3DGS predictor for a recording when none is named → (path, why):
    ``$RECONPHYS_GS_MODEL`` when set; else the shipped whole-frame predictor for the plain look
    (the object on black with a camera file: the data it was trained on), and the shipped
    object-centric one for anything else (docs/usage.md "The 3DGS predictor")."""
    if os.environ.get(ENV_VAR, "").strip():
        return default_gs_model_path(), f"${ENV_VAR}"
    if plain_look:
        return SHIPPED_GS_PATH, "the plain look (object on black, camera given): whole frame"
    return SHIPPED_GS_CROP_PATH, "not the plain look: the object-centric predictor"


def save_gaussian_predictor(model: GaussianPredictor, path: str | os.PathLike, training: dict):
    """Write the weights and ``NAME.json`` (config + ``training``), each replaced atomically."""
    from safetensors.torch import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().float().cpu().contiguous() for k, v in model.state_dict().items()}
    with atomic_file(path) as tmp:
        save_file(tensors, str(tmp), {"format": FORMAT})
    metadata = {
        "format": FORMAT,
        "version": VERSION,
        "predictor": model.config.to_dict(),
        "training": training,
    }
    with atomic_file(config_path(path)) as tmp:
        tmp.write_text(json.dumps(metadata, indent=1) + "\n")
    return path


@dataclass
class LoadedGaussianPredictor:
    model: GaussianPredictor  # eval mode
    metadata: dict
    path: Path


def load_gaussian_predictor(
    path: str | os.PathLike | None = None, device="cpu"
) -> LoadedGaussianPredictor:
    """The 3DGS predictor at ``path`` (default: :func:`default_gs_model_path`); InputError naming
    the file when it is missing, corrupt or does not match its config."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    if path is not None:
        path = Path(path)
        path = path / TRAINED_NAME if path.is_dir() else path
    else:
        path = default_gs_model_path()
    if not path.is_file():
        raise InputError(
            "3DGS predictor not found (train one with `reconphys train-gs`, docs/usage.md)",
            source=str(path),
        )
    json_path = config_path(path)
    if not json_path.is_file():
        raise InputError(f"its config {json_path.name} is missing", source=str(path))
    metadata = read_json(json_path, FORMAT, VERSION)
    try:
        model = GaussianPredictor(GaussianPredictorConfig.from_dict(metadata["predictor"]))
        tensors = load_file(str(path))
        model.load_state_dict(tensors)
    except (KeyError, TypeError, ValueError, RuntimeError, SafetensorError, OSError) as e:
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"cannot load the 3DGS predictor ({message})", source=str(path)) from None
    return LoadedGaussianPredictor(model.to(device).eval(), metadata, path)
