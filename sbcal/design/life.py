"""Service life of a span under aeolian vibration: a wind climate, an S-N curve and Miner's rule
over the Strouhal lines of an energy balance (``docs/span.md``, "Service life").

Each line ``i`` of a :class:`~sbcal.design.span.SpanResult` (wind ``v_i``, frequency ``f_i``,
stress amplitude ``sigma_i``) stands for the winds between the midpoints to its neighbours,
clipped to the study's band. With ``h_i`` the hours per year the wind blows across the line in
that interval, the line sees ``n_i = 3600 h_i f_i`` cycles per year and the yearly damage is
``D = sum_i n_i / N(sigma_i)``; the life is ``1 / D`` years.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.plotting import pyplot, save_png
from .conductor import Conductor
from .span import SpanResult
from .vibration import SAFE_BORDER


__all__ = ["HOURS_PER_YEAR", "Climate", "parse_climate", "allowed_cycles", "life_endurance_limit", "Life",
           "service_life", "plot_life", "check_across"]

HOURS_PER_YEAR = 8766.0
"""Hours in a year of 365.25 days (as pallas-dohl ``lifespan.damage_year``: 365.25 * 24 * 3600 s)."""

_HOURS_SLACK = 1.005  # a histogram may exceed a year by 0.5 % (rounding) before it is refused
_COLUMNS = ("wind_m_s", "hours_per_year")
_TI = "turbulence_intensity"


# ---------------------------------------------------------------------------------------------
# Wind climate


@dataclass(frozen=True, eq=False)
class Climate:
    """How many hours per year the wind blows at each speed.

    Attributes
    ----------
    kind : str
        ``"weibull"`` or ``"histogram"``.
    k, c : float or None
        Weibull shape and scale [m/s] (``P(V > v) = exp(-(v/c)^k)``), over :data:`HOURS_PER_YEAR`.
    speeds_mps, hours : ndarray, shape (B,)
        Histogram bin centres [m/s] and hours per year in each bin (empty for a Weibull law).
    edges_mps : ndarray, shape (B + 1,)
        Bin edges [m/s]: midpoints between neighbouring speeds; the outer edges half a neighbouring
        interval beyond the end speeds (the lower one not below 0).
    turbulence_intensity : ndarray, shape (B,), or None
        Per bin, when the CSV gives it: reported only (the balance uses the conductor's I_v).
    source : str
        The CSV file read ("" for a Weibull law).
    """

    kind: str
    k: float | None = None
    c: float | None = None
    speeds_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hours: np.ndarray = field(default_factory=lambda: np.zeros(0))
    edges_mps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    turbulence_intensity: np.ndarray | None = None
    source: str = ""

    @property
    def total_hours(self) -> float:
        """Hours per year over all wind speeds [h]."""
        return HOURS_PER_YEAR if self.kind == "weibull" else float(self.hours.sum())

    def hours_between(self, v_lo, v_hi) -> np.ndarray:
        """Hours per year with the wind speed in ``[v_lo, v_hi)`` [h] (broadcast; 0 where ``v_hi <= v_lo``).

        Weibull: ``8766 (exp(-(v_lo/c)^k) - exp(-(v_hi/c)^k))``. Histogram: the hours of each bin
        spread uniformly over it (a piecewise-constant density), integrated.
        """
        lo = np.maximum(np.asarray(v_lo, dtype=float), 0.0)
        hi = np.maximum(np.asarray(v_hi, dtype=float), lo)
        if self.kind == "weibull":
            return HOURS_PER_YEAR * (np.exp(-(lo / self.c) ** self.k) - np.exp(-(hi / self.c) ** self.k))
        cum = np.concatenate([[0.0], np.cumsum(self.hours)])
        return np.interp(hi, self.edges_mps, cum) - np.interp(lo, self.edges_mps, cum)

    def describe(self) -> str:
        """``weibull:k=K,c=C`` or the CSV path (the JSON's ``climate``)."""
        return f"weibull:k={self.k:g},c={self.c:g}" if self.kind == "weibull" else self.source


def _weibull(spec: str) -> Climate:
    want = "expected --climate weibull:k=K,c=C (k shape > 0, c scale > 0 in m/s)"
    values = {}
    for part in spec.split(":", 1)[1].split(","):
        name, eq, text = part.partition("=")
        name = name.strip()
        if not eq or name not in ("k", "c") or name in values:
            raise InputError(f"--climate: {want}, got {spec!r}")
        try:
            values[name] = float(text)
        except ValueError:
            raise InputError(f"--climate: {name} = {text.strip()!r} is not a number ({want})") from None
        if not (math.isfinite(values[name]) and values[name] > 0):
            raise InputError(f"--climate: {name} = {text.strip()} must be finite and > 0 ({want})")
    if set(values) != {"k", "c"}:
        raise InputError(f"--climate: {want}, got {spec!r}")
    return Climate(kind="weibull", k=values["k"], c=values["c"])


def _histogram(path: Path) -> Climate:
    name = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            for col in _COLUMNS:
                if col not in header:
                    raise InputError(f"{name}: column '{col}': missing (need {', '.join(_COLUMNS)}; "
                                     f"optional {_TI})")
            reader.fieldnames = header
            cols = _COLUMNS + ((_TI,) if _TI in header else ())
            rows, lines = [], []
            for row in reader:
                if not any((row.get(col) or "").strip() for col in cols):
                    continue
                values = []
                for col in cols:
                    text = (row.get(col) or "").strip()
                    try:
                        x = float(text)
                    except ValueError:
                        raise InputError(f"{name}: line {reader.line_num}, column '{col}': "
                                         f"{text!r} is not a number") from None
                    if not math.isfinite(x) or x < 0 or (col == _TI and x >= 1):
                        need = "0 <= I_v < 1" if col == _TI else "finite and >= 0"
                        raise InputError(f"{name}: line {reader.line_num}, column '{col}': {text} is "
                                         f"{'negative' if x < 0 else 'out of range'} (need {need})")
                    values.append(x)
                if rows and values[0] <= rows[-1][0]:
                    raise InputError(f"{name}: line {reader.line_num}, column 'wind_m_s': speeds must increase "
                                     f"strictly, got {values[0]:g} after {rows[-1][0]:g}")
                rows.append(values)
                lines.append(reader.line_num)
    except OSError as exc:
        raise InputError(f"--climate: {name}: cannot read ({exc.strerror or exc})") from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise InputError(f"{name}: not a readable CSV file ({str(exc).splitlines()[0]})") from None
    if len(rows) < 2:
        raise InputError(f"{name}: need at least two rows of wind_m_s, hours_per_year (bins are bounded by "
                         f"the midpoints between speeds), got {len(rows)}")
    a = np.array(rows)
    v, h = a[:, 0], a[:, 1]
    if h.sum() > HOURS_PER_YEAR * _HOURS_SLACK:
        raise InputError(f"{name}: column 'hours_per_year': hours that do not add up: {h.sum():.6g} h in all, "
                         f"more than a year ({HOURS_PER_YEAR:g} h)")
    mid = 0.5 * (v[1:] + v[:-1])
    edges = np.concatenate([[max(v[0] - (mid[0] - v[0]), 0.0)], mid, [v[-1] + (v[-1] - mid[-1])]])
    return Climate(kind="histogram", speeds_mps=v, hours=h, edges_mps=edges,
                   turbulence_intensity=a[:, 2] if a.shape[1] == 3 else None, source=name)


def parse_climate(spec) -> Climate:
    """A wind climate from ``weibull:k=K,c=C`` or the path of a CSV histogram.

    Parameters
    ----------
    spec : str or path-like
        ``weibull:k=2.0,c=4.5`` (shape k, scale c [m/s]; both finite and > 0), or a CSV file with
        columns ``wind_m_s`` (bin centres [m/s], strictly increasing, >= 0), ``hours_per_year``
        (>= 0; in all at most 8766 h, +0.5 %) and optionally ``turbulence_intensity``.

    Returns
    -------
    Climate

    Raises
    ------
    InputError
        One line naming ``--climate`` (a spec that is neither form, a bad Weibull parameter) or the
        file with its line and column (missing column, not a number, negative or unsorted speed,
        negative hours, hours over a year).
    """
    if isinstance(spec, Climate):
        return spec
    text = str(spec).strip()
    if text.lower().startswith("weibull:"):
        return _weibull(text)
    path = Path(text)
    if text and (path.is_file() or path.suffix.lower() == ".csv"):
        return _histogram(path)
    raise InputError(f"--climate: expected weibull:k=K,c=C or a CSV file of hours per year by wind speed "
                     f"(columns wind_m_s, hours_per_year), got {text!r}")


# ---------------------------------------------------------------------------------------------
# S-N curve


def life_endurance_limit(conductor: Conductor) -> float | None:
    """Stress amplitude [Pa] at or below which a cycle does no damage, or None (every cycle counts).

    The file's ``sn_endurance_limit_pa``, else its ``endurance_limit_pa`` (the margin's limit when
    the file gives one); None when neither is given: the safe border line at ``design_cycles`` is a
    stress for a number of cycles, not an endurance limit, and the line goes on falling beyond it.
    """
    if conductor.sn_endurance_limit_pa is not None:
        return float(conductor.sn_endurance_limit_pa)
    return None if conductor.endurance_limit_pa is None else float(conductor.endurance_limit_pa)


def allowed_cycles(stress_pa, conductor: Conductor) -> np.ndarray:
    """Cycles to failure N(sigma) at a stress amplitude: the inverse S-N curve.

    Without ``conductor.sn_curve`` the CIGRE safe border line of ``conductor.fatigue_layers``
    (``sigma = a1 N^b1`` MPa up to N0, ``a2 N^b2`` beyond) inverted: ``(sigma/a1)^(1/b1)`` for
    ``sigma >= a1 N0^b1``, ``(sigma/a2)^(1/b2)`` for ``sigma <= a2 N0^b2``, and N0 in between (the
    line steps down at N0: 16.4 to 15.7 MPa multi-layer, 25.3 to 24.7 MPa single-layer), as
    pallas-dohl ``damage.inv_safe_border_line``. With ``sn_curve``: log-log interpolation of its
    points, extrapolated by the end slopes. At or below :func:`life_endurance_limit`, and for a
    zero stress, ``inf``; NaN stays NaN.

    Parameters
    ----------
    stress_pa : array_like
        Stress amplitude [Pa], any shape.
    conductor : Conductor

    Returns
    -------
    ndarray, shape of ``stress_pa``
    """
    s = np.asarray(stress_pa, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if conductor.sn_curve:
            pts = np.log(np.asarray(conductor.sn_curve, dtype=float))[::-1]  # ascending in stress
            ls, ln = pts[:, 1], pts[:, 0]
            x = np.log(s)
            lo_slope = (ln[1] - ln[0]) / (ls[1] - ls[0])
            hi_slope = (ln[-1] - ln[-2]) / (ls[-1] - ls[-2])
            y = np.interp(x, ls, ln)
            y = np.where(x < ls[0], ln[0] + lo_slope * (x - ls[0]), y)
            y = np.where(x > ls[-1], ln[-1] + hi_slope * (x - ls[-1]), y)
            n = np.exp(y)
        else:
            n0, a1, b1, a2, b2 = SAFE_BORDER[conductor.fatigue_layers]
            mpa = s * 1e-6
            n = np.where(mpa >= a1 * n0**b1, (mpa / a1) ** (1 / b1),
                         np.where(mpa <= a2 * n0**b2, (mpa / a2) ** (1 / b2), n0))
    limit = life_endurance_limit(conductor)
    n = np.where(s <= 0, np.inf, n)
    if limit is not None:
        n = np.where(s <= limit, np.inf, n)
    return np.where(np.isnan(s), np.nan, n)


# ---------------------------------------------------------------------------------------------
# Miner's rule over the lines


def _damage(cycles, stress, conductor):
    """n / N per line; a failed balance (NaN stress) does infinite damage where the line has hours."""
    n_allowed = allowed_cycles(stress, conductor)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(np.isnan(stress), np.inf, cycles / n_allowed)
    return n_allowed, np.where(cycles > 0, d, 0.0)


def _quantiles(a, qs=(0.05, 0.5, 0.95)):
    """Quantiles over axis 0 by numpy's linear rule, with inf allowed (inf - inf is not taken)."""
    a = np.sort(np.asarray(a, dtype=float), axis=0)
    out = []
    for q in qs:
        h = (a.shape[0] - 1) * q
        i = int(math.floor(h))
        j, t = min(i + 1, a.shape[0] - 1), h - i
        x0, x1 = a[i], a[j]
        with np.errstate(invalid="ignore"):
            out.append(np.where((t == 0) | (x0 == x1), x0, x0 + t * (x1 - x0)))
    return np.array(out)


def _years(damage):
    with np.errstate(divide="ignore"):
        return 1.0 / np.asarray(damage, dtype=float)


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True, eq=False)
class Life:
    """Yearly fatigue damage and service life of a span (:func:`service_life`).

    Attributes
    ----------
    climate : Climate
    across : float
        Share of the time the wind blows across the line.
    wind_mps, wind_lo_mps, wind_hi_mps, freq_hz : ndarray, shape (F,)
        Each line's wind [m/s], the interval of winds it stands for [m/s], and its frequency [Hz].
    hours_per_year, cycles_per_year : ndarray, shape (F,)
        Hours per year across the line in the interval [h] and the cycles they make.
    stress_bare_pa, allowed_cycles_bare, damage_bare : ndarray, shape (F,)
        The bare span: stress amplitude [Pa], cycles to failure, damage per year.
    stress_q_pa, allowed_cycles_q, damage_q : ndarray, shape (3, F)
        With the dampers: 5 %, 50 %, 95 % quantiles over draws (a failed balance counts as infinite
        stress); NaN for a bare span.
    damage_draws : ndarray, shape (S,)
        Damage per year with the dampers, per draw (empty for a bare span).
    damage_total_bare : float
        Damage per year of the bare span.
    unsolved_bare : int
        Lines whose bare balance failed (infinite damage).
    unsolved_draws : int
        Draws with a failed balance at some line with hours.
    has_dampers : bool
    conductor_turbulence : float
        The conductor's I_v, which the balance used.
    """

    climate: Climate
    across: float
    wind_mps: np.ndarray
    wind_lo_mps: np.ndarray
    wind_hi_mps: np.ndarray
    freq_hz: np.ndarray
    hours_per_year: np.ndarray
    cycles_per_year: np.ndarray
    stress_bare_pa: np.ndarray
    allowed_cycles_bare: np.ndarray
    damage_bare: np.ndarray
    stress_q_pa: np.ndarray
    allowed_cycles_q: np.ndarray
    damage_q: np.ndarray
    damage_draws: np.ndarray
    damage_total_bare: float
    unsolved_bare: int
    unsolved_draws: int
    has_dampers: bool
    conductor_turbulence: float = 0.0

    @property
    def years_bare(self) -> float:
        """Life of the bare span [years]; inf when it takes no damage, 0 when a balance failed."""
        return float(_years(self.damage_total_bare))

    @property
    def years_draws(self) -> np.ndarray:
        """Life with the dampers per draw [years], shape (S,): inf where a draw takes no damage."""
        return _years(self.damage_draws)

    @property
    def years_q(self) -> np.ndarray:
        """Life with the dampers [years]: 5 %, 50 %, 95 % quantiles over draws (NaN for a bare span)."""
        return _quantiles(_years(self.damage_draws)) if self.has_dampers else np.full(3, np.nan)

    @property
    def damage_total_q(self) -> np.ndarray:
        """Damage per year with the dampers: 5 %, 50 %, 95 % quantiles over draws."""
        return _quantiles(self.damage_draws) if self.has_dampers else np.full(3, np.nan)

    def to_frame(self):
        """One row per line (``life.csv``); the with-damper columns NaN for a bare span. A DataFrame."""
        import pandas as pd

        return pd.DataFrame({
            "wind_m_s": self.wind_mps, "wind_lo_m_s": self.wind_lo_mps, "wind_hi_m_s": self.wind_hi_mps,
            "frequency_hz": self.freq_hz, "hours_per_year": self.hours_per_year,
            "cycles_per_year": self.cycles_per_year, "stress_bare_mpa": self.stress_bare_pa * 1e-6,
            "allowed_cycles_bare": self.allowed_cycles_bare, "damage_per_year_bare": self.damage_bare,
            "stress_median_mpa": self.stress_q_pa[1] * 1e-6, "allowed_cycles_median": self.allowed_cycles_q[1],
            "damage_per_year_median": self.damage_q[1], "damage_per_year_q05": self.damage_q[0],
            "damage_per_year_q95": self.damage_q[2],
        })

    def to_dict(self) -> dict:
        """The JSON object (``null`` for NaN, inf and unlimited lives; ``years`` null for a bare span)."""
        yq, dq = self.years_q, self.damage_total_q
        return {
            "climate": self.climate.describe(), "across": self.across,
            "hours_per_year": float(self.hours_per_year.sum()),
            "years_bare": _num(self.years_bare), "damage_per_year_bare": _num(self.damage_total_bare),
            "unlimited_bare": bool(self.damage_total_bare == 0),
            "years": ({"median": _num(yq[1]), "q05": _num(yq[0]), "q95": _num(yq[2])}
                      if self.has_dampers else None),
            "damage_per_year": ({"median": _num(dq[1]), "q05": _num(dq[0]), "q95": _num(dq[2])}
                                if self.has_dampers else None),
            "unlimited": bool(self.has_dampers and dq[1] == 0),
        }

    def words(self) -> list[str]:
        """Printable lines: the climate, and the life without and with the dampers."""
        lo, hi = self.wind_lo_mps.min(), self.wind_hi_mps.max()
        out = [f"climate {self.climate.describe()}, wind across the line {100 * self.across:g} % of the time: "
               f"{self.hours_per_year.sum():.0f} h per year in the band {lo:g}-{hi:g} m/s"]
        if self.climate.turbulence_intensity is not None:
            ti = self.climate.turbulence_intensity
            out.append(f"turbulence intensity in the climate file ({ti.min():g}-{ti.max():g}) reported only: "
                       f"the balance used the conductor's I_v = {self.conductor_turbulence:g}")
        d = self.damage_total_bare
        out.append("no damper: " + ("unlimited (no damage)" if d == 0 else
                                    f"{_fmt(1 / d)} years (damage {d:.3g} per year)"))
        if self.has_dampers:
            y, dq = self.years_q, self.damage_total_q
            life = ("unlimited" if dq[1] == 0 else f"{_fmt(y[1])} years") + f" [{_fmt(y[0])}, {_fmt(y[2])}]"
            out.append(f"with dampers: {life} (median [5 %, 95 %]); damage {dq[1]:.3g} per year "
                       f"[{dq[0]:.3g}, {dq[2]:.3g}]")
        if self.unsolved_bare:
            out.append(f"no balance at {self.unsolved_bare} line(s) without dampers: counted as infinite damage")
        if self.unsolved_draws:
            out.append(f"{self.unsolved_draws} draw(s) with a failed balance: counted as infinite damage")
        return out


def _fmt(years) -> str:
    if not math.isfinite(years):
        return "unlimited"
    return f"{years:.0f}" if years >= 100 else f"{years:.3g}"


def check_across(across) -> float:
    """The share of the time the wind blows across the line, in (0, 1]; InputError otherwise."""
    ok = not isinstance(across, bool) and isinstance(across, (int, float, np.floating, np.integer))
    if not ok or not (0 < float(across) <= 1):
        raise InputError(f"--across: the share of the time the wind blows across the line must be in (0, 1], "
                         f"got {across!r}")
    return float(across)


def service_life(result: SpanResult, climate, *, across: float = 1.0) -> Life:
    """Miner damage per year and service life, per line and in all, with and without the dampers.

    Parameters
    ----------
    result : SpanResult
        An energy balance; its lines' winds ``wind_mps`` (F,), frequencies ``freq_hz`` (F,) and
        stresses ``stress_pa`` (S, F) and ``stress_bare_pa`` (F,) [Pa].
    climate : Climate or str
        A :class:`Climate` or a spec for :func:`parse_climate`.
    across : float
        Share of the time the wind blows across the line, in (0, 1].

    Returns
    -------
    Life
    """
    clim = parse_climate(climate)
    share = check_across(across)
    c, v, f = result.conductor, np.asarray(result.wind_mps, float), np.asarray(result.freq_hz, float)
    order = np.argsort(v, kind="stable")
    vs = v[order]
    mid = 0.5 * (vs[1:] + vs[:-1])
    lo, hi = np.empty_like(v), np.empty_like(v)
    lo[order] = np.concatenate([vs[:1], mid])
    hi[order] = np.concatenate([mid, vs[-1:]])
    hours = share * clim.hours_between(lo, hi)
    cycles = 3600.0 * hours * f

    n_bare, d_bare = _damage(cycles, np.asarray(result.stress_bare_pa, float), c)
    dampers = len(result.positions_m) > 0
    if dampers:
        s = np.asarray(result.stress_pa, float)
        n_all, d_all = _damage(cycles, s, c)
        s_inf = np.where(np.isnan(s), np.inf, s)
        stress_q, n_q, d_q = _quantiles(s_inf), _quantiles(np.where(np.isnan(s), 0.0, n_all)), _quantiles(d_all)
        draws = d_all.sum(axis=1)
        unsolved = int(np.sum(np.any(np.isnan(s) & (cycles > 0), axis=1)))
    else:
        stress_q = n_q = d_q = np.full((3, v.size), np.nan)
        draws, unsolved = np.zeros(0), 0
    return Life(
        climate=clim, across=share, wind_mps=v, wind_lo_mps=lo, wind_hi_mps=hi, freq_hz=f,
        hours_per_year=hours, cycles_per_year=cycles, stress_bare_pa=np.asarray(result.stress_bare_pa, float),
        allowed_cycles_bare=n_bare, damage_bare=d_bare, stress_q_pa=stress_q, allowed_cycles_q=n_q, damage_q=d_q,
        damage_draws=draws, damage_total_bare=float(d_bare.sum()),
        unsolved_bare=int(np.sum(np.isnan(result.stress_bare_pa) & (cycles > 0))), unsolved_draws=unsolved,
        has_dampers=dampers, conductor_turbulence=c.turbulence_intensity,
    )


def plot_life(life: Life, path) -> Path:
    """Damage per year against wind speed (log scale), without and with the dampers (median and
    90 % band), beside the hours per year each line stands for; one PNG written atomically."""
    plt = pyplot()
    fig, (ax_h, ax) = plt.subplots(1, 2, figsize=(9.6, 4.0))
    v = life.wind_mps
    ax_h.bar(v, life.hours_per_year, width=life.wind_hi_mps - life.wind_lo_mps, color="0.7", edgecolor="0.4",
             lw=0.5)
    ax_h.set(xlabel="wind speed [m/s]", ylabel="hours per year across the line",
             title=f"Climate: {life.climate.describe()}")

    def positive(a):
        a = np.asarray(a, dtype=float)
        return np.where((a > 0) & np.isfinite(a), a, np.nan)

    ax.plot(v, positive(life.damage_bare), "k--", lw=1, marker=".",
            label=f"no damper: {_fmt(life.years_bare)} years")
    if life.has_dampers:
        q05, med, q95 = (positive(x) for x in life.damage_q)
        ax.fill_between(v, q05, q95, color="C0", alpha=0.25)
        ax.plot(v, med, color="C0", marker=".", label=f"with dampers (median, 90 %): {_fmt(life.years_q[1])} years")
    ax.set(yscale="log", xlabel="wind speed [m/s]", ylabel="damage per year (Miner)",
           title="Fatigue damage per line")
    for a in (ax_h, ax):
        a.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
