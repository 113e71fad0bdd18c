"""The dataset folder on disk: objects, samples and the manifest — atomic and reproducible.

Layout (docs/dataset.md has the full description)::

    DIR/manifest.json                  the samples a reader may use (+ settings, seed, version)
    DIR/objects/<key>/                 canonical object: gaussians.ply, anchors.npz, binding.npz,
                                       object.json
    DIR/samples/<id>/                  sample.json, frames.npz, trajectory.npz, view_<v>.mp4

Every object and sample folder is assembled under a hidden staging name beside its target and
renamed into place (:func:`reconphys.io.atomic_folder`), so a folder either is complete or does
not exist. The manifest is replaced
atomically and lists only complete samples. Files are byte-reproducible: .npz members carry a
fixed timestamp and JSON is written with sorted keys.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path, PurePosixPath

import numpy as np
import torch

from .. import __version__
from ..assets.ply import read_ply, write_ply
from ..errors import InputError
from ..io import atomic_file, atomic_folder, read_json, read_npz
from .generate import GeneratedSample
from .objects import CanonicalObject
from .plan import PlannedSample
from .settings import DataSettings

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "reconphys.dataset"
OBJECT_FORMAT = "reconphys.object"
SAMPLE_FORMAT = "reconphys.sample"
VERSION = 1
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def shard_manifest_name(shard: tuple[int, int]) -> str:
    return f"manifest.shard-{shard[0]:04d}-of-{shard[1]:04d}.json"


# ----------------------------------------------------------------------------------------------
# files


def write_npz(path: Path, arrays: dict[str, np.ndarray], compress: bool = False) -> None:
    """Like ``np.savez[_compressed]`` but byte-reproducible (fixed member timestamps)."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=method) as archive:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with archive.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(array), allow_pickle=False)


def write_json(path: Path, data: dict) -> None:
    """JSON with sorted keys, replaced atomically."""
    with atomic_file(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


@contextmanager
def staged_folder(target: Path) -> Iterator[Path]:
    """Yield a fresh hidden folder beside ``target``; on success it replaces ``target`` at once.

    On any error the staging folder is removed and ``target`` is left as it was. OSErrors
    (read-only or full disk) become InputError naming the target.
    """
    try:
        with atomic_folder(target, overwrite=True) as staging:
            yield staging
    except OSError as e:
        reason = e.strerror or str(e)
        raise InputError(
            f"cannot write ({reason}); the dataset is unchanged", str(target)
        ) from None


def _file_sizes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in sorted(folder.iterdir()) if p.is_file()}


def _is_complete(folder: Path, meta_name: str, fmt: str, fingerprint: str) -> bool:
    """Complete = the metadata file parses, carries these settings, and lists every file with
    its size (the metadata is written last, the folder renamed into place after it)."""
    try:
        meta = read_json(folder / meta_name, fmt, VERSION)
    except InputError:
        return False
    if meta.get("settings") != fingerprint:
        return False
    files = meta.get("files")
    if not isinstance(files, dict):
        return False
    return all(
        (folder / n).is_file() and (folder / n).stat().st_size == s for n, s in files.items()
    )


# ----------------------------------------------------------------------------------------------
# objects


def write_object(root: Path, obj: CanonicalObject, settings: DataSettings) -> Path:
    target = root / "objects" / obj.key
    with staged_folder(target) as folder:
        write_ply(folder / "gaussians.ply", obj.gaussians)
        write_npz(
            folder / "anchors.npz",
            {
                "x0": obj.anchors.numpy().astype(np.float32),
                "springs": obj.springs.numpy().astype(np.int64),
                "rest_length": obj.rest_length.numpy().astype(np.float32),
            },
        )
        write_npz(
            folder / "binding.npz",
            {
                "index": obj.binding_index.numpy().astype(np.int64),
                "weight": obj.binding_weight.numpy().astype(np.float32),
            },
        )
        files = _file_sizes(folder)
        meta = {
            "format": OBJECT_FORMAT,
            "version": VERSION,
            "id": obj.id,
            "key": obj.key,
            "description": obj.description,
            "settings": settings.fingerprint(),
            "num_gaussians": obj.gaussians.num_gaussians,
            "num_anchors": int(obj.anchors.shape[0]),
            "num_springs": int(obj.springs.shape[0]),
            "files": files,
        }
        write_json(folder / "object.json", meta)
    return target


def object_is_complete(root: Path, key: str, settings: DataSettings) -> bool:
    return _is_complete(
        root / "objects" / key, "object.json", OBJECT_FORMAT, settings.fingerprint()
    )


def read_object(folder: Path) -> CanonicalObject:
    """A canonical object folder, validated (shapes, dtypes, index ranges, finiteness)."""
    meta = read_json(folder / "object.json", OBJECT_FORMAT, VERSION)
    gaussians = read_ply(folder / "gaussians.ply")
    anchors = read_npz(folder / "anchors.npz", ("x0", "springs", "rest_length"))
    binding = read_npz(folder / "binding.npz", ("index", "weight"))
    x0, springs, rest = anchors["x0"], anchors["springs"], anchors["rest_length"]
    index, weight = binding["index"], binding["weight"]
    where = str(folder / "anchors.npz")
    if x0.ndim != 2 or x0.shape[1] != 3 or not np.isfinite(x0).all():
        raise InputError(f"expected finite [N_A, 3], got {list(x0.shape)}", where, "x0")
    if springs.ndim != 2 or springs.shape[1] != 2 or springs.dtype.kind not in "iu":
        raise InputError("expected integer [E, 2]", where, "springs")
    if springs.size and (springs.min() < 0 or springs.max() >= len(x0)):
        raise InputError(f"indices outside [0, {len(x0)})", where, "springs")
    if rest.shape != (len(springs),) or not (rest > 0).all():
        raise InputError("expected [E] positive lengths", where, "rest_length")
    where = str(folder / "binding.npz")
    if index.ndim != 2 or index.shape[0] != gaussians.num_gaussians or index.dtype.kind not in "iu":
        raise InputError(f"expected integer [{gaussians.num_gaussians}, n_b]", where, "index")
    if index.size and (index.min() < 0 or index.max() >= len(x0)):
        raise InputError(f"indices outside [0, {len(x0)})", where, "index")
    if weight.shape != index.shape or not np.isfinite(weight).all():
        raise InputError(f"expected finite {list(index.shape)}", where, "weight")
    return CanonicalObject(
        id=str(meta["id"]),
        key=str(meta["key"]),
        description=meta.get("description", {}),
        gaussians=gaussians,
        anchors=torch.from_numpy(x0.astype(np.float32)),
        springs=torch.from_numpy(springs.astype(np.int64)),
        rest_length=torch.from_numpy(rest.astype(np.float32)),
        binding_index=torch.from_numpy(index.astype(np.int64)),
        binding_weight=torch.from_numpy(weight.astype(np.float32)),
    )


# ----------------------------------------------------------------------------------------------
# samples


def video_name(view: int) -> str:
    return f"view_{view}.mp4"


def write_sample(
    root: Path,
    planned: PlannedSample,
    sample: GeneratedSample,
    settings: DataSettings,
    device: str,
) -> dict:
    """Write one sample folder atomically; returns its manifest entry."""
    from ..render.video import write_mp4

    target = root / "samples" / planned.id
    with staged_folder(target) as folder:
        write_npz(
            folder / "frames.npz",
            {f"view_{v}": sample.frames[v] for v in range(len(sample.frames))},
            compress=True,
        )
        write_npz(
            folder / "trajectory.npz",
            {
                "anchors": sample.anchors,
                "velocities": sample.velocities,
                "substeps_used": np.int64(sample.substeps),
                "frame_dt": np.float64(settings.frame_dt),
            },
        )
        if sample.masks is not None:  # the realistic look: true masks and the encoded videos
            write_npz(
                folder / "masks.npz",
                {f"view_{v}": sample.masks[v] for v in range(len(sample.masks))},
                compress=True,
            )
        for v in range(len(sample.frames)):
            if sample.videos is not None:
                (folder / video_name(v)).write_bytes(sample.videos[v])  # the folder is staged
            else:
                write_mp4(folder / video_name(v), sample.frames[v], fps=1.0 / settings.frame_dt)
        spec, placement, cameras = sample.spec, sample.placement, sample.cameras
        meta = {
            "format": SAMPLE_FORMAT,
            "version": VERSION,
            "id": planned.id,
            "object": planned.object.ref.id,
            "object_dir": f"objects/{planned.object.key}",
            "split": planned.split,
            "index": planned.index,
            "settings": settings.fingerprint(),
            "device": device,
            "attributes": spec.attributes,
            "initial_state": {
                "rotation": placement.rotation.tolist(),
                "translation": placement.translation.tolist(),
                "launch": spec.launch,
                "linear_velocity": list(spec.linear_velocity),
                "angular_velocity": list(spec.angular_velocity),
                "drop_height": placement.drop_height,
                "target_contact_frame": spec.target_contact_time / settings.frame_dt,
                "scale": 1.0 if sample.scene is None else sample.scene.size / settings.size,
            },
            "contact_frame": sample.contact_frame,
            "substeps": sample.substeps,
            "num_frames": settings.num_frames,
            "frame_dt": settings.frame_dt,
            "cameras": {
                "width": cameras.width,
                "height": cameras.height,
                "K": cameras.K.double().tolist(),
                "world_to_cam": cameras.world_to_cam.double().tolist(),
            },
            "files": _file_sizes(folder),
        }
        if sample.scene is not None:
            meta["scene"] = sample.scene.to_dict()
        write_json(folder / "sample.json", meta)
    return manifest_entry(meta)


def sample_is_complete(root: Path, sample_id: str, settings: DataSettings) -> bool:
    return _is_complete(
        root / "samples" / sample_id, "sample.json", SAMPLE_FORMAT, settings.fingerprint()
    )


def read_sample_meta(root: Path, sample_id: str) -> dict:
    return read_json(root / "samples" / sample_id / "sample.json", SAMPLE_FORMAT, VERSION)


def manifest_entry(meta: dict) -> dict:
    folder = f"samples/{meta['id']}"
    views = len(meta["cameras"]["K"])
    return {
        "id": meta["id"],
        "object": meta["object"],
        "object_dir": meta["object_dir"],
        "split": meta["split"],
        "index": meta["index"],
        "attributes": meta["attributes"],
        "contact_frame": meta["contact_frame"],
        "dir": folder,
        "frames": f"{folder}/frames.npz",
        "trajectory": f"{folder}/trajectory.npz",
        "videos": [f"{folder}/{video_name(v)}" for v in range(views)],
        **({"masks": f"{folder}/masks.npz"} if "scene" in meta else {}),
    }


# ----------------------------------------------------------------------------------------------
# manifest


def make_manifest(
    settings: DataSettings,
    objects: list[dict],
    samples: list[dict],
    complete: bool,
    shard: tuple[int, int] | None = None,
) -> dict:
    counts = {
        split: {
            "objects": sum(o["split"] == split for o in objects),
            "samples": sum(s["split"] == split for s in samples),
        }
        for split in ("train", "test")
    }
    return {
        "format": MANIFEST_FORMAT,
        "version": VERSION,
        "package_version": __version__,
        "seed": settings.seed,
        "settings": settings.to_dict(),
        "settings_fingerprint": settings.fingerprint(),
        "complete": complete,
        "shard": list(shard) if shard else None,
        "counts": counts,
        "num_views": 4,
        "objects": objects,
        "samples": samples,
    }


def write_manifest(root: Path, manifest: dict, name: str = MANIFEST) -> None:
    try:
        write_json(root / name, manifest)
    except OSError as e:
        raise InputError(f"cannot write ({e.strerror or e})", source=str(root / name)) from None


def read_manifest(root: Path, name: str = MANIFEST) -> dict:
    """The manifest, validated; its ``settings`` parsed back into ``DataSettings``."""
    path = root / name
    if not path.is_file():
        hint = " (an unfinished or sharded run: rerun make-data, or run data merge)"
        raise InputError("file not found" + hint, source=str(path))
    manifest = read_json(path, MANIFEST_FORMAT, VERSION)
    for key in ("settings", "samples", "objects", "complete"):
        if key not in manifest:
            raise InputError("missing", source=str(path), field=key)
    _check_inside(manifest, str(path))
    manifest["parsed_settings"] = DataSettings.from_dict(manifest["settings"], str(path))
    return manifest


# relative to the folder
SAMPLE_PATHS = ("dir", "object_dir", "frames", "trajectory", "videos", "masks")


def _check_inside(manifest: dict, source: str) -> None:
    """Refuse a manifest whose sample or object paths leave the dataset folder (absolute, or
    through ``..``): a dataset reads and writes only below its own root."""
    entries = [("samples", i, e, SAMPLE_PATHS) for i, e in enumerate(manifest["samples"])]
    entries += [("objects", i, e, ("dir",)) for i, e in enumerate(manifest["objects"])]
    for table, index, entry, keys in entries:
        if not isinstance(entry, dict):
            raise InputError("expected an object", source=source, field=f"{table}[{index}]")
        for key in keys:
            values = entry.get(key, [])
            for value in values if isinstance(values, list) else [values]:
                where = f"{table}[{index}].{key}"
                if not isinstance(value, str):
                    raise InputError(f"expected a relative path, got {value!r}", source, where)
                parts = PurePosixPath(value.replace("\\", "/")).parts
                if value.startswith(("/", "\\")) or ":" in value[:3] or ".." in parts:
                    raise InputError(
                        f"{value!r} points outside the dataset folder (paths must be relative, "
                        "without ..)",
                        source,
                        where,
                    )
