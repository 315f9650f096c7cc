"""The sampling engine's screen of proposals: delayed acceptance with a quadratic of the log-density.

Where one log-density call costs milliseconds per parameter set (a cable state's model), most of a
sampler's calls go to proposals it rejects (acceptance 0.05-0.3). Delayed acceptance (Christen & Fox
2005) first judges a proposal ``x -> x'`` by a cheap surrogate ``s`` and calls the exact density ``f`` only
on the proposals that pass, accepting them with the corrected ratio:

- stage 1: accept with ``min(1, exp(s(x') - s(x)) q(x | x') / q(x' | x))`` (the proposal's own ratio, 1
  for differential evolution);
- stage 2: accept with ``min(1, exp((f(x') - f(x)) - (s(x') - s(x))))``.

The two stages together are a Metropolis-Hastings kernel that leaves ``f``'s posterior invariant whatever
``s`` is; a poor ``s`` costs mixing (stage 2 rejects more), never correctness. Here ``s`` is a quadratic
in the whitened coordinates fitted by least squares to one ensemble's kept steps and their
log-densities at the end of a round, fixed for the next (as the independence proposal is), ``-inf``
outside the prior box, and used only where it predicts held-out steps' log-densities to
``MAX_RESIDUAL_SD`` nats (in the bent coordinates of the ensemble's proposal, where a curved ridge is
nearer a quadratic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .proposal import bend_features

__all__ = ["QuadraticSurrogate", "fit_surrogate", "MAX_RESIDUAL_SD"]

MAX_RESIDUAL_SD = 0.5
"""The largest held-out residual sd [nats] at which the screen is used. Measured on damper1's cable states
(``benchmarks/cable_engine.py``): the dry state's quadratic predicts to 0.14-0.36 nats and the screen leaves
the autocorrelation as it was (7 -> 8 steps) with half the calls; the oiled state's one-test ridge to
0.53-0.76 nats and the screen doubled its autocorrelation (13 -> 25: the quadratic's light tails screen out
moves into the ridge's tails), gaining nothing; the zoned law's 17 dimensions to 1.3-2.0 nats."""
MAX_POINTS = 6000  # kept steps used for the fit (evenly thinned): 171 coefficients in 17 dimensions
RIDGE = 1e-8  # relative ridge on the normal equations (repeated steps of rejected moves make them near-singular)


@dataclass(frozen=True)
class QuadraticSurrogate:
    """``s(z) = f(W (m(z) - mean)) . coef`` (:func:`sbcal.inference.proposal.bend_features`: a constant, the
    whitened coordinates and their pairwise products), ``-inf`` outside ``[lower, upper]``; ``m`` the
    ensemble's proposal's bent coordinates (:meth:`sbcal.inference.proposal.MapProposal.mapped`: a thin
    curved ridge is near quadratic in them) or the identity.

    Attributes
    ----------
    mean : ndarray, shape (ndim,)
    whiten : ndarray, shape (ndim, ndim)
        ``W``: the kept steps' inverse Cholesky factor (whitened coordinates ``u = (z - mean) W^T``).
    coef : ndarray, shape (n_features,)
    lower, upper : ndarray, shape (ndim,), or None
        The prior box in the sampled coordinates.
    residual_sd : float
        Held-out residual sd of the fit [nats] (kept for inspection; the fit is used only below ``MAX_RESIDUAL_SD``).
    mapping : MapProposal or None
    """

    mean: np.ndarray
    whiten: np.ndarray
    coef: np.ndarray
    lower: np.ndarray | None
    upper: np.ndarray | None
    residual_sd: float
    mapping: object = None

    def __call__(self, z) -> np.ndarray:
        """``s`` at sampled coordinates ``z (n, ndim)`` -> ``(n,)``."""
        z = np.atleast_2d(z)
        out = bend_features((_map(self.mapping, z) - self.mean) @ self.whiten.T) @ self.coef
        inside = np.ones(len(z), bool)
        if self.lower is not None:
            inside &= (z >= self.lower).all(axis=1)
        if self.upper is not None:
            inside &= (z <= self.upper).all(axis=1)
        return np.where(inside, out, -np.inf)


def _map(mapping, z):
    return z if mapping is None else mapping.mapped(z)


def _solve(features, y) -> np.ndarray:
    a = features.T @ features
    a[np.diag_indices_from(a)] += RIDGE * np.trace(a) / len(a)
    return np.linalg.solve(a, features.T @ y)


def fit_surrogate(chain, log_prob, box=(None, None), mapping=None) -> QuadraticSurrogate | None:
    """The quadratic screen of one ensemble from its kept steps, or None where it would not pay.

    Parameters
    ----------
    chain : ndarray, shape (steps, walkers, ndim)
        Kept steps in the sampled coordinates.
    log_prob : ndarray, shape (steps, walkers)
        Their log-densities.
    box : (lower, upper)
        The prior box in the sampled coordinates (None: unbounded).
    mapping : MapProposal, optional
        The quadratic is fitted in its bent coordinates (the ensemble's proposal for the same round).

    Returns
    -------
    QuadraticSurrogate or None
        Fitted on all kept steps; None when the steps are too few for the ``1 + ndim (ndim + 3) / 2``
        coefficients (four points a coefficient), degenerate, or when a fit on half the walkers predicts
        the other half's log-densities with a residual sd above ``MAX_RESIDUAL_SD`` (its mean removed:
        a constant offset cancels in the ratios).
    """
    steps, walkers, ndim = chain.shape
    n_features = 1 + ndim + ndim * (ndim + 1) // 2
    every = max(1, steps * walkers // MAX_POINTS)
    x = chain[::every].reshape(-1, ndim)
    y = log_prob[::every].reshape(-1)
    walker = np.broadcast_to(np.arange(walkers), log_prob[::every].shape).reshape(-1)
    ok = np.isfinite(y)
    x, y, walker = _map(mapping, x[ok]), y[ok], walker[ok]
    # fitted on the even walkers, judged on the odd ones (a walker's own steps are correlated)
    fit, held = walker % 2 == 0, walker % 2 == 1
    if fit.sum() < 4 * n_features or held.sum() < n_features:
        return None
    mean = x.mean(axis=0)
    try:
        whiten = np.linalg.inv(np.linalg.cholesky(np.cov(x, rowvar=False)))
        feats = bend_features((x - mean) @ whiten.T)
        coef = _solve(feats[fit], y[fit])
        r = y[held] - feats[held] @ coef
        coef = _solve(feats, y)
    except np.linalg.LinAlgError:
        return None
    sd = float(np.std(r))
    if not sd <= MAX_RESIDUAL_SD:
        return None
    lower, upper = box
    return QuadraticSurrogate(mean=mean, whiten=whiten, coef=coef, lower=None if lower is None else np.asarray(lower),
                              upper=None if upper is None else np.asarray(upper), residual_sd=sd, mapping=mapping)
