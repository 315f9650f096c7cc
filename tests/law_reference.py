"""The laws' periodic operators in numpy: the reference the compiled ones are tested against.

:func:`bw_periodic_reference` and :func:`masing_periodic_reference` are the numpy formulation of
:meth:`sbcal.model.laws.base.HysteresisLaw.periodic_moment` (Bouc-Wen's state stepped along the arc and
its period map solved by Newton; Masing's rule with Madelung's memory), every row stepped together
sample by sample, and :func:`bw_turning_reference` Bouc-Wen's turning state (every loop's Newton
together), before the compiled kernels (:mod:`sbcal.model.laws.kernels`) replaced them;
:func:`iwan5_rigidity_reference` the five-parameter Iwan law's describing function and
:func:`slip_integral_reference` the Iwan laws' slip integral before :mod:`sbcal.model.laws.iwan_kernel`.
:func:`reference_law` is a law on these (the whole harmonic balance on the reference):
``tests/test_law_kernels.py`` holds the two to 1e-10, ``benchmarks/harmonic_balance.py`` times them
side by side.

Where they differ: the numpy Newtons (the period map's, the turning state's) stop when every row has
converged, so a row's last digits depend on the rows beside it; the compiled ones stop per row.
"""

from __future__ import annotations

from dataclasses import replace
from unittest import mock

import numpy as np
from scipy import special

from sbcal.model.laws.base import jenkins_rigidity
from sbcal.model.laws.bouc_wen import BoucWenLaw, DahlLaw, _bw_arc, _bw_signed_arc, _bw_signed_inverse
from sbcal.model.laws import iwan
from sbcal.model.laws.iwan import _P_ZERO as P_ZERO
from sbcal.model.laws.iwan import Iwan5Law, IwanTailLaw, _power_integral
from sbcal.model.laws.zones import ZonedLaw


__all__ = ["bw_turning_reference", "bw_periodic_reference", "masing_periodic_reference", "reference_law",
           "iwan5_rigidity_reference", "slip_integral_reference"]


def reference_law(law):
    """``law`` (an instance) with its periodic operator, Bouc-Wen's steady-loop branch and the five-parameter
    Iwan law's describing function on the numpy reference (a subclass: same name and parameters; a zoned
    law's base law so)."""
    if isinstance(law, ZonedLaw):
        return replace(law, base=reference_law(law.base))
    base = type(law)

    def _periodic(self, chi, dirs, **p):
        if isinstance(self, DahlLaw):
            return bw_periodic_reference(chi, dirs, p["delta_EJ"], p["chi_dahl"], np.ones_like(p["chi_dahl"]))
        if isinstance(self, BoucWenLaw):
            return bw_periodic_reference(chi, dirs, p["delta_EJ"], p["chi_slip"], p["sharpness"])
        return masing_periodic_reference(lambda x: self.backbone(x[:, None], **p)[:, 0], chi, dirs)

    body = {"_periodic": _periodic, "__module__": __name__}
    if isinstance(law, BoucWenLaw):
        body["_branch"] = _bw_branch_reference
    if isinstance(law, Iwan5Law):
        body["_rigidity"] = lambda self, chi, **p: iwan5_rigidity_reference(chi, **p)
    if isinstance(law, IwanTailLaw):
        body["_rigidity"] = _tail_rigidity_reference
    return type("Reference" + base.__name__, (base,), body)()


def _tail_rigidity_reference(self, chi, **p):
    """:meth:`sbcal.model.laws.iwan.IwanTailLaw._rigidity` on the numpy slip integral."""
    with mock.patch.object(iwan, "_slip_integral", slip_integral_reference):
        return IwanTailLaw._rigidity(self, chi, **p)


def _bw_branch_reference(self, chi, chi_a, *, delta_EJ, chi_slip, sharpness):
    """:meth:`sbcal.model.laws.bouc_wen.BoucWenLaw._branch` on :func:`bw_turning_reference`."""
    eta_a = bw_turning_reference(chi_a / chi_slip, sharpness)
    y = _bw_arc(eta_a, sharpness, 1.0) - (chi_a - chi) / chi_slip
    n = np.broadcast_to(sharpness, y.shape)
    eta = _bw_signed_inverse(y, n)
    slope = 1.0 + np.sign(eta) * np.abs(eta) ** n
    return delta_EJ * chi_slip * eta, delta_EJ * slope, -delta_EJ * slope * eta_a**n


def bw_turning_reference(a, n):
    """``eta_a`` of the steady loop at amplitude ``a``: ``A+(eta_a) + A-(eta_a) = 2 a``
    (``sbcal.model.laws.bouc_wen._bw_turning``), every loop's Newton in ``eta_a`` together."""
    a, n = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(n, dtype=float))
    lo, hi = np.zeros(a.shape), np.ones(a.shape)
    eta_a = np.minimum(a, 0.5)
    for _ in range(200):  # bisection-safeguarded Newton on eta_a in (0, 1)
        e_n = eta_a**n
        g = _bw_arc(eta_a, n, 1.0) + _bw_arc(eta_a, n, -1.0) - 2.0 * a
        lo, hi = np.where(g < 0, eta_a, lo), np.where(g >= 0, eta_a, hi)
        new = eta_a - g / (1.0 / (1.0 + e_n) + 1.0 / np.maximum(1.0 - e_n, 1e-300))
        new = np.where((new > lo) & (new < hi), new, 0.5 * (lo + hi))
        done = np.abs(new - eta_a) <= 1e-16
        eta_a = new
        if done.all():
            break
    return eta_a


def bw_periodic_reference(chi, dirs, delta_EJ, chi_slip, n):
    """Bouc-Wen (and Dahl, ``n = 1``) over one period of any periodic curvature ``chi`` (m, n_t), steady;
    with derivatives along ``dirs`` (m, n_t, k) (:meth:`HysteresisLaw.periodic_moment`).

    Each step between samples is monotone, so the arc advances exactly: falling, ``A(eta') = A(eta) -
    |d chi| / chi_slip``; rising, the same for ``-eta`` (:func:`_bw_signed_arc`); the state is kept as
    its arc coordinate and converted only where the direction turns. The periodic state at the largest
    sample is the fixed point of the period map, by Newton from the outer loop's state
    (:func:`_bw_branch_eta`) with the map's exact derivative ``prod A'(eta) / A'(eta')``. Derivatives
    ride along at a fixed start, then the fixed point's own motion is added.
    """
    m, nt = chi.shape
    rows = np.arange(m)
    start = np.argmax(chi, axis=1)
    order = (start[:, None] + np.arange(nt + 1)[None, :]) % nt
    path = chi[rows[:, None], order] / chi_slip
    dsteps = np.diff(dirs[rows[:, None], order] / chi_slip[..., None], axis=1)
    n = np.broadcast_to(n, (m, 1))[:, 0]
    steps = np.diff(path, axis=1)
    eta0 = bw_turning_reference(0.5 * (path[:, 0] - path.min(axis=1)), n)

    def slope(e, nn=n):  # d eta / dy on the falling arc (1 / A')
        return 1.0 + np.sign(e) * np.abs(e) ** nn

    def sweep(e0, track=False):
        # the state as its arc coordinate y in the current direction s (falling +1: eta = A^-1(y);
        # rising -1: -eta follows the falling arc), converted only where the direction turns
        eta, deriv, out = e0.copy(), np.ones(m), np.empty((m, nt))
        mode, y = np.ones(m), _bw_signed_arc(e0, n)
        k = dsteps.shape[2]
        dy, deta = np.zeros((m, k)), np.zeros((m, k))
        dout, dstart = (np.empty((m, nt, k)), np.empty((m, nt))) if track else (None, None)
        for j in range(nt):
            d = steps[:, j]
            s = np.where(d > 0, -1.0, np.where(d < 0, 1.0, mode))
            turn = s != mode
            if turn.any():
                y[turn] = _bw_signed_arc(s[turn] * eta[turn], n[turn])
                if track:
                    dy[turn] = (s[turn] / slope(s[turn] * eta[turn], n[turn]))[:, None] * deta[turn]
                mode = s
            y += s * d
            new = s * _bw_signed_inverse(y, n)
            below, above = slope(s * eta), slope(s * new)
            deriv *= np.divide(above, below, out=np.zeros(m), where=below > 0)  # saturated: 0
            eta = new
            out[:, j] = eta
            if track:
                dy += s[:, None] * dsteps[:, j]
                deta = (s * above)[:, None] * dy
                dout[:, j], dstart[:, j] = deta, deriv
        return out, deriv, dout, dstart

    for _ in range(8):  # Newton on the period map (a contraction): quadratic from the outer loop's state
        out, deriv, _, _ = sweep(eta0)
        gap = out[:, -1] - eta0
        if np.all(np.abs(gap) <= 1e-13):
            break
        eta0 = np.clip(eta0 - gap / np.where(deriv < 1.0, deriv - 1.0, -1.0), -1.0, 1.0)
    out, deriv, dout, dstart = sweep(eta0, track=True)
    # the periodic start moves with the path: d eta0 = d eta_end (at fixed start) / (1 - d eta_end / d eta0)
    move = dout[:, -1] / np.where(deriv < 1.0, 1.0 - deriv, 1.0)[:, None]
    dout = dout + dstart[..., None] * move[:, None, :]
    back = np.empty_like(order[:, 1:])
    back[rows[:, None], order[:, 1:]] = np.arange(nt)[None, :]
    scale = delta_EJ * chi_slip
    return (scale * out)[rows[:, None], back], (scale[..., None] * dout)[rows[:, None], back]


def masing_periodic_reference(backbone, chi, dirs):
    """:meth:`HysteresisLaw.periodic_moment` of a Masing law (parallel Jenkins elements obey it exactly).

    The steady state starts at the period's largest curvature on the outer loop it spans with the
    smallest. Reversal points are kept on a stack; each branch runs ``M = M_r + 2 B((chi - chi_r) / 2)``
    (odd ``B``) from the last reversal ``r``; once the curvature passes the reversal before it, the
    inner loop has closed and both points are dropped (Madelung's rule: the path rejoins the branch it
    left). Derivatives ride along: ``dM = dM_r + B'(u) (d chi - d chi_r)`` (``B'`` by a forward
    difference).
    """
    n, nt = chi.shape
    rows = np.arange(n)
    start = np.argmax(chi, axis=1)
    low = np.argmin(chi, axis=1)
    order = (start[:, None] + np.arange(nt + 1)[None, :]) % nt
    path = chi[rows[:, None], order]  # from the largest sample round to it again
    dpath = dirs[rows[:, None], order]
    top, bottom = path[:, 0], chi[rows, low]
    h = 1e-7 * (top - bottom) + 1e-300

    def odd(x):
        return np.sign(x) * backbone(np.abs(x))

    def slope(x):
        return (backbone(x + h) - backbone(x)) / h

    # the outer loop of an odd periodic curvature: M(top) = B(half range)
    half = 0.5 * (top - bottom)
    m_top = backbone(half)
    dm_top = slope(half)[:, None] * 0.5 * (dpath[:, 0] - dirs[rows, low])
    depth = 8
    sk, sm = np.zeros((n, depth)), np.zeros((n, depth))
    dsk, dsm = np.zeros((n, depth) + dirs.shape[2:]), np.zeros((n, depth) + dirs.shape[2:])
    sk[:, 0], sm[:, 0], dsk[:, 0], dsm[:, 0] = bottom, -m_top, dirs[rows, low], -dm_top
    sk[:, 1], sm[:, 1], dsk[:, 1], dsm[:, 1] = top, m_top, dpath[:, 0], dm_top
    level = np.ones(n, dtype=int)
    m_out, dm_out = np.empty((n, nt)), np.empty((n, nt) + dirs.shape[2:])
    going_up = np.zeros(n, dtype=bool)
    prev_k, prev_m, prev_dk, prev_dm = top.copy(), m_top.copy(), dpath[:, 0], dm_top
    for j in range(1, nt + 1):
        x, dx = path[:, j], dpath[:, j]
        up = x > prev_k
        turn = (up != going_up) & (x != prev_k) & (j > 1)
        if turn.any():  # the previous sample was a reversal: push it
            g = turn & (level < depth - 1)
            level = np.where(g, level + 1, level)
            sk[rows[g], level[g]], sm[rows[g], level[g]] = prev_k[g], prev_m[g]
            dsk[rows[g], level[g]], dsm[rows[g], level[g]] = prev_dk[g], prev_dm[g]
        going_up = np.where(x != prev_k, up, going_up)
        for _ in range(depth):  # pass the reversal before the last: the inner loop closes
            closed = (level >= 2) & np.where(going_up, x >= sk[rows, level - 1], x <= sk[rows, level - 1])
            if not closed.any():
                break
            level = np.where(closed, level - 2, level)
        kr, mr, dkr, dmr = sk[rows, level], sm[rows, level], dsk[rows, level], dsm[rows, level]
        u = 0.5 * (x - kr)
        m = mr + 2.0 * odd(u)
        dm = dmr + slope(np.abs(u))[:, None] * (dx - dkr)
        at = order[:, j] if j < nt else order[:, 0]
        m_out[rows, at], dm_out[rows, at] = m, dm
        prev_k, prev_m, prev_dk, prev_dm = x, m, dx, dm
    return m_out, dm_out


def iwan5_rigidity_reference(chi, *, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio):
    """:class:`sbcal.model.laws.iwan.Iwan5Law`'s describing function in numpy (whole-array passes, scipy's
    ``betainc`` at both ends of the slip integral): the formulation before :mod:`sbcal.model.laws.iwan_kernel`."""
    shape = np.broadcast_shapes(np.shape(chi), np.shape(delta_EJ), np.shape(chi_micro), np.shape(chi_macro),
                                np.shape(density_exponent), np.shape(macro_ratio))
    chi, dej, lo, hi, c, beta = (np.broadcast_to(np.asarray(v, dtype=float), shape)
                                 for v in (chi, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio))
    k_cont = dej / (1.0 + beta)
    out = np.array(dej, dtype=complex)  # stuck below chi_micro
    m = chi > lo
    if m.any():
        x_lo, x_hi, p, km = lo[m] / chi[m], hi[m] / chi[m], c[m] + 1.0, k_cont[m]
        slipping = slip_integral_reference(x_lo, np.minimum(x_hi, 1.0), p)
        cont = 1.0 - slipping / _power_integral(x_lo, x_hi, p)
        out[m] = km * cont + (dej[m] - km) * jenkins_rigidity(x_hi)
    return out


def slip_integral_reference(x1, x2, p):
    """The numpy formulation of :func:`sbcal.model.laws.iwan._slip_integral` (before
    :mod:`sbcal.model.laws.iwan_kernel`): ``int_x1^x2 x^(p-1) (1 - J(x)) dx`` for ``0 < x1 <= x2 <= 1`` and
    ``p > -3/2`` (J: Jenkins).

    Real part by parts (``1 - g`` vanishes at 1, ``g' = 8 sqrt(x (1 - x)) / pi``)::

        [x^p (1 - g(x)) / p + 8 B(x; p + 3/2, 3/2) / (pi p)]_x1^x2

    with ``B`` the incomplete beta integral; imaginary part ``-(4 / pi) int x^p (1 - x) dx``.
    The two real terms are ~1/p each: for ``|p| < P_ZERO`` (a log-uniform density) the value is
    the linear interpolation between ``p = +-P_ZERO``: its error ~P_ZERO^2 (ln x1)^2 and the
    rounding ~eps / P_ZERO are both ~1e-10 of the integral.
    """
    near = np.abs(p) < P_ZERO
    if near.any():
        lo = slip_integral_reference(x1, x2, np.where(near, -P_ZERO, p))
        hi = slip_integral_reference(x1, x2, np.where(near, P_ZERO, p))
        t = (np.where(near, p, 0.0) + P_ZERO) / (2 * P_ZERO)
        return np.where(near, lo + t * (hi - lo), hi)

    def primitive(x):
        g = jenkins_rigidity(x).real
        b = special.betainc(p + 1.5, 1.5, x) * special.beta(p + 1.5, 1.5)
        return (np.exp(p * np.log(x)) * (1.0 - g) + 8.0 * b / np.pi) / p

    im = -(4.0 / np.pi) * (_power_integral(x1, x2, p + 1.0) - _power_integral(x1, x2, p + 2.0))
    return primitive(x2) - primitive(x1) + 1j * im
