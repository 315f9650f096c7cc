"""Iwan laws: parallel Jenkins elements with a density of slip curvatures (Segalman's four parameters, a
power law between two cut-offs, with a power-law tail, and the virtual bench's log-normal density)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import special
from scipy.interpolate import CubicSpline

from ...core.errors import InputError
from .base import DELTA_EJ, HysteresisLaw, LawParameter, jenkins_rigidity, masing_loop
from .iwan_kernel import iwan5_rigidity, slip_integral
from .registry import register


__all__ = ["IwanLaw", "Iwan5Law", "IwanTailLaw", "LognormalIwanLaw"]

# The slip curvatures' boxes, log-uniform: each is known to an order of magnitude. Bench curvatures span ~1e-4
# (0.1 mm, off resonance) to ~0.1 (2 mm at a resonance): macro-slip a decade beyond each end
_CHI_MACRO = LawParameter("chi_macro", "1/m", "curvature amplitude at which every wire slips (macro-slip)",
                          prior=("loguniform", 1e-5, 1.0))
# Segalman's beta: 0 is a smooth entry into macro-slip; large values put most wires at one slip curvature
# (a sharp knee, folds at low damping)
_MACRO_RATIO = LawParameter("macro_ratio", "1", ">= 0: wires slipping only at chi_macro, relative to the spread part",
                            include_low=True, prior=("uniform", 0.0, 5.0))

# --- Iwan (Segalman's four parameters) ----------------------------------------------------------

@register
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
        DELTA_EJ,
        _CHI_MACRO,
        LawParameter("micro_exponent", "1", "c > -1: slip-curvature density ~ phi^c; micro-slip W ~ chi_a^(c+3)",
                     low=-1.0),
        _MACRO_RATIO,
    )
    within: ClassVar[str] = "iwan5"
    scale: ClassVar[str] = "chi_macro"
    typical: ClassVar[dict] = {"micro_exponent": -0.5, "macro_ratio": 0.0}

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
        return masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


# --- Iwan with a power-law density between two cut-offs (five parameters) ----------------------

_P_ZERO = 1e-6  # |c + 1| below this the closed form's 1/p terms cancel: interpolate across p = 0


def _power_integral(x1, x2, q):
    """``int_x1^x2 x^(q-1) dx`` for ``0 < x1 <= x2``, any real q (``ln(x2 / x1)`` at q = 0)."""
    span = np.log(x2 / x1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = np.exp(q * np.log(x1)) * np.expm1(q * span) / q
    return np.where(q == 0, span, out)


def _slip_integral(x1, x2, p):
    """``int_x1^x2 x^(p-1) (1 - J(x)) dx`` for ``0 < x1 <= x2 <= 1`` and ``p > -3/2`` (J: Jenkins), broadcast.

    Real part by parts (``1 - g`` vanishes at 1, ``g' = 8 sqrt(x (1 - x)) / pi``)::

        [x^p (1 - g(x)) / p + 8 B(x; p + 3/2, 3/2) / (pi p)]_x1^x2

    with ``B`` the incomplete beta integral; imaginary part ``-(4 / pi) int x^p (1 - x) dx``.
    The two real terms are ~1/p each: for ``|p| < _P_ZERO`` (a log-uniform density) the value is
    the linear interpolation between ``p = +-_P_ZERO``: its error ~_P_ZERO^2 (ln x1)^2 and the
    rounding ~eps / _P_ZERO are both ~1e-10 of the integral. Compiled
    (:func:`sbcal.model.laws.iwan_kernel.slip_integral`; its numpy formulation is ``tests/law_reference.py``'s).
    """
    shape, flat = _flat(x1, x2, p)
    return slip_integral(*flat, _P_ZERO).reshape(shape)


def _flat(*values) -> tuple:
    """The broadcast shape of ``values`` and each as a 1-D float array of it, copied (numba, typing a call,
    reads its arguments' flags: a broadcast view's warn) for :mod:`sbcal.model.laws.iwan_kernel`."""
    values = np.broadcast_arrays(*values)
    return values[0].shape, [np.array(v, dtype=float).reshape(-1) for v in values]


# from far below any bench curvature (Segalman's Iwan-4, no cut-off) to the bench's middle; < the upper cut-off
_CHI_MICRO = LawParameter("chi_micro", "1/m", "curvature amplitude below which every wire sticks (the lower cut-off)",
                          prior=("loguniform", 1e-7, 0.1))
# -1 spreads the wires evenly over the decades between the cut-offs; lap joints measure -0.5..0 (Segalman);
# below -2 the wires at chi_micro dominate (Coulomb-like W ~ chi), above 2 those at the upper end
_DENSITY_EXPONENT = LawParameter("density_exponent", "1", "c > -5/2: slip-curvature density ~ phi^c above chi_micro",
                                 low=-2.5, prior=("uniform", -2.4, 2.0))
_TYPICAL_DENSITY = {"chi_micro": 1e-6, "density_exponent": -0.5}


@register
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
    incomplete beta function), compiled (:mod:`sbcal.model.laws.iwan_kernel`). Below ``chi_micro`` every
    wire sticks (``W = 0``: the material loss is :mod:`sbcal.model.cable`'s); between the cut-offs
    ``W ~ chi_a^(c+3)`` for ``-2 < c``, Coulomb-like ``W ~ chi_a`` for ``c < -2`` (the wires near
    ``chi_micro`` dominate); above ``chi_macro`` the moment saturates (Coulomb). A Masing law: the loop
    follows from :meth:`backbone`.
    """

    name: ClassVar[str] = "iwan5"
    parameters: ClassVar[tuple] = (DELTA_EJ, _CHI_MICRO, _CHI_MACRO, _DENSITY_EXPONENT, _MACRO_RATIO)
    ordered: ClassVar[tuple] = (("chi_micro", "chi_macro"),)
    fitted: ClassVar[bool] = True
    summary: ClassVar[str] = "Iwan with two cut-offs, Segalman's 4-parameter law as a limit"
    scale: ClassVar[str] = "chi_macro"
    typical: ClassVar[dict] = dict(_TYPICAL_DENSITY, macro_ratio=0.0)

    def _rigidity(self, chi, *, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio):
        # compiled (sbcal.model.laws.iwan_kernel): the cable model's compliance table evaluates this most
        shape, flat = _flat(chi, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio)
        return iwan5_rigidity(*flat, _P_ZERO).reshape(shape)

    def backbone(self, chi, *, delta_EJ, chi_micro, chi_macro, density_exponent, macro_ratio):
        """Virgin loading curve ``M_b(chi) = int rho(phi) min(chi, phi) dphi`` [N m], chi >= 0."""
        p = density_exponent + 1.0
        k_cont = delta_EJ / (1.0 + macro_ratio)
        r = k_cont / _power_integral(chi_micro, chi_macro, p)
        u = np.clip(chi, chi_micro, chi_macro)
        cont = r * (_power_integral(chi_micro, u, p + 1.0) + chi * _power_integral(u, chi_macro, p))
        return cont + (delta_EJ - k_cont) * np.minimum(chi, chi_macro)

    def seen_ratios(self, chi_ref, **params):
        """``macro_ratio``: the point mass over the spread density's mass, of which the bench sees the part above
        ``chi_ref`` (``g = int_max(chi_micro, chi_ref)^chi_macro phi^c / int_chi_micro^chi_macro phi^c``)."""
        ok = self.valid(**params)
        p = {k: np.where(ok, v, 1.0) for k, v in self._arrays(params).items()}
        lo, hi, q = p["chi_micro"], np.where(ok, p["chi_macro"], 2.0), p["density_exponent"] + 1.0
        above = chi_ref < hi
        with np.errstate(divide="ignore", invalid="ignore"):
            g = _power_integral(np.minimum(np.maximum(lo, chi_ref), hi), hi, q) / _power_integral(lo, hi, q)
            out = np.where(above, np.log(g), -np.inf)
        return {"macro_ratio": np.where(ok, out, np.nan)}

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone` (exact for parallel Jenkins elements)."""
        return masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


# --- Iwan with a power-law tail beyond the macro-slip curvature -----------------------------------

@register
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
        DELTA_EJ,
        _CHI_MICRO,
        LawParameter("chi_tail", "1/m", "curvature where the slip-curvature density's power changes to the tail's",
                     prior=_CHI_MACRO.prior),
        _DENSITY_EXPONENT,
        # short of the domain's ends: at -1 the tail's wires would hold infinite rigidity
        LawParameter("tail_exponent", "1", "-5/2 < c_t < -1: density ~ phi^c_t beyond chi_tail", low=-2.5, high=-1.0,
                     prior=("uniform", -2.45, -1.05)),
    )
    ordered: ClassVar[tuple] = (("chi_micro", "chi_tail"),)
    fitted: ClassVar[bool] = True
    summary: ClassVar[str] = "Iwan whose density ends in a power-law tail"
    scale: ClassVar[str] = "chi_tail"
    typical: ClassVar[dict] = dict(_TYPICAL_DENSITY, tail_exponent=-1.5)

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
        return masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)


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


@register
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
        DELTA_EJ,
        LawParameter("chi_median", "1/m", "median slip curvature of the wires"),
        LawParameter("log_spread", "1", "log standard deviation of the slip curvatures (scalar)"),
    )
    scale: ClassVar[str] = "chi_median"
    typical: ClassVar[dict] = {"log_spread": 1.5}

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
        lower = chi_median * np.exp(0.5 * s * s) * special.ndtr(z - s)
        return delta_EJ * (lower + chi * special.ndtr(-z))

    def steady_loop(self, chi_a, theta, **params):
        """Masing's rule on :meth:`backbone`."""
        return masing_loop(lambda x: self.backbone(x, **params), chi_a, theta)
