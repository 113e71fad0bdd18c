"""Which optional dependencies this machine has, checked once each.

- Numba: the compiled CPU simulator, the CPU renderer and farthest-point sampling;
- Triton: the fused simulator kernels (CUDA, or the CPU interpreter);
- gsplat: the CUDA renderer.

Each check imports the package the first time it is asked and caches the answer. Modules that
use the package import it themselves behind the check.
"""

from __future__ import annotations

from functools import cache


@cache
def numba_available() -> bool:
    """Whether Numba can be imported."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


@cache
def triton_available() -> bool:
    """Whether Triton (and ``triton.language``) can be imported."""
    try:
        import triton
        import triton.language  # noqa: F401
    except ImportError:
        return False
    return True


@cache
def gsplat_available() -> bool:
    """Whether gsplat can be imported (it still needs CUDA tensors to render)."""
    try:
        import gsplat  # noqa: F401
    except Exception:  # a broken CUDA extension raises more than ImportError
        return False
    return True
