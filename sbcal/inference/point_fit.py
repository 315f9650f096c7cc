"""The thesis's point fit: a global least-squares search on its cost function (Eq. 4.5).

The thesis used MATLAB's genetic algorithm (population 500, up to 500 generations). Here scipy's
differential evolution, a well-kept evolutionary optimiser, stands in for it, vectorised over the
population. It is the baseline users can compare with (``sbcal sample --method point``, alias ``ga``, and ``ga`` in
every run's ``summary.json``): one number per parameter, no uncertainty.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution

from .likelihood import TestLikelihood


__all__ = ["EDGE", "PointFit", "fit_thesis_cost"]

EDGE = 1e-3
"""A best value this close to a bound, as a fraction of the box's width, sits on the bound."""


@dataclass(frozen=True)
class PointFit:
    """Result of :func:`fit_thesis_cost`.

    Attributes
    ----------
    names : tuple of str
        Model parameters (the prior's, without the model-error scales).
    x : ndarray, shape (n_model,)
        Best parameters, natural units.
    cost : float
        The minimised thesis cost at ``x`` (Eq. 4.5).
    n_evaluations : int
        Forward-model evaluations (parameter sets).
    generations : int
    wall_s : float
    on_bound : tuple of str
        Parameters whose best value lies on an edge of the search box (within :data:`EDGE` of its
        width, in the searched coordinate): the prior's bounds, not the data, set them.
    """

    names: tuple
    x: np.ndarray
    cost: float
    n_evaluations: int
    generations: int
    wall_s: float
    on_bound: tuple = ()

    def as_dict(self) -> dict:
        return {"parameters": dict(zip(self.names, map(float, self.x))), "cost": self.cost,
                "n_evaluations": self.n_evaluations, "generations": self.generations, "wall_s": self.wall_s,
                "on_bound": list(self.on_bound)}


def fit_thesis_cost(like: TestLikelihood, *, seed, population: int = 60, generations: int = 300, tol: float = 1e-6,
           polish: bool = True, callback=None) -> PointFit:
    """Minimise the thesis's cost (Eq. 4.5) over the prior box of the model parameters.

    Parameters
    ----------
    like : TestLikelihood
        Supplies the data, the model and the prior box (log-uniform parameters searched in log);
        the model-error scales do not enter the thesis's cost.
    seed : int or numpy.random.Generator
    population : int
        Total population size (the thesis: 500).
    generations : int
        Maximum number of generations (the thesis: 500).
    tol : float
        scipy's relative convergence tolerance of the population's cost spread.
    polish : bool
        Finish with L-BFGS-B from the best member.
    callback : callable, optional
        scipy's ``callback(intermediate_result)``, called once per generation; returning True stops
        the search (a stopping rule of the caller's, e.g. MATLAB ``ga``'s stall test).
    """
    prior = like.prior
    names = prior.model_names
    im = [prior.names.index(n) for n in names]
    lo, hi = prior.z_lower[im], prior.z_upper[im]
    log_scale = prior.log_scale[im]
    ndim = len(im)
    count = [0]

    def objective(zt):
        zt = np.atleast_2d(zt.T).reshape(-1, ndim)  # scipy passes (ndim, S) when vectorized
        x = np.where(log_scale, np.exp(zt), zt)
        params = {n: x[:, i] for i, n in enumerate(names)}
        c = np.full(len(zt), 1e10)
        ok = like.valid(params)
        if ok.any():
            c[ok] = like.thesis_cost({n: v[ok] for n, v in params.items()})
        count[0] += len(zt)
        return np.where(np.isfinite(c), c, 1e10)

    t0 = time.perf_counter()
    res = differential_evolution(
        objective, bounds=list(zip(lo, hi)), popsize=max(1, int(np.ceil(population / ndim))), maxiter=generations,
        tol=tol, seed=seed, polish=polish, vectorized=True, updating="deferred", init="sobol", callback=callback,
    )
    x = np.where(log_scale, np.exp(res.x), res.x)
    edge = EDGE * (hi - lo)
    on_bound = tuple(n for n, z, a, b, e in zip(names, res.x, lo, hi, edge) if z - a <= e or b - z <= e)
    return PointFit(names=names, x=x, cost=float(res.fun), n_evaluations=count[0],
                    generations=int(res.nit), wall_s=time.perf_counter() - t0, on_bound=on_bound)
