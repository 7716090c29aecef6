"""
warmup.py
---------
What a Dask worker loads before its first tile task: pcprep's filter modules
(NumPy, SciPy and numba come with them, about 0.6 s) and numba's first call
(LLVM's start, about 0.25 s).  ``tiles.dask_client`` asks every worker of a
cluster it attaches to by address to do it on a thread of its own while the
driver reads the input (not on the local clusters it starts, whose workers
share the driver's cores).

This module imports nothing heavy itself: Dask unpickles the coroutine it runs
in the worker's event loop, and the driver waits for that, so the unpickling
must be quick; the heavy imports happen on the thread.
"""

from __future__ import annotations

import threading

#: the filter modules the tile tasks import
MODULES = ("outliers", "denoise", "saliency", "multiscale", "sharp", "holes", "simplify",
           "sparse")


async def start() -> None:
    """Start the warm-up thread (a coroutine: Dask runs only those without
    waiting for them to finish)."""
    threading.Thread(target=warm, name="pcprep-warm", daemon=True).start()


def warm() -> None:
    """Import the tile tasks' modules and make numba's first call.  A task that
    arrives meanwhile waits on Python's import lock and numba's compiler lock,
    so nothing is done twice."""
    import importlib

    from . import tiles

    for mod in MODULES:
        importlib.import_module(f"pcprep.filters.{mod}")
    tiles._load_index_kernels()
