"""``make-data``: generate a dataset folder, resumably, with worker processes and shards.

The run is idempotent: it plans every object and sample from the settings, skips those already
complete on disk (a killed run therefore continues where it stopped), builds the missing canonical
objects, then the missing samples, and rewrites the manifest atomically after each sample
(``"complete": false`` until the last one). Sharded runs (``shard=(I, N)``) own every N-th object
and write ``manifest.shard-I-of-N.json``; :func:`merge_shards` checks and joins them.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from ..devices import resolve_device
from ..errors import InputError
from ..io import read_json, remove_stale_staging
from ..threads import set_cpu_threads
from .generate import generate_sample
from .objects import CanonicalObject, build_object
from .plan import PlannedObject, PlannedSample, in_shard, plan_objects, plan_samples
from .settings import DataSettings
from .sources import open_source
from .storage import (
    MANIFEST,
    OBJECT_FORMAT,
    VERSION,
    make_manifest,
    manifest_entry,
    object_is_complete,
    read_manifest,
    read_object,
    read_sample_meta,
    sample_is_complete,
    shard_manifest_name,
    write_manifest,
    write_object,
    write_sample,
)


@dataclass
class MakeReport:
    manifest: dict
    generated: int  # samples written by this run
    skipped: int  # samples already complete on disk
    seconds: float


def _check_settings(root: Path, name: str, settings: DataSettings) -> None:
    """Refuse to mix settings in one folder (resume needs the same ones)."""
    if not (root / name).is_file():
        return
    existing = read_manifest(root, name)["parsed_settings"]
    if existing != settings:
        old, new = existing.to_dict(), settings.to_dict()
        key = next(k for k in new if old.get(k) != new.get(k))
        raise InputError(
            f"holds a dataset made with other settings ({key}: {old.get(key)!r} there, "
            f"{new.get(key)!r} now); resume with the same flags or choose another --out",
            source=str(root),
        )


# --- work done in worker processes (or in-process with workers=1) ---------------------------

_worker: dict = {}  # per-process context: set once by _init_worker, read by the tasks


def _init_worker(settings, source, root, device, threads: int | None) -> None:
    """Set up a worker process (``threads=None``: the calling process itself, left as it is)."""
    if threads is not None:
        set_cpu_threads(threads)
        # Settling objects drive velocities into float32 denormals, very slow on CPUs.
        torch.set_flush_denormal(True)
    _worker.update(settings=settings, source=source, root=root, device=device, cache=None)


def _object_task(planned: PlannedObject) -> str:
    settings, source, root = _worker["settings"], _worker["source"], _worker["root"]
    gaussians = source.load(planned.ref, settings)
    obj = build_object(
        planned.ref.id, planned.key, gaussians, settings, source.describe(planned.ref)
    )
    write_object(root, obj, settings)
    return planned.key


def _load_object(key: str) -> CanonicalObject:
    cache = _worker.get("cache")
    if cache is None or cache.key != key:
        cache = read_object(_worker["root"] / "objects" / key)
        _worker["cache"] = cache
    return cache


def _sample_task(planned: PlannedSample) -> dict:
    settings, root, device = _worker["settings"], _worker["root"], _worker["device"]
    obj = _load_object(planned.object.key)
    sample = generate_sample(obj, planned.index, settings, device)
    return write_sample(root, planned, sample, settings, torch.device(device).type)


def _run(tasks, function, workers: int, initargs: tuple, progress: str | None):
    """Yield ``function(task)`` results in completion order, in-process or in a spawn pool."""
    from tqdm.auto import tqdm

    bar = tqdm(total=len(tasks), desc=progress, unit="item", disable=progress is None)
    try:
        if workers <= 1 or len(tasks) <= 1:
            _init_worker(*initargs[:4], None)
            for task in tasks:
                yield function(task)
                bar.update()
            return
        context = multiprocessing.get_context("spawn")
        with context.Pool(min(workers, len(tasks)), _init_worker, initargs) as pool:
            for result in pool.imap_unordered(function, tasks):
                yield result
                bar.update()
    finally:
        bar.close()


def default_workers(device: str) -> int:
    """One process per CPU core on the CPU (each with one thread); one on a GPU."""
    return 1 if device.startswith("cuda") else max(1, os.cpu_count() or 1)


def make_dataset(
    settings: DataSettings,
    out: str | os.PathLike,
    workers: int | None = 1,
    device: str = "cpu",
    shard: tuple[int, int] | None = None,
    objaverse_root: str | os.PathLike | None = None,
    download: bool = False,
    progress: bool = False,
    on_sample: Callable[[dict], None] | None = None,
) -> MakeReport:
    """Generate (or finish) the dataset of ``settings`` in ``out``; see the module docstring.

    ``workers``: processes (``None`` or 0: :func:`default_workers`); with more than one, each
    uses ``cpu_count // workers`` torch threads. ``on_sample(entry)`` is called after each sample
    is written (progress reporting, tests).
    """
    started = time.perf_counter()
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise InputError("exists and is not a folder", source=str(root))
    device = str(resolve_device(device))
    workers = default_workers(device) if workers in (None, 0) else workers
    if workers < 1:
        raise InputError(f"must be ≥ 0 (0: automatic), got {workers}", field="--workers")
    manifest_name = MANIFEST if shard is None else shard_manifest_name(shard)
    _check_settings(root, manifest_name, settings)
    if shard is not None:
        _check_settings(root, MANIFEST, settings)
    source = open_source(settings.source, settings, objaverse_root, download)
    objects = [o for o in plan_objects(settings, source) if in_shard(o, shard)]
    samples = plan_samples(settings, objects)
    try:
        root.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(root / manifest_name)  # a manifest write a killed run left half-done
    except OSError as e:
        raise InputError(f"cannot create ({e.strerror})", source=str(root)) from None
    for obj in objects:
        remove_stale_staging(root / "objects" / obj.key)
    for planned in samples:
        remove_stale_staging(root / "samples" / planned.id)

    entries: dict[str, dict] = {}
    for planned in samples:
        if sample_is_complete(root, planned.id, settings):
            entries[planned.id] = manifest_entry(read_sample_meta(root, planned.id))
    skipped = len(entries)

    def object_entries() -> list[dict]:
        listed = []
        for obj in objects:
            path = root / "objects" / obj.key / "object.json"
            description = (
                read_json(path, OBJECT_FORMAT, VERSION)["description"] if path.is_file() else {}
            )
            listed.append(
                {
                    "id": obj.ref.id,
                    "key": obj.key,
                    "index": obj.index,
                    "split": obj.split,
                    "dir": f"objects/{obj.key}",
                    "description": description,
                }
            )
        return listed

    def save_manifest(listed_objects: list[dict]) -> dict:
        ordered = [entries[p.id] for p in samples if p.id in entries]
        done = len(ordered) == len(samples)
        manifest = make_manifest(settings, listed_objects, ordered, done, shard)
        write_manifest(root, manifest, manifest_name)
        return manifest

    manifest = save_manifest([])
    initargs = (settings, source, root, device, max(1, (os.cpu_count() or 1) // workers))
    todo_objects = [o for o in objects if not object_is_complete(root, o.key, settings)]
    for _ in _run(todo_objects, _object_task, workers, initargs, "objects" if progress else None):
        pass
    listed_objects = object_entries()
    manifest = save_manifest(listed_objects)
    todo = [p for p in samples if p.id not in entries]
    for entry in _run(todo, _sample_task, workers, initargs, "samples" if progress else None):
        entries[entry["id"]] = entry
        manifest = save_manifest(listed_objects)
        if on_sample is not None:
            on_sample(entry)
    return MakeReport(manifest, len(todo), skipped, time.perf_counter() - started)


# --- merging shards ------------------------------------------------------------------------


def _copy_folder(source: Path, target: Path) -> None:
    """Copy ``source`` to ``target`` through a staging folder (atomic appearance)."""
    from .storage import staged_folder

    with staged_folder(target) as staging:
        shutil.rmtree(staging)
        shutil.copytree(source, staging)


def merge_shards(out: str | os.PathLike, sources: list[str | os.PathLike] = ()) -> dict:
    """Join the shard manifests found in ``out`` and ``sources`` into ``out/manifest.json``.

    Checks: same settings and package version everywhere, shards 0..N−1 each present once and
    complete, every planned object and sample present once and complete on disk. Folders of
    shards that live elsewhere are copied into ``out``. The shard manifests in ``out`` are removed
    after the joined manifest is written; the result equals an unsharded run's manifest.
    """
    root = Path(out)
    folders = [root, *[Path(s) for s in sources if Path(s).resolve() != root.resolve()]]
    found: dict[int, tuple[Path, dict]] = {}
    counts = set()
    for folder in folders:
        if not folder.is_dir():
            raise InputError("folder not found", source=str(folder))
        for path in sorted(folder.glob("manifest.shard-*-of-*.json")):
            manifest = read_manifest(folder, path.name)
            index, count = manifest.get("shard") or (None, None)
            if index is None:
                raise InputError("has no shard field", source=str(path))
            if index in found:
                raise InputError(f"shard {index} appears twice", source=str(path))
            found[index] = (folder, manifest)
            counts.add(count)
    if not found:
        raise InputError("no shard manifests (manifest.shard-I-of-N.json) found", str(root))
    if len(counts) != 1:
        raise InputError(f"shards of different splittings: N = {sorted(counts)}", str(root))
    count = counts.pop()
    missing = sorted(set(range(count)) - set(found))
    if missing:
        raise InputError(f"shard {missing[0]}/{count} is missing", source=str(root))
    first = found[0][1]
    for index, (folder, manifest) in sorted(found.items()):
        where = str(folder / shard_manifest_name((index, count)))
        if manifest["settings"] != first["settings"]:
            raise InputError("settings differ from shard 0's", source=where, field="settings")
        if manifest.get("package_version") != first.get("package_version"):
            raise InputError("made by another reconphys version", where, "package_version")
        if not manifest["complete"]:
            raise InputError("shard is not complete: rerun its make-data", source=where)
    settings = first["parsed_settings"]
    objects = sorted((o for _, m in found.values() for o in m["objects"]), key=lambda o: o["index"])
    total = settings.objects + settings.test_objects
    if [o["index"] for o in objects] != list(range(total)):
        raise InputError(f"shards do not hold objects 0..{total - 1} exactly once", str(root))
    order = {o["id"]: o["index"] for o in objects}
    samples = sorted(
        (s for _, m in found.values() for s in m["samples"]),
        key=lambda s: (order[s["object"]], s["index"]),
    )
    for obj in objects:
        have = sum(s["object"] == obj["id"] for s in samples)
        if have != settings.samples_for(obj["split"]):
            raise InputError(f"object {obj['id']} has {have} samples", source=str(root))
    for folder, manifest in found.values():
        for obj in manifest["objects"]:
            _bring(
                folder, root, obj["dir"], "object.json", settings, object_is_complete, obj["key"]
            )
        for sample in manifest["samples"]:
            _bring(
                folder,
                root,
                sample["dir"],
                "sample.json",
                settings,
                sample_is_complete,
                sample["id"],
            )
    merged = make_manifest(settings, objects, samples, True, None)
    write_manifest(root, merged)
    for index in range(count):
        (root / shard_manifest_name((index, count))).unlink(missing_ok=True)
    return merged


def _bring(folder: Path, root: Path, relative: str, meta: str, settings, is_complete, name) -> None:
    """Make sure the complete folder ``relative`` is in ``root`` (copied from ``folder``)."""
    kind = relative.split("/")[0]
    if folder != root and not is_complete(root, name, settings):
        if not is_complete(folder, name, settings):
            raise InputError(f"incomplete {kind[:-1]} folder", source=str(folder / relative))
        _copy_folder(folder / relative, root / relative)
    if not is_complete(root, name, settings):
        raise InputError(f"incomplete {kind[:-1]} folder", source=str(root / relative))
