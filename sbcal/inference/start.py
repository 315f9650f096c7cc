"""The sampling engine's start (:func:`sbcal.inference.sampler.sample`, step 1): the posterior mode and the
walkers drawn around it.

- :func:`find_mode`: a caller's start polished, or else the best of local ascents from a
  differential-evolution search and a Sobol design of the prior box (:func:`start_points`);
- :func:`ascend`: local L-BFGS-B ascents inside the box, several side by side with one vectorised call of
  the log-density per round (a cable fit's start uses it too);
- :func:`laplace`: the covariance of the Laplace approximation at the mode;
- :func:`initial_walkers`: an ensemble's walkers drawn from it (spreads capped, :func:`capped_cov`).

Every function works in the prior's sampled coordinates ``z`` and takes a *target* as the engine does
(``target.prior``, ``target(z) -> (n,)``).
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.optimize import differential_evolution, minimize
from scipy.stats import qmc

__all__ = ["ascend", "capped_cov", "find_mode", "initial_walkers", "laplace", "start_points",
           "START_DESIGN", "START_ASCENTS"]

_BIG = 1e100  # the cost outside the support (differential evolution needs a finite one)
START_DESIGN, START_ASCENTS = 1024, 32  # a Sobol design of the box, local ascents from its best points


def _cost(target):
    def cost(zt):
        zt = np.atleast_2d(zt.T).reshape(-1, target.prior.ndim)  # scipy passes (ndim, S) when vectorized
        lp = target(zt)
        return np.where(np.isfinite(lp), -lp, _BIG)
    return cost


class _Lockstep:
    """One vectorised call of ``cost`` per round for several optimisers run side by side, one per thread.

    Each optimiser's objective hands its points over and waits; when every optimiser still running has
    handed its points over, they are evaluated in one call, in the optimisers' order. A per-test target's
    call is mostly overhead (damper1 0.5 mm: 0.36 ms for 7 points, 1.7 ms for 363), so the start's 33
    ascents cost a few times one, not 33. The rounds and their contents depend only on the values, not on
    the threads' timing: the same seed gives the same ends."""

    def __init__(self, cost, n: int):
        self.cost, self.active = cost, n
        self.pending, self.results, self.error = {}, {}, None
        self.cond = threading.Condition()

    def __call__(self, i: int, zt: np.ndarray) -> np.ndarray:
        with self.cond:
            self.pending[i] = zt
            self._maybe_run()
            self.cond.wait_for(lambda: i in self.results or self.error is not None)
            if self.error is not None:
                raise self.error
            return self.results.pop(i)

    def done(self) -> None:
        with self.cond:
            self.active -= 1
            self._maybe_run()

    def _maybe_run(self) -> None:
        if not self.pending or len(self.pending) < self.active:
            return
        keys = sorted(self.pending)
        blocks = [self.pending.pop(k) for k in keys]
        try:
            c = self.cost(np.hstack(blocks))
        except BaseException as e:  # every waiting optimiser re-raises it
            self.error = e
        else:
            for k, part in zip(keys, np.split(c, np.cumsum([b.shape[1] for b in blocks])[:-1])):
                self.results[k] = part
        self.cond.notify_all()


def ascend(target, starts, *, central: bool = True) -> list[tuple[np.ndarray, float]]:
    """Local ascents of the log-density inside the box (L-BFGS-B), one from each of ``starts`` (n, ndim),
    side by side (:class:`_Lockstep`); ``[(z, cost)]``, each end no worse than its start.

    ``central``: the gradient by central differences, the ``2 ndim + 1`` points in one call (one-sided on a
    bound); else scipy's forward differences, one point a call (a caller's start, polished as before)."""
    prior = target.prior
    lo, hi = prior.z_lower, prior.z_upper
    h, eye = 1e-6 * (hi - lo), np.eye(prior.ndim, dtype=bool)
    starts = np.atleast_2d(starts)
    batch = _Lockstep(_cost(target), len(starts))

    def one(i):
        z0 = starts[i]
        try:
            f0 = batch(i, z0[:, None])[0]
            if central:
                def fun(z):
                    up, down = np.minimum(z + h, hi), np.maximum(z - h, lo)
                    c = batch(i, np.vstack([z, np.where(eye, up, z), np.where(eye, down, z)]).T)
                    return c[0], (c[1:prior.ndim + 1] - c[prior.ndim + 1:]) / (up - down)
            else:
                def fun(z):
                    return batch(i, z[:, None])[0]
            res = minimize(fun, z0, jac=central, method="L-BFGS-B", bounds=list(zip(lo, hi)),
                           options={"maxiter": 1000})
        finally:
            batch.done()
        return (res.x, float(res.fun)) if np.isfinite(res.fun) and res.fun <= f0 else (z0, float(f0))

    if len(starts) == 1:
        return [one(0)]
    with ThreadPoolExecutor(len(starts)) as pool:
        return list(pool.map(one, range(len(starts))))


def _inside(prior, z) -> np.ndarray:
    """``z`` moved just inside the box (an ascent's start on a bound has no gradient across it)."""
    width = prior.z_upper - prior.z_lower
    return np.clip(z, prior.z_lower + 1e-9 * width, prior.z_upper - 1e-9 * width)


def start_points(target, rng, config) -> np.ndarray:
    """Where :func:`find_mode` ascends from when no start is given, ``(START_ASCENTS + 1, ndim)``: the best point of
    a differential-evolution search over the box, then the ``START_ASCENTS`` best of a Sobol design of it."""
    prior = target.prior
    lo, hi = prior.z_lower, prior.z_upper
    cost = _cost(target)
    res = differential_evolution(cost, bounds=list(zip(lo, hi)), popsize=max(1, math.ceil(config.de_population / prior.ndim)),
                                 maxiter=config.de_generations, tol=1e-6, seed=rng, polish=False, vectorized=True,
                                 updating="deferred", init="sobol")
    design = lo + (hi - lo) * qmc.Sobol(prior.ndim, seed=rng).random(START_DESIGN)
    return _inside(prior, np.vstack([res.x, design[np.argsort(cost(design.T), kind="stable")[:START_ASCENTS]]]))


def find_mode(target, start, rng, config) -> np.ndarray:
    """The posterior mode in ``z``: ``start`` polished by L-BFGS-B, or else the best of local ascents
    (:func:`ascend`) from the best point of a differential-evolution search over the box and from the
    ``START_ASCENTS`` best points of a Sobol design of it. The search alone is not enough: its population
    can collapse into one mode of a posterior with several (damper1's viscous damping at 0.1 mm: material
    damping alone, viscous alone, or a mix, 16 nats apart; the search found the lowest)."""
    if start is None:
        return min(ascend(target, start_points(target, rng, config)), key=lambda e: e[1])[0]
    # a caller's start (a cable fit's own search, a population's): polished by scipy's forward differences, as
    # before the ascents. Polished by central differences it ends ~1e-4 away, and tests/test_population.py's
    # joint fit of population and units, which that moves onto another path, then stops at the step cap
    # (tau 345): a fit that converges on one path and not on another, kept as it was until its mixing is
    # looked at.
    prior = target.prior
    z0 = prior.z_of(start)[0] if isinstance(start, dict) else np.asarray(start, float)
    return ascend(target, _inside(prior, z0)[None], central=False)[0][0]


def laplace(target, z0) -> tuple:
    """``(cov, full)``: the covariance of the Laplace approximation at the mode ``z0`` (finite-difference
    Hessian of the log-density in one batched call, a few steps inside the box where the mode is on a
    bound) and True; where the Hessian is not negative definite, the diagonal one of each parameter's
    own curvature and False, or ``(None, False)`` where that is not negative either or the log-density is
    not finite beside the mode."""
    prior = target.prior
    d = prior.ndim
    h = 1e-4 * (prior.z_upper - prior.z_lower)
    z0 = np.clip(z0, prior.z_lower + 2.5 * h, prior.z_upper - 2.5 * h)
    e = np.eye(d) * h
    pts = [z0]
    for i in range(d):
        for j in range(i, d):
            pts += [z0 + e[i] + e[j], z0 + e[i] - e[j], z0 - e[i] + e[j], z0 - e[i] - e[j]]
    lp = target(np.array(pts))
    if not np.all(np.isfinite(lp)):
        return None, False
    hess = np.empty((d, d))
    k = 1
    for i in range(d):
        for j in range(i, d):
            hess[i, j] = hess[j, i] = (lp[k] - lp[k + 1] - lp[k + 2] + lp[k + 3]) / (4 * h[i] * h[j])
            k += 4
    try:
        cov = np.linalg.inv(-hess)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        # not a maximum in every direction (a mode on a bound, a kink of the model): each parameter's
        # own curvature, where that is negative
        curv = -np.diag(hess)
        return (np.diag(1.0 / curv), False) if np.all(curv > 0) else (None, False)
    return cov, True


def capped_cov(prior, cov) -> np.ndarray:
    """The Laplace covariance with every spread capped at a tenth of the box."""
    sd = np.sqrt(np.diag(cov))
    cap = np.minimum(1.0, 0.1 * (prior.z_upper - prior.z_lower) / sd)
    return cov * np.outer(cap, cap)


def initial_walkers(target, z0, cov, nwalkers, rng) -> np.ndarray:
    """Walkers around the mode, all inside the box with finite log-probability: drawn from the
    Laplace approximation (no burn-in transient while the ensemble expands; its spread capped at a
    tenth of the box, for directions the mode barely constrains) or, without one, from a small ball."""
    prior = target.prior
    width = prior.z_upper - prior.z_lower
    chol = None if cov is None else np.linalg.cholesky(capped_cov(prior, cov))
    p0 = np.empty((nwalkers, prior.ndim))
    filled, scale = 0, 1.0 if cov is not None else 1e-3
    for _ in range(60):
        normal = rng.standard_normal((nwalkers, prior.ndim))
        cand = z0 + scale * (normal @ chol.T if cov is not None else width * normal)
        # reflect into the box once (a clip would pile walkers on a bound); what is still out is drawn again
        cand = np.where(cand < prior.z_lower, 2 * prior.z_lower - cand, cand)
        cand = np.where(cand > prior.z_upper, 2 * prior.z_upper - cand, cand)
        inside = np.all((cand >= prior.z_lower) & (cand <= prior.z_upper), axis=1)
        cand = cand[inside]
        ok = cand[np.isfinite(target(cand))] if len(cand) else cand
        take = min(len(ok), nwalkers - filled)
        p0[filled:filled + take] = ok[:take]
        filled += take
        if filled == nwalkers:
            return p0
        scale *= 0.7
    raise ValueError("no finite log-probability near the start: the target is -inf around its mode")
