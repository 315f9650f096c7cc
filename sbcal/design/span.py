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
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.optimize import elementwise

from ..core.errors import InputError
from ..model.damper import Damper
from ..model.fem import dynamic_stiffness
from .conductor import Conductor
from .vibration import (CIGRE_ZERO, TABLE_SEARCH_MAX, bending_amplitude, fatigue_limit, poffenberger_swart,
                        strouhal_band, turbulence_factor, wind_check, wind_curve_range, wind_power_curve)


__all__ = ["Impedance", "FemImpedance", "STATUS", "energy_balance", "SpanResult", "AMPLITUDE_FLOOR_M",
           "checked_positions", "quantiles_90", "jsonable"]

STATUS = ("ok", "extrapolated", "below_range", "no_solution")
"""Status codes of a balance: 0 root inside the wind curve's validity range; 1 root found outside
it (the curve is extrapolated); 2 dissipation exceeds the wind input even at the lowest amplitude
searched (Y_max reported as that amplitude, an upper bound); 3 the wind input exceeds the
dissipation up to the highest amplitude searched (no solution, Y_max NaN, margin 0)."""

_WAVES = ("travelling", "standing")
AMPLITUDE_FLOOR_M = 1e-9  # a damper at a node sees X_d = 0; its K* is evaluated at 1 nm instead

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

    ``params`` are keyword parameters of :func:`sbcal.model.fem.dynamic_stiffness` (scalars or arrays of
    shape (S,), e.g. posterior draws of ``EJ`` and ``beta``). The amplitude is ignored.
    Module-level and picklable.
    """

    damper: Damper
    params: dict = field(default_factory=dict)

    def __call__(self, freq_hz, amplitude_m):
        return dynamic_stiffness(self.damper, freq_hz, **self.params)


# ---------------------------------------------------------------------------------------------
# The balance


def checked_positions(conductor: Conductor, position_m, ends) -> np.ndarray:
    """Damper positions [m] from the span end as an array; InputError unless inside the span (or half of it)."""
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
        self.a_w = c.span_length_m * freq**3 * d**4 * turbulence_factor(c.turbulence_intensity)
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
        """K* of shape (S, F) (or (1, F)) at clamp amplitudes (S or 1, F); checked. Amplitudes with a
        leading axis (K, S or 1, F) (a grid of trial states) give (K, S, F): in one call when the
        impedance has a ``stacked`` method of that signature, else one call per k."""
        amplitude = np.maximum(amplitude, AMPLITUDE_FLOOR_M)
        if np.ndim(amplitude) == 3:
            stacked = getattr(self.impedance, "stacked", None)
            k = (np.asarray(stacked(self.freq, amplitude)) if stacked is not None
                 else np.array([self._checked(self.impedance(self.freq, a)) for a in amplitude]))
            return self._checked(k, stacked=True)
        return self._checked(self.impedance(self.freq, amplitude))

    def _checked(self, k, stacked=False):
        k = np.asarray(k)
        core = k.shape[1:] if stacked else k.shape
        if len(core) != 2 or core[1] != self.freq.size or (self.n_sets and core[0] not in (1, self.n_sets)):
            raise InputError(f"impedance: returned shape {k.shape}, expected (S, {self.freq.size})")
        if not np.all(np.isfinite(k)):
            raise InputError("impedance: returned a non-finite dynamic stiffness")
        bad = k.imag < -1e-9 * np.abs(k)
        if bad.any():
            f = self.freq[np.nonzero(bad)[-1][0]]
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
    y_hi = d * (CIGRE_ZERO if c.wind_curve == "cigre" else TABLE_SEARCH_MAX)
    scale = np.broadcast_to(bal.a_w, shape)  # g is divided by the wind scale: O(1) values

    def g_and_y(v):
        y, pd, _ = bal.evaluate(v)
        pw, pc = bal.conductor_powers(y)
        return (pw - pc - pd) / scale, y

    def g(v):
        return g_and_y(v)[0]

    v_lo, v_hi = bal.unknown_for(y_lo, shape), bal.unknown_for(y_hi, shape)
    if bal.linear:
        below, none = g(v_lo) <= 0, g(v_hi) > 0
        a, b = v_lo, v_hi
        found = ~below & ~none
    else:
        grid = np.linspace(v_lo - 2.0, v_hi + 2.0, _GRID)  # (K, S, F); +-2: the guess of ln B is rough
        gk, yk = g_and_y(grid)  # the whole grid at once (an impedance with ``stacked`` evaluates it in one call)
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
        warnings = wind_check(wind)[2]
    else:
        freq = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        if freq.ndim != 1 or freq.size == 0 or not np.all(np.isfinite(freq) & (freq > 0)):
            raise InputError("freq_hz: expected positive finite frequencies of shape (F,)")
        wind_mps = freq * c.diameter_m / c.strouhal
        warnings = wind_check((wind_mps.min(), wind_mps.max()), allow_single=True)[2]
    if (impedance is None) != (position_m is None):
        raise InputError("position_m: give it together with an impedance (a damper), or neither")
    positions = checked_positions(c, position_m, ends) if impedance is not None else np.zeros(0)

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


def quantiles_90(a, axis=0):
    """5 %, 50 %, 95 % quantiles over draws (NaN propagates: it marks an unsolved draw)."""
    return np.quantile(a, [0.05, 0.5, 0.95], axis=axis)


def jsonable(a):
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
            lo, mid, hi = quantiles_90(arr)
            cols |= {f"{name}_median_{unit}": mid, f"{name}_q05_{unit}": lo, f"{name}_q95_{unit}": hi}
        cols |= {"ymax_bare_m": self.ymax_bare_m, "bending_amplitude_bare_m": self.bending_amplitude_bare_m,
                 "stress_bare_mpa": self.stress_bare_pa * 1e-6}
        for name, arr in (("p_wind", self.p_wind_w), ("p_self", self.p_self_w), ("p_damper", self.p_damper_w)):
            lo, mid, hi = quantiles_90(arr)
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
            "margin": {"median": jsonable(np.median(m)), "q05": jsonable(np.quantile(m, 0.05)),
                       "q10": jsonable(np.quantile(m, 0.1)), "q95": jsonable(np.quantile(m, 0.95)),
                       "median_db": jsonable(20 * np.log10(np.median(m))) if np.median(m) > 0 else None},
            "margin_bare": jsonable(self.margin_bare),
            "per_frequency": {k: (jsonable(v.to_numpy(dtype=float)) if is_numeric_dtype(v) else [str(x) for x in v])
                              for k, v in frame.items()},
            "warnings": list(self.warnings),
        }
