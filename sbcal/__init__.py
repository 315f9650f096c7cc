"""sbcal: Bayesian calibration of Stockbridge damper models from shaker-bench recordings.


Subpackages by concern, each importing only those below it: ``core`` (errors, files, streams),
``data`` (recordings), ``model`` (the physics), ``simulate`` (the virtual bench), ``inference``
(priors, likelihoods, the engine, the run store), ``diagnosis``, ``design`` (new dampers, spans),
``report``; :mod:`sbcal.pipeline` and :mod:`sbcal.cli` on top.
"""

from .core.errors import InputError
from .core.version import __version__
from .model.damper import Damper, load_damper, resolve_damper
from .model.fem import PARAMETER_NAMES, STANDARD_GRID_HZ, clamp_impedance, dynamic_stiffness, natural_frequencies


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
]
