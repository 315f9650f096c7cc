"""Boundary zones of the element cable model (the virtual bench's): fixed zones with a law of their own,
of any family (:class:`CableZone`), and the zoned mesh (nodes at the zone boundaries).

Richer than the fitted model's zones (:class:`sbcal.model.laws.zones.ZonedLaw`, the middle's family scaled):
the bench can make a cable whose clamp zone follows another law than its middle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .laws import law_for
from .laws.zones import ZONED_SUFFIX


__all__ = ["MIN_ZONE_ELEMENTS", "UNIT_EJ", "UNIT_CHI", "CableZone", "zone_spec", "zoned_mesh"]

MIN_ZONE_ELEMENTS = 2
"""Least number of elements of each zone of a zoned cable (the total per arm is raised to this if needed)."""

UNIT_EJ, UNIT_CHI = "N m^2", "1/m"


@dataclass(frozen=True)
class CableZone:
    """A boundary zone of each arm with a law of its own and fixed parameter values (the element model's).

    Richer than :class:`sbcal.model.laws.zones.ZonedLaw`, whose zones are the middle's family scaled: a
    zone here may follow another family (``dahl`` or ``lognormal_iwan`` where the cable is swaged
    into the clamp, ``iwan5`` in the free middle). Its law parameters are

    - those given in :attr:`params` (fixed values; with :meth:`ElementCableModel.state`'s
      ``zone_scale``, the N m^2 ones times its first factor, the 1/m ones times its second);
    - when the zone's family is the middle's, every other parameter is the middle's (per parameter
      set), ``delta_EJ`` times :attr:`delta_EJ_ratio` and every 1/m parameter times :attr:`chi_ratio`
      (as a :class:`~sbcal.model.laws.zones.ZonedLaw` zone);
    - for another family, ``delta_EJ`` (if not given) is the middle's times :attr:`delta_EJ_ratio`;
      every other parameter must be given.

    The zone's linear part is ``EJ_min * EJ_min_ratio * (1 + i beta_material)`` (or the model's
    ``linear_rigidity`` times the ratio).

    Attributes
    ----------
    where : str
        ``"clamp"`` (``0 <= s/L < length``, s from the clamp) or ``"mass"`` (``1 - length < s/L <= 1``).
    length : float
        The zone's length as a fraction of the arm, in (0, 0.5).
    law : str or None
        Its family (:data:`sbcal.model.laws.LAWS`); None: the middle's.
    params : tuple of (str, float)
        Fixed parameter values of the zone's law (sorted by name once checked).
    EJ_min_ratio, delta_EJ_ratio, chi_ratio : float
        Ratios to the middle's values (> 0); ``delta_EJ_ratio`` only where ``delta_EJ`` is not given,
        ``chi_ratio`` only where the zone takes 1/m parameters from the middle (its family's).
    """

    where: str
    length: float
    law: str | None = None
    params: tuple = ()
    EJ_min_ratio: float = 1.0
    delta_EJ_ratio: float = 1.0
    chi_ratio: float = 1.0

    def __post_init__(self):
        if self.where not in ("clamp", "mass"):
            raise InputError(f"cable zone: where must be 'clamp' or 'mass', got {self.where!r}")
        tag = f"{self.where} zone"
        length = _finite(self.length, f"{tag}: length")
        if not 0 < length < 0.5:
            raise InputError(f"{tag}: length must be a fraction of the arm in (0, 0.5), got {self.length!r}")
        for name in ("EJ_min_ratio", "delta_EJ_ratio", "chi_ratio"):
            v = _finite(getattr(self, name), f"{tag}: {name}")
            if v <= 0:
                raise InputError(f"{tag}: {name} must be > 0, got {v!r}")
            object.__setattr__(self, name, v)
        if self.law is not None:
            if str(self.law).endswith(ZONED_SUFFIX):
                raise InputError(f"{tag}: law {self.law!r} is zoned itself; give a family (e.g. {self.law[:-len(ZONED_SUFFIX)]})")
            try:
                law_for(self.law)
            except InputError as e:
                raise InputError(f"{tag}: {e}") from None
        try:
            params = {str(k): v for k, v in dict(self.params).items()}
        except (TypeError, ValueError):
            raise InputError(f"{tag}: params must be (name, value) pairs, got {self.params!r}") from None
        for k, v in params.items():
            params[k] = _finite(v, f"{tag}: {k}")
        if "delta_EJ" in params and self.delta_EJ_ratio != 1.0:
            raise InputError(f"{tag}: give delta_EJ or delta_EJ_ratio, not both")
        object.__setattr__(self, "length", length)
        object.__setattr__(self, "params", tuple(sorted(params.items())))


def _finite(value, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a number, got {value!r}") from None
    if not np.isfinite(v):
        raise InputError(f"{what}: expected a finite number, got {value!r}")
    return v


@dataclass(frozen=True)
class _ZoneSpec:
    """A :class:`CableZone` checked against the middle's law: its law and where its parameters come from."""

    where: str
    length: float
    law: object  # HysteresisLaw
    fixed: tuple  # (name, value, unit)
    derived: tuple  # (name, unit): taken from the middle, times the ratio of its unit
    EJ_min_ratio: float
    delta_EJ_ratio: float
    chi_ratio: float


def zone_spec(zone: CableZone, middle) -> _ZoneSpec:
    """A zone's law and its given and derived parameters, checked against the middle's law ``middle``."""
    tag = f"{zone.where} zone"
    law = middle if zone.law is None or zone.law == middle.name else law_for(zone.law)
    units = {p.name: p.unit for p in law.parameters}
    given = dict(zone.params)
    unknown = sorted(set(given) - set(units))
    if unknown:
        raise InputError(f"{tag}: {unknown[0]} is not a parameter of the {law.name} law; known: {', '.join(units)}")
    for k, v in given.items():
        if not law._domain(k, np.asarray(v)):
            raise InputError(f"{tag}: {k} is outside the {law.name} law's domain, got {v!r}")
    same = law.name == middle.name
    if same:
        derived = tuple((k, units[k]) for k in law.parameter_names if k not in given)
    else:
        missing = [k for k in law.parameter_names if k not in given and k != "delta_EJ"]
        if missing:
            raise InputError(f"{tag}: the {law.name} law needs {missing[0]} (a zone of another family than the "
                             f"middle's ({middle.name}) takes only delta_EJ from it)")
        derived = (("delta_EJ", UNIT_EJ),) if "delta_EJ" not in given else ()
    if zone.chi_ratio != 1.0 and not any(u == UNIT_CHI for _, u in derived):
        raise InputError(f"{tag}: chi_ratio scales the middle's curvatures, which a {law.name} zone "
                         + ("does not take (another family)" if not same else "does not take (all given)"))
    return _ZoneSpec(where=zone.where, length=zone.length, law=law,
                     fixed=tuple((k, v, units[k]) for k, v in sorted(given.items())), derived=derived,
                     EJ_min_ratio=zone.EJ_min_ratio, delta_EJ_ratio=zone.delta_EJ_ratio, chi_ratio=zone.chi_ratio)


def _allocate(lengths, n: int) -> np.ndarray:
    """Elements per zone: in proportion to its length, at least :data:`MIN_ZONE_ELEMENTS`, ``n`` in
    all where that allows (largest remainders first)."""
    target = n * np.asarray(lengths, dtype=float)
    counts = np.maximum(MIN_ZONE_ELEMENTS, np.floor(target + 1e-9).astype(int))
    while counts.sum() < n:
        counts[np.argmax(target - counts)] += 1
    while counts.sum() > n:
        over = np.where(counts > MIN_ZONE_ELEMENTS, counts - target, -np.inf)
        if not np.isfinite(over).any():
            break
        counts[np.argmax(over)] -= 1
    return counts


def zoned_mesh(clamp: float, mass: float, n: int):
    """Nodes (fractions of the arm from the clamp) with the zone boundaries among them, and each zone's
    elements: ``{"clamp" | "middle" | "mass": slice}`` (a zone of length 0 left out)."""
    spans = [(name, a, b) for name, a, b in (("clamp", 0.0, clamp), ("middle", clamp, 1.0 - mass), ("mass", 1.0 - mass, 1.0))
             if b - a > 0]
    counts = _allocate([b - a for _, a, b in spans], n)
    nodes, slices, start = [np.zeros(1)], {}, 0
    for (name, a, b), m in zip(spans, counts):
        nodes.append(a + (b - a) * np.arange(1, m + 1) / m)
        slices[name] = slice(start, start + m)
        start += m
    mesh = np.concatenate(nodes)
    mesh[-1] = 1.0
    return mesh, slices
