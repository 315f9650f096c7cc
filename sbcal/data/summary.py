"""What ``sbcal data`` shows per damper and test: runs, grid, amplitudes, scatter, outlier runs,
branches, unmatched frequencies."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .bench import BenchData
from .cleaning import DEFAULT_Z_THRESHOLD, check_threshold, quality_table, remove_outlier_runs
from .noise import noise_model


__all__ = ["CV_BANDS_HZ", "bench_summary", "summary_notes"]

# --- per-file summary (sbcal data) ---------------------------------------------------------------

CV_BANDS_HZ = (("f<=15Hz", 0.0, 15.0), ("f>15Hz", 15.0, math.inf))
"""Frequency bands of the CV summary: the thesis found the scatter largest at 4-15 Hz (section 2.5)."""


def _band_medians(table: pd.DataFrame, column: str) -> dict:
    f = table["frequency_hz"].to_numpy()
    out = {}
    for name, lo, hi in CV_BANDS_HZ:
        v = table[column].to_numpy()[(f > lo) & (f <= hi)]
        v = v[np.isfinite(v)]
        out[name] = float(np.median(v)) if v.size else None
    return out


def _none_if_nan(x) -> float | None:
    return None if not np.isfinite(x) else float(x)


def bench_summary(bench: BenchData, z_threshold: float = DEFAULT_Z_THRESHOLD) -> dict:
    """Per damper and test: runs, grid, amplitudes, CV bands, outlier runs, branches, unmatched
    frequencies (what ``sbcal data`` shows).

    Parameters
    ----------
    bench : BenchData
    z_threshold : float
        Passed to :func:`remove_outlier_runs`.

    Returns
    -------
    dict
        ``{damper: {test: {...}}}`` (dampers sorted, tests in :meth:`BenchData.tests` order), each
        test holding ``runs`` (count), ``run_ids``, ``removed_runs``, ``amplitude_mm_pp`` (unique
        commanded amplitudes [mm p-p], ascending), ``n_frequencies``, ``frequency_min_hz``,
        ``frequency_max_hz``, ``z_threshold``, ``run_scores`` (aligned with ``run_ids``; None when
        undefined), ``cv_median_pct`` = ``{"raw"|"clean": {"magnitude"|"phase": {band: median
        CV [%] or None}}}`` over :data:`CV_BANDS_HZ`, ``branches`` (:meth:`Branches.as_dict`) and
        ``unmatched`` (``[{"run", "frequency_hz", "nearest_line_hz"}]``, values left out because
        they match no line); where the file has measured columns, ``measured``: ``{"values", "se_logmag_median",
        "se_phase_median_deg", "distortion_max", "distortion_max_hz", "noise_lines"}`` (values measured; medians of
        the standard errors [1] and [deg]; the largest force distortion [1] and its line; lines where the
        measured error sets the noise model's sigma). JSON-serialisable.
    """
    z = check_threshold(z_threshold)
    out = {}
    for damper in bench.dampers():
        out[damper] = {}
        for label in bench.tests(damper):
            t = bench.test(damper, label)
            cleaned = remove_outlier_runs(t, z)
            cv = {}
            for key, data in (("raw", t), ("clean", cleaned.data)):
                q = quality_table(data)
                cv[key] = {name: _band_medians(q, f"{name}_cv") for name in ("magnitude", "phase")}
            out[damper][label] = {
                "runs": int(t.runs.size),
                "run_ids": [int(r) for r in t.runs],
                "removed_runs": list(cleaned.removed_runs),
                "amplitude_mm_pp": [float(a) for a in np.unique(t.amplitude_mm_pp)],
                "n_frequencies": int(t.freq_hz.size),
                "frequency_min_hz": float(t.freq_hz[0]),
                "frequency_max_hz": float(t.freq_hz[-1]),
                "z_threshold": z,
                "run_scores": [_none_if_nan(x) for x in cleaned.scores],
                "cv_median_pct": cv,
                "branches": cleaned.branches.as_dict(),
                "unmatched": [{"run": r, "frequency_hz": f, "nearest_line_hz": c} for r, f, c in t.unmatched],
            }
            if t.se_logmag is not None or t.distortion is not None:
                out[damper][label]["measured"] = _measured(t, cleaned.data)
    return out


def _measured(t, kept) -> dict:
    """What the measured columns say of a test (:func:`bench_summary`'s ``measured``)."""
    se_l = t.se_logmag if t.se_logmag is not None else np.full(t.magnitude.shape, np.nan)
    se_p = t.se_phase if t.se_phase is not None else np.full(t.magnitude.shape, np.nan)
    dist = t.distortion if t.distortion is not None else np.full(t.magnitude.shape, np.nan)
    have = np.isfinite(se_l) | np.isfinite(dist)
    worst = np.nanmax(dist, axis=0, initial=-np.inf, where=np.isfinite(dist))
    k = int(np.argmax(worst)) if np.isfinite(worst).any() else None
    return {
        "values": int(have.sum()),
        "se_logmag_median": _none_if_nan(np.median(se_l[np.isfinite(se_l)])) if np.isfinite(se_l).any() else None,
        "se_phase_median_deg": (_none_if_nan(np.degrees(np.median(se_p[np.isfinite(se_p)])))
                                if np.isfinite(se_p).any() else None),
        "distortion_max": None if k is None else float(worst[k]),
        "distortion_max_hz": None if k is None else float(t.freq_hz[k]),
        "noise_lines": int(noise_model(kept).measured.sum()),
    }


def summary_notes(entry: dict) -> list[str]:
    """One-line notes on a test of :func:`bench_summary` (two branches, unmatched frequencies) for
    ``sbcal data``'s table; empty for most tests."""
    notes = []
    b = entry.get("branches") or {}
    if b.get("split"):
        lines = ", ".join(f"{f:g}" for f in b["lines_hz"])
        minority, majority = b["runs"]
        notes.append(f"two response branches at {lines} Hz: runs {','.join(map(str, minority))} vs "
                     f"{len(majority)} others; both branches kept (a run is judged within its branch)")
    m = entry.get("measured")
    if m:
        se = ("" if m["se_logmag_median"] is None else
              f"standard errors (median) {100 * m['se_logmag_median']:.3g} % / {m['se_phase_median_deg']:.3g} deg, "
              f"setting the noise on {m['noise_lines']} line(s); ")
        dist = ("" if m["distortion_max"] is None else
                f"force distortion up to {100 * m['distortion_max']:.3g} % ({m['distortion_max_hz']:g} Hz)")
        notes.append(f"measured ({m['values']} values): {se}{dist}".rstrip("; "))
    if entry.get("unmatched"):
        vals = ", ".join(f"run {u['run']} at {u['frequency_hz']:g} Hz (line {u['nearest_line_hz']:g})"
                         for u in entry["unmatched"][:5])
        more = f" and {len(entry['unmatched']) - 5} more" if len(entry["unmatched"]) > 5 else ""
        notes.append(f"unmatched frequencies, left out: {vals}{more}")
    return notes
