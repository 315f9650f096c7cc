"""A test's true mean curve given its runs: the model plus the discrepancy's posterior.

The likelihood (:mod:`sbcal.inference.likelihood`) carries the model's misfit as a discrepancy
``delta_k ~ N(0, s^2)`` per line, shared by the test's runs. The damper's true mean curve is ``mu + delta``,
and given the run mean ``ybar`` (per posterior draw of ``mu`` and ``s``)::

    ybar - mu = delta + e,   e ~ N(0, C)
    delta | ybar ~ N(s^2 (s^2 I + C)^-1 (ybar - mu),  s^2 I - s^2 (s^2 I + C)^-1 s^2)

with ``C`` the run mean's error covariance over the lines, from the runs themselves: a re-clamped run moves
all its lines together, and an error smooth over the lines moves a resonance far less than independent
errors of the same size would. With fewer runs than lines (a lab's 3 to 10 runs over 37 lines) the runs'
sample covariance is singular: a posterior given it would take the run mean as exact in every direction
the few runs happen not to span. Its correlations are therefore shrunk toward none by the Schafer-Strimmer
intensity (as far as the runs' number leaves them uncertain), and each line's variance is floored at the
measured noise over the run count. The draw is exact (Matheron's rule: prior draws of ``delta`` and ``e``
corrected by the gain, ``delta = d + s^2 (s^2 I + C)^-1 (ybar - mu - d - e)``).

Tried and measured, not kept (docs/compare.md): a discrepancy smooth in ``ln f`` (a Gaussian process whose
length the runs choose) to take the noise out of the largest-over-the-lines change. On the virtual bench it
chose a length near the line spacing, left that criterion as conservative as before and made the first
resonance's frequency overconfident (its length smooths the misfit's sharp shape at the peak).
"""

from __future__ import annotations

import numpy as np


__all__ = ["true_mean_draws"]

_JITTER = 1e-9


def _wrap(x, wrap):
    return np.where(wrap, np.angle(np.exp(1j * x)), x)


def _run_mean(y, wrap):
    """The runs' mean per line; a phase's as the mean direction (runs either side of +-pi)."""
    with np.errstate(invalid="ignore"):
        return np.where(wrap, np.angle(np.nanmean(np.exp(1j * y), axis=0)), np.nanmean(y, axis=0))


def _mean_error_cov(y, noise_var, wrap) -> np.ndarray:
    """The run mean's error covariance over the lines, shape (F, F).

    The runs' sample covariance over ``n``, its correlations shrunk toward none by the Schafer-Strimmer
    intensity (``lambda = sum Var(r_ij) / sum r_ij^2`` over ``i != j``): with fewer runs than lines the sample
    covariance is singular, and a posterior given it would take the run mean as exact in the directions the
    runs happen not to span. Each line's variance is floored at the measured noise over ``n``.
    """
    n_line = np.sum(np.isfinite(y), axis=0).astype(float)
    dev = np.nan_to_num(_wrap(y - _run_mean(y, wrap), wrap))  # a missing run adds nothing
    R = y.shape[0]
    var = np.sum(dev * dev, axis=0) / np.maximum(n_line - 1, 1.0)
    sd = np.sqrt(np.maximum(var, 1e-300))
    x = dev / sd  # standardised deviations, (R, F)
    w = x[:, :, None] * x[:, None, :]  # (R, F, F)
    corr = w.sum(axis=0) / max(R - 1, 1)
    off = ~np.eye(corr.shape[0], dtype=bool)
    var_corr = R / max(R - 1, 1) ** 3 * np.sum((w - w.mean(axis=0)) ** 2, axis=0)
    denom = np.sum(corr[off] ** 2)
    lam = 1.0 if denom == 0 else float(np.clip(np.sum(var_corr[off]) / denom, 0.0, 1.0))
    corr = np.where(off, (1 - lam) * corr, 1.0)
    v = np.maximum(var, np.asarray(noise_var, float)) / np.maximum(n_line, 1.0)
    return np.sqrt(v)[:, None] * corr * np.sqrt(v)[None, :]


def true_mean_draws(mu, s, y, noise_var, *, wrap, rng: np.random.Generator) -> np.ndarray:
    """Draws of the true mean curve, ``mu + delta`` (module docstring).

    Both quantities of a test go in at once, as columns (log-magnitude lines, then phase lines), so that the
    run mean's error keeps its correlation between a line's magnitude and phase (a re-clamped run moves both).

    Parameters
    ----------
    mu : ndarray, shape (S, F)
        The model curve per posterior draw (log-magnitude, or phase [rad], per column).
    s : ndarray, shape (S,) or (S, F)
        The discrepancy's scale per draw (``sigma_mag`` or ``sigma_phase``), per column where they differ.
    y : ndarray, shape (R, F)
        The runs (NaN where a run misses a line).
    noise_var : ndarray, shape (F,)
        The line's measured noise variance (one run's).
    wrap : bool or ndarray of bool, shape (F,)
        The columns that are phases: their run mean is the mean direction, their residuals and deviations
        are wrapped to (-pi, pi].
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (S, F)
    """
    mu = np.asarray(mu, float)
    S, F = mu.shape
    s2 = np.broadcast_to(np.asarray(s, float).reshape(S, -1), (S, F)) ** 2
    wrap = np.broadcast_to(np.asarray(wrap, bool), (F,))
    y = np.asarray(y, float)
    r = _wrap(_run_mean(y, wrap) - mu, wrap)
    C = _mean_error_cov(y, noise_var, wrap)
    C = C + np.diag(_JITTER * np.diag(C) + 1e-300)
    d = np.sqrt(s2) * rng.standard_normal((S, F))  # prior draws of delta, independent lines
    e = rng.standard_normal((S, F)) @ np.linalg.cholesky(C).T  # ... and of the run mean's error
    A = C[None, :, :] + s2[:, :, None] * np.eye(F)  # s^2 I + C per draw
    gain_in = np.linalg.solve(A, (r - d - e)[:, :, None])[..., 0]
    return mu + d + s2 * gain_in
