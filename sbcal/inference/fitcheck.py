"""Does a test's fitted curve pass through its runs? The check a report prints beside each posterior.

The likelihood (:mod:`sbcal.inference.likelihood`) says that at line ``k`` the runs' mean is
``ybar_k = mu_k(theta) + delta_k + e_k``: the model curve, a discrepancy ``delta_k ~ N(0, s_q^2)``
**independent from line to line**, and the mean's noise ``e_k ~ N(0, SE_k^2)``, ``SE_k = sd_k / sqrt(n_k)``
from the runs' own scatter. A converged posterior can still be a bad fit: a large learned ``s_q`` (the
model error) hides a curve that misses the runs' mean by many times their noise, and when that misfit
is the shape of missing physics it is smooth over frequency, which the model's own assumption (an
independent discrepancy per line) excludes. Two statements, from the stored posterior only:

- **where the curve misses the mean**: lines with ``|ybar_k - median mu_k| > t* SE_k``, ``t*`` the
  Student-t quantile (``n_k - 1`` degrees of freedom: ``SE_k`` is estimated from the same runs) of
  ``alpha / (2 n_lines)`` (Bonferroni over the lines: at most ``alpha`` false alarms a quantity when the
  curve is right);
- **the model's own check**: the lag-1 autocorrelation over frequency of the standardised residuals
  ``(ybar_k - mu_k) / sqrt(SE_k^2 + s_q^2)``, against the same statistic of the residuals permuted over
  the lines (:data:`PERMUTATIONS`, a fixed generator: the same page every time): under the model's
  independent discrepancy the lines are exchangeable, so the check, failing at a permutation p-value
  below ``alpha``, has size ``alpha`` for any number of lines (the normal approximation
  ``N(-1/n, 1/n)`` gives 0.4 % instead of 1 % at 37 lines).

The median curve and the median ``s_q`` stand for the posterior (both are tightly known when the
check matters). Phase differences are wrapped to [-180, 180) deg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import t as student_t

from .likelihood import wrap_phase


__all__ = ["FitCheck", "check_curve", "fit_check"]

PERMUTATIONS = 1999
"""Permutations of the lag-1 test (p-values in steps of 1/2000)."""

_QUANTITIES = (("magnitude", "logmag", "sigma_mag"), ("phase", "phase", "sigma_phase"))


@dataclass(frozen=True)
class FitCheck:
    """One quantity's check (:func:`fit_check`).

    Attributes
    ----------
    quantity : str
        ``"magnitude"`` or ``"phase"``.
    freq_hz : ndarray, shape (n_freq,)
    misfit : ndarray, shape (n_freq,)
        Runs' mean minus the median model curve: ln |f| [1] or phase [deg].
    missed : ndarray of bool, shape (n_freq,)
        Lines where the curve misses the mean beyond its noise (module docstring).
    noise_ratio : float
        The median model error ``s_q`` over the median standard error of the runs' mean.
    lag1 : float
        The standardised residuals' lag-1 autocorrelation over frequency.
    p_value : float
        Its permutation p-value under the model's independent discrepancy.
    alpha : float
    """

    quantity: str
    freq_hz: np.ndarray
    misfit: np.ndarray
    missed: np.ndarray
    noise_ratio: float
    lag1: float
    p_value: float
    alpha: float

    @property
    def fails(self) -> bool:
        """The model's own assumption (a discrepancy independent from line to line) is contradicted."""
        return bool(self.p_value < self.alpha)

    def bands(self) -> str:
        """The missed lines as frequency ranges: ``"12-14, 30-40 Hz"``."""
        f, m = self.freq_hz, self.missed
        out, start = [], None
        for i in range(f.size + 1):
            if i < f.size and m[i]:
                start = i if start is None else start
            elif start is not None:
                out.append(f"{f[start]:g}" if start == i - 1 else f"{f[start]:g}-{f[i - 1]:g}")
                start = None
        return ", ".join(out) + " Hz" if out else ""

    def words(self) -> str:
        """One sentence for the report."""
        worst = float(np.nanmax(np.abs(self.misfit))) if self.misfit.size else 0.0
        size = f"{100 * np.expm1(worst):.0f} %" if self.quantity == "magnitude" else f"{worst:.0f} deg"
        where = (f"misses the runs' mean at {int(self.missed.sum())} of {self.missed.size} lines ({self.bands()}) "
                 f"by up to {size}" if self.missed.any() else "stays within the runs' noise at every line")
        text = f"{self.quantity}: the median curve {where}; model error {self.noise_ratio:.3g} times the mean's noise"
        if self.fails:
            text += (f"; the misfit is smooth over frequency (lag-1 correlation {self.lag1:.2f}, p = {self.p_value:.2g} "
                     f"under the model's independent error): physics the model lacks, not noise")
        return text


def _lag1(z: np.ndarray) -> np.ndarray:
    """Lag-1 autocorrelation along the last axis (mean removed); 0 for a constant row."""
    z = z - z.mean(axis=-1, keepdims=True)
    ss = np.sum(z**2, axis=-1)
    return np.divide(np.sum(z[..., 1:] * z[..., :-1], axis=-1), ss, out=np.zeros_like(ss), where=ss > 0)


def _lag1_test(z: np.ndarray, rng) -> tuple[float, float]:
    """The lag-1 autocorrelation of ``z`` and its one-sided permutation p-value."""
    if z.size < 3:
        return 0.0, 1.0
    observed = float(_lag1(z))
    null = _lag1(rng.permuted(np.broadcast_to(z, (PERMUTATIONS, z.size)), axis=1))
    return observed, float((1 + np.sum(null >= observed)) / (1 + PERMUTATIONS))


def check_curve(quantity: str, freq_hz, runs, curve, model_error: float = 0.0, *, alpha: float = 0.01) -> FitCheck:
    """One quantity's :class:`FitCheck` from arrays.

    Parameters
    ----------
    quantity : {"magnitude", "phase"}
    freq_hz : array_like, shape (n_freq,)
    runs : array_like, shape (n_runs, n_freq)
        The recorded runs: ln |f| [1] or phase [rad] (NaN where a run lacks a line).
    curve : array_like, shape (n_freq,)
        The model's median curve, same units.
    model_error : float
        The median learned discrepancy scale ``s_q`` (same units; 0 for a noise-only likelihood).
    alpha : float
        The size of each statement (module docstring).
    """
    f = np.asarray(freq_hz, float)
    obs = np.asarray(runs, float)
    n = np.isfinite(obs).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ybar = np.nanmean(obs, axis=0)
        se = np.nanstd(obs, axis=0, ddof=1) / np.sqrt(n)
    d = ybar - np.asarray(curve, float)
    if quantity == "phase":
        d = wrap_phase(d)
    ok = np.isfinite(d) & np.isfinite(se) & (se > 0)
    limit = student_t.isf(alpha / (2 * max(ok.sum(), 1)), np.maximum(n - 1, 1)) * se
    missed = ok & (np.abs(d) > np.where(ok, limit, np.inf))
    lag1, p = _lag1_test(d[ok] / np.sqrt(se[ok] ** 2 + model_error**2), np.random.default_rng(0))
    return FitCheck(quantity=quantity, freq_hz=f, misfit=np.degrees(d) if quantity == "phase" else d, missed=missed,
                    noise_ratio=model_error / float(np.median(se[ok])) if ok.any() else float("nan"),
                    lag1=lag1, p_value=p, alpha=alpha)


def fit_check(idata, *, alpha: float = 0.01) -> list[FitCheck]:
    """Both quantities' :class:`FitCheck` of a stored test posterior.

    Parameters
    ----------
    idata : arviz.InferenceData
        A run's ``posterior.nc``: ``constant_data`` ``freq_hz``, ``observed_data`` (run, freq) of ``logmag``
        and ``phase`` [rad], ``posterior_predictive`` ``model_logmag``/``model_phase`` (chain, draw, freq),
        and, when the likelihood has them, ``sigma_mag``/``sigma_phase`` in the posterior.
    alpha : float
    """
    f = np.asarray(idata.constant_data["freq_hz"], float)
    out = []
    for name, key, scale in _QUANTITIES:
        model = np.asarray(idata.posterior_predictive[f"model_{key}"], float).reshape(-1, f.size)
        s = float(np.median(np.asarray(idata.posterior[scale]))) if scale in idata.posterior else 0.0
        out.append(check_curve(name, f, idata.observed_data[key], np.median(model, axis=0), s, alpha=alpha))
    return out
