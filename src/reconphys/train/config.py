"""Training configuration: five sections, a config file (TOML or JSON) and ``key=value`` overrides.

Sections and what they hold (every key, its type and default is the dataclass field below)::

    [data]       where the videos come from, which view and frames the predictor reads
    [model]      the PhysicsPredictor (its num_frames / resolution come from [data])
    [objective]  self_supervised | supervised | mixed, the detach window
    [optim]      AdamW, learning-rate schedule, gradient clipping
    [train]      steps, batch, seed, device, AMP, checkpoints, logs, output folder

A file gives any subset of keys; the rest keep their defaults. Overrides on the command line use
dotted keys (``optim.lr=3e-4``, ``data.generate.objects=4``, ``model.encoder_channels=[16,32]``);
values are TOML literals, or plain text for string keys. Every value is type-checked against the
field it sets, and a bad key or value raises :class:`~reconphys.errors.InputError` naming it (the
reading, parsing and type checks are :mod:`reconphys.config_loader`'s, shared with ``make-data``
and ``train-gs``; this module adds the sections, the ``data.generate``/``model.extra`` tables
and the semantic checks).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field, fields, replace

from ..config_loader import (
    check_type,
    field_types,
    flatten,
    parse_override,
    parse_value,
    read_table,
    resolve,
)
from ..data.settings import PRESETS, DataSettings
from ..errors import InputError
from ..models.encoders import encoder_names
from ..models.physics_predictor import INPUTS, PredictorConfig

GENERATE = "generate"  # data.source value: generate the samples on the fly (no folder)
OBJECTIVES = ("self_supervised", "supervised", "mixed")
SUPERVISED_TARGETS = ("attributes", "observables")  # train.objective.supervised_loss' targets
SCHEDULES = ("cosine", "constant")
AMP_DTYPES = ("bfloat16", "float16")
SPLITS = ("train", "test", "all")
GEOMETRIES = ("true", "predicted")
MASK_KINDS = ("true", "segmenter", "both")
DERIVED_MODEL_KEYS = {"num_frames": "data.frames", "resolution": "data.resolution"}


@dataclass
class DataConfig:
    source: str = GENERATE  # a dataset folder written by make-data, or "generate" (on the fly)
    preset: str = "small"  # generate only: the make-data preset the overrides below start from
    generate: dict = field(default_factory=dict)  # generate only: DataSettings overrides
    split: str = "train"  # train, test or all
    view: int = 0  # the input view, 0–3 (docs/design.md#conventions)
    all_views: bool = False  # train on every view, each its own video (4× the videos; not eval)
    objects: int = 0  # a folder only: the split's first N objects' samples (0: all; data curves)
    # further folders made like data.source but with another seed: their samples of the same
    # objects (those data.source and data.objects select) are read too — more drops of each
    more_sources: tuple[str, ...] = ()
    cache: bool = False  # keep each video in memory (uint8, or float16 when resampled): no rereads
    frames: int = 20  # the predictor reads frames 0..frames−1; the loss compares 1..frames−1
    resolution: int = 64  # predictor input, pixels (square; frames are resized to it)
    render_resolution: int = 0  # size of the photometric loss' renders, pixels (0: resolution)
    num_workers: int = 0  # DataLoader worker processes (0: load in the training process)
    geometry: str = "true"  # true (the dataset's assets) or predicted (the frozen 3DGS predictor)
    gs_model: str = ""  # geometry = predicted: a 3DGS predictor (.safetensors or run); "": shipped
    # a realistic-look folder read by a model of object crops: the object cut out by its true
    # masks, the mask segmenter's (written by `reconphys segment-data`: what predict gets), or
    # both (each video twice, cut out by each)
    masks: str = "true"

    @property
    def loss_resolution(self) -> int:
        return self.render_resolution or self.resolution


@dataclass
class ObjectiveConfig:
    kind: str = "self_supervised"  # self_supervised, supervised or mixed
    supervised_weight: float = 1e-3  # mixed: loss = photometric + supervised_weight × supervised
    supervised_target: str = "attributes"  # attributes (m, k, d, f) or observables (k/m, d/m, f)
    detach_window: int = 1  # frames between detaches of the simulated state (paper: 1)
    min_substeps: int = 0  # floor of the simulator's substeps per frame (0: the dataset's)


@dataclass
class OptimConfig:
    lr: float = 3e-4  # peak learning rate of AdamW
    weight_decay: float = 0.01
    beta1: float = 0.9
    beta2: float = 0.999
    grad_clip: float = 1.0  # maximum global gradient norm (0: no clipping)
    schedule: str = "cosine"  # cosine (to min_lr_ratio × lr at the last step) or constant
    warmup_steps: int = 0  # linear warm-up from 0
    min_lr_ratio: float = 0.1


@dataclass
class RunConfig:
    steps: int = 1000  # optimiser steps in total (a resumed run continues to this count)
    batch_size: int = 4  # samples per step over all processes (divided among DDP ranks)
    seed: int = 0  # model initialisation and data order
    device: str = "auto"  # auto, cpu, cuda or cuda:N (DDP on CUDA: cuda:LOCAL_RANK)
    amp: bool = False  # mixed precision for the predictor; CUDA only (ignored on CPU)
    amp_dtype: str = "bfloat16"  # bfloat16, or float16 (with a gradient scaler)
    threads: int = 0  # torch CPU threads per process (0: torch's default)
    checkpoint_every: int = 100  # steps between checkpoints (also written at the last step)
    log_every: int = 10  # steps between console lines and TensorBoard points
    tensorboard: bool = True  # write OUT/tensorboard when the tensorboard package is installed
    out: str = "runs/train"  # output folder: checkpoint, logs, exported model
    init: str = ""  # weights to start from (a model .safetensors or a training OUT); "": random
    # > 1: train that many networks, seeds seed, seed + 1, …, each into OUT/member-I (a run of
    # its own: resumable), then write their ensemble (the mean answer) to OUT/model.safetensors
    members: int = 1


@dataclass
class TrainConfig:
    data: DataConfig = field(default_factory=DataConfig)
    model: PredictorConfig = field(default_factory=PredictorConfig)
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    train: RunConfig = field(default_factory=RunConfig)

    def predictor_config(self) -> PredictorConfig:
        """The network's config: [model] with the frames and resolution of [data]."""
        return replace(self.model, num_frames=self.data.frames, resolution=self.data.resolution)

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        for key in DERIVED_MODEL_KEYS:
            out["model"].pop(key)
        return _jsonable(out)

    @staticmethod
    def from_dict(data: dict, where: str = "config") -> TrainConfig:
        config = TrainConfig()
        for key, value in flatten(data, where, _is_dict_field):
            set_value(config, key, value, where)
        return config.validated()

    def validated(self) -> TrainConfig:
        _validate(self)
        return self


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


# ----------------------------------------------------------------------------------------------
# reading and setting keys (the generic parts: reconphys.config_loader)

FREE_TABLES = (["data", "generate"], ["model", "extra"])  # dict fields set entry by entry


def _is_dict_field(dotted: str) -> bool:
    try:
        owner, name = resolve(TrainConfig(), dotted, "config", DERIVED_MODEL_KEYS)
    except InputError:
        return False
    return field_types(type(owner)).get(name) is dict


def set_value(config: TrainConfig, key: str, value, where: str | None = "config") -> None:
    """Set dotted ``key`` of ``config`` to ``value`` (already parsed), checking its type.

    ``data.generate.NAME`` and ``model.extra.NAME`` set one entry of those tables; the former is
    checked against :class:`~reconphys.data.settings.DataSettings`. ``where`` names the file in
    errors (None for command-line overrides).
    """
    parts = key.split(".")
    if len(parts) == 1:
        raise InputError("expected SECTION.KEY (e.g. optim.lr)", source=where, field=key)
    if parts[0] == "model" and len(parts) == 2 and parts[1] in DERIVED_MODEL_KEYS:
        raise InputError(f"set {DERIVED_MODEL_KEYS[parts[1]]} instead", source=where, field=key)
    if len(parts) >= 3 and parts[:2] in FREE_TABLES:
        table = getattr(getattr(config, parts[0]), parts[1])
        name = ".".join(parts[2:])
        if parts[1] == "generate":
            table[name] = _check_generate_entry(name, value, where, key)
        else:
            table[name] = value
        return
    owner, name = resolve(config, key, where, DERIVED_MODEL_KEYS)
    value = check_type(value, field_types(type(owner))[name], key, where)
    if key == "data.generate":
        value = {k: _check_generate_entry(k, v, where, f"{key}.{k}") for k, v in value.items()}
    setattr(owner, name, value)


def _check_generate_entry(name: str, value, where: str | None, key: str):
    hints = field_types(DataSettings)
    if name not in hints:
        known = ", ".join(f.name for f in fields(DataSettings))
        raise InputError(f"not a make-data setting (known: {known})", source=where, field=key)
    return check_type(value, hints[name], key, where)


def _field_hint(key: str):
    """The type of dotted ``key`` (None for free-form entries such as model.extra.*)."""
    parts = key.split(".")
    if len(parts) >= 3 and parts[:2] == ["data", "generate"]:
        return field_types(DataSettings).get(".".join(parts[2:]))
    if len(parts) >= 3 and parts[:2] == ["model", "extra"]:
        return None
    try:
        owner, name = resolve(TrainConfig(), key, "override", DERIVED_MODEL_KEYS)
    except InputError:
        return None
    return field_types(type(owner))[name]


def apply_overrides(config: TrainConfig, overrides: list[str]) -> TrainConfig:
    """Apply ``KEY=VALUE`` strings in order, then validate."""
    for text in overrides:
        key, raw = parse_override(text)
        set_value(config, key, parse_value(raw, _field_hint(key)), where=None)
    return config.validated()


def load_config(path: str | os.PathLike | None, overrides: list[str] = ()) -> TrainConfig:
    """Defaults ← the file at ``path`` (if any) ← ``overrides``, validated."""
    config = TrainConfig()
    if path is not None:
        where = str(path)
        for key, value in flatten(read_table(path), where, _is_dict_field):
            set_value(config, key, value, where)
        try:
            config.validated()
        except InputError as e:
            raise InputError(str(e), source=where) from None
    return apply_overrides(config, list(overrides))


# ----------------------------------------------------------------------------------------------
# semantic checks


def _require(condition: bool, key: str, message: str) -> None:
    if not condition:
        raise InputError(message, field=key)


def _choice(value: str, choices: tuple[str, ...], key: str) -> None:
    _require(value in choices, key, f"expected one of {', '.join(choices)}, got {value!r}")


def _validate(config: TrainConfig) -> None:
    d, m, o, p, r = config.data, config.model, config.objective, config.optim, config.train
    _require(bool(d.source), "data.source", 'expected a dataset folder or "generate"')
    _choice(d.preset, tuple(PRESETS), "data.preset")
    _choice(d.split, SPLITS, "data.split")
    _require(0 <= d.view < 4, "data.view", f"expected 0, 1, 2 or 3, got {d.view}")
    _require(d.frames >= 2, "data.frames", f"must be ≥ 2 (frame 0 + one compared), got {d.frames}")
    _require(d.resolution >= 8, "data.resolution", f"must be ≥ 8 pixels, got {d.resolution}")
    _require(
        d.render_resolution == 0 or d.render_resolution >= 8,
        "data.render_resolution",
        f"must be 0 (= data.resolution) or ≥ 8 pixels, got {d.render_resolution}",
    )
    _require(d.num_workers >= 0, "data.num_workers", f"must be ≥ 0, got {d.num_workers}")
    _choice(d.geometry, GEOMETRIES, "data.geometry")
    _choice(d.masks, MASK_KINDS, "data.masks")
    _require(
        d.masks == "true" or (d.source != GENERATE and m.crop),
        "data.masks",
        "the segmenter's masks are read from a realistic-look folder by a model of object "
        "crops (model.crop = true)",
    )
    _require(
        d.geometry == "predicted" or not d.gs_model,
        "data.gs_model",
        "a 3DGS predictor is only used with data.geometry = predicted",
    )
    _require(d.objects >= 0, "data.objects", f"must be ≥ 0 (0: all), got {d.objects}")
    _require(
        not d.more_sources or d.source != GENERATE,
        "data.more_sources",
        "for a folder only; generated data takes data.generate.samples_per_object",
    )
    _require(
        d.objects == 0 or d.source != GENERATE,
        "data.objects",
        "for a folder only; generated data takes data.generate.objects",
    )
    _require(
        not (d.cache and d.num_workers),
        "data.cache",
        "the cache lives in the training process: set data.num_workers = 0",
    )
    _choice(m.inputs, INPUTS, "model.inputs")
    _require(
        not m.crop or o.kind == "supervised",
        "model.crop",
        "a model of object crops is trained supervised (its input is not the camera's view)",
    )
    _require(m.track_channels >= 1, "model.track_channels", "must be ≥ 1")
    _choice(m.encoder, tuple(encoder_names()), "model.encoder")
    _require(
        all(c >= 1 for c in m.encoder_channels) and len(m.encoder_channels) >= 1,
        "model.encoder_channels",
        f"expected a non-empty list of positive channel counts, got {list(m.encoder_channels)}",
    )
    _require(m.token_channels >= 1, "model.token_channels", "must be ≥ 1")
    _require(m.trunk_blocks >= 0, "model.trunk_blocks", "must be ≥ 0")
    _require(
        m.attention_heads >= 1 and m.token_channels % m.attention_heads == 0,
        "model.attention_heads",
        f"must be ≥ 1 and divide model.token_channels ({m.token_channels})",
    )
    _require(all(w >= 1 for w in m.mlp_hidden), "model.mlp_hidden", "widths must be ≥ 1")
    _choice(o.kind, OBJECTIVES, "objective.kind")
    _choice(o.supervised_target, SUPERVISED_TARGETS, "objective.supervised_target")
    _require(
        math.isfinite(o.supervised_weight) and o.supervised_weight >= 0,
        "objective.supervised_weight",
        f"must be a finite number ≥ 0, got {o.supervised_weight}",
    )
    _require(o.detach_window >= 1, "objective.detach_window", "must be ≥ 1 frame")
    _require(o.min_substeps >= 0, "objective.min_substeps", "must be ≥ 0 (0: the dataset's)")
    _require(math.isfinite(p.lr) and p.lr > 0, "optim.lr", f"must be > 0, got {p.lr}")
    _require(p.weight_decay >= 0, "optim.weight_decay", "must be ≥ 0")
    for key, beta in (("optim.beta1", p.beta1), ("optim.beta2", p.beta2)):
        _require(0 <= beta < 1, key, f"must be in [0, 1), got {beta}")
    _require(p.grad_clip >= 0, "optim.grad_clip", "must be ≥ 0 (0: off)")
    _choice(p.schedule, SCHEDULES, "optim.schedule")
    _require(p.warmup_steps >= 0, "optim.warmup_steps", "must be ≥ 0")
    _require(0 <= p.min_lr_ratio <= 1, "optim.min_lr_ratio", "must be in [0, 1]")
    _require(r.steps >= 1, "train.steps", f"must be ≥ 1, got {r.steps}")
    _require(r.batch_size >= 1, "train.batch_size", f"must be ≥ 1, got {r.batch_size}")
    _require(r.seed >= 0, "train.seed", f"must be ≥ 0, got {r.seed}")
    _require(r.members >= 1, "train.members", f"must be ≥ 1, got {r.members}")
    device_ok = r.device in ("auto", "cpu", "cuda") or (
        r.device.startswith("cuda:") and r.device[5:].isdigit()
    )
    _require(device_ok, "train.device", f"expected auto, cpu, cuda or cuda:N, got {r.device!r}")
    _choice(r.amp_dtype, AMP_DTYPES, "train.amp_dtype")
    _require(r.threads >= 0, "train.threads", "must be ≥ 0 (0: torch's default)")
    _require(r.checkpoint_every >= 1, "train.checkpoint_every", "must be ≥ 1 step")
    _require(r.log_every >= 1, "train.log_every", "must be ≥ 1 step")
    _require(bool(r.out), "train.out", "expected an output folder")


# Keys a resumed run may change: they do not alter the optimisation (devices, threads and
# workers may change its last bits, not its course). Everything else must match the checkpoint.
RESUME_FREE_KEYS = (
    "train.steps",
    "train.checkpoint_every",
    "train.log_every",
    "train.tensorboard",
    "train.device",
    "train.threads",
    "train.out",
    "data.num_workers",
    "data.source",  # the data itself is compared by its fingerprint
)


def differing_keys(old: dict, new: dict) -> list[str]:
    """Dotted keys whose values differ between two ``to_dict()`` configs (free keys excluded).
    A key missing from one side counts as its default (a checkpoint written before the key
    existed)."""

    def flat(table, prefix=""):
        out = {}
        for key, value in table.items():
            dotted = prefix + key
            if isinstance(value, dict) and dotted not in ("data.generate", "model.extra"):
                out.update(flat(value, dotted + "."))
            else:
                out[dotted] = value
        return out

    defaults = flat(TrainConfig().to_dict())
    a, b = flat(old), flat(new)
    keys = sorted(set(a) | set(b))
    return [
        k
        for k in keys
        if k not in RESUME_FREE_KEYS and a.get(k, defaults.get(k)) != b.get(k, defaults.get(k))
    ]
