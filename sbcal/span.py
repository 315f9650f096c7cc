"""A Stockbridge damper on a conductor span: the energy balance method (``docs/span.md``).

For each Strouhal frequency ``f = S v / D`` of the wind band, the antinode amplitude Y_max of the
span's standing wave balances the power the wind puts in against the power the conductor
(self-damping) and the dampers take out::

    L f^3 D^4 fnc(Y/D) = L k Y^l f^m / T^n + P_d(Y)

The damper enters only through its dynamic stiffness ``K* = F/X`` (an :class:`Impedance`). P_d is
either the standing-wave form ``sum_d 0.5 omega Im K*(f, X_d) X_d^2`` with ``X_d = Y |sin(2 pi
x_d / lambda)|``, ``lambda = sqrt(T/m) / f`` (the damper does not move the nodes), or, by default,
the exact power a reflecting termination (clamp plus point dampers on a taut string) absorbs,
which equals it for a light damper. A posterior of S parameter sets gives S balances at once:
arrays are (S, F), draws on axis 0 and frequency last, and the roots are found together by
:func:`scipy.optimize.elementwise.find_root`. From Y_max follow the bending amplitude Y_b at
89 mm from the clamp, the Poffenberger-Swart stress and the margin to the fatigue limit (CIGRE
safe border line).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import elementwise

from .plotting import pyplot, save_png
from .conductor import WIND_CURVES, Conductor
from .damper import Damper
from .errors import InputError
from .fem import dynamic_stiffness
from .labels import parse_label

__all__ = [
    "Impedance",
    "FemImpedance",
    "STATUS",
    "strouhal_band",
    "wind_power_curve",
    "wind_curve_range",
    "bending_amplitude",
    "poffenberger_swart",
    "safe_border_line",
    "fatigue_limit",
    "energy_balance",
    "optimise_position",
    "SpanResult",
    "Placement",
    "plot_span",
    "SPAN_STORE",
    "AMPLITUDE_MARGIN",
    "SpanStudy",
    "span_study",
    "span_dir",
    "store_span",
    "read_span",
    "stored_spans",
]

X_B = 0.089
"""Distance from the last point of contact at which Y_b is taken [m] (pallas-dohl damage.py: xb=0.089)."""

STATUS = ("ok", "extrapolated", "below_range", "no_solution")
"""Status codes of a balance: 0 root inside the wind curve's validity range; 1 root found outside
it (the curve is extrapolated); 2 dissipation exceeds the wind input even at the lowest amplitude
searched (Y_max reported as that amplitude, an upper bound); 3 the wind input exceeds the
dissipation up to the highest amplitude searched (no solution, Y_max NaN, margin 0)."""

_WIND_HARD = (0.0, 15.0)   # pallas-dohl lifespan.py integrates winds over 0-15 m/s
_WIND_SOFT = (1.0, 7.0)    # seed section 1.1: aeolian vibration comes with winds of 1-7 m/s
_WAVES = ("travelling", "standing")
_AMPLITUDE_FLOOR_M = 1e-9  # a damper at a node sees X_d = 0; its K* is evaluated at 1 nm instead

# CIGRE cubic for fnc(Y/D) [W m^-1 Hz^-3 m^-4]: Foti & Martinelli (2018) eqs (4)-(5), as coded in
# pallas-dohl src/dohl/ebp.py lines 21-44 (commit 45b6cb9); highest power first.
_CIGRE_POLY = (-99.73, 101.62, 0.1627, 0.2256)
# Above about one diameter the cubic falls to zero (at Y/D ~ 1.02); the seed (section 1.1) gives
# one diameter as the usual largest aeolian amplitude, so Y/D <= 1 is taken as its validity.
_CIGRE_RANGE = (0.0, 1.0)
_CIGRE_ZERO = float(max(r.real for r in np.roots(_CIGRE_POLY) if abs(r.imag) < 1e-12 and r.real > 0))

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
_TABLE_SEARCH_MAX = 2.0  # Y/D searched with a tabulated curve (extrapolated past its last point)

# CIGRE safe border lines, (N0, a1, b1, a2, b2): sigma = a1 N^b1 [MPa] for N <= N0, else a2 N^b2.
# EPRI Orange Book, "Safe Border Line Method" p. 3-30, as coded in pallas-dohl src/dohl/damage.py
# (_slc, _mlc, lines 243-276, commit 45b6cb9).
_SAFE_BORDER = {
    "single": (2.0e7, 730.0, -0.20, 430.0, -0.17),
    "multi": (1.56e7, 450.0, -0.20, 263.0, -0.17),
}


class Impedance(Protocol):
    """A damper as the span sees it: its dynamic stiffness ``K* = F / X`` at the clamp.

    Called as ``impedance(freq_hz, amplitude_m)`` with ``freq_hz`` of shape (F,) [Hz] and
    ``amplitude_m`` the peak (0-peak) clamp displacement [m] of shape (S, F) or (1, F); returns
    complex ``K*`` [N/m] of shape (S, F), one row per parameter set (posterior draw). Time
    convention ``exp(+i omega t)``: a passive damper has ``Im K* >= 0``. A linear damper ignores
    the amplitude; an amplitude-dependent one must accept any positive amplitude.
    """

    def __call__(self, freq_hz: np.ndarray, amplitude_m: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class FemImpedance:
    """A linear damper from sbcal's 6-DOF model: ``dynamic_stiffness(damper, f, **params)``.

    ``params`` are keyword parameters of :func:`sbcal.fem.dynamic_stiffness` (scalars or arrays of
    shape (S,), e.g. posterior draws of ``EJ`` and ``beta``). The amplitude is ignored.
    Module-level and picklable.
    """

    damper: Damper
    params: dict = field(default_factory=dict)

    def __call__(self, freq_hz, amplitude_m):
        return dynamic_stiffness(self.damper, freq_hz, **self.params)


# ---------------------------------------------------------------------------------------------
# The laws


def _wind_check(wind, *, allow_single: bool = False) -> tuple[float, float, list[str]]:
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
    lo, hi, _ = _wind_check(wind)
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
    raise RuntimeError("sbcal.conductor.WIND_CURVES and sbcal.span's wind curves disagree")


def wind_power_curve(yd, curve: str = "cigre") -> np.ndarray:
    """Reduced wind power ``fnc(Y/D) = P_w / (L f^3 D^4)`` [W m^-1 Hz^-3 m^-4] (smooth flow).

    ``curve="cigre"`` is the cubic of Foti & Martinelli (2018) (the CIGRE fit); the other names
    interpolate digitised EPRI curves (:data:`sbcal.conductor.WIND_CURVES`). Outside
    :func:`wind_curve_range` the values are extrapolations.
    """
    yd = np.asarray(yd, dtype=float)
    if curve == "cigre":
        return np.polyval(_CIGRE_POLY, yd)
    return _TABLE_FNC[curve](yd)


def _turbulence_factor(iv: float) -> float:
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
    if layers not in _SAFE_BORDER:
        raise InputError(f"layers: expected one of {', '.join(_SAFE_BORDER)}, got {layers!r}")
    n0, a1, b1, a2, b2 = _SAFE_BORDER[layers]
    n = np.asarray(n_cycles, dtype=float)
    return 1e6 * np.where(n <= n0, a1 * n**b1, a2 * n**b2)


def fatigue_limit(conductor: Conductor) -> float:
    """The stress limit [Pa]: the file's endurance limit, else the safe border line at its design cycles."""
    if conductor.endurance_limit_pa is not None:
        return float(conductor.endurance_limit_pa)
    return float(safe_border_line(conductor.design_cycles, conductor.fatigue_layers))


# ---------------------------------------------------------------------------------------------
# The balance


def _positions(conductor: Conductor, position_m, ends) -> np.ndarray:
    if ends not in (1, 2):
        raise InputError(f"ends: expected 1 (dampers at one span end) or 2 (both ends), got {ends!r}")
    try:
        x = np.atleast_1d(np.asarray(position_m, dtype=float))
    except (TypeError, ValueError):
        raise InputError(f"position_m: expected a distance in m or a list of them, got {position_m!r}") from None
    if x.ndim != 1 or x.size == 0:
        raise InputError(f"position_m: expected a distance or a flat list of distances, got shape {x.shape}")
    top = conductor.span_length_m / ends
    where = "the span" if ends == 1 else "half the span (dampers at both ends)"
    for xi in x:
        if not (math.isfinite(xi) and 0 < xi < top):
            raise InputError(f"position_m: {xi:g} m is outside {where}: need 0 < x < {top:g} m")
    return x


class _Balance:
    """Powers [W] over the span, vectorised over (S, F), as functions of one unknown per element.

    ``wave="standing"`` (and the bare span): the unknown is ``v = ln Y``; each damper sees the
    undisturbed mode's ``X_d = Y |sin(k x_d)|`` and takes ``0.5 omega Im K* X_d^2``.

    ``wave="travelling"``: the clamp and the dampers terminate the span as point impedances on a
    taut string. The unknown is ``v = ln B``, B the amplitude of ``B sin(k x)`` between the clamp
    and the first damper; outward from there every damper's amplitude, its K* (amplitude-dependent
    or not), the slope jump ``K* phi / T`` and finally the incident and reflected waves beyond the
    last damper follow explicitly: ``Y = |inc| + |ref|`` and the end absorbs
    ``0.5 sqrt(T m) omega^2 (|inc|^2 - |ref|^2)`` (``docs/span.md``). Exact for point dampers of any
    size; equal to the standing-wave form for a light damper.
    """

    def __init__(self, conductor, freq, impedance, positions, ends, wave="travelling"):
        c = self.c = conductor
        self.freq, self.omega = freq, 2 * np.pi * freq
        d = c.diameter_m
        self.a_w = c.span_length_m * freq**3 * d**4 * _turbulence_factor(c.turbulence_intensity)
        self.a_c = c.span_length_m * c.self_damping_k * freq**c.self_damping_m / (c.tension_n * 1e-3) ** c.self_damping_n
        self.impedance, self.ends = impedance, ends
        self.by_clamp = impedance is not None and wave == "travelling"
        self.k = self.omega / c.wave_speed_m_s  # string wavenumber, 2 pi / lambda
        self.zc = math.sqrt(c.tension_n * c.mass_kg_per_m)  # characteristic impedance [N s/m]
        self.positions = positions
        self.sines = np.abs(np.sin(self.k * positions[:, None]))
        self.n_sets, self.linear = (1, True) if impedance is None else (0, False)  # learnt by probe()

    def probe(self):
        """Learn S from a first call, and whether K* depends on the amplitude."""
        a = np.full((1, self.freq.size), 1e-3 * self.c.diameter_m)
        k1 = self.stiffness(a)
        self.n_sets = k1.shape[0]
        self.linear = bool(np.array_equal(k1, self.stiffness(3 * a)))

    def stiffness(self, amplitude):
        """K* of shape (S, F) (or (1, F)) at clamp amplitudes (S or 1, F); checked."""
        k = np.asarray(self.impedance(self.freq, np.maximum(amplitude, _AMPLITUDE_FLOOR_M)))
        if k.ndim != 2 or k.shape[1] != self.freq.size or (self.n_sets and k.shape[0] not in (1, self.n_sets)):
            raise InputError(f"impedance: returned shape {k.shape}, expected (S, {self.freq.size})")
        if not np.all(np.isfinite(k)):
            raise InputError("impedance: returned a non-finite dynamic stiffness")
        bad = k.imag < -1e-9 * np.abs(k)
        if bad.any():
            f = self.freq[np.nonzero(bad)[1][0]]
            raise InputError(f"impedance: Im K* < 0 at {f:.3g} Hz: the damper would feed power into the span "
                             "(not passive; check the time convention exp(+i omega t))")
        return k

    def _from_clamp(self, b):
        """(Y, damper power, amplitudes (J, S, F)) for clamp-side amplitudes B (S, F).

        A short loop over the dampers (a handful), outward from the clamp; each step is vectorised.
        """
        t, k = self.c.tension_n, self.k
        order = np.argsort(self.positions)
        xs = self.positions[order]
        phi, psi = b * np.sin(k * xs[0]) + 0j, b * np.cos(k * xs[0]) + 0j  # psi = phi' / k
        amps = [None] * len(xs)
        for n, j in enumerate(order):
            amps[j] = np.abs(phi)
            psi = psi + self.stiffness(amps[j]) * phi / (t * k)
            if n + 1 < len(xs):
                dl = k * (xs[n + 1] - xs[n])
                phi, psi = phi * np.cos(dl) + psi * np.sin(dl), psi * np.cos(dl) - phi * np.sin(dl)
        y = (np.abs(phi - 1j * psi) + np.abs(phi + 1j * psi)) / 2  # |inc| + |ref|
        # |inc|^2 - |ref|^2 = -Im(phi psi*): the energy flux, without cancellation when ref ~ inc
        flux = np.maximum(-np.imag(phi * np.conj(psi)), 0.0)
        return y, self.ends * 0.5 * self.zc * self.omega**2 * flux, amps

    def _standing(self, y):
        xs = [y * s for s in self.sines]
        return self.ends * sum(0.5 * self.omega * self.stiffness(x).imag * x * x for x in xs), xs

    def evaluate(self, v):
        """(Y, damper power, amplitudes (J, S, F)) for the unknown v (S, F): ln B or ln Y."""
        shape = np.broadcast_shapes(v.shape, (self.n_sets, self.freq.size))
        if self.by_clamp:
            y, pd, xs = self._from_clamp(np.broadcast_to(np.exp(v), shape))
        else:
            y = np.broadcast_to(np.exp(v), shape)
            pd, xs = self._standing(y) if self.impedance is not None else (np.zeros(shape), [])
        return y, np.broadcast_to(pd, shape), np.array([np.broadcast_to(x, shape) for x in xs]).reshape(-1, *shape)

    def conductor_powers(self, y):
        """Wind input and self-damping over the span [W] at antinode amplitude Y."""
        c = self.c
        return self.a_w * wind_power_curve(y / c.diameter_m, c.wind_curve), self.a_c * y**c.self_damping_l

    def unknown_for(self, y, shape):
        """The v that gives antinode amplitude ``y`` (scalar or (S, F)): ln Y, or ln B with the
        ratio Y / B taken at B = y (exact for a linear damper, a first guess otherwise)."""
        ly = np.broadcast_to(np.log(y), shape)
        if not self.by_clamp:
            return np.array(ly)
        return ly - np.log(self.evaluate(ly)[0] / np.exp(ly))


def _scatter(fun, shape):
    """Wrap ``fun`` (whole (S, F) arrays in and out: the impedance protocol evaluates whole arrays)
    for scipy's elementwise root finder, which passes only the elements still active (their flat
    indices ``idx``): they are scattered into a full state array, the rest keep their last values."""
    state = np.zeros(shape)

    def f(v, idx):
        flat = idx.astype(np.intp)
        state.flat[flat] = v
        return fun(state).ravel()[flat]

    return f


def _roots(fun, lo, hi, shape, where=None):
    """Elementwise root of ``fun`` in [lo, hi] (a sign change there) with Chandrupatla's method;
    only where ``where`` (all by default); NaN elsewhere."""
    out = np.full(shape, np.nan)
    sel = np.ones(shape, bool) if where is None else where
    idx = np.flatnonzero(sel).astype(float)
    if idx.size:
        res = elementwise.find_root(_scatter(fun, shape), (lo[sel], hi[sel]), args=(idx,),
                                    tolerances=dict(xatol=1e-11, xrtol=0.0))
        if not np.all(res.success):
            raise RuntimeError(f"energy balance: the bracketing root finder failed (status {np.unique(res.status)})")
        out[sel] = res.x
    return out


_GRID = 48  # points of the search grid for an amplitude-dependent damper


def _solve(bal: _Balance, shape):
    """Y_max (S, F), status codes, damper power and amplitudes at Y_max: ``P_w = P_c + P_d``.

    Bare span or linear damper: ``g = (P_w - P_c - P_d) / (L f^3 D^4)`` crosses zero once between
    the amplitudes Y_lo = 1e-4 D and Y_hi (where the wind curve ends), so the root is bracketed
    there directly. Amplitude-dependent damper: g may cross several times (a nonlinear termination
    can have several states for one amplitude), so it is tabulated on a grid of the unknown and
    the largest amplitude at which the wind input falls below the losses is refined: the
    conservative root.
    """
    c = bal.c
    d = c.diameter_m
    y_lo = 1e-4 * d
    y_hi = d * (_CIGRE_ZERO if c.wind_curve == "cigre" else _TABLE_SEARCH_MAX)
    scale = np.broadcast_to(bal.a_w, shape)  # g is divided by the wind scale: O(1) values

    def g(v):
        y, pd, _ = bal.evaluate(v)
        pw, pc = bal.conductor_powers(y)
        return (pw - pc - pd) / scale

    v_lo, v_hi = bal.unknown_for(y_lo, shape), bal.unknown_for(y_hi, shape)
    if bal.linear:
        below, none = g(v_lo) <= 0, g(v_hi) > 0
        a, b = v_lo, v_hi
        found = ~below & ~none
    else:
        grid = np.linspace(v_lo - 2.0, v_hi + 2.0, _GRID)  # (K, S, F); +-2: the guess of ln B is rough
        gk = np.array([g(v) for v in grid])
        yk = np.array([bal.evaluate(v)[0] for v in grid])
        valid = (yk >= y_lo) & (yk <= y_hi)
        # + to -: a stable balance. The cell's upper end may pass the top of the search: the wind curve
        # is spent there (g < 0), and a balance just under the top would otherwise fall between points
        down = valid[:-1] & (yk[1:] >= y_lo) & (gk[:-1] > 0) & (gk[1:] <= 0)
        found = down.any(axis=0)
        last = (_GRID - 2) - np.argmax(down[::-1], axis=0)               # the largest such cell
        a = np.take_along_axis(grid, last[None], 0)[0]
        b = np.take_along_axis(grid, last[None] + 1, 0)[0]
        top = (_GRID - 1) - np.argmax(valid[::-1], axis=0)              # the largest valid amplitude
        g_top = np.take_along_axis(gk, top[None], 0)[0]
        none = ~found & ((g_top > 0) | ~valid.any(axis=0))
        below = ~found & ~none
        v_lo = np.take_along_axis(grid, np.argmax(valid, axis=0)[None], 0)[0]
    exact = found & (g(b) == 0)
    v = np.where(exact, b, _roots(g, a, b, shape, where=found & ~exact))
    v = np.where(below, v_lo, v)
    y, pd, xs = bal.evaluate(np.where(none, v_lo, v))  # placeholders where there is no solution
    y = np.where(none, np.nan, np.where(below, np.minimum(y, y_lo) if bal.linear else y, y))
    pd = np.where(none, np.nan, pd)
    xs = np.where(none, np.nan, xs)
    vlo, vhi = wind_curve_range(c.wind_curve)
    inside = (y >= vlo * d) & (y <= vhi * d)
    status = np.where(none, 3, np.where(below, 2, np.where(inside, 0, 1))).astype(np.int8)
    return y, status, pd, xs


def energy_balance(conductor: Conductor, impedance: Impedance | None = None, position_m=None, *, ends: int = 1,
                   wind=(1.0, 7.0), n_freq: int = 60, freq_hz=None, wave: str = "travelling") -> SpanResult:
    """Aeolian vibration of a span with dampers, by the energy balance method.

    Parameters
    ----------
    conductor : Conductor
    impedance : Impedance or None
        The damper's dynamic stiffness (see :class:`Impedance`); None for a bare span.
    position_m : float or sequence of float
        Distance of each damper's clamp from the suspension clamp [m] (several values: several
        dampers at the same span end). Required with ``impedance``.
    ends : {1, 2}
        Dampers at one span end, or the same set mirrored at both ends.
    wind : (float, float)
        Wind band [m/s]: ``0 < min < max <= 15`` (else InputError); outside 1-7 m/s a warning.
    n_freq : int
        Frequencies in the band (equally spaced).
    freq_hz : array_like, shape (F,), optional
        Explicit frequencies [Hz] instead of the band; the implied winds ``f D / S`` are checked.
    wave : {"travelling", "standing"}
        How a damper takes power from the span. ``"standing"``: ``0.5 omega Im K* X_d^2`` with
        ``X_d = Y |sin(2 pi x_d / lambda)|`` (the damper does not move the nodes; a warning when
        its loading says otherwise). ``"travelling"`` (default): the clamp and dampers as a
        reflecting termination of a taut string, exact for point dampers of any size, equal to
        the first for a light damper.

    Returns
    -------
    SpanResult
        Per draw and frequency, and the bare span for comparison.
    """
    c = conductor
    if wave not in _WAVES:
        raise InputError(f"wave: expected one of {', '.join(_WAVES)}, got {wave!r}")
    if freq_hz is None:
        freq, wind_mps = strouhal_band(c, wind, n_freq)
        warnings = _wind_check(wind)[2]
    else:
        freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        if freq.ndim != 1 or freq.size == 0 or not np.all(np.isfinite(freq) & (freq > 0)):
            raise InputError("freq_hz: expected positive finite frequencies of shape (F,)")
        wind_mps = freq * c.diameter_m / c.strouhal
        warnings = _wind_check((wind_mps.min(), wind_mps.max()), allow_single=True)[2]
    if (impedance is None) != (position_m is None):
        raise InputError("position_m: give it together with an impedance (a damper), or neither")
    positions = _positions(c, position_m, ends) if impedance is not None else np.zeros(0)

    bare = _Balance(c, freq, None, positions, ends)
    y_bare, st_bare, _, _ = _solve(bare, (1, freq.size))
    pw_bare = bare.conductor_powers(y_bare)[0]

    if impedance is None:
        y, st, bal = y_bare, st_bare, bare
        pd, xd = np.zeros_like(y), np.zeros((0, 1, freq.size))
        loading = np.zeros((1, freq.size))
    else:
        bal = _Balance(c, freq, impedance, positions, ends, wave)
        bal.probe()
        y, st, pd, xd = _solve(bal, (bal.n_sets, freq.size))
        # Im K* sin^2(k x_d) / (omega sqrt(T m)) at the undisturbed mode's amplitudes: the
        # standing-wave damper power over the power a pure travelling wave of amplitude Y carries;
        # above ~0.1 the damper moves the nodes and the two formulations part
        loading = sum(bal.stiffness(np.nan_to_num(y) * s).imag * s * s for s in bal.sines) / (bal.omega * bal.zc)
        loading = np.broadcast_to(loading, y.shape)
        if wave == "standing" and np.max(loading) > 0.1:
            warnings.append(f"damper loading up to {np.max(loading):.2g} (> 0.1): the damper moves the nodes "
                            "and the standing-wave formula misjudges its power; use wave='travelling'")
    pw, pc = bal.conductor_powers(y)
    k_ps = poffenberger_swart(c)
    yb = bending_amplitude(c, freq, y)
    yb_bare = bending_amplitude(c, freq, y_bare)[0]
    if np.any(st == 1):
        warnings.append("the wind power curve is extrapolated at some frequencies (status 'extrapolated')")
    if np.any(st == 3):
        warnings.append("no balance within the searched amplitudes at some frequencies (status 'no_solution')")
    return SpanResult(
        conductor=c, freq_hz=freq, wind_mps=wind_mps, positions_m=tuple(float(x) for x in positions), ends=ends,
        ymax_m=y, status=st, bending_amplitude_m=yb, stress_pa=k_ps * yb,
        p_wind_w=pw, p_self_w=pc, p_damper_w=pd, damper_amplitude_m=xd, damper_loading=loading, wave=wave,
        ymax_bare_m=y_bare[0], status_bare=st_bare[0], bending_amplitude_bare_m=yb_bare,
        stress_bare_pa=k_ps * yb_bare, p_wind_bare_w=pw_bare[0],
        limit_pa=fatigue_limit(c), warnings=tuple(warnings),
    )


def _q(a, axis=0):
    """5 %, 50 %, 95 % quantiles over draws (NaN propagates: it marks an unsolved draw)."""
    return np.quantile(a, [0.05, 0.5, 0.95], axis=axis)


def _jsonable(a):
    """A float or a list of floats, NaN and inf as None."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 0:
        return float(a) if math.isfinite(a) else None
    return [float(x) if math.isfinite(x) else None for x in a.ravel()]


@dataclass(frozen=True, eq=False)
class SpanResult:
    """One energy balance: arrays (S, F) over draws and frequencies, and the bare span's (F,).

    Attributes
    ----------
    conductor : Conductor
    freq_hz, wind_mps : ndarray, shape (F,)
        Frequencies [Hz] and the wind speeds that shed vortices at them [m/s].
    positions_m : tuple of float
        Damper distances from the suspension clamp [m] (empty for a bare span).
    ends : int
        1 or 2 span ends equipped.
    ymax_m : ndarray, shape (S, F)
        Antinode amplitude Y_max [m, 0-peak].
    status : ndarray of int8, shape (S, F)
        Codes of :data:`STATUS`.
    bending_amplitude_m, stress_pa : ndarray, shape (S, F)
        Y_b [m, peak-to-peak at 89 mm] and the Poffenberger-Swart stress amplitude [Pa].
    p_wind_w, p_self_w, p_damper_w : ndarray, shape (S, F)
        Wind input, self-damping and damper dissipation over the span at Y_max [W].
    damper_amplitude_m : ndarray, shape (J, S, F)
        Clamp amplitude X_d of each damper position [m, 0-peak].
    damper_loading : ndarray, shape (S, F)
        ``sum_j Im K*_j sin^2(k x_j) / (omega sqrt(T m))`` per span end: small (< 0.1) for a light
        damper, for which both wave formulations agree.
    wave : str
        ``"travelling"`` or ``"standing"`` (see :func:`energy_balance`).
    ymax_bare_m, status_bare, bending_amplitude_bare_m, stress_bare_pa, p_wind_bare_w : ndarray, shape (F,)
        The same without dampers.
    limit_pa : float
        Stress limit (endurance limit or safe border line at the design cycles) [Pa].
    warnings : tuple of str
    """

    conductor: Conductor
    freq_hz: np.ndarray
    wind_mps: np.ndarray
    positions_m: tuple
    ends: int
    ymax_m: np.ndarray
    status: np.ndarray
    bending_amplitude_m: np.ndarray
    stress_pa: np.ndarray
    p_wind_w: np.ndarray
    p_self_w: np.ndarray
    p_damper_w: np.ndarray
    damper_amplitude_m: np.ndarray
    damper_loading: np.ndarray
    wave: str
    ymax_bare_m: np.ndarray
    status_bare: np.ndarray
    bending_amplitude_bare_m: np.ndarray
    stress_bare_pa: np.ndarray
    p_wind_bare_w: np.ndarray
    limit_pa: float
    warnings: tuple = ()

    @property
    def n_draws(self) -> int:
        return self.ymax_m.shape[0]

    @property
    def n_dampers(self) -> int:
        return len(self.positions_m) * self.ends

    @property
    def wavelength_m(self) -> np.ndarray:
        """Wavelength of the taut string, ``sqrt(T/m) / f`` [m], shape (F,)."""
        return self.conductor.wave_speed_m_s / self.freq_hz

    @property
    def margin(self) -> np.ndarray:
        """Worst-case margin over the band per draw, ``limit / max_f stress``, shape (S,) (0 if unsolved)."""
        worst = np.max(np.where(np.isnan(self.stress_pa), np.inf, self.stress_pa), axis=1)
        return self.limit_pa / worst

    @property
    def margin_bare(self) -> float:
        s = self.stress_bare_pa
        return float(self.limit_pa / np.max(np.where(np.isnan(s), np.inf, s)))

    @property
    def flags(self) -> list[str]:
        """Per frequency: the worst status over draws."""
        return [STATUS[i] for i in self.status.max(axis=0)]

    def to_frame(self):
        """One row per frequency: medians and 90 % bands over draws (Y_max, Y_b, stress, powers), and
        the bare span (Y_max, Y_b, stress, wind power). A DataFrame."""
        import pandas as pd

        cols = {"frequency_hz": self.freq_hz, "wind_m_s": self.wind_mps, "wavelength_m": self.wavelength_m}
        for name, arr, unit in (("ymax", self.ymax_m, "m"), ("bending_amplitude", self.bending_amplitude_m, "m"),
                                ("stress", self.stress_pa * 1e-6, "mpa")):
            lo, mid, hi = _q(arr)
            cols |= {f"{name}_median_{unit}": mid, f"{name}_q05_{unit}": lo, f"{name}_q95_{unit}": hi}
        cols |= {"ymax_bare_m": self.ymax_bare_m, "bending_amplitude_bare_m": self.bending_amplitude_bare_m,
                 "stress_bare_mpa": self.stress_bare_pa * 1e-6}
        for name, arr in (("p_wind", self.p_wind_w), ("p_self", self.p_self_w), ("p_damper", self.p_damper_w)):
            lo, mid, hi = _q(arr)
            cols |= {f"{name}_median_w": mid, f"{name}_q05_w": lo, f"{name}_q95_w": hi}
        cols["p_wind_bare_w"] = self.p_wind_bare_w  # = the bare span's self-damping at its balance
        for j in range(len(self.positions_m)):
            cols[f"damper{j + 1}_amplitude_median_m"] = np.median(self.damper_amplitude_m[j], axis=0)
        cols["damper_loading_median"] = np.median(self.damper_loading, axis=0)
        cols |= {"flag": self.flags, "n_extrapolated": (self.status == 1).sum(axis=0),
                 "n_below_range": (self.status == 2).sum(axis=0), "n_no_solution": (self.status == 3).sum(axis=0),
                 "flag_bare": [STATUS[i] for i in self.status_bare]}
        return pd.DataFrame(cols)

    def to_dict(self) -> dict:
        """A JSON-ready summary (NaN as null)."""
        from pandas.api.types import is_numeric_dtype

        c = self.conductor
        m = self.margin
        frame = self.to_frame()
        return {
            "conductor": {"name": c.name, "diameter_m": c.diameter_m, "tension_n": c.tension_n,
                          "tension_pct_rts": c.tension_pct_rts, "span_length_m": c.span_length_m,
                          "wind_curve": c.wind_curve, "self_damping": c.self_damping_label},
            "positions_m": list(self.positions_m), "ends": self.ends, "n_dampers": self.n_dampers, "wave": self.wave,
            "n_draws": self.n_draws, "limit_mpa": self.limit_pa * 1e-6,
            "margin": {"median": _jsonable(np.median(m)), "q05": _jsonable(np.quantile(m, 0.05)),
                       "q95": _jsonable(np.quantile(m, 0.95)),
                       "median_db": _jsonable(20 * np.log10(np.median(m))) if np.median(m) > 0 else None},
            "margin_bare": _jsonable(self.margin_bare),
            "per_frequency": {k: (_jsonable(v.to_numpy(dtype=float)) if is_numeric_dtype(v) else [str(x) for x in v])
                              for k, v in frame.items()},
            "warnings": list(self.warnings),
        }


# ---------------------------------------------------------------------------------------------
# Placement


@dataclass(frozen=True, eq=False)
class Placement:
    """Worst-case margin over the band against the damper position.

    Attributes
    ----------
    positions_m : ndarray, shape (P,)
        Positions evaluated [m from the suspension clamp].
    margin : ndarray, shape (P,)
        The ``quantile`` of the worst-case margin over draws, per position.
    margin_median : ndarray, shape (P,)
    quantile : float
    ends : int
    best_position_m, best_margin : float
        The position with the largest ``margin`` and that margin.
    suffices : bool
        ``best_margin >= 1``: this many dampers (``ends``) keep the stress under the limit.
    best : SpanResult
        The balance at the best position.
    """

    positions_m: np.ndarray
    margin: np.ndarray
    margin_median: np.ndarray
    quantile: float
    ends: int
    best_position_m: float
    best_margin: float
    suffices: bool
    best: SpanResult

    def to_frame(self):
        import pandas as pd

        return pd.DataFrame({"position_m": self.positions_m, f"margin_q{round(100 * self.quantile):02d}": self.margin,
                             "margin_median": self.margin_median})

    def to_dict(self) -> dict:
        return {"positions_m": _jsonable(self.positions_m), "margin": _jsonable(self.margin),
                "margin_median": _jsonable(self.margin_median), "quantile": self.quantile, "ends": self.ends,
                "best_position_m": self.best_position_m, "best_margin": _jsonable(self.best_margin),
                "suffices": self.suffices}


def optimise_position(conductor: Conductor, impedance: Impedance, positions_m=None, *, ends: int = 1,
                      quantile: float = 0.1, wind=(1.0, 7.0), n_freq: int = 60, freq_hz=None,
                      wave: str = "travelling") -> Placement:
    """The damper position that maximises the worst-case margin over the band.

    One damper per equipped span end. Each position is a full vectorised balance over draws and
    frequencies; positions are a short outer design loop.

    Parameters
    ----------
    positions_m : array_like, shape (P,), optional
        Candidate distances from the suspension clamp [m]; default 40 points from 5 % to 100 % of
        the shortest wavelength of the band (within the span).
    quantile : float
        Which quantile over draws of the worst-case margin is maximised (0.1: the margin that 90 %
        of the posterior exceeds; 0.5: the median).
    ends, wind, n_freq, freq_hz, wave
        As in :func:`energy_balance`.
    """
    if not 0 < quantile < 1:
        raise InputError(f"quantile: expected a number in (0, 1), got {quantile!r}")
    if positions_m is None:
        freq = strouhal_band(conductor, wind, n_freq)[0] if freq_hz is None else np.asarray(freq_hz, float)
        lam_min = conductor.wave_speed_m_s / np.max(freq)
        top = conductor.span_length_m / (ends if ends in (1, 2) else 1)
        positions_m = np.linspace(0.05, 1.0, 40) * min(lam_min, 0.99 * top)
    pos = np.atleast_1d(np.asarray(positions_m, dtype=float))
    _positions(conductor, pos, ends)
    margins, medians, results = [], [], []
    for x in pos:
        r = energy_balance(conductor, impedance, float(x), ends=ends, wind=wind, n_freq=n_freq, freq_hz=freq_hz,
                           wave=wave)
        m = r.margin
        margins.append(float(np.quantile(m, quantile)))
        medians.append(float(np.median(m)))
        results.append(r)
    margins = np.array(margins)
    i = int(np.argmax(margins))
    return Placement(positions_m=pos, margin=margins, margin_median=np.array(medians), quantile=quantile,
                     ends=ends, best_position_m=float(pos[i]), best_margin=float(margins[i]),
                     suffices=bool(margins[i] >= 1.0), best=results[i])


# ---------------------------------------------------------------------------------------------
# Plot


def plot_span(result: SpanResult, path, *, placement: Placement | None = None) -> None:
    """Y_max/D and stress against frequency with and without the dampers, the powers, and (with
    ``placement``) the margin against position; one PNG written atomically."""
    plt = pyplot()
    r, d = result, result.conductor.diameter_m
    f = r.freq_hz
    n = 4 if placement is not None else 3
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.0))
    label = f"{r.n_dampers} damper(s) at {', '.join(f'{x:.2f}' for x in r.positions_m)} m" if r.positions_m else ""

    ax = axes[0]
    ax.plot(f, r.ymax_bare_m / d, "k--", lw=1, label="no damper")
    if r.positions_m:
        lo, mid, hi = _q(r.ymax_m / d)
        ax.fill_between(f, lo, hi, color="C0", alpha=0.25)
        ax.plot(f, mid, color="C0", label=f"{label} (median, 90 %)")
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="Y_max / D", title="Antinode amplitude")

    ax = axes[1]
    ax.plot(f, r.stress_bare_pa * 1e-6, "k--", lw=1, label="no damper")
    if r.positions_m:
        lo, mid, hi = _q(r.stress_pa * 1e-6)
        ax.fill_between(f, lo, hi, color="C0", alpha=0.25)
        ax.plot(f, mid, color="C0", label="with dampers (median, 90 %)")
    ax.axhline(r.limit_pa * 1e-6, color="C3", lw=1, label=f"limit {r.limit_pa * 1e-6:.1f} MPa")
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="stress amplitude [MPa]",
           title="Poffenberger-Swart stress at 89 mm")

    ax = axes[2]
    ax.plot(f, r.p_wind_bare_w, "k--", lw=1, label="wind = self-damping, no damper")
    for arr, name, color in ((r.p_wind_w, "wind input", "C0"), (r.p_self_w, "self-damping", "C1"),
                             (r.p_damper_w, "dampers", "C2")):
        if name == "dampers" and not r.positions_m:
            continue
        ax.plot(f, np.median(arr, axis=0), color=color, label=name)
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="power over the span [W]", title="Powers at Y_max (median)")

    if placement is not None:
        ax = axes[3]
        q = round(100 * placement.quantile)
        ax.plot(placement.positions_m, placement.margin, "o-", color="C0", ms=3, label=f"{q} % quantile over draws")
        ax.plot(placement.positions_m, placement.margin_median, color="C0", lw=1, alpha=0.5, label="median")
        ax.axhline(1.0, color="C3", lw=1, label="margin 1")
        ax.axvline(placement.best_position_m, color="k", lw=0.8, ls=":")
        ax.set(xlabel="damper position from the clamp [m]", ylabel="worst-case margin over the band",
               title=f"Placement ({placement.ends} end(s))")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


# ---------------------------------------------------------------------------------------------
# A study (``sbcal span``): a stored damper on a conductor, stored and read back

SPAN_STORE = "span"
"""The run store's directory of span studies: ``<runs>/span/<label>/`` (:func:`span_dir`)."""

AMPLITUDE_MARGIN = 0.10
"""A damper's clamp amplitude counts as beyond the calibration when it exceeds the largest amplitude
of the cable run's tests by more than this fraction (the law is extrapolated there: a warning)."""

_NO_DAMPER = ("none", "")


@dataclass(frozen=True, eq=False)
class SpanStudy:
    """The energy balance of one conductor with one damper design, and where the damper came from.

    Attributes
    ----------
    result : SpanResult
        At the given position (or, with a placement and no position, at the best position).
    placement : Placement or None
        The margin against position (``optimise``).
    damper : str
        The damper's name; ``"none"`` for a bare span.
    cable : str
        The stored cable-law run the damper's impedance comes from ("" for a bare span).
    cable_damper, state, law : str
        That run's calibration damper, cable state and law family.
    seed : int
        Seed of the posterior subset and the geometry draws.
    calibrated_amplitude_mm_pp : tuple of float
        Least and largest clamp amplitude of the cable run's tests [mm p-p] (empty without a damper).
    extrapolated_hz : tuple of float
        Frequencies at which the median over draws of the dampers' largest clamp amplitude exceeds
        the calibrated range by more than :data:`AMPLITUDE_MARGIN`.
    warnings : tuple of str
        The balance's and the study's (cable posterior not converged, law extrapolated).
    """

    result: SpanResult
    placement: Placement | None = None
    damper: str = "none"
    cable: str = ""
    cable_damper: str = ""
    state: str = ""
    law: str = ""
    seed: int = 0
    calibrated_amplitude_mm_pp: tuple = ()
    extrapolated_hz: tuple = ()
    warnings: tuple = ()

    @property
    def label(self) -> str:
        """``<conductor>-<damper>[-<cable damper>]-<state>[-2ends]``, or ``<conductor>-bare``."""
        parts = [self.result.conductor.name]
        if self.cable:
            parts += [self.damper] + ([self.cable_damper] if self.cable_damper != self.damper else []) + [self.state]
        else:
            parts.append("bare")
        if self.result.ends == 2:
            parts.append("2ends")
        return re.sub(r"[^A-Za-z0-9._-]+", "_", "-".join(parts))

    def worst_stress_mpa(self) -> dict:
        """Largest stress over the band [MPa]: with the dampers (median, 5 %, 95 % over draws) and bare."""
        r = self.result
        worst = r.limit_pa / r.margin * 1e-6  # margin = limit / max stress; an unsolved draw gives inf
        return {"median": _jsonable(np.median(worst)), "q05": _jsonable(np.quantile(worst, 0.05)),
                "q95": _jsonable(np.quantile(worst, 0.95)), "bare": _jsonable(r.limit_pa / r.margin_bare * 1e-6)}

    def to_dict(self) -> dict:
        """JSON-ready: the source of the damper, :meth:`SpanResult.to_dict` and the placement."""
        doc = {"label": self.label, "damper": self.damper, "cable": self.cable, "cable_damper": self.cable_damper,
               "state": self.state, "law": self.law, "seed": self.seed,
               "calibrated_amplitude_mm_pp": list(self.calibrated_amplitude_mm_pp),
               "extrapolated_hz": list(self.extrapolated_hz)}
        doc |= self.result.to_dict()
        doc["worst_stress_mpa"] = self.worst_stress_mpa()
        doc["placement"] = self.placement.to_dict() if self.placement is not None else None
        doc["warnings"] = list(self.warnings)
        return doc


def _damper_source(damper, cable):
    """(CableRun or None, Damper or None) from the study's ``damper`` and ``cable`` arguments."""
    from .damper import resolve_damper
    from .predict import load_cable_run

    bare = damper is None or (isinstance(damper, str) and damper.strip().lower() in _NO_DAMPER)
    if bare:
        if cable is not None:
            raise InputError("damper: a cable run was given without a damper; give the new damper's file with it, "
                             "or the run itself as the damper")
        return None, None
    if not isinstance(damper, Damper) and Path(str(damper)).is_dir():
        if cable is not None:
            raise InputError(f"damper: {damper} is a stored cable run, which brings its own damper; give a damper "
                             "file instead to build a new damper with the cable run")
        run = load_cable_run(damper)
        if run.calibration is None:
            raise InputError(f"{run.path}/summary.json: key 'damper_values': missing, so the run's damper is unknown; "
                             "give the damper's file as the damper and this run as the cable")
        return run, run.calibration
    d = damper if isinstance(damper, Damper) else resolve_damper(damper)
    if cable is None:
        where = d.source or d.name
        raise InputError(f"{where}: damper {d.name!r} has no cable law: give a stored cable fit with it "
                         "(cable=RUN, sbcal span --cable RUN, e.g. runs/damper1/cable-dry)")
    return load_cable_run(cable), d


def _calibrated_amplitudes(run) -> tuple:
    """(least, largest) amplitude [mm p-p] of a cable run's tests, from their labels ``A-B``."""
    labels = (parse_label(t) for t in run.summary.get("tests", []))
    amps = [a for p in labels if p for a in p.amplitudes]
    return (min(amps), max(amps)) if amps else ()


def span_study(conductor, damper=None, *, cable=None, position_m=None, ends: int = 1, wind=(1.0, 7.0),
               n_freq: int = 60, n_draws: int = 200, seed: int = 0, optimise: bool = False, positions_m=None,
               quantile: float = 0.1, wave: str = "travelling", search_draws: int = 40) -> SpanStudy:
    """One conductor, one damper design from a stored cable fit (or none): the energy balance with
    posterior bands, the bare span beside it, and optionally the placement. Reads the cable run;
    never refits.

    Parameters
    ----------
    conductor : Conductor or str
        A :class:`Conductor`, a bundled name (``drake``, ``aster570``) or a TOML path.
    damper : None, "none", path-like, str or Damper
        None or ``"none"``: the bare span. A stored cable-fit directory (``runs/damper1/cable-dry``):
        that run's calibration damper with its own cable. Otherwise a damper (bundled name, TOML
        path or :class:`sbcal.damper.Damper`) built with the cable of ``cable``.
    cable : path-like, optional
        The stored cable-fit directory for a new damper.
    position_m : float or sequence of float, optional
        Damper distance(s) from the suspension clamp [m]; required with a damper unless ``optimise``
        (then the study's result is at the best position).
    ends, wind, n_freq, wave
        As in :func:`energy_balance`.
    n_draws, seed
        Posterior draws and their seed, as in :func:`sbcal.predict.impedance_from_cable`.
    optimise : bool
        Also run :func:`optimise_position` (one damper per equipped end) over ``positions_m``
        (default: its own grid) maximising the ``quantile`` of the worst-case margin.
    search_draws : int
        Draws of the placement's scan (a subset: each position is a full balance; 40 draws estimate
        the 10 % quantile of the margin to a few per cent at a fifth of the cost of 200). The result
        at the chosen position is then computed with all ``n_draws``.

    Returns
    -------
    SpanStudy

    Raises
    ------
    InputError
        One line: a conductor file missing a field, a position outside the span, a damper with no
        cable law (a directory that is not a cable fit, a damper file without ``cable``), a wind band
        outside the wind laws' range.
    """
    from .conductor import resolve_conductor
    from .predict import impedance_from_cable

    c = conductor if isinstance(conductor, Conductor) else resolve_conductor(conductor)
    run, dmp = _damper_source(damper, cable)
    _wind_check(wind)
    if run is None:
        if position_m is not None:
            raise InputError("position: a bare span has no damper position; give a damper with it")
        if optimise:
            raise InputError("optimise: the placement needs a damper")
        r = energy_balance(c, None, None, wind=wind, n_freq=n_freq, wave=wave)
        return SpanStudy(result=r, warnings=r.warnings)
    if position_m is None and not optimise:
        raise InputError("position: give the damper's distance from the suspension clamp [m] (or optimise it)")
    for xs in (position_m, positions_m):
        if xs is not None:
            try:
                _positions(c, xs, ends)
            except InputError as e:
                raise InputError(f"{c.source or c.name}: span_length_m = {c.span_length_m:g} m; {e}") from None
    notes = [w for w in (run.convergence_warning(),) if w]
    imp = impedance_from_cable(run, dmp, n_draws=n_draws, seed=seed)
    placement = None
    if optimise:
        scan = imp if search_draws >= n_draws else impedance_from_cable(run, dmp, n_draws=search_draws, seed=seed)
        placement = optimise_position(c, scan, positions_m, ends=ends, quantile=quantile, wind=wind, n_freq=n_freq,
                                      wave=wave)
    at = position_m if position_m is not None else placement.best_position_m
    r = energy_balance(c, imp, at, ends=ends, wind=wind, n_freq=n_freq, wave=wave)
    cal = _calibrated_amplitudes(run)
    extrapolated = ()
    if cal:
        top = 2e3 * np.nan_to_num(r.damper_amplitude_m, nan=0.0).max(axis=0)  # (S, F) mm p-p, largest damper
        over = np.median(top, axis=0) > (1 + AMPLITUDE_MARGIN) * cal[1]
        extrapolated = tuple(float(f) for f in r.freq_hz[over])
        if over.any():
            notes.append(f"the dampers' clamp amplitude reaches {np.max(np.median(top, axis=0)):.3g} mm p-p (median over "
                         f"draws) at {over.sum()} of {over.size} frequencies ({min(extrapolated):.3g}-"
                         f"{max(extrapolated):.3g} Hz), beyond the {cal[1]:g} mm p-p of the cable's calibration: "
                         "the cable law is extrapolated there")
    return SpanStudy(result=r, placement=placement, damper=dmp.name, cable=str(run.path), cable_damper=run.damper,
                     state=run.state, law=run.law, seed=int(seed), calibrated_amplitude_mm_pp=cal,
                     extrapolated_hz=extrapolated, warnings=tuple(r.warnings) + tuple(notes))


def span_dir(study: SpanStudy, runs_dir=None) -> Path:
    """``<runs>/span/<label>``; ``<runs>`` defaults to the store holding the cable run (its
    grandparent: ``runs/damper1/cable-dry`` -> ``runs``), or ``runs`` for a bare span."""
    if runs_dir is None:
        runs_dir = Path(study.cable).parent.parent if study.cable else Path("runs")
    return Path(runs_dir) / SPAN_STORE / study.label


def store_span(study: SpanStudy, directory=None, *, meta: dict | None = None, json_path=None) -> Path:
    """Write ``span.csv`` (per frequency, :meth:`SpanResult.to_frame`), ``span.png``
    (:func:`plot_span`), ``placement.csv`` (with a placement) and, last, ``summary.json``
    (:meth:`SpanStudy.to_dict` and ``meta``), each atomically, into ``directory`` (default
    :func:`span_dir`); also the JSON at ``json_path``. Returns the directory."""
    from ._io import atomic_path, write_json

    d = Path(directory) if directory is not None else span_dir(study)
    with atomic_path(d / "span.csv", ".csv") as tmp:
        study.result.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
    if study.placement is not None:
        with atomic_path(d / "placement.csv", ".csv") as tmp:
            study.placement.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
    plot_span(study.result, d / "span.png", placement=study.placement)
    doc = dict(study.to_dict(), **(meta or {}))
    if json_path is not None:
        write_json(json_path, doc, indent=1, allow_nan=False)
    write_json(d / "summary.json", doc, indent=1, allow_nan=False)
    return d


def read_span(directory) -> dict:
    """The ``summary.json`` of a stored span study (:func:`store_span`), checked for its main keys."""
    import json

    p = Path(directory) / "summary.json"
    if not p.is_file():
        raise InputError(f"{directory}: no stored span study (summary.json missing)")
    try:
        doc = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not valid JSON ({e.msg}, line {e.lineno})") from None
    for key in ("label", "conductor", "margin", "margin_bare", "per_frequency"):
        if key not in doc:
            raise InputError(f"{p}: key '{key}': missing (not a span study written by sbcal span)")
    return doc


def stored_spans(runs_dir) -> list:
    """Every span study of a run store: ``[(directory, summary dict)]`` sorted by directory name."""
    root = Path(runs_dir) / SPAN_STORE
    return [(d, read_span(d)) for d in sorted(root.iterdir()) if (d / "summary.json").is_file()] if root.is_dir() else []
