"""The base force's harmonic distortion a fitted cable law predicts (issue 21).

The fits use the describing-function model (:class:`sbcal.model.cable.CableModel`: each section at the
first harmonic of its own curvature); a slipping cable's moment, and so the base force, is not a sine.
:func:`predicted_distortion` solves the fit's cable at its posterior median with several odd harmonics
(:class:`sbcal.model.cable_harmonics.HarmonicBalance`) on every line of the fit's tests and says, per line,
how distorted the force is and how far the first-harmonic model the fit used is from the multi-harmonic
solve. One parameter set, not every draw: the solve costs 0.05-0.5 s a line for the Iwan laws (more for
Bouc-Wen at large amplitude), a fit's draws thousands of times that.

It is computed where a cable fit is stored (:func:`sbcal.inference.cable_fit.store_cable`, the diagnosis's
curves) and kept with it (``harmonics`` in ``cable-<state>/summary.json``); the report reads it.
"""

from __future__ import annotations

import time

import numpy as np

from ..model.cable_harmonics import DEFAULT_HARMONICS


__all__ = ["HARMONICS", "predicted_distortion"]

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
        null; ``n_not_converged``; ``parameters`` (``"posterior median"``); ``wall_s`` [s].
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
    return {
        "orders": list(state.orders), "parameters": "posterior median",
        "freq_hz": _per_test(like.freq_hz, tests, sizes), "amplitude_mm_pp": _per_test(amp, tests, sizes),
        "distortion": _per_test(distortion, tests, sizes), "gap": _per_test(gap, tests, sizes),
        "converged": _per_test(converged, tests, sizes),
        "largest": {"distortion": _largest(distortion, like.freq_hz, amp, test_of),
                    "gap": _largest(gap, like.freq_hz, amp, test_of)},
        "n_not_converged": int((~converged).sum()), "wall_s": time.perf_counter() - t0,
    }
