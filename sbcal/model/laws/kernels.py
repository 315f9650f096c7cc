"""The laws' periodic operators compiled (numba): the per-sample loops of
:meth:`sbcal.model.laws.base.HysteresisLaw.periodic_moment`.

- **Bouc-Wen** (and Dahl, ``n = 1``): :func:`bw_periodic` runs, per curvature path, the whole
  evaluation in one fused loop: the turning state of the outer loop (the start), Newton on the period
  map (each sweep steps the state sample by sample along the arc), and the final sweep with the
  derivatives carried forward and the periodic state's own motion added. The arc ``A(eta)`` is Gauss's
  hypergeometric function (scipy's own ``hyp2f1``, called through its Cython export: the same values
  as ``scipy.special.hyp2f1``), its logarithmic end taken apart as in :func:`sbcal.model.laws.bouc_wen._bw_arc`;
  the inverse arc is the per-exponent cubic Hermite table (:func:`sbcal.model.laws.bouc_wen._bw_inverse_table`),
  or Newton on the arc where the exponents are too many for tables.
- **Masing laws** (the Iwan laws): the memory of reversal points is a per-sample loop over a stack
  (:func:`masing_reversals`) that depends on the curvature path only; the backbone is then evaluated
  once over all samples (numpy, the law's own), and :func:`masing_accumulate` runs the recurrence
  ``M = M_r + 2 B((chi - chi_r) / 2)`` and its derivatives.

The arithmetic is that of the numpy formulation they replaced, step for step (``tests/law_reference.py``
keeps it; ``tests/test_law_kernels.py`` holds the two to 1e-10), except that every path's Newton stops
on its own (the numpy one ran until all rows had converged) and the turning state's Newton runs in
``-ln(1 - eta_a)`` (in ``eta_a`` it took ~50 steps, mostly bisection, towards saturation). Compiled on
first use (~3 s) and cached on disk (numba's ``cache=True``; loaded in ~0.15 s).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .scipy_c import hyp2f1


__all__ = ["bw_turning", "bw_periodic", "masing_reversals", "masing_accumulate"]

_BW_NEAR = 0.9  # as sbcal.model.laws.bouc_wen._BW_NEAR
_END_X, _END_W = np.polynomial.legendre.leggauss(20)  # as sbcal.model.laws.bouc_wen._BW_END_NODES
_ONE_BELOW = 1.0 - 2.0**-53
_EULER = float(np.euler_gamma)
_U_TOP = 40.0  # -ln(1 - eta) beyond the doubles below 1
_NEWTON_PERIOD = 8  # Newton steps on the period map (as the numpy formulation)
_PERIOD_TOL = 1e-13


# --- Bouc-Wen -----------------------------------------------------------------------------------

@njit(cache=True)
def _arc(eta, n, sign, psi):
    """``int_0^eta dz / (1 + sign z^n)`` (:func:`sbcal.model.laws.bouc_wen._bw_arc`), scalar; ``psi`` is
    ``digamma(1 / n)`` (in the logarithmic end's constant)."""
    eta = min(eta, _ONE_BELOW)
    y = eta**n
    if sign < 0 and y > _BW_NEAR:
        c = 1.0 / n - 1.0
        tail = 0.0
        for i in range(_END_X.size):
            t = y + (1.0 - y) * 0.5 * (_END_X[i] + 1.0)
            g = math.expm1(c * math.log(t)) / max(1.0 - t, 1e-300) if t < 1.0 else -c
            tail += g * _END_W[i]
        tail = 0.5 * (1.0 - y) * tail
        log_gap = -math.log(-math.expm1(n * math.log(eta)))
        return (log_gap - psi - _EULER - tail) / n
    return eta * hyp2f1(1.0, 1.0 / n, 1.0 + 1.0 / n, -sign * y)


@njit(cache=True)
def _signed_arc(eta, n, psi):
    """Arc from 0 to ``eta`` in either sign while unloading (:func:`sbcal.model.laws.bouc_wen._bw_signed_arc`)."""
    if eta >= 0:
        return _arc(abs(eta), n, 1.0, psi)
    return -_arc(abs(eta), n, -1.0, psi)


@njit(cache=True)
def _arc_inverse(y, n, sign, psi):
    """``eta`` with ``_arc(eta, n, sign) = y >= 0`` (:func:`sbcal.model.laws.bouc_wen._bw_arc_inverse`)."""
    lo, hi = 0.0, (1.0 if sign > 0 else 60.0)
    x = min(y, 0.5 * hi) if sign > 0 else math.log1p(y)
    for _ in range(100):
        eta = x if sign > 0 else -math.expm1(-x)
        g = _arc(eta, n, sign, psi) - y
        if g == 0:  # a root exactly (the numpy formulation bisected away from it)
            break
        if g < 0:
            lo = x
        else:
            hi = x
        if sign > 0:
            slope = 1.0 / (1.0 + eta**n)
        else:
            d = -math.expm1(n * math.log(max(eta, 1e-300)))
            slope = math.exp(-x) / max(d, 1e-300) if d > 0 else 1.0 / n
        new = x - g / slope
        if not (new > lo and new < hi):
            new = 0.5 * (lo + hi)
        done = abs(new - x) <= 1e-15 * max(1.0, abs(x))
        x = new
        if done:
            break
    return x if sign > 0 else -math.expm1(-x)


@njit(cache=True)
def _inverse(v, n, psi, table, yk, ek, dk, hint):
    """``eta`` with ``_signed_arc(eta) = v``: the cubic Hermite table ``table`` (row of ``yk``, ``ek``,
    ``dk``; :func:`sbcal.model.laws.bouc_wen._bw_table_inverse`), or Newton on the arc where ``table < 0``.

    The node is found from ``hint`` (the last one found: a path's next sample lies a few nodes
    away) by galloping, then bisection: ``np.searchsorted``'s (left) answer. Returns ``eta`` and the hint.
    """
    if table < 0:
        if v >= 0:
            return _arc_inverse(max(v, 0.0), n, 1.0, psi), hint
        return -_arc_inverse(max(-v, 0.0), n, -1.0, psi), hint
    y, e, d = yk[table], ek[table], dk[table]
    size = y.size
    if v > y[size - 1]:
        return e[size - 1], hint
    if v < y[0]:  # saturated: the falling end approaches -1 as exp(n y)
        return -1.0 + (1.0 + e[0]) * math.exp(n * min(v - y[0], 0.0)), hint
    # the first node i with y[i] >= v (np.searchsorted, left): bracket [lo, hi] from the hint, then bisect
    lo, hi = 0, size
    h0 = min(max(hint, 0), size - 1)
    step = 1
    if y[h0] < v:
        lo = h0 + 1
        while h0 + step < size:
            if y[h0 + step] >= v:
                hi = h0 + step
                break
            lo = h0 + step + 1
            step *= 2
    else:
        hi = h0
        while h0 - step >= 0:
            if y[h0 - step] < v:
                lo = h0 - step + 1
                break
            hi = h0 - step
            step *= 2
    while lo < hi:
        mid = (lo + hi) >> 1
        if y[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    j = min(max(lo - 1, 0), size - 2)
    h = y[j + 1] - y[j]
    if not h > 0:
        h = 1.0  # nodes that round to one arc length at the saturated ends
    t = min(max((v - y[j]) / h, 0.0), 1.0)
    t2, t3 = t * t, t * t * t
    return ((2 * t3 - 3 * t2 + 1) * e[j] + (t3 - 2 * t2 + t) * h * d[j]
            + (-2 * t3 + 3 * t2) * e[j + 1] + (t3 - t2) * h * d[j + 1]), lo


@njit(cache=True)
def _slope(e, n):
    """``d eta / dy = 1 + |eta|^(n-1) eta`` on the falling arc (``1 / A'``)."""
    if e > 0:
        return 1.0 + abs(e) ** n
    if e < 0:
        return 1.0 - abs(e) ** n
    return 1.0


@njit(cache=True)
def _turning(a, n, psi):
    """``eta_a`` with ``A+(eta_a) + A-(eta_a) = 2 a`` (:func:`sbcal.model.laws.bouc_wen._bw_turning`).

    Bisection-safeguarded Newton in ``u = -ln(1 - eta_a)``, where the sum grows like ``u / n`` towards
    saturation (in ``eta_a`` Newton overshoots there and the bisection takes ~50 steps); 1 where the
    arc to the largest double below 1 is still short of ``2 a`` (as the numpy formulation gives).
    """
    if _arc(_ONE_BELOW, n, 1.0, psi) + _arc(_ONE_BELOW, n, -1.0, psi) < 2.0 * a:
        return 1.0
    lo, hi = 0.0, _U_TOP
    u = -math.log1p(-min(a, 0.5))
    for _ in range(200):
        eta = -math.expm1(-u)
        g = _arc(eta, n, 1.0, psi) + _arc(eta, n, -1.0, psi) - 2.0 * a
        if g == 0:
            return eta
        if g < 0:
            lo = u
        else:
            hi = u
        # d/du = (1 - eta) (1 / (1 + eta^n) + 1 / (1 - eta^n)); (1 - eta) / (1 - eta^n) -> 1 / n at 1
        gap = -math.expm1(n * math.log(max(eta, 1e-300)))
        rise = 1.0 / n if not gap > 0 else math.exp(-u) / gap
        new = u - g / (math.exp(-u) / (1.0 + eta**n) + rise)
        if not (new > lo and new < hi):
            new = 0.5 * (lo + hi)
        done = abs(new - u) <= 1e-15 * u
        u = new
        if done:
            break
    return -math.expm1(-u)


@njit(cache=True)
def bw_turning(a, n, psi):
    """``eta_a`` of the steady loops at amplitudes ``a`` (in units of ``chi_slip``), exponents ``n`` and
    ``psi = digamma(1 / n)``, 1-D arrays alike (:func:`sbcal.model.laws.bouc_wen._bw_turning`)."""
    out = np.empty(a.size)
    for i in range(a.size):
        out[i] = _turning(a[i], n[i], psi[i])
    return out


@njit(cache=True)
def _sweep(eta0, steps, nt, n, psi, table, yk, ek, dk):
    """One period of the state from ``eta0`` at the largest sample, not tracked: ``(eta_end, d eta_end / d eta0)``."""
    eta, deriv, mode, hint = eta0, 1.0, 1.0, 0
    y = _signed_arc(eta0, n, psi)
    below = _slope(eta0, n)
    for j in range(nt):
        d = steps[j]
        s = -1.0 if d > 0 else (1.0 if d < 0 else mode)
        if s != mode:  # the direction turns: the state's arc coordinate in the new direction
            y = _signed_arc(s * eta, n, psi)
            below = _slope(s * eta, n)
            mode = s
        y += s * d
        e, hint = _inverse(y, n, psi, table, yk, ek, dk, hint)
        above = _slope(e, n)
        deriv *= above / below if below > 0 else 0.0  # saturated: 0
        eta, below = s * e, above
    return eta, deriv


@njit(cache=True)
def bw_periodic(chi, dirs, chi_slip, n, psi, table, yk, ek, dk):
    """Bouc-Wen over one period of each row of ``chi`` (m, n_t), steady; with derivatives along ``dirs``
    (m, n_t, k).

    ``chi_slip``, ``n``, ``psi`` (``digamma(1 / n)``) and ``table`` (the row of the inverse
    tables ``yk``, ``ek``, ``dk`` (T, N); -1: Newton on the arc) per row. Returns ``eta`` (m, n_t) and
    its derivatives (m, n_t, k); the moment is ``delta_EJ chi_slip eta``. The method is
    :func:`sbcal.model.laws.bouc_wen._bw_periodic`'s: the state stepped exactly along the arc between samples
    (its arc coordinate kept in the current direction, converted where the direction turns), the
    periodic state by Newton on the period map from the outer loop's turning state, and the
    derivatives carried forward at a fixed start, then the fixed point's own motion added.
    """
    m, nt = chi.shape
    k = dirs.shape[2]
    out = np.empty((m, nt))
    dout = np.empty((m, nt, k))
    path = np.empty(nt + 1)
    dpath = np.empty((nt + 1, k))
    steps = np.empty(nt)
    dsteps = np.empty((nt, k))
    order = np.empty(nt + 1, dtype=np.int64)
    eta_t = np.empty(nt)
    deta_t = np.empty((nt, k))
    dstart = np.empty(nt)
    dy = np.empty(k)
    deta = np.empty(k)
    for r in range(m):
        cs, nn, en, tb = chi_slip[r], n[r], psi[r], table[r]
        start = 0
        for j in range(1, nt):
            if chi[r, j] > chi[r, start]:
                start = j
        low = np.inf
        for j in range(nt + 1):
            o = (start + j) % nt
            order[j] = o
            path[j] = chi[r, o] / cs
            low = min(low, path[j])
            for i in range(k):
                dpath[j, i] = dirs[r, o, i] / cs
        for j in range(nt):
            steps[j] = path[j + 1] - path[j]
            for i in range(k):
                dsteps[j, i] = dpath[j + 1, i] - dpath[j, i]
        eta0 = _turning(0.5 * (path[0] - low), nn, en)
        for _ in range(_NEWTON_PERIOD):  # Newton on the period map (a contraction)
            eta_end, deriv = _sweep(eta0, steps, nt, nn, en, tb, yk, ek, dk)
            gap = eta_end - eta0
            if abs(gap) <= _PERIOD_TOL:
                break
            eta0 = min(max(eta0 - gap / (deriv - 1.0 if deriv < 1.0 else -1.0), -1.0), 1.0)
        # the tracked sweep from the periodic state
        eta, deriv, mode, hint = eta0, 1.0, 1.0, 0
        y = _signed_arc(eta0, nn, en)
        below = _slope(eta0, nn)
        dy[:] = 0.0
        deta[:] = 0.0
        for j in range(nt):
            d = steps[j]
            s = -1.0 if d > 0 else (1.0 if d < 0 else mode)
            if s != mode:
                y = _signed_arc(s * eta, nn, en)
                below = _slope(s * eta, nn)
                q = s / below
                for i in range(k):
                    dy[i] = q * deta[i]
                mode = s
            y += s * d
            e, hint = _inverse(y, nn, en, tb, yk, ek, dk, hint)
            above = _slope(e, nn)
            deriv *= above / below if below > 0 else 0.0
            eta, below = s * e, above
            eta_t[j] = eta
            sa = s * above
            for i in range(k):
                dy[i] += s * dsteps[j, i]
                deta[i] = sa * dy[i]
                deta_t[j, i] = deta[i]
            dstart[j] = deriv
        # the periodic start moves with the path: d eta0 = d eta_end (fixed start) / (1 - d eta_end / d eta0)
        denom = 1.0 - deriv if deriv < 1.0 else 1.0
        for j in range(nt):
            o = order[j + 1]
            out[r, o] = eta_t[j]
            for i in range(k):
                dout[r, o, i] = deta_t[j, i] + dstart[j] * (deta_t[nt - 1, i] / denom)
    return out, dout


# --- Masing laws --------------------------------------------------------------------------------

_MASING_DEPTH = 8  # reversal points kept (as the numpy formulation)


@njit(cache=True)
def masing_reversals(path):
    """The reversal point each sample's branch runs from, per row of ``path`` (n, n_t + 1): the curvature
    from its largest sample round to it again.

    Madelung's memory: reversal points on a stack, the outer loop's two at its bottom (the path's
    least curvature, coded -1, and its start, index 0); a sample where the direction turns pushes the
    one before it; once the curvature passes the reversal before the last, the inner loop has closed and
    both are dropped. Returns the path index of each sample's reversal (n, n_t + 1; column 0 unused).
    """
    n, nt1 = path.shape
    ref = np.zeros((n, nt1), dtype=np.int64)
    stack_k = np.empty(_MASING_DEPTH)
    stack_i = np.empty(_MASING_DEPTH, dtype=np.int64)
    for r in range(n):
        bottom = path[r, 0]
        for j in range(1, nt1 - 1):
            bottom = min(bottom, path[r, j])
        stack_k[0], stack_i[0] = bottom, -1
        stack_k[1], stack_i[1] = path[r, 0], 0
        level = 1
        going_up = False
        prev = path[r, 0]
        for j in range(1, nt1):
            x = path[r, j]
            up = x > prev
            if up != going_up and x != prev and j > 1 and level < _MASING_DEPTH - 1:  # a reversal: push it
                level += 1
                stack_k[level], stack_i[level] = prev, j - 1
            if x != prev:
                going_up = up
            while level >= 2 and (x >= stack_k[level - 1] if going_up else x <= stack_k[level - 1]):
                level -= 2  # the inner loop has closed
            ref[r, j] = stack_i[level]
            prev = x
    return ref


@njit(cache=True)
def masing_accumulate(ref, order, branch, slope, m_top, dm_top, dpath, dlow):
    """The moments along each path from its reversals (:func:`masing_reversals`): ``M_j = M_r + branch_j``
    and ``dM_j = dM_r + slope_j (d chi_j - d chi_r)``, the reversal ``r = ref[j]`` (-1: the path's least
    curvature, moment ``-m_top``; 0: its start, ``m_top``). ``branch``, ``slope`` (n, n_t + 1) are
    ``2 B((chi - chi_r) / 2)`` and ``B'(|chi - chi_r| / 2)``; ``dpath`` (n, n_t + 1, k) the path's
    derivatives, ``dlow`` (n, k) those of its least curvature. Returns the moments at the samples in
    their own order (``order``: the path's sample indices), (n, n_t) and (n, n_t, k).
    """
    n, nt1 = ref.shape
    nt = nt1 - 1
    k = dpath.shape[2]
    m_out = np.empty((n, nt))
    dm_out = np.empty((n, nt, k))
    m = np.empty(nt1)
    dm = np.empty((nt1, k))
    for r in range(n):
        m[0] = m_top[r]
        for i in range(k):
            dm[0, i] = dm_top[r, i]
        for j in range(1, nt1):
            q = ref[r, j]
            if q < 0:
                m[j] = -m_top[r] + branch[r, j]
                for i in range(k):
                    dm[j, i] = -dm_top[r, i] + slope[r, j] * (dpath[r, j, i] - dlow[r, i])
            else:
                m[j] = m[q] + branch[r, j]
                for i in range(k):
                    dm[j, i] = dm[q, i] + slope[r, j] * (dpath[r, j, i] - dpath[r, q, i])
            o = order[r, j]
            m_out[r, o] = m[j]
            for i in range(k):
                dm_out[r, o, i] = dm[j, i]
    return m_out, dm_out
