"""One calibration, end to end: bench data -> cleaned runs -> noise model -> likelihood ->
sampler -> stored run. The CLI's ``sample`` and ``run`` commands are thin wrappers over this.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .bench import DEFAULT_Z_THRESHOLD, load_bench, noise_model, remove_outlier_runs
from .damper import Damper
from .ga import fit_ga
from .likelihood import TestLikelihood
from .priors import load_prior
from .runs import read_summary, run_dir, summarize, to_inference_data, versions, write_run
from ._io import write_json
from .sampler import SamplerConfig, sample

__all__ = ["likelihood_for", "test_likelihood", "calibrate_test", "calibrate_tests", "point_fit_test", "is_up_to_date"]

POINT_FIT_POPULATION, POINT_FIT_GENERATIONS = 60, 200
"""The thesis-cost point fit stored beside every posterior as its baseline (``ga`` in summary.json)."""


def _fingerprint(bench) -> str:
    """sha256 of the bench file: a stored run is up to date only for the same data."""
    import hashlib

    return hashlib.sha256(Path(bench.source).read_bytes()).hexdigest()


def likelihood_for(damper: Damper, data, prior, *, model=None, fixed=None) -> TestLikelihood:
    """The likelihood of a test's (cleaned) runs with the pipeline's noise model.

    Parameters
    ----------
    damper : Damper
    data : TestData
        The runs (:class:`sbcal.bench.TestData`).
    prior : Prior
    model, fixed
        As :class:`sbcal.likelihood.TestLikelihood`.
    """
    noise = noise_model(data)
    return TestLikelihood(damper, prior, data.freq_hz, data.magnitude, data.phase_deg, noise.sigma_logmag,
                          noise.sigma_phase, noise_dof=np.stack([noise.dof_logmag, noise.dof_phase]), fixed=fixed,
                          model=model, amplitude_mm_pp=data.amplitude_mm_pp)


def test_likelihood(damper: Damper, bench, test: str, paramset: str = "theta1", prior_path=None,
                    z_threshold=None, model=None, fixed=None):
    """Build the likelihood of one test's cleaned runs.

    Returns ``(like, cleaned)`` where ``cleaned`` is the :class:`sbcal.bench.CleanedTest`.
    """
    td = bench.test(damper.name, test)
    cleaned = remove_outlier_runs(td, DEFAULT_Z_THRESHOLD if z_threshold is None else z_threshold)
    like = likelihood_for(damper, cleaned.data, load_prior(paramset, damper, prior_path), model=model, fixed=fixed)
    return like, cleaned


def calibrate_test(damper: Damper, bench, test: str, *, paramset: str = "theta1", seed: int = 0, out="runs",
                   config: SamplerConfig = SamplerConfig(), prior_path=None, z_threshold=None,
                   progress: bool = True, command: str = "") -> dict:
    """Sample one test's posterior and store it under ``out``; returns the summary.

    Parameters
    ----------
    damper : Damper
    bench : BenchData
    test : str
        Test label (e.g. ``"0.5-0.5"``).
    paramset : str
        Named parameter set of the prior file.
    seed : int
        The same seed gives the same draws.
    out : path-like
        Root of the run store (``<out>/<damper>/<test>/<paramset>/``).
    config : SamplerConfig
    prior_path : path-like, optional
    z_threshold : float, optional
        Outlier-run threshold (default: the loader's).
    progress : bool
    command : str
        The command line, kept for provenance.
    """
    like, cleaned = test_likelihood(damper, bench, test, paramset, prior_path, z_threshold)
    label = f"{damper.name}/{test}/{paramset}"
    seqs = np.random.SeedSequence(seed).spawn(2)  # the thesis's point fit and the posterior
    point = fit_ga(like, seed=np.random.default_rng(seqs[0]), population=POINT_FIT_POPULATION,
                   generations=POINT_FIT_GENERATIONS)
    result = sample(like, seed=seqs[1], config=config, progress=label if progress else None)
    meta = {"damper": damper.name, "damper_source": damper.source, "test": test, "paramset": paramset,
            "bench": bench.source, "bench_sha256": _fingerprint(bench), "prior": like.prior.as_dict(), "sampler": asdict(config),
            "command": command, "damper_values": asdict(damper)}
    idata = to_inference_data(result, like, runs=cleaned.data.runs, removed_runs=cleaned.removed_runs,
                              seed=seed, meta=meta)
    summary = summarize(idata, result, point_fit=point.as_dict())
    write_run(idata, summary, run_dir(out, damper.name, test, paramset))
    return summary


def point_fit_test(damper: Damper, bench, test: str, *, paramset: str = "theta1", seed: int = 0, out="runs",
                   population: int = 500, generations: int = 500, prior_path=None) -> dict:
    """The thesis's workflow (GA point fit, here differential evolution) on one test; writes ``ga.json``."""
    like, cleaned = test_likelihood(damper, bench, test, paramset, prior_path)
    fit = fit_ga(like, seed=seed, population=population, generations=generations)
    doc = {"damper": damper.name, "test": test, "paramset": paramset, "seed": seed,
           "removed_runs": list(cleaned.removed_runs), "versions": versions(), **fit.as_dict()}
    path = run_dir(out, damper.name, test, paramset) / "ga.json"
    write_json(path, doc, indent=2, sort_keys=True)
    return doc


def _work(job):
    damper, bench_path, test, kwargs = job
    return test, calibrate_test(damper, load_bench(bench_path), test, **kwargs)


def _init_worker():
    os.environ["OMP_NUM_THREADS"] = "1"


def calibrate_tests(damper: Damper, bench, tests, *, workers: int = 1, **kwargs) -> dict:
    """:func:`calibrate_test` for several tests, in ``workers`` processes; ``{test: summary}``."""
    if workers <= 1 or len(tests) <= 1:
        return {t: calibrate_test(damper, bench, t, **kwargs) for t in tests}
    # tests in parallel: each sampler then runs its ensembles in its own process
    kwargs["config"] = replace(kwargs.get("config", SamplerConfig()), workers=1)
    jobs = [(damper, bench.source, t, kwargs) for t in tests]
    with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker) as pool:
        return dict(pool.map(_work, jobs))


def is_up_to_date(out, damper: Damper, bench, test: str, paramset: str, seed: int,
                  config: SamplerConfig = SamplerConfig()) -> bool:
    """True when a finished run of this test exists for the same data, damper, seed and settings."""
    s = read_summary(run_dir(out, damper.name, test, paramset))
    if s is None:
        return False
    cfg = s.get("config", {})

    def settings(d):  # the number of processes does not change the draws
        return {k: v for k, v in (d or {}).items() if k != "workers"}

    return (s.get("seed") == seed and cfg.get("bench_sha256") == _fingerprint(bench)
            and settings(cfg.get("sampler")) == settings(asdict(config))
            and cfg.get("damper_values") == asdict(damper))
