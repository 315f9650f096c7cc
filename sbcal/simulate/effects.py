"""The virtual bench's effects: what the bench adds to the calibration model, each parsed from its command-line
spelling and checked at the door (``docs/virtual_bench.md``, "Effects").

:class:`SlipLaw` (the cable's strand slip: a hysteresis law along both arms, optionally zoned or integrated
in time), :class:`FixtureResonance` (outside the catalogue), the catalogue's scalar effects, and
:func:`parse_effect` (``--effect ID=VALUE``). :mod:`sbcal.simulate.virtual_bench` plays them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..core._io import finite_number
from ..core.errors import InputError
from ..model.cable_element import ElementCableModel
from ..model.cable_time import DEFAULT_STEPS_PER_PERIOD
from ..model.cable_zones import CableZone
from ..model.fem import PARAMETER_NAMES
from ..model.laws import LAWS, law_for
from ..model.laws.zones import ZONE_PARAMETERS, ZONED_SUFFIX


EFFECTS = (
    "strand_slip",
    "fixture_mass",
    "sensor_delay",
    "viscous_damping",
    "asymmetric_damping",
    "base_rocking",
    "frequency_dependent_stiffness",
)
"""Catalogue effect ids (the catalogue of ``docs/diagnose.md``)."""

EXTRA_EFFECTS = ("fixture_resonance",)
"""Selectable effects outside the catalogue (physics no catalogue entry explains)."""



# --- effect descriptions -----------------------------------------------------------------------

_ZONE_RATIOS = ("EJ_min_ratio", "delta_EJ_ratio", "chi_ratio")
BENCH_ELEMENTS = 12
"""Hermite elements per arm of the bench's cable (richer than the fit's :data:`sbcal.model.cable_element.DEFAULT_N_ELEMENTS`)."""
BENCH_SECTIONS = 16
"""Gauss sections per arm of the time-domain bench's cable (:class:`sbcal.model.cable.CableModel`; a zoned
law's middle), richer than the fit's :data:`sbcal.model.cable.DEFAULT_SECTIONS`."""
BENCH_ZONE_SECTIONS = 8
"""Gauss sections of each boundary zone of the time-domain bench's zoned law (the fit's default: 3)."""

BENCH_HARMONICS = 9
"""The force's harmonics the time-domain bench analyses (:func:`sbcal.model.cable_time.time_response`'s default)."""
# effects the time-domain bench refuses, and why: the fast cable has one loss factor and one EJ_min for
# both arms, constant in frequency (a distorted force has harmonics at other frequencies than the line's)
TIME_REFUSED = {
    "asymmetric_damping": "per-arm loss factors",
    "beta1": "per-arm loss factors",
    "beta2": "per-arm loss factors",
    "viscous_damping": "a loss factor that depends on the frequency",
    "frequency_dependent_stiffness": "a rigidity that depends on the frequency",
}


def _family(law: str) -> str:
    """A zoned law's family (``iwan5_zoned`` -> ``iwan5``), else the law."""
    return law[:-len(ZONED_SUFFIX)] if law.endswith(ZONED_SUFFIX) else law


@dataclass(frozen=True)
class SlipLaw:
    """The bench cable's strand slip: a hysteresis law of :mod:`sbcal.model.laws` along both arms.

    The cable is :class:`sbcal.model.cable_element.ElementCableModel` with ``elements`` Hermite elements per arm,
    each with ``EJ*_e = EJ_min (1 + i beta_material) + EJ_slip*(chi_e)``; ``EJ_min`` is the bench's ``EJ``
    parameter and ``beta_material`` its ``beta``. Each run follows the branch a stepped-sine sweep up
    the grid reaches (continuation from line to line).

    Time domain (``time_domain``; ``docs/virtual_bench.md``, "Time domain"): the cable is instead
    :class:`sbcal.model.cable.CableModel` with :data:`BENCH_SECTIONS` Gauss sections per arm
    (:data:`BENCH_ZONE_SECTIONS` per boundary zone of a ``_zoned`` law), integrated from rest with a ramp
    at every line on its own (:func:`sbcal.model.cable_time.time_response`); the reading is the first
    harmonic of the distorted force. It takes neither ``elements`` nor ``zones``.

    A zoned cable (``docs/virtual_bench.md``, "Zoned cables"): ``zones``, boundary zones at the clamp
    and/or the mass with laws of their own (:class:`sbcal.model.cable_zones.CableZone`, any family,
    fixed values), or ``law`` a fitted model's zoned family (``"iwan5_zoned"``: the family's scaled
    versions in zones of :class:`sbcal.model.laws.zones.ZonedLaw`, its parameters in ``params``).

    Attributes
    ----------
    law : str
        ``"lognormal_iwan"`` (the bench's own law, fitted by no family), a fitted family
        (``"bouc_wen"``, ``"iwan5"``, ``"iwan_tail"``), a special case (``"dahl"``, ``"iwan"``), or
        any of these with ``_zoned`` (its zone parameters in ``params``: ``clamp_zone`` and
        ``mass_zone`` required, the ratios default 1).
    params : tuple of (str, float)
        The law's parameters (:attr:`sbcal.model.laws.HysteresisLaw.parameters`); ``delta_EJ``
        defaults to ``ej_static - EJ`` (the stuck cable is the damper's static rigidity), the shape
        parameters to the law's :attr:`~sbcal.model.laws.HysteresisLaw.typical` values (e.g. ``sharpness = 1``
        for bouc_wen, ``log_spread = 1.5`` for lognormal_iwan). The law's curvature scale
        (:attr:`~sbcal.model.laws.HysteresisLaw.scale`: ``chi_slip``, ``chi_macro``, ...) is required.
    elements : int
        Hermite elements per arm (default :data:`BENCH_ELEMENTS`; a zoned cable's in all its zones, at
        least 2 per zone).
    zones : tuple of CableZone
        Boundary zones with laws of their own (at most one per end); ``law`` is the middle's. A zone
        of another family than the middle's gets that family's defaults above and needs its curvature
        scale; its ``delta_EJ`` defaults to the middle's times its ``delta_EJ_ratio``.
    time_domain : bool
        Integrate the fast cable in time and read the first harmonic (above) instead of the element
        model's describing-function steady state.
    steps_per_period : int
        Time steps per period of every line (time domain only; more than twice the 9 harmonics analysed).
    """

    law: str = "lognormal_iwan"
    params: tuple = ()
    elements: int = BENCH_ELEMENTS
    zones: tuple = ()
    time_domain: bool = False
    steps_per_period: int = DEFAULT_STEPS_PER_PERIOD

    def __post_init__(self):
        family = _family(str(self.law))
        if family not in LAWS:
            raise InputError(f"strand_slip: unknown law {self.law!r}; known: {', '.join(LAWS)} "
                             f"(each also with {ZONED_SUFFIX})")
        zoned = family != self.law
        defaults = dict(LAWS[family].typical)
        if zoned:
            defaults.update({p.name: 1.0 for p in ZONE_PARAMETERS if p.name.endswith("_ratio")})
        params = dict(defaults, **dict(self.params))
        model = law_for(self.law)
        unknown = sorted(set(params) - set(model.parameter_names))
        if unknown:
            raise InputError(f"strand_slip: {unknown[0]} is not a parameter of the {self.law} law; "
                             f"known: {', '.join(model.parameter_names)}")
        required = [LAWS[family].scale] + (["clamp_zone", "mass_zone"] if zoned else [])
        for name in required:
            if name not in params:
                raise InputError(f"strand_slip: {name} is required")
        for name, value in params.items():
            v = np.asarray(value, dtype=float)
            if not (np.isfinite(v) and model._domain(name, v)):
                raise InputError(f"strand_slip: {name} is outside the {self.law} law's domain, got {value!r}")
        if int(self.elements) != self.elements or self.elements < 1:
            raise InputError(f"strand_slip: elements must be an integer >= 1, got {self.elements!r}")
        zones = tuple(self.zones or ())
        self._check_time_domain(zones)
        if zones and zoned:
            raise InputError(f"strand_slip: the {self.law} law has its zones in its parameters; "
                             f"give zones with its family ({family})")
        zones = tuple(self._zone_defaults(z) for z in zones)
        object.__setattr__(self, "params", tuple(sorted(params.items())))
        object.__setattr__(self, "elements", int(self.elements))
        object.__setattr__(self, "zones", zones)
        if zones:
            try:
                ElementCableModel(model, n_elements=self.elements, zones=zones)  # checks the zones against the middle
            except InputError as e:
                raise InputError(f"strand_slip: {e}") from None

    def _check_time_domain(self, zones: tuple):
        """The time-domain fields: given only with ``time_domain``, which takes no element-model fields."""
        if not isinstance(self.time_domain, (bool, np.bool_)):
            raise InputError(f"strand_slip: time_domain must be True or False, got {self.time_domain!r}")
        steps = self.steps_per_period
        try:
            whole = not isinstance(steps, (bool, np.bool_)) and int(steps) == steps
        except (TypeError, ValueError, OverflowError):
            whole = False
        if not whole or steps <= 2 * BENCH_HARMONICS:
            raise InputError(f"strand_slip: steps_per_period must be an integer > {2 * BENCH_HARMONICS} "
                             f"(twice the {BENCH_HARMONICS} harmonics analysed), got {steps!r}")
        object.__setattr__(self, "steps_per_period", int(steps))
        object.__setattr__(self, "time_domain", bool(self.time_domain))
        if not self.time_domain:
            if self.steps_per_period != DEFAULT_STEPS_PER_PERIOD:
                raise InputError("strand_slip: steps_per_period is the time-domain bench's; add time:1")
            return
        if self.elements != BENCH_ELEMENTS:
            raise InputError(f"strand_slip: the time-domain bench does not take elements (it integrates the fast "
                             f"model, {BENCH_SECTIONS} Gauss sections per arm)")
        if zones:
            raise InputError(f"strand_slip: the time-domain bench does not take clamp/mass zones (the element "
                             f"model's); give a zoned law, e.g. law:{_family(self.law)}{ZONED_SUFFIX} with "
                             "clamp_zone, mass_zone and their ratios")

    def _zone_defaults(self, zone) -> CableZone:
        if not isinstance(zone, CableZone):
            raise InputError(f"strand_slip: zones must be CableZone values, got {zone!r}")
        if zone.law is None or zone.law == self.law:
            return zone
        if zone.law not in LAWS:
            raise InputError(f"strand_slip: {zone.where} zone: unknown law {zone.law!r}; known: {', '.join(LAWS)}")
        params = dict(LAWS[zone.law].typical, **dict(zone.params))
        return replace(zone, params=tuple(params.items()))

    @property
    def scale_name(self) -> str:
        """The law's curvature scale parameter (scaled by the re-clamping scatter ``chi0_scatter``)."""
        return LAWS[_family(self.law)].scale

    def law_params(self, ej_min, ej_static: float) -> dict:
        """The law's parameters for given ``EJ_min``, with ``delta_EJ`` defaulting to ``ej_static - EJ_min``."""
        p = dict(self.params)
        p.setdefault("delta_EJ", ej_static - np.asarray(ej_min, dtype=float))
        return p


@dataclass(frozen=True)
class FixtureResonance:
    """A fixture mode on the table (not in the catalogue): a mass on a spring, rigid part calibrated out.

    A modal mass ``m_r`` on a spring ``k_r = m_r omega_r^2 (1 + i eta)`` riding on the table adds
    ``-omega^2 m_r k_r / (k_r - omega^2 m_r)``; the empty-table calibration removes its rigid-body
    part ``-omega^2 m_r``, leaving a narrow, passive resonance::

        f_meas = f - m_r omega^4 / (omega_r^2 (1 + i eta) - omega^2)

    Attributes
    ----------
    freq_hz : float
        Fixture natural frequency ``omega_r / 2 pi`` [Hz].
    mass_kg : float
        Modal mass ``m_r`` [kg].
    eta : float
        The fixture's loss factor (narrow resonance: small).
    """

    freq_hz: float
    mass_kg: float = 0.05
    eta: float = 0.05

    def __post_init__(self):
        for name in ("freq_hz", "mass_kg", "eta"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"fixture_resonance: {name} must be finite and > 0, got {v!r}")


_KEYED = {
    "fixture_resonance": (FixtureResonance, "freq_hz", {"f": "freq_hz", "freq_hz": "freq_hz", "m": "mass_kg",
                                                        "mass_kg": "mass_kg", "eta": "eta"}),
}


def parse_effect(spec: str):
    """``"NAME=VALUE"`` to ``(name, value)``, checked.

    Numeric effects take a number (units: see the module table). ``strand_slip`` and
    ``fixture_resonance`` take a number (the default law's ``chi_median`` [1/m], resp. ``freq_hz``)
    or ``key:value`` pairs separated by commas:
    ``strand_slip=law:iwan,chi_macro:0.02,micro_exponent:-0.4,delta_EJ:50,elements:8`` (``law`` one
    of ``lognormal_iwan`` (default), ``dahl``, ``iwan``; the other keys the law's parameters),
    ``fixture_resonance=f:23,m:0.05,eta:0.03``; they return a :class:`SlipLaw` /
    :class:`FixtureResonance`. A zoned cable's boundary zones are the keys ``clamp`` and ``mass``,
    each ``[FAMILY/]LENGTH[/KEY=VALUE...]`` (:class:`sbcal.model.cable_zones.CableZone`: the family
    defaults to the middle's, LENGTH is a fraction of the arm, KEY a parameter of the zone's law or
    ``EJ_min_ratio``, ``delta_EJ_ratio``, ``chi_ratio``):
    ``strand_slip=law:iwan5,chi_macro:0.01,clamp:dahl/0.2/chi_dahl=0.03/delta_EJ_ratio=2/EJ_min_ratio=1.5,mass:0.1/chi_ratio=2``.
    ``time:1`` switches the time-domain bench on (``time:0``, the default, off), ``steps_per_period:N``
    sets its steps (:class:`SlipLaw`): ``strand_slip=law:iwan5_zoned,chi_macro:0.02,clamp_zone:0.2,mass_zone:0.1,time:1``.

    Raises
    ------
    InputError
        One line: unknown effect, malformed spec, non-numeric or out-of-range value.
    """
    name, sep, value = str(spec).partition("=")
    name, value = name.strip(), value.strip()
    known = EFFECTS + EXTRA_EFFECTS
    if not sep or not value:
        raise InputError(f"effect {spec!r}: expected NAME=VALUE")
    if name not in known:
        raise InputError(f"effect {spec!r}: unknown effect {name!r}; known: {', '.join(known)}")
    if name == "strand_slip":
        return name, _parse_slip(spec, value)
    if name in _KEYED:
        cls, first, keys = _KEYED[name]
        kwargs = {}
        if ":" not in value:
            kwargs[first] = finite_number(value, f"effect {spec!r}")
        else:
            for item in value.split(","):
                key, colon, text = item.partition(":")
                key = key.strip()
                if not colon or key not in keys:
                    raise InputError(f"effect {spec!r}: expected key:value pairs with keys {', '.join(keys)}")
                kwargs[keys[key]] = finite_number(text, f"effect {spec!r}")
            if first not in kwargs:
                raise InputError(f"effect {spec!r}: {first} is required")
        try:
            return name, cls(**kwargs)
        except InputError as e:
            raise InputError(f"effect {spec!r}: {str(e).removeprefix(name + ': ')}") from None
    x = finite_number(value, f"effect {spec!r}")
    if name in ("fixture_mass", "sensor_delay") and x < 0:
        raise InputError(f"effect {spec!r}: must be >= 0")
    if name == "viscous_damping" and x <= 0:
        raise InputError(f"effect {spec!r}: the reference frequency must be > 0 Hz")
    return name, x


def _parse_slip(spec: str, value: str) -> SlipLaw:
    """``CHI`` (the default law's curvature scale) or ``law:NAME,elements:N,PARAM:VALUE,...`` with
    optional zones ``clamp:[FAMILY/]LENGTH[/KEY=VALUE...]`` and ``mass:...``, and the time domain's
    ``time:0|1`` and ``steps_per_period:N``."""
    try:
        if ":" not in value:
            return SlipLaw(params=((LAWS[SlipLaw.law].scale, finite_number(value, f"effect {spec!r}")),))
        law, elements, params, zones = SlipLaw.law, BENCH_ELEMENTS, {}, []
        time_domain, steps = False, DEFAULT_STEPS_PER_PERIOD
        for item in value.split(","):
            key, colon, text = (t.strip() for t in item.partition(":"))
            if not colon or not key:
                raise InputError(f"effect {spec!r}: expected key:value pairs (law:NAME, elements:N, law parameters, "
                                 "clamp:ZONE, mass:ZONE, time:0|1, steps_per_period:N)")
            if key == "law":
                law = text
            elif key == "elements":
                elements = finite_number(text, f"effect {spec!r}")
            elif key in ("clamp", "mass"):
                zones.append(_parse_zone(spec, key, text))
            elif key == "time":
                flag = finite_number(text, f"effect {spec!r}: time")
                if flag not in (0, 1):
                    raise InputError(f"effect {spec!r}: time must be 0 or 1, got {text!r}")
                time_domain = flag == 1
            elif key == "steps_per_period":
                steps = finite_number(text, f"effect {spec!r}: steps_per_period")
            else:
                params[key] = finite_number(text, f"effect {spec!r}")
        return SlipLaw(law=law, params=tuple(params.items()), elements=elements, zones=tuple(zones),
                       time_domain=time_domain, steps_per_period=steps)
    except InputError as e:
        text = str(e)
        if text.startswith("effect "):
            raise
        raise InputError(f"effect {spec!r}: {text.removeprefix('strand_slip: ')}") from None


def _parse_zone(spec: str, where: str, text: str) -> CableZone:
    """``[FAMILY/]LENGTH[/KEY=VALUE...]`` of a ``clamp`` or ``mass`` zone."""
    syntax = f"effect {spec!r}: {where} zone {text!r}: expected [FAMILY/]LENGTH[/KEY=VALUE...]"
    parts = [t.strip() for t in text.split("/")]
    if not parts[0]:
        raise InputError(syntax)
    family = None
    try:
        float(parts[0])
    except ValueError:
        family, parts = parts[0], parts[1:]
    if not parts or "=" in parts[0]:
        raise InputError(f"{syntax} (the LENGTH, a fraction of the arm, is missing)")
    length = finite_number(parts[0], f"effect {spec!r}: {where} zone length")
    ratios, params = {}, {}
    for item in parts[1:]:
        key, eq, v = (t.strip() for t in item.partition("="))
        if not eq or not key:
            raise InputError(f"{syntax} (got {item!r})")
        x = finite_number(v, f"effect {spec!r}: {where} zone {key}")
        (ratios if key in _ZONE_RATIOS else params)[key] = x
    return CableZone(where=where, length=length, law=family, params=tuple(params.items()), **ratios)


def check_params(params: dict) -> dict:
    out = dict(params)
    for name, value in out.items():
        if name not in PARAMETER_NAMES:
            raise InputError(f"unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}")
        if name.startswith("q"):
            raise InputError(f"parameter {name!r}: the bench's EJ(omega) is the frequency_dependent_stiffness effect")
        if not np.all(np.isfinite(np.asarray(value, dtype=float))):
            raise InputError(f"parameter {name!r}: value is not finite")
    return out


def check_effects(effects: dict) -> dict:
    out = {}
    for name, value in effects.items():
        if name not in EFFECTS + EXTRA_EFFECTS:
            raise InputError(f"unknown effect {name!r}; known: {', '.join(EFFECTS + EXTRA_EFFECTS)}")
        if name == "strand_slip":
            if not isinstance(value, SlipLaw):
                value = SlipLaw(params=((LAWS[SlipLaw.law].scale, float(value)),))
        elif name in _KEYED:
            cls, first, _ = _KEYED[name]
            if not isinstance(value, cls):
                value = cls(**{first: float(value)})
        else:
            _, value = parse_effect(f"{name}={float(value)!r}")
        out[name] = value
    return out
