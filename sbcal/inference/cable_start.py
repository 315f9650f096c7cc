"""Where a cable fit starts, and which families are worth sampling at all.

The start of a cable fit (:func:`cable_start`) is a global search of the box for the posterior mode; it is
also all a comparison of families needs to drop a family that cannot win (:func:`screen_families`): a law
whose best fit lies thousands of nats of log-likelihood below another's has an ELPD as far below, and
sampling it (a minute on the bundled bench) only to rank it last is waste. The kept families are sampled
from the same starts, with the same streams, so their draws are those of an unscreened comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution, least_squares, minimize
from scipy.stats import qmc

from ..core.workers import one_blas_thread, run_jobs
from .likelihood import JointLikelihood


__all__ = ["cable_start", "polish_mode", "fit_streams", "FamilyMode", "family_mode", "screen_families",
           "screen", "unscreened", "SCREEN_FLOOR", "SCREEN_PER_PARAMETER"]

SCREEN_FLOOR = 100.0
"""Nats: a family is never screened out by a smaller gap in log-likelihood at the mode."""
SCREEN_PER_PARAMETER = 10.0
"""Nats per parameter of the two families compared (over their cable states): the screen's margin.

Why this is safe: for a regular posterior the ELPD sits about ``d`` below the log-likelihood at the mode (the
asymptotics behind AIC), so the ELPD gap of two families is about their mode gap less the difference of
their parameter counts. A margin of ``10 (d_a + d_b)`` lets either family's shortfall exceed its regular
value several times over (a misspecified law, heavy-tailed runs: measured 1.4-4.5 nats a parameter) before
the screen could drop a family that would have ranked first. On the bundled bench the mode gap of
Bouc-Wen to Iwan is 13 446 nats against an ELPD gap of 13 417 +- 390 (damper1; threshold 320)."""


def _residuals(like: JointLikelihood, z) -> np.ndarray:
    """Run means minus model over the noise's scale of a mean, every test and line: ``(n, n_values)``
    at sampled coordinates ``z`` (n, ndim); 1e3 where the model fails."""
    out = []
    for lk, mu in zip(like.likes, like.predict(like.prior.params(np.atleast_2d(z)))):
        r = lk.residual(mu) / np.sqrt(lk.sigma ** 2 / lk.n)[:, None, :]
        out.append(np.moveaxis(r, 1, 0).reshape(mu.shape[1], -1))
    r = np.concatenate(out, axis=1)
    return np.where(np.isfinite(r), r, 1e3)


_START_DESIGN = 512  # Sobol points over the box
_START_BEST = 6  # of which the best are refined
_START_NFEV = 60  # Gauss-Newton iterations per refinement
_START_DE = (6, 60)  # differential evolution: population per dimension, generations


def polish_mode(like: JointLikelihood, z0) -> tuple[np.ndarray, float]:
    """L-BFGS-B ascent of the log-posterior within the box from ``z0`` (value and central-difference
    gradient in one batched call); ``(z, log-posterior)``.

    Not the engine's :func:`sbcal.inference.start.ascend`, which runs a test's ascents side by side: a cable
    likelihood costs in proportion to the parameter sets of a call, so side by side gains nothing (damper1's
    dry cable under ``iwan5``, :func:`cable_start`'s 7 candidates beside another job: 17.0 s one after another,
    25.2 s side by side, whose ends also differ: the engine's one-sided differences on a bound take another
    path, the best end 10.6 nats lower)."""
    prior = like.prior
    lo, hi = prior.z_lower, prior.z_upper
    h = 1e-6 * (hi - lo)
    eye = np.diag(h)

    def cost(z):
        lp = like(np.vstack([z, z + eye, z - eye]))
        lp = np.where(np.isfinite(lp), lp, -1e100)
        d = prior.ndim
        return -lp[0], -(lp[1:d + 1] - lp[d + 1:]) / (2 * h)

    z0 = np.clip(z0, lo + 2 * h, hi - 2 * h)
    res = minimize(cost, z0, jac=True, method="L-BFGS-B", bounds=list(zip(lo + h, hi - h)), options={"maxiter": 300})
    z = res.x if -res.fun >= like(z0[None])[0] else z0
    return z, float(like(z[None])[0])


def cable_start(like: JointLikelihood, rng: np.random.Generator) -> np.ndarray:
    """The start of a cable fit in sampled coordinates ``(ndim,)``: the highest log-posterior of
    several local ascents (:func:`polish_mode`) from distinct places of the box.

    Candidates: Gauss-Newton least-squares descents (trust region within the box, soft-L1 loss on
    the run means' standardised residuals, forward-difference Jacobian in one batched model call)
    from the best points of a Sobol design, and the best of a differential-evolution search on the
    log-posterior. Each kind alone stops in a wrong place on some data: differential evolution on a
    plateau where a cut-off runs to its bound and the law stops changing within the bench's
    curvatures (damper1's dry cable under ``iwan5``: ``chi_macro`` at 1/m, 720 below the mode in
    log-posterior; two of four ensembles stayed there), least squares in a local mode of the
    least-squares cost that is not the posterior's (``bouc_wen``, whose misfit is many noise scales,
    where the robust t likelihood weighs residuals differently).
    """
    prior = like.prior
    lo, hi = prior.z_lower, prior.z_upper
    s_sobol, s_de = rng.spawn(2)
    z = lo + (hi - lo) * qmc.Sobol(prior.ndim, seed=s_sobol).random(_START_DESIGN)
    lp = np.concatenate([like(z[i:i + 128]) for i in range(0, len(z), 128)])
    step = 1e-6 * (hi - lo)

    def jac(zz):
        h = np.where(zz + step <= hi, step, -step)
        r = _residuals(like, np.vstack([zz, zz + np.diag(h)]))
        return ((r[1:] - r[0]) / h[:, None]).T

    candidates = []
    for z0 in z[np.argsort(-lp)[:_START_BEST]]:
        z0 = np.clip(z0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        res = least_squares(lambda zz: _residuals(like, zz)[0], z0, jac=jac, bounds=(lo, hi), loss="soft_l1",
                            f_scale=3.0, max_nfev=_START_NFEV)
        candidates.append(res.x)

    def cost(zt):  # scipy passes (ndim, S) when vectorized
        v = like(np.atleast_2d(zt.T).reshape(-1, prior.ndim))
        return np.where(np.isfinite(v), -v, 1e100)

    per_dim, generations = _START_DE
    de = differential_evolution(cost, bounds=list(zip(lo, hi)), popsize=per_dim, maxiter=generations, tol=1e-6,
                                seed=s_de, polish=False, vectorized=True, updating="deferred", init="sobol")
    candidates.append(de.x)
    best = max((polish_mode(like, c) for c in candidates), key=lambda t: t[1])
    return best[0]


# --- the family screen ------------------------------------------------------------------------------

def fit_streams(seed: np.random.SeedSequence) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """A cable fit's two streams, the start's and the engine's: the next two children of ``seed``, made
    from a copy so that asking again gives the same two (the screen's start is the fit's own)."""
    copy = np.random.SeedSequence(seed.entropy, spawn_key=seed.spawn_key, pool_size=seed.pool_size,
                                  n_children_spawned=seed.n_children_spawned)
    s_start, s_sample = copy.spawn(2)
    return s_start, s_sample


@dataclass(frozen=True)
class FamilyMode:
    """One cable state's start under one family.

    Attributes
    ----------
    z : ndarray, shape (ndim,)
        The start (:func:`cable_start`) in sampled coordinates.
    log_lik : float
        The log-likelihood there, summed over the runs of every test as PSIS-LOO scores them
        (``JointLikelihood.pointwise_log_likelihood``); ``-inf`` where the model fails.
    ndim : int
    """

    z: np.ndarray
    log_lik: float
    ndim: int


def family_mode(job) -> FamilyMode:
    """:class:`FamilyMode` of ``job = (like, seed)``: a cable state's likelihood and its fit's stream (a
    module-level function of one job, for :func:`sbcal.core.workers.run_jobs`)."""
    like, seed = job
    z = cable_start(like, np.random.default_rng(fit_streams(seed)[0]))
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        ll = float(like.pointwise_log_likelihood(like.prior.params(z[None])).sum())
    return FamilyMode(z=z, log_lik=ll if np.isfinite(ll) else -np.inf, ndim=like.prior.ndim)


def screen_families(modes: dict) -> dict:
    """The families not worth sampling: those whose start lies further below the best family's, in
    log-likelihood summed over the cable states, than :data:`SCREEN_PER_PARAMETER` nats per parameter of
    the two (at least :data:`SCREEN_FLOOR`).

    Parameters
    ----------
    modes : dict
        ``{law: {state: FamilyMode}}``, the same states for every law.

    Returns
    -------
    dict
        ``{law: {"log_lik_gap": nats, "threshold": nats, "below": best law}}`` of the screened families
        (JSON-ready; empty when every family is kept, or when no family's start has a finite likelihood).
    """
    total = {law: sum(m.log_lik for m in ms.values()) for law, ms in modes.items()}
    dims = {law: sum(m.ndim for m in ms.values()) for law, ms in modes.items()}
    best = max(total, key=total.get)
    if not np.isfinite(total[best]):
        return {}
    out = {}
    for law in sorted(total):
        gap = total[best] - total[law]
        threshold = max(SCREEN_FLOOR, SCREEN_PER_PARAMETER * (dims[law] + dims[best]))
        if gap > threshold:
            out[law] = {"log_lik_gap": float(gap) if np.isfinite(gap) else None, "threshold": threshold,
                        "below": best}
    return out


def _mode_job(job) -> FamilyMode:
    with one_blas_thread():  # one process a core
        return family_mode(job)


def screen(jobs: dict, *, workers: int = 1, label: str | None = None) -> tuple[dict, dict]:
    """Every family's start, then :func:`screen_families`: ``(modes, screened)``.

    ``jobs``: ``{law: {state: (like, seed)}}`` (a cable state's likelihood under the law, the fit's
    stream); the starts are made in ``workers`` processes. ``modes`` is ``{law: {state: FamilyMode}}``:
    a kept family's fit starts from ``modes[law][state].z`` with the same stream, so its draws are the
    ones it would have without the screen."""
    keys = [(law, state) for law in jobs for state in jobs[law]]
    done = run_jobs(_mode_job, [jobs[law][state] for law, state in keys], workers=workers, label=label,
                    unit="start")
    modes = {}
    for (law, state), mode in zip(keys, done):
        modes.setdefault(law, {})[state] = mode
    return modes, screen_families(modes)


def unscreened(screened: dict, converged: dict) -> list:
    """The screened families to sample after all: those screened below a family whose posterior did not
    converge (``converged``: ``{law: bool}`` of the sampled families). A comparison rests on converged
    posteriors only (:func:`sbcal.inference.cable_compare.compare_families`), so a family far below one that
    cannot be used is a candidate again: sampled, it may be the best converged family."""
    return sorted(law for law, v in screened.items() if not converged.get(v["below"], True))
