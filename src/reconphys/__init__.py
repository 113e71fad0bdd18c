"""reconphys: one monocular video of a dropped deformable object → a simulation-ready asset.

3D Gaussians (appearance) bound to a spring-mass system (mass, stiffness, damping, ground
friction). Conventions (SI units, z up, ground z = 0, frame_dt 0.03 s) are in docs/design.md.
"""

__version__ = "0.1.0"

# The asset API, imported on first use so that ``import reconphys`` (and the CLI's start) does not
# load torch: ``from reconphys import Asset, predict, read_asset``.
_LAZY = {
    "Asset": "reconphys.assets.asset",
    "read_asset": "reconphys.assets.asset",
    "predict": "reconphys.pipeline.predict",
}
__all__ = ["Asset", "__version__", "predict", "read_asset"]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'reconphys' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
