"""Which objects and samples a dataset holds, with their splits, ids and shards.

The plan is a pure function of the settings and the source's candidate list: the candidates are
shuffled with the dataset seed, the first ``objects`` become the training split and the next
``test_objects`` the test split (splits are by object, never by sample). Shard ``I/N`` owns the
objects whose position in the plan is ``I`` modulo ``N``, with all their samples.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..physics import seed_from_id
from .settings import DataSettings
from .source_base import ObjectRef

SPLITS = ("train", "test")


@dataclass(frozen=True)
class PlannedObject:
    index: int  # position in the dataset's object list
    ref: ObjectRef
    split: str  # "train" or "test"

    @property
    def key(self) -> str:
        """Folder name under ``objects/``: the id when it is a safe name, else slug + hash."""
        return object_key(self.ref.id)


@dataclass(frozen=True)
class PlannedSample:
    object: PlannedObject
    index: int  # attribute sample of the object, 0 ..

    @property
    def id(self) -> str:
        return f"{self.object.key}_s{self.index:02d}"

    @property
    def split(self) -> str:
        return self.object.split


def object_key(object_id: str) -> str:
    if re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,79}", object_id):
        return object_id
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", object_id).strip("._-")[:60] or "object"
    return f"{slug}-{hashlib.sha1(object_id.encode()).hexdigest()[:8]}"


def plan_objects(settings: DataSettings, source) -> list[PlannedObject]:
    """The dataset's objects in order: training objects first, then test objects."""
    total = settings.objects + settings.test_objects
    candidates = source.candidates(total)
    if len(candidates) < total:
        raise InputError(
            f"has {len(candidates)} objects, {total} asked for "
            f"({settings.objects} train + {settings.test_objects} test)",
            source=str(getattr(source, "name", "source")),
        )
    order = np.random.default_rng(seed_from_id(f"select:{settings.seed}")).permutation(
        len(candidates)
    )
    chosen = [candidates[int(i)] for i in order[:total]]
    planned = [
        PlannedObject(i, ref, "train" if i < settings.objects else "test")
        for i, ref in enumerate(chosen)
    ]
    keys = [p.key for p in planned]
    if len(set(keys)) != len(keys):
        raise InputError("two objects map to the same folder name", source=str(source.name))
    return planned


def plan_samples(settings: DataSettings, objects: list[PlannedObject]) -> list[PlannedSample]:
    return [
        PlannedSample(obj, j) for obj in objects for j in range(settings.samples_for(obj.split))
    ]


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """ "I/N" (0 ≤ I < N) → (I, N); None → None."""
    if text is None:
        return None
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text)
    if not match or not int(match[1]) < int(match[2]):
        raise InputError(f"expected I/N with 0 ≤ I < N, got {text!r}", field="--shard")
    return int(match[1]), int(match[2])


def in_shard(obj: PlannedObject, shard: tuple[int, int] | None) -> bool:
    return shard is None or obj.index % shard[1] == shard[0]
