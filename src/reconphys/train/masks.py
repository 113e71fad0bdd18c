"""Training the mask segmenter (``reconphys train-masks``, models/mask_segmenter.py), and
writing its masks beside a realistic dataset's frames (``reconphys segment-data``).

Examples are single frames of realistic-look datasets (``make-data --scene realistic``, which
stores the true masks): every view of every training-split sample is a clip; a folder of
recordings with their true masks (another engine's renders: :func:`recording_clips`) adds each
recording as a clip; a step draws
``batch_size`` (clip, frame) pairs, one zoom factor log-uniform in ``zoom`` (the step's frames
resampled: area-averaged down, bilinear up, so the network sees objects at more pixel sizes than
the data were rendered at), a random ``crop``² window (smaller frames are used whole) and a
horizontal mirror (never a vertical one: objects fall downwards), and minimises binary cross
entropy + soft Dice against the stored mask. The run writes ``OUT/model.safetensors`` +
``model.json``, ``OUT/log.jsonl``, and a checkpoint every ``checkpoint_every`` steps; running the
same command again resumes it. ``init`` starts from a trained segmenter's weights instead of a
random draw (fine-tuning it on other data, with the same schedule).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..data.dataset import SEGMENTER_FINGERPRINT, SEGMENTER_MASKS, DropDataset
from ..errors import InputError
from ..io import atomic_file
from ..models.mask_segmenter import (
    MaskSegmenter,
    SegmenterConfig,
    clip_references,
    frame_inputs,
    load_mask_segmenter,
    save_mask_segmenter,
    segment_clip,
    shipped_fingerprint,
)
from .checkpoint import resume_step, save_step

CHECKPOINT = "checkpoint.pt"


@dataclass
class MaskTrainSettings:
    data: tuple[str, ...]  # realistic-look dataset folders (their train splits)
    out: str
    steps: int = 4000
    batch_size: int = 16
    crop: int = 96  # pixels per side of the training window
    lr: float = 2e-3  # peak (cosine to 5 %)
    seed: int = 0
    checkpoint_every: int = 500
    zoom: tuple[float, float] = (1.0, 1.0)  # per step, log-uniform: frames resampled by it
    exclude: tuple[str, ...] = ()  # meshes left out: a folder's test split's, or a list file
    views_per_sample: int = 4  # sample i gives views i, i + 1, … (mod 4): more meshes per GB
    channels: tuple[int, ...] = SegmenterConfig().channels  # the U-Net's width per level
    init: str = ""  # a trained segmenter (.safetensors or a run's folder) to start from; "": random
    # share of a step's clips seen through another camera (_photometric: exposure, white
    # balance, tone curve, softness), their references made again from the changed frames
    photometric: float = 0.0


def _recorded(settings: MaskTrainSettings) -> dict:
    """The settings a checkpoint records: ``init`` and ``photometric`` only when given (older
    runs still resume)."""
    recorded = asdict(settings)
    if not recorded["init"]:
        recorded.pop("init")
    if not recorded["photometric"]:
        recorded.pop("photometric")
    return recorded


@dataclass
class _Clip:
    frames: torch.Tensor  # [T, H, W, 3] uint8
    references: torch.Tensor  # [3, 3, H, W] float
    masks: torch.Tensor  # [T, H, W] bool


def held_out_meshes(source: str) -> set[str]:
    """The meshes (a sample's ``object``) that ``source`` names: a dataset folder's test split's,
    or a text file's lines (a mesh per line, ``#`` starts a comment: configs/masks_held_out.txt)."""
    path = Path(source)
    if path.is_file():
        lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
        return {line for line in lines if line}
    return {s["object"] for s in DropDataset(path, split="test").samples}


def load_clips(
    folders: tuple[str, ...],
    split: str = "train",
    progress: bool = False,
    exclude: tuple[str, ...] = (),
    views_per_sample: int = 4,
) -> list:
    """The views of every ``split`` sample of ``folders`` as clips (refuses plain datasets):
    ``views_per_sample`` of them (sample i's views i, i + 1, … mod the view count), and none of
    a mesh that an ``exclude`` entry names (a held-out set stays held out): a dataset folder's
    test split's meshes, or a text file of meshes (:func:`held_out_meshes`)."""
    held_out = set().union(*map(held_out_meshes, exclude))
    clips = []
    for folder in folders:
        if not (Path(folder) / "manifest.json").is_file():
            clips += recording_clips(folder, held_out, progress)
            continue
        dataset = DropDataset(folder, split=split)
        samples = [s for s in dataset.samples if s["object"] not in held_out]
        per_view = []  # one dataset a view: a sample's other views are not decoded
        for view in dataset.views:
            per_view.append(DropDataset(folder, split=split, views=[view]))
            per_view[-1].samples = samples
        indices = range(len(samples))
        if progress:
            from tqdm.auto import tqdm

            indices = tqdm(indices, desc=f"reading {folder}", unit="sample")
        count = len(per_view)
        for index in indices:
            for view in sorted({(index + k) % count for k in range(views_per_sample)}):
                frames = per_view[view][index]["frames"][0]  # [T, H, W, 3] in [0, 1]
                clips.append(
                    _Clip(
                        frames=(frames * 255).round().to(torch.uint8),
                        references=clip_references(frames),
                        masks=per_view[view].masks(index)[0],
                    )
                )
    if not clips:
        raise InputError(f"no {split} samples", source=", ".join(folders))
    return clips


def recording_clips(
    folder: str, held_out: set[str] | frozenset[str] = frozenset(), progress: bool = False
) -> list:
    """Clips of a folder of recordings with their true masks (another engine's renders:
    benchmarks/other_engine.py render): every subfolder with ``video.mp4`` and ``masks.npz``
    (``masks`` [T, H, W], the frames' size) is one clip, all of it training (no split); one
    whose ``truth.json`` names a mesh in ``held_out`` (``object``) is left out. A video one
    pixel larger than its masks (H.264's even sizes: render/video.write_mp4 pads) is cut to them.
    InputError for a folder without such clips, an unreadable masks.npz or truth.json, or masks
    that do not match their video."""
    from ..capture.video import read_video

    root = Path(folder)
    found = (
        sorted(f for f in root.iterdir() if (f / "video.mp4").is_file()) if root.is_dir() else []
    )
    if not found:
        raise InputError(
            "neither a dataset (manifest.json) nor recordings (*/video.mp4 + masks.npz)",
            source=str(root),
        )
    if progress:
        from tqdm.auto import tqdm

        found = tqdm(found, desc=f"reading {folder}", unit="clip")
    clips = []
    for clip in found:
        truth = clip / "truth.json"
        if truth.is_file():
            try:
                mesh = json.loads(truth.read_text()).get("object")
            except (OSError, UnicodeDecodeError, ValueError, AttributeError) as e:
                raise InputError(f"unreadable JSON ({e})", source=str(truth)) from e
            if mesh in held_out:
                continue
        try:
            masks = torch.from_numpy(np.load(clip / "masks.npz")["masks"]) > 0.5
        except (OSError, KeyError, ValueError) as e:
            raise InputError(f"no readable masks.npz with 'masks' ({e})", source=str(clip)) from e
        decoded = read_video(clip / "video.mp4")[0][..., :3]
        if masks.ndim == 3 and all(
            0 <= d - m <= 1 for d, m in zip(decoded.shape[1:3], masks.shape[1:], strict=True)
        ):
            decoded = decoded[:, : masks.shape[1], : masks.shape[2]]
        if masks.ndim != 3 or decoded.shape[:3] != tuple(masks.shape):
            raise InputError(
                f"masks {list(masks.shape)} do not match the video's frames "
                f"{list(decoded.shape[:3])}",
                source=str(clip),
            )
        frames = torch.from_numpy(decoded)
        clips.append(_Clip(frames, clip_references(frames.float() / 255), masks))
    return clips


def _zoomed(image: torch.Tensor, zoom: float) -> torch.Tensor:  # [C, H, W] → [C, h, w]
    if zoom == 1.0:
        return image
    size = [max(1, round(n * zoom)) for n in image.shape[-2:]]
    mode = "area" if zoom < 1 else "bilinear"
    return F.interpolate(image[None], size=size, mode=mode)[0]


# _photometric's ranges: exposure gain, each channel's gain about it (white balance), the tone
# curve's exponent, and the weight of a 3×3 blur (a softer lens or renderer)
EXPOSURE = (0.6, 1.6)
WHITE_BALANCE = (0.8, 1.25)
TONE_EXPONENT = (0.7, 1.45)
BLUR = (0.0, 0.8)


def _log_uniform(rng: np.random.Generator, low: float, high: float, size: int | None = None):
    return np.exp(rng.uniform(np.log(low), np.log(high), size))


def _photometric(frames: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """A clip [T, H, W, 3] in [0, 1] as another camera might have taken it: one exposure gain
    and white balance (log-uniform, EXPOSURE × WHITE_BALANCE per channel), one tone curve
    ``x ** γ`` (γ log-uniform in TONE_EXPONENT) and one softness (a 3×3 binomial blur mixed in
    at a weight uniform in BLUR) for all its frames, as a renderer or phone other than the
    training data's would differ; the masks stay as they are."""
    gain = _log_uniform(rng, *EXPOSURE) * _log_uniform(rng, *WHITE_BALANCE, 3)
    exponent = float(_log_uniform(rng, *TONE_EXPONENT))
    weight = float(rng.uniform(*BLUR))
    x = (frames * torch.tensor(gain, dtype=frames.dtype)).clamp(0, 1) ** exponent
    if weight > 0:
        kernel = torch.tensor([1.0, 2.0, 1.0], dtype=x.dtype)
        kernel = (kernel[:, None] * kernel[None, :] / 16).expand(3, 1, 3, 3)
        channels = x.permute(0, 3, 1, 2)
        blurred = F.conv2d(F.pad(channels, (1, 1, 1, 1), mode="replicate"), kernel, groups=3)
        x = ((1 - weight) * channels + weight * blurred).permute(0, 2, 3, 1)
    return x


def _batch(clips: list, rng: np.random.Generator, settings: MaskTrainSettings):
    low, high = settings.zoom  # drawn only when it varies: the default recipe's batches as before
    zoom = float(np.exp(rng.uniform(np.log(low), np.log(high)))) if low < high else low
    inputs, targets = [], []
    for _ in range(settings.batch_size):
        clip = clips[int(rng.integers(len(clips)))]
        count = clip.masks.shape[0]
        t = int(rng.integers(count))
        references = clip.references
        if settings.photometric and rng.uniform() < settings.photometric:
            changed = _photometric(clip.frames.float() / 255, rng)
            frame, references = changed[t : t + 1], clip_references(changed)
        else:
            frame = clip.frames[t : t + 1].float() / 255
        x = frame_inputs(frame, references, torch.tensor([t / (count - 1)]))[0]
        x, y = _zoomed(x, zoom), _zoomed(clip.masks[t : t + 1].float(), zoom)[0]
        height, width = y.shape
        size_h, size_w = min(settings.crop, height), min(settings.crop, width)
        i, j = int(rng.integers(height - size_h + 1)), int(rng.integers(width - size_w + 1))
        x, y = x[:, i : i + size_h, j : j + size_w], y[i : i + size_h, j : j + size_w]
        if rng.uniform() < 0.5:
            x, y = x.flip(-1), y.flip(-1)
        inputs.append(x)
        targets.append(y)
    return torch.stack(inputs), torch.stack(targets)


def mask_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """BCE + soft Dice (per image, averaged): [B, H, W] logits and {0, 1} targets."""
    probability = torch.sigmoid(logits)
    overlap = 2 * (probability * target).sum((1, 2)) + 1
    dice = 1 - overlap / (probability.sum((1, 2)) + target.sum((1, 2)) + 1)
    return F.binary_cross_entropy_with_logits(logits, target) + dice.mean()


def train_mask_segmenter(settings: MaskTrainSettings, progress: bool = True, log=print) -> Path:
    out = Path(settings.out)
    torch.manual_seed(settings.seed)
    model = MaskSegmenter(SegmenterConfig(channels=tuple(settings.channels)))
    if settings.init:  # before the data are read: a wrong --init fails at once
        start = load_mask_segmenter(settings.init)
        if start.config.channels != model.config.channels:
            widths = ",".join(map(str, start.config.channels))
            raise InputError(
                f"its network's channels are {widths}: give --channels {widths}",
                source=settings.init,
            )
        model.load_state_dict(start.state_dict())
    clips = load_clips(
        settings.data, "train", progress, settings.exclude, settings.views_per_sample
    )
    optimizer = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=1e-4)
    checkpoint = out / CHECKPOINT
    first = resume_step(checkpoint, model, optimizer, _recorded(settings), log)
    out.mkdir(parents=True, exist_ok=True)
    steps = range(first, settings.steps + 1)
    if progress:
        from tqdm.auto import tqdm

        steps = tqdm(
            steps, desc="train-masks", unit="step", initial=first - 1, total=settings.steps
        )
    started = time.perf_counter()
    model.train()
    loss = torch.tensor(float("nan"))
    for step in steps:
        rng = np.random.default_rng([settings.seed, step])
        lr = settings.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * step / settings.steps)))
        for group in optimizer.param_groups:
            group["lr"] = lr
        inputs, targets = _batch(clips, rng, settings)
        loss = mask_loss(model(inputs), targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        with open(out / "log.jsonl", "a") as f:
            f.write(json.dumps({"step": step, "loss": loss.item(), "lr": lr}) + "\n")
        if progress:
            steps.set_postfix(loss=f"{loss.item():.3f}")
        if step % settings.checkpoint_every == 0 or step == settings.steps:
            save_step(checkpoint, model, optimizer, step, _recorded(settings))
    training = {
        "data": [str(Path(d).resolve()) for d in settings.data],
        "clips": len(clips),
        "settings": _recorded(settings),
        "wall_clock_seconds_last_session": round(time.perf_counter() - started, 1),
        "final_loss": loss.item(),
    }
    return save_mask_segmenter(model.eval(), out / "model.safetensors", training)


def _segment_samples(job: tuple[str, list[int], bool]) -> int:
    """Worker: write the shipped segmenter's masks of samples ``indices`` of ``root``."""
    root, indices, overwrite = job
    torch.set_num_threads(1)
    model = load_mask_segmenter()
    fingerprint = shipped_fingerprint()
    dataset = DropDataset(root, split=None)  # every view, every frame
    for index in indices:
        path = dataset.root / dataset.samples[index]["dir"] / SEGMENTER_MASKS
        if path.is_file() and not overwrite:
            continue
        frames = dataset[index]["frames"]  # [V, T, H, W, 3]
        arrays = {
            f"view_{v}": segment_clip(model, frames[i]).bool().numpy()
            for i, v in enumerate(dataset.views)
        }
        with atomic_file(path) as tmp:
            np.savez_compressed(tmp, **arrays, **{SEGMENTER_FINGERPRINT: np.array(fingerprint)})
    return len(indices)


def segment_dataset(
    root: str | os.PathLike, workers: int = 2, overwrite: bool = False, progress: bool = True
) -> int:
    """Write the shipped mask segmenter's masks of every view of every sample of a realistic-look
    dataset beside its frames (``SEGMENTER_MASKS``: what ``predict`` reads from a recording
    without masks), for training on them (``data.masks = "segmenter"``). Samples that have them
    are kept unless ``overwrite``. Returns the number of samples."""
    dataset = DropDataset(root, split=None)
    if dataset.settings.scene == "plain":
        raise InputError(
            "a plain-look dataset: its object is on black, cut out by its colour (no segmenter)",
            source=str(root),
        )
    count = len(dataset)
    jobs = [(str(root), list(range(s, min(count, s + 16))), overwrite) for s in range(0, count, 16)]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=count, desc="segment-data", unit="sample")
    if workers <= 1:
        results = map(_segment_samples, jobs)
    else:
        pool = multiprocessing.get_context("spawn").Pool(workers)
        results = pool.imap_unordered(_segment_samples, jobs)
    try:
        for done in results:
            if bar is not None:
                bar.update(done)
    finally:
        if workers > 1:
            pool.close()
            pool.join()
        if bar is not None:
            bar.close()
    return count
