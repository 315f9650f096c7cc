"""Bench-data throughput: load + validate, quality table, outlier removal and noise model.

Usage: python benchmarks/bench_load.py [--rows 100000] [--repeat 5] [--seed 0]

Writes a synthetic bench CSV of about ``--rows`` rows (10 dampers x the 9 thesis tests x N runs x
the 37 standard lines, a few planted outlier runs) to a temporary directory, then times
:func:`sbcal.data.readers.load_bench` alone and the whole per-test pipeline for every test, and, as a
baseline measured in the same run, a bare ``pandas.read_csv`` of the same file. Prints rows/s,
the ratio to the baseline and the pipeline's peak traced memory (tracemalloc, a separate pass).
"""

import argparse
import math
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd

from sbcal import STANDARD_GRID_HZ, dynamic_stiffness
from sbcal.data.bench import THESIS_TESTS, curves_to_frame, write_bench
from sbcal.data.cleaning import quality_table, remove_outlier_runs
from sbcal.data.noise import noise_model
from sbcal.data.readers import load_bench
from sbcal.model.damper import resolve_damper

from _timing import best_time


def make_file(path: Path, rows: int, seed: int) -> None:
    d = resolve_damper("damper1")
    f = STANDARD_GRID_HZ
    n_dampers = 10
    n_runs = math.ceil(rows / (n_dampers * len(THESIS_TESTS) * f.size))
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(n_dampers):
        base = dynamic_stiffness(d, f, EJ=rng.uniform(5, 30, len(THESIS_TESTS)), beta=0.3)
        for j, test in enumerate(THESIS_TESTS):
            c = base[j] * np.exp(0.02 * rng.standard_normal((n_runs, 1))
                                 + 0.02 * rng.standard_normal((n_runs, f.size))
                                 + 0.02j * rng.standard_normal((n_runs, f.size)))
            c[rng.integers(n_runs)] *= np.exp(0.3)  # one planted outlier run per test
            parts.append(curves_to_frame(f"damper{k}", test, f, 1.0, c))
    write_bench(pd.concat(parts, ignore_index=True), path)


def pipeline(path):
    b = load_bench(path)
    removed = 0
    for damper in b.dampers():
        for test in b.tests(damper):
            t = b.test(damper, test)
            quality_table(t)
            cleaned = remove_outlier_runs(t)
            noise_model(cleaned.data)
            removed += len(cleaned.removed_runs)
    return b, removed


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.csv"
        make_file(path, args.rows, args.seed)
        b, removed = pipeline(path)
        rows, n_tests = len(b.frame), sum(len(b.tests(d)) for d in b.dampers())
        size_mb = path.stat().st_size / 1e6

        t_naive = best_time(lambda: pd.read_csv(path), args.repeat)
        t_load = best_time(lambda: load_bench(path), args.repeat)
        t_all = best_time(lambda: pipeline(path), args.repeat)

        tracemalloc.start()
        pipeline(path)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()

    print(f"file          : {rows} rows, {size_mb:.1f} MB, {n_tests} tests; {removed} runs removed "
          f"({n_tests} planted)")
    print(f"pd.read_csv   : {t_naive * 1e3:7.1f} ms  -> {rows / t_naive:.3g} rows/s  (baseline, no validation)")
    print(f"load_bench    : {t_load * 1e3:7.1f} ms  -> {rows / t_load:.3g} rows/s  ({t_load / t_naive:.2f}x the baseline)")
    print("load + quality + clean + noise, all tests:")
    print(f"                {t_all * 1e3:7.1f} ms  -> {rows / t_all:.3g} rows/s  ({t_all / t_naive:.1f}x the baseline), "
          f"{(t_all - t_load) / n_tests * 1e3:.2f} ms per test")
    print(f"peak traced memory (whole pipeline): {peak / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
