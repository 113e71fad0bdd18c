"""CPU thread counts of torch and Numba, set together."""

from __future__ import annotations

import torch

from ._optional import numba_available


def set_cpu_threads(threads: int) -> None:
    """Use ``threads`` CPU threads in torch and in Numba (the compiled CPU simulator).

    Numba's threads must follow torch's: more threads than free cores make each parallel region
    wait for a descheduled thread, which slowed simulation and rendering 30–100× on a busy
    machine. Numba goes first: its first ``set_num_threads`` starts its OpenMP pool, which resets
    the calling thread's OpenMP thread count — torch's — to Numba's default (all cores).
    """
    if numba_available():
        import numba

        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    torch.set_num_threads(threads)
