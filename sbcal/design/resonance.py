"""Resonances of a damper's characteristic, draw by draw: the one peak finder of ``predict`` and ``compare``.

A resonance is a local maximum against frequency of the damper's mechanical resistance
``R = Re(F / V) = Im(f_uu) / omega`` [N s/m]: where the damper takes the most power per unit squared clamp
velocity (``P = 0.5 R (omega X0)^2``; under constant velocity the maxima of the power itself). The peaks of
the median curve of ``ln R`` over the draws (prominence :data:`PROMINENCE`) define windows between the
minima that separate them; each draw's resonance is its local maximum inside the window nearest the
median's peak, refined by the parabola through its three lines in (ln f, ln R) (the grid may be uneven:
a bench's lines). A draw without a local maximum in the window has none (NaN).
"""

from __future__ import annotations

import warnings

import numpy as np


__all__ = ["PROMINENCE", "resonance_draws"]

PROMINENCE = 0.05
"""Least prominence of a peak of the median resistance curve in ln R (5 %) to count as a resonance."""


def _log_resistance(freq_hz, fuu) -> np.ndarray:
    omega = 2 * np.pi * np.asarray(freq_hz, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.imag(fuu) / omega
        return np.where(r > 0, np.log(np.where(r > 0, r, 1.0)), np.nan)


def resonance_draws(freq_hz, fuu, x0) -> list:
    """Every resonance of a characteristic, per draw.

    Parameters
    ----------
    freq_hz : ndarray, shape (F,)
        Increasing frequency lines [Hz] (any spacing).
    fuu : ndarray of complex, shape (S, F)
        Draws of the dynamic stiffness [N/m] (NaN where a draw has no value).
    x0 : ndarray, shape (F,)
        Clamp amplitude per line [m, 0-peak].

    Returns
    -------
    list of dict
        One per resonance, increasing in frequency: ``freq_hz`` and ``power_w`` (S,) per draw (NaN where
        the draw has none in the window), ``median_hz`` the median curve's peak line [Hz] and
        ``prominence`` its prominence in ln R.
    """
    from scipy.signal import find_peaks

    f = np.asarray(freq_hz, float)
    logr = _log_resistance(f, fuu)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(logr, axis=0)
    ok = np.isfinite(med)
    if ok.sum() < 3:
        return []
    med = np.where(ok, med, np.nanmin(med[ok]))
    peaks, props = find_peaks(med, prominence=PROMINENCE)
    bounds = [0] + [int(a + np.argmin(med[a:b + 1])) for a, b in zip(peaks[:-1], peaks[1:])] + [f.size - 1]
    lf = np.log(f)
    filled = np.where(np.isfinite(logr), logr, -np.inf)
    rows = np.arange(filled.shape[0])
    out = []
    for k in range(peaks.size):  # a handful of peaks; vectorised over the draws
        a, b = bounds[k], bounds[k + 1]
        sub = filled[:, a:b + 1]
        if sub.shape[1] < 3:
            continue
        # each draw's local maximum nearest the median's peak (a window may also hold a rising edge)
        top = np.zeros(sub.shape, dtype=bool)
        top[:, 1:-1] = (sub[:, 1:-1] >= sub[:, :-2]) & (sub[:, 1:-1] > sub[:, 2:]) & np.isfinite(sub[:, 1:-1])
        dist = np.where(top, np.abs(np.arange(sub.shape[1]) - (peaks[k] - a))[None, :], sub.shape[1])
        j = np.argmin(dist, axis=1)
        jj = np.clip(j, 1, sub.shape[1] - 2)
        y0, y1, y2 = sub[rows, jj - 1], sub[rows, jj], sub[rows, jj + 1]
        u0, u1, u2 = lf[a + jj - 1], lf[a + jj], lf[a + jj + 1]
        interior = top[rows, j] & np.isfinite(y0) & np.isfinite(y2)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # the parabola through three points of uneven spacing: y = y1 + c1 (u - u1) + c2 (u - u1)^2
            d0, d2 = u0 - u1, u2 - u1
            c2 = ((y0 - y1) / d0 - (y2 - y1) / d2) / (d0 - d2)
            c1 = (y0 - y1) / d0 - c2 * d0
            shift = np.where(c2 < 0, -c1 / (2 * np.where(c2 < 0, c2, -1.0)), 0.0)
            shift = np.clip(shift, d0 / 2, d2 / 2)  # within half a step of the line either side
            fk = np.exp(u1 + shift)
            rk = np.exp(y1 + c1 * shift + c2 * shift ** 2)
        xk = np.interp(np.log(fk), lf, np.asarray(x0, float))
        pk = 0.5 * rk * (2 * np.pi * fk * xk) ** 2
        out.append({"freq_hz": np.where(interior, fk, np.nan), "power_w": np.where(interior, pk, np.nan),
                    "median_hz": float(f[peaks[k]]), "prominence": float(props["prominences"][k])})
    return out
