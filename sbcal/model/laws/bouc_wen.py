"""Dahl's law and Bouc-Wen with a free exponent (a smooth knee; Dahl's family), their first harmonics
tabulated once per process."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import special
from scipy.integrate import solve_ivp
from scipy.interpolate import RectBivariateSpline
from scipy.optimize import brentq

from . import kernels
from .base import DELTA_EJ, HysteresisLaw, LawParameter
from .registry import register
from .steppers import BoucWenStepper, DahlStepper


__all__ = ["DahlLaw", "BoucWenLaw"]

# --- Dahl ---------------------------------------------------------------------------------------

# bench curvatures span ~1e-4 (0.1 mm, off resonance) to ~0.1 (2 mm at a resonance): a decade beyond each end
_SATURATION_BOX = ("loguniform", 1e-5, 1.0)


@register
@dataclass(frozen=True)
class DahlLaw(HysteresisLaw):
    """Dahl's law: Bouc-Wen with ``n = 1``, ``beta = 1``, ``gamma = 0`` (slenderpy's Stockbridge masses).

    ``chi_dahl d(eta)/dt = d(chi)/dt - |d(chi)/dt| eta``, slip moment ``M_slip = delta_EJ chi_dahl eta``.
    With ``a = chi_a / chi_dahl`` the steady loop turns at ``eta_a = tanh a``, and on the unloading
    branch ``eta = -1 + (1 + tanh a) exp((chi - chi_a) / chi_dahl)``. Its Fourier coefficients are
    closed forms (``I1`` the modified Bessel function)::

        Re EJ_slip* = 4 delta_EJ exp(-a) I1(a) / (a (1 + exp(-2 a)))
        Im EJ_slip* = 4 delta_EJ (a - tanh a) / (pi a^2)

    ``W = 4 delta_EJ chi_dahl^2 (a - tanh a)``: ``~ chi_a^3`` in micro-slip (a fixed exponent), linear
    in ``chi_a`` (Coulomb-like, slip moment ``delta_EJ chi_dahl``) in gross slip, where the in-phase
    part falls as ``a^-3/2``.
    """

    name: ClassVar[str] = "dahl"
    parameters: ClassVar[tuple] = (
        DELTA_EJ,
        LawParameter("chi_dahl", "1/m", "Dahl curvature: the slip moment saturates at delta_EJ chi_dahl",
                     prior=_SATURATION_BOX),
    )
    within: ClassVar[str] = "bouc_wen"
    scale: ClassVar[str] = "chi_dahl"

    def time_stepper(self, params, *, resolution=1.0, linear=None):
        return DahlStepper(params["delta_EJ"], params["chi_dahl"])

    def _rigidity(self, chi, *, delta_EJ, chi_dahl):
        a = chi / chi_dahl
        zero = a <= 0
        a_safe = np.where(zero, 1.0, a)
        re = np.where(zero, 1.0, 4 * special.i1e(a_safe) / (a_safe * (1 + np.exp(-2 * a_safe))))
        # a - tanh a loses digits for small a: its series a^3/3 - 2 a^5/15 + 17 a^7/315 below 0.01
        small = a < 1e-2
        a2 = a * a
        series = a * (1 / 3 - a2 * (2 / 15 - a2 * 17 / 315))
        im = np.where(small, series, (a_safe - np.tanh(a_safe)) / a_safe**2) * 4 / np.pi
        return delta_EJ * (re + 1j * im)

    def _branch(self, chi, chi_a, *, delta_EJ, chi_dahl):
        """Closed form: ``eta = -1 + (1 + tanh a) exp(-(chi_a - chi) / chi_dahl)`` (Bouc-Wen, ``n = 1``)."""
        eta_a = np.tanh(chi_a / chi_dahl)
        decay = np.exp(-np.maximum(chi_a - chi, 0.0) / chi_dahl)
        rise = (1.0 + eta_a) * decay  # 1 + eta
        return delta_EJ * chi_dahl * (rise - 1.0), delta_EJ * rise, -delta_EJ * rise * eta_a

    def _periodic(self, chi, dirs, *, delta_EJ, chi_dahl):
        return _bw_periodic(chi, dirs, delta_EJ, chi_dahl, np.ones_like(chi_dahl))

    def steady_loop(self, chi_a, theta, *, delta_EJ, chi_dahl):
        """Time-steps the Dahl ODE, exactly per step (on a monotone step it is linear in eta).

        ``theta`` is an increasing grid over one period from 0 (the turning point ``chi = chi_a``).
        Every step is affine in ``eta``, so the period map is ``eta -> A eta + B``: two passes
        (from 0 and from 1) give A and B, the periodic state ``B / (1 - A)`` starts the returned
        pass (shooting; at small amplitude the transient would need ~1/a periods to die out).
        """
        theta = np.asarray(theta, dtype=float)
        chi = np.append(chi_a * np.cos(theta), chi_a)  # close the period at the turning point

        def run(eta):
            out = np.empty(chi.size)
            prev = chi_a
            for k, c in enumerate(chi):
                d = (c - prev) / chi_dahl
                # chi rising: eta -> 1 - (1 - eta) e^-d ; falling: eta -> -1 + (1 + eta) e^d
                eta = 1 - (1 - eta) * math.exp(-d) if d >= 0 else -1 + (1 + eta) * math.exp(d)
                out[k] = eta
                prev = c
            return out

        b = run(0.0)[-1]
        a = run(1.0)[-1] - b
        return delta_EJ * chi_dahl * run(b / (1 - a))[:-1]


# --- Bouc-Wen with a free exponent (Dahl's family) ------------------------------------------------

_BW_SHARPNESS = (0.3, 5.0)  # the law's range of the exponent n
_BW_TABLE_N = (0.25, 6.0)  # the table's, wider: a spline is least accurate in its end intervals
_BW_XI = (-5.0, 9.2)  # table range of xi (below: micro-slip, corrections ~ a^2n < 5e-5; above: a > 1e4)
_BW_XI_NODES = 201
_BW_PSI_NODES = 36  # nodes in psi = ln n + n / 2: dense at small n, and at large n (the knee sharpens)
_BW_TAIL = 40.0  # the profile is integrated until 1 - |P| ~ exp(-40)
_BW_GAUSS = 48  # Gauss-Legendre nodes per piece of a branch


def _bw_xi(v, n):
    """Table coordinate along ``v = ln a``: ``n v`` in micro-slip (``ln a^n``), ``v`` in gross slip."""
    return n * v + (1.0 - n) * np.logaddexp(0.0, v)


def _bw_v(xi, n):
    """Inverse of :func:`_bw_xi` (Newton; ``d xi / dv`` lies between n and 1)."""
    xi, n = np.broadcast_arrays(np.asarray(xi, dtype=float), np.asarray(n, dtype=float))
    v = np.where(xi < 0, xi / n, xi)
    for _ in range(50):
        step = (_bw_xi(v, n) - xi) / (n + (1.0 - n) * special.expit(v))
        v = v - step
        if np.all(np.abs(step) <= 1e-13 * (1.0 + np.abs(v))):
            break
    return v


def _bw_psi(n):
    """Table coordinate along the exponent."""
    return np.log(n) + 0.5 * n


def _bouc_wen_profile(n: float):
    """The unloading arc from saturation, ``P(s)``: ``dP/ds = -(1 + |P|^(n-1) P)``, ``P(0) = 1``.

    Returns ``(s_c, upper, lower)``: the arc's zero ``s_c`` and dense interpolants (DOP853, rtol
    1e-13) above it (``P >= 0``) and below it, until ``1 - |P| ~ exp(-_BW_TAIL)``. Split at the zero,
    where ``|P|^n`` is not smooth, so each piece is smooth inside.
    """
    zero = lambda s, y: y[0]  # noqa: E731
    zero.terminal = True
    opts = dict(method="DOP853", rtol=1e-13, atol=1e-16, dense_output=True)
    upper = solve_ivp(lambda s, y: -(1.0 + np.maximum(y, 0.0) ** n), (0.0, 2.0), [1.0], events=zero, **opts)
    s_c = float(upper.t_events[0][0])  # int_0^1 dz / (1 + z^n) < 1
    lower = solve_ivp(lambda s, y: -(1.0 - np.abs(np.minimum(y, 0.0)) ** n), (s_c, s_c + _BW_TAIL / n), [0.0], **opts)
    return s_c, upper.sol, lower.sol


def _bouc_wen_harmonics(n: float, a) -> np.ndarray:
    """``EJ_slip* / delta_EJ`` of the Bouc-Wen law by quadrature of its steady loops, shape of ``a``.

    Every steady loop's unloading branch is an arc ``P(s0 .. s0 + 2 a)`` of one profile
    (:func:`_bouc_wen_profile`; ``P(s0 + 2 a) = -P(s0)`` fixes ``s0``, safeguarded Newton), with
    ``s = s0 + a (1 - cos theta)``. Integrated by parts, the Fourier coefficients are::

        Re = 2 / (pi a^2) int sqrt((s - s0)(s0 + 2 a - s)) g(P(s)) ds,   g = -dP/ds
        Im = -2 / (pi a^2) int P(s) ds

    over the arc: Gauss-Legendre on each side of the zero ``s_c``, nodes mapped by
    ``1 - (1 - tau^2)^k`` (smooth at the square-root end, clustered at ``s_c``, where ``|P|^n``
    is not smooth: ``k n >= 3``). Beyond the profile's tail ``P = -1``.
    """
    s_c, upper, lower = _bouc_wen_profile(n)
    s_tail = s_c + _BW_TAIL / n
    a = np.asarray(a, dtype=float)

    def arc(s):
        out = np.full(s.shape, -1.0)
        up, mid = s <= s_c, (s > s_c) & (s < s_tail)
        if up.any():
            out[up] = upper(np.maximum(s[up], 0.0))[0]
        if mid.any():
            out[mid] = lower(s[mid])[0]
        return out

    def slope(p):
        return 1.0 + np.sign(p) * np.abs(p) ** n

    lo, hi = np.zeros(a.shape), np.full(a.shape, s_c)
    s0 = np.clip(s_c - a, 0.0, s_c)
    for _ in range(100):
        p0, p1 = arc(s0), arc(s0 + 2 * a)
        h = p0 + p1  # decreasing in s0
        lo, hi = np.where(h > 0, s0, lo), np.where(h <= 0, s0, hi)
        new = s0 + h / (slope(p0) + slope(p1))
        new = np.where((new >= lo) & (new <= hi), new, 0.5 * (lo + hi))
        done = np.abs(new - s0) <= 4e-15
        s0 = new
        if done.all():
            break
    x, w = np.polynomial.legendre.leggauss(_BW_GAUSS)
    tau, w = 0.5 * (x + 1.0), 0.5 * w
    k = min(max(math.ceil(3.0 / n), 2), 10)  # |P|^n at s_c: ~ (1 - tau)^(k n) after the map
    m = 1.0 - (1.0 - tau**2) ** k
    w = w * 2 * k * tau * (1.0 - tau**2) ** (k - 1)  # dm / dtau
    s0, end = s0[..., None], (s0 + 2 * a)[..., None]
    top = np.minimum(end, s_tail)
    re = im = 0.0
    for s, length in ((s0 + (s_c - s0) * m, s_c - s0), (top - (top - s_c) * m, top - s_c)):
        p = arc(s)
        kernel = np.sqrt(np.maximum((s - s0) * (end - s), 0.0))
        re = re + length[..., 0] * (w * kernel * slope(p)).sum(axis=-1)
        im = im + length[..., 0] * (w * p).sum(axis=-1)
    im = im - np.maximum(end - s_tail, 0.0)[..., 0]  # P = -1 beyond the tail
    return 2.0 * (re - 1j * im) / (np.pi * a**2)


_BW_NEAR = 0.9  # beyond this z^n the falling arc's logarithmic end is taken apart (scipy's hyp2f1 loses digits)
_BW_END_NODES = np.polynomial.legendre.leggauss(20)


def _bw_arc(eta, n, sign):
    """``int_0^eta dz / (1 + sign z^n)``, ``0 <= eta < 1``: the arc length (in ``chi / chi_slip``) over
    which the Bouc-Wen state runs from 0 to ``+eta`` (sign +1) or ``-eta`` (sign -1) while unloading.

    Gauss's hypergeometric function, except near ``z^n = 1`` on the falling side (``c - a - b = 0``:
    logarithmic), where with ``y = eta^n``, ``c = 1/n - 1``::

        n A = -ln(1 - y) - psi(1/n) - gamma - int_y^1 (w^c - 1) / (1 - w) dw

    the last integrand smooth (Gauss-Legendre).
    """
    eta, n = np.broadcast_arrays(np.minimum(np.asarray(eta, dtype=float), 1.0 - 2.0**-53), np.asarray(n, dtype=float))
    y = eta**n
    near = (sign < 0) & (y > _BW_NEAR)
    out = eta * special.hyp2f1(1.0, 1.0 / n, 1.0 + 1.0 / n, -sign * np.where(near, 0.0, y))
    if near.any():
        yn, nn = y[near], n[near]
        x, w = _BW_END_NODES
        t = yn[:, None] + (1.0 - yn[:, None]) * 0.5 * (x + 1.0)[None, :]
        c = 1.0 / nn[:, None] - 1.0
        g = np.where(t < 1.0, np.expm1(c * np.log(t)) / np.maximum(1.0 - t, 1e-300), -c)
        tail = 0.5 * (1.0 - yn) * (g * w[None, :]).sum(axis=1)
        log_gap = -np.log(-np.expm1(nn * np.log(eta[near])))  # -ln(1 - y)
        out = np.array(out, dtype=float)
        out[near] = (log_gap - special.digamma(1.0 / nn) - np.euler_gamma - tail) / nn
    return out


def _bw_arc_inverse(y, n, sign):
    """``eta`` with ``_bw_arc(eta, n, sign) = y >= 0``: safeguarded Newton, in ``u = -ln(1 - eta)``
    on the side that diverges (sign -1, where the arc grows like ``u / n``)."""
    y = np.asarray(y, dtype=float)
    lo, hi = np.zeros(y.shape), np.full(y.shape, 1.0 if sign > 0 else 60.0)
    x = np.minimum(y, 0.5 * hi) if sign > 0 else np.log1p(y)
    for _ in range(100):
        eta = x if sign > 0 else -np.expm1(-x)
        g = _bw_arc(eta, n, sign) - y
        lo, hi = np.where(g < 0, x, lo), np.where(g >= 0, x, hi)
        if sign > 0:
            slope = 1.0 / (1.0 + eta**n)
        else:  # (1 - eta) / (1 - eta^n): 1 / n as eta -> 1
            d = -np.expm1(n * np.log(np.maximum(eta, 1e-300)))
            slope = np.where(d > 0, np.exp(-x) / np.maximum(d, 1e-300), 1.0 / n)
        new = x - g / slope
        new = np.where((new > lo) & (new < hi), new, 0.5 * (lo + hi))
        done = np.abs(new - x) <= 1e-15 * np.maximum(1.0, np.abs(x))
        x = new
        if done.all():
            break
    return x if sign > 0 else -np.expm1(-x)


def _bw_branch_eta(x, a, n):
    """Bouc-Wen state on the unloading branch of the steady loop at amplitude ``a`` (in units of
    ``chi_slip``), ``x = (chi_a - chi) / chi_slip`` from the turning point; and ``eta_a``.

    The arc from ``eta`` to 0 and on to ``-eta`` spans ``A+(eta) + A-(eta)`` (:func:`_bw_arc`), and the
    loop is odd, so ``A+(eta_a) + A-(eta_a) = 2 a``; the branch then has ``A(eta) = A+(eta_a) - x``
    (Gauss's hypergeometric function: exact to rounding, for every exponent in one vectorised call).
    """
    eta_a = _bw_turning(a, n)
    return _bw_signed_inverse(_bw_arc(eta_a, n, 1.0) - x, n), eta_a


def _bw_turning(a, n):
    """``eta_a`` of the steady loop at amplitude ``a``: ``A+(eta_a) + A-(eta_a) = 2 a`` (:func:`_bw_branch_eta`;
    bisection-safeguarded Newton in ``-ln(1 - eta_a)``, compiled: :func:`sbcal.model.laws.kernels.bw_turning`)."""
    a, n = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(n, dtype=float))
    flat_n = np.ascontiguousarray(n).ravel()
    eta_a = kernels.bw_turning(np.ascontiguousarray(a).ravel(), flat_n, special.digamma(1.0 / flat_n))
    return eta_a.reshape(a.shape)


def _bw_signed_arc(eta, n):
    """Arc from 0 to ``eta`` in either sign while unloading (:func:`_bw_arc`; negative below 0)."""
    return np.where(eta >= 0, _bw_arc(np.abs(eta), n, 1.0), -_bw_arc(np.abs(eta), n, -1.0))


_BW_INVERSE_NODES = 6001  # nodes of the tabulated inverse arc, uniform in atanh(eta) over +-_BW_INVERSE_SPAN
_BW_INVERSE_SPAN = 18.0  # 1 - |eta| ~ 5e-16 at the ends
_BW_INVERSE_TABLES = 64  # more distinct exponents than this: the exact inverse instead


@functools.lru_cache(maxsize=_BW_INVERSE_TABLES)
def _bw_inverse_table(n: float):
    """``eta`` against the signed arc ``y = A(eta)`` at nodes uniform in ``atanh(eta)``, with the exact
    slope ``d eta / dy = 1 + |eta|^(n-1) eta``: a cubic Hermite inverse (nodes crowding geometrically
    at 0, where ``|eta|^n`` is not smooth)."""
    near = np.geomspace(1e-10, 0.3, 400)  # |eta|^n is not smooth at 0: nodes crowd there
    eta = np.unique(np.concatenate([np.tanh(np.linspace(-_BW_INVERSE_SPAN, _BW_INVERSE_SPAN, _BW_INVERSE_NODES)),
                                    near, -near, [0.0]]))
    y = _bw_signed_arc(eta, np.full(eta.shape, n))
    return y, eta, 1.0 + np.sign(eta) * np.abs(eta) ** n


def _bw_signed_inverse(y, n):
    """``eta`` with ``_bw_signed_arc(eta, n) = y``: tabulated per exponent (:func:`_bw_inverse_table`,
    within ~1e-10) where the exponents are few (a sweep, a posterior median), else exact."""
    y, n = np.broadcast_arrays(np.asarray(y, dtype=float), np.asarray(n, dtype=float))
    if n.size and n.flat[0] == n.min() == n.max():  # one exponent (the common case): no masks
        return _bw_table_inverse(y, float(n.flat[0]))
    values = np.unique(n)
    if values.size > _BW_INVERSE_TABLES:
        return np.where(y >= 0, _bw_arc_inverse(np.maximum(y, 0.0), n, 1.0),
                        -_bw_arc_inverse(np.maximum(-y, 0.0), n, -1.0))
    out = np.empty(y.shape)
    for value in values:
        mask = n == value
        out[mask] = _bw_table_inverse(y[mask], float(value))
    return out


def _bw_table_inverse(v, value):
    """:func:`_bw_signed_inverse` for one exponent ``value`` (its table)."""
    yk, ek, dk = _bw_inverse_table(value)
    j = np.clip(np.searchsorted(yk, v) - 1, 0, yk.size - 2)
    h = yk[j + 1] - yk[j]
    h = np.where(h > 0, h, 1.0)  # nodes that round to one arc length at the saturated ends
    t = np.clip((v - yk[j]) / h, 0.0, 1.0)
    t2, t3 = t * t, t * t * t
    e = ((2 * t3 - 3 * t2 + 1) * ek[j] + (t3 - 2 * t2 + t) * h * dk[j]
         + (-2 * t3 + 3 * t2) * ek[j + 1] + (t3 - t2) * h * dk[j + 1])
    # beyond the ends: saturated (the falling end approaches -1 as exp(n y))
    e = np.where(v < yk[0], -1.0 + (1.0 + ek[0]) * np.exp(value * np.minimum(v - yk[0], 0.0)), e)
    return np.where(v > yk[-1], ek[-1], e)


def _bw_periodic(chi, dirs, delta_EJ, chi_slip, n):
    """Bouc-Wen (and Dahl, ``n = 1``) over one period of any periodic curvature ``chi`` (m, n_t), steady;
    with derivatives along ``dirs`` (m, n_t, k) (:meth:`HysteresisLaw.periodic_moment`).

    Each step between samples is monotone, so the arc advances exactly: falling, ``A(eta') = A(eta) -
    |d chi| / chi_slip``; rising, the same for ``-eta`` (:func:`_bw_signed_arc`); the state is kept as
    its arc coordinate and converted only where the direction turns. The periodic state at the largest
    sample is the fixed point of the period map, by Newton from the outer loop's state
    (:func:`_bw_branch_eta`) with the map's exact derivative ``prod A'(eta) / A'(eta')``. Derivatives
    ride along at a fixed start, then the fixed point's own motion is added. Compiled, one fused loop
    per row (:func:`sbcal.model.laws.kernels.bw_periodic`); the inverse arc from the per-exponent tables
    (:func:`_bw_signed_inverse`'s choice).
    """
    m, nt = chi.shape
    ks = np.ascontiguousarray(np.broadcast_to(chi_slip, (m, 1))[:, 0], dtype=float)
    n = np.ascontiguousarray(np.broadcast_to(n, (m, 1))[:, 0], dtype=float)
    values, row = np.unique(n, return_inverse=True)
    if values.size > _BW_INVERSE_TABLES:  # too many exponents for tables: Newton on the arc
        row = np.full(m, -1)
        yk = ek = dk = np.zeros((1, 2))
    else:
        yk, ek, dk = (np.stack(t) for t in zip(*(_bw_inverse_table(float(v)) for v in values)))
    eta, deta = kernels.bw_periodic(np.ascontiguousarray(chi, dtype=float),
                                        np.ascontiguousarray(dirs, dtype=float), ks, n, special.digamma(1.0 / n),
                                        row.astype(np.int64), yk, ek, dk)
    scale = delta_EJ * chi_slip
    return scale * eta, scale[..., None] * deta


@functools.lru_cache(maxsize=1)
def _bouc_wen_table():
    """Quintic splines of ``ln Re`` and ``ln Im`` (of ``EJ_slip* / delta_EJ``) over ``(xi, psi)``.

    In these coordinates (:func:`_bw_xi`, :func:`_bw_psi`) both vary gently with the exponent at
    fixed ``xi``: interpolation error <= 1.2e-7 of ``delta_EJ`` over n in [0.3, 5] (largest at the
    ends), ~1e-9 at n ~ 1; the quadrature's own ~1e-8. Built at first use (~1 s).
    """
    psi = np.linspace(_bw_psi(_BW_TABLE_N[0]), _bw_psi(_BW_TABLE_N[1]), _BW_PSI_NODES)
    xi = np.linspace(*_BW_XI, _BW_XI_NODES)
    table = np.empty((2, xi.size, psi.size))
    for j, target in enumerate(psi):
        n = brentq(lambda x: _bw_psi(x) - target, 0.1, 10.0, xtol=1e-15)
        h = _bouc_wen_harmonics(n, np.exp(_bw_v(xi, n)))
        table[:, :, j] = np.log(h.real), np.log(h.imag)
    return tuple(RectBivariateSpline(xi, psi, t, kx=5, ky=5) for t in table)


def _bouc_wen_rigidity(a, n):
    """``EJ_slip* / delta_EJ`` of the Bouc-Wen law from its table, broadcast shape of ``a`` and ``n``.

    Beyond the table its ends continue with the law's limits (:class:`BoucWenLaw`), matched to
    the table's end: micro-slip ``Im = 4 a^n (1 + D a^2n) / (pi (n + 2))`` and ``1 - Re = K_n a^2n
    (1 + D' a^2n)`` (exact leading terms; ``D``, ``D'`` from the end value), gross slip
    ``Re ~ a^-3/2 (1 + B / a)`` (value and slope in ``ln a``) and ``Im = 4 (a - R) / (pi a^2)``
    (Coulomb friction; ``R`` from the end value).
    """
    spline_re, spline_im = _bouc_wen_table()
    a, n = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(n, dtype=float))
    with np.errstate(divide="ignore"):
        v = np.log(a)
    xi, psi = _bw_xi(v, n), _bw_psi(n)
    y_re, y_im = np.empty(a.shape), np.empty(a.shape)
    inside = (xi >= _BW_XI[0]) & (xi <= _BW_XI[1])
    y_re[inside] = spline_re.ev(xi[inside], psi[inside])
    y_im[inside] = spline_im.ev(xi[inside], psi[inside])

    def edge(mask, end):
        """The table's end ``end`` for the points ``mask``: its ln a, both splines' values there."""
        v_end = _bw_v(_BW_XI[end], n[mask])
        return v_end, v[mask] - v_end, spline_re.ev(_BW_XI[end], psi[mask]), spline_im.ev(_BW_XI[end], psi[mask])

    low = xi < _BW_XI[0]
    if low.any():
        v_end, dv, r0, i0 = edge(low, 0)
        nl = n[low]
        # the exact leading terms, the next order's coefficient from the table's end value
        c_im = 4.0 / (np.pi * (nl + 2.0))
        k_re = 2 * nl / (np.pi * (nl + 1)) * (special.beta(1.5, nl / 2) - special.beta(1.5, nl + 0.5))
        q0, q = np.exp(2 * nl * v_end), np.exp(2 * nl * (v_end + dv))  # a^2n at the end and here
        d_im = (np.exp(i0 - nl * v_end) / c_im - 1.0) / q0
        d_re = (-np.expm1(r0) / (k_re * q0) - 1.0) / q0
        y_im[low] = np.log(c_im) + nl * (v_end + dv) + np.log1p(d_im * q)
        y_re[low] = np.log1p(-k_re * q * (1.0 + d_re * q))
    high = xi > _BW_XI[1]
    if high.any():
        v_end, dv, r0, i0 = edge(high, 1)
        nh = n[high]
        d_r = spline_re.ev(_BW_XI[1], psi[high], dx=1) * (nh + (1.0 - nh) * special.expit(v_end))  # d/d ln a
        # ln Re = r0 - 1.5 dv + ln((1 + b e^-dv) / (1 + b)), b = B / a_end from the slope
        b = -(d_r + 1.5) / (1 + d_r + 1.5)
        y_re[high] = r0 - 1.5 * dv + np.log1p(b * np.exp(-dv)) - np.log1p(b)
        a_end = np.exp(v_end)
        r_coulomb = a_end - np.pi * a_end**2 * np.exp(i0) / 4
        y_im[high] = np.log(4 * (a[high] - r_coulomb) / (np.pi * a[high] ** 2))
    out = np.exp(y_re) + 1j * np.exp(y_im)
    return np.where(a > 0, out, 1.0 + 0j)


@register
@dataclass(frozen=True)
class BoucWenLaw(HysteresisLaw):
    """Bouc-Wen law with ``beta = 1``, ``gamma = 0`` and a free exponent: Dahl's law with a knee of any sharpness.

    ``chi_slip d(eta)/dt = d(chi)/dt - |d(chi)/dt| |eta|^(n-1) eta``, ``M_slip = delta_EJ chi_slip eta``
    (Bouc 1967, Wen 1976; ``n = sharpness``). ``n = 1`` is :class:`DahlLaw`; larger ``n`` sharpen
    the transition from stick to slip (``n -> inf``: one Jenkins element). With ``x = chi / chi_slip``
    and ``a = chi_a / chi_slip``, the branches obey ``d(eta)/dx = 1 -+ |eta|^(n-1) eta`` (loading,
    unloading): every steady loop is an arc of one profile, and its describing function is a
    quadrature of that arc (:func:`_bouc_wen_harmonics`), tabulated once over amplitude and
    exponent and interpolated by quintic splines of ``ln Re`` and ``ln Im`` (smooth in both;
    within 1.2e-7 of ``delta_EJ``, :func:`_bouc_wen_table`).

    Limits (the table's ends continue with them, :func:`_bouc_wen_rigidity`)::

        micro-slip:  Im EJ_slip* = 4 delta_EJ a^n / (pi (n + 2)),   W ~ chi_a^(n+2)
                     delta_EJ - Re EJ_slip* = K_n delta_EJ a^2n,
                     K_n = 2 n / (pi (n + 1)) (B(3/2, n/2) - B(3/2, n + 1/2))
        gross slip:  W = 4 delta_EJ chi_slip^2 (a - R_n) (Coulomb: slip moment delta_EJ chi_slip),
                     Re EJ_slip* ~ a^-3/2

    (``B`` the beta function; relative corrections ``O(a^2n)`` and ``O(1/a)``). Unlike an Iwan law,
    the in-phase softening (``a^2n``) is of higher order than the loss (``a^n``) in micro-slip.
    """

    name: ClassVar[str] = "bouc_wen"
    parameters: ClassVar[tuple] = (
        DELTA_EJ,
        LawParameter("chi_slip", "1/m", "Bouc-Wen curvature: the slip moment saturates at delta_EJ chi_slip",
                     prior=_SATURATION_BOX),
        # the whole domain (the table's), log-uniform: micro-slip W ~ chi^(n+2) from chi^2.3 (a broad knee)
        # to chi^7 (nearly one Jenkins element); 1 is Dahl
        LawParameter("sharpness", "1", f"Bouc-Wen exponent n in [{_BW_SHARPNESS[0]}, {_BW_SHARPNESS[1]}]: "
                     "sharpness of the stick-slip knee; micro-slip W ~ chi_a^(n+2)",
                     low=_BW_SHARPNESS[0], high=_BW_SHARPNESS[1], include_low=True, include_high=True,
                     prior=("loguniform", *_BW_SHARPNESS)),
    )
    fitted: ClassVar[bool] = True
    summary: ClassVar[str] = "the Bouc-Wen family, Dahl's law at sharpness 1"
    scale: ClassVar[str] = "chi_slip"
    typical: ClassVar[dict] = {"sharpness": 1.0}

    def time_stepper(self, params, *, resolution=1.0, linear=None):
        return BoucWenStepper.from_params(params["delta_EJ"], params["chi_slip"], params["sharpness"])

    def _rigidity(self, chi, *, delta_EJ, chi_slip, sharpness):
        return delta_EJ * _bouc_wen_rigidity(chi / chi_slip, sharpness)

    def _branch(self, chi, chi_a, *, delta_EJ, chi_slip, sharpness):
        """The branch from the arc's integral (:func:`_bw_branch_eta`); slopes in closed form:
        ``dm/dchi = delta_EJ (1 + |eta|^(n-1) eta)``, ``dm/dchi_a = -delta_EJ (1 + |eta|^(n-1) eta) eta_a^n``."""
        # the turning state once per loop (chi_a and the parameters may broadcast against many chi)
        eta_a = _bw_turning(chi_a / chi_slip, sharpness)
        y = _bw_arc(eta_a, sharpness, 1.0) - (chi_a - chi) / chi_slip
        n = np.broadcast_to(sharpness, y.shape)
        eta = _bw_signed_inverse(y, n)
        slope = 1.0 + np.sign(eta) * np.abs(eta) ** n
        return delta_EJ * chi_slip * eta, delta_EJ * slope, -delta_EJ * slope * eta_a**n

    def _periodic(self, chi, dirs, *, delta_EJ, chi_slip, sharpness):
        return _bw_periodic(chi, dirs, delta_EJ, chi_slip, sharpness)

    def steady_loop(self, chi_a, theta, *, delta_EJ, chi_slip, sharpness):
        """Time-steps the Bouc-Wen ODE over the unloading half period (DOP853, rtol 1e-13).

        ``d(eta)/d(theta) = -a sin(theta) (1 + |eta|^(n-1) eta)`` from ``eta(0) = eta_a``; the
        periodic state solves ``eta(pi) = -eta_a`` (the loop is odd: the loading half is its
        mirror image), by Brent's method on ``eta_a``.
        """
        a, n = chi_a / chi_slip, sharpness

        def half(eta_a, dense=False):
            rhs = lambda t, y: -a * np.sin(t) * (1.0 + np.sign(y) * np.abs(y) ** n)  # noqa: E731
            return solve_ivp(rhs, (0.0, np.pi), [eta_a], method="DOP853", rtol=1e-13, atol=1e-16, dense_output=dense)

        gap = lambda e: half(e).y[0, -1] + e  # noqa: E731
        eta_a = 1.0 if gap(1.0) <= 0 else brentq(gap, 0.0, 1.0, xtol=1e-15, rtol=1e-15)
        sol = half(eta_a, dense=True).sol
        theta = np.mod(np.asarray(theta, dtype=float), 2 * np.pi)
        first = theta <= np.pi
        eta = np.where(first, sol(np.minimum(theta, np.pi))[0], -sol(np.maximum(theta - np.pi, 0.0))[0])
        return delta_EJ * chi_slip * eta
