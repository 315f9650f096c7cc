"""Aeolian vibration of a conductor, the laws the energy balance rests on: the Strouhal band of a wind,
the wind's power (CIGRE and tabulated curves), the bending amplitude near the clamp, the
Poffenberger-Swart stress and the fatigue limit (CIGRE safe border line) (``docs/span.md``)."""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import PchipInterpolator

from ..core.errors import InputError
from .conductor import WIND_CURVES, Conductor


__all__ = [
    "X_B", "strouhal_band", "wind_power_curve", "wind_curve_range", "bending_amplitude", "poffenberger_swart",
    "safe_border_line", "fatigue_limit", "CIGRE_ZERO", "TABLE_SEARCH_MAX", "SAFE_BORDER", "wind_check",
    "turbulence_factor",
]

X_B = 0.089
"""Distance from the last point of contact at which Y_b is taken [m] (pallas-dohl damage.py: xb=0.089)."""

_WIND_HARD = (0.0, 15.0)   # pallas-dohl lifespan.py integrates winds over 0-15 m/s
_WIND_SOFT = (1.0, 7.0)    # seed section 1.1: aeolian vibration comes with winds of 1-7 m/s
# CIGRE cubic for fnc(Y/D) [W m^-1 Hz^-3 m^-4]: Foti & Martinelli (2018) eqs (4)-(5), as coded in
# pallas-dohl src/dohl/ebp.py lines 21-44 (commit 45b6cb9); highest power first.
_CIGRE_POLY = (-99.73, 101.62, 0.1627, 0.2256)
# Above about one diameter the cubic falls to zero (at Y/D ~ 1.02); the seed (section 1.1) gives
# one diameter as the usual largest aeolian amplitude, so Y/D <= 1 is taken as its validity.
_CIGRE_RANGE = (0.0, 1.0)
CIGRE_ZERO = float(max(r.real for r in np.roots(_CIGRE_POLY) if abs(r.imag) < 1e-12 and r.real > 0))

# Digitised wind power curves, (Y/D, fnc) points: EPRI Orange Book tables A2.1-1 and A2.1-2 as
# listed in pallas-dohl src/dohl/wind_power_data.yaml ("ampl", "power"; commit 45b6cb9).
_WIND_TABLES = {
    "farquharson1956": ((0.01, 0.03, 0.06, 0.10), (0.02, 0.11, 0.40, 0.84)),
    "carroll1936": ((0.03, 0.06, 0.10), (0.11, 0.40, 0.85)),
    "rawlins1958": ((0.03, 0.06, 0.10, 0.20), (0.18, 0.50, 1.20, 3.20)),
    "bate1930": ((0.06, 0.10, 0.20), (0.65, 1.60, 3.90)),
    "diana1971": ((0.03, 0.06, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80),
                  (0.23, 0.70, 1.80, 5.00, 9.00, 14.00, 18.00, 20.00, 21.00, 20.00)),
    "brika1995": ((0.01, 0.03, 0.06, 0.10, 0.20, 0.30, 0.40), (0.03, 0.17, 0.49, 1.10, 3.20, 5.50, 6.00)),
    "rawlins1983": ((0.03, 0.06, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70),
                    (0.18, 0.60, 1.60, 4.00, 6.50, 9.00, 10.10, 10.70, 10.80)),
    "pon1989": ((0.01, 0.03, 0.06, 0.10, 0.20, 0.30), (0.04, 0.20, 0.60, 1.50, 3.00, 4.50)),
}
TABLE_SEARCH_MAX = 2.0  # Y/D searched with a tabulated curve (extrapolated past its last point)

# CIGRE safe border lines, (N0, a1, b1, a2, b2): sigma = a1 N^b1 [MPa] for N <= N0, else a2 N^b2.
# EPRI Orange Book, "Safe Border Line Method" p. 3-30, as coded in pallas-dohl src/dohl/damage.py
# (_slc, _mlc, lines 243-276, commit 45b6cb9).
SAFE_BORDER = {
    "single": (2.0e7, 730.0, -0.20, 430.0, -0.17),
    "multi": (1.56e7, 450.0, -0.20, 263.0, -0.17),
}


# ---------------------------------------------------------------------------------------------
# The laws


def wind_check(wind, *, allow_single: bool = False) -> tuple[float, float, list[str]]:
    """(min, max, warnings) of a wind band [m/s]; InputError outside the laws' range."""
    try:
        lo, hi = (float(w) for w in wind)
    except (TypeError, ValueError):
        raise InputError(f"wind: expected two speeds (min, max) in m/s, got {wind!r}") from None
    ordered = lo <= hi if allow_single else lo < hi
    if not (math.isfinite(lo) and math.isfinite(hi) and ordered and _WIND_HARD[0] < lo and hi <= _WIND_HARD[1]):
        raise InputError(f"wind: ({lo:g}, {hi:g}) m/s is outside the wind power laws' range: "
                         f"need {_WIND_HARD[0]:g} < min < max <= {_WIND_HARD[1]:g} m/s")
    warnings = []
    if lo < _WIND_SOFT[0] or hi > _WIND_SOFT[1]:
        warnings.append(f"wind ({lo:g}, {hi:g}) m/s reaches outside {_WIND_SOFT[0]:g}-{_WIND_SOFT[1]:g} m/s, "
                        "where aeolian vibration is usual: the balance there is an extrapolation")
    return lo, hi, warnings


def strouhal_band(conductor: Conductor, wind=(1.0, 7.0), n_freq: int = 60):
    """The vortex-shedding frequencies of a wind band: ``f = S v / D``.

    Parameters
    ----------
    conductor : Conductor
        Supplies D and the Strouhal number S.
    wind : (float, float)
        Lowest and highest wind speed [m/s]; ``0 < min < max <= 15``.
    n_freq : int
        Number of frequencies, equally spaced in wind speed (and so in frequency).

    Returns
    -------
    freq_hz, wind_mps : ndarray, shape (n_freq,)
    """
    lo, hi, _ = wind_check(wind)
    if int(n_freq) != n_freq or n_freq < 2:
        raise InputError(f"n_freq: expected an integer >= 2, got {n_freq!r}")
    v = np.linspace(lo, hi, int(n_freq))
    return conductor.strouhal * v / conductor.diameter_m, v


def wind_curve_range(curve: str) -> tuple[float, float]:
    """The Y/D range over which a reduced wind power curve was measured or fitted."""
    if curve == "cigre":
        return _CIGRE_RANGE
    pts = _WIND_TABLES[curve][0]
    return pts[0], pts[-1]


def _table_curve(curve):
    """log fnc as a function of log(Y/D): PCHIP through the points, straight lines beyond."""
    x, y = np.log(_WIND_TABLES[curve][0]), np.log(_WIND_TABLES[curve][1])
    inner = PchipInterpolator(x, y, extrapolate=False)
    s0, s1 = (y[1] - y[0]) / (x[1] - x[0]), (y[-1] - y[-2]) / (x[-1] - x[-2])

    def fnc(yd):
        u = np.log(yd)
        out = inner(np.clip(u, x[0], x[-1]))
        out = np.where(u < x[0], y[0] + s0 * (u - x[0]), out)
        out = np.where(u > x[-1], y[-1] + s1 * (u - x[-1]), out)
        return np.exp(out)

    return fnc


_TABLE_FNC = {name: _table_curve(name) for name in _WIND_TABLES}
if set(WIND_CURVES) != {"cigre", *_WIND_TABLES}:  # the names the conductor files may use
    raise RuntimeError("sbcal.design.conductor.WIND_CURVES and sbcal.design.vibration's wind curves disagree")


def wind_power_curve(yd, curve: str = "cigre") -> np.ndarray:
    """Reduced wind power ``fnc(Y/D) = P_w / (L f^3 D^4)`` [W m^-1 Hz^-3 m^-4] (smooth flow).

    ``curve="cigre"`` is the cubic of Foti & Martinelli (2018) (the CIGRE fit); the other names
    interpolate digitised EPRI curves (:data:`sbcal.design.conductor.WIND_CURVES`). Outside
    :func:`wind_curve_range` the values are extrapolations.
    """
    yd = np.asarray(yd, dtype=float)
    if curve == "cigre":
        return np.polyval(_CIGRE_POLY, yd)
    return _TABLE_FNC[curve](yd)


def turbulence_factor(iv: float) -> float:
    """Factor (0, 1] by which turbulence intensity ``iv`` scales the wind power input."""
    # Foti & Martinelli (2018) eq. (5) as coded in pallas-dohl ebp.py line 43: I_L = 0.09
    return 1.0 / math.sqrt(1.0 + (iv / 0.09) ** 2)


def _wavenumbers(conductor: Conductor, freq_hz):
    """Roots of ``EJ s^4 - T s^2 - m omega^2 = 0`` with EJ = EJ_min: (a, b) [1/m], decay and wave."""
    omega2 = (2 * np.pi * np.asarray(freq_hz, dtype=float)) ** 2
    t, ej, m = conductor.tension_n, conductor.ej_min_nm2, conductor.mass_kg_per_m
    disc = np.sqrt(t * t + 4 * ej * m * omega2)
    return np.sqrt((t + disc) / (2 * ej)), np.sqrt(2 * m * omega2 / (t + disc))  # b without cancellation


def bending_amplitude(conductor: Conductor, freq_hz, ymax_m, x_m: float = X_B) -> np.ndarray:
    """Peak-to-peak bending amplitude Y_b [m] at ``x_m`` from the last point of contact.

    The free span near a clamp is a tensioned beam (EJ_min) whose displacement and slope vanish at
    the clamp; with the boundary-layer solution that decays into the span (``docs/span.md``)::

        y(x) = Y [sin(b x) - (b/a)(cos(b x) - exp(-a x))] / sqrt(1 + b^2/a^2),   Y_b = 2 |y(x_b)|

    Parameters
    ----------
    freq_hz : array_like, shape (F,)
    ymax_m : array_like, shape (..., F)
        Antinode (0-peak) amplitude Y_max [m].

    Returns
    -------
    ndarray, shape of ``ymax_m``
    """
    a, b = _wavenumbers(conductor, freq_hz)
    r = b / a
    shape = (np.sin(b * x_m) - r * (np.cos(b * x_m) - np.exp(-a * x_m))) / np.sqrt(1 + r * r)
    return 2.0 * np.asarray(ymax_m, dtype=float) * np.abs(shape)


def poffenberger_swart(conductor: Conductor, x_m: float = X_B) -> float:
    """The Poffenberger-Swart factor K [Pa/m]: idealised stress amplitude ``sigma_a = K Y_b``.

    ``K = E_a d p^2 / (4 (exp(-p x) - 1 + p x))``, ``p = sqrt(T / EJ_min)``, with E_a and d the
    outer-layer wires' modulus and diameter and Y_b peak-to-peak at ``x``.
    """
    p = math.sqrt(conductor.tension_n / conductor.ej_min_nm2)
    px = p * x_m
    return conductor.wire_modulus_pa * conductor.wire_diameter_m * p * p / (4.0 * (math.exp(-px) - 1.0 + px))


def safe_border_line(n_cycles, layers: str = "multi") -> np.ndarray:
    """The CIGRE safe border line: the stress amplitude [Pa] a conductor survives for N cycles.

    ``layers`` is ``"single"`` (single aluminium layer ACSR: 730 N^-0.2 MPa up to 2e7 cycles,
    430 N^-0.17 beyond) or ``"multi"`` (450 N^-0.2 up to 1.56e7, 263 N^-0.17 beyond).
    """
    if layers not in SAFE_BORDER:
        raise InputError(f"layers: expected one of {', '.join(SAFE_BORDER)}, got {layers!r}")
    n0, a1, b1, a2, b2 = SAFE_BORDER[layers]
    n = np.asarray(n_cycles, dtype=float)
    return 1e6 * np.where(n <= n0, a1 * n**b1, a2 * n**b2)


def fatigue_limit(conductor: Conductor) -> float:
    """The stress limit [Pa]: the file's endurance limit, else the safe border line at its design cycles."""
    if conductor.endurance_limit_pa is not None:
        return float(conductor.endurance_limit_pa)
    return float(safe_border_line(conductor.design_cycles, conductor.fatigue_layers))
