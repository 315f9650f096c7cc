"""The independence proposal of the sampling engine (:mod:`sbcal.inference.sampler`).

One ensemble's proposal is fitted to its own kept steps at the end of a round and fixed for the next:
a multivariate t with the steps' mean and covariance as location and scale, or, where the engine's
``bend`` allows it, the same t in the posterior's principal axes with its narrow directions' centres
bent along the widest ones (:class:`MapProposal`): a thin curved ridge is then proposed along its curve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MapProposal", "fit_proposal"]

T_DOF = 5.0  # the independence proposal's t: heavier tails than a near-Gaussian posterior
MIN_GAIN = 0.02  # nats per point a bend must add to the held-out density to be kept
BOX_TRIES = 8  # redraws of a proposal outside the prior box (a posterior piled against a bound)


def bend_features(d) -> np.ndarray:
    """Regressors on the wide coordinates ``d (n, k)``: a constant, each, and their pairwise products."""
    a, b = np.triu_indices(d.shape[1])
    return np.concatenate([np.ones((len(d), 1)), d, d[:, a] * d[:, b]], axis=1)


@dataclass(frozen=True)
class MapProposal:
    """One ensemble's independence proposal: a multivariate t, bent along the posterior's widest directions.

    Whitened along the principal axes, widest first, ``u = W (x - mean) = (d, r)`` with ``d`` the first
    ``bent`` coordinates, the map ``(d, r) -> (d, r - C f(d))`` (``f`` :func:`bend_features`: a constant,
    ``d`` and its pairwise products) takes the posterior to a multivariate t (``T_DOF`` degrees of
    freedom, scale ``chol chol^T``). A posterior that is a thin curved ridge (narrow directions whose
    centre moves with a wide one, as a cable law's onset and scale trade against each other on one test)
    is then proposed along its curve, where an ellipsoid proposes mostly off it. ``bent = 0`` is the t
    approximation of the posterior (the first round's, from the Laplace approximation). Both maps have a
    constant Jacobian (``W`` fixed; the bend triangular with unit diagonal), so the density below is
    exact up to a constant and the independence move's Metropolis-Hastings ratio holds.
    """

    mean: np.ndarray
    whiten: np.ndarray  # W, (ndim, ndim)
    bent: int
    coef: np.ndarray  # C, (n_features, ndim - bent)
    chol: np.ndarray  # (ndim, ndim): the t's scale
    # made once: W^-1 (transposed), chol^-1 and -log det chol
    _made: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_made", (np.linalg.inv(self.whiten).T, np.linalg.inv(self.chol),
                                           -np.log(np.diag(self.chol)).sum()))

    @property
    def unwhiten(self) -> np.ndarray:
        """``W^-1`` (ndim, ndim): whitened coordinates back to sampled ones."""
        return self._made[0].T

    @property
    def chol_inverse(self) -> np.ndarray:
        """``chol^-1`` (ndim, ndim): the t's scale undone."""
        return self._made[1]

    @property
    def log_norm(self) -> float:
        """``-log det chol``: :meth:`log_density`'s constant."""
        return self._made[2]

    @classmethod
    def ellipsoid(cls, mean, cov) -> "MapProposal":
        """The t of location ``mean`` and covariance ``cov`` (no bend)."""
        n = len(mean)
        return cls(mean=np.asarray(mean, float), whiten=np.eye(n), bent=0, coef=np.zeros((1, n)),
                   chol=np.linalg.cholesky(cov))

    def draw(self, rng, n, lower=None, upper=None) -> np.ndarray:
        """``n`` draws; with a box (``lower``, ``upper``: ``(ndim,)``) each is the first inside it of
        ``BOX_TRIES + 1`` independent tries: the draws inside then follow this density restricted to the box (its
        constant cancels in the Metropolis-Hastings ratio), and one whose tries all fall outside is rejected as
        before (the engine's compiled moves, :mod:`sbcal.inference.move_kernel`, take the same first try inside)."""
        if lower is None:
            return self._draw(rng, n)
        tries = self._draw(rng, n * (BOX_TRIES + 1)).reshape(BOX_TRIES + 1, n, self.mean.size)
        inside = np.all((tries >= lower) & (tries <= upper), axis=2)
        first = np.where(inside.any(axis=0), inside.argmax(axis=0), BOX_TRIES)
        return tries[first, np.arange(n)]

    def _draw(self, rng, n) -> np.ndarray:
        v = rng.standard_normal((n, self.mean.size)) @ self.chol.T
        v *= np.sqrt(T_DOF / rng.chisquare(T_DOF, n))[:, None]
        v[:, self.bent:] += bend_features(v[:, :self.bent]) @ self.coef if self.bent else self.coef[0]
        return self.mean + v @ self._made[0]

    def mapped(self, x) -> np.ndarray:
        """The bent whitened coordinates ``(d, r - C f(d))`` of points ``x (n, ndim)``: where the posterior is
        near the t's ellipsoid (the surrogate of :mod:`sbcal.inference.surrogate` is a quadratic in them)."""
        v = (np.atleast_2d(x) - self.mean) @ self.whiten.T
        v[:, self.bent:] -= bend_features(v[:, :self.bent]) @ self.coef if self.bent else self.coef[0]
        return v

    def log_density(self, x) -> np.ndarray:
        """Up to a constant of ``W`` and the dimension (so proposals of one whitening compare)."""
        y = self.mapped(x) @ self._made[1].T
        return self._made[2] - 0.5 * (T_DOF + self.mean.size) * np.log1p(np.einsum("ij,ij->i", y, y) / T_DOF)


def fit_map(x, mean, whiten, bent: int) -> MapProposal | None:
    """The proposal of ``bent`` wide directions fitted to points ``x (n, ndim)`` whitened by ``whiten`` (least
    squares for the bend, the bent points' covariance for the t), or None where it is degenerate."""
    v = (x - mean) @ whiten.T
    f = bend_features(v[:, :bent])
    if len(x) < 4 * f.shape[1]:
        return None
    coef, *_ = np.linalg.lstsq(f, v[:, bent:], rcond=None)
    v[:, bent:] -= f @ coef
    try:
        chol = np.linalg.cholesky(np.atleast_2d(np.cov(v.T)))  # a t of 5/3 that covariance: wider tails
    except np.linalg.LinAlgError:
        return None
    return MapProposal(mean=mean, whiten=whiten, bent=bent, coef=coef, chol=chol)


def fit_proposal(chain, bend: int = 0) -> MapProposal | None:
    """The proposal of one ensemble from its own kept steps ``chain (steps, walkers, ndim)``, or None where
    they do not span every direction. At most ``bend`` wide directions bend the rest (0: the t alone, with
    the steps' mean and covariance). How many is chosen on the steps themselves:
    fitted on the first half, the one whose density is highest on the second half (the smallest
    Kullback-Leibler divergence from the posterior to the proposal, which the independence move's
    acceptance rests on), then refitted on all of them."""
    x = chain.reshape(-1, chain.shape[-1])
    cov = np.atleast_2d(np.cov(x.T))
    sd = np.sqrt(np.diag(cov))
    if not np.all(np.isfinite(sd) & (sd > 0)):
        return None
    try:
        ev, vec = np.linalg.eigh(cov + 1e-10 * np.diag(np.diag(cov)))
    except np.linalg.LinAlgError:
        return None
    if not ev.min() > 0:
        return None
    order = np.argsort(ev)[::-1]
    mean, whiten = x.mean(axis=0), (vec[:, order] / np.sqrt(ev[order])).T
    best = 0
    if bend:  # the held-out choice; without a bend allowed there is nothing to choose
        half = len(chain) // 2
        first, second = chain[:half].reshape(-1, x.shape[1]), chain[half:].reshape(-1, x.shape[1])
        best_held = None
        for bent in range(min(x.shape[1] - 1, bend) + 1):
            trial = fit_map(first, mean, whiten, bent)
            if trial is None:
                break
            held = trial.log_density(second)
            gain = held - best_held if best_held is not None else None
            # a bend must pay: its held-out gain beyond 0.02 nats a point and twice its standard error (the
            # points are correlated, so this error is a floor), else a Gaussian posterior would keep one by chance
            if gain is None or gain.mean() > max(MIN_GAIN, 2 * gain.std() / math.sqrt(len(gain))):
                best, best_held = bent, held
    return fit_map(x, mean, whiten, best)
