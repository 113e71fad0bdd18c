"""Interactive manipulation of an asset: drop it, grab it, squeeze and stretch it (docs/viewer.md).

- :mod:`.session`: :class:`ViewerSession`, the headless controller (simulation state, attributes,
  grips, recording, background simulation thread). Everything else drives it.
- :mod:`.grips`: picking and the controller-point springs of a grip.
- :mod:`.script`: scripted headless interaction (a JSON list of actions).
- :mod:`.recording`: writing a recorded interaction (trajectory.npz, mp4).
- :mod:`.app`: the browser UI (viser; optional dependency ``reconphys[viewer]``).
"""

from .grips import Grip, nearest_anchors, pick_point
from .script import load_script, run_script
from .session import Recording, SessionStatus, ViewerSession

__all__ = [
    "Grip",
    "Recording",
    "SessionStatus",
    "ViewerSession",
    "load_script",
    "nearest_anchors",
    "pick_point",
    "run_script",
]
