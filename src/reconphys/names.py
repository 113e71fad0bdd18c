"""Names the command line offers as choices, defined once and free of torch.

The modules that act on these names (the renderer, the exporter, the device resolver) import them
from here, and so does :mod:`reconphys.cli`, whose option help and validation are built from them
without importing torch at ``reconphys --help`` time. Imports nothing.
"""

from __future__ import annotations

RENDER_BACKENDS = ("auto", "torch", "numba", "gsplat")  # render(..., backend=...)
EXPORT_FORMATS = ("newton", "mjcf")  # assets.export.export_asset(..., format=...)
DEVICES = ("auto", "cpu", "cuda")  # --device (and cuda:N); devices.resolve_device
