"""A dataset sample as ``predict``'s input: the stored frames of one view and its camera (an
:class:`~reconphys.capture.Observation`), and, separately, the sample's truth (its placed asset:
ground-truth geometry and initial state, an upper bound; and its attributes)."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

from torch import Tensor

from ..assets.asset import Asset
from ..capture import Observation, load_observation
from ..capture.calibrate import FALL_FIT_PX, SEGMENTER_FALL_FIT_PX
from ..capture.masks import read_mask_folder
from ..capture.observation import stored_observation
from ..errors import InputError
from ..physics import ATTRIBUTES


@dataclass
class SampleTruth:
    """What a dataset knows about one sample and a recording does not."""

    root: str  # the dataset folder
    id: str  # the sample id
    view: int
    asset: Asset  # the placed object with its true attributes and initial velocity
    attributes: dict[str, float]  # the true attributes (ATTRIBUTES)


def is_dataset(path: str | os.PathLike) -> bool:
    """True for a dataset folder written by ``make-data`` (it has a manifest.json)."""
    path = Path(path)
    return path.is_dir() and (path / "manifest.json").is_file()


def load_sample(
    root: str | os.PathLike,
    sample: str | None,
    view: int = 0,
    masks: str | os.PathLike | None = None,  # folder of mask images of the view's frames
) -> tuple[Observation, SampleTruth]:
    """The stored frames of ``sample``'s ``view`` (black backdrop, ground z = 0) and its truth;
    the object's masks from ``masks`` when given (one image per stored frame), else from the
    black backdrop (the plain look) or the mask segmenter (the realistic look)."""
    from ..data.dataset import DropDataset
    from ..data.storage import read_manifest

    root = Path(root)
    if sample is None:
        raise InputError("a dataset folder: give the sample with --sample ID", source=str(root))
    if not 0 <= view < 4:
        raise InputError(f"expected 0–3, got {view}", field="--view")
    read_manifest(root)  # a clear error for a folder that is not a dataset
    dataset = DropDataset(root, views=[view], allow_incomplete=True, verify=False)
    index = dataset.index_of(sample)
    item = dataset[index]
    frames = item["frames"][0].float()
    found, mask_source, rating = None, None, None  # found: [T, H, W] masks (None: the backdrop)
    fit_px = FALL_FIT_PX
    if masks is not None:  # a segmentation tool's masks, as for a recording
        found = read_mask_folder(masks, *frames.shape[:3])
        mask_source = f"mask folder {masks}"
    elif dataset.settings.scene == "realistic":  # as a recording: no stored mask is used
        found, rating = segment_frames(frames)
        mask_source = "mask segmenter and the clip's own colours (realistic scene)"
        fit_px = SEGMENTER_FALL_FIT_PX
    observation = stored_observation(
        frames,
        item["K"][0],
        item["world_to_cam"][0],
        dataset.settings.frame_dt,
        f"{root} sample {sample} view {view} (stored frames)",
        masks=found,
        mask_source=mask_source,
        fall_fit_px=fit_px,
        mask_rating=rating,
    )
    truth = SampleTruth(
        root=str(root),
        id=sample,
        view=view,
        asset=dataset.asset(index),
        attributes=dict(zip(ATTRIBUTES, item["attributes"].tolist(), strict=True)),
    )
    return observation, truth


def load_input(
    input: str | os.PathLike,
    *,
    masks: str | os.PathLike | None = None,
    background: str | os.PathLike | None = None,
    camera: str | os.PathLike | None = None,
    fps: float | None = None,
    frame_dt: float = 0.03,
    fov_deg: float | None = None,  # vertical field of view when the camera is estimated
    touch: str | None = None,  # how the object meets the ground, when the camera is estimated
    # (calibrate.TOUCHES; None: "soft")
    drop_height: float | None = None,  # metres: frame 0's lowest point above the ground, known
    sample: str | None = None,  # dataset input: the sample id
    view: int = 0,  # dataset input: the view
    start: float | str = 0.0,  # seconds into a recording: its release (frame 0), or "auto"
    end: float | None = None,  # seconds into a recording: the frames after it are dropped
    min_frames: int = 0,  # a recording with fewer (after resampling) is refused at once
) -> tuple[Observation, SampleTruth | None]:
    """INPUT (a video, a frame folder, or a dataset folder with ``sample``) → the observation,
    and the sample's truth for a dataset input (None otherwise). Raises InputError, also for
    ``background``, ``camera``, ``fps``, ``fov_deg``, ``touch``, ``drop_height``, ``start`` or
    ``end`` given with a dataset sample (its camera and frame rate are stored): refused, not
    dropped."""
    path = Path(input)
    if not path.exists():
        raise InputError("not found", source=str(path))
    if is_dataset(path):
        given = {
            "--start/--end": start != 0.0 or end is not None,
            "--background": background is not None,
            "--camera": camera is not None,
            "--fps": fps is not None,
            "--fov": fov_deg is not None,
            "--touch": touch is not None,
            "--drop-height": drop_height is not None,
        }
        named = [name for name, used in given.items() if used]
        if named:
            raise InputError(
                f"{', '.join(named)} {'is' if len(named) == 1 else 'are'} for recordings, not "
                "dataset samples (a sample's camera and frame rate are stored with it)",
                source=str(path),
            )
        return load_sample(path, sample, view, masks)
    if sample is not None:
        raise InputError("--sample is for dataset folders (with manifest.json)", source=str(path))
    observation = load_observation(
        path,
        masks=masks,
        background=background,
        camera=camera,
        fps=fps,
        frame_dt=frame_dt,
        fov_deg=fov_deg,
        touch=touch or "soft",
        drop_height=drop_height,
        start=start,
        end=end,
        segment=segment_frames,
        min_frames=min_frames,
    )
    return observation, None


@functools.cache
def _segmenter():
    from ..models.mask_segmenter import load_mask_segmenter

    return load_mask_segmenter()


def segment_frames(frames: Tensor) -> tuple[Tensor, dict]:  # [T, H, W, 3] in [0, 1]
    """The object's masks [T, H, W] in {0, 1} by the shipped mask segmenter and how sure they are
    (models/mask_segmenter.py: rated_segment_clip, mask_rating)."""
    from ..models.mask_segmenter import rated_segment_clip

    return rated_segment_clip(_segmenter(), frames)
