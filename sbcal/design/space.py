"""A design space (``sbcal design --space SPACE.toml``): which damper-file fields vary, between which
bounds, under which constraints.

::

    [vary]
    "mass1.mass_kg" = [1.0, 3.0]        # the damper file's own words, [lower, upper] (SI, as in the file)
    "cable.length1_m" = [0.15, 0.30]

    [constraints]
    total_mass_kg_max = 6.0             # Damper.total_mass: clamp, both masses and the cable
    arm_length_sum_m_max = 0.55         # length1_m + length2_m

Every other field keeps the starting damper's value.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core._io import read_toml
from ..core.errors import InputError
from ..model.damper import FILE_KEYS, Damper, with_value


__all__ = ["CONSTRAINTS", "DesignSpace", "parse_space", "load_space"]

CONSTRAINTS = {
    "total_mass_kg_max": ("total mass", "kg", lambda d: d.total_mass, 1.0),
    "total_mass_kg_min": ("total mass", "kg", lambda d: d.total_mass, -1.0),
    "arm_length_sum_m_max": ("arm length sum", "m", lambda d: d.L1 + d.L2, 1.0),
    "arm_length_sum_m_min": ("arm length sum", "m", lambda d: d.L1 + d.L2, -1.0),
}
"""Constraint name -> (what, unit, value of a damper, sign): ``sign (value - limit) <= 0`` is feasible."""

# properties of the calibrated messenger cable, not of the damper built with it
_FIXED = {"cable.ej_static_nm2": "the cable's rigidity comes from its calibration",
          "cable.linear_density_kg_m": "the messenger cable's mass per metre is the calibrated cable's"}

_FEASIBILITY_SAMPLES = 4000  # random designs tried (besides the box's corners) before a space is declared empty


@dataclass(frozen=True)
class DesignSpace:
    """The free fields, their bounds and the constraints of a design search.

    Attributes
    ----------
    fields : tuple of str
        Damper-file keys (``"mass1.mass_kg"``), in the file's order.
    lower, upper : tuple of float
        Bounds per field (SI, as in the damper file).
    constraints : tuple of (str, float)
        ``(name, limit)`` of :data:`CONSTRAINTS`.
    source : str
        The file read.
    """

    fields: tuple
    lower: tuple
    upper: tuple
    constraints: tuple = ()
    source: str = ""

    @property
    def bounds(self) -> list:
        return list(zip(self.lower, self.upper))

    def damper(self, start: Damper, x) -> Damper:
        """``start`` with the free fields set to ``x`` (shape (n_fields,))."""
        d = start
        for key, value in zip(self.fields, np.asarray(x, float)):
            d = with_value(d, key, float(value), where=self.source or "<space>")
        return d

    def violations(self, damper: Damper) -> np.ndarray:
        """``sign (value - limit)`` per constraint, shape (n_constraints,): <= 0 where met."""
        return np.array([CONSTRAINTS[n][3] * (CONSTRAINTS[n][2](damper) - lim) for n, lim in self.constraints])

    def feasible(self, damper: Damper) -> bool:
        return bool(np.all(self.violations(damper) <= 1e-12))

    def check_feasible(self, start: Damper, rng) -> None:
        """InputError when no design of the box meets the constraints: its corners (every constraint
        is linear in the fields, so a linear one's least value is at a corner) and random designs."""
        if not self.constraints:
            return
        lo, hi = np.array(self.lower), np.array(self.upper)
        n = len(self.fields)
        corners = np.array(list(itertools.product(*zip(lo, hi)))) if n <= 10 else np.empty((0, n))
        tries = np.vstack([corners, lo + (hi - lo) * rng.random((_FEASIBILITY_SAMPLES, n))])
        viol = np.array([self.violations(self.damper(start, x)) for x in tries])
        if np.any(np.all(viol <= 1e-12, axis=1)):
            return
        never = np.flatnonzero(np.all(viol > 1e-12, axis=0))  # constraints no design meets on its own
        if never.size == 0:
            raise InputError(f"{self.source}: key 'constraints': no design in the box meets them all together")
        name, limit = self.constraints[int(never[0])]
        what, unit, value, sign = CONSTRAINTS[name]
        reach = sign * min(sign * value(self.damper(start, x)) for x in tries)
        raise InputError(f"{self.source}: key 'constraints.{name}': no design in the box meets it "
                         f"({'least' if sign > 0 else 'largest'} {what} {reach:.4g} {unit}, limit {limit:g} {unit})")


def parse_space(doc: dict, start: Damper, path: str = "<space>") -> DesignSpace:
    """Validate a parsed design-space TOML against the starting damper (module docstring).

    Raises
    ------
    InputError
        One line naming the file and key: no ``[vary]`` table or an empty one, an unknown damper field,
        a field of the calibrated cable, bounds that are not two finite numbers, empty or inverted
        bounds, a bound the damper file would refuse (a mass <= 0), an unknown constraint, a limit
        that is not a number.
    """
    vary = doc.get("vary")
    if not isinstance(vary, dict) or not vary:
        raise InputError(f"{path}: table '[vary]': missing or empty (give the free fields, e.g. "
                         "\"mass1.mass_kg\" = [1.0, 3.0])")
    fields, lower, upper = [], [], []
    for key, value in vary.items():
        full = f"vary.{key}"
        if key not in FILE_KEYS:
            raise InputError(f"{path}: key '{full}': unknown damper field; known: "
                             + ", ".join(k for k in FILE_KEYS if k not in _FIXED))
        if key in _FIXED:
            raise InputError(f"{path}: key '{full}': not a design field ({_FIXED[key]})")
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise InputError(f"{path}: key '{full}': expected [lower, upper], two numbers, got {value!r}")
        lo, hi = float(value[0]), float(value[1])
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise InputError(f"{path}: key '{full}': bounds must be finite, got {value!r}")
        if not lo < hi:
            raise InputError(f"{path}: key '{full}': empty or inverted bounds [{lo:g}, {hi:g}] (need lower < upper)")
        for v in (lo, hi):
            with_value(start, key, v, where=f"{path} (vary)")
        fields.append(key)
        lower.append(lo)
        upper.append(hi)
    cons = doc.get("constraints", {})
    if not isinstance(cons, dict):
        raise InputError(f"{path}: key 'constraints': expected a table, got {type(cons).__name__}")
    constraints = []
    for key, value in cons.items():
        if key not in CONSTRAINTS:
            raise InputError(f"{path}: key 'constraints.{key}': unknown constraint; known: {', '.join(CONSTRAINTS)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise InputError(f"{path}: key 'constraints.{key}': expected a number > 0, got {value!r}")
        constraints.append((key, float(value)))
    return DesignSpace(fields=tuple(fields), lower=tuple(lower), upper=tuple(upper), constraints=tuple(constraints),
                       source=path)


def load_space(path, start: Damper) -> DesignSpace:
    """Read a design-space file (module docstring) for the starting damper ``start``."""
    return parse_space(read_toml(path), start, str(Path(path)))
