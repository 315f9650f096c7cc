"""One BLAS thread per process: how sbcal's parallel work shares the cores.

Every parallel stage runs one job per core: the pipeline's per-test sampling, diagnose's fits and the
engine's ensembles (``workers``), locally or on a Dask cluster. numpy's OpenBLAS would otherwise start
a thread per core in every one of those processes, and its idle threads spin: on 2 cores two cable
fits side by side took 239 s each with OpenBLAS's default threads and 92 s each with one thread
(``benchmarks/threads.py`` measures the ratio again). sbcal's matrix products are small (the cable
model's inner dimension is its 8 sections), where threads buy nothing even alone.

The limit is set at run time with threadpoolctl (the library scikit-learn and joblib use for this):
an environment variable such as ``OPENBLAS_NUM_THREADS`` is read only when numpy is first imported,
so it cannot be set from inside a running process.
"""

from __future__ import annotations

import os

from threadpoolctl import threadpool_limits


__all__ = ["one_blas_thread", "default_workers"]


def default_workers() -> int:
    """Processes a stage uses unless told: one per core, at most 2 (the engine's ensembles and the
    pipeline's jobs scale no further on the machines sbcal is measured on; ``--workers`` raises it)."""
    return max(1, min(2, os.cpu_count() or 1))


def one_blas_thread():
    """A context manager: BLAS libraries loaded in this process use one thread inside it."""
    return threadpool_limits(limits=1, user_api="blas")
