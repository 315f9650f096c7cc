"""Posterior sampling with emcee: several independently seeded ensembles, run to convergence.

Each ensemble is an ``emcee.EnsembleSampler`` (``vectorize=True``, differential-evolution moves)
started in a small ball around the point fit of :mod:`sbcal.ga` refined to the posterior mode. An
ensemble runs in blocks until its chain is longer than ``tau_factor`` integrated autocorrelation
times (after discarding the first ``burn_fraction`` as burn-in) or ``max_steps`` is reached; the
kept chain is thinned by half the smallest autocorrelation time. R-hat compares the ensembles
(R-hat across the walkers of one ensemble is not meaningful: they are not independent).
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field

import emcee
import numpy as np
from scipy.optimize import minimize

from .ga import PointFit, fit_ga
from .likelihood import TestLikelihood

__all__ = ["SamplerConfig", "SampleResult", "sample"]


@dataclass(frozen=True)
class SamplerConfig:
    """Sampler settings (stored with every run).

    Attributes
    ----------
    nwalkers : int
        Walkers per ensemble (at least ``2 ndim + 2``; raised automatically).
    n_ensembles : int
        Independently seeded ensembles (the chains of R-hat).
    tau_factor : float
        Run until the kept chain is longer than this many autocorrelation times.
    burn_fraction : float
        Fraction of each chain discarded as burn-in.
    check_every : int
        Steps between convergence checks.
    max_steps : int
        Cap on steps per ensemble (a run that hits it is flagged not converged).
    max_draws : int
        Draws kept per ensemble after thinning (further thinned evenly beyond this).
    ga_population, ga_generations : int
        The initialising point fit.
    workers : int
        Processes for the ensembles (they are independent; the draws do not depend on it);
        default 2 where there are 2 cores, 1 runs them in this process.
    """

    nwalkers: int = 24
    n_ensembles: int = 4
    tau_factor: float = 50.0
    burn_fraction: float = 0.2
    check_every: int = 200
    max_steps: int = 20000
    max_draws: int = 1000
    ga_population: int = 60
    ga_generations: int = 200
    workers: int = max(1, min(2, os.cpu_count() or 1))


@dataclass(frozen=True)
class SampleResult:
    """Draws of one posterior.

    Attributes
    ----------
    names : tuple of str
    x : ndarray, shape (n_ensembles, n_draws, ndim)
        Draws in natural units; within an ensemble the draws of each walker are consecutive.
    log_prob : ndarray, shape (n_ensembles, n_draws)
    acceptance : ndarray, shape (n_ensembles,)
        Mean acceptance fraction.
    tau : ndarray, shape (n_ensembles, ndim)
        Integrated autocorrelation time [steps] of the kept chain.
    n_steps : ndarray of int, shape (n_ensembles,)
    burn, thin : ndarray of int, shape (n_ensembles,)
    converged : bool
        Every ensemble reached ``tau_factor`` autocorrelation times.
    init : PointFit
        The thesis-cost point fit (reported as the baseline; the chains start from a likelihood fit).
    wall_s : float
    config : SamplerConfig
    """

    names: tuple
    x: np.ndarray
    log_prob: np.ndarray
    acceptance: np.ndarray
    tau: np.ndarray
    n_steps: np.ndarray
    burn: np.ndarray
    thin: np.ndarray
    converged: bool
    init: PointFit
    wall_s: float
    config: SamplerConfig = field(default_factory=SamplerConfig)

    def config_dict(self) -> dict:
        return asdict(self.config)


def _mode(like: TestLikelihood, fit: PointFit) -> np.ndarray:
    """Posterior mode in z, started from a point fit (model-error scales from its residuals)."""
    prior = like.prior
    x = np.empty(prior.ndim)
    x[[prior.names.index(n) for n in prior.model_names]] = fit.x
    r = like._residual(like.predict(x[None]))[:, 0]  # (2, n_freq); the scales do not enter mu
    # moment estimate of the discrepancy variance: mean squared residual minus the noise share
    excess = np.mean(r**2 - like.sigma**2 / like.n, axis=1)
    for q, name in enumerate(("sigma_mag", "sigma_phase")):
        i = prior.names.index(name)
        x[i] = np.clip(np.sqrt(max(excess[q], 0.0)), prior.lower[i] * 1.01, prior.upper[i] * 0.99)
    lo, hi = prior.z_lower, prior.z_upper
    z0 = np.clip(prior.to_z(x)[0], lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    res = minimize(lambda z: -like(z)[0], z0, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                   options={"maxiter": 500})
    return res.x if np.isfinite(res.fun) and res.fun <= -like(z0)[0] else z0


def _ball(like: TestLikelihood, z0, nwalkers, rng) -> np.ndarray:
    """Walkers in a small ball around ``z0``, all with finite log-probability."""
    prior = like.prior
    width = prior.z_upper - prior.z_lower
    p0 = np.empty((nwalkers, prior.ndim))
    filled = 0
    scale = 1e-3
    while filled < nwalkers:
        cand = z0 + scale * width * rng.standard_normal((nwalkers, prior.ndim))
        cand = np.clip(cand, prior.z_lower, prior.z_upper)
        ok = cand[np.isfinite(like(cand))]
        take = min(len(ok), nwalkers - filled)
        p0[filled:filled + take] = ok[:take]
        filled += take
        scale *= 0.5
    return p0


class _Progress:
    """A one-line progress display on stderr (rewritten in place on a terminal)."""

    def __init__(self, label: str, enabled: bool):
        self.label, self.enabled = label, enabled
        self.tty = enabled and sys.stderr.isatty()
        self.last = 0.0

    def __call__(self, text: str, final: bool = False):
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            sys.stderr.write(f"\r{self.label}: {text}\033[K" + ("\n" if final else ""))
        elif final or now - self.last > 5:
            sys.stderr.write(f"{self.label}: {text}\n")
        else:
            return
        self.last = now
        sys.stderr.flush()


def _run_ensemble(job):
    """One independently seeded ensemble, run to convergence; module-level so processes can run it."""
    like, z0, ss, nwalkers, config, progress, e = job
    prior = like.prior
    ndim = prior.ndim
    show = _Progress(progress or "", progress is not None)
    rng = np.random.default_rng(ss)
    p0 = _ball(like, z0, nwalkers, rng)
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(nwalkers, ndim, like, vectorize=True, moves=moves)
    state = emcee.State(p0, random_state=np.random.RandomState(rng.integers(2**32)).get_state())
    n = 0
    while True:
        state = sampler.run_mcmc(state, config.check_every, progress=False)
        n += config.check_every
        burn = int(config.burn_fraction * n)
        tau = sampler.get_autocorr_time(discard=burn, quiet=True, tol=0)
        done = (n - burn) >= config.tau_factor * np.max(tau)
        show(f"ensemble {e + 1}/{config.n_ensembles}, step {n}, tau {np.max(tau):.0f}, "
             f"need {config.tau_factor * np.max(tau) / (1 - config.burn_fraction):.0f} steps")
        if done or n >= config.max_steps:
            break
    thin = max(1, int(0.5 * np.min(tau)))
    chain = sampler.get_chain(discard=burn, thin=thin)  # (steps, walkers, ndim)
    lp = sampler.get_log_prob(discard=burn, thin=thin)
    chain = np.swapaxes(chain, 0, 1).reshape(-1, ndim)  # walker-major
    lp = lp.T.reshape(-1)
    if len(chain) > config.max_draws:
        keep = np.linspace(0, len(chain) - 1, config.max_draws).round().astype(int)
        chain, lp = chain[keep], lp[keep]
    return (prior.to_natural(chain), lp, float(np.mean(sampler.acceptance_fraction)), tau, n, burn, thin,
            bool(done))


def sample(like: TestLikelihood, *, seed: int, config: SamplerConfig = SamplerConfig(),
           progress: str | None = None) -> SampleResult:
    """Sample the posterior of one likelihood.

    Parameters
    ----------
    like : TestLikelihood
        The log-posterior (``like(z)`` in the prior's sampled coordinates).
    seed : int
        Seeds the point fit and every ensemble (through ``numpy.random.SeedSequence``): the same
        seed gives the same draws.
    config : SamplerConfig
    progress : str, optional
        A label; when given, progress is shown on stderr.

    Returns
    -------
    SampleResult
    """
    t0 = time.perf_counter()
    prior = like.prior
    ndim = prior.ndim
    nwalkers = max(config.nwalkers, 2 * ndim + 2)
    nwalkers += nwalkers % 2
    show = _Progress(progress or "", progress is not None)
    seqs = np.random.SeedSequence(seed).spawn(config.n_ensembles + 1)  # the same draws for any `workers`
    show("point fits (differential evolution)")
    ga_rng = np.random.default_rng(seqs[0])
    fit = fit_ga(like, seed=ga_rng, population=config.ga_population, generations=config.ga_generations)
    start = fit_ga(like, seed=ga_rng, population=config.ga_population, generations=config.ga_generations,
                   cost="likelihood")
    z0 = _mode(like, start)
    jobs = [(like, z0, ss, nwalkers, config, progress, e) for e, ss in enumerate(seqs[1:])]
    if config.workers > 1 and config.n_ensembles > 1:
        # the ensembles are independent: one process each, up to `workers` at a time
        with ProcessPoolExecutor(max_workers=min(config.workers, config.n_ensembles)) as pool:
            runs = list(pool.map(_run_ensemble, jobs))
    else:
        runs = [_run_ensemble(job) for job in jobs]
    xs, lps, acc, taus, steps, burns, thins, done = (list(v) for v in zip(*runs))
    converged = all(done)
    n_draws = min(len(x) for x in xs)
    result = SampleResult(
        names=prior.names, x=np.stack([x[:n_draws] for x in xs]), log_prob=np.stack([lp[:n_draws] for lp in lps]),
        acceptance=np.array(acc), tau=np.array(taus), n_steps=np.array(steps), burn=np.array(burns),
        thin=np.array(thins), converged=converged, init=fit, wall_s=time.perf_counter() - t0, config=config,
    )
    show(f"done in {result.wall_s:.1f} s, acceptance {result.acceptance.mean():.2f}", final=True)
    return result
