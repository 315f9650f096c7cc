"""sbcal: Bayesian calibration of Stockbridge damper models from shaker-bench recordings."""

from .damper import Damper, load_damper
from .errors import InputError
from .fem import PARAMETER_NAMES, STANDARD_GRID_HZ, clamp_impedance, dynamic_stiffness, natural_frequencies

__version__ = "0.1.0"

__all__ = [
    "Damper",
    "InputError",
    "PARAMETER_NAMES",
    "STANDARD_GRID_HZ",
    "clamp_impedance",
    "dynamic_stiffness",
    "load_damper",
    "natural_frequencies",
]
