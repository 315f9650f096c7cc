"""The base force's harmonic distortion a fitted cable law predicts (issue 21).

The fits use the describing-function model (:class:`sbcal.model.cable.CableModel`: each section at the
first harmonic of its own curvature); a slipping cable's moment, and so the base force, is not a sine.
:func:`predicted_distortion` solves the fit's cable at its posterior median with several odd harmonics
(:class:`sbcal.model.cable_harmonics.HarmonicBalance`) on every line of the fit's tests and says, per line,
how distorted the force is and how far the first-harmonic model the fit used is from the multi-harmonic
solve. One parameter set, not every draw: the solve costs 0.05-0.5 s a line for the Iwan laws (more for
Bouc-Wen at large amplitude), a fit's draws thousands of times that.

Where the bench file carries the distortion measured per line (``sbcal import``: the ``distortion`` column), it
is set beside the prediction, and the *harmonic switch* says per line whether the multi-harmonic solve is
needed (:func:`harmonic_switch`): only where the first-harmonic model's gap exceeds what the data resolve
*and* the measured force is distorted as the law predicts. A law that predicts distortion the recordings do not
have is then named, rather than trusted.

It is computed where a cable fit is stored (:func:`sbcal.inference.cable_fit.store_cable`, the diagnosis's
curves) and kept with it (``harmonics`` in ``cable-<state>/summary.json``); the report reads it.
"""

from __future__ import annotations

import time

import numpy as np

from ..model.cable_harmonics import DEFAULT_HARMONICS


__all__ = ["HARMONICS", "AGREEMENT", "RESOLVED", "line_standard_errors", "predicted_distortion", "harmonic_switch"]

HARMONICS = DEFAULT_HARMONICS
"""Odd harmonics solved (orders 1, 3, 5, 7, 9): the multi-harmonic solve's default."""


def _per_test(values, tests, sizes) -> dict:
    """``{test: list}`` of a flat per-line array over the concatenated lines (NaN -> None: JSON null)."""
    parts = np.split(np.asarray(values), np.cumsum(sizes)[:-1])
    return {t: [None if isinstance(v, float) and not np.isfinite(v) else v for v in part.tolist()]
            for t, part in zip(tests, parts)}


def _largest(values, freq_hz, amplitude_mm_pp, test_of) -> dict | None:
    """Where a per-line quantity is largest: ``{value, test, freq_hz, amplitude_mm_pp}``; None when it is
    NaN on every line."""
    if not np.isfinite(values).any():
        return None
    i = int(np.nanargmax(values))
    return {"value": float(values[i]), "test": test_of[i], "freq_hz": float(freq_hz[i]),
            "amplitude_mm_pp": float(amplitude_mm_pp[i])}


AGREEMENT = 0.5
"""The measured distortion must be at least this share of the predicted one for the data to confirm it (and at
most its inverse: a law that predicts a third of what is measured is not the cable's either)."""

RESOLVED = 2.0
"""A gap is resolved by the data where it exceeds this many standard errors of the line's mean."""


def line_standard_errors(like) -> np.ndarray:
    """Standard errors of the lines' mean log-magnitude [1] and phase [rad] over the concatenated lines of a
    joint likelihood (the noise model's sigma over sqrt(runs)), shape (2, n_lines)."""
    return np.concatenate([lk.sigma / np.sqrt(lk.n) for lk in like.likes], axis=1)



def harmonic_switch(predicted, measured, gap, sigma_mean) -> tuple[np.ndarray, np.ndarray]:
    """Per line: is the multi-harmonic solve needed, and do the recordings confirm the predicted distortion?

    Parameters
    ----------
    predicted, measured : ndarray, shape (n_freq,)
        Force distortion [1] predicted (posterior median) and measured (median over the runs; NaN: not measured).
    gap : ndarray, shape (n_freq,)
        ``|f_uu / f_uu_first - 1|`` [1] of the multi-harmonic solve against the first-harmonic model (NaN: the
        solve did not converge).
    sigma_mean : ndarray, shape (n_freq,)
        Standard error of the line's mean log-magnitude [1] (the noise model's sigma over sqrt(runs)).

    Returns
    -------
    switch : ndarray of bool, shape (n_freq,)
        The gap is resolved (``> 2 sigma_mean``) and the measured distortion agrees with the predicted within a
        factor :data:`AGREEMENT`: the first-harmonic model misses what the data hold there.
    agrees : ndarray of bool, shape (n_freq,)
        The measured distortion agrees with the predicted (False where either is missing).
    """
    p, m, g = (np.asarray(a, float) for a in (predicted, measured, gap))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = m / p
        agrees = np.isfinite(ratio) & (ratio >= AGREEMENT) & (ratio <= 1 / AGREEMENT)
        switch = agrees & (g > RESOLVED * np.asarray(sigma_mean, float))
    return switch, agrees


def predicted_distortion(like, params: dict, tests) -> dict:
    """The force distortion a cable fit predicts per line, at one parameter set (the posterior median).

    Parameters
    ----------
    like : JointLikelihood
        The fit's likelihood (:func:`sbcal.inference.cable_fit.cable_likelihood`): its lines, amplitudes,
        damper and forward model (:class:`sbcal.inference.cable_fit.CableForward`), so the parameters reach
        the cable exactly as in the fit (geometry, rocking, the measurement chain's effects).
    params : dict
        Natural values by name, floats (every name of ``like.prior``).
    tests : sequence of str
        The fit's tests, in the likelihood's order.

    Returns
    -------
    dict
        JSON-ready. ``orders``: the harmonic orders solved; per test (``{test: list}``, one entry per line):
        ``freq_hz`` [Hz], ``amplitude_mm_pp`` [mm p-p], ``distortion`` (``sqrt(sum_{h>1} |F_h|^2) / |F_1|`` of
        the measured base force [1]), ``gap`` (``|f_uu / f_uu_first - 1|``: the first-harmonic model against
        the multi-harmonic solve [1]), both null where the solve did not converge, and ``converged``;
        ``largest``: ``{"distortion": ..., "gap": ...}``, each ``{value, test, freq_hz, amplitude_mm_pp}`` or
        null; ``n_not_converged``; ``parameters`` (``"posterior median"``); ``wall_s`` [s]. Where the data carry
        a measured distortion: ``measured`` (per test, null where not measured), ``switch`` and ``agrees`` (per
        test, :func:`harmonic_switch`) and ``comparison``: ``{n_measured, n_agree, n_switch, median_ratio}``
        (median of measured over predicted on lines predicted above 1 %, or null).
    """
    t0 = time.perf_counter()
    state, f_uu, first = like.model.harmonic_state(like.damper, like.freq_hz, harmonics=HARMONICS,
                                                    **like.model_params(params))
    converged = state.converged[0]
    # a fixture mass's force is a sine: it adds to the measured first harmonic only (a delay moves no magnitude)
    distortion = np.where(converged, state.distortion[0] * np.abs(state.f_uu[0]) / np.abs(f_uu[0]), np.nan)
    gap = np.where(converged, np.abs(f_uu[0] / first[0] - 1), np.nan)
    sizes = [lk.freq_hz.size for lk in like.likes]
    amp = like.model.amplitude_mm_pp
    test_of = np.repeat(list(tests), sizes).tolist()
    out = {
        "orders": list(state.orders), "parameters": "posterior median",
        "freq_hz": _per_test(like.freq_hz, tests, sizes), "amplitude_mm_pp": _per_test(amp, tests, sizes),
        "distortion": _per_test(distortion, tests, sizes), "gap": _per_test(gap, tests, sizes),
        "converged": _per_test(converged, tests, sizes),
        "largest": {"distortion": _largest(distortion, like.freq_hz, amp, test_of),
                    "gap": _largest(gap, like.freq_hz, amp, test_of)},
        "n_not_converged": int((~converged).sum()), "wall_s": time.perf_counter() - t0,
    }
    measured = np.concatenate([lk.measured_distortion for lk in like.likes])
    if np.isfinite(measured).any():
        sigma_mean = line_standard_errors(like)[0]
        switch, agrees = harmonic_switch(distortion, measured, gap, sigma_mean)
        have = np.isfinite(measured) & np.isfinite(distortion)
        big = have & (distortion > 0.01)
        out.update(measured=_per_test(measured, tests, sizes), switch=_per_test(switch, tests, sizes),
                   agrees=_per_test(agrees, tests, sizes),
                   comparison={"n_measured": int(have.sum()), "n_agree": int(agrees.sum()),
                               "n_switch": int(switch.sum()),
                               "median_ratio": float(np.median(measured[big] / distortion[big])) if big.any() else None})
    return out
