"""The optional-dependency checks: one cached answer each, agreeing with an import attempt."""

from __future__ import annotations

import importlib

import pytest

from reconphys import _optional


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
    except Exception:
        return False
    return True


@pytest.mark.parametrize(
    "check, module",
    [
        (_optional.numba_available, "numba"),
        (_optional.triton_available, "triton.language"),
        (_optional.gsplat_available, "gsplat"),
    ],
)
def test_checks_agree_with_an_import_and_are_cached(check, module):
    assert check() is _importable(module)
    assert check.cache_info().currsize == 1
