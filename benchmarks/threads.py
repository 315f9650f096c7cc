"""BLAS threads in parallel fits: the cable likelihood in two processes side by side, with OpenBLAS's
default threads (the baseline) and with one thread per process (``sbcal.core.workers.one_blas_thread``).

Usage: python benchmarks/threads.py [--sets 80] [--repeat 40]

The workload is what ``sbcal diagnose`` runs on 2 cores: two cable fits at once, each evaluating the
joint likelihood of damper1's dry tests (8 tests, 283 lines) on ``--sets`` parameter sets per call (an
engine step of 4 ensembles of 20 walkers). Prints the mean time per call, alone and two side by side,
for both settings, and the ratio. On the 2-core development machine: alone 60 ms per call either way;
side by side 158 ms with the default threads against 62 ms with one thread (2.5x). Whole cable fits
side by side: 239 s against 92 s; damper1's ``sbcal diagnose``: 350 s against 215 s.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.data.labels import state_tests  # noqa: E402
from sbcal.inference.cable_fit import cable_likelihood  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.core.workers import one_blas_thread  # noqa: E402


def _calls(job) -> float:
    """Mean wall time [s] of one likelihood call on ``sets`` parameter sets, ``repeat`` calls."""
    one, sets, repeat = job
    damper = resolve_damper("damper1")
    bench = load_bench(default_bench_path())
    like = cable_likelihood(damper, clean_bench(bench, dampers=["damper1"]), state_tests(bench.tests("damper1"))["dry"], "iwan5")
    lo, hi = like.prior.z_lower, like.prior.z_upper
    z = lo + (hi - lo) * np.random.default_rng(0).uniform(0.3, 0.7, (sets, like.prior.ndim))
    with one_blas_thread() if one else contextlib.nullcontext():
        like(z)  # tables and caches
        t0 = time.perf_counter()
        for _ in range(repeat):
            like(z)
        return (time.perf_counter() - t0) / repeat


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=80)
    ap.add_argument("--repeat", type=int, default=40)
    args = ap.parse_args(argv)
    rows = {}
    for one in (False, True):
        with ProcessPoolExecutor(max_workers=2) as pool:  # fresh processes: OpenBLAS's own default
            alone = pool.submit(_calls, (one, args.sets, args.repeat)).result()
            pair = list(pool.map(_calls, [(one, args.sets, args.repeat)] * 2))
        rows[one] = (alone, max(pair))
        label = "one thread per process" if one else "default BLAS threads (baseline)"
        print(f"{label:32s}: alone {1e3 * alone:6.1f} ms per call, two side by side {1e3 * max(pair):6.1f} ms")
    print(f"side by side, baseline / one thread: {rows[False][1] / rows[True][1]:.2f}x "
          f"(alone: {rows[False][0] / rows[True][0]:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
