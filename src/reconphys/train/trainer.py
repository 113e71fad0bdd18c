"""The training loop of ``reconphys train`` (docs/design.md#models): data → predictor → loss → step
→ log.

One step::

    batch (frames 0..T−1 of the input view, the samples' assets)      train.data
      → predictor(frames resized to data.resolution) → p = (m, k, d, f)
      → loss: self_supervised  photometric_loss (self-forced rollout from the initial state,
                               detached every objective.detach_window frames, bind, render,
                               MSE on frames 1..T−1)                   train.objective
              supervised       L1 on normalised attributes
              mixed            photometric + supervised_weight × supervised
      → backward → clip the global gradient norm → AdamW step (skipped, and counted, when the
        loss or the gradient is not finite) → learning-rate schedule
      → OUT/log.jsonl (+ TensorBoard, progress bar); OUT/checkpoint.pt every checkpoint_every
        steps; OUT/model.safetensors + OUT/model.json at every checkpoint and at the end.

A run whose OUT holds a checkpoint continues from it (same config required, see
:data:`~reconphys.train.config.RESUME_FREE_KEYS`) and reproduces the uninterrupted run's losses:
the batches of step s depend only on (seed, s), and model, optimiser, schedule and random states
come back exactly. Geometry: the samples' ground-truth assets (labelled in the model metadata).

Why one module of ~500 lines: the :class:`Trainer` is the loop's state (model, optimiser,
schedule, scaler, data order, logs) and its methods are the loop's stages in order (build,
resume, step, report, save), read top to bottom like nanoGPT's ``train.py``; the parts that stand
alone already live beside it (config, data, objective, checkpoint, distributed).
"""

from __future__ import annotations

import json
import math
import os
import random
import shutil
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader

from .. import __version__
from ..errors import InputError
from ..io import atomic_file
from ..models.physics_predictor import PhysicsPredictor, PredictorEnsemble, resize_frames
from ..models.shipped import (
    TRAINED_NAME,
    LoadedPredictor,
    load_predictor,
    model_metadata,
    save_predictor,
)
from ..physics import ATTRIBUTES
from ..render import Cameras
from ..render.photometric import SceneBatch, photometric_loss
from ..threads import set_cpu_threads
from . import distributed
from .checkpoint import CHECKPOINT, load_checkpoint, rng_state, save_checkpoint, set_rng_state
from .config import TrainConfig, differing_keys
from .data import Batch, StepSampler, TrainingSamples, collate
from .objective import observable_scale_loss, supervised_loss

LOG = "log.jsonl"
TENSORBOARD = "tensorboard"
CONFIG = "config.json"


@dataclass
class TrainResult:
    out: Path
    step: int  # optimiser steps done in total
    first_step: int  # the first step this call ran (1 for a fresh run)
    model: PhysicsPredictor | PredictorEnsemble  # the trained network(s), unwrapped
    records: list[dict] = field(default_factory=list)  # log records of this call's steps
    seconds: float = 0.0  # wall-clock of the whole run, earlier parts of a resumed one included


def lr_factor(step: int, config: TrainConfig) -> float:
    """Multiplier of optim.lr at 0-based step ``step``: linear warm-up, then cosine or constant."""
    o, total = config.optim, config.train.steps
    if step < o.warmup_steps:
        return (step + 1) / o.warmup_steps
    if o.schedule == "constant":
        return 1.0
    progress = (step - o.warmup_steps) / max(1, total - o.warmup_steps)
    progress = min(1.0, progress)
    return o.min_lr_ratio + (1 - o.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress))


@dataclass
class Physics:
    """What the rollout of the photometric loss needs from the data."""

    frame_dt: float  # seconds
    min_substeps: int


def compute_losses(
    model: torch.nn.Module,
    batch: Batch,
    config: TrainConfig,
    physics: Physics,
    autocast_dtype: torch.dtype | None,  # None: full precision
) -> dict[str, Tensor]:
    """Scalar tensors: "loss" (what is minimised), its terms ("photometric", "supervised"), and
    "attribute_error" (normalised L1 to the truth, for monitoring; no gradient)."""
    device = batch.frames.device
    inputs = resize_frames(batch.frames, config.data.resolution)  # [B, T, R, R, 3]
    with torch.autocast(device.type, dtype=autocast_dtype or torch.float32,
                        enabled=autocast_dtype is not None):  # fmt: skip
        out = model(inputs)
    attributes = {name: out[name].float() for name in ATTRIBUTES}  # simulate in float32
    kind = config.objective.kind
    terms: dict[str, Tensor] = {}
    if kind in ("self_supervised", "mixed"):
        size = batch.frames.shape[2]
        terms["photometric"] = photometric_loss(
            attributes,
            SceneBatch.from_assets(batch.assets, device),
            batch.frames,
            Cameras(batch.K, batch.world_to_cam, size, size),
            window=config.objective.detach_window,
            frame_dt=physics.frame_dt,
            min_substeps=physics.min_substeps,
        )
    if kind in ("supervised", "mixed"):
        target = config.objective.supervised_target
        terms["supervised"] = supervised_loss(attributes, batch.attributes, target)
    if kind == "self_supervised":
        terms["loss"] = terms["photometric"]
    elif kind == "supervised":
        terms["loss"] = terms["supervised"]
    else:
        terms["loss"] = (
            terms["photometric"] + config.objective.supervised_weight * terms["supervised"]
        )
    if "observable_scale" in out:  # model.scale_head: its own term, which moves it alone
        terms["scale"] = observable_scale_loss(
            attributes, out["observable_scale"].float(), batch.attributes
        )
        terms["loss"] = terms["loss"] + terms["scale"]
    with torch.no_grad():
        detached = {k: v.detach() for k, v in attributes.items()}
        terms["attribute_error"] = supervised_loss(detached, batch.attributes)
        terms["observable_error"] = supervised_loss(detached, batch.attributes, "observables")
    return terms


def clip_groups(model: PhysicsPredictor) -> tuple[list[Tensor], list[Tensor]]:
    """The model's parameters → (the answer's, the scale head's; empty without one), clipped
    each by its own norm: with ``model.scale_head`` the answer trains exactly as without it."""
    scale = list(model.scale.parameters()) if model.scale is not None else []
    ids = {id(p) for p in scale}
    return [p for p in model.parameters() if id(p) not in ids], scale


class Trainer:
    """One training run into ``config.train.out`` (see the module docstring)."""

    def __init__(
        self,
        config: TrainConfig,
        overwrite: bool = False,
        progress: bool = True,
        callback: Callable[[int, dict], None] | None = None,
        log: Callable[[str], None] = print,
    ):
        self.config = config
        self.overwrite = overwrite
        self.progress = progress
        self.callback = callback
        self.log = log
        self.out = Path(config.train.out)

    # --- set-up -------------------------------------------------------------------------------

    def _prepare_output(self) -> None:
        if self.context.is_main:
            if self.overwrite:
                for name in (CHECKPOINT, LOG, CONFIG, TRAINED_NAME, "model.json"):
                    (self.out / name).unlink(missing_ok=True)
                shutil.rmtree(self.out / TENSORBOARD, ignore_errors=True)
            try:
                self.out.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise InputError(f"cannot create ({e.strerror or e})", str(self.out)) from None
        distributed.barrier(self.context)

    def _open_data(self) -> None:
        """The samples (checked before OUT is touched: bad data leaves nothing behind)."""
        if self.config.train.threads:
            set_cpu_threads(self.config.train.threads)
        torch.set_flush_denormal(True)  # settling objects make float32 denormals (slow on CPU)
        supervised = self.config.objective.kind == "supervised"  # no rollout: no assets to build
        self.data = TrainingSamples(
            self.config.data, assets=not supervised, crop=self.config.model.crop
        )
        self.init = self._load_init(self.config.train.init) if self.config.train.init else None

    def _build(self) -> None:
        config, context = self.config, self.context
        if config.train.batch_size % context.world_size:
            raise InputError(
                f"{config.train.batch_size} is not divisible by the {context.world_size} processes",
                field="train.batch_size",
            )
        self.physics = Physics(
            frame_dt=self.data.settings.frame_dt,
            min_substeps=config.objective.min_substeps or self.data.settings.min_substeps,
        )
        seed = config.train.seed
        torch.manual_seed(seed)
        np.random.seed(seed)  # noqa: NPY002 (legacy global state, seeded for third-party code)
        random.seed(seed)
        self.model = PhysicsPredictor(config.predictor_config()).to(self.device)
        self.clip_groups = clip_groups(self.model)  # the same parameter objects for the whole run
        o = config.optim
        self.optimizer = torch.optim.AdamW(
            self.model.parameters(), lr=o.lr, betas=(o.beta1, o.beta2), weight_decay=o.weight_decay
        )
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, lambda step: lr_factor(step, config)
        )
        cuda = self.device.type == "cuda"
        if config.train.amp and not cuda:
            warnings.warn("train.amp: mixed precision is CUDA-only; float32 on CPU", stacklevel=2)
        amp = config.train.amp and cuda
        self.autocast_dtype = getattr(torch, config.train.amp_dtype) if amp else None
        self.scaler = torch.amp.GradScaler("cuda", enabled=self.autocast_dtype == torch.float16)
        self.init_source = None
        if self.init is not None:  # before the optimiser state exists; a resume overrides it
            self.model.load_state_dict(self.init.model.state_dict())
            trained = self.init.metadata.get("training") or {}
            self.init_source = {
                "path": str(self.init.path),
                "objective": trained.get("objective"),
                "steps": trained.get("steps"),
            }
        self.step = 0
        self.skipped = 0
        self.elapsed_before = 0.0

    def _load_init(self, path: str) -> LoadedPredictor:
        """The model ``train.init`` names (fine-tuning), checked against this run's network."""
        loaded = load_predictor(path)
        source = str(loaded.path)
        if isinstance(loaded.model, PredictorEnsemble):
            raise InputError("an ensemble; start from one of its members' model.safetensors",
                             source=source, field="train.init")  # fmt: skip
        if loaded.model.config != self.config.predictor_config():
            raise InputError("its predictor config differs from this run's [model]/[data] "
                             "settings", source=source, field="train.init")  # fmt: skip
        view = self.config.data.view
        if loaded.view != view:
            message = f"trained on view {loaded.view}, this run reads view {view}"
            raise InputError(message, source=source, field="train.init")
        return loaded

    def _resume(self) -> None:
        path = self.out / CHECKPOINT
        if not path.is_file():
            return
        payload = load_checkpoint(path)
        differ = differing_keys(payload["config"], self.config.to_dict())
        if differ:
            key = differ[0]
            raise InputError(
                f"{path} was written with another config ({len(differ)} key(s) differ, first "
                f"{key}); use the same config to resume, or pass --overwrite to start again",
                field=key,
            )
        if payload["data_fingerprint"] != self.data.fingerprint():
            raise InputError(
                f"{path} was trained on other data (settings or samples differ); use the same "
                "data to resume, or pass --overwrite",
                field="data.source",
            )
        self.model.load_state_dict(payload["model"])
        self.optimizer.load_state_dict(payload["optimizer"])
        self.scheduler.load_state_dict(payload["scheduler"])
        self.scaler.load_state_dict(payload["scaler"])
        set_rng_state(payload["rng"])
        self.step = int(payload["step"])
        self.skipped = int(payload["skipped"])
        self.elapsed_before = float(payload["elapsed"])
        if self.context.is_main:
            _truncate_log(self.out / LOG, self.step)
            self.log(f"resuming {self.out} from step {self.step}")

    # --- outputs ------------------------------------------------------------------------------

    def _payload(self) -> dict:
        return {
            "step": self.step,
            "skipped": self.skipped,
            "elapsed": self.elapsed(),
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "scaler": self.scaler.state_dict(),
            "rng": rng_state(),
            "config": self.config.to_dict(),
            "data_fingerprint": self.data.fingerprint(),
        }

    def elapsed(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.started

    def _training_metadata(self, last: dict | None) -> dict:
        c, d = self.config, self.data
        return {
            "objective": c.objective.kind,
            "supervised_weight": c.objective.supervised_weight
            if c.objective.kind == "mixed"
            else None,
            "detach_window": c.objective.detach_window,
            "steps": self.step,
            "batch_size": c.train.batch_size,
            "skipped_steps": self.skipped,
            "geometry": d.geometry,
            "init": self.init_source,
            "data": {
                "source": d.source,
                "split": c.data.split,
                "samples": len(d),
                "fingerprint": d.fingerprint(),
                "settings": d.settings.to_dict(),
                "render_resolution": c.data.loss_resolution,
            },
            "attribute_medians": d.medians(),
            "final_loss": None if last is None else last.get("loss"),
            "final_attribute_error": None if last is None else last.get("attribute_error"),
            "seed": c.train.seed,
            "world_size": self.context.world_size,
            "device": str(self.device),
            "amp": self.autocast_dtype is not None,
            "wall_clock_seconds": round(self.elapsed(), 1),
            "reconphys_version": __version__,
            "config": c.to_dict(),
        }

    def _save(self, last: dict | None) -> None:
        save_checkpoint(self.out / CHECKPOINT, self._payload())
        metadata = model_metadata(
            self.config.predictor_config(),
            self.config.data.view,
            self.physics.frame_dt,
            self._training_metadata(last),
        )
        save_predictor(self.model, self.out / TRAINED_NAME, metadata)

    # --- the loop -----------------------------------------------------------------------------

    def run(self) -> TrainResult:
        self.started = time.perf_counter()
        threads = torch.get_num_threads()
        self.context, self.device = distributed.setup(self.config.train.device)
        try:
            return self._run()
        finally:
            distributed.cleanup(self.context)
            if self.config.train.threads:
                set_cpu_threads(threads)  # the caller's setting (tests run many trainings)

    def _run(self) -> TrainResult:
        config, context = self.config, self.context
        self._open_data()
        self._prepare_output()
        self._build()
        self._resume()
        first_step = self.step + 1
        if context.is_main:
            text = json.dumps(config.to_dict(), indent=1) + "\n"
            (self.out / CONFIG).write_text(text)
        network = self.model
        if context.enabled:
            ids = [self.device.index] if self.device.type == "cuda" else None
            network = DistributedDataParallel(self.model, device_ids=ids)
        sampler = StepSampler(
            len(self.data), config.train.batch_size, config.train.seed, first_step,
            config.train.steps, context.rank, context.world_size,
        )  # fmt: skip
        loader = DataLoader(
            self.data,
            batch_sampler=sampler,
            num_workers=config.data.num_workers,
            collate_fn=collate,
        )
        writer = self._tensorboard(first_step)
        bar = self._progress_bar(first_step - 1)
        records: list[dict] = []
        log_file = (self.out / LOG).open("a") if context.is_main else None
        try:
            tick = time.perf_counter()
            for step, batch in enumerate(loader, start=first_step):
                record = self._train_step(network, batch, step, tick)
                tick = time.perf_counter()
                records.append(record)
                if context.is_main:
                    log_file.write(json.dumps(record) + "\n")
                    log_file.flush()
                    self._report(record, writer, bar)
                if self.callback is not None:
                    self.callback(step, record)
                if step % config.train.checkpoint_every == 0 or step == config.train.steps:
                    if context.is_main:
                        self._save(record)
        finally:
            if log_file is not None:
                log_file.close()
            if writer is not None:
                writer.close()
            if bar is not None:
                bar.close()
        if context.is_main and not records and not (self.out / TRAINED_NAME).is_file():
            self._save(None)  # resumed at or past the last step: export what there is
        return TrainResult(self.out, self.step, first_step, self.model, records, self.elapsed())

    def _train_step(self, network, batch: Batch, step: int, tick: float) -> dict:
        config, context = self.config, self.context
        batch = batch.to(self.device)
        network.train()
        self.optimizer.zero_grad(set_to_none=True)
        terms = compute_losses(network, batch, config, self.physics, self.autocast_dtype)
        self.scaler.scale(terms["loss"]).backward()  # every rank, always: DDP all-reduces here
        self.scaler.unscale_(self.optimizer)
        limit = config.optim.grad_clip if config.optim.grad_clip > 0 else math.inf
        answer, scale = self.clip_groups
        grad_norm = torch.nn.utils.clip_grad_norm_(answer, limit)
        if scale:  # its own norm: the scale head's gradients never shrink the answer's step
            torch.nn.utils.clip_grad_norm_(scale, limit)
        names = sorted(terms)
        values = torch.stack([terms[n].detach().float() for n in names]).cpu()
        values = distributed.all_reduce_mean(values.to(self.device), context).cpu()
        reduced = dict(zip(names, values.tolist(), strict=True))
        finite = math.isfinite(reduced["loss"]) and bool(torch.isfinite(grad_norm))
        lr = self.optimizer.param_groups[0]["lr"]
        if finite or self.scaler.is_enabled():
            self.scaler.step(self.optimizer)  # the float16 scaler skips non-finite steps itself
            self.scaler.update()
        if not finite:
            self.skipped += 1
            self.optimizer.zero_grad(set_to_none=True)
            warnings.warn(
                f"step {step}: non-finite loss or gradient ({reduced['loss']}); step skipped",
                stacklevel=2,
            )
        self.scheduler.step()
        self.step = step
        seconds = time.perf_counter() - tick
        samples = len(batch) * context.world_size
        return {
            "step": step,
            "epoch": round(step * config.train.batch_size / len(self.data), 4),
            **reduced,
            "lr": lr,
            "grad_norm": float(grad_norm),
            "skipped_step": not finite,
            "skipped": self.skipped,
            "samples_per_s": samples / seconds if seconds > 0 else None,
            "seconds": seconds,
            "elapsed": self.elapsed(),
        }

    def _tensorboard(self, first_step: int):
        if not (self.context.is_main and self.config.train.tensorboard):
            return None
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard not installed: log.jsonl has everything
            return None
        return SummaryWriter(str(self.out / TENSORBOARD), purge_step=first_step)

    def _progress_bar(self, done: int):
        if not (self.context.is_main and self.progress):
            return None
        from tqdm import tqdm

        return tqdm(total=self.config.train.steps, initial=done, desc="train", dynamic_ncols=True)

    def _report(self, record: dict, writer, bar) -> None:
        step = record["step"]
        if bar is not None:
            bar.update(1)
            bar.set_postfix(
                loss=f"{record['loss']:.4g}",
                samples_s=f"{record['samples_per_s'] or 0:.2f}",
                skipped=record["skipped"],
            )
        if step % self.config.train.log_every and step != self.config.train.steps:
            return
        if writer is not None:
            for key in ("loss", "photometric", "supervised", "attribute_error", "grad_norm", "lr",
                        "samples_per_s"):  # fmt: skip
                if record.get(key) is not None:
                    writer.add_scalar(f"train/{key}", record[key], step)
            writer.flush()
        if bar is None:
            self.log(
                f"step {step}/{self.config.train.steps} loss {record['loss']:.5g} "
                f"attribute_error {record['attribute_error']:.4f} lr {record['lr']:.3g} "
                f"{record['samples_per_s'] or 0:.2f} samples/s"
            )


def _truncate_log(path: Path, step: int) -> None:
    """Drop log lines past ``step`` (written by a run killed after its last checkpoint)."""
    if not path.is_file():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line)["step"] <= step:
                kept.append(line)
        except (json.JSONDecodeError, KeyError, TypeError):
            continue  # a line cut short by the kill
    with atomic_file(path) as tmp:
        tmp.write_text("".join(line + "\n" for line in kept))


def train(
    config: TrainConfig,
    overwrite: bool = False,
    progress: bool = True,
    callback: Callable[[int, dict], None] | None = None,
    log: Callable[[str], None] = print,
) -> TrainResult:
    """Train (or continue training) the physics predictor as ``config`` says; see the module
    docstring. ``callback(step, record)`` runs after every step on every rank. With
    ``train.members`` = M > 1: M runs (seeds seed..seed+M−1) into OUT/member-0..M−1, then their
    ensemble into OUT/model.safetensors (:func:`train_ensemble`)."""
    if config.train.members > 1:
        run = lambda member: train(member, overwrite, progress, callback, log)  # noqa: E731
        return train_ensemble(config, run, log)
    return Trainer(config, overwrite, progress, callback, log).run()


def member_config(config: TrainConfig, index: int) -> TrainConfig:
    """The run of ensemble member ``index``: its own seed and folder, one network."""
    run = replace(
        config.train,
        seed=config.train.seed + index,
        out=str(Path(config.train.out) / f"member-{index}"),
        members=1,
    )
    return replace(config, train=run)


def train_ensemble(
    config: TrainConfig,
    run: Callable[[TrainConfig], TrainResult],  # trains one member's config
    log: Callable[[str], None] = print,
) -> TrainResult:
    """Each member in turn with ``run`` (a finished member is skipped on a second call: each
    resumes), then
    OUT/model.safetensors + model.json: the members' weights under ``members.I.`` and their
    training records under ``training.members``."""
    out = Path(config.train.out)
    results = []
    for index in range(config.train.members):
        log(
            f"ensemble member {index + 1}/{config.train.members} (seed {config.train.seed + index})"
        )
        results.append(run(member_config(config, index)))
    if int(os.environ.get("RANK", "0")) != 0:
        return results[-1]  # under torchrun: rank 0 writes the ensemble
    loaded = [load_predictor(r.out / TRAINED_NAME) for r in results]
    ensemble = PredictorEnsemble(loaded[0].model.config, len(loaded))
    for member, one in zip(ensemble.members, loaded, strict=True):
        member.load_state_dict(one.model.state_dict())
    first = loaded[0].metadata
    training = dict(first["training"])
    training["members"] = [
        {
            "out": str(r.out),
            "seed": one.metadata["training"].get("seed"),
            "final_loss": one.metadata["training"].get("final_loss"),
            "wall_clock_seconds": one.metadata["training"].get("wall_clock_seconds"),
        }
        for r, one in zip(results, loaded, strict=True)
    ]
    training["wall_clock_seconds"] = round(sum(r.seconds for r in results), 1)
    training["config"] = config.to_dict()
    metadata = model_metadata(
        ensemble.config, first["input"]["view"], first["input"]["frame_dt"], training,
        members=len(loaded),
    )  # fmt: skip
    save_predictor(ensemble.eval(), out / TRAINED_NAME, metadata)
    last = results[-1]
    records = [record for r in results for record in r.records]
    first_step = min(r.first_step for r in results)
    seconds = sum(r.seconds for r in results)
    return TrainResult(out, last.step, first_step, ensemble, records, seconds)
