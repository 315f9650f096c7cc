"""sbcal: Bayesian calibration of Stockbridge dampers from shaker-bench recordings.

Subpackages by concern, each importing only those below it: ``core`` (errors, files, streams),
``data`` (recordings), ``model`` (the physics), ``simulate`` (the virtual bench), ``inference``
(priors, likelihoods, the engine, the run store), ``diagnosis``, ``design`` (new dampers, spans),
``report``; :mod:`sbcal.pipeline` and :mod:`sbcal.cli` on top.

The library API (``docs/api.md``): the forward model is imported with the package; the rest of a
script's names (reading a bench, calibrating, diagnosing, the cable law, predict, span, import) load on
first use.
"""

from .core.errors import InputError
from .core.lazy import lazy_exports
from .core.version import __version__
from .model.damper import Damper, load_damper, resolve_damper
from .model.fem import PARAMETER_NAMES, STANDARD_GRID_HZ, clamp_impedance, dynamic_stiffness, natural_frequencies

_LAZY = {
    # recordings
    "load_bench": ".data.readers", "write_bench": ".data.bench", "clean_bench": ".data.clean_bench",
    "import_recordings": ".data.acquisition.importer", "load_channel_map": ".data.acquisition.channel_map",
    # calibration
    "SamplerConfig": ".inference.sampler", "calibrate_test": ".inference.calibrate", "read_run": ".inference.runs",
    "fit_check": ".inference.fitcheck", "amplitude_map": ".inference.amplitude",
    # missing physics and the cable law
    "diagnose": ".diagnosis.diagnose", "fit_cable": ".inference.cable_fit", "store_cable": ".inference.cable_fit",
    "read_cable": ".inference.cable_fit",
    # using the calibration
    "predict": ".design.predict", "sweep": ".design.sweep", "resolve_conductor": ".design.conductor",
    "FemImpedance": ".design.span", "energy_balance": ".design.span", "optimise_position": ".design.placement",
    "span_study": ".design.span_study", "service_life": ".design.life", "read_acceptance": ".design.acceptance",
    "compare_runs": ".design.compare_runs",
    # the virtual bench
    "BenchConfig": ".simulate.virtual_bench", "record": ".simulate.virtual_bench",
}
__getattr__, __dir__ = lazy_exports(__name__, _LAZY)

__all__ = [
    "__version__",
    "Damper",
    "InputError",
    "PARAMETER_NAMES",
    "STANDARD_GRID_HZ",
    "clamp_impedance",
    "dynamic_stiffness",
    "load_damper",
    "natural_frequencies",
    "resolve_damper",
    *sorted(_LAZY),
]
