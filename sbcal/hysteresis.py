"""Moment-curvature hysteresis laws of the messenger cable's strand slip (``docs/cable.md``).

A length of cable carries the moment ``M = EJ_min chi + M_slip(chi history)``: an elastic part (the
fully slipped strand, with a material loss factor, handled by :mod:`sbcal.cable`) and a hysteretic
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

=================  ===========================================  ===================================
law                parameters                                   describing function
=================  ===========================================  ===================================
``dahl``           ``delta_EJ`` [N m^2], ``chi_dahl`` [1/m]     closed form (Bessel I1, tanh)
``iwan``           ``delta_EJ``, ``chi_macro`` [1/m],           closed form (powers, incomplete
                   ``micro_exponent`` [1], ``macro_ratio`` [1]  beta function in macro-slip)
``lognormal_iwan`` ``delta_EJ``, ``chi_median`` [1/m],          1-D quadrature, tabulated once per
                   ``log_spread`` [1]                           ``log_spread`` (virtual bench only)
=================  ===========================================  ===================================

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
from scipy.interpolate import CubicSpline

from .errors import InputError

__all__ = [
    "LawParameter",
    "HysteresisLaw",
    "DahlLaw",
    "IwanLaw",
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


LAWS = {law.name: law for law in (DahlLaw, IwanLaw, LognormalIwanLaw)}
"""Law classes by name."""

FITTED_LAWS = ("dahl", "iwan")
"""The families a calibration fits; ``lognormal_iwan`` is the virtual bench's own."""


def law_for(name: str) -> HysteresisLaw:
    """A law instance by name (:data:`LAWS`); one-line InputError for an unknown name."""
    if name not in LAWS:
        raise InputError(f"unknown hysteresis law {name!r}; known: {', '.join(LAWS)}")
    return LAWS[name]()
