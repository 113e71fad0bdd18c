"""The one device resolver (devices.py)."""

from __future__ import annotations

import pytest
import torch

from reconphys.devices import resolve_device
from reconphys.errors import InputError


def test_resolve_device_names_and_errors():
    assert resolve_device("cpu") == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == expected
    with pytest.raises(InputError, match="--device"):
        resolve_device("tpu")
    with pytest.raises(InputError, match=r"train\.device"):
        resolve_device("gpu", field="train.device")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            resolve_device("cuda", local_rank=0)
    else:
        assert resolve_device("cuda", local_rank=0) == torch.device("cuda:0")
