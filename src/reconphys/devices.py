"""Device names → ``torch.device``: the one resolver of the ``--device`` options, ``make-data``
and ``train.device``."""

from __future__ import annotations

import torch

from .errors import InputError
from .names import DEVICES


def resolve_device(
    name: str,  # "auto", "cpu", "cuda" or "cuda:N"
    local_rank: int | None = None,  # this process's GPU under torchrun (DDP); None: one process
    field: str = "--device",  # the option named in errors
) -> torch.device:
    """ "auto" → CUDA when available, else CPU; "cuda" without a GPU is a user error.

    With ``local_rank`` (a torchrun worker) a CUDA device becomes ``cuda:LOCAL_RANK``.
    """
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name not in DEVICES and not name.startswith("cuda:"):
        raise InputError(
            f"expected {', '.join(DEVICES[:-1])} or {DEVICES[-1]}, got {name!r}", field=field
        )
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("CUDA was asked for but no CUDA device is available", field=field)
    if name.startswith("cuda") and local_rank is not None:
        name = f"cuda:{local_rank}"
    return torch.device(name)
