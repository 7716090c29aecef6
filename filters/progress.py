"""
progress.py
-----------
Progress of the long steps (k-NN queries, iterations, dictionary learning,
coding, greedy removal), reported to one listener that the caller installs:
the ``pcprep`` command line shows a tqdm bar on a terminal, a MeshLab-style host
can pass MeshLab's callback.  With no listener (the default, and in library use)
a step costs one attribute lookup; the algorithms never import a UI library.

    with progress.step("K-SVD", total=max_iter) as advance:
        for it in range(max_iter):
            ...
            advance()
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

#: ``listener(name, done, total)``; ``done == total`` or ``done < 0`` ends the step
_listener: Callable[[str, int, int], None] | None = None


def set_listener(listener: Callable[[str, int, int], None] | None):
    """Install ``listener`` (None: none) and return the previous one."""
    global _listener
    previous, _listener = _listener, listener
    return previous


@contextmanager
def step(name: str, total: int) -> Iterator[Callable[[int], None]]:
    """A step of ``total`` units; the yielded ``advance(k=1)`` reports progress."""
    listener = _listener
    if listener is None:
        yield _ignore
        return
    done = 0
    listener(name, 0, total)

    def advance(k: int = 1) -> None:
        nonlocal done
        done += k
        listener(name, min(done, total), total)

    try:
        yield advance
    finally:
        listener(name, -1, total)


def _ignore(k: int = 1) -> None:
    return None
