"""Posterior statistics through ArviZ: convergence diagnostics, PSIS-LOO and ELPD differences.

The only module that imports ArviZ (``arviz>=0.20,<1``; 1.x replaced ``InferenceData`` and needs
Python >= 3.12), so a change of ArviZ touches one file. Every array here keeps the real chain
structure, ``(chain, draw, ...)``: a chain is one independently seeded emcee ensemble, its draws the
thinned steps of its walkers, walker after walker (see :mod:`sbcal.inference.sampler`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp


# ArviZ 0.x announces its 1.x refactor once a day on import; the bound arviz<1 is the answer to it
_REFACTOR_NOTICE = r"\s*ArviZ is undergoing a major refactor"
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=_REFACTOR_NOTICE, category=FutureWarning)
    import arviz as az

__all__ = ["convergence", "Loo", "loo", "elpd_difference", "CLEAR_SE", "arviz_version", "inference_data", "read_netcdf"]


def arviz_version() -> str:
    return az.__version__


def inference_data(**groups):
    """``arviz.from_dict`` (groups such as ``posterior``, ``log_likelihood``, ``coords``, ``dims``)."""
    return az.from_dict(**groups)


def read_netcdf(path):
    """``arviz.from_netcdf``: a stored run's InferenceData."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_REFACTOR_NOTICE, category=FutureWarning)
        return az.from_netcdf(str(path))


def convergence(draws: dict) -> dict:
    """Rank-normalised split R-hat, bulk and tail ESS of every parameter.

    Parameters
    ----------
    draws : dict of str -> ndarray, shape (n_chains, n_draws)

    Returns
    -------
    dict of str -> {"r_hat", "ess_bulk", "ess_tail"}
        The same numbers ``arviz.summary`` prints for these draws.
    """
    idata = az.from_dict(posterior={n: np.asarray(v, float) for n, v in draws.items()})
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        # constant draws: ArviZ warns and returns NaN, which we keep (a deprecation still shows)
        for category in (UserWarning, RuntimeWarning):
            warnings.simplefilter("ignore", category)
        r = az.rhat(idata, method="rank")
        bulk = az.ess(idata, method="bulk")
        tail = az.ess(idata, method="tail")
    return {n: {"r_hat": float(r[n]), "ess_bulk": float(bulk[n]), "ess_tail": float(tail[n])} for n in draws}


@dataclass(frozen=True)
class Loo:
    """PSIS-LOO of one model.

    Attributes
    ----------
    pointwise : ndarray, shape (n_points,)
        Expected log predictive density of each left-out point (a run).
    pareto_k : ndarray, shape (n_points,)
        Pareto smoothing diagnostic (> 0.7: the estimate of that point is unreliable).
    elpd, se : float
        Sum of ``pointwise`` and its standard error ``sqrt(n var)``.
    """

    pointwise: np.ndarray
    pareto_k: np.ndarray
    elpd: float
    se: float


def loo(log_lik) -> Loo:
    """PSIS-LOO of a pointwise log-likelihood ``(n_chains, n_draws, n_points)`` (or ``(n_draws, n_points)``).

    The chain axis lets ArviZ estimate the relative efficiency of the draws. Where the Pareto
    smoothing fails (a point whose log-likelihood spans thousands of nats over the draws: the weights
    fall on one draw and the tail fit is undefined) the plain importance-sampling estimate
    ``-log mean(exp(-log_lik))`` stands in; such points have Pareto k far above 0.7.
    """
    ll = np.asarray(log_lik, float)
    if ll.ndim == 2:
        ll = ll[None]
    idata = az.from_dict(posterior={"_": np.zeros(ll.shape[:2])}, log_likelihood={"y": ll})
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        # Pareto-k warnings are reported by the callers that care (a deprecation still shows)
        for category in (UserWarning, RuntimeWarning):
            warnings.simplefilter("ignore", category)
        res = az.loo(idata, pointwise=True)
    out = np.asarray(res.loo_i, dtype=float)
    bad = ~np.isfinite(out)
    if bad.any():
        flat = ll.reshape(-1, ll.shape[-1])[:, bad]
        out[bad] = -(logsumexp(-flat, axis=0) - np.log(flat.shape[0]))
    n = out.size
    return Loo(pointwise=out, pareto_k=np.asarray(res.pareto_k, float), elpd=float(out.sum()),
               se=float(np.sqrt(n * np.var(out))) if n > 1 else 0.0)


CLEAR_SE = 4.0
"""A model beats another clearly when its ELPD is above by more than ``CLEAR_SE`` standard errors of the
difference (:func:`elpd_difference`): the diagnosis's rule for an extension and the cable-law comparison's
for a family that did not converge."""


def elpd_difference(a, b) -> tuple[float, float]:
    """ELPD of model ``b`` minus model ``a`` on the same points, and the standard error of the difference.

    ``a`` and ``b`` are :class:`Loo` results or pointwise ELPD arrays of shape (n_points,). The
    standard error is ``sqrt(n var(d_i))`` of the pointwise differences (as ``arviz.compare``'s dSE).
    """
    pa = a.pointwise if isinstance(a, Loo) else np.asarray(a, float)
    pb = b.pointwise if isinstance(b, Loo) else np.asarray(b, float)
    d = pb - pa
    return float(d.sum()), float(np.sqrt(d.size * np.var(d))) if d.size > 1 else 0.0
