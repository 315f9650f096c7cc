"""The likelihood of one test's cleaned runs (``docs/likelihood.md``).

Observation model, per frequency line k, quantity q in {log-magnitude, phase}, run r::

    y_rk = mu_k(theta) + delta_k + eps_rk,    eps_rk ~ N(0, sigma_k^2),    delta_k ~ N(0, s_q^2)

``mu`` is the forward model (natural log of |f_uu|, and arg f_uu in rad), ``sigma_k`` the run-to-run
scatter estimated from the repeats (the noise model), and ``delta_k`` a model discrepancy shared by
all runs of the test, with a learned scale ``s_q`` (``sigma_mag``, ``sigma_phase``). Integrating
``delta`` out, the run mean is sufficient: ``ybar_k ~ N(mu_k, sigma_k^2 / n_k + s_q^2)``. Because the
discrepancy does not average away over runs, the credible bands stay as wide as the misfit when the
model is wrong, instead of shrinking as 1/sqrt(n_runs).

``sigma_k`` is itself estimated from the same n_k runs, so the run mean is taken Student-t with
``nu_k = n_k - 1`` degrees of freedom and scale ``sqrt(sigma_k^2 / n_k + s_q^2)`` (exact when s_q = 0:
``(ybar - mu) / (sigma_hat / sqrt(n))`` is t-distributed); the new-run predictive likewise. With
10 runs a normal band would under-cover held-out runs by about 4 points at 90 %.

Pointwise log-likelihood for model comparison is grouped by run (the points of one curve are not
independent) and, since runs share ``delta``, uses the conditional density of a run given the
others, ``log p(y_r | y_-r, theta)`` (Buerkner, Gabry & Vehtari 2021, non-factorised normal models),
which is what PSIS-LOO needs.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from .damper import Damper
from .fem import dynamic_stiffness
from .priors import Prior

__all__ = ["TestLikelihood", "JointLikelihood"]

_LOG_2PI = np.log(2 * np.pi)


def _wrap(a):
    """Angle difference to [-pi, pi)."""
    return np.remainder(a + np.pi, 2 * np.pi) - np.pi


class TestLikelihood:
    """Log-posterior of one test for the sampler: bound data, picklable, vectorised.

    Parameters
    ----------
    damper : Damper
    prior : Prior
    freq_hz : ndarray, shape (n_freq,)
    magnitude : ndarray, shape (n_runs, n_freq)
        Cleaned runs, |F/X| [N/m]; NaN where a run lacks a line.
    phase_deg : ndarray, shape (n_runs, n_freq)
    sigma_logmag, sigma_phase : ndarray, shape (n_freq,)
        Run-to-run scatter of one run: natural-log magnitude and phase [rad].
    fixed : dict, optional
        Model parameters held fixed (not sampled), passed to the forward model.
    model : callable, optional
        ``model(damper, freq_hz, **params) -> complex (n, n_freq)``; default
        :func:`sbcal.fem.dynamic_stiffness` (a physics extension swaps it).
    amplitude_mm_pp : ndarray, shape (n_freq,), optional
        Commanded amplitude per line (kept with the run; amplitude-dependent models read it).

    Calling the object with ``z`` of shape ``(n, ndim)`` (the prior's sampled coordinates) returns
    the log-posterior, shape ``(n,)``: emcee's ``log_prob`` with ``vectorize=True``.
    """

    __test__ = False  # "Test" here is a bench test, not a pytest class

    def __init__(self, damper: Damper, prior: Prior, freq_hz, magnitude, phase_deg, sigma_logmag,
                 sigma_phase, fixed=None, model=None, amplitude_mm_pp=None):
        self.damper = damper
        self.prior = prior
        self.freq_hz = np.asarray(freq_hz, dtype=float)
        self.amplitude_mm_pp = (np.full(self.freq_hz.shape, np.nan) if amplitude_mm_pp is None
                                else np.broadcast_to(np.asarray(amplitude_mm_pp, float), self.freq_hz.shape))
        mag = np.atleast_2d(np.asarray(magnitude, dtype=float))
        self.y = np.stack([np.log(mag), np.radians(np.atleast_2d(phase_deg))])  # (2, n_runs, n_freq)
        self.present = np.isfinite(mag)
        self.n = self.present.sum(axis=0)  # (n_freq,)
        if np.any(self.n == 0):
            raise ValueError("every frequency line needs at least one run")
        self.sigma = np.stack([np.asarray(sigma_logmag, float), np.asarray(sigma_phase, float)])  # (2, F)
        if not np.all(np.isfinite(self.sigma) & (self.sigma > 0)):
            raise ValueError("noise scales must be finite and > 0")
        y0 = np.where(self.present, self.y, 0.0)
        self.ybar = y0.sum(axis=1) / self.n  # (2, F)
        # phase mean: average the wrapped deviations from the first run's line, so a wrap
        # between runs cannot corrupt it
        ref = np.nanmedian(np.where(self.present, self.y[1], np.nan), axis=0)
        dev = np.where(self.present, _wrap(self.y[1] - ref), 0.0)
        self.ybar[1] = ref + dev.sum(axis=0) / self.n
        self.nu = np.maximum(self.n - 1, 1).astype(float)  # dof of the noise estimate per line
        self._t_const = gammaln((self.nu + 1) / 2) - gammaln(self.nu / 2) - 0.5 * np.log(self.nu * np.pi)
        self.fixed = dict(fixed or {})
        self.model = dynamic_stiffness if model is None else model
        self._imodel = [prior.names.index(n) for n in prior.model_names]
        # a prior without the model-error scales gives the noise-only likelihood (s_q = 0): the
        # model must explain the run means within the noise (``sbcal.diagnose`` compares so)
        self._ierr = ([prior.names.index("sigma_mag"), prior.names.index("sigma_phase")]
                      if "sigma_mag" in prior.names else None)
        self._poly = [n for n in prior.model_names if n.startswith("q")]

    # -- pieces -----------------------------------------------------------------------------
    def params(self, x) -> dict:
        """Natural-unit rows ``(n, ndim)`` -> forward-model keyword arguments."""
        x = np.atleast_2d(x)
        p = {n: x[:, i] for n, i in zip(self.prior.model_names, self._imodel)}
        p.update(self.fixed)
        return p

    def predict(self, x) -> np.ndarray:
        """Model curves ``mu``: shape ``(2, n, n_freq)`` (log-magnitude, phase [rad])."""
        fuu = self.model(self.damper, self.freq_hz, **self.params(x))
        return np.stack([np.log(np.abs(fuu)), np.angle(fuu)])

    def _residual(self, mu):
        r = self.ybar[:, None, :] - mu
        r[1] = _wrap(r[1])
        return r

    def _valid(self, x) -> np.ndarray:
        """Support constraints beyond the box: a polynomial EJ(omega) must stay > 0 on the grid."""
        if not self._poly:
            return np.ones(len(x), bool)
        omega = 2 * np.pi * self.freq_hz
        p = self.params(x)
        ej = sum(p[q][:, None] * omega ** (int(q[1:]) - 1) for q in self._poly)
        return np.all(ej > 0, axis=1)

    def _s2(self, x) -> np.ndarray:
        """Model-error variances ``s_q^2``: shape (2, n, 1) (zeros for the noise-only likelihood)."""
        if self._ierr is None:
            return np.zeros((2, len(x), 1))
        return x[:, self._ierr].T[:, :, None] ** 2

    def log_likelihood(self, x, mu=None) -> np.ndarray:
        """Log-likelihood of the run means, natural units ``(n, ndim)`` -> ``(n,)``.

        ``mu`` (as :meth:`predict` returns) skips the forward model when the caller has it.
        """
        x = np.atleast_2d(x)
        mu = self.predict(x) if mu is None else mu
        var = self.sigma[:, None, :] ** 2 / self.n + self._s2(x)
        r = self._residual(mu)
        # Student-t log-density with nu = n - 1 and scale sqrt(var)
        lp = self._t_const - 0.5 * np.log(var) - 0.5 * (self.nu + 1) * np.log1p(r * r / (self.nu * var))
        return np.sum(lp, axis=(0, 2))

    def __call__(self, z) -> np.ndarray:
        z = np.atleast_2d(z)
        out = self.prior.log_prob(z)
        ok = np.isfinite(out)
        if ok.any():
            x = self.prior.to_natural(z[ok])
            valid = self._valid(x)
            lp = np.full(len(x), -np.inf)
            if valid.any():
                lp[valid] = self.log_likelihood(x[valid])
            lp[~np.isfinite(lp)] = -np.inf  # a NaN would stop emcee
            out[ok] = lp
        return out

    # -- for stored draws ---------------------------------------------------------------------
    def _delta_posterior(self, r, s2, n):
        """Mean and variance of delta given ``n`` runs whose mean deviates by ``r`` from ``mu``."""
        if self._ierr is None:  # no discrepancy term
            return np.zeros_like(r), np.zeros_like(r)
        prec = 1.0 / s2 + n / self.sigma[:, None, :] ** 2
        v = 1.0 / prec
        return v * n / self.sigma[:, None, :] ** 2 * r, v

    def pointwise_log_likelihood(self, x, mu=None) -> np.ndarray:
        """``log p(y_r | y_-r, theta)`` per run: ``(n, n_runs)`` (magnitude and phase summed)."""
        x = np.atleast_2d(x)
        mu = self.predict(x) if mu is None else mu  # (2, n, F)
        s2 = self._s2(x)
        n_runs = self.y.shape[1]
        out = np.zeros((len(x), n_runs))
        y0 = np.where(self.present, self.y, 0.0)
        for r in range(n_runs):
            pres = self.present[r]
            n_other = self.n - pres
            with np.errstate(invalid="ignore", divide="ignore"):
                mean_other = np.where(n_other > 0, (self.ybar * self.n - y0[:, r]) / np.maximum(n_other, 1), 0.0)
            dev = mean_other[:, None, :] - mu
            dev[1] = _wrap(dev[1])
            m, v = self._delta_posterior(dev, s2, n_other)
            res = y0[:, r][:, None, :] - mu - m
            res[1] = _wrap(res[1])
            var = self.sigma[:, None, :] ** 2 + v
            lp = -0.5 * (res * res / var + np.log(var) + _LOG_2PI)
            out[:, r] = np.sum(np.where(pres, lp, 0.0), axis=(0, 2))
        return out

    def predictive(self, x, rng: np.random.Generator) -> np.ndarray:
        """One posterior-predictive new run per row: ``(2, n, n_freq)`` (log-magnitude, phase [rad]).

        ``y_new = mu + delta + eps`` with delta from its posterior given all runs; ``eps`` is
        Student-t with the noise estimate's ``nu`` degrees of freedom (see the module docstring).
        """
        x = np.atleast_2d(x)
        mu = self.predict(x)
        m, v = self._delta_posterior(self._residual(mu), self._s2(x), self.n)
        sd = np.sqrt(self.sigma[:, None, :] ** 2 + v)
        return mu + m + sd * rng.standard_t(self.nu, size=mu.shape)

    def thesis_cost(self, x) -> np.ndarray:
        """The thesis's GA fitness (Eq. 4.5) on the run means: ``(n,)``.

        ``sqrt(W1 sum W3 (a - b)^2 / a^2 + W2 sum W3 (x - y)^2 / x^2)``: relative magnitude and phase
        errors (phase in degrees), ``W1 = 0.3``, ``W2 = 0.7``, ``W3`` the local frequency step
        normalised to mean 1 (the grid is uneven).
        """
        x = np.atleast_2d(x)
        fuu = self.model(self.damper, self.freq_hz, **self.params(x))
        a = np.exp(self.ybar[0])
        ph = np.degrees(self.ybar[1])
        w3 = np.gradient(self.freq_hz) if self.freq_hz.size > 1 else np.ones(1)
        w3 = w3 / w3.mean()
        em = np.sum(w3 * ((a - np.abs(fuu)) / a) ** 2, axis=1)
        ep = np.sum(w3 * ((ph - np.degrees(np.angle(fuu))) / ph) ** 2, axis=1)
        return np.sqrt(0.3 * em + 0.7 * ep)


class JointLikelihood:
    """One parameter set for several tests: the log-posterior over all their run means.

    The forward model runs once on all the tests' lines together (a physics that ties amplitudes
    together, such as strand slip, gets every test's commanded amplitude per line); each test keeps
    its own data and noise model (:class:`TestLikelihood`, whose ``model`` is not used here).

    Parameters
    ----------
    likes : sequence of TestLikelihood
        The tests (same damper).
    prior : Prior
        Over the shared parameters.
    model : callable
        ``model(damper, freq_hz, **params) -> complex (n, n_lines)`` on the concatenated lines; a
        :class:`sbcal.extensions.SlipModel` built on the concatenated amplitudes.
    """

    def __init__(self, likes, prior: Prior, model):
        self.likes = list(likes)
        self.damper = self.likes[0].damper
        self.prior = prior
        self.model = model
        self.freq_hz = np.concatenate([lk.freq_hz for lk in self.likes])
        self._split = np.cumsum([lk.freq_hz.size for lk in self.likes])[:-1]
        self._imodel = [prior.names.index(n) for n in prior.model_names]

    def params(self, x) -> dict:
        x = np.atleast_2d(x)
        return {n: x[:, i] for n, i in zip(self.prior.model_names, self._imodel)}

    def predict(self, x) -> list:
        """Model curves per test: a list of ``(2, n, n_freq_t)`` (log-magnitude, phase [rad])."""
        fuu = self.model(self.damper, self.freq_hz, **self.params(x))
        mu = np.stack([np.log(np.abs(fuu)), np.angle(fuu)])
        return np.split(mu, self._split, axis=2)

    def _valid(self, x) -> np.ndarray:
        return np.ones(len(np.atleast_2d(x)), bool)

    def log_likelihood(self, x) -> np.ndarray:
        x = np.atleast_2d(x)
        return sum(lk.log_likelihood(x, mu) for lk, mu in zip(self.likes, self.predict(x)))

    def pointwise_log_likelihood(self, x) -> np.ndarray:
        """Per run of every test, tests in order: ``(n, sum of n_runs)``."""
        x = np.atleast_2d(x)
        return np.concatenate([lk.pointwise_log_likelihood(x, mu) for lk, mu in zip(self.likes, self.predict(x))],
                              axis=1)

    def __call__(self, z) -> np.ndarray:
        z = np.atleast_2d(z)
        out = self.prior.log_prob(z)
        ok = np.isfinite(out)
        if ok.any():
            with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
                lp = self.log_likelihood(self.prior.to_natural(z[ok]))
            out[ok] = np.where(np.isfinite(lp), lp, -np.inf)
        return out
