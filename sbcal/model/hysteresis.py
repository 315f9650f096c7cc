"""Moment-curvature hysteresis laws of the messenger cable's strand slip (``docs/cable.md``).

A length of cable carries the moment ``M = EJ_min chi + M_slip(chi history)``: an elastic part (the
fully slipped strand, with a material loss factor, handled by :mod:`sbcal.model.cable`) and a hysteretic
*slip part* from the friction between the wires. Over a steady cycle ``chi = chi_a cos(omega t)`` the
first harmonic of the slip part defines its complex secant rigidity (describing function)::

    M_slip ~ Re(EJ_slip*(chi_a) chi_a exp(i omega t)),
    Re EJ_slip* =  1/(pi chi_a) int_0^2pi M_slip cos(theta) dtheta,
    Im EJ_slip* = -1/(pi chi_a) int_0^2pi M_slip sin(theta) dtheta,

time convention ``exp(+i omega t)``, a positive imaginary part dissipates: the energy per cycle and
unit length is ``W = pi Im(EJ_slip*) chi_a^2`` [J/m]. The cable's total rigidity is
``EJ*(chi_a) = EJ_min (1 + i beta_material) + EJ_slip*(chi_a)``.

Each family is a small frozen class (:class:`HysteresisLaw` and one subclass each, as emcee's moves
are organised) with its parameters' names and units, a vectorised exact describing function
:meth:`HysteresisLaw.slip_rigidity`, and the law's own steady loop :meth:`HysteresisLaw.steady_loop`
(the reference the describing functions are tested against):

==================  ==========================================  ==================================
law                 parameters                                  describing function
==================  ==========================================  ==================================
``bouc_wen``        ``delta_EJ`` [N m^2], ``chi_slip`` [1/m],   quadrature of the loop, tabulated
                    ``sharpness`` [1]                           once over (amplitude, sharpness)
``iwan5``           ``delta_EJ``, ``chi_micro`` [1/m],          closed form (powers, incomplete
                    ``chi_macro`` [1/m], ``density_exponent``   beta function)
                    [1], ``macro_ratio`` [1]
``dahl``            ``delta_EJ``, ``chi_dahl`` [1/m]            closed form (Bessel I1, tanh)
``iwan``            ``delta_EJ``, ``chi_macro``,                closed form (powers, incomplete
                    ``micro_exponent`` [1], ``macro_ratio``     beta function in macro-slip)
``lognormal_iwan``  ``delta_EJ``, ``chi_median`` [1/m],         1-D quadrature, tabulated once per
                    ``log_spread`` [1]                          ``log_spread`` (virtual bench only)
==================  ==========================================  ==================================

The fitted families (:data:`FITTED_LAWS`) are ``bouc_wen`` (Dahl's law with a free sharpness:
``sharpness = 1`` is ``dahl``) and ``iwan5`` (an Iwan law whose slip curvatures spread between two
cut-offs: ``chi_micro -> 0`` is ``iwan``); ``dahl`` and ``iwan`` remain as their special cases, and
``lognormal_iwan`` is the virtual bench's own law, a special case of neither.

``delta_EJ`` is the same thing in every law: the rigidity the slip part adds while the wires stick
(``EJ_max = EJ_min + delta_EJ``). Parameters outside a law's domain give NaN, not an exception, so a
sampler can treat them as outside the support.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import special
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline, RectBivariateSpline
from scipy.optimize import brentq

from ..core.errors import InputError


__all__ = [
    "LawParameter",
    "HysteresisLaw",
    "DahlLaw",
    "BoucWenLaw",
    "IwanLaw",
    "Iwan5Law",
    "IwanTailLaw",
    "LognormalIwanLaw",
    "LAWS",
    "FITTED_LAWS",
    "law_for",
    "jenkins_rigidity",
]


@dataclass(frozen=True)
class LawParameter:
    """Name, SI unit and meaning of one law parameter."""

    name: str
    unit: str
    meaning: str


_DELTA_EJ = LawParameter("delta_EJ", "N m^2", "rigidity the slip part adds while the wires stick (EJ_max - EJ_min)")


def jenkins_rigidity(x):
    """Describing function of a Jenkins element (unit spring in series with a slider), per unit stiffness.

    ``x = phi / chi_a`` is the element's slip curvature over the amplitude. Stuck (``x >= 1``): 1.
    Slipping (Caughey 1960), with ``theta = arccos(1 - 2 x)``::

        Re = (theta - sin(theta) cos(theta)) / pi,    Im = 4 x (1 - x) / pi = sin(theta)^2 / pi

    Parameters
    ----------
    x : array_like
        ``phi / chi_a`` >= 0.

    Returns
    -------
    ndarray of complex, shape of ``x``
    """
    x = np.asarray(x, dtype=float)
    xs = np.clip(x, 0.0, 1.0)
    theta = np.arccos(1.0 - 2.0 * xs)
    re = (theta - np.sin(theta) * np.cos(theta)) / np.pi
    return np.where(x >= 1.0, 1.0 + 0j, re + 1j * 4.0 * xs * (1.0 - xs) / np.pi)


@dataclass(frozen=True)
class HysteresisLaw:
    """Base of the strand-slip law families.

    Subclasses set :attr:`name` and :attr:`parameters` and implement :meth:`_rigidity` (the
    describing function on validated, broadcast arrays) and :meth:`steady_loop`.
    """

    name: ClassVar[str] = ""
    parameters: ClassVar[tuple] = ()
    min_tests: ClassVar[int] = 1
    """Tests (amplitudes) a cable state needs before the family is compared on it."""

    @property
    def parameter_names(self) -> tuple:
        """The law's parameter names, in order."""
        return tuple(p.name for p in self.parameters)

    def _arrays(self, params: dict) -> dict:
        names = self.parameter_names
        missing = [n for n in names if n not in params]
        unknown = sorted(set(params) - set(names))
        if missing or unknown:
            raise InputError(f"{self.name} law: expected parameters {', '.join(names)}"
                             + (f"; missing {missing[0]!r}" if missing else f"; unknown {unknown[0]!r}"))
        return {n: np.asarray(params[n], dtype=float) for n in names}

    def valid(self, **params) -> np.ndarray:
        """Boolean mask (broadcast shape of the parameters): the parameters lie in the law's domain."""
        p = self._arrays(params)
        ok = np.ones(np.broadcast_shapes(*(v.shape for v in p.values())), dtype=bool)
        for name, v in p.items():
            ok &= np.isfinite(v) & self._domain(name, v)
        return ok

    def _domain(self, name: str, v: np.ndarray) -> np.ndarray:
        return v > 0

    def slip_rigidity(self, chi_a, **params) -> np.ndarray:
        """First-harmonic complex secant rigidity of the slip part at curvature amplitude ``chi_a``.

        Parameters
        ----------
        chi_a : array_like
            Curvature amplitude [1/m], >= 0.
        **params : float or array_like
            The law's parameters (:attr:`parameters`), broadcast against ``chi_a``.

        Returns
        -------
        ndarray of complex
            ``EJ_slip*`` [N m^2], broadcast shape; ``delta_EJ`` (real) at ``chi_a = 0``; NaN where
            the parameters are outside the law's domain.
        """
        p = self._arrays(params)
        chi = np.asarray(chi_a, dtype=float)
        ok = self.valid(**params)
        out = self._rigidity(np.maximum(chi, 0.0), **{k: np.where(ok, v, 1.0) for k, v in p.items()})
        return np.where(ok, out, np.nan)

    def energy_per_cycle(self, chi_a, **params) -> np.ndarray:
        """``W = pi Im(EJ_slip*) chi_a^2``: friction energy per cycle and unit length [J/m]."""
        return np.pi * self.slip_rigidity(chi_a, **params).imag * np.asarray(chi_a, dtype=float) ** 2

    def _rigidity(self, chi, **p):  # pragma: no cover - abstract
        raise NotImplementedError

    def steady_loop(self, chi_a: float, theta, **params) -> np.ndarray:  # pragma: no cover - abstract
        """Slip moment [N m] on the steady loop ``chi = chi_a cos(theta)``, theta in [0, 2 pi).

        The law's own hysteresis operator, not its describing function: the reference the tests
        hold :meth:`slip_rigidity` to. Scalar parameters.
        """
        raise NotImplementedError


def _masing_loop(backbone, chi_a, theta):
    """Steady loop of a Masing law from its backbone (virgin curve) ``backbone(chi)``, chi >= 0.

    Unloading from ``chi_a`` (theta in [0, pi], chi falling): ``M = B(chi_a) - 2 B((chi_a - chi) / 2)``;
    loading (theta in (pi, 2 pi)): ``M = -B(chi_a) + 2 B((chi_a + chi) / 2)`` (Masing's doubling rule).
    Parallel Jenkins elements (Iwan models) obey it exactly.
    """
    theta = np.mod(np.asarray(theta, dtype=float), 2 * np.pi)
    chi = chi_a * np.cos(theta)
    top = backbone(np.asarray(chi_a, dtype=float))
    unloading = theta <= np.pi
    return np.where(unloading, top - 2 * backbone((chi_a - chi) / 2), -top + 2 * backbone((chi_a + chi) / 2))


# --- Dahl ---------------------------------------------------------------------------------------

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
        _DELTA_EJ,
        LawParameter("chi_dahl", "1/m", "Dahl curvature: the slip moment saturates at delta_EJ chi_dahl"),
    )

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
        _DELTA_EJ,
        LawParameter("chi_slip", "1/m", "Bouc-Wen curvature: the slip moment saturates at delta_EJ chi_slip"),
        LawParameter("sharpness", "1", f"Bouc-Wen exponent n in [{_BW_SHARPNESS[0]}, {_BW_SHARPNESS[1]}]: "
                     "sharpness of the stick-slip knee; micro-slip W ~ chi_a^(n+2)"),
    )

    def _domain(self, name, v):
        if name == "sharpness":
            return (v >= _BW_SHARPNESS[0]) & (v <= _BW_SHARPNESS[1])
        return v > 0

    def _rigidity(self, chi, *, delta_EJ, chi_slip, sharpness):
        return delta_EJ * _bouc_wen_rigidity(chi / chi_slip, sharpness)

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


# --- Iwan (Segalman's four parameters) ----------------------------------------------------------

@dataclass(frozen=True)
class IwanLaw(HysteresisLaw):
    """Segalman's four-parameter Iwan law (J. Appl. Mech. 72:752, 2005) on curvature.

    A continuum of Jenkins elements (unit-rigidity weights, slip curvature ``phi``) with density
    ``rho(phi) = R phi^c`` on ``(0, chi_macro)`` plus a point mass ``S delta(phi - chi_macro)``;
    ``c = micro_exponent > -1``, ``macro_ratio = S / (R chi_macro^(c+1) / (c+1))`` (Segalman's beta)
    and ``delta_EJ = R chi_macro^(c+1) / (c+1) + S``. The describing function is the Jenkins one
    (:func:`jenkins_rigidity`) integrated over the density, in closed form; with ``p = c + 1``,
    ``K = delta_EJ / (1 + macro_ratio)`` (continuous part), ``x_m = chi_macro / chi_a``:

    micro-slip (``x_m >= 1``)::

        Re = delta_EJ - K (8 B / pi) x_m^-p,     B = Beta(c + 5/2, 3/2)
        Im = K (4 p / pi) x_m^-p / ((c + 2)(c + 3))

    macro-slip (``x_m < 1``, every element slips), ``g = Re jenkins_rigidity``, ``B(x)`` the
    incomplete beta integral ``int_0^x t^(c+3/2) (1 - t)^(1/2) dt``::

        Re = K (g(x_m) - (8 / pi) x_m^-p B(x_m)) + S g(x_m)
        Im = K (4 p / pi) (x_m / (c + 2) - x_m^2 / (c + 3)) + S 4 x_m (1 - x_m) / pi

    Micro-slip dissipation ``W ~ chi_a^(c+3)``: the exponent is free (Dahl fixes it at 3); in gross
    slip the moment saturates at ``M_macro = chi_macro (K p / (c + 2) + S)`` (Coulomb).
    """

    name: ClassVar[str] = "iwan"
    parameters: ClassVar[tuple] = (
        _DELTA_EJ,
        LawParameter("chi_macro", "1/m", "curvature amplitude at which every wire slips (macro-slip)"),
        LawParameter("micro_exponent", "1", "c > -1: slip-curvature density ~ phi^c; micro-slip W ~ chi_a^(c+3)"),
        LawParameter("macro_ratio", "1", ">= 0: wires slipping only at chi_macro, relative to the spread part"),
    )

    def _domain(self, name, v):
        if name == "micro_exponent":
            return v > -1
        if name == "macro_ratio":
            return v >= 0
        return v > 0

    def _rigidity(self, chi, *, delta_EJ, chi_macro, micro_exponent, macro_ratio):
        c = micro_exponent
        p = c + 1.0
        k_cont = delta_EJ / (1.0 + macro_ratio)
        s_point = delta_EJ - k_cont
        b_full = special.beta(c + 2.5, 1.5)
        with np.errstate(divide="ignore", over="ignore"):
            xm = np.where(chi > 0, chi_macro / np.where(chi > 0, chi, 1.0), np.inf)
        shape = np.broadcast_shapes(np.shape(xm), np.shape(c), np.shape(delta_EJ))
        xm, c, p, k_cont, s_point, b_full = (np.broadcast_to(v, shape) for v in (xm, c, p, k_cont, s_point, b_full))
        micro = xm >= 1.0
        t = np.where(micro, 1.0 / np.where(micro, xm, 1.0), 0.0) ** p  # (chi_a / chi_macro)^p
        re = delta_EJ - k_cont * (8 * b_full / np.pi) * t
        im = k_cont * (4 * p / np.pi) * t / ((c + 2) * (c + 3))
        out = re + 1j * im
        if not micro.all():
            m = ~micro
            x, cm, pm, km, sm = xm[m], c[m], p[m], k_cont[m], s_point[m]
            jen = jenkins_rigidity(x)
            binc = special.betainc(cm + 2.5, 1.5, x) * special.beta(cm + 2.5, 1.5)
            re_m = km * (jen.real - (8 / np.pi) * x**-pm * binc) + sm * jen.real
            im_m = km * (4 * pm / np.pi) * (x / (cm + 2) - x * x / (cm + 3)) + sm * jen.imag
            out = np.array(out, dtype=complex)
            out[m] = re_m + 1j * im_m
        return out

    def backbone(self, chi, *, delta_EJ, chi_macro, micro_exponent, macro_ratio):
        """Virgin loading curve ``M_b(chi) = int rho(phi) min(chi, phi) dphi`` [N m], chi >= 0."""
        c, p = micro_exponent, micro_exponent + 1.0
        k_cont = delta_EJ / (1.0 + macro_ratio)
        r = k_cont * p / chi_macro**p
        u = np.minimum(chi, chi_macro)
        return r * (u ** (c + 2) / (c + 2) + chi * (chi_macro**p - u**p) / p) + (delta_EJ - k_cont) * u

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone` (exact for parallel Jenkins elements)."""
        return _masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


# --- Iwan with a power-law density between two cut-offs (five parameters) ----------------------

_P_ZERO = 1e-6  # |c + 1| below this the closed form's 1/p terms cancel: interpolate across p = 0


def _power_integral(x1, x2, q):
    """``int_x1^x2 x^(q-1) dx`` for ``0 < x1 <= x2``, any real q (``ln(x2 / x1)`` at q = 0)."""
    span = np.log(x2 / x1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = np.exp(q * np.log(x1)) * np.expm1(q * span) / q
    return np.where(q == 0, span, out)


def _slip_integral(x1, x2, p):
    """``int_x1^x2 x^(p-1) (1 - J(x)) dx`` for ``0 < x1 <= x2 <= 1`` and ``p > -3/2`` (J: Jenkins).

    Real part by parts (``1 - g`` vanishes at 1, ``g' = 8 sqrt(x (1 - x)) / pi``)::

        [x^p (1 - g(x)) / p + 8 B(x; p + 3/2, 3/2) / (pi p)]_x1^x2

    with ``B`` the incomplete beta integral; imaginary part ``-(4 / pi) int x^p (1 - x) dx``.
    The two real terms are ~1/p each: for ``|p| < _P_ZERO`` (a log-uniform density) the value is
    the linear interpolation between ``p = +-_P_ZERO``: its error ~_P_ZERO^2 (ln x1)^2 and the
    rounding ~eps / _P_ZERO are both ~1e-10 of the integral.
    """
    near = np.abs(p) < _P_ZERO
    if near.any():
        lo = _slip_integral(x1, x2, np.where(near, -_P_ZERO, p))
        hi = _slip_integral(x1, x2, np.where(near, _P_ZERO, p))
        t = (np.where(near, p, 0.0) + _P_ZERO) / (2 * _P_ZERO)
        return np.where(near, lo + t * (hi - lo), hi)

    def primitive(x):
        g = jenkins_rigidity(x).real
        b = special.betainc(p + 1.5, 1.5, x) * special.beta(p + 1.5, 1.5)
        return (np.exp(p * np.log(x)) * (1.0 - g) + 8.0 * b / np.pi) / p

    im = -(4.0 / np.pi) * (_power_integral(x1, x2, p + 1.0) - _power_integral(x1, x2, p + 2.0))
    return primitive(x2) - primitive(x1) + 1j * im


_CHI_MICRO = LawParameter("chi_micro", "1/m", "curvature amplitude below which every wire sticks (the lower cut-off)")
_DENSITY_EXPONENT = LawParameter("density_exponent", "1", "c > -5/2: slip-curvature density ~ phi^c above chi_micro")


@dataclass(frozen=True)
class Iwan5Law(HysteresisLaw):
    """Five-parameter Iwan law: a power-law slip-curvature density between two cut-offs, plus a point mass.

    Jenkins elements with slip curvatures of density ``R phi^c`` on ``(chi_micro, chi_macro)`` and
    a point mass ``S delta(phi - chi_macro)``; ``c = density_exponent`` (any value > -5/2: with the
    lower cut-off the density stays finite), ``macro_ratio = S / (R int phi^c dphi)`` and
    ``delta_EJ = R int phi^c dphi + S``. ``chi_micro -> 0`` with ``c > -1`` is :class:`IwanLaw`
    (Segalman's four parameters). In ``ln phi`` the density is ``~ exp((c + 1) ln phi)`` on a finite
    interval: flat (log-uniform) at ``c = -1``, so it spreads over as many decades as
    ``chi_macro / chi_micro``, and it is never a lognormal law.

    Describing function, with ``K = delta_EJ / (1 + macro_ratio)``, ``p = c + 1``, ``x = phi / chi_a``
    (``x_lo``, ``x_hi`` for the cut-offs), ``x_u = min(x_hi, 1)`` and ``J`` the Jenkins element::

        EJ_slip* = K (1 - N int_x_lo^x_u x^(p-1) (1 - J(x)) dx) + S J(x_hi),
        N = 1 / int_x_lo^x_hi x^(p-1) dx

    (stuck while ``x_lo >= 1``), the integral in closed form (:func:`_slip_integral`: powers and an
    incomplete beta function). Below ``chi_micro`` every wire sticks (``W = 0``: the material loss is
    :mod:`sbcal.model.cable`'s); between the cut-offs ``W ~ chi_a^(c+3)`` for ``-2 < c``, Coulomb-like
    ``W ~ chi_a`` for ``c < -2`` (the wires near ``chi_micro`` dominate); above ``chi_macro`` the
    moment saturates (Coulomb). A Masing law: the loop follows from :meth:`backbone`.
    """

    name: ClassVar[str] = "iwan5"
    parameters: ClassVar[tuple] = (
        _DELTA_EJ,
        _CHI_MICRO,
        LawParameter("chi_macro", "1/m", "curvature amplitude at which every wire slips (macro-slip)"),
        _DENSITY_EXPONENT,
        LawParameter("macro_ratio", "1", ">= 0: wires slipping only at chi_macro, relative to the spread part"),
    )

    def _domain(self, name, v):
        if name == "density_exponent":
            return v > -2.5
        if name == "macro_ratio":
            return v >= 0
        return v > 0

    def valid(self, **params) -> np.ndarray:
        """As :meth:`HysteresisLaw.valid`, and ``chi_micro < chi_macro``."""
        ok = super().valid(**params)
        with np.errstate(invalid="ignore"):
            return ok & (np.asarray(params["chi_micro"], dtype=float) < np.asarray(params["chi_macro"], dtype=float))

    def _rigidity(self, chi, *, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio):
        shape = np.broadcast_shapes(np.shape(chi), np.shape(delta_EJ), np.shape(chi_micro), np.shape(chi_macro),
                                    np.shape(density_exponent), np.shape(macro_ratio))
        chi, dej, lo, hi, c, beta = (np.broadcast_to(v, shape) for v in (chi, delta_EJ, chi_micro, chi_macro,
                                                                         density_exponent, macro_ratio))
        k_cont = dej / (1.0 + beta)
        out = np.array(dej, dtype=complex)  # stuck below chi_micro
        m = chi > lo
        if m.any():
            x_lo, x_hi, p, km = lo[m] / chi[m], hi[m] / chi[m], c[m] + 1.0, k_cont[m]
            slipping = _slip_integral(x_lo, np.minimum(x_hi, 1.0), p)
            cont = 1.0 - slipping / _power_integral(x_lo, x_hi, p)
            out[m] = km * cont + (dej[m] - km) * jenkins_rigidity(x_hi)
        return out

    def backbone(self, chi, *, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio):
        """Virgin loading curve ``M_b(chi) = int rho(phi) min(chi, phi) dphi`` [N m], chi >= 0."""
        p = density_exponent + 1.0
        k_cont = delta_EJ / (1.0 + macro_ratio)
        r = k_cont / _power_integral(chi_micro, chi_macro, p)
        u = np.clip(chi, chi_micro, chi_macro)
        cont = r * (_power_integral(chi_micro, u, p + 1.0) + chi * _power_integral(u, chi_macro, p))
        return cont + (delta_EJ - k_cont) * np.minimum(chi, chi_macro)

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone` (exact for parallel Jenkins elements)."""
        return _masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


# --- Iwan with a power-law tail beyond the macro-slip curvature -----------------------------------

@dataclass(frozen=True)
class IwanTailLaw(HysteresisLaw):
    """Iwan law whose slip-curvature density is a broken power law: ``phi^c`` between the cut-offs,
    ``phi^c_t`` beyond ``chi_tail``.

    Jenkins elements with slip curvatures of density ``R phi^c`` on ``(chi_micro, chi_tail)`` and
    ``R chi_tail^c (phi / chi_tail)^c_t`` on ``(chi_tail, inf)``, ``c = density_exponent > -5/2``,
    ``-5/2 < c_t = tail_exponent < -1`` (the tail holds a finite rigidity; its wires stop slipping
    one after the other, not all at once), ``delta_EJ = R (int_micro^macro phi^c dphi +
    chi_tail^(c+1) / (-c_t - 1))``. Where :class:`Iwan5Law` ends the spread with a sharp cut-off
    (and a point mass), this law lets the density fall smoothly in ``ln phi`` — as a bell-shaped
    density's upper side does — so the slipping rigidity approaches ``EJ_min`` as ``chi_a^(c_t+1)``
    instead of saturating Coulomb-like. ``c_t -> -inf`` is :class:`Iwan5Law` without its point mass.

    Describing function, per segment a power law (``x = phi / chi_a``; :func:`_slip_integral`)::

        EJ_slip* = delta_EJ - R (chi_a^(c+1) int_x_lo^min(x_hi, 1) x^c (1 - J(x)) dx
                                 + [chi_a > chi_tail] chi_tail^(c-c_t) chi_a^(c_t+1)
                                   int_x_hi^1 x^c_t (1 - J(x)) dx)

    in closed form (powers, incomplete beta functions). A Masing law: the loop follows from :meth:`backbone`.
    """

    name: ClassVar[str] = "iwan_tail"
    # one amplitude does not pin the tail down: on the bundled oiled cables (one test each) the posterior
    # did not mix (acceptance 2-3 %, tau 550, still not converged at 24 000 steps; docs/cable.md)
    min_tests: ClassVar[int] = 2
    parameters: ClassVar[tuple] = (
        _DELTA_EJ,
        _CHI_MICRO,
        LawParameter("chi_tail", "1/m", "curvature where the slip-curvature density's power changes to the tail's"),
        _DENSITY_EXPONENT,
        LawParameter("tail_exponent", "1", "-5/2 < c_t < -1: density ~ phi^c_t beyond chi_tail"),
    )

    def _domain(self, name, v):
        if name == "density_exponent":
            return v > -2.5
        if name == "tail_exponent":
            return (v > -2.5) & (v < -1.0)
        return v > 0

    def valid(self, **params) -> np.ndarray:
        """As :meth:`HysteresisLaw.valid`, and ``chi_micro < chi_tail``."""
        ok = super().valid(**params)
        with np.errstate(invalid="ignore"):
            return ok & (np.asarray(params["chi_micro"], dtype=float) < np.asarray(params["chi_tail"], dtype=float))

    @staticmethod
    def _scale(delta_EJ, chi_micro, chi_tail, density_exponent, tail_exponent):
        """``R chi_tail^(c+1)``: the density's scale in units of ``chi_tail``."""
        inner = _power_integral(chi_micro / chi_tail, np.ones_like(chi_tail), density_exponent + 1.0)
        return delta_EJ / (inner + 1.0 / (-tail_exponent - 1.0))

    def _rigidity(self, chi, *, delta_EJ, chi_micro, chi_tail, density_exponent, tail_exponent):
        shape = np.broadcast_shapes(np.shape(chi), np.shape(delta_EJ), np.shape(chi_micro), np.shape(chi_tail),
                                    np.shape(density_exponent), np.shape(tail_exponent))
        chi, dej, lo, hi, c, ct = (np.broadcast_to(np.asarray(v, dtype=float), shape) for v in
                                   (chi, delta_EJ, chi_micro, chi_tail, density_exponent, tail_exponent))
        r = self._scale(dej, lo, hi, c, ct)
        out = np.array(dej, dtype=complex)  # stuck below chi_micro
        m = chi > lo
        if m.any():
            a, x_lo, x_hi = chi[m] / hi[m], lo[m] / chi[m], hi[m] / chi[m]  # a: amplitude in units of chi_tail
            slip = np.exp((c[m] + 1.0) * np.log(a)) * _slip_integral(x_lo, np.minimum(x_hi, 1.0), c[m] + 1.0)
            beyond = a > 1.0
            if beyond.any():
                pt = ct[m][beyond] + 1.0
                slip[beyond] += np.exp(pt * np.log(a[beyond])) * _slip_integral(x_hi[beyond], np.ones(pt.shape), pt)
            out[m] = dej[m] - r[m] * slip
        return out

    def backbone(self, chi, *, delta_EJ, chi_micro, chi_tail, density_exponent, tail_exponent):
        """Virgin loading curve ``M_b(chi) = int rho(phi) min(chi, phi) dphi`` [N m], chi >= 0."""
        p, pt = density_exponent + 1.0, tail_exponent + 1.0
        r = self._scale(delta_EJ, chi_micro, chi_tail, density_exponent, tail_exponent) / chi_tail ** p  # R
        u = np.clip(chi, chi_micro, chi_tail)
        inner = r * (_power_integral(chi_micro, u, p + 1.0) + chi * _power_integral(u, chi_tail, p))
        v = np.maximum(chi, chi_tail)
        rt = r * chi_tail ** (density_exponent - tail_exponent)
        tail = rt * (_power_integral(chi_tail, v, pt + 1.0) + chi * v ** pt / (-pt))
        return inner + tail

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone` (exact for parallel Jenkins elements)."""
        return _masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


# --- Iwan with a lognormal slip-threshold density (the virtual bench's law) ----------------------

_LOG_GRID_STEP = 0.01  # table step in ln(chi_a / chi_median)
_GL_NODES = 400  # Gauss-Legendre nodes of the slipping part's quadrature


@functools.lru_cache(maxsize=16)
def _lognormal_table(log_spread: float):
    """Spline of ``EJ_slip* / delta_EJ`` over ``v = ln(chi_a / chi_median)``; and its range.

    Stuck wires (``phi > chi_a``) add ``P(phi > chi_a) = Q(v / s)``; slipping ones
    ``int_{t < v} pdf(t) J(exp(t - v)) dt``, ``t = ln(phi / chi_median)``, evaluated with
    ``t = v - w^2`` (``J`` has a ``(1 - x)^(3/2)`` term at ``x = 1``, smooth in ``w``) by
    Gauss-Legendre on ``w in [0, sqrt(v + 10 s)]``.
    """
    s = log_spread
    v_lo, v_hi = -10.0 * s - 2.0, 10.0 * s + 14.0
    v = np.arange(v_lo, v_hi + _LOG_GRID_STEP / 2, _LOG_GRID_STEP)
    xg, wg = np.polynomial.legendre.leggauss(_GL_NODES)
    top = np.sqrt(np.maximum(v + 10.0 * s, 0.0))[:, None]
    w = 0.5 * (xg + 1.0)[None, :] * top
    weight = 0.5 * wg[None, :] * top
    t = v[:, None] - w * w
    pdf = np.exp(-0.5 * (t / s) ** 2) / (s * math.sqrt(2 * math.pi))
    slipping = (pdf * jenkins_rigidity(np.exp(-w * w)) * 2 * w * weight).sum(axis=1)
    stuck = 0.5 * special.erfc(v / (s * math.sqrt(2)))
    table = stuck + slipping
    return CubicSpline(v, table.real), CubicSpline(v, table.imag), v_lo, v_hi


@dataclass(frozen=True)
class LognormalIwanLaw(HysteresisLaw):
    """Iwan law with a lognormal slip-threshold density: the virtual bench's cable, fitted by neither family.

    Jenkins elements with slip curvatures ``phi`` lognormally distributed (median ``chi_median``,
    log standard deviation ``log_spread``), total stuck rigidity ``delta_EJ``. The describing
    function ``delta_EJ E[J(phi / chi_a)]`` (:func:`jenkins_rigidity`) is a 1-D quadrature,
    tabulated once per ``log_spread`` over ``ln(chi_a / chi_median)`` and splined; beyond the
    table it uses its limits (stuck: ``delta_EJ``; gross slip: the lognormal moments in
    ``Re ~ 16 E[phi^1.5] / (3 pi chi_a^1.5)``, ``Im ~ 4 (E[phi] / chi_a - E[phi^2] / chi_a^2) / pi``).

    Unlike both fitted families, the density vanishes faster than any power at small ``phi``, so the
    micro-slip dissipation has no fixed exponent (it steepens as the amplitude falls), and the
    transition is as broad as ``log_spread`` makes it. A Masing law: the loop follows from the
    backbone (:meth:`backbone`).
    """

    name: ClassVar[str] = "lognormal_iwan"
    parameters: ClassVar[tuple] = (
        _DELTA_EJ,
        LawParameter("chi_median", "1/m", "median slip curvature of the wires"),
        LawParameter("log_spread", "1", "log standard deviation of the slip curvatures (scalar)"),
    )

    def _rigidity(self, chi, *, delta_EJ, chi_median, log_spread):
        spreads = np.unique(log_spread)
        if spreads.size != 1:
            raise InputError("lognormal_iwan law: log_spread must be one value per call (it selects a table)")
        s = float(spreads[0])
        spline_re, spline_im, v_lo, v_hi = _lognormal_table(s)
        with np.errstate(divide="ignore"):
            v = np.log(np.maximum(chi, 1e-300) / chi_median)
        vc = np.clip(v, v_lo, v_hi)
        out = spline_re(vc) + 1j * spline_im(vc)
        # gross slip beyond the table: lognormal moments E[(phi / chi_a)^k] = exp(-k v + k^2 s^2 / 2)
        vg = np.maximum(v, v_hi)
        m1, m15, m2 = (np.exp(-k * vg + 0.5 * (k * s) ** 2) for k in (1.0, 1.5, 2.0))
        gross = 16 * m15 / (3 * np.pi) + 1j * 4 * (m1 - m2) / np.pi
        out = np.where(v > v_hi, gross, np.where(v < v_lo, 1.0 + 0j, out))
        return delta_EJ * out

    def backbone(self, chi, *, delta_EJ, chi_median, log_spread):
        """``M_b(chi) = delta_EJ (E[phi; phi < chi] + chi P(phi > chi))`` [N m], chi >= 0."""
        s = log_spread
        z = np.log(np.maximum(chi, 1e-300) / chi_median) / s
        lower = chi_median * math.exp(0.5 * s * s) * special.ndtr(z - s)
        return delta_EJ * (lower + chi * special.ndtr(-z))

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone`."""
        return _masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


LAWS = {law.name: law for law in (BoucWenLaw, Iwan5Law, IwanTailLaw, DahlLaw, IwanLaw, LognormalIwanLaw)}
"""Law classes by name."""

FITTED_LAWS = ("bouc_wen", "iwan5", "iwan_tail")
"""The families a calibration fits and compares (three shapes: a smooth Dahl-like knee, a spread of
slipping wires ending sharply, one ending in a power-law tail; each only where every cable state has
its :attr:`HysteresisLaw.min_tests`); ``dahl`` and ``iwan`` are special cases, ``lognormal_iwan`` the
virtual bench's own."""


def law_for(name: str) -> HysteresisLaw:
    """A law instance by name (:data:`LAWS`); one-line InputError for an unknown name."""
    if name not in LAWS:
        raise InputError(f"unknown hysteresis law {name!r}; known: {', '.join(LAWS)}")
    return LAWS[name]()
