"""The diagnosis's fits: its settings, the models it compares (a primary effect, maybe secondary effects on
top), one fit job per test or per cable state and law, run in worker processes, and their posteriors."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.seeds import job_seed
from ..core.workers import default_workers, one_blas_thread, run_jobs
from ..data.cleaning import DEFAULT_Z_THRESHOLD, remove_outlier_runs
from ..inference.cable_fit import (CableFit, cable_config, cable_likelihood, cable_seed, compare_families,
                                   compared_laws, sample_cable, state_tests)
from ..inference.calibrate import likelihood_for
from ..inference.likelihood import JointLikelihood
from ..inference.priors import Prior, extension_prior
from ..inference.sampler import SamplerConfig, sample
from ..inference.stats import loo
from ..model.damper import Damper
from ..model.extensions import model_for
from ..model.hysteresis import FITTED_LAWS


__all__ = ["DiagnoseConfig"]

_QUANTITIES = ("magnitude", "phase")


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`diagnose` (the defaults are what ``sbcal diagnose`` uses).

    Attributes
    ----------
    alpha : float
        Family-wise false-alarm rate of the per-line check over all lines of all tests.
    global_alpha : float
        False-alarm rate of the global check of the residual as a whole.
    clear_se : float
        An extension beats the model below it clearly when ``delta_elpd > clear_se * se``.
    min_explained : float
        ... and removes at least this share of the misfit (in the bands; without bands, of the
        global excess over chance).
    screen_t : float
        Screening: |t| of the EJ-versus-amplitude trend that admits ``strand_slip``.
    screen_share : float
        Screening: share of the misfit a signature explains (phase linear in omega: ``sensor_delay``;
        ``-omega^2 m``: ``fixture_mass``) that admits the extension.
    screen_corr : float
        Screening: lag-1 correlation of the residuals over frequency (structured misfit) that admits
        the extensions without a specific signature, or curvature correlation for strand slip.
    laws : tuple of str
        The cable-law families fitted for ``strand_slip`` (:data:`sbcal.model.hysteresis.FITTED_LAWS`), those
        of them a damper's cable states have the tests for (:func:`sbcal.inference.cable_fit.compared_laws`).
    secondary : bool
        Search for a second effect on top of the verdict's.
    draws : int
        Posterior draws kept per ensemble.
    max_steps, cable_max_steps : int
        Step caps of the engine for a per-test fit and for a cable-law fit (the policy and everything
        else are the engine's: :data:`sbcal.inference.sampler.POLICY`).
    workers : int
        Processes: fits run in parallel, one per process.
    z_threshold : float
        Outlier-run threshold of the cleaning (:func:`sbcal.data.cleaning.remove_outlier_runs`); the pipeline
        sets it from its own settings, so every stage cleans alike.
    """

    alpha: float = 0.05
    global_alpha: float = 0.01
    clear_se: float = 4.0
    min_explained: float = 0.8
    screen_t: float = 3.0
    screen_share: float = 0.05
    screen_corr: float = 0.3
    laws: tuple = FITTED_LAWS
    secondary: bool = True
    draws: int = 250
    max_steps: int = 20000
    cable_max_steps: int = 8000
    workers: int = field(default_factory=default_workers)
    z_threshold: float = DEFAULT_Z_THRESHOLD

    def sampler(self, ndim: int, joint: bool = False) -> SamplerConfig:
        if joint:  # the cable fit's own settings, capped as here
            return cable_config(ndim, workers=1, max_steps=self.cable_max_steps, max_draws=self.draws)
        return SamplerConfig(nwalkers=max(16, 2 * ndim + 2), max_draws=self.draws, max_steps=self.max_steps,
                             workers=1)


# --- models: a primary effect, maybe with secondary ones on top ----------------------------------

def _name(primary: str, secondary=()) -> str:
    return "+".join((primary,) + tuple(secondary))


def _per_test_prior(primary: str, secondary, damper: Damper, prior_path) -> Prior:
    prior = extension_prior(primary, damper, base_path=prior_path)
    boxes = {n: prior.box(n) for n in prior.names}
    for e in secondary:
        ext = extension_prior(e, damper, base_path=prior_path)
        boxes.update({n: ext.box(n) for n in ext.names if n not in boxes})
    return Prior.from_boxes(_name(primary, secondary), boxes)


def _jobs(primary, secondary, damper, bench, tests, seed, config, prior_path) -> list:
    """Fit jobs of one model: one per test, or for strand slip one per cable state and law family.

    A job is a :class:`FitJob`: key ``(model name, test)`` or ``(model name, state, law)``; the stream
    keyed by what the fit is (a cable fit's is :func:`sbcal.inference.cable_fit.cable_seed`, the same as
    ``sbcal cable``'s), so no fit's draws depend on which other fits run.
    """
    name = _name(primary, secondary)
    jobs = []
    if primary == "strand_slip":
        for state, members in sorted(state_tests(tests).items()):
            for law in compared_laws(config.laws, tests):
                like = cable_likelihood(damper, bench, members, law, effects=secondary, prior_path=prior_path,
                                        z_threshold=config.z_threshold)
                jobs.append(((name, state, law), like, cable_seed(seed, damper.name, state, law, tuple(secondary))))
    else:
        prior = _per_test_prior(primary, secondary, damper, prior_path)
        model = model_for(primary, secondary)
        for t in tests:
            data = remove_outlier_runs(bench.test(damper.name, t), config.z_threshold).data
            jobs.append(((name, t), likelihood_for(damper, data, prior, model=model),
                         job_seed(seed, "diagnose", damper.name, name, t)))
    return [FitJob(key, target, s, config) for key, target, s in jobs]


# --- fits ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitJob:
    """One fit of the diagnosis (picklable: it travels to a worker process).

    Attributes
    ----------
    key : tuple
        ``(model name, test)``, or ``(model name, cable state, law)`` for a cable fit.
    target : TestLikelihood or JointLikelihood
    stream : numpy.random.SeedSequence
        The fit's own stream, keyed by what it is.
    config : DiagnoseConfig
    """

    key: tuple
    target: object
    stream: object
    config: DiagnoseConfig


def _fit(job: FitJob):
    """One posterior through the engine (a test's, or a cable state's: :func:`sbcal.inference.cable_fit.sample_cable`)."""
    like, config = job.target, job.config
    with one_blas_thread():
        if isinstance(like, JointLikelihood):
            return sample_cable(like, seed=job.stream, config=config.sampler(like.prior.ndim, True))
        return sample(like, seed=job.stream, config=config.sampler(like.prior.ndim))


def _posterior(like, res) -> dict:
    """An engine result -> what the diagnosis needs: model curves, pointwise log-likelihood, convergence."""
    params = res.flat()
    joint = isinstance(like, JointLikelihood)
    mus = like.predict(params) if joint else [like.predict(params)]
    mu_mean, mu_var, mu_median = [], [], []
    for mu in mus:
        # phase draws about the first draw, so a wrap cannot corrupt the mean
        d = mu.copy()
        d[1] = mu[1, :1] + np.remainder(mu[1] - mu[1, :1] + np.pi, 2 * np.pi) - np.pi
        mu_mean.append(d.mean(axis=1))
        mu_var.append(d.var(axis=1))
        mu_median.append(np.median(d, axis=1))
    return dict(params=params, names=like.prior.names, log_lik=res.log_likelihood, mu_mean=mu_mean, mu_var=mu_var,
                mu_median=mu_median, convergence=res.convergence_dict(), converged=res.converged,
                result=res, like=like, n_params=like.prior.ndim)


def _run_fits(jobs, config, label) -> dict:
    """Run fits, ``config.workers`` at a time (the costly cable fits first); ``{key: fit}``."""
    jobs = sorted(jobs, key=lambda j: not isinstance(j.target, JointLikelihood))
    done = run_jobs(_fit, jobs, workers=config.workers, label=label, unit="fit")
    return {job.key: _posterior(job.target, res) for job, res in zip(jobs, done)}


def _choose_law(fits: dict, name: str) -> tuple[dict, dict | None]:
    """For a cable model, keep the best family's fits (by PSIS-LOO summed over cable states):
    ``{(name, state): fit}``, and the comparison (None for per-test models)."""
    cable = {k: f for k, f in fits.items() if k[0] == name and len(k) == 3}
    if not cable:
        return {k: f for k, f in fits.items() if k[0] == name}, None
    by_law = {}
    for (_, state, law), f in cable.items():
        by_law.setdefault(law, {})[state] = CableFit(damper="", state=state, law=law, tests=(), effects=(),
                                                     result=f["result"], like=f["like"], loo=loo(f["log_lik"]))
    comparison = compare_families(by_law)
    for law in comparison["families"]:
        comparison["families"][law]["converged"] = all(cable[(name, s, law)]["converged"] for s in by_law[law])
    best = comparison["best"]
    kept = {(name, state): dict(f, law=law) for (_, state, law), f in cable.items() if law == best}
    return kept, comparison
