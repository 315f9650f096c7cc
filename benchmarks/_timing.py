"""Shared by the benchmark scripts (run as ``python benchmarks/NAME.py``, so this directory is on sys.path)."""

import time

import numpy as np


def best_time(fn, repeat):
    """Best wall time [s] of ``repeat`` calls of ``fn()``: the least disturbed measurement."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
