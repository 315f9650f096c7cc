"""Using the calibrated cable: a new damper (``predict``), conductors and the span's energy balance
(``docs/predict.md``, ``docs/span.md``)."""

from ..core.lazy import lazy_exports


# Not here, named as their modules (once imported, a package attribute of that name is the
# submodule): predict, sweep, span_study, compare_runs; the top-level package exports them (sbcal.predict, ...).
_LAZY = {
    "resolve_conductor": ".conductor", "FemImpedance": ".span", "energy_balance": ".span",
    "optimise_position": ".placement", "service_life": ".life", "read_acceptance": ".acceptance",
    "compare_characteristics": ".compare",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
__all__ = sorted(_LAZY)
