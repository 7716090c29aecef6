"""The memory benchmark measures the filter's process, not the harness that starts it."""

import sys

import numpy as np

from pcprep.baselines.bench_memory import _peak_of


def test_peak_is_the_child_s_own_even_beside_a_large_parent():
    held = np.ones(80_000_000)          # 640 MB in this process, touched
    peak, _, code = _peak_of([sys.executable, "-c", "x = bytearray(300_000_000)"])
    assert code == 0
    assert 286 <= peak < 450            # the child's 286 MiB, not the parent's 610 MiB
    assert held[-1] == 1.0
    _, _, failed = _peak_of([sys.executable, "-c", "raise SystemExit(3)"])
    assert failed == 3
