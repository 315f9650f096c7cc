"""Damper descriptions: the TOML contract (``docs/formats.md``, "Damper description") to a frozen
:class:`Damper`.

Units are SI throughout. The parameter names used here (``m1``, ``J1``, ``a1``, ``L1``, ``mu``,
...) are the public vocabulary shared with :mod:`sbcal.model.fem`, the priors and the CLI.
"""

from __future__ import annotations

import difflib
import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

from ..core._io import bundled_names, name_and_description, read_toml, resolve_bundled
from ..core.errors import InputError, InputWarning


__all__ = ["Damper", "GEOMETRY", "load_damper", "parse_damper", "bundled_dampers", "resolve_damper", "FILE_KEYS",
           "DEFAULT_TOLERANCE_PCT", "with_value", "damper_toml", "checked_number", "plausible"]

GEOMETRY = ("m1", "J1", "a1", "m2", "J2", "a2", "mc", "Jc", "ac", "L1", "L2", "mu")
"""The damper's model geometry by name: masses [kg], inertias [kg m^2], offsets [m] of mass 1, mass 2
and the clamp, arm lengths [m] and the cable's mass per length [kg/m] (the fields of :class:`Damper`
that the forward models read, and that a parameter set may override)."""


@dataclass(frozen=True)
class Damper:
    """Nominal description of one Stockbridge damper (SI units).

    Attributes
    ----------
    name : str
        Matches the ``damper`` column of bench recordings.
    m1, J1, a1 : float
        End mass 1 [kg], its inertia about its own centre of mass [kg m^2], and the signed
        offset of its centre of mass from the cable node along y [m].
    m2, J2, a2 : float
        The same for end mass 2 (``a2 < 0`` points towards the clamp).
    mc, Jc, ac : float
        The clamp's mass [kg], inertia [kg m^2] and offset [m].
    L1, L2 : float
        Free cable lengths mass 1 - clamp and clamp - mass 2 [m].
    mu : float
        Messenger cable mass per metre [kg/m].
    ej_static : float
        Full-stick flexural rigidity [N m^2]: the upper bound of EJ and its nominal value.
    description : str
        Free text.
    source : str
        Where the description was read from ("" when built in code).
    tolerance : tuple of (str, float)
        Manufacturing tolerances the file states (its optional ``[tolerance]`` table): pairs
        ``(field, percent)``, a field of this class (``m1``, ``a1``, ``L1`` ...) and its +- tolerance
        in percent of its nominal value, sorted by field. Not part of the model: only predictions
        for a new damper (:mod:`sbcal.design.predict`) use them, with :data:`DEFAULT_TOLERANCE_PCT` for
        the fields not stated (:meth:`tolerances`).
    """

    name: str
    m1: float
    J1: float
    a1: float
    m2: float
    J2: float
    a2: float
    mc: float
    Jc: float
    ac: float
    L1: float
    L2: float
    mu: float
    ej_static: float
    description: str = ""
    source: str = ""
    tolerance: tuple = ()

    def tolerances(self) -> dict:
        """+- tolerance in percent per field: the file's, and :data:`DEFAULT_TOLERANCE_PCT` where it
        states none (fields with 0 are left out)."""
        out = dict(DEFAULT_TOLERANCE_PCT, **dict(self.tolerance))
        return {k: v for k, v in out.items() if v > 0}

    @property
    def total_mass(self) -> float:
        """Total moving mass [kg]: the rigid-body limit of ``-f_uu / omega^2``."""
        return self.m1 + self.m2 + self.mc + self.mu * (self.L1 + self.L2)


# the clamp and both masses are rigid bodies with the same three keys: (key, field prefix, required, check)
_BODY_KEYS = (("mass_kg", "m", True, "pos"), ("inertia_kg_m2", "J", True, "nonneg"), ("offset_m", "a", False, "any"))

# (table, key) -> (Damper field, required, check) ; check in {"pos", "nonneg", "any"}
_FIELDS = tuple((table, key, prefix + suffix, required, check)
                for table, suffix in (("clamp", "c"), ("mass1", "1"), ("mass2", "2"))
                for key, prefix, required, check in _BODY_KEYS) + (
    ("cable", "length1_m", "L1", True, "pos"),
    ("cable", "length2_m", "L2", True, "pos"),
    ("cable", "linear_density_kg_m", "mu", True, "nonneg"),
    ("cable", "ej_static_nm2", "ej_static", True, "pos"),
)


FILE_KEYS = {f"{table}.{key}": field for table, key, field, _, _ in _FIELDS}
"""Damper-file key (``"mass1.offset_m"``) -> :class:`Damper` field (``"a1"``)."""

_CHECKS = {field: check for _, _, field, _, check in _FIELDS}

# field -> (least, largest, unit, what): a value outside is refused as a unit slip (mm or g typed in an SI file),
# with bounds wide enough for any Stockbridge damper (end masses of 0.2-8 kg, arms of 0.1-0.4 m are usual)
_PLAUSIBLE = {
    **{f"m{b}": (0.02, 50.0, "kg", "an end mass") for b in "12"},
    "mc": (0.005, 20.0, "kg", "the clamp"),
    **{f"J{b}": (0.0, 2.0, "kg m^2", "an inertia") for b in "12c"},
    **{f"a{b}": (-0.5, 0.5, "m", "an offset") for b in "12c"},
    **{f"L{b}": (0.01, 2.0, "m", "a cable arm") for b in "12"},
    "mu": (0.0, 20.0, "kg/m", "the messenger cable"),
    "ej_static": (0.05, 1e5, "N m^2", "the messenger's full-stick rigidity"),
}

_TABLES = tuple(dict.fromkeys(table for table, *_ in _FIELDS))  # clamp, mass1, mass2, cable


def _plausible(path: str, key: str, field: str, x: float) -> float:
    return plausible(field, x, f"{path}: key '{key}'", "the file is in SI units")


def plausible(field: str, x: float, where: str, units: str = "in SI units") -> float:
    """``x`` if it lies in the plausible range of the geometry field ``field`` (``"a1"``: an offset within
    0.5 m; :data:`_PLAUSIBLE`), else an InputError naming ``where`` (a file and key, or a command-line
    option) and the likely slip, millimetres or grams typed as metres or kilograms. Fields without a
    range pass."""
    if field not in _PLAUSIBLE:
        return x
    lo, hi, unit, what = _PLAUSIBLE[field]
    if not lo <= x <= hi:
        raise InputError(f"{where}: {x:g} {unit} is outside {lo:g} to {hi:g} {unit}, the plausible range for "
                         f"{what} ({units}: millimetres or grams typed as metres or kilograms?)")
    return x


def _close_keys(path: str, doc: dict) -> dict:
    """Unknown keys of the damper's tables that are one slip from a known one: ``{table.known: table.unknown}``
    (other unknown keys are ignored, as the contract allows)."""
    out = {}
    for table in _TABLES:
        section = doc.get(table)
        if not isinstance(section, dict):
            continue
        known = [k for t, k, *_ in _FIELDS if t == table]
        for key in section:
            if key in known:
                continue
            close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
            if close:
                out[f"{table}.{close[0]}"] = f"{table}.{key}"
    return out

DEFAULT_TOLERANCE_PCT = {"a1": 5.0, "a2": 5.0, "ac": 5.0}
"""Tolerances [+- %] of the fields a damper file's ``[tolerance]`` table does not state: the thesis's
5 % on the centre-of-mass offsets (Table 4.4: a1, a2 within +-5 % of nominal)."""

_NO_TOLERANCE = {"ej_static": "the cable's rigidity comes from its calibration, not from the damper file"}


def _tolerance(doc: dict, path: str) -> tuple:
    """The optional ``[tolerance]`` table: ``"mass1.offset_m" = 5`` (or ``[tolerance.mass1]`` with
    ``offset_m = 5``), percent >= 0 and < 100 of the nominal value; returns sorted (field, percent)."""
    table = doc.get("tolerance")
    if table is None:
        return ()
    if not isinstance(table, dict):
        raise InputError(f"{path}: key 'tolerance': expected a table, got {type(table).__name__}")
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    out = {}
    for key, value in flat.items():
        full = f"tolerance.{key}"
        field = FILE_KEYS.get(key)
        if field is None or field in _NO_TOLERANCE:
            why = _NO_TOLERANCE.get(field) or "unknown key; known: " + ", ".join(
                k for k, f in FILE_KEYS.items() if f not in _NO_TOLERANCE)
            raise InputError(f"{path}: key '{full}': {why}")
        x = checked_number(path, full, value, "nonneg")
        if x >= 100:
            raise InputError(f"{path}: key '{full}': a tolerance in percent must be below 100, got {value!r}")
        out[field] = x
    return tuple(sorted(out.items()))


def with_value(damper: Damper, key: str, value: float, *, where: str | None = None) -> Damper:
    """A copy of ``damper`` with one damper-file field (``"cable.length1_m"``) or :class:`Damper` field
    (``"L1"``) set to ``value``, checked as the file reader checks it (errors name ``where``, default
    the damper's file)."""
    field = FILE_KEYS.get(key, key if key in _CHECKS else None)
    if field is None:
        raise InputError(f"unknown damper field {key!r}; known: {', '.join(FILE_KEYS)}")
    file_key = next(k for k, f in FILE_KEYS.items() if f == field)
    try:
        x = value if isinstance(value, bool) else float(value)  # numpy scalars as plain floats
    except (TypeError, ValueError):
        x = value  # checked_number names the wrong type
    path = where or damper.source or "<damper>"
    return replace(damper, **{field: _plausible(path, file_key, field,
                                                checked_number(path, file_key, x, _CHECKS[field]))})


def damper_toml(damper: Damper, *, comment: str = "") -> str:
    """The damper file (``formats.md`` section 1) of ``damper``: what :func:`parse_damper` reads back
    to an equal :class:`Damper` (but ``source``). Floats are written with ``repr`` (round-trip exact);
    strings as JSON strings, which are TOML basic strings. Hand-written rather than a TOML writer
    library: the file is five tables of numbers, and sbcal depends on none."""
    import json

    lines = [f"# {line}" for line in comment.splitlines()]
    lines += [f"name = {json.dumps(damper.name)}"]
    if damper.description:
        lines.append(f"description = {json.dumps(damper.description)}")
    table = None
    for tbl, key, field, required, _ in _FIELDS:
        value = getattr(damper, field)
        if not required and value == 0.0:
            continue
        if tbl != table:
            lines += ["", f"[{tbl}]"]
            table = tbl
        lines.append(f"{key} = {float(value)!r}")
    if damper.tolerance:
        lines += ["", "[tolerance]"]
        keys = {f: k for k, f in FILE_KEYS.items()}
        lines += [f"{json.dumps(keys[f])} = {float(v)!r}" for f, v in damper.tolerance]
    return "\n".join(lines) + "\n"


def checked_number(path: str, key: str, value, check: str) -> float:
    """A file key's value as a finite float (``check``: ``pos`` > 0, ``nonneg`` >= 0); InputError otherwise."""
    # bool is an int subclass in Python; "true" is not a mass.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{path}: key '{key}': expected a number, got {type(value).__name__} {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise InputError(f"{path}: key '{key}': value {value!r} is not finite")
    if check == "pos" and x <= 0:
        raise InputError(f"{path}: key '{key}': must be > 0, got {value!r}")
    if check == "nonneg" and x < 0:
        raise InputError(f"{path}: key '{key}': must be >= 0, got {value!r}")
    return x


def parse_damper(doc: dict, path: str = "<damper>") -> Damper:
    """Validate a parsed TOML document and build a :class:`Damper` (see :func:`load_damper`)."""
    name, description = name_and_description(doc, path)
    close = _close_keys(path, doc)
    values = {}
    for table, key, field, required, check in _FIELDS:
        full = f"{table}.{key}"
        section = doc.get(table)
        if section is None:
            raise InputError(f"{path}: table '[{table}]': missing")
        if not isinstance(section, dict):
            raise InputError(f"{path}: key '{table}': expected a table, got {type(section).__name__}")
        if key not in section:
            if required:
                hint = f" (the file has '{close[full]}')" if full in close else ""
                raise InputError(f"{path}: key '{full}': missing{hint}")
            values[field] = 0.0
            continue
        values[field] = _plausible(path, full, field, checked_number(path, full, section[key], check))
    damper = Damper(name=name, description=description, source=path, tolerance=_tolerance(doc, path), **values)
    for known, unknown in close.items():  # after every check: a refused file gets one line, its error
        warnings.warn(f"{path}: key '{unknown}': unknown, ignored; did you mean '{known}'?", InputWarning, stacklevel=2)
    return damper


def load_damper(path) -> Damper:
    """Read a damper description (TOML, ``formats.md`` section 1).

    Parameters
    ----------
    path : str or path-like
        The TOML file. Extra keys are allowed and ignored (the contract), except inside the optional
        ``[tolerance]`` table (see :attr:`Damper.tolerance`), whose keys must be damper-file fields; an
        unknown key one slip from a known one (``mass_g`` beside ``mass_kg``) is ignored with an
        :class:`~sbcal.core.errors.InputWarning` naming the known key.

    Returns
    -------
    Damper

    Raises
    ------
    InputError
        One line naming the file and key: missing file or key, malformed TOML, a value of the
        wrong type, a non-positive mass, length or EJ_static, a negative density or inertia, a non-finite value,
        a value outside its plausible range (:data:`_PLAUSIBLE`: a 200 m arm, a 3100 kg mass),
        an unknown key or a value outside [0, 100) in ``[tolerance]``.
    """
    return parse_damper(read_toml(path), str(Path(path)))


def bundled_dampers() -> list[str]:
    """Names of the damper descriptions shipped with sbcal (``sbcal/models/*.toml``)."""
    return bundled_names("models")


def resolve_damper(name_or_path) -> Damper:
    """A bundled damper by name (``damper1``) or a description file by path."""
    return resolve_bundled(name_or_path, "models", "damper", load_damper)
