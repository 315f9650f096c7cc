"""The diagnosis's fits: its settings, the models it compares (a primary effect, maybe secondary effects on
top), one fit job per test or per cable state and law, run in worker processes, and their posteriors."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.seeds import job_seed
from ..core.workers import default_workers, one_blas_thread, run_jobs
from ..data.labels import state_tests
from ..inference.cable_compare import compare_families, zoned_candidate
from ..inference.cable_fit import CableFit, cable_config, cable_likelihood, cable_seed, compared_laws, sample_cable, zoned_start
from ..inference.cable_start import screen, unscreened
from ..inference.calibrate import likelihood_for
from ..inference.checks import ALPHA, GLOBAL_ALPHA, curve_moments, predictive_check, qualifier
from ..inference.likelihood import JointLikelihood
from ..inference.priors import composed_prior
from ..inference.sampler import SamplerConfig, sample
from ..inference.stats import CLEAR_SE, loo
from ..model.extensions import model_for
from ..model.laws import fitted_laws
from ..model.laws.zones import ZONED_SUFFIX


__all__ = ["DiagnoseConfig", "posterior_record", "CURVE_QUANTITIES", "model_name", "fit_jobs", "screen_cable_jobs",
           "run_fits", "choose_law", "late_laws", "zoned_law"]

CURVE_QUANTITIES = ("magnitude", "phase")


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`diagnose` (the defaults are what ``sbcal diagnose`` uses).

    The outlier-run threshold is not among them: the diagnosis fits the runs the clean stage kept.

    Attributes
    ----------
    alpha : float
        Family-wise false-alarm rate of the per-line check over all lines of all tests.
    global_alpha : float
        False-alarm rate of the global check of the residual as a whole.
    clear_se : float
        An extension beats the model below it clearly when ``delta_elpd > clear_se * se``.
    min_explained : float
        ... and removes at least this share of the misfit where it is (its excess over chance in the
        bands and, when the global check fails, outside them: ``docs/diagnose.md``, "Verdict").
    screen_t : float
        Screening: |t| of the EJ-versus-amplitude trend that admits ``strand_slip``.
    screen_share : float
        Screening: share of the misfit a signature explains (phase linear in omega: ``sensor_delay``;
        ``-omega^2 m``: ``fixture_mass``) that admits the extension.
    screen_corr : float
        Screening: lag-1 correlation of the residuals over frequency (structured misfit) that admits
        the extensions without a specific signature, or curvature correlation for strand slip.
    laws : tuple of str
        The cable-law families fitted for ``strand_slip`` (:func:`sbcal.model.laws.fitted_laws`), those
        of them a damper's cable states have the tests for (:func:`sbcal.inference.cable_fit.compared_laws`).
    secondary : bool
        Search for a second effect on top of the verdict's.
    draws : int
        Posterior draws kept per ensemble.
    max_steps, cable_max_steps : int
        Step caps of the engine for a per-test fit and for a cable-law fit (``cable_max_steps`` None:
        :func:`sbcal.inference.cable_fit.cable_config`'s, by the dimension; the policy and everything else are
        the engine's: :data:`sbcal.inference.sampler.POLICY`).
    workers : int
        Processes: fits run in parallel, one per process.
    harmonics : bool
        Refit a strand-slip verdict's cable law with the multi-harmonic solve where it is needed
        (:func:`sbcal.inference.harmonic_refit.refit_harmonics`).
    """

    alpha: float = ALPHA
    global_alpha: float = GLOBAL_ALPHA
    clear_se: float = CLEAR_SE
    min_explained: float = 0.8
    laws: tuple = field(default_factory=fitted_laws)
    screen_t: float = 3.0
    screen_share: float = 0.05
    screen_corr: float = 0.3
    workers: int = field(default_factory=default_workers)
    secondary: bool = True
    draws: int = 250
    max_steps: int = 20000
    cable_max_steps: int | None = None
    harmonics: bool = True

    def sampler(self, ndim: int, joint: bool = False, workers: int = 1) -> SamplerConfig:
        """The engine's settings of one fit; ``workers``: processes for its ensembles (the draws do not
        depend on them)."""
        if joint:  # the cable fit's own settings, capped as here
            return cable_config(ndim, workers=workers, max_steps=self.cable_max_steps, max_draws=self.draws)
        return SamplerConfig(nwalkers=max(16, 2 * ndim + 2), max_draws=self.draws, max_steps=self.max_steps,
                             workers=workers)


# --- models: a primary effect, maybe with secondary ones on top ----------------------------------

def model_name(primary: str, secondary=()) -> str:
    """A model's name: its primary effect and secondary ones joined by ``+``."""
    return "+".join((primary,) + tuple(secondary))


def fit_jobs(primary, secondary, *, damper, data, tests, seed, config, prior_path, starts=None) -> list:
    """Fit jobs of one model: one per test, or for strand slip one per cable state and law family.

    A job is a :class:`FitJob`: key ``(model name, test)`` or ``(model name, state, law)``; the stream
    keyed by what the fit is (a cable fit's is :func:`sbcal.inference.cable_fit.cable_seed`, the same as
    ``sbcal cable``'s), so no fit's draws depend on which other fits run. ``starts``: a cable fit's start
    per cable state (natural values by name; default the cable start search).
    """
    name = model_name(primary, secondary)
    jobs = []
    if primary == "strand_slip":
        for state, members in sorted(state_tests(tests).items()):
            for law in compared_laws(config.laws, tests):
                like = cable_likelihood(damper, data, members, law, effects=secondary, prior_path=prior_path)
                stream = cable_seed(seed, damper.name, state, law, tuple(secondary))
                jobs.append(FitJob((name, state, law), like, stream, config, tuple(members),
                                   (starts or {}).get(state)))
    else:
        prior = composed_prior(primary, secondary, damper, base_path=prior_path)
        model = model_for(primary, secondary)
        for t in tests:
            like = likelihood_for(damper, data.kept(damper.name, t), prior, model=model)
            jobs.append(FitJob((name, t), like, job_seed(seed, "diagnose", damper.name, name, t), config, (t,)))
    return jobs


# --- fits ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitJob:
    """One fit of the diagnosis (picklable: it travels to a worker process).

    Built by :func:`fit_jobs` for one model, run by :func:`_fit`, read back by :func:`_posterior`.

    Attributes
    ----------
    key : tuple
        ``(model name, test)``, or ``(model name, cable state, law)`` for a cable fit.
    target : TestLikelihood or JointLikelihood
    stream : numpy.random.SeedSequence
        The fit's own stream, keyed by what it is.
    config : DiagnoseConfig
    tests : tuple of str
        The tests the fit is of (one, or a cable state's).
    start : dict or ndarray, optional
        A cable fit's start (natural values by name, or the family screen's in sampled coordinates; default
        :func:`sbcal.inference.cable_fit.cable_start`).
    workers : int
        Processes for the fit's own ensembles (more than 1 only when its batch leaves workers idle).
    screened : dict, optional
        A cable fit's: the families of its comparison that the screen left unsampled
        (:func:`sbcal.inference.cable_start.screen_families`).
    """

    key: tuple
    target: object
    stream: object
    config: DiagnoseConfig
    tests: tuple
    start: object = None
    workers: int = 1
    screened: dict | None = None


def _fit(job: FitJob):
    """One posterior through the engine (a test's, or a cable state's: :func:`sbcal.inference.cable_fit.sample_cable`)."""
    like, config = job.target, job.config
    with one_blas_thread():
        if isinstance(like, JointLikelihood):
            return sample_cable(like, seed=job.stream, config=config.sampler(like.prior.ndim, True, job.workers),
                                start=job.start)
        return sample(like, seed=job.stream, config=config.sampler(like.prior.ndim, workers=job.workers))


def _posterior(job: FitJob, res) -> dict:
    """An engine result -> what the diagnosis needs: model curves per test (in ``tests``), pointwise
    log-likelihood, convergence (:func:`posterior_record`); a cable fit's record also names the families
    the screen left unsampled (``screened``)."""
    record = posterior_record(job.target, job.tests, res)
    if job.screened is not None:
        record["screened"] = job.screened
    return record


def posterior_record(like, tests, res) -> dict:
    """A posterior of ``like`` (a test's or a cable state's, over ``tests``) as the diagnosis keeps it: draws,
    the posterior curves' mean, variance and median per test, pointwise log-likelihood, PSIS-LOO, convergence."""
    params = res.flat()
    joint = isinstance(like, JointLikelihood)
    mus = like.predict(params) if joint else [like.predict(params)]
    mu_mean, mu_var, mu_median = (list(m) for m in zip(*map(curve_moments, mus)))
    return dict(params=params, names=like.prior.names, log_lik=res.log_likelihood, mu_mean=mu_mean, mu_var=mu_var,
                mu_median=mu_median, convergence=res.convergence_dict(), converged=res.converged,
                result=res, like=like, n_params=like.prior.ndim, tests=tuple(tests), loo=loo(res.log_likelihood))


def screen_cable_jobs(jobs, config, label=None) -> list:
    """The jobs with each cable model's families screened (:func:`sbcal.inference.cable_start.screen`): the
    starts of every family and cable state made first, a family far below the best there dropped, the
    others started there (same stream: the draws they would have unscreened). Models with one family, or
    whose starts are given, are left as they are."""
    cable = {}
    for j in jobs:
        if isinstance(j.target, JointLikelihood) and j.start is None:
            cable.setdefault(j.key[0], {}).setdefault(j.key[2], {})[j.key[1]] = (j.target, j.stream)
    found = {name: screen(by_law, workers=config.workers, label=label) for name, by_law in cable.items()
             if len(by_law) > 1}
    out = []
    for j in jobs:
        if isinstance(j.target, JointLikelihood) and j.key[0] in found:
            modes, screened = found[j.key[0]]
            if j.key[2] in screened:
                continue
            j = replace(j, start=modes[j.key[2]][j.key[1]].z, screened=screened)
        out.append(j)
    return out


def run_fits(jobs, config, label) -> dict:
    """Run fits, ``config.workers`` at a time (the costly cable fits first); ``{key: fit}``. A batch of
    fewer fits than workers (a zoned law's one cable state) runs each fit's ensembles in parallel instead."""
    jobs = sorted(jobs, key=lambda j: not isinstance(j.target, JointLikelihood))
    if 0 < len(jobs) < config.workers:
        jobs = [replace(j, workers=config.workers // len(jobs)) for j in jobs]
    done = run_jobs(_fit, jobs, workers=config.workers, label=label, unit="fit")
    return {job.key: _posterior(job, res) for job, res in zip(jobs, done)}


def choose_law(fits: dict, name: str) -> tuple[dict, dict | None]:
    """For a cable model, keep the best family's fits (by PSIS-LOO summed over cable states):
    ``{(name, state): fit}``, and the comparison (None for per-test models)."""
    cable = {k: f for k, f in fits.items() if k[0] == name and len(k) == 3}
    if not cable:
        return {k: f for k, f in fits.items() if k[0] == name}, None
    by_law = {}
    for (_, state, law), f in cable.items():
        by_law.setdefault(law, {})[state] = CableFit(damper="", state=state, law=law, tests=(), effects=(),
                                                     result=f["result"], like=f["like"], loo=f["loo"])
    screened = {}  # what the screens of every batch left unsampled (a later batch's word last)
    for f in cable.values():
        screened.update(f.get("screened") or {})
    comparison = compare_families(by_law, {law: v for law, v in screened.items() if law not in by_law})
    best = comparison["best"]
    kept = {(name, state): dict(f, law=law) for (_, state, law), f in cable.items() if law == best}
    return kept, comparison


def late_laws(fits: dict, name: str) -> tuple:
    """The cable families of the model ``name`` that the screen left unsampled below a family whose posterior
    did not converge (:func:`sbcal.inference.cable_start.unscreened`): to be fitted after all."""
    _, comparison = choose_law(fits, name)
    if comparison is None:
        return ()
    return tuple(unscreened(comparison["screened"], {law: v["converged"] for law, v in comparison["families"].items()}))


def zoned_law(fits: dict, name: str, config: DiagnoseConfig) -> tuple[str | None, dict | None]:
    """The zoned family to fit next for the cable model ``name`` (:func:`sbcal.inference.cable_compare.zoned_candidate`:
    the highest-ELPD family's, converged or not, when the best converged family leaves a misfit in a cable
    state by the diagnosis's own rule, or none converged), and its start per cable state
    (:func:`sbcal.inference.cable_fit.zoned_start` from that family's fits); ``(None, None)`` when none."""
    kept, comparison = choose_law(fits, name)
    if comparison is None:
        return None, None
    partial = any(qualifier(predictive_check(f["like"].likes, f["mu_mean"], f["mu_var"], config.alpha, f["n_params"]),
                            config.global_alpha) == "partial" for f in kept.values())
    law = zoned_candidate(comparison, partial)
    if law is None or not compared_laws((law,), [t for f in kept.values() for t in f["tests"]]):
        return None, None
    top = law[:-len(ZONED_SUFFIX)]
    starts = {key[1]: zoned_start({n: float(np.median(v)) for n, v in f["params"].items()}, f["like"].prior)
              for key, f in fits.items() if key[0] == name and len(key) == 3 and key[2] == top}
    return law, starts
