"""A population of units from their stored posteriors: the hierarchical model, fitted by reweighting.

Every unit ``u`` of a lot was calibrated alone, under a prior ``pi``; its stored draws ``x_us`` of the
chosen parameters are draws of ``p(x | data_u) ∝ p(data_u | x) pi(x)``. If the units' parameters are
instead drawn from a population ``g(x | eta)``, each unit's marginal likelihood of the hyper-parameters
``eta`` is, up to a constant that does not depend on ``eta``, the importance-sampling mean (the
"recycling" of stored posteriors; Hogg et al. 2010, bilby's ``hyper`` module)::

    L_u(eta) ∝ mean_s g(x_us | eta) / pi(x_us)

so the population is fitted with no new forward solve. Each draw is smoothed by a small Gaussian kernel
that keeps the unit's mean and covariance (:class:`_BlockFeatures`: a sum of spikes is no surface to
sample on where the lot is narrower than a unit's posterior). The estimate is only as good as the draws
cover ``g``: its effective sample size per unit is computed at the hyper-posterior's draws and a unit
below :data:`MIN_ESS` is flagged (:func:`unit_ess`).

The population (:class:`PopulationModel`), in the coordinates the priors sample: ``log x`` for a
log-uniform box, ``logit((x - lower) / (upper - lower))`` for a uniform one (unbounded, so a normal fits
there). The parameter vector of a unit is grouped in *blocks*, one per physical parameter (``EJ``,
``beta``), each holding that parameter at every test (amplitude) of the lot. Within a block the
population is normal with a mean and a scatter per test and one correlation between tests (compound
symmetry): a unit with a stiffer cable is stiffer at every amplitude, and how much of its deviation is
shared is what the lot says; across blocks the deviations are independent. Twelve units support a
mean, a scatter and a shared fraction per block; they do not support a free correlation matrix (a block
of five tests would need ten correlations from twelve points).

Outliers (``outliers=True``): a two-component population. A unit is, with probability ``1 - epsilon``,
a member; with probability ``epsilon`` it is "not like the others" in one block (chosen evenly among
the blocks), whose deviation along the block's common direction is then ``OUTLIER_SCALE`` times the
lot's scatter: covariance ``Sigma + (k^2 - 1) tau tau^T``. Its probability of membership is then a
posterior probability (:func:`outlier_probabilities`) that the lot's own spread calibrates, which a
leave-one-out tail probability is not (for twelve ordinary units, half of them would sit above 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import expit, logit

from .priors import Prior


__all__ = ["OUTLIER_SCALE", "MIN_ESS", "to_population_coordinates", "from_population_coordinates", "UnitDraws", "HyperPrior",
           "PopulationModel", "PopulationTarget", "unit_ess", "outlier_probabilities", "shrunk_draws",
           "predictive_draws"]

OUTLIER_SCALE = 4.0
"""k: an outlier's deviation along its block's common direction is k times the lot's scatter."""

MIN_ESS = 30.0
"""A unit whose reweighted draws have fewer effective samples than this (at the hyper-posterior's
median) cannot represent the population: flagged, never silently trusted."""

_LOG_2PI = math.log(2.0 * math.pi)


def to_population_coordinates(values, box) -> tuple[np.ndarray, np.ndarray]:
    """Natural values under a prior box -> ``(x, log pi(x))`` in the population's coordinates.

    Parameters
    ----------
    values : array_like, shape (n,)
    box : tuple ``(log_scale, lower, upper)``
        The box the unit was sampled under (:meth:`sbcal.inference.priors.Prior.box`).

    Returns
    -------
    x, log_density : ndarray, shape (n,)
        ``log value`` (log-uniform: density ``1 / ln(upper / lower)``) or ``logit`` of the box fraction
        (uniform: density ``u (1 - u)``).
    """
    v = np.asarray(values, dtype=float)
    log_scale, lo, hi = box
    if log_scale:
        return np.log(v), np.full(v.shape, -math.log(math.log(hi / lo)))
    u = np.clip((v - lo) / (hi - lo), 1e-12, 1 - 1e-12)
    return logit(u), np.log(u) + np.log1p(-u)


def from_population_coordinates(x, box) -> np.ndarray:
    """The inverse of :func:`to_population_coordinates` (natural values)."""
    log_scale, lo, hi = box
    x = np.asarray(x, dtype=float)
    return np.exp(x) if log_scale else lo + (hi - lo) * expit(x)


@dataclass(frozen=True)
class UnitDraws:
    """One unit's stored posterior in the population's coordinates.

    Attributes
    ----------
    name : str
    x : ndarray, shape (n_draws, n_dims)
        Joint draws of the lot's dimensions (:attr:`PopulationModel.dims` order).
    log_prior : ndarray, shape (n_draws,)
        ``log pi(x)`` of the prior each draw was sampled under (the chosen dimensions' product).
    """

    name: str
    x: np.ndarray
    log_prior: np.ndarray


@dataclass(frozen=True)
class HyperPrior:
    """Priors of the hyper-parameters (in the population's coordinates).

    Attributes
    ----------
    mean_box : tuple of (lower, upper) per dimension
        A flat prior on each mean within this box (the sampler's box).
    mean_normal : tuple of (loc, scale) per dimension, optional
        Instead a normal prior on each mean (truncated to ``mean_box``).
    scatter_scale : float
        A half-Cauchy prior of this scale on each scatter (0.25: a quarter in log or logit units is
        a plausible spread of a production lot, with heavy tails for one that is not).
    scatter_box : tuple (lower, upper)
        Truncation of the scatter (sampled as its log).
    outlier_beta : tuple (a, b)
        Beta prior on the outlier fraction ``epsilon`` (mean ``a / (a + b)``; 1, 19: one unit in twenty of a
        production lot expected off, the rest as the lot is).
    """

    mean_box: tuple
    mean_normal: tuple | None = None
    scatter_scale: float = 0.25
    scatter_box: tuple = (1e-4, 10.0)
    outlier_beta: tuple = (1.0, 19.0)


@dataclass(frozen=True)
class PopulationModel:
    """The population's structure: dimensions in blocks, and whether it has an outlier component.

    Attributes
    ----------
    blocks : tuple of (name, tuple of str)
        Each block's parameter name and its tests (labels), e.g. ``("EJ", ("0.2-0.2", "1-1"))``.
    hyper : HyperPrior
    outliers : bool
    """

    blocks: tuple
    hyper: HyperPrior
    outliers: bool = True

    def __post_init__(self):
        if len(self.hyper.mean_box) != len(self.dims):
            raise ValueError(f"mean_box: {len(self.hyper.mean_box)} boxes for {len(self.dims)} dimensions")

    @property
    def dims(self) -> tuple:
        """``(parameter, test)`` of every dimension, block after block."""
        return tuple((p, t) for p, tests in self.blocks for t in tests)

    @staticmethod
    def label(parameter: str, test: str) -> str:
        return f"{parameter}[{test}]" if test else parameter

    def hyper_names(self) -> dict:
        """Hyper-parameter names: ``{"mean": [...], "scatter": [...], "correlation": [...], "outlier": [...]}``."""
        names = {"mean": [f"{self.label(p, t)}.mean" for p, t in self.dims],
                 "scatter": [f"{self.label(p, t)}.scatter" for p, t in self.dims],
                 "correlation": [f"{p}.correlation" for p, tests in self.blocks if len(tests) > 1],
                 "outlier": ["outlier_fraction"] if self.outliers else []}
        return names

    def prior(self) -> Prior:
        """The sampler's boxes (means flat, scatters log-uniform before their half-Cauchy density)."""
        names = self.hyper_names()
        boxes = {}
        for n, (lo, hi) in zip(names["mean"], self.hyper.mean_box):
            boxes[n] = (False, lo, hi)
        for n in names["scatter"]:
            boxes[n] = (True, *self.hyper.scatter_box)
        for n, (_, tests) in zip(names["correlation"], [b for b in self.blocks if len(b[1]) > 1]):
            boxes[n] = (False, -1.0 / (len(tests) - 1) + 1e-6, 1.0 - 1e-6)
        for n in names["outlier"]:
            boxes[n] = (False, 0.0, 0.5)
        return Prior.from_boxes("population", boxes)

    def unpack(self, params: dict) -> tuple[np.ndarray, np.ndarray, dict, np.ndarray]:
        """Hyper-parameters by name (arrays of shape (n,)) -> ``mean (n, D)``, ``scatter (n, D)``,
        ``{block: correlation (n,)}``, ``epsilon (n,)``."""
        names = self.hyper_names()
        mean = np.stack([np.asarray(params[n], float) for n in names["mean"]], axis=-1)
        scatter = np.stack([np.asarray(params[n], float) for n in names["scatter"]], axis=-1)
        rho = {p: np.asarray(params[f"{p}.correlation"], float) for p, tests in self.blocks if len(tests) > 1}
        eps = np.asarray(params["outlier_fraction"], float) if self.outliers else np.zeros(mean.shape[0])
        return mean, scatter, rho, eps

    def block_slices(self):
        start = 0
        for p, tests in self.blocks:
            yield p, slice(start, start + len(tests))
            start += len(tests)

    def covariances(self, scatter, rho) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per block: the member and outlier covariances, each ``(n, T, T)``."""
        out = []
        k2 = OUTLIER_SCALE ** 2
        for p, sl in self.block_slices():
            tau = scatter[:, sl]
            T = tau.shape[1]
            r = rho.get(p, np.zeros(tau.shape[0]))[:, None, None]
            corr = (1 - r) * np.eye(T) + r * np.ones((T, T))
            member = tau[:, :, None] * corr * tau[:, None, :]
            outlier = member + (k2 - 1) * tau[:, :, None] * tau[:, None, :]
            out.append((member, outlier))
        return out


def logsumexp(a, axis=0, keepdims=False):
    """``log sum exp`` along ``axis`` (scipy's checks its inputs on every call: too slow inside the target)."""
    a = np.asarray(a)
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True)) + m
    return out if keepdims else np.squeeze(out, axis=axis)


class _BlockFeatures:
    """A block's unit draws as kernels and as the features of a quadratic form.

    Each unit's draws are smoothed by a Gaussian kernel of covariance ``h^2 C_u`` (``C_u`` the draws'
    covariance, ``h`` Scott's factor ``S^(-1/(T+4))``) after shrinking them towards their mean by
    ``sqrt(1 - h^2)``, which keeps the unit's mean and covariance (Silverman's shrunk kernel estimate). A
    raw reweighting's estimate of ``L_u`` is a sum of spikes where the population is narrower than a unit's
    posterior, a surface no sampler crosses; the kernel makes it smooth and changes nothing where the
    posterior is Gaussian. Then ``N(x_s; mean, cov + h^2 C_u)`` of every draw is, per unit, a matrix
    product of the features ``(y_i y_j, y_i)``, ``y = x - centre``, with each hyper-point's precision.
    """

    def __init__(self, x, centre):
        U, S, T = x.shape
        h2 = S ** (-2.0 / (T + 4))
        m = x.mean(axis=1, keepdims=True)
        self.kernel = h2 * np.stack([np.atleast_2d(np.cov(x[u], rowvar=False)) for u in range(U)])   # (U, T, T)
        y = m + math.sqrt(1.0 - h2) * (x - m) - centre                                                # (U, S, T)
        self.pairs = [(i, j) for i in range(T) for j in range(i, T)]
        self.quad = np.stack([y[..., i] * y[..., j] * (1.0 if i == j else 2.0) for i, j in self.pairs], axis=-1)
        self.lin = y
        self.centre = centre

    def log_normal(self, mean, cov) -> np.ndarray:
        """``log N(x; mean, cov + kernel_u)`` for ``mean (n, T)``, ``cov (n, T, T)`` -> ``(n, U, S)``."""
        full = cov[:, None] + self.kernel[None]                           # (n, U, T, T)
        if full.shape[-1] == 1:  # one dimension (a cable law's parameter, a one-test lot): no matrices
            v = full[..., 0, 0][:, :, None]                               # (n, U, 1)
            d = self.lin[None, :, :, 0] - (mean - self.centre)[:, None, :]  # (n, U, S)
            return -0.5 * (d * d / v + np.log(v) + _LOG_2PI)
        chol = np.linalg.cholesky(full)
        prec = np.linalg.inv(full)
        m = mean - self.centre                                            # (n, T)
        pm = np.einsum("nuij,nj->nui", prec, m)                           # (n, U, T)
        const = np.einsum("ni,nui->nu", m, pm)
        logdet = np.log(np.diagonal(chol, axis1=2, axis2=3)).sum(axis=2)  # (n, U)
        T = m.shape[1]
        U, S = self.lin.shape[:2]
        out = np.empty((mean.shape[0], U, S))
        pv = np.stack([prec[..., i, j] for i, j in self.pairs], axis=-1)  # (n, U, K)
        for u in range(U):
            q = self.quad[u] @ pv[:, u].T - 2.0 * self.lin[u] @ pm[:, u].T + const[:, u][None]   # (S, n)
            out[:, u] = (-0.5 * q - (logdet[:, u] + 0.5 * T * _LOG_2PI)[None]).T
        return out


def _features(model: PopulationModel, x) -> list:
    centre = np.median(x.reshape(-1, x.shape[-1]), axis=0)
    return [_BlockFeatures(x[:, :, sl], centre[sl]) for _, sl in model.block_slices()]


def _component_logs(model: PopulationModel, features, log_prior, params):
    """Per hyper-point and unit draw: log member density over the prior ``(n, U, S)`` and, per block,
    the log density of "outlier in that block" over the prior ``(n, U, S)``; with ``epsilon (n,)``."""
    mean, scatter, rho, eps = model.unpack(params)
    member_blocks, outlier_blocks = [], []
    for (p, sl), (cov_m, cov_o), feat in zip(model.block_slices(), model.covariances(scatter, rho), features):
        member_blocks.append(feat.log_normal(mean[:, sl], cov_m))
        outlier_blocks.append(feat.log_normal(mean[:, sl], cov_o) if model.outliers else None)
    member = sum(member_blocks) - log_prior[None]
    outlier = [member - m + o for m, o in zip(member_blocks, outlier_blocks)] if model.outliers else []
    return member, outlier, eps


def _unit_terms(model, features, log_prior, params):
    """``log (1 - eps) m_u`` and ``log (eps / P) m_u^(p)`` per hyper-point and unit: ``(n, U)``, ``(P, n, U)``."""
    member, outlier, eps = _component_logs(model, features, log_prior, params)
    S = log_prior.shape[1]
    with np.errstate(divide="ignore"):
        log_m = logsumexp(member, axis=2) - math.log(S) + np.log1p(-eps)[:, None]
        if not outlier:
            return log_m, np.full((0,) + log_m.shape, -np.inf)
        share = np.log(eps / len(outlier))[:, None]
        log_o = np.stack([logsumexp(o, axis=2) - math.log(S) + share for o in outlier])
    return log_m, log_o


def _stack_units(units) -> tuple[np.ndarray, np.ndarray]:
    S = min(u.x.shape[0] for u in units)
    return (np.stack([u.x[:S] for u in units]), np.stack([u.log_prior[:S] for u in units]))


class PopulationTarget:
    """The hyper-posterior as a target of :func:`sbcal.inference.sampler.sample` (picklable).

    ``__call__(z)`` is the log hyper-posterior at a batch of sampled coordinates: the boxes, the
    half-Cauchy scatters (with the Jacobian of sampling their log), the normal means where given, the
    Beta outlier fraction, and ``sum_u log L_u`` by reweighting.
    """

    def __init__(self, model: PopulationModel, units, *, chunk: int = 64):
        self.model = model
        self.prior = model.prior()
        self.names = [u.name for u in units]
        self.x, self.log_prior = _stack_units(units)
        self.features = _features(model, self.x)
        self.chunk = chunk

    def log_hyper_prior(self, params: dict, z) -> np.ndarray:
        hp = self.model.hyper
        names = self.model.hyper_names()
        out = self.prior.log_prob(z)
        c = hp.scatter_scale
        for n in names["scatter"]:
            t = params[n]
            out = out + math.log(2 / (math.pi * c)) - np.log1p((t / c) ** 2) + np.log(t)   # half-Cauchy, d tau = tau d log tau
        if hp.mean_normal is not None:
            for n, (loc, scale) in zip(names["mean"], hp.mean_normal):
                out = out - 0.5 * ((params[n] - loc) / scale) ** 2
        if self.model.outliers:
            a, b = hp.outlier_beta
            e = params["outlier_fraction"]
            with np.errstate(divide="ignore", invalid="ignore"):   # outside the box: already -inf
                out = out + (a - 1) * np.log(e) + (b - 1) * np.log1p(-e)
        return out

    def log_likelihood_units(self, params: dict) -> np.ndarray:
        """``log L_u`` per hyper-point and unit, ``(n, U)`` (up to each unit's evidence, a constant)."""
        log_m, log_o = self._terms(params)
        return np.logaddexp(log_m, logsumexp(log_o, axis=0)) if log_o.size else log_m

    def _terms(self, params):
        n = len(next(iter(params.values())))
        parts_m, parts_o = [], []
        for i in range(0, n, self.chunk):
            sub = {k: np.asarray(v)[i:i + self.chunk] for k, v in params.items()}
            m, o = _unit_terms(self.model, self.features, self.log_prior, sub)
            parts_m.append(m)
            parts_o.append(o)
        return np.concatenate(parts_m, axis=0), np.concatenate(parts_o, axis=1)

    def __call__(self, z) -> np.ndarray:
        z = np.atleast_2d(z)
        params = self.prior.params(z)
        lp = self.log_hyper_prior(params, z)
        ok = np.isfinite(lp)
        out = np.full(z.shape[0], -np.inf)
        if ok.any():
            sub = {k: v[ok] for k, v in params.items()}
            out[ok] = lp[ok] + self.log_likelihood_units(sub).sum(axis=1)
        return out


def _weights(target: PopulationTarget, params: dict, component: str = "mixture") -> np.ndarray:
    """Normalised importance weights of every unit's draws per hyper-point, ``(n, U, S)``."""
    member, outlier, eps = _component_logs(target.model, target.features, target.log_prior, params)
    if component == "member" or not outlier:
        logw = member
    else:
        P = len(outlier)
        with np.errstate(divide="ignore"):
            logw = np.logaddexp(member + np.log1p(-eps)[:, None, None],
                                logsumexp(np.stack(outlier), axis=0) + np.log(eps / P)[:, None, None])
    return np.exp(logw - logsumexp(logw, axis=2, keepdims=True))


def unit_ess(target: PopulationTarget, params: dict) -> np.ndarray:
    """Effective sample size of each unit's reweighted draws under the member population, per
    hyper-point: ``(sum w)^2 / sum w^2``, shape ``(n, U)`` (Kish)."""
    w = _weights(target, params, "member")
    return 1.0 / np.sum(w ** 2, axis=2)


def outlier_probabilities(target: PopulationTarget, params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Posterior probability that each unit is an outlier, and per block: ``(U,)`` and ``(P, U)``,
    averaged over the hyper-posterior's draws ``params``."""
    log_m, log_o = target._terms(params)
    total = np.logaddexp(log_m, logsumexp(log_o, axis=0))
    per_block = np.exp(log_o - total[None]).mean(axis=1)
    return per_block.sum(axis=0), per_block


def shrunk_draws(target: PopulationTarget, params: dict, rng: np.random.Generator) -> np.ndarray:
    """Each unit's parameters given the lot: one of its draws per hyper-point, resampled by its weight
    under the fitted (mixture) population. Returns ``(U, n, D)``."""
    w = _weights(target, params)
    n, U, S = w.shape
    c = np.cumsum(w, axis=2)
    u = rng.random((n, U, 1))
    idx = np.minimum((c < u).sum(axis=2), S - 1)
    return np.stack([target.x[j, idx[:, j]] for j in range(U)])


def predictive_draws(model: PopulationModel, params: dict, rng: np.random.Generator) -> np.ndarray:
    """The next unit of the design: one draw of the member population per hyper-point, ``(n, D)``."""
    mean, scatter, rho, _ = model.unpack(params)
    out = np.empty_like(mean)
    for (p, sl), (cov, _) in zip(model.block_slices(), model.covariances(scatter, rho)):
        chol = np.linalg.cholesky(cov)
        e = rng.standard_normal(mean[:, sl].shape)
        out[:, sl] = mean[:, sl] + np.einsum("nij,nj->ni", chol, e)
    return out
