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

Each family is a small frozen class in a module of its own (:class:`HysteresisLaw` and one subclass
each, as emcee's moves are organised), registered by name in :mod:`~sbcal.model.laws.registry`, with
its parameters' names, units, domains and prior boxes, a vectorised exact describing function
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

The fitted families (:func:`fitted_laws`) are ``bouc_wen`` (Dahl's law with a free sharpness:
``sharpness = 1`` is ``dahl``) and ``iwan5`` (an Iwan law whose slip curvatures spread between two
cut-offs: ``chi_micro -> 0`` is ``iwan``); ``dahl`` and ``iwan`` remain as their special cases, and
``lognormal_iwan`` is the virtual bench's own law, a special case of neither.

``delta_EJ`` is the same thing in every law: the rigidity the slip part adds while the wires stick
(``EJ_max = EJ_min + delta_EJ``). Parameters outside a law's domain give NaN, not an exception, so a
sampler can treat them as outside the support.

A new law is a module here with one :func:`register`-decorated class and its name on the import line
below (``docs/cable.md``, "A law of your own").
"""

from __future__ import annotations

from . import bouc_wen, iwan  # noqa: F401 - the modules whose laws register themselves; a new law's module joins here
from .base import HysteresisLaw, LawParameter, jenkins_rigidity
from .bouc_wen import BoucWenLaw, DahlLaw
from .iwan import Iwan5Law, IwanLaw, IwanTailLaw, LognormalIwanLaw
from .registry import LAWS, aliases, fitted_laws, law_for, parameter_units, register, zoned
from .zones import ZONED_SUFFIX, ZonedLaw


__all__ = [
    "LawParameter", "HysteresisLaw", "DahlLaw", "BoucWenLaw", "IwanLaw", "Iwan5Law", "IwanTailLaw",
    "LognormalIwanLaw", "ZonedLaw", "ZONED_SUFFIX", "LAWS", "register", "fitted_laws", "aliases", "law_for",
    "zoned", "parameter_units", "jenkins_rigidity",
]
