"""Interaction with a simulated asset, without threads or UI: grips, attribute changes, scripts,
recordings (docs/viewer.md).

- :mod:`.interaction`: :class:`Interaction`, state, attributes, grips and recording of one asset.
- :mod:`.script`: scripted interaction (a JSON list of actions) and ``simulate --push``.
- :mod:`.recording`: :class:`Recording` and writing it (trajectory.npz, interaction.json, mp4).

The viewer (:mod:`reconphys.viewer`) runs an :class:`Interaction` in a background thread.
"""

from .interaction import Interaction
from .recording import Recording, write_recording
from .script import load_script, push_script, run_script

__all__ = [
    "Interaction",
    "Recording",
    "load_script",
    "push_script",
    "run_script",
    "write_recording",
]
