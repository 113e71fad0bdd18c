"""Synthetic dataset pipeline (docs/design.md#attribute-ranges, docs/design.md#synthetic-dataset):
objects → Gaussians → sampled physics → 30-frame, 4-view drop videos, written resumably
(``make-data``) or generated on the fly.

- :mod:`.settings`  what to generate (and the presets)
- :mod:`.sources`   procedural shapes, mesh folders, pybullet meshes, :mod:`.objaverse`
- :mod:`.plan`      which objects and samples, splits by object, shards
- :mod:`.sampling`  attribute / orientation / velocity / drop-height distributions
- :mod:`.objects`   canonical objects and the per-sample assets placed from them
- :mod:`.generate`  one sample in memory (simulate + render)
- :mod:`.storage`   the folder layout, atomic writes, the manifest
- :mod:`.make`      the ``make-data`` run: resume, workers, shards, merge
- :mod:`.dataset`   PyTorch datasets (folder, on the fly)
- :mod:`.show`      summary table and contact sheet
"""

from .dataset import DropDataset, GeneratedDropDataset
from .make import make_dataset, merge_shards
from .settings import PRESETS, DataSettings, make_settings

__all__ = [
    "PRESETS",
    "DataSettings",
    "DropDataset",
    "GeneratedDropDataset",
    "make_dataset",
    "make_settings",
    "merge_shards",
]
