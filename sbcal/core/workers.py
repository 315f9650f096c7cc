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
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

from threadpoolctl import threadpool_limits


__all__ = ["one_blas_thread", "default_workers", "process_pool", "run_jobs"]


def default_workers() -> int:
    """Processes a stage uses unless told: one per core, at most 2 (the engine's ensembles and the
    pipeline's jobs scale no further on the machines sbcal is measured on; ``--workers`` raises it)."""
    return max(1, min(2, os.cpu_count() or 1))


def one_blas_thread():
    """A context manager: BLAS libraries loaded in this process use one thread inside it."""
    return threadpool_limits(limits=1, user_api="blas")


@contextmanager
def process_pool(workers: int):
    """A pool of ``workers`` local processes (None when ``workers`` <= 1: work stays in this process),
    shut down on exit. The pool of :func:`run_jobs` and of the engine's ensemble rounds."""
    if workers <= 1:
        yield None
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        yield pool


def run_jobs(fn, jobs, *, workers: int = 1, executor=None, label: str | None = None, unit: str = "job") -> list:
    """``fn`` over ``jobs``, results in job order, a progress bar over jobs: the one process loop of sbcal.

    Parameters
    ----------
    fn : callable
        A module-level function of one job (picklable, as the job must be).
    jobs : list
    workers : int
        Local processes (here, in this process, when 1 or when there is a single job).
    executor : concurrent.futures.Executor, optional
        A cluster's executor (:func:`sbcal.pipeline.executor_for`); it takes precedence over ``workers``.
    label, unit : str
        The progress bar's text and unit (no bar when ``label`` is None).
    """
    from .progress import progress_bar

    out = []
    with progress_bar(label, total=len(jobs), unit=unit) as bar:
        with process_pool(workers if executor is None and len(jobs) > 1 else 1) as pool:
            runner = executor or pool  # a cluster, local processes, or this process
            for r in (runner.map(fn, jobs) if runner is not None else map(fn, jobs)):
                out.append(r)
                bar.update(1)
    return out
