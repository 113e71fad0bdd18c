"""What every command shares: the one-line error contract, value checks, option help built from
the package's own name tuples (:mod:`reconphys.names`), and which options were given.

Imports nothing that imports torch: ``reconphys --help`` stays fast.
"""

from __future__ import annotations

import functools
import math

import typer

from ..errors import InputError
from ..names import DEVICES


def user_errors(fn):
    """Turn InputError (and unreadable-input OSErrors) into one line on stderr and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except InputError as e:
            typer.echo(f"error: {e}", err=True)
            raise typer.Exit(2) from None

    return wrapper


def or_list(names) -> str:
    """``("a", "b", "c")`` → ``"a, b or c"``."""
    names = list(names)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


DEVICE_CHOICES = or_list(DEVICES)  # "auto, cpu or cuda": the help of every --device


def check_choice(value: str, choices, name: str) -> None:
    if value not in choices:
        raise InputError(f"expected {or_list(choices)}, got {value!r}", field=name)


def check_positive(value: float, name: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"must be a positive number, got {value}", field=name)


def check_non_negative(value: float, name: str) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"must be a finite number ≥ 0, got {value}", field=name)


def check_resolution(resolution: int) -> None:
    if resolution < 8:
        raise InputError(f"must be ≥ 8 pixels, got {resolution}", field="--resolution")


def given_options(ctx: typer.Context) -> set[str]:
    """Parameter names of the running command that the user gave (command line or environment),
    as opposed to those left at their declared defaults."""
    given = ("COMMANDLINE", "ENVIRONMENT")
    return {name for name in ctx.params if ctx.get_parameter_source(name).name in given}


def command_line(
    ctx: typer.Context, prog: str, names: tuple[str, ...], always: tuple[str, ...], values: dict
) -> str:
    """The running command as a line for a report: ``prog``, then each parameter in ``names``
    (in that order) as ``--flag value`` when it is in ``always`` or differs from the option's
    declared default. ``values`` gives a parameter's text where it is not ``str(value)`` (e.g. a
    normalised list or a formatted number)."""
    params = {p.name: p for p in ctx.command.params}
    words = [prog]
    for name in names:
        value = ctx.params[name]
        if name in always or value != params[name].default:
            words += [params[name].opts[0], str(values.get(name, value))]
    return " ".join(words)
