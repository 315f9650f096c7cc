"""The thesis's point fit: a global least-squares search on its cost function (Eq. 4.5).

The thesis used MATLAB's genetic algorithm (population 500, up to 500 generations). Here scipy's
differential evolution, a well-kept evolutionary optimiser, stands in for it, vectorised over the
population. It initialises the sampler and is the baseline users can compare with
(``sbcal sample --method ga``): one number per parameter, no uncertainty.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution

from .likelihood import TestLikelihood

__all__ = ["PointFit", "fit_ga"]


@dataclass(frozen=True)
class PointFit:
    """Result of :func:`fit_ga`.

    Attributes
    ----------
    names : tuple of str
        Model parameters (the prior's, without the model-error scales).
    x : ndarray, shape (n_model,)
        Best parameters, natural units.
    cost : float
        The minimised cost at ``x``: the thesis's (Eq. 4.5) or the negative log-likelihood.
    n_evaluations : int
        Forward-model evaluations (parameter sets).
    generations : int
    wall_s : float
    """

    names: tuple
    x: np.ndarray
    cost: float
    n_evaluations: int
    generations: int
    wall_s: float

    def as_dict(self) -> dict:
        return {"parameters": dict(zip(self.names, map(float, self.x))), "cost": self.cost,
                "n_evaluations": self.n_evaluations, "generations": self.generations, "wall_s": self.wall_s}


def fit_ga(like: TestLikelihood, *, seed, population: int = 60, generations: int = 300, tol: float = 1e-6,
           polish: bool = True, cost: str = "thesis") -> PointFit:
    """Minimise the thesis's cost (or the negative log-likelihood) over the prior box.

    Parameters
    ----------
    like : TestLikelihood
        Supplies the data, the model and the prior box (log-uniform parameters searched in log).
    seed : int or numpy.random.Generator
    population : int
        Total population size (the thesis: 500).
    generations : int
        Maximum number of generations (the thesis: 500).
    tol : float
        scipy's relative convergence tolerance of the population's cost spread (the thesis's
        FunctionTolerance was 1e-6).
    polish : bool
        Finish with L-BFGS-B from the best member.
    cost : {"thesis", "likelihood"}
        ``"thesis"``: Eq. 4.5, the baseline. ``"likelihood"``: the negative log-likelihood with
        both model-error scales held at 0.1 (robust to the lines where the thesis's relative
        phase error explodes); the sampler starts from this one.
    """
    prior = like.prior
    im = [prior.names.index(n) for n in prior.model_names]
    lo, hi = prior.z_lower[im], prior.z_upper[im]
    ndim = len(im)
    # the error scales do not enter the thesis cost; the likelihood cost holds them at 0.1
    filler = prior.to_z(np.clip(np.full(prior.ndim, 0.1), prior.lower, prior.upper))[0]
    count = [0]

    def objective(zt):
        zt = np.atleast_2d(zt.T).reshape(-1, ndim)  # scipy passes (ndim, S) when vectorized
        z = np.tile(filler, (len(zt), 1))
        z[:, im] = zt
        x = prior.to_natural(z)
        c = np.full(len(zt), 1e10)
        ok = like._valid(x)
        if ok.any():
            c[ok] = like.thesis_cost(x[ok]) if cost == "thesis" else -like.log_likelihood(x[ok])
        count[0] += len(zt)
        return np.where(np.isfinite(c), c, 1e10)

    t0 = time.perf_counter()
    res = differential_evolution(
        objective, bounds=list(zip(lo, hi)), popsize=max(1, int(np.ceil(population / ndim))), maxiter=generations,
        tol=tol, seed=seed, polish=polish, vectorized=True, updating="deferred", init="sobol",
    )
    z = np.tile(filler, (1, 1))
    z[0, im] = res.x
    x = prior.to_natural(z)[0, im]
    return PointFit(names=prior.model_names, x=x, cost=float(res.fun), n_evaluations=count[0],
                    generations=int(res.nit), wall_s=time.perf_counter() - t0)
