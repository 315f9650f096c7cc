"""The hysteresis laws sbcal knows, by name: the one place a law is registered.

A law is one module of :mod:`sbcal.model.laws` holding one :class:`~sbcal.model.laws.base.HysteresisLaw`
subclass decorated with :func:`register`, and its module's name on the import line of the package's
``__init__``. Everything else reads the law from here: the prior of its parameters
(:attr:`LawParameter.prior <sbcal.model.laws.base.LawParameter.prior>`, overridable in
``priors/cable.toml``), ``sbcal cable --law`` and its help (:attr:`~HysteresisLaw.fitted`,
:attr:`~HysteresisLaw.summary`, :attr:`~HysteresisLaw.within`), the virtual bench
(:attr:`~HysteresisLaw.scale`, :attr:`~HysteresisLaw.typical`), the time-domain cable
(:meth:`~HysteresisLaw.time_stepper`) and the units of the diagnosis's words (:func:`parameter_units`).
A script can register a law of its own the same way, before it fits (``docs/cable.md``, "A law of your own").
"""

from __future__ import annotations

import math

from ...core.errors import InputError
from .base import HysteresisLaw, LawParameter
from .zones import ZONE_PARAMETERS, ZONED_SUFFIX, ZonedLaw


__all__ = ["LAWS", "register", "fitted_laws", "law_for", "zoned", "aliases", "parameter_units"]

LAWS: dict = {}
"""Law classes by name, in the order they were registered."""

_DISTS = ("uniform", "loguniform")


def register(law: type) -> type:
    """Add the law class ``law`` to :data:`LAWS` (a class decorator); checks what the rest of sbcal will
    read from it and raises TypeError naming the first gap.

    Parameters
    ----------
    law : type
        A subclass of :class:`HysteresisLaw` with a unique :attr:`~HysteresisLaw.name` and
        :attr:`~HysteresisLaw.parameters`; a fitted one (:attr:`~HysteresisLaw.fitted`) needs a prior box
        on every parameter.

    Returns
    -------
    type
        ``law`` itself.
    """
    where = f"hysteresis law {getattr(law, '__name__', law)!r}"
    if not (isinstance(law, type) and issubclass(law, HysteresisLaw)):
        raise TypeError(f"{where}: not a subclass of HysteresisLaw")
    name = law.name
    if not name or not name.isidentifier() or name.endswith(ZONED_SUFFIX):
        raise TypeError(f"{where}: name {name!r} must be an identifier not ending in {ZONED_SUFFIX}")
    if name in LAWS and LAWS[name] is not law:
        raise TypeError(f"{where}: the name {name!r} is taken by {LAWS[name].__name__}")
    params = law.parameters
    if not params or not all(isinstance(p, LawParameter) for p in params):
        raise TypeError(f"{where}: parameters must be a non-empty tuple of LawParameter")
    names = [p.name for p in params]
    if "delta_EJ" not in names:
        raise TypeError(f"{where}: delta_EJ (the rigidity the slip part adds while the wires stick) is every "
                        "law's first parameter")
    clash = sorted(set(names) & {"EJ_min", "beta_material"} | (set(names) & {p.name for p in ZONE_PARAMETERS}))
    if clash or len(set(names)) != len(names):
        raise TypeError(f"{where}: parameter names must be unique and not the cable's or the zones' "
                        f"({clash[0] if clash else 'a duplicate'})")
    if law.scale not in names or law.scale == "delta_EJ":
        raise TypeError(f"{where}: scale {law.scale!r} must name the parameter that sets the slip curvature")
    shape = set(names) - {"delta_EJ", law.scale}
    if set(law.typical) != shape:
        raise TypeError(f"{where}: typical must give every shape parameter ({', '.join(sorted(shape)) or 'none'}), "
                        f"got {', '.join(sorted(law.typical)) or 'none'}")
    for p in params:
        if p.prior:
            _check_box(where, p)
        elif law.fitted:
            raise TypeError(f"{where}: fitted, but parameter {p.name!r} has no prior box")
    LAWS[name] = law
    return law


def _check_box(where: str, p: LawParameter):
    box = p.prior
    dist, lower, upper = (box + (None, None, None))[:3]
    ok = (len(box) in (3, 4) and dist in _DISTS and all(isinstance(v, (int, float)) and math.isfinite(v)
                                                        for v in (lower, upper)) and lower < upper)
    if len(box) == 4 and box[3] != "of_ej_static":
        ok = False
    if not ok or (dist == "loguniform" and lower <= 0):
        raise TypeError(f"{where}: parameter {p.name!r}: prior must be (dist, lower, upper[, 'of_ej_static']) "
                        f"with dist in {_DISTS}, lower < upper (> 0 for loguniform), got {box!r}")


def fitted_laws() -> tuple:
    """Names of the families a calibration fits and compares, in registration order."""
    return tuple(n for n, law in LAWS.items() if law.fitted)


def aliases() -> dict:
    """``{special case: fitted family that contains it}`` (``dahl`` -> ``bouc_wen``): a law one may name
    where a fitted family is asked for."""
    return {n: law.within for n, law in LAWS.items() if law.within in LAWS}


def law_for(name: str) -> HysteresisLaw:
    """A law instance by name (:data:`LAWS`, or a family of them with ``_zoned``: its
    :class:`sbcal.model.laws.zones.ZonedLaw`); one-line InputError for an unknown name."""
    base = name[:-len(ZONED_SUFFIX)] if name.endswith(ZONED_SUFFIX) else name
    if base not in LAWS:
        raise InputError(f"unknown hysteresis law {name!r}; known: {', '.join(LAWS)} (each also with {ZONED_SUFFIX})")
    return ZonedLaw(LAWS[base]()) if base != name else LAWS[base]()


def zoned(name: str) -> str:
    """The zoned family of the law ``name`` (``iwan5`` -> ``iwan5_zoned``)."""
    return name if name.endswith(ZONED_SUFFIX) else name + ZONED_SUFFIX


def parameter_units() -> dict:
    """``{parameter name: SI unit}`` of every registered law's parameters and the zones'."""
    out = {p.name: p.unit for p in ZONE_PARAMETERS}
    for law in LAWS.values():
        out.update({p.name: p.unit for p in law.parameters})
    return out
