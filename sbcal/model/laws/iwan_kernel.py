"""The Iwan laws' describing functions compiled (numba): the five-parameter law's in one fused loop per
point, and the slip integral every Iwan law with cut-offs calls (:func:`slip_integral`).

:class:`sbcal.model.laws.iwan.Iwan5Law` is the law sbcal fits most, and its describing function is what
the cable model's compliance table evaluates (~230 curvatures per parameter set and call): in numpy it
cost ~0.7 us a point, most of it two incomplete beta functions and the temporaries of ~40 array passes,
more than the cable's Newton on a one-test fit (``docs/cable.md``, "Speed"). Here each point runs the
arithmetic of the numpy formulation (``tests/law_reference.py``) in registers, with

- the incomplete beta integral ``B(x; a, 3/2)`` from its power series where ``x <= 0.3`` (at most ~30
  terms to rounding; the lower cut-off ``x_lo = chi_micro / chi_a`` mostly lies there), scipy's own
  ``betainc`` elsewhere, none at ``x = 1`` (the complete integral);
- ``Beta(a, 3/2)`` computed once per run of equal exponents (the table's points share their set's).

The two agree to rounding, amplified only where the formulation itself amplifies it (``|c + 1|`` near 0,
its ~1/p cancellation: :data:`sbcal.model.laws.iwan._P_ZERO`); ``tests/test_law_kernels.py`` holds them
together. Compiled on first use and cached on disk (numba's ``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .scipy_c import beta, betainc


__all__ = ["iwan5_rigidity", "slip_integral"]

_SERIES_X = 0.3  # B(x; a, 3/2) by its power series below this x (ratio of terms -> x: ~30 terms to 1e-16)
_SERIES_TERMS = 200


@njit(cache=True, error_model="numpy", inline="always")
def _jenkins(x):
    """``(Re, Im)`` of :func:`sbcal.model.laws.base.jenkins_rigidity` at ``x >= 0``."""
    if x >= 1.0:
        return 1.0, 0.0
    xs = max(x, 0.0)
    theta = math.acos(1.0 - 2.0 * xs)
    return (theta - math.sin(theta) * math.cos(theta)) / math.pi, 4.0 * xs * (1.0 - xs) / math.pi


@njit(cache=True, error_model="numpy", inline="always")
def _power_integral(x1, x2, q):
    """``int_x1^x2 x^(q-1) dx`` (:func:`sbcal.model.laws.iwan._power_integral`)."""
    span = math.log(x2 / x1)
    if q == 0.0:
        return span
    return math.exp(q * math.log(x1)) * math.expm1(q * span) / q


@njit(cache=True, error_model="numpy")
def _incomplete(a, x, complete):
    """``B(x; a, 3/2) = int_0^x t^(a-1) (1 - t)^(1/2) dt`` for ``a > 0``, ``0 < x <= 1``; ``complete`` is
    ``Beta(a, 3/2)``. Below :data:`_SERIES_X` the series ``x^a sum_k (-1/2)_k / k! x^k / (a + k)``."""
    if x >= 1.0:
        return complete
    if x > _SERIES_X:
        return betainc(a, 1.5, x) * complete
    total, coef, xk = 0.0, 1.0, 1.0
    for k in range(_SERIES_TERMS):
        term = coef * xk / (a + k)
        total += term
        if abs(term) <= 1e-17 * abs(total):
            break
        coef *= (k - 0.5) / (k + 1.0)
        xk *= x
    return math.exp(a * math.log(x)) * total


@njit(cache=True, error_model="numpy")
def _slip_integral(x1, x2, p, complete):
    """``int_x1^x2 x^(p-1) (1 - J(x)) dx`` as ``(Re, Im)`` (:func:`sbcal.model.laws.iwan._slip_integral`
    away from ``p = 0``); ``complete`` is ``Beta(p + 3/2, 3/2)``."""
    a = p + 1.5
    g2, _ = _jenkins(x2)
    g1, _ = _jenkins(x1)
    upper = (math.exp(p * math.log(x2)) * (1.0 - g2) + 8.0 * _incomplete(a, x2, complete) / math.pi) / p
    lower = (math.exp(p * math.log(x1)) * (1.0 - g1) + 8.0 * _incomplete(a, x1, complete) / math.pi) / p
    im = -(4.0 / math.pi) * (_power_integral(x1, x2, p + 1.0) - _power_integral(x1, x2, p + 2.0))
    return upper - lower, im


@njit(cache=True, error_model="numpy", inline="always")
def _slip_point(x1, x2, p, p_zero, ends, last_a, complete):
    """:func:`_slip_integral` at one point, interpolated across ``|p| < p_zero`` (as the numpy formulation)
    between the band's ends, whose ``Beta(+-p_zero + 3/2, 3/2)`` are ``ends``; ``last_a`` and ``complete``:
    the last ``a = p + 3/2`` and its ``Beta(a, 3/2)`` (the table's points share their set's exponent).
    Returns ``(Re, Im, last_a, complete)``: the memo passed on in registers."""
    if abs(p) < p_zero:
        lo_re, lo_im = _slip_integral(x1, x2, -p_zero, ends[0])
        hi_re, hi_im = _slip_integral(x1, x2, p_zero, ends[1])
        t = (p + p_zero) / (2.0 * p_zero)
        return lo_re + t * (hi_re - lo_re), lo_im + t * (hi_im - lo_im), last_a, complete
    if p + 1.5 != last_a:
        last_a, complete = p + 1.5, beta(p + 1.5, 1.5)
    re, im = _slip_integral(x1, x2, p, complete)
    return re, im, last_a, complete


@njit(cache=True, error_model="numpy")
def iwan5_rigidity(chi, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio, p_zero):
    """``EJ_slip*`` of :class:`sbcal.model.laws.iwan.Iwan5Law` at curvature amplitudes ``chi`` (n,) >= 0,
    each parameter (n,) in the law's domain; ``p_zero``: within this of ``p = c + 1 = 0`` the value is
    interpolated between ``p = +-p_zero`` (as the numpy formulation). Returns complex (n,)."""
    n = chi.size
    out = np.empty(n, dtype=np.complex128)
    ends = (beta(1.5 - p_zero, 1.5), beta(1.5 + p_zero, 1.5))
    last_a, complete = np.nan, np.nan
    for i in range(n):
        dej, lo, hi, beta_ratio = delta_EJ[i], chi_micro[i], chi_macro[i], macro_ratio[i]
        k_cont = dej / (1.0 + beta_ratio)
        if not chi[i] > lo:  # every wire sticks
            out[i] = complex(dej, 0.0)
            continue
        x_lo, x_hi = lo / chi[i], hi / chi[i]
        p = density_exponent[i] + 1.0
        s_re, s_im, last_a, complete = _slip_point(x_lo, min(x_hi, 1.0), p, p_zero, ends, last_a, complete)
        norm = _power_integral(x_lo, x_hi, p)
        j_re, j_im = _jenkins(x_hi)
        out[i] = complex(k_cont * (1.0 - s_re / norm) + (dej - k_cont) * j_re,
                         k_cont * (-s_im / norm) + (dej - k_cont) * j_im)
    return out


@njit(cache=True, error_model="numpy")
def slip_integral(x1, x2, p, p_zero):
    """:func:`sbcal.model.laws.iwan._slip_integral` elementwise: ``int_x1^x2 x^(p-1) (1 - J(x)) dx`` for
    ``0 < x1 <= x2 <= 1``, ``p > -3/2`` (each (n,)), interpolated across ``|p| < p_zero``. Complex (n,)."""
    n = x1.size
    out = np.empty(n, dtype=np.complex128)
    ends = (beta(1.5 - p_zero, 1.5), beta(1.5 + p_zero, 1.5))
    last_a, complete = np.nan, np.nan
    for i in range(n):
        re, im, last_a, complete = _slip_point(x1[i], x2[i], p[i], p_zero, ends, last_a, complete)
        out[i] = complex(re, im)
    return out
