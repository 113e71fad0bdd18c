"""Scripted, headless interaction: a JSON list of actions driving an
:class:`~reconphys.interact.interaction.Interaction` (or the viewer's session, which is one).

The same controller API as the browser UI, without a browser (tests, batch renders). A script is a
JSON list; each entry is an object with one action::

    [
      {"drop": 0.3},                                   lowest point 0.3 m above the ground, at rest
      {"run": 30},                                     simulate 30 frames (0.03 s each)
      {"set": {"stiffness": 600, "substeps": 40}},     attributes (m, k, d, f) and/or substeps
      {"grab": {"name": "left", "at": "-x"}},          grip the object's extreme point along -x
      {"grab": {"name": "right", "point": [0.2, 0, 0.1]}},   or the point nearest to a position
      {"move": {"grip": "left", "by": [-0.1, 0, 0], "frames": 20}},  move over 20 frames
      {"move": {"grip": "right", "to": [0.3, 0, 0.2], "frames": 20}},
      {"release": "left"},                             or "all"
      {"reset": true}                                  back to the asset's initial state
    ]

``move`` changes the grip's goal linearly over ``frames`` frames (simulating them); without
``frames`` it only sets the goal. Positions are metres in the world frame (z up).

:func:`push_script` writes the script that ``reconphys simulate --push X,Y,Z`` runs.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import torch

from ..errors import InputError
from ..io import read_json
from .interaction import Interaction
from .recording import Recording

AXES = {"+x": (0, 1.0), "-x": (0, -1.0), "+y": (1, 1.0), "-y": (1, -1.0), "+z": (2, 1.0)}
AXES["-z"] = (2, -1.0)
ACTIONS = ("run", "drop", "set", "grab", "move", "release", "reset")
PUSH_MOVE_FRAMES = 10  # frames over which `simulate --push` moves its grip


def load_script(path: str | os.PathLike) -> list[dict]:
    """Read and check the shape of a script file (a JSON list of one-key objects)."""
    return read_json(path, expected="a JSON list of actions", kind=list)


def _vector(value, where: str) -> torch.Tensor:
    try:
        vector = torch.tensor(value, dtype=torch.float32)
    except (TypeError, ValueError):
        vector = None
    if vector is None or vector.shape != (3,) or not bool(torch.isfinite(vector).all()):
        raise InputError(f"expected [x, y, z] in metres, got {value!r}", field=where)
    return vector


def _extreme_point(session: Interaction, axis: str, where: str) -> torch.Tensor:
    if axis not in AXES:
        raise InputError(f"expected one of {list(AXES)}, got {axis!r}", field=where)
    dim, sign = AXES[axis]
    means = session.gaussian_means()
    return means[int(torch.argmax(sign * means[:, dim]))]


def run_script(session: Interaction, steps: list[dict], record: bool = True) -> Recording | None:
    """Apply ``steps`` in order (simulating in the calling thread); with ``record`` returns the
    recording of every frame from the start of the script."""
    if record:
        session.start_recording()
    for number, entry in enumerate(steps):
        where = f"script[{number}]"
        if not isinstance(entry, dict) or len(entry) != 1 or next(iter(entry)) not in ACTIONS:
            raise InputError(f"expected an object with one key of {ACTIONS}", field=where)
        action, value = next(iter(entry.items()))
        where = f"{where}.{action}"
        try:
            _apply(session, action, value, where)
        except InputError as e:
            message = str(e)
            if not message.startswith("script["):
                raise InputError(message, field=where) from None
            raise
    return session.stop_recording() if record else None


def _apply(session: Interaction, action: str, value, where: str) -> None:
    if action == "run":
        if not isinstance(value, int) or value < 0:
            raise InputError(f"expected a frame count ≥ 0, got {value!r}", field=where)
        session.advance(value)
    elif action == "drop":
        if not isinstance(value, int | float):
            raise InputError(f"expected a height in metres, got {value!r}", field=where)
        session.drop(float(value))
    elif action == "reset":
        session.reset()
    elif action == "set":
        if not isinstance(value, dict):
            raise InputError("expected an object of attributes / substeps", field=where)
        value = dict(value)
        if "substeps" in value:
            session.set_substeps(int(value.pop("substeps")))
        session.set_attributes(**value)
    elif action == "grab":
        _grab(session, value, where)
    elif action == "move":
        _move(session, value, where)
    elif action == "release" and value == "all":
        session.release_all()
    elif action == "release":
        session.release(str(value))


def _grab(session: Interaction, value, where: str) -> None:
    if not isinstance(value, dict) or ("at" in value) == ("point" in value):
        raise InputError('expected {"name": ..., "at": "+x"} or {"point": [x, y, z]}', field=where)
    if "at" in value:
        point = _extreme_point(session, value["at"], where)
    else:
        point = _vector(value["point"], where)
    count = value.get("anchors")
    session.grab(point, count=int(count) if count else None, name=value.get("name"))


def _move(session: Interaction, value, where: str) -> None:
    if not isinstance(value, dict) or "grip" not in value or ("by" in value) == ("to" in value):
        raise InputError('expected {"grip": NAME, "by" or "to": [x, y, z]}', field=where)
    name = str(value["grip"])
    grips = session.grips()
    if name not in grips:
        raise InputError(f"no such grip (have: {', '.join(grips) or 'none'})", field=where)
    start = grips[name]["goal"]
    if "by" in value:
        goal = start + _vector(value["by"], where)
    else:
        goal = _vector(value["to"], where)
    frames = int(value.get("frames", 0))
    if frames <= 0:
        session.move_grip(name, goal)
        return
    for frame in range(1, frames + 1):
        session.move_grip(name, start + (goal - start) * (frame / frames))
        session.advance(1)


def parse_vector(text: str, where: str) -> tuple[float, float, float]:
    """``"X,Y,Z"`` (three finite numbers, metres) → a tuple; InputError naming ``where``."""
    try:
        values = tuple(float(part) for part in str(text).split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f'expected "X,Y,Z" (three numbers, metres), got {text!r}', field=where)
    return values


def push_script(
    frames: int,  # total frames of the clip
    displacement: Sequence[float],  # [3] metres the grip moves, world frame
    move_frames: int = PUSH_MOVE_FRAMES,
) -> list[dict]:
    """The script of ``reconphys simulate --push``: a push by ``displacement`` at a third of the
    clip.

    Runs free to frame ``frames // 3``; grabs the object at its extreme point on the side facing
    away from the push (along the dominant axis of the displacement: a push along +x grabs the
    −x side, like a hand pushing from behind); moves that grip by ``displacement`` over
    ``move_frames`` frames (fewer when the clip ends sooner); releases it; runs free to frame
    ``frames``. The grip holds the viewer's default G = 16 anchors and its controller follows at
    most 1.5 m/s (docs/viewer.md), so over 10 frames (0.3 s) a displacement beyond 0.45 m is not
    reached before the release. Writing this list to a JSON file and running ``--script`` gives
    the same trajectory.
    """
    vector = [float(v) for v in displacement]
    if len(vector) != 3 or not all(math.isfinite(v) for v in vector):
        raise InputError(f"expected [x, y, z] in metres, got {displacement!r}", field="--push")
    if not any(vector):
        raise InputError("the push must not be zero", field="--push")
    if frames < 1:
        raise InputError(f"must be ≥ 1, got {frames}", field="--frames")
    axis = max(range(3), key=lambda i: abs(vector[i]))
    side = ("-" if vector[axis] > 0 else "+") + "xyz"[axis]
    start = frames // 3
    move = max(1, min(int(move_frames), frames - start))
    return [
        {"run": start},
        {"grab": {"name": "push", "at": side}},
        {"move": {"grip": "push", "by": vector, "frames": move}},
        {"release": "push"},
        {"run": frames - start - move},
    ]
