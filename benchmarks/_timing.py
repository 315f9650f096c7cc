"""Shared by the benchmark scripts (run as ``python benchmarks/NAME.py``, so this directory is on sys.path)."""

import argparse
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


def positive_count(text: str) -> int:
    """A positive count (an argparse type: a wrong one is one line and exit 2)."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {text!r}")
    return n
