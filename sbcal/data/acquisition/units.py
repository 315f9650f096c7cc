"""Unit names of force and base-motion sensors: the quantity each measures and its factor to SI.

The spelling is tolerant, because each acquisition system writes its own: ``m/s^2``, ``m/s²``,
``m s^-2``, ``m/s2`` and ``m*s**-2`` are one unit; ``µm``, ``μm`` and ``um`` another. SI here is
N, m/s^2, m/s and m.
"""

from __future__ import annotations

import math

from ...core.errors import InputError


__all__ = ["QUANTITIES", "BASE_QUANTITIES", "parse_unit", "same_unit", "known_units"]

QUANTITIES = ("force", "acceleration", "velocity", "displacement")
"""The quantities a sensor may measure (force; base motion in one of the three others)."""

BASE_QUANTITIES = QUANTITIES[1:]
"""What the base channel may measure: acceleration, velocity or displacement."""

_G = 9.80665  # standard gravity [m/s^2]
_INCH = 0.0254  # [m]

# normalised spelling (see _key) -> SI factor, per quantity; the first of each is the one shown in messages
_UNITS = {
    "force": {"N": 1.0, "kN": 1e3, "lbf": 4.4482216152605},
    "acceleration": {"g": _G, "m/s^2": 1.0, "mm/s^2": 1e-3, "in/s^2": _INCH},
    "velocity": {"m/s": 1.0, "mm/s": 1e-3, "in/s": _INCH},
    "displacement": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "in": _INCH},
}
# further spellings of the same units (after _key)
_ALIASES = {
    "newton": "N", "newtons": "N", "gn": "g", "g0": "g",
    "m/s/s": "m/s^2", "ms-2": "m/s^2", "mm/s/s": "mm/s^2", "mms-2": "mm/s^2", "ins-2": "in/s^2",
    "ms-1": "m/s", "mms-1": "mm/s", "ins-1": "in/s", "ips": "in/s",
    "micron": "um", "microns": "um", "inch": "in", "inches": "in",
}


def _key(text: str) -> str:
    """The spelling with the variants removed: lower case, no blanks, no power signs, µ as u."""
    s = text.strip().replace("µ", "u").replace("μ", "u").replace("²", "2").replace("⁻", "-")
    s = s.replace("**", "").replace("^", "").replace("·", "").replace("*", "").replace(".", "")
    return "".join(s.split()).lower()


_LOOKUP = {_key(name): (quantity, factor) for quantity, units in _UNITS.items() for name, factor in units.items()}
_LOOKUP.update({_key(alias): _LOOKUP[_key(name)] for alias, name in _ALIASES.items()})


def known_units(quantity: str | None = None) -> str:
    """The units accepted for ``quantity`` (all quantities when None), for messages: ``"m/s, mm/s, in/s"``."""
    quantities = QUANTITIES if quantity is None else (quantity,)
    return ", ".join(name for q in quantities for name in _UNITS[q])


def parse_unit(text: str) -> tuple[str, float]:
    """The quantity a unit measures and its factor to SI.

    Parameters
    ----------
    text : str
        A unit name, e.g. ``"m/s^2"``, ``"mm s^-1"``, ``"kN"``, ``"µm"``.

    Returns
    -------
    quantity : str
        One of :data:`QUANTITIES`.
    factor : float
        A value in ``text`` times ``factor`` is in N, m/s^2, m/s or m.

    Raises
    ------
    InputError
        One line naming the unknown unit and the known ones (the caller adds the file and key).
    """
    hit = _LOOKUP.get(_key(str(text)))
    if hit is None:
        raise InputError(f"unknown unit '{text}' (known: {known_units()})")
    return hit


def same_unit(a: str, b: str) -> bool:
    """Whether two unit strings name the same unit (``"m/s^2"`` and ``"m s^-2"``: yes; ``"g"`` and
    ``"m/s^2"``: no). Strings that are not known units (a voltage, ``"mV/N"``) are the same only when
    spelt the same, up to case and blanks."""
    ka, kb = _key(a), _key(b)
    if ka in _LOOKUP and kb in _LOOKUP:
        (qa, fa), (qb, fb) = _LOOKUP[ka], _LOOKUP[kb]
        return qa == qb and math.isclose(fa, fb, rel_tol=1e-12)
    return ka == kb
