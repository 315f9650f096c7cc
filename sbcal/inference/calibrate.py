"""One calibration, end to end: bench data -> cleaned runs -> noise model -> likelihood ->
sampler -> stored run. :mod:`sbcal.pipeline` runs it over tests and dampers (and says when a stored
run is still fresh).
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from ..core._io import write_json
from ..core.seeds import job_seed, seed_key
from ..data.noise import noise_model
from ..model.damper import Damper
from .likelihood import TestLikelihood
from .point_fit import fit_thesis_cost
from .priors import load_prior
from .runs import summarize, to_inference_data, versions, write_run
from .sampler import SamplerConfig, sample
from .store import point_fit_path, run_dir


__all__ = ["likelihood_for", "test_likelihood", "calibrate_test", "point_fit_test"]

POINT_FIT_POPULATION, POINT_FIT_GENERATIONS = 60, 200
"""The thesis-cost point fit stored beside every posterior as its baseline (``ga`` in summary.json)."""


def likelihood_for(damper: Damper, data, prior, *, model=None, fixed=None) -> TestLikelihood:
    """The likelihood of a test's (cleaned) runs with the pipeline's noise model.

    Parameters
    ----------
    damper : Damper
    data : TestData
        The runs (:class:`sbcal.data.bench.TestData`).
    prior : Prior
    model, fixed
        As :class:`sbcal.inference.likelihood.TestLikelihood`.
    """
    noise = noise_model(data)
    return TestLikelihood(damper, prior, data.freq_hz, data.magnitude, data.phase_deg, noise.sigma_logmag,
                          noise.sigma_phase, noise_dof=np.stack([noise.dof_logmag, noise.dof_phase]), fixed=fixed,
                          model=model, amplitude_mm_pp=data.amplitude_mm_pp,
                          measured_distortion=data.line_distortion())


def test_likelihood(damper: Damper, data, test: str, *, paramset: str = "theta1", prior_path=None, model=None,
                    fixed=None) -> TestLikelihood:
    """The likelihood of one test's kept runs (``data``: a :class:`sbcal.data.clean_bench.CleanBench`)."""
    return likelihood_for(damper, data.kept(damper.name, test), load_prior(paramset, damper, prior_path), model=model,
                          fixed=fixed)


def calibrate_test(damper: Damper, data, test: str, *, paramset: str = "theta1", seed: int = 0, out="runs",
                   config: SamplerConfig = SamplerConfig(), prior_path=None, progress: bool = True,
                   command: str = "", inputs: dict | None = None) -> dict:
    """Sample one test's posterior and store it under ``out``; returns the summary.

    Parameters
    ----------
    damper : Damper
    data : CleanBench
        The recordings with their stored cleaning (:class:`sbcal.data.clean_bench.CleanBench`): the
        test's kept runs are sampled.
    test : str
        Test label (e.g. ``"0.5-0.5"``).
    paramset : str
        Named parameter set of the prior file.
    seed : int
        The user's seed; the test's stream is keyed by ``("sample", damper, test)``
        (:func:`sbcal.core.seeds.job_seed`): the same seed gives the same draws, whichever other tests run.
    out : path-like
        Root of the run store (``<out>/<damper>/<test>/<paramset>/``).
    config : SamplerConfig
    prior_path : path-like, optional
    progress : bool
    command : str
        The command line, kept for provenance.
    inputs : dict, optional
        Digests of what the run is made from (:func:`sbcal.pipeline.sample_inputs`), stored in
        ``summary.json`` so that a later run can tell whether it is still fresh.
    """
    like = test_likelihood(damper, data, test, paramset=paramset, prior_path=prior_path)
    label = f"{damper.name}/{test}/{paramset}"
    key = ("sample", damper.name, test)
    s_point, s_sample, s_predictive = job_seed(seed, *key).spawn(3)
    point = fit_thesis_cost(like, seed=np.random.default_rng(s_point), population=POINT_FIT_POPULATION,
                            generations=POINT_FIT_GENERATIONS)
    result = sample(like, seed=s_sample, config=config, progress=label if progress else None)
    meta = {"damper": damper.name, "damper_source": damper.source, "test": test, "paramset": paramset,
            "bench": data.source, "prior": like.prior.as_dict(), "sampler": asdict(config),
            "command": command, "damper_values": asdict(damper)}
    idata = to_inference_data(result, like, runs=data.kept(damper.name, test).runs,
                              removed_runs=data.removed_runs(damper.name, test),
                              seed=seed, seed_key=seed_key(*key), rng=np.random.default_rng(s_predictive), meta=meta)
    summary = summarize(idata, result, point_fit=point.as_dict())
    if inputs is not None:
        summary["inputs"] = inputs
    write_run(idata, summary, run_dir(out, damper.name, test, paramset))
    return summary


def point_fit_test(damper: Damper, data, test: str, *, paramset: str = "theta1", seed: int = 0, out="runs",
                   population: int = 500, generations: int = 500, prior_path=None) -> dict:
    """The thesis's workflow (GA point fit, here differential evolution) on one test; writes ``ga.json``."""
    like = test_likelihood(damper, data, test, paramset=paramset, prior_path=prior_path)
    key = ("point_fit", damper.name, test)
    fit = fit_thesis_cost(like, seed=np.random.default_rng(job_seed(seed, *key)), population=population,
                          generations=generations)
    doc = {"damper": damper.name, "test": test, "paramset": paramset, "seed": seed, "seed_key": seed_key(*key),
           "removed_runs": list(data.removed_runs(damper.name, test)), "versions": versions(), **fit.as_dict()}
    path = point_fit_path(out, damper.name, test, paramset)
    write_json(path, doc, indent=2, sort_keys=True)
    return doc
