"""Design sweeps: one field of a damper file stepped over values, the prediction at each, and the
resonances tracked from value to value."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..model.damper import FILE_KEYS, Damper, resolve_damper, with_value
from .cable_run import (cable_params, drawn_geometry, drawn_tolerances, is_calibration_damper, load_cable_run, streams,
                        subset, unit_draws)
from .harmonics import TABLE_STEP, harmonic_correction, on_grid
from .predict import (MODES, RESONANCE_STEP, FromCable, checked_frequencies, checked_levels, clamp_amplitude, draw_checks, evaluate,
                      fine_grid, from_cable_fields, level_resonances, nan_quantiles)


__all__ = ["TRACK_STEP", "parse_sweep", "SweepResult", "sweep", "unjson"]

# --- design sweeps ----------------------------------------------------------------------------------

def parse_sweep(spec: str) -> tuple[str, np.ndarray]:
    """``"cable.length1_m=0.15:0.30:7"`` -> ``("cable.length1_m", 7 values from 0.15 to 0.30)``."""
    key, sep, rng = str(spec).partition("=")
    key = key.strip()
    parts = rng.split(":")
    if not sep or len(parts) != 3:
        raise InputError(f"--sweep {spec!r}: expected NAME=START:STOP:N (e.g. cable.length1_m=0.15:0.30:7)")
    if key not in FILE_KEYS:
        raise InputError(f"--sweep {spec!r}: unknown damper field {key!r}; known: {', '.join(FILE_KEYS)}")
    try:
        start, stop, n = float(parts[0]), float(parts[1]), float(parts[2])
    except ValueError:
        raise InputError(f"--sweep {spec!r}: START, STOP and N must be numbers") from None
    if not (np.isfinite(start) and np.isfinite(stop)) or n != int(n) or n < 2:
        raise InputError(f"--sweep {spec!r}: expected finite START and STOP and an integer N >= 2")
    return key, np.linspace(start, stop, int(n))


@dataclass(frozen=True, eq=False, kw_only=True)
class SweepResult(FromCable):
    """Resonances and peak dissipated power against one design variable (:func:`sweep`): the attributes
    of :class:`sbcal.design.predict.FromCable` (``damper`` the base damper) and these.

    Attributes
    ----------
    field : str
        The swept damper-file field (``"cable.length1_m"``).
    values : ndarray, shape (V,)
        The field's values (SI, as in the damper file).
    resonance_hz : ndarray, shape (V, L, K, 3)
        The :data:`QUANTILES` of the frequency [Hz] of resonance track k (NaN at values where the
        track has no resonance). A track follows one resonance across the values (:data:`TRACK_STEP`);
        tracks are numbered by their median frequency.
    resonance_share : ndarray, shape (V, L, K)
        Fraction of the draws that have it.
    peak_power_w : ndarray, shape (V, L, 3)
        Quantiles of each draw's largest dissipated power over the band [W].
    extrapolated : ndarray of bool, shape (V, L)
        Some line of the band bends the arms outside the calibrated range (as :class:`Prediction`'s).
    fold_share : ndarray, shape (V, L)
        Fraction of (draw, line) pairs with two steady states.
    """

    field: str
    values: np.ndarray
    resonance_hz: np.ndarray
    resonance_share: np.ndarray
    peak_power_w: np.ndarray
    extrapolated: np.ndarray
    fold_share: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        """One row per (value, condition): ``resonance<k>_hz`` (median), ``_q05``, ``_q95``, ``_share``,
        ``peak_power_w`` (median), ``_q05``, ``_q95``, ``extrapolated``."""
        level = MODES[self.mode]
        rows = []
        for v, value in enumerate(self.values):
            for i, lv in enumerate(self.levels):
                row = {"damper": self.damper, "field": self.field, "value": float(value), level: float(lv)}
                for k in range(self.resonance_hz.shape[2]):
                    q = self.resonance_hz[v, i, k]
                    row.update({f"resonance{k + 1}_hz": q[1], f"resonance{k + 1}_q05": q[0],
                                f"resonance{k + 1}_q95": q[2], f"resonance{k + 1}_share": self.resonance_share[v, i, k]})
                p = self.peak_power_w[v, i]
                row.update({"peak_power_w": p[1], "peak_power_q05": p[0], "peak_power_q95": p[2],
                            "extrapolated": bool(self.extrapolated[v, i])})
                rows.append(row)
        return pd.DataFrame(rows)

    def summary(self) -> dict:
        """JSON-ready (NaN as null)."""
        return self._summary() | {
            "field": self.field, "values": self.values.tolist(), "resonance_hz": _jsonable(self.resonance_hz),
            "resonance_share": _jsonable(self.resonance_share), "peak_power_w": _jsonable(self.peak_power_w),
            "extrapolated": self.extrapolated.tolist(), "fold_share": self.fold_share.tolist()}


def _jsonable(a):
    """NaN -> None, nested lists."""
    a = np.asarray(a, float)
    return [_jsonable(x) for x in a] if a.ndim else (None if not np.isfinite(a) else float(a))


def unjson(x) -> np.ndarray:
    """A float array from stored JSON (nested lists), None read as NaN."""
    return np.array(json.loads(json.dumps(x).replace("null", "NaN")), dtype=float)


TRACK_STEP = 0.4
"""A resonance at the next design value continues a track when its frequency is within this distance
in ln f of the track's last one (a factor 1.5); otherwise it starts a track of its own. The closest
pairs are joined first, so neighbouring modes keep their tracks; a sweep too coarse for a mode to move
less than that between values splits its track."""


def _tracks(per_value: list) -> list:
    """Follow resonances across design values: ``per_value[v]`` the resonances at value v (by
    frequency); returns tracks ``[(v, Resonance), ...]``, sorted by their median frequency. Greedy:
    the closest (track, resonance) pairs in ln f are joined first."""
    tracks, last = [], []  # last: (ln f of the track's latest resonance, value index) per track
    for v, found in enumerate(per_value):
        lf = [np.log(r.freq_hz[1]) for r in found]
        pairs = sorted((abs(a - b[0]), t, j) for t, b in enumerate(last) for j, a in enumerate(lf)
                       if b[1] == v - 1 and abs(a - b[0]) <= TRACK_STEP)
        used_t, used_j = set(), set()
        for _, t, j in pairs:
            if t not in used_t and j not in used_j:
                tracks[t].append((v, found[j]))
                last[t] = (lf[j], v)
                used_t.add(t)
                used_j.add(j)
        for j, r in enumerate(found):
            if j not in used_j:
                tracks.append([(v, r)])
                last.append((lf[j], v))
    return sorted(tracks, key=lambda tr: np.median([r.freq_hz[1] for _, r in tr]))


def sweep(run, damper, field_key: str, values, *, amplitude_mm_pp=None, velocity_m_s=None, freq_hz=None,
          n_draws: int = 200, seed: int = 0, bench_effects: bool = False) -> SweepResult:
    """Resonance frequencies and peak dissipated power against one damper-file field.

    Every value gets the same posterior draws and the same relative geometry draws (common random
    numbers: the curves against the value are smooth); each value's damper is the base ``damper``
    with the field replaced (and toleranced like the nominal value). A run whose harmonic refit was used
    gets its correction per value (:mod:`sbcal.design.harmonics`, at that value's draws' median, solved every
    :data:`~sbcal.design.harmonics.TABLE_STEP` in ln f and carried onto the search grid). All (value, draw) sets of one
    test condition are solved in one vectorised pass.

    Parameters
    ----------
    run, damper, amplitude_mm_pp, velocity_m_s, n_draws, seed, bench_effects
        As :func:`predict`.
    field_key : str
        A damper-file field (:data:`sbcal.model.damper.FILE_KEYS`), e.g. ``"cable.length1_m"``, ``"mass2.mass_kg"``.
    values : array_like, shape (V,)
        Its values [SI].
    freq_hz : array_like, optional
        The band searched for resonances (its least and largest value; default 4-40 Hz).

    Returns
    -------
    SweepResult
    """
    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    if field_key not in FILE_KEYS:
        raise InputError(f"sweep: unknown damper field {field_key!r}; known: {', '.join(FILE_KEYS)}")
    attr = FILE_KEYS[field_key]
    if attr == "ej_static":
        raise InputError(f"sweep: {field_key} does not change a prediction (the cable's rigidity is the calibration's)")
    vals = np.atleast_1d(np.asarray(values, dtype=float))
    if vals.ndim != 1 or vals.size == 0:
        raise InputError("sweep: expected one or more values")
    designs = [with_value(damper, field_key, v, where="sweep") for v in vals]  # checked as the file reader checks
    mode, levels = checked_levels(cable, amplitude_mm_pp, velocity_m_s)
    fine = fine_grid(checked_frequencies(freq_hz))
    n_draws = draw_checks(n_draws)
    own = is_calibration_damper(cable, damper) and attr not in ("a1", "a2")
    pick, geo = streams(seed)
    idx = subset(cable, n_draws, pick)
    n, nv = idx.size, vals.size
    tolerance = drawn_tolerances(designs, own)
    units = unit_draws(tolerance, n, geo)
    per_value = [drawn_geometry(d, tolerance, units) for d in designs]
    names = sorted(set().union(*per_value) | {attr})
    params = {k: np.tile(v, nv) for k, v in cable_params(cable, idx, bench_effects, own).items()}
    for k in names:
        params[k] = np.concatenate([g.get(k, np.full(n, getattr(d, k))) for g, d in zip(per_value, designs)])
    effects = tuple(cable.summary.get("effects", ())) if bench_effects else ()
    nl = levels.size
    res = [[[] for _ in range(nl)] for _ in range(nv)]
    peak = np.full((nv, nl, 3), np.nan)
    extra = np.zeros((nv, nl), dtype=bool)
    fold = np.zeros((nv, nl))
    conv = np.ones((nv, nl))
    coarse = fine[::max(1, int(round(TABLE_STEP / RESONANCE_STEP)))]  # the correction's lines: carried onto fine
    for i, level in enumerate(levels):
        xf = clamp_amplitude(mode, level, fine)
        r = evaluate(cable.law, effects, damper, fine, xf, params, n * nv)
        if cable.harmonic:  # per design value, at its draws' median (sbcal.design.harmonics)
            xc = clamp_amplitude(mode, level, coarse)
            c = [harmonic_correction(cable.law, effects, d, coarse, xc, {k: v[j * n:(j + 1) * n] for k, v in params.items()})[0]
                 for j, d in enumerate(designs)]
            r["fuu"] = (r["fuu"].reshape(nv, n, -1) * on_grid(np.array(c), coarse, fine)[:, None]).reshape(nv * n, -1)
        power = (0.5 * 2 * np.pi * fine * r["fuu"].imag * xf**2).reshape(nv, n, fine.size)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            peak[:, i] = nan_quantiles(np.nanmax(power, axis=2), axis=1).T
            top = np.nanmedian(r["cmax"].reshape(nv, n, -1), axis=1)
        extra[:, i] = (cable.range_status(top) != 0).any(axis=1)
        fold[:, i] = r["fold"].reshape(nv, -1).mean(axis=1)
        conv[:, i] = r["converged"].reshape(nv, -1).mean(axis=1)
        fuu = r["fuu"].reshape(nv, n, fine.size)
        for v in range(nv):  # peak finding per design value (a handful); vectorised over the draws
            res[v][i] = level_resonances(fine, fuu[v], xf, level)
    tracks = [_tracks([res[v][i] for v in range(nv)]) for i in range(nl)]
    k_max = max((len(t) for t in tracks), default=0)
    hz = np.full((nv, nl, k_max, 3), np.nan)
    share = np.zeros((nv, nl, k_max))
    for i, level_tracks in enumerate(tracks):
        for k, track in enumerate(level_tracks):
            for v, r_ in track:
                hz[v, i, k], share[v, i, k] = r_.freq_hz, r_.share
    notes = []
    if conv.min() < 1:
        notes.append(f"the cable model did not converge for {100 * (1 - conv.mean()):.2g} % of the (draw, line) pairs")
    return SweepResult(**from_cable_fields(cable, damper, mode=mode, levels=levels, n_draws=n, seed=seed,
                                           tolerance=tolerance, own=own, bench_effects=bench_effects, notes=notes),
                       field=field_key, values=vals, resonance_hz=hz, resonance_share=share, peak_power_w=peak,
                       extrapolated=extra, fold_share=fold)
