"""PyTorch datasets of drop videos: over a generated folder, or generated on the fly.

Both return the same dict per sample (``V`` views, ``T`` frames)::

    frames         [V, T, H, W, 3] float32 in [0, 1] (black background)
    K              [V, 3, 3] intrinsics in pixels (scaled to the returned resolution)
    world_to_cam   [V, 4, 4] OpenCV convention, metres
    attributes     [4] float32: mass (kg per anchor), stiffness, damping, friction
    anchors        [T, N_A, 3] float32 anchor positions of the returned frames, metres
    x0, v0         [N_A, 3] the initial state (frame 0, whatever the frame range), m and m/s
    frame_index    [T] int64 indices of the returned frames in the clip
    contact_frame  int (−1 when the object never touched the ground)
    id, object, split   strings

The canonical object (Gaussians + anchors + springs + binding) is not in the dict: it differs in
size between objects; get it with ``dataset.object(i)`` or the sample's full asset with
``dataset.asset(i)``.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from ..assets.asset import Asset
from ..errors import InputError
from ..io import read_npz
from ..physics import ATTRIBUTES
from .generate import generate_sample
from .objects import CanonicalObject, Placement, build_object, sample_asset, scale_object
from .plan import plan_objects, plan_samples
from .sampling import SampleSpec
from .scene import look_from_dict, printed_object
from .settings import DataSettings
from .sources import open_source
from .storage import read_manifest, read_object, read_sample_meta, sample_is_complete

# `reconphys segment-data` writes each realistic sample's mask-segmenter masks beside its frames:
# every view ("view_V": [T, H, W] bool) and the weights' fingerprint they came from
SEGMENTER_MASKS = "segmenter_masks.npz"
SEGMENTER_FINGERPRINT = "segmenter_sha256"


def _frame_range(frames, num_frames: int) -> list[int]:
    if frames is None:
        return list(range(num_frames))
    if isinstance(frames, slice):
        return list(range(num_frames))[frames]
    picked = [int(f) for f in frames]
    if not picked or min(picked) < 0 or max(picked) >= num_frames:
        raise InputError(f"frame indices must lie in [0, {num_frames})", field="frames")
    return picked


def _resize(
    frames: torch.Tensor,  # [V, T, H, W, 3] float
    K: torch.Tensor,  # [V, 3, 3]
    resolution: int | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Resize square frames to ``resolution`` (area average down, bilinear up) and scale K."""
    size = frames.shape[2]
    if resolution is None or resolution == size:
        return frames, K
    v, t = frames.shape[:2]
    flat = frames.reshape(v * t, size, size, 3).permute(0, 3, 1, 2)
    mode = "area" if resolution < size else "bilinear"
    kwargs = {} if mode == "area" else {"align_corners": False}
    flat = F.interpolate(flat, size=(resolution, resolution), mode=mode, **kwargs)
    frames = flat.permute(0, 2, 3, 1).reshape(v, t, resolution, resolution, 3).clamp(0, 1)
    scale = resolution / size
    K = K.clone()
    K[:, :2] *= scale  # pixel-centre convention (u + 0.5) is preserved by a pure scaling
    return frames, K


def _item(
    meta: dict,
    frames: np.ndarray,  # [V, T_all, H, W, 3] uint8 (only the selected views)
    anchors: np.ndarray,  # [T_all, N_A, 3]
    velocities: np.ndarray,  # [T_all, N_A, 3]
    views: list[int],
    frame_index: list[int],
    resolution: int | None,
) -> dict:
    cameras = meta["cameras"]
    K = torch.tensor(cameras["K"], dtype=torch.float32)[views]
    world_to_cam = torch.tensor(cameras["world_to_cam"], dtype=torch.float32)[views]
    images = torch.from_numpy(frames[:, frame_index]).float() / 255.0
    images, K = _resize(images, K, resolution)
    return {
        "frames": images,
        "K": K,
        "world_to_cam": world_to_cam,
        "attributes": torch.tensor([meta["attributes"][a] for a in ATTRIBUTES]).float(),
        "anchors": torch.from_numpy(anchors[frame_index]),
        "x0": torch.from_numpy(anchors[0]),
        "v0": torch.from_numpy(velocities[0]),
        "frame_index": torch.tensor(frame_index, dtype=torch.int64),
        "contact_frame": int(meta["contact_frame"]),
        "id": meta["id"],
        "object": meta["object"],
        "split": meta["split"],
    }


class _Selection:
    """Shared argument checks for the two datasets."""

    def _select(self, settings: DataSettings, views, frames, resolution, split) -> None:
        if split not in (None, "train", "test"):
            raise InputError(f"expected train, test or None, got {split!r}", field="split")
        self.views = list(range(4)) if views is None else [int(v) for v in views]
        if not self.views or any(not 0 <= v < 4 for v in self.views):
            raise InputError(f"views must be in 0..3, got {views}", field="views")
        self.frame_index = _frame_range(frames, settings.num_frames)
        if resolution is not None and resolution < 1:
            raise InputError(f"must be ≥ 1 pixel, got {resolution}", field="resolution")
        self.resolution = resolution
        self.split = split


class DropDataset(Dataset, _Selection):
    """Samples of a folder written by ``make-data``; reads only what the manifest lists.

    Args:
        root: the dataset folder.
        split: "train", "test" or None (all samples).
        views: which of the 4 views (default all), in the order given.
        frames: frame indices, a slice, or None (all ``num_frames``).
        resolution: square output size in pixels (None: as stored).
        allow_incomplete: accept the manifest of an unfinished run (its listed samples are
            complete; the run just has not made the others yet).
        verify: check every listed sample's files (sizes, settings tag) when opening.
        objects: keep only the samples of the split's first ``objects`` objects, in the
            manifest's order (0: all) — a smaller training set held out the same way.
    """

    def __init__(
        self,
        root: str | os.PathLike,
        split: str | None = None,
        views: Sequence[int] | None = None,
        frames: Sequence[int] | slice | None = None,
        resolution: int | None = None,
        allow_incomplete: bool = False,
        verify: bool = True,
        objects: int = 0,
    ):
        self.root = Path(root)
        self.manifest = read_manifest(self.root)
        self.settings: DataSettings = self.manifest["parsed_settings"]
        if not self.manifest["complete"] and not allow_incomplete:
            raise InputError(
                "the dataset is incomplete (rerun make-data to finish it, or pass "
                "allow_incomplete=True)",
                source=str(self.root / "manifest.json"),
            )
        self._select(self.settings, views, frames, resolution, split)
        self.samples = [s for s in self.manifest["samples"] if split in (None, s["split"])]
        if objects:
            kept = list(dict.fromkeys(s["object_dir"] for s in self.samples))[:objects]
            self.samples = [s for s in self.samples if s["object_dir"] in set(kept)]
        if verify:
            for sample in self.samples:
                if not sample_is_complete(self.root, sample["id"], self.settings):
                    raise InputError("incomplete or altered sample", str(self.root / sample["dir"]))
        self._objects: OrderedDict[str, CanonicalObject] = OrderedDict()

    def __len__(self) -> int:
        return len(self.samples)

    def index_of(self, sample_id: str) -> int:
        """The index of the sample called ``sample_id``; InputError naming the dataset if none."""
        for index, sample in enumerate(self.samples):
            if sample["id"] == sample_id:
                return index
        raise InputError("no such sample in manifest.json", source=str(self.root), field=sample_id)

    def meta(self, index: int) -> dict:
        """The sample's sample.json (attributes, initial state, cameras, contact frame, ...)."""
        return read_sample_meta(self.root, self.samples[index]["id"])

    def __getitem__(self, index: int) -> dict:
        entry = self.samples[index]
        meta = self.meta(index)
        folder = self.root / entry["dir"]
        names = tuple(f"view_{v}" for v in self.views)
        stored = read_npz(folder / "frames.npz", names)
        frames = np.stack([stored[n] for n in names])
        expected = (meta["num_frames"], meta["cameras"]["height"], meta["cameras"]["width"], 3)
        if frames.dtype != np.uint8 or frames.shape[1:] != expected:
            raise InputError(f"expected uint8 [V, {', '.join(map(str, expected))}]", str(folder))
        trajectory = read_npz(folder / "trajectory.npz", ("anchors", "velocities"))
        anchors = trajectory["anchors"].astype(np.float32)
        if anchors.ndim != 3 or anchors.shape[0] != meta["num_frames"]:
            raise InputError(f"expected [{meta['num_frames']}, N_A, 3]", str(folder), "anchors")
        return _item(
            meta,
            frames,
            anchors,
            trajectory["velocities"].astype(np.float32),
            self.views,
            self.frame_index,
            self.resolution,
        )

    def object(self, index: int) -> CanonicalObject:
        """The canonical object of sample ``index`` (cached, a few at a time)."""
        directory = self.samples[index]["object_dir"]
        if directory not in self._objects:
            self._objects[directory] = read_object(self.root / directory)
            while len(self._objects) > 8:
                self._objects.popitem(last=False)
        return self._objects[directory]

    def asset(self, index: int) -> Asset:
        """The sample's simulation-ready asset: the placed object, its attributes, v0."""
        meta = self.meta(index)
        state = meta["initial_state"]
        spec = SampleSpec(
            **meta["attributes"],
            rotation=np.array(state["rotation"]),
            linear_velocity=tuple(state["linear_velocity"]),
            angular_velocity=tuple(state["angular_velocity"]),
            target_contact_time=state["target_contact_frame"] * meta["frame_dt"],
        )
        placement = Placement(spec.rotation, np.array(state["translation"]), state["drop_height"])
        obj = scale_object(self.object(index), float(state.get("scale", 1.0)))
        if "scene" in meta:  # the realistic look: its print, if any (data/scene.py)
            obj = printed_object(obj, look_from_dict(meta["scene"]["look"]))
        return sample_asset(obj, spec, placement, self.settings)

    def masks(self, index: int, kind: str = "true") -> torch.Tensor:  # [V, T, H, W] bool
        """The object's masks of a realistic sample's selected views and frames, at the stored
        resolution: the true ones (``kind="true"``), or the mask segmenter's that ``reconphys
        segment-data`` wrote beside them (``kind="segmenter"``: what a user without masks gets)."""
        entry = self.samples[index]
        names = tuple(f"view_{v}" for v in self.views)
        if kind == "segmenter":
            stored = read_npz(self._segmenter_masks(index), names)
        elif kind == "true":
            if "masks" not in entry:
                raise InputError("stores no masks (made with --scene plain)", str(self.root))
            stored = read_npz(self.root / entry["masks"], names)
        else:
            raise ValueError(f"kind: expected true or segmenter, got {kind!r}")
        masks = np.stack([stored[n] for n in names])[:, self.frame_index]
        return torch.from_numpy(masks.astype(bool))

    def segmenter_fingerprint(self, index: int) -> str:
        """The weights fingerprint recorded with sample ``index``'s segmenter masks."""
        path = self._segmenter_masks(index)
        return str(read_npz(path, (SEGMENTER_FINGERPRINT,))[SEGMENTER_FINGERPRINT])

    def _segmenter_masks(self, index: int) -> Path:
        path = self.root / self.samples[index]["dir"] / SEGMENTER_MASKS
        if not path.is_file():
            raise InputError(
                f"no mask segmenter's masks (write them with `reconphys segment-data {self.root}`)",
                str(path),
            )
        return path


class GeneratedDropDataset(Dataset, _Selection):
    """The samples ``make-data`` would write for ``settings``, generated when indexed (no disk).

    Objects are built on first use and cached (``cache_objects`` of them). Frames go through
    the same uint8 quantisation as the stored ones, so items equal those of :class:`DropDataset`
    over a folder made with the same settings on the same kind of device.
    """

    def __init__(
        self,
        settings: DataSettings,
        split: str | None = None,
        views: Sequence[int] | None = None,
        frames: Sequence[int] | slice | None = None,
        resolution: int | None = None,
        device: str = "cpu",
        cache_objects: int = 8,
        objaverse_root: str | os.PathLike | None = None,
    ):
        self.settings = settings.validated()
        self._select(self.settings, views, frames, resolution, split)
        self.source = open_source(settings.source, settings, objaverse_root)
        objects = plan_objects(self.settings, self.source)
        self.samples = [s for s in plan_samples(self.settings, objects) if split in (None, s.split)]
        self.device = device
        self.cache_objects = cache_objects
        self._objects: OrderedDict[str, CanonicalObject] = OrderedDict()

    def __len__(self) -> int:
        return len(self.samples)

    def object(self, index: int) -> CanonicalObject:
        planned = self.samples[index].object
        if planned.key not in self._objects:
            gaussians = self.source.load(planned.ref, self.settings)
            description = self.source.describe(planned.ref)
            self._objects[planned.key] = build_object(
                planned.ref.id, planned.key, gaussians, self.settings, description
            )
            while len(self._objects) > self.cache_objects:
                self._objects.popitem(last=False)
        return self._objects[planned.key]

    def masks(self, index: int, kind: str = "true") -> torch.Tensor:  # [V, T, H, W] bool
        """The true masks of a realistic sample's selected views and frames (generated again;
        generated samples have no segmenter masks: ``kind`` must be "true")."""
        if kind != "true":
            raise InputError(
                f"generated samples have only their true masks, not {kind!r}", "settings"
            )
        if self.settings.scene != "realistic":
            raise InputError("stores no masks (settings with scene plain)", "settings")
        planned = self.samples[index]
        sample = generate_sample(self.object(index), planned.index, self.settings, self.device)
        return torch.from_numpy(sample.masks[self.views][:, self.frame_index])

    def __getitem__(self, index: int) -> dict:
        planned = self.samples[index]
        sample = generate_sample(self.object(index), planned.index, self.settings, self.device)
        meta = {
            "id": planned.id,
            "object": planned.object.ref.id,
            "split": planned.split,
            "attributes": sample.spec.attributes,
            "contact_frame": sample.contact_frame,
            "cameras": {
                "K": sample.cameras.K.double().tolist(),
                "world_to_cam": sample.cameras.world_to_cam.double().tolist(),
            },
        }
        return _item(
            meta,
            sample.frames[self.views],
            sample.anchors,
            sample.velocities,
            self.views,
            self.frame_index,
            self.resolution,
        )
