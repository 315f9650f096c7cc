"""The physics: damper descriptions, the 6-DOF finite-element model, the hysteresis laws of the cable,
the distributed cable model and the catalogue of physics extensions (``docs/model.md``, ``docs/cable.md``)."""

from ..core.lazy import lazy_exports

_LAZY = {
    "Damper": ".damper", "load_damper": ".damper", "resolve_damper": ".damper",
    "PARAMETER_NAMES": ".fem", "STANDARD_GRID_HZ": ".fem", "dynamic_stiffness": ".fem",
    "natural_frequencies": ".fem", "clamp_impedance": ".fem",
    "CableModel": ".cable", "HarmonicBalance": ".cable_harmonics", "time_response": ".cable_time",
    "LAWS": ".laws", "HysteresisLaw": ".laws", "LawParameter": ".laws", "register": ".laws",
    "fitted_laws": ".laws", "law_for": ".laws",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
