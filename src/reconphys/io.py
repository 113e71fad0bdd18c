"""Files on disk: atomic writes with one permission rule, and validated JSON / NPZ reads.

Every writer of the package goes through :func:`atomic_file` or :func:`atomic_folder`: the
output is assembled under a hidden name beside its target and renamed into place only when
complete, so a failed or killed write leaves no partial output and the previous one intact.
Outputs get the usual permissions whatever wrote them: files ``0o666 & ~umask``, folders
``0o777 & ~umask`` (``tempfile`` would give 0600 / 0700).

Readers raise :class:`~reconphys.errors.InputError` with a one-line message naming the file and,
when known, the field.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
import threading
import zipfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import InputError

_UMASK_LOCK = threading.Lock()


def umask() -> int:
    """The process umask, read without changing it for other threads (Linux: /proc)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:  # elsewhere: set and restore at once (other threads may see it briefly)
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """Permissions of a written file: ``0o666 & ~umask``."""
    return 0o666 & ~umask()


def folder_mode() -> int:
    """Permissions of a written folder: ``0o777 & ~umask``."""
    return 0o777 & ~umask()


def _token() -> str:
    return f"{os.getpid()}-{secrets.token_hex(4)}"


def check_new_output(path: str | os.PathLike, overwrite: bool, field: str | None = None) -> Path:
    """``path`` as a Path; InputError naming it (and ``field``, e.g. an option, when given) if it
    exists and ``overwrite`` is false."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", str(path), field)
    return path


@contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` to write to; renamed over ``path`` on success.

    The temporary name keeps ``path``'s suffix (``.{stem}.<token>{suffix}``), so writers that
    pick a format by extension (ffmpeg, ``np.savez``) behave as for ``path``. On any error the
    temporary file is removed and ``path`` is left as it was. The parent folder is created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{_token()}{path.suffix}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        yield tmp
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_folder(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield an empty staging folder beside ``path``; swapped in for ``path`` on success.

    The staging folder is ``.{name}.staging-<token>`` (:func:`remove_stale_staging` removes the
    ones a killed run left). An existing ``path`` is refused (InputError) unless ``overwrite``;
    with it, the old folder is moved aside, the new one renamed in, and only then the old one
    deleted. On any error the staging folder is removed and ``path`` is left as it was.
    """
    path = Path(path)
    check_new_output(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_name(f".{path.name}.staging-{_token()}")
    old = path.with_name(f".{path.name}.old-{_token()}")
    try:
        staging.mkdir()
        yield staging
        os.chmod(staging, folder_mode())
        if path.exists():
            os.replace(path, old)
            try:
                os.replace(staging, path)
            except BaseException:
                os.replace(old, path)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(staging, path)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def remove_stale_staging(path: str | os.PathLike) -> None:
    """Remove the staging (and moved-aside) folders a killed :func:`atomic_folder` left for
    ``path``, and temporary files a killed :func:`atomic_file` left."""
    path = Path(path)
    if not path.parent.is_dir():
        return
    for pattern in (f".{path.name}.staging-*", f".{path.name}.old-*"):
        for stale in path.parent.glob(pattern):
            shutil.rmtree(stale, ignore_errors=True)
    for stale in path.parent.glob(f".{path.stem}.*-*{path.suffix}"):  # atomic_file's temporaries
        if stale.is_file():
            stale.unlink(missing_ok=True)


# ----------------------------------------------------------------------------------------------
# reading


def read_json(
    path: str | os.PathLike,
    format: str | None = None,
    version: int | None = None,
    expected: str = "a JSON object",
    kind: type = dict,
) -> dict | list:
    """The JSON value in ``path`` (an object, or a list with ``kind=list``); InputError naming the
    file when it is missing, unreadable, not JSON, not a ``kind`` (``expected`` says what it
    should be), or (when given) has another ``format`` field or ``version``."""
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise InputError("file not found", source=source)
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not valid JSON ({e})", source=source) from None
    except OSError as e:
        raise InputError(f"cannot read ({e.strerror or e})", source=source) from None
    if format is not None and (not isinstance(data, dict) or data.get("format") != format):
        raise InputError(f"expected format {format!r}", source=source, field="format")
    if not isinstance(data, kind):
        raise InputError(f"expected {expected}", source=source)
    if version is not None and data.get("version") != version:
        message = f"version {data.get('version')!r} is not supported (expected {version})"
        raise InputError(message, source, "version")
    return data


# A field of an .npz: dtype kind ('f' float, 'i' integer) and shape (None = any size).
FieldSpec = tuple[str, tuple[int | None, ...]]


def read_npz(
    path: str | os.PathLike,
    names: tuple[str, ...] | Mapping[str, FieldSpec] | None = None,
) -> dict[str, np.ndarray]:
    """The arrays of an .npz file (only ``names`` when given); InputError naming the file, and
    the field when one is missing. With ``{name: (kind, shape)}`` each array is also checked
    (see :func:`check_array`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", source=str(path))
    try:
        with np.load(path, allow_pickle=False) as data:
            wanted = data.files if names is None else list(names)
            arrays = {n: data[n] for n in wanted if n in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(f"not a readable .npz file ({e})", source=str(path)) from None
    missing = [n for n in wanted if n not in arrays]
    if missing:
        raise InputError("missing", source=str(path), field=missing[0])
    if isinstance(names, Mapping):
        for name, (kind, shape) in names.items():
            check_array(arrays, path, name, kind, shape)
    return arrays


def check_array(
    data: Mapping[str, np.ndarray],
    path: str | os.PathLike,
    name: str,
    kind: str,
    shape: tuple[int | None, ...],
) -> np.ndarray:
    """``data[name]``, checked: dtype kind ('f' float, 'i' integer), shape (None = any size),
    finite when floating point; InputError naming ``path`` and ``name`` otherwise."""
    source = str(path)
    if name not in data:
        raise InputError("missing", source=source, field=name)
    a = data[name]
    ok_kind = a.dtype.kind == "f" if kind == "f" else a.dtype.kind in "iu"
    if not ok_kind:
        expected = "floating point" if kind == "f" else "integer"
        raise InputError(f"dtype {a.dtype}, expected {expected}", source=source, field=name)
    if a.ndim != len(shape) or any(
        s is not None and s != n for s, n in zip(shape, a.shape, strict=False)
    ):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise InputError(f"shape {list(a.shape)}, expected {want}", source=source, field=name)
    if kind == "f" and not np.isfinite(a).all():
        raise InputError("contains NaN or inf", source=source, field=name)
    return a


def check_number(
    data: Mapping, path: str | os.PathLike, name: str, low=-math.inf, high=math.inf, integer=False
) -> float | int:
    """``data[name]`` as a finite number in ``[low, high]`` (an int when ``integer``);
    InputError naming ``path`` and ``name`` otherwise."""
    source = str(path)
    if name not in data:
        raise InputError("missing", source=source, field=name)
    value = data[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"expected a number, got {value!r}", source=source, field=name)
    if integer and int(value) != value:
        raise InputError(f"expected an integer, got {value!r}", source=source, field=name)
    if not (math.isfinite(value) and low <= value <= high):
        raise InputError(f"{value!r} is outside [{low}, {high}]", source=source, field=name)
    return int(value) if integer else float(value)
