"""Settings dataclasses from config files and overrides: one loader for every runnable pipeline.

The dataclasses are the source of truth (``train.config.TrainConfig``'s sections,
``train.gaussians.GaussianTrainSettings``, ``data.settings.DataSettings``); this module reads a
``.toml``/``.json`` file into a table, applies ``KEY=VALUE`` overrides (dotted keys for nested
sections; values are TOML literals, or plain text for string fields) and type-checks every value
against the field it sets (int → float, list → tuple). A bad key or value raises
:class:`~reconphys.errors.InputError` naming the file (``source``) and the key (``field``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path

from .errors import InputError

try:  # Python ≥ 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 without tomli
    try:
        import tomli as tomllib
    except ModuleNotFoundError:
        tomllib = None


def read_table(path: str | os.PathLike) -> dict:
    """The nested table of a .toml or .json config file (InputError naming the file)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("config file not found", source=str(path))
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            if tomllib is None:  # pragma: no cover
                raise InputError("TOML needs Python ≥ 3.11 or tomli; use JSON", str(path))
            with path.open("rb") as f:
                return tomllib.load(f)
        if suffix == ".json":
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise InputError("expected a JSON object of sections", source=str(path))
            return data
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read ({e})", source=str(path)) from None
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON ({e})", source=str(path)) from None
    except Exception as e:  # tomllib.TOMLDecodeError (module may be tomli)
        if tomllib is not None and isinstance(e, tomllib.TOMLDecodeError):
            raise InputError(f"not valid TOML ({e})", source=str(path)) from None
        raise
    raise InputError("expected a .toml or .json file", source=str(path))


def field_types(cls) -> dict:
    """Field name → resolved type hint of a dataclass."""
    return typing.get_type_hints(cls)


def _type_name(hint) -> str:
    if hint is float:
        return "a number"
    if hint is int:
        return "an integer"
    if hint is bool:
        return "true or false"
    if hint is str:
        return "a string"
    if hint is dict:
        return "a table"
    return f"a value of type {getattr(hint, '__name__', hint)}"


def check_type(value, hint, key: str, where: str | None = "config"):
    """``value`` converted to the field type ``hint`` (int → float, list → tuple, a copied dict)
    or InputError naming ``key`` (and ``where``, the file; None for the command line)."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(hint)
        if value is None and type(None) in options:
            return None
        last = None
        for option in options:
            if option is type(None):
                continue
            try:
                return check_type(value, option, key, where)
            except InputError as e:
                last = e
        raise last
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise InputError(f"expected a list, got {value!r}", source=where, field=key)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(check_type(v, args[0], key, where) for v in value)
        if len(value) != len(args):
            raise InputError(f"expected {len(args)} values, got {value!r}", where, key)
        return tuple(check_type(v, a, key, where) for v, a in zip(value, args, strict=True))
    if hint is bool:
        if isinstance(value, bool):
            return value
    elif hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif hint is str:
        if isinstance(value, str):
            return value
    elif hint is dict:
        if isinstance(value, dict):
            return dict(value)
    else:  # pragma: no cover - every field type is handled above
        return value
    raise InputError(f"expected {_type_name(hint)}, got {value!r}", source=where, field=key)


def parse_override(text: str) -> tuple[str, str]:
    """``"optim.lr=3e-4"`` → ``("optim.lr", "3e-4")``."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise InputError("expected KEY=VALUE (e.g. optim.lr=3e-4)", field=text)
    return key, value.strip()


def parse_value(text: str, hint) -> object:
    """An override's text as a value: plain text for string fields, otherwise a TOML literal
    (``3e-4``, ``true``, ``[16, 32]``, ``"text"``), falling back to plain text."""
    if hint is str:
        if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
            return text[1:-1]
        return text
    if tomllib is not None:
        try:
            return tomllib.loads(f"value = {text}")["value"]
        except tomllib.TOMLDecodeError:
            pass
    else:  # pragma: no cover
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            pass
    return text


def _known(owner, hidden: Iterable[str]) -> str:
    names = [f.name for f in dataclasses.fields(owner) if f.name not in hidden]
    if all(dataclasses.is_dataclass(getattr(owner, n, None)) for n in names):
        return "sections: " + ", ".join(names)
    return "known: " + ", ".join(names)


def resolve(root, key: str, where: str | None = "config", hidden: Iterable[str] = ()):
    """The (nested) dataclass instance that holds dotted ``key`` and the field name in it.
    ``hidden`` names fields left out of the "known: ..." list of an unknown-key error."""
    parts = key.split(".")
    owner = root
    for depth, part in enumerate(parts[:-1]):
        names = {f.name for f in dataclasses.fields(owner)}
        if part not in names or not dataclasses.is_dataclass(getattr(owner, part)):
            prefix = ".".join(parts[: depth + 1])
            raise InputError(f"unknown key ({_known(owner, hidden)})", source=where, field=prefix)
        owner = getattr(owner, part)
    if parts[-1] not in {f.name for f in dataclasses.fields(owner)}:
        raise InputError(f"unknown key ({_known(owner, hidden)})", source=where, field=key)
    return owner, parts[-1]


def flatten(table: dict, where: str, is_leaf=lambda dotted: False, prefix: str = ""):
    """Nested sections → ``[(dotted key, value)]``; a table whose dotted key ``is_leaf`` (a
    dict-valued field) is kept whole."""
    if not isinstance(table, dict):
        raise InputError("expected a table of sections", source=where, field=prefix or None)
    items = []
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict) and not is_leaf(dotted):
            items += flatten(value, where, is_leaf, dotted + ".")
        else:
            items.append((dotted, value))
    return items


def checked_values(cls, table: Mapping, where: str | None = "config") -> dict:
    """The entries of a flat ``table`` type-checked against the fields of dataclass ``cls``."""
    hints = field_types(cls)
    values = {}
    for key, value in table.items():
        if key not in hints:
            known = ", ".join(f.name for f in dataclasses.fields(cls))
            raise InputError(f"unknown key (known: {known})", source=where, field=key)
        values[key] = check_type(value, hints[key], key, where)
    return values


def load_settings(cls, *layers: tuple[Mapping, str | None], base=None):
    """An instance of the flat dataclass ``cls``: ``base`` (an instance, e.g. a preset; else the
    field defaults) ← each ``(table, where)`` layer in order, every value type-checked.

    A layer is a config file's table (``where`` = its path) or the options given on the command
    line (``where`` = None). A required field that no layer sets is an InputError.
    """
    values = {}
    for table, where in layers:
        values.update(checked_values(cls, table, where))
    if base is not None:
        return dataclasses.replace(base, **values)
    missing = [
        f.name
        for f in dataclasses.fields(cls)
        if f.name not in values
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise InputError("missing (set it in the config file or as an option)", field=missing[0])
    return cls(**values)
