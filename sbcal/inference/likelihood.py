"""The likelihood of one test's cleaned runs (``docs/calibration.md``).

Observation model, per frequency line k and quantity q (natural-log magnitude, phase [rad]), run r::

    y_rk = mu_k(theta) + delta_k + eps_rk,   eps_rk ~ N(0, sigma_k^2 / lambda_k),   delta_k ~ N(0, s_q^2 / lambda_k)

``mu`` is the forward model, ``sigma_k`` the run-to-run scatter of the noise model
(:func:`sbcal.data.noise.noise_model`), ``delta_k`` a model discrepancy shared by all runs of the test with a
learned scale ``s_q`` (``sigma_mag``, ``sigma_phase``; absent in the noise-only likelihood of
``sbcal diagnose``), and ``lambda_k ~ Gamma(nu_k / 2, nu_k / 2)`` says that the line's noise level is
known only as well as the repeats tell: ``nu_k`` is the noise estimate's degrees of freedom from the
neighbouring lines it was pooled with (at least :data:`NU_MIN`), and the line's own runs update it.
The runs of one line are then jointly **multivariate Student-t**::

    y_k ~ MVT_nu(mu_k 1, Sigma_k),   Sigma_k = sigma_k^2 I + s_q^2 1 1^T

This is the density the sampler samples, and it is a proper joint density of the runs, so it
decomposes by run exactly: the pointwise log-likelihood used by PSIS-LOO is the conditional density
of a run given the test's other runs, ``log p(y_r | y_-r, theta) = log p(y | theta) - log p(y_-r | theta)``,
a univariate t (closed form below). Its run mean is ``ybar_k ~ t_nu(mu_k, sigma_k^2 / n_k + s_q^2)``.

Closed forms (Sherman-Morrison), with ``S`` the runs' sum of squared deviations from their mean::

    Q = S / sigma^2 + n (ybar - mu)^2 / (sigma^2 + n s^2),   log|Sigma| = (n-1) log sigma^2 + log(sigma^2 + n s^2)
    log p(y) = lgamma((nu+n)/2) - lgamma(nu/2) + (nu/2) log nu - (n/2) log pi - log|Sigma| / 2
               - ((nu+n)/2) log(nu + Q)

and a run given the m = n - 1 others is ``t_{nu+m}(c, v (nu + Q_m) / (nu + m))`` with the normal
conditional mean ``c = mu + m s^2 / (sigma^2 + m s^2) (ybar_-r - mu)`` and variance
``v = sigma^2 + sigma^2 s^2 / (sigma^2 + m s^2)`` and ``Q_m`` the quadratic form of the others.
Why the discrepancy: if the model cannot follow the data, the misfit does not average away over runs,
so the credible bands stay as wide as the misfit instead of shrinking as 1/sqrt(n). Phase deviations
are wrapped to [-pi, pi).
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from ..model.damper import Damper
from ..model.fem import dynamic_stiffness
from .density_kernel import mvt_log_likelihood
from .priors import Prior


__all__ = ["NU_MIN", "TestLikelihood", "JointLikelihood", "wrap_phase"]

NU_MIN = 2.0
"""Least degrees of freedom of a line's noise level (a line whose sigma rests on its own runs only)."""

_NU_MAX = 1e6  # a known sigma (infinite dof) is taken as this: the normal limit to ~1e-9 in log density
_MODEL_ERROR = ("sigma_mag", "sigma_phase")


def wrap_phase(a):
    """Angle difference to [-pi, pi)."""
    return np.remainder(a + np.pi, 2 * np.pi) - np.pi


def _mvt_const(nu, n):
    """The theta-free part of the MVT log density of n runs: ``lgamma((nu+n)/2) - lgamma(nu/2) + nu/2 log nu - n/2 log pi``."""
    return gammaln((nu + n) / 2) - gammaln(nu / 2) + 0.5 * nu * np.log(nu) - 0.5 * n * np.log(np.pi)


class TestLikelihood:
    """Log-posterior of one test for the sampler: bound data, picklable, vectorised, parameters by name.

    Parameters
    ----------
    damper : Damper
    prior : Prior
        Its ``model_names`` go to the forward model; ``sigma_mag``/``sigma_phase``, when the prior has
        them, are the discrepancy scales (without them: the noise-only likelihood).
    freq_hz : ndarray, shape (n_freq,)
    magnitude : ndarray, shape (n_runs, n_freq)
        Cleaned runs, |F/X| [N/m]; NaN where a run lacks a line.
    phase_deg : ndarray, shape (n_runs, n_freq)
    sigma_logmag, sigma_phase : ndarray, shape (n_freq,)
        Noise model: scatter of one run, natural-log magnitude and phase [rad].
    noise_dof : array_like, shape (2, n_freq) or broadcastable, optional
        Degrees of freedom behind the sigmas (``NoiseModel.dof_logmag``, ``dof_phase``): the pooled
        ``sum (n_k - 1)``. The Student-t takes ``nu = max(noise_dof - (n - 1), NU_MIN)``: the
        neighbours' share, the line's own runs entering through the likelihood itself. ``inf`` for a
        known sigma (normal); default: sigma from the line's own runs only (``nu = NU_MIN``).
    fixed : dict, optional
        Model parameters held fixed (not sampled), passed to the forward model.
    model : callable, optional
        ``model(damper, freq_hz, **params) -> complex (n, n_freq)``; default
        :func:`sbcal.model.fem.dynamic_stiffness` (a physics extension swaps it).
    amplitude_mm_pp : ndarray, shape (n_freq,), optional
        Commanded amplitude per line (kept with the run; amplitude-dependent models read it).
    measured_distortion : ndarray, shape (n_freq,), optional
        The force's harmonic distortion measured per line (median over the runs; NaN where not measured;
        default: none). Kept with the data for the harmonic switch (:func:`sbcal.inference.distortion.predicted_distortion`);
        the density does not use it.

    Calling the object with ``z`` of shape ``(n, ndim)`` (the prior's sampled coordinates) returns
    the log-posterior, shape ``(n,)``: emcee's ``log_prob`` with ``vectorize=True``. Every other method
    takes the parameters by name: ``{name: ndarray (n,)}``.
    """

    __test__ = False  # "Test" here is a bench test, not a pytest class

    def __init__(self, damper: Damper, prior: Prior, freq_hz, magnitude, phase_deg, sigma_logmag,
                 sigma_phase, *, noise_dof=None, fixed=None, model=None, amplitude_mm_pp=None,
                 measured_distortion=None):
        self.damper = damper
        self.prior = prior
        self.freq_hz = np.asarray(freq_hz, dtype=float)
        self.amplitude_mm_pp = (np.full(self.freq_hz.shape, np.nan) if amplitude_mm_pp is None
                                else np.broadcast_to(np.asarray(amplitude_mm_pp, float), self.freq_hz.shape))
        self.measured_distortion = (np.full(self.freq_hz.shape, np.nan) if measured_distortion is None else
                                    np.broadcast_to(np.asarray(measured_distortion, float), self.freq_hz.shape))
        mag = np.atleast_2d(np.asarray(magnitude, dtype=float))
        self.y = np.stack([np.log(mag), np.radians(np.atleast_2d(phase_deg))])  # (2, n_runs, n_freq)
        self.present = np.isfinite(mag)
        self.n = self.present.sum(axis=0)  # (n_freq,)
        if np.any(self.n == 0):
            raise ValueError("every frequency line needs at least one run")
        self.sigma = np.stack([np.asarray(sigma_logmag, float), np.asarray(sigma_phase, float)])  # (2, F)
        if not np.all(np.isfinite(self.sigma) & (self.sigma > 0)):
            raise ValueError("noise scales must be finite and > 0")
        own = np.broadcast_to(np.maximum(self.n - 1, 0).astype(float), self.sigma.shape)
        pooled = own if noise_dof is None else np.broadcast_to(np.asarray(noise_dof, float), self.sigma.shape)
        self.nu = np.clip(pooled - own, NU_MIN, _NU_MAX)  # (2, F)
        # run deviations about their mean: phase about the median run, so a wrap cannot corrupt them
        ref = np.stack([np.zeros(self.freq_hz.shape), np.nanmedian(np.where(self.present, self.y[1], np.nan), axis=0)])
        d = np.where(self.present, self.y - ref[:, None, :], 0.0)
        d[1] = np.where(self.present, wrap_phase(d[1]), 0.0)
        self._ref, self._d = ref, d  # (2, F), (2, n_runs, F): each run's deviation from ref
        self.ybar = ref + d.sum(axis=1) / self.n  # (2, F)
        dev = np.where(self.present, d - (self.ybar - ref)[:, None, :], 0.0)
        self.ss = np.sum(dev * dev, axis=1)  # (2, F): S
        self._const = _mvt_const(self.nu, self.n)
        sig2 = self.sigma ** 2
        # the compiled density's per-line constants (ybar, S / sigma^2, sigma^2, n, nu, the theta-free part)
        self._density = tuple(np.ascontiguousarray(a, dtype=float) for a in (
            self.ybar, self.ss / sig2, sig2, self.n, self.nu, self._const - 0.5 * (self.n - 1) * np.log(sig2)))
        self.fixed = dict(fixed or {})
        self.model = dynamic_stiffness if model is None else model
        self._errors = all(n in prior.names for n in _MODEL_ERROR)
        self._poly = [n for n in prior.model_names if n.startswith("q")]

    # -- pieces -----------------------------------------------------------------------------
    def model_params(self, params: dict) -> dict:
        """The forward model's keyword arguments: the prior's model parameters plus ``fixed``."""
        p = {n: np.atleast_1d(params[n]) for n in self.prior.model_names}
        p.update(self.fixed)
        return p

    def predict(self, params: dict) -> np.ndarray:
        """Model curves ``mu``: shape ``(2, n, n_freq)`` (log-magnitude, phase [rad])."""
        fuu = self.model(self.damper, self.freq_hz, **self.model_params(params))
        return np.stack([np.log(np.abs(fuu)), np.angle(fuu)])

    def residual(self, mu) -> np.ndarray:
        """Run mean minus model, phase wrapped: ``(2, n, n_freq)``."""
        r = self.ybar[:, None, :] - mu
        r[1] = wrap_phase(r[1])
        return r

    def valid(self, params: dict) -> np.ndarray:
        """Support constraints beyond the box: a polynomial EJ(omega) must stay > 0 on the grid."""
        n = len(np.atleast_1d(params[self.prior.names[0]]))
        if not self._poly:
            return np.ones(n, bool)
        omega = 2 * np.pi * self.freq_hz
        ej = sum(np.atleast_1d(params[q])[:, None] * omega ** (int(q[1:]) - 1) for q in self._poly)
        return np.all(ej > 0, axis=1)

    def discrepancy_variance(self, params: dict, n: int) -> np.ndarray:
        """``s_q^2``: shape (2, n, 1) (zeros for the noise-only likelihood)."""
        if not self._errors:
            return np.zeros((2, n, 1))
        return np.stack([np.atleast_1d(params[q]) for q in _MODEL_ERROR])[:, :, None] ** 2

    def _parts(self, params, mu):
        mu = self.predict(params) if mu is None else mu
        return mu, self.discrepancy_variance(params, mu.shape[1]), self.sigma[:, None, :] ** 2

    def log_likelihood(self, params: dict, mu=None) -> np.ndarray:
        """Log density of all runs (multivariate t per line and quantity): ``(n,)``.

        ``mu`` (as :meth:`predict` returns) skips the forward model when the caller has it. Compiled
        (:func:`sbcal.inference.density_kernel.mvt_log_likelihood`).
        """
        mu = self.predict(params) if mu is None else mu
        s2 = self.discrepancy_variance(params, mu.shape[1])[:, :, 0]
        return mvt_log_likelihood(np.ascontiguousarray(mu, dtype=float), *self._density, np.ascontiguousarray(s2))

    def __call__(self, z) -> np.ndarray:
        return self.prior.log_posterior(z, self._valid_log_likelihood)

    def _valid_log_likelihood(self, params: dict) -> np.ndarray:
        """:meth:`log_likelihood` where :meth:`valid`, ``-inf`` elsewhere."""
        valid = self.valid(params)
        lp = np.full(valid.shape, -np.inf)
        if valid.any():
            lp[valid] = self.log_likelihood({k: v[valid] for k, v in params.items()})
        return lp

    # -- by run, for LOO, checks and predictions -----------------------------------------------
    def _conditional(self, mu, s2, sig2, dsum, ss, m):
        """The t of one more run given ``m`` runs (deviation sum ``dsum`` from ref, squares ``ss``):
        location offset from ``mu``, scale^2 and dof, each (2, n, F)."""
        mean_m = np.where(m > 0, dsum / np.maximum(m, 1), 0.0)  # mean deviation of the m runs from ref
        r = (self._ref + mean_m)[:, None, :] - mu
        r[1] = wrap_phase(r[1])
        big = sig2 + m * s2
        w = np.where(m > 0, m * s2 / big, 0.0)
        q = ss[:, None, :] / sig2 + m * r * r / big
        nu = self.nu[:, None, :]
        var = (sig2 + sig2 * s2 / big) * (nu + q) / (nu + m)
        return w * r, var, nu + m

    def pointwise_log_likelihood(self, params: dict, mu=None) -> np.ndarray:
        """``log p(y_r | y_-r, theta)`` per run: ``(n, n_runs)`` (lines and quantities summed).

        Exactly ``log_likelihood`` of all runs minus that of the runs without r (the t's closed form).
        """
        mu, s2, sig2 = self._parts(params, mu)
        n_runs = self.y.shape[1]
        out = np.zeros((mu.shape[1], n_runs))
        dsum = self._d.sum(axis=1)
        dbar = dsum / self.n
        for r in range(n_runs):
            pres = self.present[r]
            m = self.n - pres
            # the others' squared deviations about their own mean: S - n/m (d_r - dbar)^2
            ss_other = np.where(pres & (m > 0), self.ss - self.n / np.maximum(m, 1) * (self._d[:, r] - dbar) ** 2,
                                self.ss)
            shift, var, dof = self._conditional(mu, s2, sig2, dsum - self._d[:, r], np.maximum(ss_other, 0.0), m)
            e = (self._ref + self._d[:, r])[:, None, :] - mu - shift
            e[1] = wrap_phase(e[1])
            lp = (gammaln((dof + 1) / 2) - gammaln(dof / 2) - 0.5 * np.log(dof * np.pi * var)
                  - 0.5 * (dof + 1) * np.log1p(e * e / (dof * var)))
            out[:, r] = np.sum(np.where(pres, lp, 0.0), axis=(0, 2))
        return out

    def new_run(self, params: dict, mu=None):
        """The t of a new run given all recorded runs: ``(location, scale, dof)``, each (2, n, n_freq)."""
        mu, s2, sig2 = self._parts(params, mu)
        shift, var, dof = self._conditional(mu, s2, sig2, self._d.sum(axis=1), self.ss, self.n)
        return mu + shift, np.sqrt(var), dof

    def mean_scale(self, params: dict, mu=None):
        """The t of the run mean given the runs' deviations: ``(scale, dof)``, each (2, n, n_freq).

        ``ybar - mu ~ t_{nu+n-1}(0, (sigma^2/n + s^2) (nu + S/sigma^2) / (nu + n - 1))`` (the deviations
        inform the line's noise level; ``sbcal diagnose`` standardises residuals with it).
        """
        mu, s2, sig2 = self._parts(params, mu)
        nu = self.nu[:, None, :]
        dof = nu + self.n - 1
        var = (sig2 / self.n + s2) * (nu + self.ss[:, None, :] / sig2) / dof
        return np.sqrt(var), np.broadcast_to(dof, var.shape)

    def predictive(self, params: dict, rng: np.random.Generator) -> np.ndarray:
        """One posterior-predictive new run per parameter set: ``(2, n, n_freq)`` (log-magnitude, phase [rad])."""
        loc, scale, dof = self.new_run(params)
        return loc + scale * rng.standard_t(np.broadcast_to(dof, loc.shape))

    def thesis_cost(self, params: dict) -> np.ndarray:
        """The thesis's GA fitness (Eq. 4.5) on the run means: ``(n,)``.

        ``sqrt(W1 sum W3 (a - b)^2 / a^2 + W2 sum W3 (x - y)^2 / x^2)``: relative magnitude and phase
        errors (phase in degrees), ``W1 = 0.3``, ``W2 = 0.7``, ``W3`` the local frequency step
        normalised to mean 1 (the grid is uneven).
        """
        fuu = self.model(self.damper, self.freq_hz, **self.model_params(params))
        a = np.exp(self.ybar[0])
        ph = np.degrees(self.ybar[1])
        w3 = np.gradient(self.freq_hz) if self.freq_hz.size > 1 else np.ones(1)
        w3 = w3 / w3.mean()
        em = np.sum(w3 * ((a - np.abs(fuu)) / a) ** 2, axis=1)
        ep = np.sum(w3 * ((ph - np.degrees(np.angle(fuu))) / ph) ** 2, axis=1)
        return np.sqrt(0.3 * em + 0.7 * ep)


class JointLikelihood:
    """One parameter set for several tests: the log-posterior over all their runs.

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
        ``model(damper, freq_hz, **params) -> complex (n, n_lines)`` on the concatenated lines.
    """

    def __init__(self, likes, prior: Prior, model):
        self.likes = list(likes)
        self.damper = self.likes[0].damper
        self.prior = prior
        self.model = model
        self.freq_hz = np.concatenate([lk.freq_hz for lk in self.likes])
        self._split = np.cumsum([lk.freq_hz.size for lk in self.likes])[:-1]

    def model_params(self, params: dict) -> dict:
        """The forward model's keyword arguments: the prior's model parameters, each ``(n,)``."""
        return {n: np.atleast_1d(params[n]) for n in self.prior.model_names}

    def predict(self, params: dict) -> list:
        """Model curves per test: a list of ``(2, n, n_freq_t)`` (log-magnitude, phase [rad])."""
        fuu = self.model(self.damper, self.freq_hz, **self.model_params(params))
        mu = np.stack([np.log(np.abs(fuu)), np.angle(fuu)])
        return np.split(mu, self._split, axis=2)

    def log_likelihood(self, params: dict) -> np.ndarray:
        return sum(lk.log_likelihood(params, mu) for lk, mu in zip(self.likes, self.predict(params)))

    def pointwise_log_likelihood(self, params: dict) -> np.ndarray:
        """Per run of every test, tests in order: ``(n, sum of n_runs)``."""
        return np.concatenate([lk.pointwise_log_likelihood(params, mu)
                               for lk, mu in zip(self.likes, self.predict(params))], axis=1)

    def __call__(self, z) -> np.ndarray:
        return self.prior.log_posterior(z, self.log_likelihood)
