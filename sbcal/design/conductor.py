"""Conductor descriptions for the span energy balance: a TOML file to a frozen :class:`Conductor`.

The schema, every default and its source are in ``docs/span.md``. Units are SI except where a
name says otherwise; the self-damping law keeps the units its coefficients were fitted in
(tension in kN, see :data:`SELF_DAMPING_PRESETS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..core._io import bundled_names, name_and_description, read_toml, resolve_bundled
from ..core.errors import InputError
from ..model.damper import checked_number


__all__ = [
    "Conductor",
    "load_conductor",
    "parse_conductor",
    "bundled_conductors",
    "resolve_conductor",
    "lilien_k",
    "SELF_DAMPING_PRESETS",
    "WIND_CURVES",
]

SELF_DAMPING_PRESETS = {
    # name: (l, m, n, label) for P_c = L k Y^l f^m / T^n; exponents as tabulated in pallas-dohl
    # src/dohl/damping_power_data.yaml (commit 45b6cb9), which cites the papers named here.
    "kraus": (2.47, 5.38, 2.80, "Kraus & Hagedorn (1991)"),
    "noiseux1991": (2.44, 5.63, 2.76, "Noiseux (1991)"),
    "mocks": (2.45, 5.38, 2.40, "Moecks & Schmidt (1989)"),
    "pdm": (2.43, 5.50, 2.00, "Mech. Lab Politecnico di Milano (2000)"),
    "seppa": (2.50, 5.75, 2.80, "Seppa (1971)"),
}
"""Self-damping exponents (l on Y [m], m on f [Hz], n on T [kN]) by name."""

WIND_CURVES = ("cigre", "bate1930", "carroll1936", "farquharson1956", "rawlins1958", "diana1971",
               "rawlins1983", "pon1989", "brika1995")
"""Names of the reduced wind-power curves ``fnc(Y/D)`` known to :mod:`sbcal.design.span`."""

_LAYERS = ("single", "multi")


def lilien_k(diameter_m: float, mass_kg_per_m: float, rts_n: float) -> float:
    """Default self-damping coefficient ``k = D[mm] / sqrt(m[kg/m] RTS[kN])``.

    As coded in pallas-dohl ``src/dohl/ebp.py`` (``_k_lilien``, lines 134-135, commit 45b6cb9),
    attributed there to J.-L. Lilien; with it ``P_c`` is in W per metre of span for Y in m,
    f in Hz and T in kN.
    """
    return diameter_m * 1e3 / math.sqrt(mass_kg_per_m * rts_n * 1e-3)


@dataclass(frozen=True)
class Conductor:
    """A conductor strung on one span, with the empirical laws of the energy balance.

    Attributes
    ----------
    name, description, source : str
        Identification; ``source`` is the file read ("" when built in code).
    diameter_m : float
        Outer diameter D [m].
    mass_kg_per_m : float
        Mass per metre m [kg/m].
    rts_n : float
        Rated tensile strength [N].
    tension_n : float
        Everyday (horizontal) tension T [N].
    ej_min_nm2 : float
        Minimum bending stiffness EJ_min [N m^2] (all wires bending independently).
    wire_diameter_m, wire_modulus_pa : float
        Diameter d [m] and Young's modulus E_a [Pa] of the outer-layer wires (Poffenberger-Swart).
    span_length_m : float
        Span length L [m].
    self_damping_k, self_damping_l, self_damping_m, self_damping_n : float
        ``P_c = L k Y^l f^m / T^n`` [W] with Y [m], f [Hz], T [kN].
    self_damping_label : str
        Where the exponents come from.
    wind_curve : str
        One of :data:`WIND_CURVES`.
    turbulence_intensity : float
        I_v; the wind input is multiplied by ``(1 + (I_v / 0.09)^2)^-1/2``.
    strouhal : float
        Strouhal number S of ``f = S v / D``.
    fatigue_layers : str
        ``"single"`` or ``"multi"``: which CIGRE safe border line applies.
    design_cycles : float
        Number of cycles at which the safe border line gives the stress limit.
    endurance_limit_pa : float or None
        When given, the stress limit itself [Pa] (overrides the safe border line); also the service
        life's endurance limit unless ``sn_endurance_limit_pa`` is given (``sbcal.design.life``).
    sn_curve : tuple of (float, float)
        Optional S-N curve for the service life: (cycles, stress amplitude [Pa]) points, cycles
        increasing and stress decreasing, interpolated log-log and extrapolated by the end slopes;
        empty: the CIGRE safe border line of ``fatigue_layers``.
    sn_endurance_limit_pa : float or None
        Optional stress amplitude [Pa] at or below which a cycle does no damage (service life).
    """

    name: str
    diameter_m: float
    mass_kg_per_m: float
    rts_n: float
    tension_n: float
    ej_min_nm2: float
    wire_diameter_m: float
    wire_modulus_pa: float
    span_length_m: float
    self_damping_k: float
    self_damping_l: float = SELF_DAMPING_PRESETS["kraus"][0]
    self_damping_m: float = SELF_DAMPING_PRESETS["kraus"][1]
    self_damping_n: float = SELF_DAMPING_PRESETS["kraus"][2]
    self_damping_label: str = SELF_DAMPING_PRESETS["kraus"][3]
    wind_curve: str = "cigre"
    turbulence_intensity: float = 0.0
    strouhal: float = 0.185
    fatigue_layers: str = "multi"
    design_cycles: float = 5e8
    endurance_limit_pa: float | None = None
    description: str = ""
    source: str = ""
    sn_curve: tuple = ()
    sn_endurance_limit_pa: float | None = None

    @property
    def tension_pct_rts(self) -> float:
        """Tension as a percentage of the rated tensile strength."""
        return 100.0 * self.tension_n / self.rts_n

    @property
    def wave_speed_m_s(self) -> float:
        """Transverse wave speed ``sqrt(T / m)`` of the taut string [m/s]."""
        return math.sqrt(self.tension_n / self.mass_kg_per_m)


def _table(doc: dict, path: str, name: str) -> dict:
    section = doc.get(name, {})
    if not isinstance(section, dict):
        raise InputError(f"{path}: key '{name}': expected a table, got {type(section).__name__}")
    return section


def _get(section: dict, path: str, key: str, full: str, check: str, default=None):
    if key not in section:
        if default is None:
            raise InputError(f"{path}: key '{full}': missing")
        return default
    return checked_number(path, full, section[key], check)


def _choice(section: dict, path: str, key: str, full: str, choices, default: str) -> str:
    value = section.get(key, default)
    if value not in choices:
        raise InputError(f"{path}: key '{full}': expected one of {', '.join(choices)}, got {value!r}")
    return value


def _sn_curve(value, path: str) -> tuple:
    """``[fatigue] sn_curve``: at least two [cycles, stress_pa] pairs, cycles increasing, stress decreasing."""
    key = "fatigue.sn_curve"
    if not isinstance(value, list) or len(value) < 2:
        raise InputError(f"{path}: key '{key}': expected a list of at least two [cycles, stress_pa] pairs, "
                         f"got {value!r}")
    points = []
    for j, pair in enumerate(value):
        if not isinstance(pair, list) or len(pair) != 2:
            raise InputError(f"{path}: key '{key}[{j}]': expected a pair [cycles, stress_pa], got {pair!r}")
        points.append((checked_number(path, f"{key}[{j}][0]", pair[0], "pos"),
                       checked_number(path, f"{key}[{j}][1]", pair[1], "pos")))
    for j in range(1, len(points)):
        if points[j][0] <= points[j - 1][0]:
            raise InputError(f"{path}: key '{key}[{j}]': cycles must increase along the curve, "
                             f"got {points[j][0]:g} after {points[j - 1][0]:g}")
        if points[j][1] >= points[j - 1][1]:
            raise InputError(f"{path}: key '{key}[{j}]': stress must decrease as cycles increase, "
                             f"got {points[j][1]:g} Pa after {points[j - 1][1]:g} Pa")
    return tuple(points)


def parse_conductor(doc: dict, path: str = "<conductor>") -> Conductor:
    """Validate a parsed TOML document and build a :class:`Conductor` (see :func:`load_conductor`)."""
    name, description = name_and_description(doc, path)

    v = {k: _get(doc, path, k, k, "pos") for k in
         ("diameter_m", "mass_kg_per_m", "rts_n", "ej_min_nm2", "span_length_m")}
    has_n, has_pct = "tension_n" in doc, "tension_pct_rts" in doc
    if has_n == has_pct:
        raise InputError(f"{path}: key 'tension_n': give exactly one of tension_n and tension_pct_rts"
                         f" ({'both' if has_n else 'neither'} given)")
    if has_n:
        tension = checked_number(path, "tension_n", doc["tension_n"], "pos")
        if tension >= v["rts_n"]:
            raise InputError(f"{path}: key 'tension_n': {tension:g} N is not below rts_n = {v['rts_n']:g} N")
    else:
        pct = checked_number(path, "tension_pct_rts", doc["tension_pct_rts"], "pos")
        if pct >= 100:
            raise InputError(f"{path}: key 'tension_pct_rts': must be < 100, got {doc['tension_pct_rts']!r}")
        tension = pct / 100.0 * v["rts_n"]

    wire = _table(doc, path, "outer_wire")
    wire_d = _get(wire, path, "diameter_m", "outer_wire.diameter_m", "pos")
    wire_e = _get(wire, path, "modulus_pa", "outer_wire.modulus_pa", "pos")
    if wire_d >= v["diameter_m"]:
        raise InputError(f"{path}: key 'outer_wire.diameter_m': {wire_d:g} m is not below diameter_m")

    sd = _table(doc, path, "self_damping")
    preset = _choice(sd, path, "preset", "self_damping.preset", tuple(SELF_DAMPING_PRESETS), "kraus")
    l0, m0, n0, label = SELF_DAMPING_PRESETS[preset]
    exps = {e: _get(sd, path, e, f"self_damping.{e}", "pos", d) for e, d in (("l", l0), ("m", m0), ("n", n0))}
    if any(e in sd for e in ("l", "m", "n")):
        label = f"{label} with exponents from the file" if "preset" in sd else "exponents from the file"
    k = _get(sd, path, "k", "self_damping.k", "pos", lilien_k(v["diameter_m"], v["mass_kg_per_m"], v["rts_n"]))

    wind = _table(doc, path, "wind")
    curve = _choice(wind, path, "curve", "wind.curve", WIND_CURVES, "cigre")
    iv = _get(wind, path, "turbulence_intensity", "wind.turbulence_intensity", "nonneg", 0.0)
    if iv >= 1:
        raise InputError(f"{path}: key 'wind.turbulence_intensity': must be < 1, got {wind['turbulence_intensity']!r}")
    strouhal = _get(wind, path, "strouhal", "wind.strouhal", "pos", 0.185)
    if not 0.1 <= strouhal <= 0.3:
        raise InputError(f"{path}: key 'wind.strouhal': expected 0.1-0.3 (about 0.185-0.2), got {strouhal:g}")

    fat = _table(doc, path, "fatigue")
    layers = _choice(fat, path, "layers", "fatigue.layers", _LAYERS, "multi")
    cycles = _get(fat, path, "design_cycles", "fatigue.design_cycles", "pos", 5e8)
    limit = (checked_number(path, "fatigue.endurance_limit_pa", fat["endurance_limit_pa"], "pos")
             if "endurance_limit_pa" in fat else None)
    sn_curve = _sn_curve(fat["sn_curve"], path) if "sn_curve" in fat else ()
    sn_limit = (checked_number(path, "fatigue.sn_endurance_limit_pa", fat["sn_endurance_limit_pa"], "pos")
                if "sn_endurance_limit_pa" in fat else None)
    return Conductor(
        name=name, description=description, source=path, tension_n=tension,
        wire_diameter_m=wire_d, wire_modulus_pa=wire_e,
        self_damping_k=k, self_damping_l=exps["l"], self_damping_m=exps["m"], self_damping_n=exps["n"],
        self_damping_label=label, wind_curve=curve, turbulence_intensity=iv, strouhal=strouhal,
        fatigue_layers=layers, design_cycles=cycles, endurance_limit_pa=limit,
        sn_curve=sn_curve, sn_endurance_limit_pa=sn_limit,
        **v,
    )


def load_conductor(path) -> Conductor:
    """Read a conductor description (TOML; schema in ``docs/span.md``).

    Parameters
    ----------
    path : str or path-like
        The TOML file. Extra keys are allowed and ignored.

    Returns
    -------
    Conductor

    Raises
    ------
    InputError
        One line naming the file and key: a missing file or key, malformed TOML, a value that is
        not a number, not finite, not positive; both or neither of ``tension_n`` and
        ``tension_pct_rts``; an unknown preset, wind curve or layer count; an S-N curve whose cycles do
        not increase or whose stresses do not decrease.
    """
    return parse_conductor(read_toml(path), str(Path(path)))


def bundled_conductors() -> list[str]:
    """Names of the conductor descriptions shipped with sbcal (``sbcal/conductors/*.toml``)."""
    return bundled_names("conductors")


def resolve_conductor(name_or_path) -> Conductor:
    """A bundled conductor by name (``drake``) or a description file by path."""
    return resolve_bundled(name_or_path, "conductors", "conductor", load_conductor)
