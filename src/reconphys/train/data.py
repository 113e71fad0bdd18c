"""Training samples and their order: one view's frames + the sample's asset, in a fixed order.

:class:`TrainingSamples` wraps the two datasets of :mod:`reconphys.data.dataset` (a folder written
by ``make-data``, or generation on the fly) and adds to every item the sample's simulation-ready
asset — the frozen geometry of the self-supervised objective. For now this is the dataset's
canonical Gaussians, anchors, springs and binding placed as in the sample, i.e. **ground-truth
geometry** (docs/design.md#models (a): an upper bound, labelled as such in the model's metadata).

The order is a pure function of ``(seed, epoch)`` (:func:`epoch_permutation`), and the samples of
optimiser step ``s`` are a pure function of ``(seed, s, rank, world size)``
(:func:`step_indices`): a resumed run reads exactly the batches the uninterrupted run would have,
and DDP ranks read disjoint parts of every global batch (DistributedSampler-style striding).
"""

from __future__ import annotations

import hashlib
import statistics
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset, Sampler

from ..assets.asset import Asset
from ..data.dataset import DropDataset, GeneratedDropDataset
from ..data.objects import place, sample_asset
from ..data.sampling import draw_sample
from ..data.settings import DataSettings, make_settings
from ..data.storage import read_manifest
from ..errors import InputError
from ..models.model_input import object_crop
from ..physics import ATTRIBUTES
from .config import GENERATE, DataConfig

GEOMETRY = "ground truth (the dataset's canonical Gaussians, anchors and springs)"
PREDICTED_GEOMETRY = (
    "predicted: the frozen 3DGS predictor {gs_model} on frame 0 of the input view, initial "
    "velocity from the masks (as `predict` builds it)"
)


@dataclass
class Batch:
    """B samples of one view (H = W = the loss' render resolution)."""

    frames: Tensor  # [B, T, H, W, 3] float32 in [0, 1], frames 0..T−1 of the input view
    K: Tensor  # [B, 3, 3] intrinsics in pixels at resolution H
    world_to_cam: Tensor  # [B, 4, 4] OpenCV convention, metres
    attributes: Tensor  # [B, 4] true mass, stiffness, damping, friction (ATTRIBUTES)
    assets: list[Asset]  # the samples' placed objects (geometry + initial state)
    ids: list[str]

    def __len__(self) -> int:
        return len(self.ids)

    def to(self, device) -> Batch:
        return Batch(
            self.frames.to(device),
            self.K.to(device),
            self.world_to_cam.to(device),
            self.attributes.to(device),
            self.assets,
            self.ids,
        )


def collate(items: list[dict]) -> Batch:
    return Batch(
        frames=torch.stack([item["frames"][0] for item in items]),
        K=torch.stack([item["K"][0] for item in items]),
        world_to_cam=torch.stack([item["world_to_cam"][0] for item in items]),
        attributes=torch.stack([item["attributes"] for item in items]),
        assets=[item["asset"] for item in items],
        ids=[item["id"] for item in items],
    )


def generate_settings(config: DataConfig) -> DataSettings:
    """The DataSettings of ``data.source = "generate"``: the preset with data.generate on top."""
    try:
        return make_settings(config.preset, **config.generate)
    except InputError as e:  # names make-data's flag, e.g. "--num-anchors: must be ..."
        raise InputError(str(e), field="data.generate") from None


# settings in which data.more_sources may differ from data.source (what else differs would change
# what a video shows); the meshes' stretch is free (other proportions of the same objects); a model
# of object crops reads every folder resampled to its crop, so for it the recordings' resolution is
# free too (several resolutions: the look of small and large objects)
FREE_KEYS = (
    "seed",
    "objects",
    "test_objects",
    "samples_per_object",
    "test_samples_per_object",
    "stretch_range",
)
CROP_FREE_KEYS = (*FREE_KEYS, "resolution")


class Folders(Dataset):
    """Several dataset folders' samples (each a :class:`DropDataset` of one view) read as one,
    in order: ``data.source`` then ``data.more_sources``."""

    def __init__(self, parts: list[DropDataset]):
        self.parts = parts
        self.samples = [s for part in parts for s in part.samples]
        self._where = [(k, i) for k, part in enumerate(parts) for i in range(len(part))]

    def __len__(self) -> int:
        return len(self._where)

    def __getitem__(self, index: int) -> dict:
        part, index = self._where[index]
        return self.parts[part][index]

    def sample_id(self, index: int) -> str:
        """The sample's id; from data.more_sources[K − 1]: ``source{K}/`` before it (two seeds
        may give a sample the same id)."""
        part, inner = self._where[index]
        name = self.parts[part].samples[inner]["id"]
        return f"source{part}/{name}" if part else name

    def masks(self, index: int, kind: str = "true") -> Tensor:
        part, index = self._where[index]
        return self.parts[part].masks(index, kind)

    def segmenter_fingerprint(self, index: int) -> str:
        part, index = self._where[index]
        return self.parts[part].segmenter_fingerprint(index)

    def asset(self, index: int) -> Asset:
        part, index = self._where[index]
        return self.parts[part].asset(index)


class TrainingSamples(Dataset):
    """Items ``{frames [1, T, H, W, 3], K [1, 3, 3], world_to_cam [1, 4, 4], attributes [4],
    id, asset}`` of one view, frames 0..T−1, at the loss' render resolution.

    With ``config.all_views`` every view of a sample is its own item (item ``i`` = sample
    ``i // 4``, view ``i % 4``): four videos of the same drop from four azimuths. With
    ``assets=False`` the asset is None (the supervised objective simulates nothing).

    With ``crop`` (a model of object crops, ``PredictorConfig.crop``; supervised only) the frames
    are the object's crop at ``config.resolution`` (``models.model_input.object_crop``) of the
    stored frames, and a realistic-look dataset is read too: its frames times its true masks (the
    object on black, as ``predict`` masks a recording)."""

    def __init__(self, config: DataConfig, assets: bool = True, crop: bool = False):
        split = None if config.split == "all" else config.split
        frames = range(config.frames)
        self.crop = config.resolution if crop else 0
        resolution = None if crop else config.loss_resolution
        self.views = [0, 1, 2, 3] if config.all_views else [config.view]
        if config.source == GENERATE:
            self.settings = generate_settings(config)
            if not crop:
                self.settings.require_plain("data", "train", "generate with scene plain")
            self._check_frames(config)
            self.per_view = [
                GeneratedDropDataset(
                    self.settings, split, views=[v], frames=frames, resolution=resolution
                )
                for v in self.views
            ]
            self.source = GENERATE
        else:
            root = Path(config.source)
            if not root.is_dir():
                raise InputError(
                    "dataset folder not found (make it with `reconphys make-data`, see the "
                    "config's header and docs/training.md)",
                    source=str(root),
                    field="data.source",
                )
            self.settings = read_manifest(root)["parsed_settings"]
            if not crop:
                self.settings.require_plain(
                    str(root), "train", "make its data with --scene plain, or train crops"
                )
            self._check_frames(config)
            self.per_view = [
                DropDataset(
                    root,
                    split,
                    views=[v],
                    frames=frames,
                    resolution=resolution,
                    objects=config.objects,
                )
                for v in self.views
            ]
            self.source = str(root.resolve())
            if config.more_sources:
                self.per_view = [
                    Folders([dataset, *self._more(config, dataset, v, resolution)])
                    for v, dataset in zip(self.views, self.per_view, strict=True)
                ]
                self.source = ",".join([self.source, *map(str, config.more_sources)])
        self.dataset = self.per_view[0]  # samples, assets and attributes (the same in every view)
        if len(self.dataset) == 0:
            raise InputError(f"no samples in split {config.split!r}", field="data.split")
        self.assets = assets
        # the masks that cut a realistic video's object out: each kind its own copy of the video
        self.mask_kinds = ("true", "segmenter") if config.masks == "both" else (config.masks,)
        self.per_sample = len(self.views) * len(self.mask_kinds)  # items (videos) per sample
        if self.mask_kinds != ("true",):
            if self.settings.scene == "plain":
                raise InputError(
                    "a plain-look folder: its object is on black, there are no masks to choose",
                    source=self.source,
                    field="data.masks",
                )
            self._check_segmenter_masks()
        self.cache: dict[int, dict] | None = {} if config.cache else None
        self.gs_predictor = None
        self.geometry = GEOMETRY
        if config.geometry == "predicted":
            from ..models.gaussian_shipped import load_gaussian_predictor

            self.gs_predictor = load_gaussian_predictor(config.gs_model or None)
            self.geometry = PREDICTED_GEOMETRY.format(gs_model=self.gs_predictor.path)
            self._asset_attributes = self.medians()  # replaced by the objective's
        self._predicted_assets: dict[int, Asset] = {}  # item index → asset (deterministic)

    def _check_segmenter_masks(self) -> None:
        """The stored segmenter masks came from the shipped segmenter (first and last sample)."""
        from ..models.mask_segmenter import shipped_fingerprint

        expected = shipped_fingerprint()
        for index in (0, len(self.dataset) - 1):
            if self.dataset.segmenter_fingerprint(index) != expected:
                raise InputError(
                    "its segmenter masks came from another mask segmenter than the shipped one: "
                    "write them again with `reconphys segment-data --overwrite`",
                    source=self.source,
                    field="data.masks",
                )

    def _more(self, config: DataConfig, first: DropDataset, view: int, resolution):
        """data.more_sources' samples of ``first``'s objects (view ``view``)."""
        objects = {s["object"] for s in first.samples}
        free = CROP_FREE_KEYS if self.crop else FREE_KEYS
        same = {k: v for k, v in self.settings.to_dict().items() if k not in free}
        for folder in config.more_sources:
            dataset = DropDataset(
                folder, first.split, views=[view], frames=first.frame_index, resolution=resolution
            )
            theirs = {k: v for k, v in dataset.settings.to_dict().items() if k not in free}
            if theirs != same:
                differ = sorted(k for k in same if theirs.get(k) != same[k])
                raise InputError(
                    f"made with other settings than data.source ({', '.join(differ)}): only "
                    "the seed, the stretch and the counts of objects and samples may differ"
                    + ("" if self.crop else " (and the resolution, for a model of object crops)"),
                    source=folder,
                    field="data.more_sources",
                )
            dataset.samples = [s for s in dataset.samples if s["object"] in objects]
            yield dataset

    def _check_frames(self, config: DataConfig) -> None:
        if config.frames > self.settings.num_frames:
            raise InputError(
                f"{config.frames} frames asked, the dataset's videos have "
                f"{self.settings.num_frames}",
                field="data.frames",
            )

    def __len__(self) -> int:
        return len(self.dataset) * self.per_sample

    def _video_of(self, index: int) -> tuple[int, int, str]:
        """Item ``index`` → (sample, position in self.views, mask kind)."""
        sample, inner = divmod(index, self.per_sample)
        kind, view = divmod(inner, len(self.views))
        return sample, view, self.mask_kinds[kind]

    def sample_id(self, index: int) -> str:
        sample, view, kind = self._video_of(index)
        suffix = f"/view{self.views[view]}" if len(self.views) > 1 else ""
        if len(self.mask_kinds) > 1:
            suffix += f"/{kind}-masks"
        return self._sample_id(sample) + suffix

    def _sample_id(self, index: int) -> str:
        if isinstance(self.dataset, Folders):
            return self.dataset.sample_id(index)
        if not isinstance(self.dataset, GeneratedDropDataset):
            return self.dataset.samples[index]["id"]
        return self.dataset.samples[index].id

    def asset(self, index: int) -> Asset:
        """The sample's placed object with its true attributes and initial velocity."""
        index //= self.per_sample
        if not isinstance(self.dataset, GeneratedDropDataset):
            return self.dataset.asset(index)
        planned = self.dataset.samples[index]
        obj = self.dataset.object(index)
        spec = draw_sample(self.settings, obj.id, planned.index)
        return sample_asset(obj, spec, place(obj, spec), self.settings)

    def predicted_asset(self, index: int, item: dict) -> Asset:
        """Item ``index``'s asset from the frozen 3DGS predictor (``data.geometry = predicted``):
        built once from frame 0 of its view, with the training medians as attributes (the
        objective replaces them)."""
        if index not in self._predicted_assets:
            from ..capture.observation import stored_observation
            from ..models.reconstruct import feed_forward_asset

            observation = stored_observation(
                item["frames"][0],
                item["K"][0],
                item["world_to_cam"][0],
                self.settings.frame_dt,
                self.sample_id(index),
            )
            self._predicted_assets[index] = feed_forward_asset(
                observation, self._asset_attributes, self.settings.to_dict(), self.gs_predictor
            )
        return self._predicted_assets[index]

    def _video(self, index: int) -> dict:
        """Frames, cameras and attributes of item ``index`` (from the cache when it has them;
        frames are cached as uint8 when that is exact, i.e. stored at the loss' resolution)."""
        if self.cache is not None and index in self.cache:
            item = dict(self.cache[index])
            if item["frames"].dtype == torch.uint8:
                item["frames"] = item["frames"].float() / 255
            else:
                item["frames"] = item["frames"].float()
            return item
        sample, view, kind = self._video_of(index)
        dataset = self.per_view[view]
        item = dataset[sample]
        if self.crop:
            frames = item["frames"][0]  # [T, H, W, 3]
            if self.settings.scene != "plain":  # the object on black, as predict masks it
                masks = dataset.masks(sample, kind)[0]
                frames = frames * masks[..., None].to(frames)
            item = {**item, "frames": object_crop(frames, self.crop)}
        if self.cache is not None:
            kept = {k: item[k] for k in ("frames", "K", "world_to_cam", "attributes")}
            quantised = (item["frames"] * 255).round().to(torch.uint8)
            if torch.equal(quantised.float() / 255, item["frames"]):
                kept["frames"] = quantised
            else:  # resampled (object crops): half precision, ~1e-4 off, half the memory
                kept["frames"] = item["frames"].to(torch.float16).contiguous()
            self.cache[index] = kept
        return item

    def __getitem__(self, index: int) -> dict:
        item = self._video(index)
        if not self.assets:
            asset = None
        elif self.gs_predictor is None:
            asset = self.asset(index)
        else:
            asset = self.predicted_asset(index, item)
        return {
            "frames": item["frames"],
            "K": item["K"],
            "world_to_cam": item["world_to_cam"],
            "attributes": item["attributes"],
            "id": self.sample_id(index),
            "asset": asset,
        }

    def true_attributes(self) -> list[dict[str, float]]:
        """The attributes of every sample (no simulation, no image I/O)."""
        if not isinstance(self.dataset, GeneratedDropDataset):
            return [dict(s["attributes"]) for s in self.dataset.samples]
        out = []
        for planned in self.dataset.samples:
            spec = draw_sample(self.settings, planned.object.ref.id, planned.index)
            out.append(dict(spec.attributes))
        return out

    def medians(self) -> dict[str, float]:
        """Median of each attribute over the samples: the trivial predictor of this data."""
        attributes = self.true_attributes()
        return {n: float(statistics.median(a[n] for a in attributes)) for n in ATTRIBUTES}

    def fingerprint(self) -> str:
        """Hash of the data settings and the sample list: a resumed run must see the same."""
        ids = ",".join(self.sample_id(i) for i in range(len(self)))
        masks = "" if self.mask_kinds == ("true",) else f"|masks {'+'.join(self.mask_kinds)}"
        text = f"{self.settings.fingerprint()}|{ids}{masks}"
        return hashlib.sha256(text.encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------------------------
# order


@lru_cache(maxsize=8)
def epoch_permutation(num_samples: int, seed: int, epoch: int) -> tuple[int, ...]:
    """The order of the samples in ``epoch``: a permutation drawn from (seed, epoch) only."""
    rng = np.random.default_rng([seed, epoch, 0x7261696E])
    return tuple(int(i) for i in rng.permutation(num_samples))


def step_indices(
    step: int,  # 1-based optimiser step
    num_samples: int,
    batch_size: int,  # global: samples per step over all ranks
    seed: int,
    rank: int = 0,
    world_size: int = 1,
) -> list[int]:
    """The samples ``rank`` reads at ``step``: slots ``rank, rank + W, ...`` of the step's
    ``batch_size`` consecutive slots in the stream of epoch permutations."""
    first = (step - 1) * batch_size
    out = []
    for slot in range(first + rank, first + batch_size, world_size):
        epoch, position = divmod(slot, num_samples)
        out.append(epoch_permutation(num_samples, seed, epoch)[position])
    return out


class StepSampler(Sampler[list[int]]):
    """Batch sampler of the steps ``first_step..last_step`` (1-based, inclusive) for one rank."""

    def __init__(self, num_samples, batch_size, seed, first_step, last_step, rank=0, world_size=1):
        self.args = (num_samples, batch_size, seed)
        self.first_step, self.last_step = first_step, last_step
        self.rank, self.world_size = rank, world_size

    def __len__(self) -> int:
        return max(0, self.last_step - self.first_step + 1)

    def __iter__(self):
        for step in range(self.first_step, self.last_step + 1):
            yield step_indices(step, *self.args, self.rank, self.world_size)
