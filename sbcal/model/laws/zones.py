"""A strand-slip law that changes along the arm: boundary zones at the clamp and at the mass (``docs/cable.md``).

Where the messenger is swaged into the clamp and into the masses the wires are pressed together:
near either end the cable is stiffer when stuck and slips at other curvatures than in its free
middle. :class:`ZonedLaw` gives each arm three zones along its length ``s`` (from the clamp):

==========  ==========================  ==========================================================
zone        where                       law
==========  ==========================  ==========================================================
clamp       ``0 <= s/L < clamp_zone``   the middle's family with ``EJ_min`` and ``delta_EJ`` times the
                                        zone's ratios, every curvature scale of the law (unit 1/m) times
                                        ``moment_ratio / delta_EJ_ratio``
middle      between                     the law of the family's own parameters
mass        ``1 - mass_zone < s/L``     as the clamp zone, with its own ratios
==========  ==========================  ==========================================================

The shape parameters (exponents, sharpness, ratios of the law) are the middle's in every zone: what a
swage changes is how hard the wires are pressed (the stuck and slipped rigidities) and how far they
bend before they slip (the curvature scales), not how the wires' slip curvatures are spread. Ratios
rather than the zones' own values: a ratio of 1 is the uniform law, and in ratios the zones' values
mix less with the middle's. The third ratio is of the slip moment (``delta_EJ`` times a curvature
scale: the moment the wires' friction holds), not of the curvature scale itself: the bench pins the
moment at which a zone slips, and the zone's ``delta_EJ`` and curvature scale trade along it (their
logs correlated -0.99 in the posterior of ``benchmarks/zones_identifiability.py``; ``docs/cable.md``,
"Zones").

The section models use :meth:`ZonedLaw.zones`; :meth:`HysteresisLaw.slip_rigidity` of a zoned law is its
middle's (the curve of the free cable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import HysteresisLaw, LawParameter


__all__ = ["ZONED_SUFFIX", "ZONE_PARAMETERS", "ZONES", "ZonedLaw"]

ZONED_SUFFIX = "_zoned"
"""A zoned family's name is its middle's plus this (``iwan5_zoned``)."""

ZONES = ("middle", "clamp", "mass")
"""The zones, in the order the section models stack their tables."""


def _zone_parameters(zone: str) -> tuple:
    where = "from the clamp" if zone == "clamp" else "from the mass"
    return (
        LawParameter(f"{zone}_zone", "1", f"length of the {zone} zone {where}, as a fraction of the arm", high=0.5),
        LawParameter(f"{zone}_EJ_min_ratio", "1", f"the {zone} zone's EJ_min over the middle's"),
        LawParameter(f"{zone}_delta_EJ_ratio", "1", f"the {zone} zone's delta_EJ over the middle's"),
        LawParameter(f"{zone}_moment_ratio", "1", f"the {zone} zone's slip moments (delta_EJ times each curvature "
                     "scale) over the middle's: its curvature scales are the middle's times moment_ratio / delta_EJ_ratio"),
    )


ZONE_PARAMETERS = _zone_parameters("clamp") + _zone_parameters("mass")
"""The parameters a zoned law adds to its middle's."""


@dataclass(frozen=True)
class ZonedLaw(HysteresisLaw):
    """The law ``base`` in the middle of each arm, scaled versions of it in the clamp and mass zones.

    Attributes
    ----------
    base : HysteresisLaw
        The middle's family.
    """

    base: HysteresisLaw = None

    @property
    def name(self) -> str:
        return self.base.name + ZONED_SUFFIX

    @property
    def parameters(self) -> tuple:
        return self.base.parameters + ZONE_PARAMETERS

    @property
    def ordered(self) -> tuple:
        return self.base.ordered

    @property
    def min_tests(self) -> int:
        """Two tests a cable state at least (as ``iwan_tail``'s tail): at one amplitude the zones trade with
        the middle's law, and the family is compared on all of a damper's states or on none."""
        return max(2, self.base.min_tests)

    def _rigidity(self, chi, **p):
        return self.base._rigidity(chi, **{k: p[k] for k in self.base.parameter_names})

    def steady_loop(self, chi_a: float, theta, **params) -> np.ndarray:
        return self.base.steady_loop(chi_a, theta, **{k: params[k] for k in self.base.parameter_names})

    def seen_ratios(self, chi_ref, **params):
        """The middle's (its shape parameters are every zone's)."""
        return self.base.seen_ratios(chi_ref, **{k: params[k] for k in self.base.parameter_names})

    def zones(self, params: dict) -> list:
        """Per zone of :data:`ZONES`: ``(name, (start, end) as fractions of the arm from the clamp, law
        parameters, EJ_min ratio)``; values broadcast as given (scalars or per parameter set)."""
        base = {k: params[k] for k in self.base.parameter_names}
        units = {p.name: p.unit for p in self.base.parameters}
        clamp, mass = params["clamp_zone"], params["mass_zone"]
        out = [("middle", (clamp, 1.0 - np.asarray(mass)), base, 1.0)]
        for zone, span in (("clamp", (0.0 * np.asarray(clamp), clamp)), ("mass", (1.0 - np.asarray(mass), 1.0))):
            lp = {}
            delta = params[f"{zone}_delta_EJ_ratio"]
            for k, v in base.items():
                if units[k] == "N m^2":
                    v = v * delta
                elif units[k] == "1/m":
                    v = v * (params[f"{zone}_moment_ratio"] / delta)
                lp[k] = v
            out.append((zone, span, lp, params[f"{zone}_EJ_min_ratio"]))
        return out
