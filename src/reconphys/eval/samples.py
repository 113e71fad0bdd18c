"""The evaluation samples of a dataset folder: frames, cameras, true attributes and geometry.

A sample carries everything any method or metric may need. What a method is *allowed* to use is
part of its definition (see :mod:`reconphys.eval.methods`): the per-scene baselines read only
``frames``, ``cameras`` and ``frame_dt``; the methods labelled "ground-truth geometry" also read
``true_asset`` (an upper bound, labelled so in every report).
"""

from __future__ import annotations

import os
import statistics
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from ..assets.asset import Asset
from ..data.dataset import DropDataset
from ..data.settings import DataSettings
from ..errors import InputError
from ..physics import ATTRIBUTE_RANGES, ATTRIBUTES
from ..render import Cameras

SPLITS = ("test", "train", "all")

# The trivial predictor's values when a folder has no training split: the medians of the paper
# protocol's uniform attribute ranges (docs/design.md#attribute-ranges), i.e. the midpoints. They
# stand in for "the medians of the shipped model's training data" until a model is shipped with its
# own.
FALLBACK_MEDIANS = {name: 0.5 * (low + high) for name, (low, high) in ATTRIBUTE_RANGES.items()}


@dataclass
class EvalSample:
    """One drop video with its ground truth (V views, T frames, N Gaussians, N_A anchors)."""

    id: str
    object: str
    split: str
    frames: Tensor  # [V, T, H, W, 3] float32 in [0, 1], black background
    cameras: Cameras  # V cameras, no batch dims
    frame_dt: float  # seconds between frames
    attributes: dict[str, float]  # true mass (kg per anchor), stiffness, damping, friction
    true_asset: Asset  # the placed object with its true attributes and initial velocity
    anchors: Tensor  # [T, N_A, 3] stored anchor trajectory, frame 0 = initial state, metres
    gaussian_means: Tensor  # [T, N, 3] true Gaussian centres per frame, metres

    @property
    def num_frames(self) -> int:
        return self.frames.shape[1]

    @property
    def num_views(self) -> int:
        return self.frames.shape[0]


@dataclass
class TrivialAttributes:
    """The trivial predictor: one value per attribute, with where it came from."""

    values: dict[str, float]  # mass, stiffness, damping, friction
    source: str  # e.g. "median of 40 training samples"


class EvalSet:
    """The samples of one split of a dataset folder, loaded one at a time.

    Args:
        root: the dataset folder written by ``make-data`` (must be complete).
        split: "test", "train" or "all".
        limit: evaluate only the first ``limit`` samples of the split (manifest order).
        shard: (I, N): of those, only the I-th, (I + N)-th, ... (N evaluations in parallel).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        split: str = "test",
        limit: int | None = None,
        shard: tuple[int, int] | None = None,
    ):
        if split not in SPLITS:
            raise InputError(f"expected one of {', '.join(SPLITS)}, got {split!r}", field="--split")
        if limit is not None and limit < 1:
            raise InputError(f"must be ≥ 1, got {limit}", field="--limit")
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError("dataset folder not found", source=str(self.root))
        self.dataset = DropDataset(self.root, split=None if split == "all" else split)
        self.split = split
        self.settings: DataSettings = self.dataset.settings
        self.settings.require_plain(
            str(self.root),
            "evaluate",
            "measure realistic recordings with benchmarks/realistic_predict.py (docs/usage.md)",
        )
        if len(self.dataset) == 0:
            counts = self.dataset.manifest.get("counts", {})
            have = ", ".join(f"{k}: {v.get('samples', 0)}" for k, v in counts.items())
            raise InputError(
                f"no samples in split {split!r} (samples per split: {have or 'none'})",
                source=str(self.root / "manifest.json"),
            )
        self.indices = list(range(len(self.dataset)))[:limit]
        if shard is not None:
            self.indices = self.indices[shard[0] :: shard[1]]
            if not self.indices:
                raise InputError(
                    f"shard {shard[0]}/{shard[1]} holds no sample "
                    f"({len(self.dataset)} in the split)",
                    field="--shard",
                )

    def __len__(self) -> int:
        return len(self.indices)

    @property
    def ids(self) -> list[str]:
        return [self.dataset.samples[i]["id"] for i in self.indices]

    def trivial_attributes(self) -> TrivialAttributes:
        """Median attributes of the folder's training split (FALLBACK_MEDIANS without one)."""
        train = [s["attributes"] for s in self.dataset.manifest["samples"] if s["split"] == "train"]
        if not train:
            return TrivialAttributes(
                dict(FALLBACK_MEDIANS),
                "no training split: midpoints of the docs/design.md#attribute-ranges ranges "
                "(medians of the paper's "
                "uniform training distribution)",
            )
        values = {name: float(statistics.median(a[name] for a in train)) for name in ATTRIBUTES}
        return TrivialAttributes(values, f"median of the {len(train)} training samples")

    def load(self, position: int) -> EvalSample:
        """Sample ``position`` (0 ≤ position < len(self)) with its ground truth."""
        index = self.indices[position]
        item = self.dataset[index]
        meta = self.dataset.meta(index)
        asset = self.dataset.asset(index)
        anchors = item["anchors"]  # [T, N_A, 3]
        if anchors.shape[1] != asset.num_anchors:
            raise InputError(
                f"{anchors.shape[1]} anchors, the object has {asset.num_anchors}",
                source=str(self.root / self.dataset.samples[index]["trajectory"]),
                field="anchors",
            )
        cameras = Cameras(
            item["K"], item["world_to_cam"], meta["cameras"]["width"], meta["cameras"]["height"]
        )
        with torch.no_grad():
            means = asset.gaussian_means(anchors)
        return EvalSample(
            id=item["id"],
            object=item["object"],
            split=item["split"],
            frames=item["frames"],
            cameras=cameras,
            frame_dt=float(meta["frame_dt"]),
            attributes={k: float(v) for k, v in meta["attributes"].items()},
            true_asset=asset,
            anchors=anchors,
            gaussian_means=means,
        )
