"""Bench recordings: the CSV contract (``shared/spec/formats.md`` section 2).

Long format, one row per (run, frequency line): ``damper, test, run, frequency_hz,
amplitude_mm_pp, stiffness_n_per_m, phase_deg`` (phase in degrees, convention exp(+i w t)).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._io import atomic_path

__all__ = ["BENCH_COLUMNS", "test_label", "curves_to_frame", "write_bench"]

BENCH_COLUMNS = (
    "damper", "test", "run", "frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m", "phase_deg",
)


def test_label(amplitude_mm_pp: float) -> str:
    """The thesis's label of a constant-amplitude test: ``0.5 -> "0.5-0.5"``, ``1 -> "1-1"``."""
    a = f"{float(amplitude_mm_pp):g}"
    return f"{a}-{a}"


def curves_to_frame(damper: str, test: str, freq_hz, amplitude_mm_pp, fuu, runs=None) -> pd.DataFrame:
    """Complex dynamic-stiffness curves to bench rows.

    Parameters
    ----------
    damper, test : str
    freq_hz : array_like, shape (n_freq,)
    amplitude_mm_pp : float or array_like, shape (n_freq,)
        Commanded base displacement per line [mm p-p].
    fuu : array_like of complex, shape (n_runs, n_freq)
        One curve per run [N/m].
    runs : array_like of int, shape (n_runs,), optional
        Run ids (default 1..n_runs).

    Returns
    -------
    DataFrame with :data:`BENCH_COLUMNS`, phase in degrees in (-180, 180].
    """
    fuu = np.atleast_2d(fuu)
    n_runs, n_freq = fuu.shape
    runs = np.arange(1, n_runs + 1) if runs is None else np.asarray(runs)
    amp = np.broadcast_to(np.asarray(amplitude_mm_pp, dtype=float), (n_freq,))
    return pd.DataFrame({
        "damper": damper,
        "test": test,
        "run": np.repeat(runs, n_freq),
        "frequency_hz": np.tile(np.asarray(freq_hz, dtype=float), n_runs),
        "amplitude_mm_pp": np.tile(amp, n_runs),
        "stiffness_n_per_m": np.abs(fuu).ravel(),
        "phase_deg": np.degrees(np.angle(fuu)).ravel(),
    }, columns=list(BENCH_COLUMNS))


def write_bench(frame: pd.DataFrame, path) -> None:
    """Write bench rows as CSV, atomically (no partial file on interruption)."""
    with atomic_path(path, ".csv") as tmp:
        frame.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
