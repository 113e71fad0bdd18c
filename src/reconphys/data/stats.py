"""Dataset statistics measured without rendering: when the planned samples touch the ground.

Used to document and check the contact-frame distribution (docs/dataset.md) over many samples
cheaply: the objects are built and the samples simulated exactly as ``make-data`` does, but
nothing is rendered or written.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch

from .objects import build_object, place, sample_asset
from .plan import plan_objects, plan_samples
from .sampling import contact_frame, draw_sample
from .settings import DataSettings
from .sources import open_source


def simulated_contact_frames(
    settings: DataSettings,
    device: str = "cpu",
) -> Iterator[tuple[str, int]]:
    """Yield ``(sample id, first contact frame)`` for every planned sample (−1: no contact)."""
    source = open_source(settings.source, settings)
    objects = plan_objects(settings, source)
    current = None
    for planned in plan_samples(settings, objects):
        if current is None or current.id != planned.object.ref.id:
            gaussians = source.load(planned.object.ref, settings)
            current = build_object(
                planned.object.ref.id, planned.object.key, gaussians, settings, {}
            )
        spec = draw_sample(settings, current.id, planned.index)
        asset = sample_asset(current, spec, place(current, spec), settings)
        trajectory = asset.simulate(settings.num_frames - 1, torch.device(device))
        yield planned.id, contact_frame(trajectory.x[0].cpu().numpy())
