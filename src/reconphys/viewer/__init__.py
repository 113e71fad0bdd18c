"""Interactive manipulation of an asset: drop it, grab it, squeeze and stretch it (docs/viewer.md).

- :mod:`.session`: :class:`ViewerSession`, the :class:`~reconphys.interact.Interaction` (state,
  attributes, grips, recording) with a background simulation thread. Everything else drives it.
- :mod:`.app`: the browser UI (viser; optional dependency ``reconphys[viewer]``).
- :mod:`.command`: ``reconphys view``.

Grips and the frame stepper are physics (:mod:`reconphys.physics.control`); scripts and
recordings are :mod:`reconphys.interact`.
"""

from .session import SessionStatus, ViewerSession

__all__ = ["SessionStatus", "ViewerSession"]
