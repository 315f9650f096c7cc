"""Bench recordings: the long-format contract (``shared/spec/formats.md`` section 2) read from CSV,
Excel or Parquet, quality check, outlier-run removal, response branches and the repeatability
noise model.

Long format, one row per (run, frequency line): ``damper, test, run, frequency_hz,
amplitude_mm_pp, stiffness_n_per_m, phase_deg`` (phase in degrees, convention exp(+i w t)).

Data flow: :func:`load_bench` (read any format, validate with one set of checks) ->
:meth:`BenchData.test` (one damper and test as arrays, each run's frequencies matched to the
test's lines) -> :func:`quality_table` (thesis section 2.5) -> :func:`remove_outlier_runs`
(section 2.6, whole curves; a test whose runs settle on two response branches is reported, not
cut) -> :func:`noise_model` (per-line scatter of one run, for the likelihood).
The rules and the statistics are described in ``docs/data.md``.
"""

from __future__ import annotations

import csv
import datetime as _dt
import gzip
import io
import math
import re
import warnings
from collections import defaultdict
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from ._io import atomic_path
from .errors import InputError

__all__ = [
    "BENCH_COLUMNS",
    "THESIS_TESTS",
    "DEFAULT_Z_THRESHOLD",
    "NOISE_FLOOR",
    "SINGLE_RUN_SIGMA",
    "FREQ_REL_TOL",
    "FREQ_STEP_FRACTION",
    "FREQ_NEAR_REL",
    "BRANCH_GAP",
    "BRANCH_MIN_FRACTION",
    "BRANCH_MIN_RUNS",
    "BRANCH_MAX_LINE_FRACTION",
    "TestData",
    "BenchData",
    "Branches",
    "CleanedTest",
    "NoiseModel",
    "load_bench",
    "default_bench_path",
    "quality_table",
    "run_scores",
    "find_branches",
    "remove_outlier_runs",
    "noise_model",
    "CV_BANDS_HZ",
    "bench_summary",
    "summary_notes",
    "test_label",
    "curves_to_frame",
    "write_bench",
]

BENCH_COLUMNS = (
    "damper", "test", "run", "frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m", "phase_deg",
)

THESIS_TESTS = ("0.1-0.1", "0.2-0.2", "0.3-0.3", "0.4-0.4", "0.5-0.5", "1-1", "2-2", "2-1", "1-1-oiled")
"""The seed thesis's test labels in its own order (Table 4.5)."""

DEFAULT_Z_THRESHOLD = 3.0
"""Default run-score threshold of :func:`remove_outlier_runs` (the thesis used Z = 2 or 3).

How often a clean run is flagged (docs/data.md derives and simulates it). When a run's scatter
is independent from line to line its score concentrates near 1: P(score > 3) ~ 0 (< 0.1 %).
The worst case is a run that differs from the others by one common offset on every line
(curve-level noise): its score is then max(|z_mag|, |z_phase|), above 3 with probability
1 - (1 - 2 (1 - Phi(3)))^2 = 0.54 % for many runs, and more with few runs because the scale is
estimated from them (simulated: 3.2 % with 12 runs, 8 % with 4-5). At Z = 2 those figures are
8.9 % and 12-16 %: Z = 2 would discard good runs routinely and leave a noise model fitted to a
trimmed, too narrow scatter. Z = 3 still flags a whole curve 3 sigma off in either component.
"""

NOISE_FLOOR = 0.002
"""Lower bound of every noise sigma: 0.2 % in magnitude (natural-log units) and 0.002 rad in phase."""

SINGLE_RUN_SIGMA = 0.05
"""Sigma used where no repeat is available within the pooling window: a 5 % complex relative
error, i.e. 0.05 in log-magnitude and 0.05 rad (2.9 deg) in phase."""

FREQ_REL_TOL = 0.005
"""Two runs' recorded frequencies within 0.5 % of each other are one line (a controller that
settles within a tolerance, a frequency read with 0.01-0.02 Hz resolution at 4 Hz). The standard
grid's smallest relative step is 3.3 % (29 -> 30 Hz), so its lines never merge. See
:data:`FREQ_STEP_FRACTION` for fine grids."""

FREQ_STEP_FRACTION = 0.25
"""... but never more than a quarter of the run's own local step (the distance to its nearest other
frequency), so a run's finely spaced lines are never merged."""

FREQ_NEAR_REL = 0.02
"""A value of one run only, beyond the tolerance but within 2 % of a line that other runs share
and that this run lacks, is that run's missed attempt at the line: reported as unmatched and
left out, never made a line of its own. Farther away it is a line of the run's own grid."""

BRANCH_GAP = 6.0
"""A line splits into two branches when its runs form two groups separated by an empty interval of
at least 6 robust sigma (the scale of :func:`run_scores`). Simulated without branches (37 lines x
2 components, 6-30 runs, 2000 tests each): with Gaussian scatter no test's widest gap reached
5 sigma (largest 4.6); with Student-t3 tails 0-0.1 % of tests reached 6 (docs/data.md section 3b)."""

BRANCH_MIN_FRACTION = 0.15
"""Each branch holds at least 15 % of the runs at its line (the bundled data hold branches of 4 of
24 runs, 17 %, as clear as the larger ones) ..."""

BRANCH_MIN_RUNS = 3
"""... and at least 3 runs: two runs that agree far from the rest may be two outliers."""

BRANCH_MAX_LINE_FRACTION = 0.25
"""A test has two branches only when its split lines are at most a quarter of the lines where a
split can be seen: a fold is confined to a band near a resonance, while a group of bad curves
differs everywhere (and is left to outlier removal)."""

_ROBUST_POOL = 30     # residuals pooled per line for the robust scale (MAD rel. error ~ 1.17/sqrt(30) = 21 %)
_POOL_DOF = 10        # degrees of freedom pooled per line for the noise sigma (rel. error 1/sqrt(20) = 22 %)
_MAX_HALF_WINDOW = 3  # pool at most +-3 neighbouring lines
_VALUE_Z = 8.0        # single values beyond 8 robust sigma (a glitch, not noise) leave the noise model
_VALUE_MIN_RUNS = 4   # ... judged only on lines with >= 4 runs (with 3 the robust scale is too noisy)
_MAX_RUN_ID = 2.0 ** 53  # run ids must be exact in float64

# Median |x_i - median(x)| and RMS of (x_i - median(x)) for n iid N(0, 1) values, n = 2..15
# (simulation, 2e7 residuals per n; n = 2 is exact: 0.6745/sqrt(2) and 1/sqrt(2)). Beyond 15:
# q = 0.6745 (1 - 1.2/n), k = sqrt(1 - 0.55/n) (within 1 %). The exact zero residual of the
# median itself for odd n is why q(3) < q(2).
_Q_SMALL = np.array([np.nan, np.nan, 0.4769, 0.3138, 0.4864, 0.4906, 0.5276, 0.5518, 0.5632,
                     0.5826, 0.5877, 0.6013, 0.6038, 0.6130, 0.6150, 0.6224])
_K_SMALL = np.array([np.nan, np.nan, 0.7071, 0.8842, 0.8934, 0.9417, 0.9387, 0.9617, 0.9583,
                     0.9715, 0.9689, 0.9776, 0.9750, 0.9811, 0.9794, 0.9838])
_PHI_075 = 0.6744897501960817  # median of |N(0, 1)|


# --- arrays of one test ------------------------------------------------------------------------

def _readonly(a, dtype=None) -> np.ndarray:
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class TestData:
    """The runs of one (damper, test) on the test's frequency lines.

    Attributes
    ----------
    damper, test : str
    runs : ndarray of int, shape (n_runs,)
        Run ids, ascending.
    freq_hz : ndarray, shape (n_freq,)
        The test's lines [Hz], ascending: each the median of the runs' recorded frequencies that
        match it (:meth:`BenchData.test`).
    amplitude_mm_pp : ndarray, shape (n_freq,)
        Commanded base displacement per line [mm p-p], the median over the runs that have it.
    magnitude : ndarray, shape (n_runs, n_freq)
        Dynamic stiffness |F/X| [N/m]; NaN only where that run lacks that line.
    phase_deg : ndarray, shape (n_runs, n_freq)
        Phase of F/X [deg], not wrapped; NaN where :attr:`magnitude` is.
    unmatched : tuple of (int, float, float)
        ``(run, frequency_hz, nearest_line_hz)`` of recorded values that match no line (left out
        of the arrays), sorted; empty for most tests.

    Arrays are read-only; equality is identity (arrays have no single truth value).
    """

    __test__ = False  # not a pytest test class despite its name

    damper: str
    test: str
    runs: np.ndarray
    freq_hz: np.ndarray
    amplitude_mm_pp: np.ndarray
    magnitude: np.ndarray
    phase_deg: np.ndarray
    unmatched: tuple = ()

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "runs", _readonly(self.runs, np.int64))
        for name in ("freq_hz", "amplitude_mm_pp", "magnitude", "phase_deg"):
            set_(self, name, _readonly(self.__dict__[name], float))
        set_(self, "unmatched", tuple((int(r), float(f), float(c)) for r, f, c in self.unmatched))
        n_runs, n_freq = self.runs.size, self.freq_hz.size
        if self.runs.ndim != 1 or self.freq_hz.ndim != 1 or self.amplitude_mm_pp.shape != (n_freq,):
            raise ValueError("TestData: runs, freq_hz and amplitude_mm_pp must be 1-D, the last two of equal length")
        if self.magnitude.shape != (n_runs, n_freq) or self.phase_deg.shape != (n_runs, n_freq):
            raise ValueError(f"TestData: magnitude and phase_deg must have shape {(n_runs, n_freq)}")

    @property
    def present(self) -> np.ndarray:
        """Which (run, line) pairs were recorded: bool, shape (n_runs, n_freq)."""
        return ~np.isnan(self.magnitude)

    def select_runs(self, run_ids) -> "TestData":
        """The same test restricted to ``run_ids`` (any order; kept ascending).

        Lines that none of the kept runs has are dropped; the commanded amplitude of a kept line
        is unchanged (it is a property of the test, not of a run). ``unmatched`` keeps the kept
        runs' entries.

        Raises
        ------
        InputError
            An id that is not a run of this test, or no id at all.
        """
        ids = np.unique(np.asarray(run_ids, dtype=np.int64).ravel())
        if ids.size == 0:
            raise InputError(f"{self.damper} {self.test}: select_runs: no run selected")
        missing = ids[~np.isin(ids, self.runs)]
        if missing.size:
            raise InputError(f"{self.damper} {self.test}: no run {int(missing[0])}; runs: "
                             f"{', '.join(map(str, self.runs))}")
        rows = np.searchsorted(self.runs, ids)
        cols = np.flatnonzero(self.present[rows].any(axis=0))
        keep = set(ids.tolist())
        return TestData(self.damper, self.test, ids, self.freq_hz[cols], self.amplitude_mm_pp[cols],
                        self.magnitude[np.ix_(rows, cols)], self.phase_deg[np.ix_(rows, cols)],
                        tuple(u for u in self.unmatched if u[0] in keep))


def _test_order(label: str):
    # thesis labels first, in the thesis's order; anything else after, sorted
    return (THESIS_TESTS.index(label), "") if label in THESIS_TESTS else (len(THESIS_TESTS), label)


def _segment_medians(sorted_values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Median of each run of ``sorted_values`` (ascending within segments) starting at ``starts``."""
    counts = np.diff(np.append(starts, sorted_values.size))
    return 0.5 * (sorted_values[starts + (counts - 1) // 2] + sorted_values[starts + counts // 2])


def _split_chains(cluster: np.ndarray, run: np.ndarray, freq: np.ndarray) -> np.ndarray:
    """Cut clusters (labels ascending along ``freq``, which is sorted) that hold a run twice.

    ``run`` holds run indices 0..n_runs-1. Tolerances are at most a quarter of each run's own step,
    so this needs a chain of other runs' values bridging two lines of one run: rare, so a plain
    loop over the few such clusters. Each is cut at its widest gaps until no run repeats.
    Returns new labels, ascending.
    """
    codes = cluster * (run.max() + 1) + run
    uniq, counts = np.unique(codes, return_counts=True)
    if counts.size == codes.size:
        return cluster
    bad = np.unique(uniq[counts > 1] // (run.max() + 1))
    cut = np.zeros(cluster.size, bool)  # cut[i]: a new cluster starts at position i
    for c in bad:
        todo = [np.flatnonzero(cluster == c)]
        while todo:
            idx = todo.pop()
            if np.unique(run[idx]).size == idx.size:
                continue
            k = int(np.argmax(np.diff(freq[idx]))) + 1
            cut[idx[k]] = True
            todo += [idx[:k], idx[k:]]
    start = np.append(True, cluster[1:] != cluster[:-1]) | cut
    return np.cumsum(start) - 1


def _match_lines(run: np.ndarray, freq: np.ndarray):
    """Match the recorded frequencies of one test's rows to the test's lines.

    Returns ``(line, centres, nearest)``: ``line`` (n_rows,) the line index of each row or -1
    (unmatched), ``centres`` (n_lines,) ascending line frequencies [Hz], ``nearest`` (n_rows,)
    the nearest shared line of each unmatched row (NaN elsewhere). Rules (docs/data.md 1b):

    1. tolerance of a value: ``min(FREQ_REL_TOL f, FREQ_STEP_FRACTION * its run's local step)``;
    2. single-linkage clusters along frequency: neighbours join when each lies within the other's
       tolerance; a cluster never holds one run twice (cut at its widest gap);
    3. a cluster shared by >= 2 runs (or any, in a test of one run) is a line, at the median of
       its values; so is a one-run cluster unless it lies within ``FREQ_NEAR_REL`` of a shared
       line that its run lacks: then it is that run's missed attempt, unmatched.
    """
    m = freq.size
    # each run's local step: the distance to its own nearest other frequency
    o = np.lexsort((freq, run))
    same = run[o][1:] == run[o][:-1]
    d = np.where(same, np.diff(freq[o]), np.inf)
    step = np.empty(m)
    step[o] = np.minimum(np.append(np.inf, d), np.append(d, np.inf))
    tol = np.minimum(FREQ_REL_TOL * freq, FREQ_STEP_FRACTION * step)

    o = np.argsort(freq, kind="stable")
    fo, to = freq[o], tol[o]
    run_ids, run_idx = np.unique(run[o], return_inverse=True)
    join = np.diff(fo) <= np.minimum(to[1:], to[:-1])
    cluster = _split_chains(np.append(0, np.cumsum(~join)), run_idx, fo)
    starts = np.flatnonzero(np.append(True, cluster[1:] != cluster[:-1]))
    n_clusters = starts.size
    centre = _segment_medians(fo, starts)
    support = np.bincount(cluster, minlength=n_clusters)  # one value per run and cluster (step 2)
    shared = (support >= 2) | (run_ids.size == 1)

    is_line = np.ones(n_clusters, bool)
    nearest_c = np.full(n_clusters, np.nan)
    lone = np.flatnonzero(~shared)
    if lone.size and shared.any():
        sc, sid = centre[shared], np.flatnonzero(shared)
        v = fo[starts[lone]]  # a lone cluster holds one value
        hi = np.minimum(np.searchsorted(sc, v), sc.size - 1)
        lo = np.maximum(hi - 1, 0)
        j = np.where(np.abs(v - sc[lo]) <= np.abs(v - sc[hi]), lo, hi)  # the nearest shared line
        near = np.abs(v - sc[j]) <= FREQ_NEAR_REL * sc[j]
        lacks = ~np.isin(run_idx[starts[lone]] * n_clusters + sid[j], run_idx * n_clusters + cluster)
        miss = near & lacks
        is_line[lone[miss]] = False
        nearest_c[lone[miss]] = sc[j[miss]]
    renumber = np.cumsum(is_line) - 1
    line_sorted = np.where(is_line[cluster], renumber[cluster], -1)
    line = np.empty(m, np.int64)
    line[o] = line_sorted
    nearest = np.empty(m)
    nearest[o] = nearest_c[cluster]
    return line, centre[is_line], nearest


@dataclass(frozen=True, eq=False)
class BenchData:
    """Validated bench recordings of one file.

    Attributes
    ----------
    source : str
        The file read.
    frame : DataFrame
        The validated rows in file order (sheets in workbook order), the seven
        :data:`BENCH_COLUMNS` only: ``run`` int64, labels stripped of surrounding blanks, the
        rest float64 (all finite).
    """

    source: str
    frame: pd.DataFrame

    @cached_property
    def _groups(self) -> dict:
        return self.frame.groupby(["damper", "test"], sort=False).indices

    def dampers(self) -> list[str]:
        """Damper names, sorted."""
        return sorted({d for d, _ in self._groups})

    def tests(self, damper: str) -> list[str]:
        """Test labels of ``damper``: thesis labels in the thesis's order (0.1-0.1 ... 2-2, 2-1,
        1-1-oiled), then any other label, sorted."""
        if damper not in self.dampers():
            raise InputError(f"{self.source}: no damper {damper!r}; dampers: {', '.join(self.dampers())}")
        return sorted((t for d, t in self._groups if d == damper), key=_test_order)

    def test(self, damper: str, test: str) -> TestData:
        """One damper's test as arrays (see :class:`TestData`).

        Each run's recorded frequencies are matched to the test's lines within
        :data:`FREQ_REL_TOL` (0.5 %, at most a quarter of the run's own step), so a frequency
        that jitters from run to run stays one line; a value of one run that misses a shared
        line by more (up to :data:`FREQ_NEAR_REL`) is left out and listed in
        :attr:`TestData.unmatched`. Runs need not share a grid (docs/data.md section 1b).

        Raises
        ------
        InputError
            No such damper or test; the message lists what the file holds.
        """
        idx = self._groups.get((damper, test))
        if idx is None:
            tests = self.tests(damper)  # raises for an unknown damper
            raise InputError(f"{self.source}: damper {damper!r} has no test {test!r}; tests: {', '.join(tests)}")
        f = self.frame
        run = f["run"].to_numpy()[idx]
        freq = f["frequency_hz"].to_numpy()[idx]
        line, centres, nearest = _match_lines(run, freq)
        ok = line >= 0
        runs, ri = np.unique(run[ok], return_inverse=True)
        grids = []
        for col in ("amplitude_mm_pp", "stiffness_n_per_m", "phase_deg"):
            g = np.full((runs.size, centres.size), np.nan)
            g[ri, line[ok]] = f[col].to_numpy()[idx][ok]
            grids.append(g)
        unmatched = sorted(zip(run[~ok].tolist(), freq[~ok].tolist(), nearest[~ok].tolist()))
        # every line has at least one run by construction: the median is defined everywhere
        return TestData(damper, test, runs, centres, _nanmedian0(grids[0]), grids[1], grids[2], tuple(unmatched))


# --- reading: one entry point, one set of checks -------------------------------------------------

def default_bench_path() -> Path:
    """The bundled bench recordings, ``sbcal/data/bench.csv`` (or ``bench.csv.gz``).

    Returns the ``.csv`` path when neither exists; :func:`load_bench` then reports it missing.
    """
    root = resources.files("sbcal") / "data"
    for name in ("bench.csv", "bench.csv.gz"):
        p = root / name
        if p.is_file():
            return Path(str(p))
    return Path(str(root / "bench.csv"))


_LABELS = ("damper", "test")
_NUMERIC = BENCH_COLUMNS[2:]
_POSITIVE = ("frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m")

# where(rows) -> one place name per row ("line 5", "sheet 'A', row 5", "row index 4");
# explain(column, row) -> what is wrong with that value. Only called to report an error.
_Where = Callable[[list], list]
_Explain = Callable[[str, int], str]


def _clean_labels(df: pd.DataFrame) -> None:
    """Strip blanks around damper and test labels (in place); few unique labels make it cheap."""
    for col in _LABELS:
        uniq = pd.unique(df[col].dropna())
        if any(isinstance(u, str) and u != u.strip() for u in uniq):
            df[col] = df[col].str.strip()


def _bad_masks(df: pd.DataFrame) -> list:
    """[(column, bad-row mask)] of the failing checks, in column order (vectorised)."""
    checks = []
    for col in _LABELS:
        s = df[col]
        empty = [u for u in pd.unique(s) if not isinstance(u, str) or not u]  # NaN, None or ""
        checks.append((col, s.isin(empty).to_numpy() | s.isna().to_numpy()))
    run = df["run"].to_numpy(dtype=float)
    checks.append(("run", ~np.isfinite(run) | (run != np.round(run)) | (np.abs(run) > _MAX_RUN_ID)))
    for col in _NUMERIC[1:]:
        x = df[col].to_numpy(dtype=float)
        bad = ~np.isfinite(x)
        if col in _POSITIVE:
            bad |= x <= 0  # NaN compares False: already flagged
        checks.append((col, bad))
    return [c for c in checks if c[1].any()]


def _raise_first(source, found: list, where: _Where, explain: _Explain) -> None:
    """InputError for the earliest bad row of ``found`` (ties: column order)."""
    row, k = min((int(np.argmax(mask)), k) for k, (_, mask) in enumerate(found))
    col = found[k][0]
    n_bad = int(np.logical_or.reduce([m for _, m in found]).sum())
    more = f" (first of {n_bad} bad rows)" if n_bad > 1 else ""
    raise InputError(f"{source}: {where([row])[0]}: column '{col}': {explain(col, row)}{more}")


def _finish(source, df: pd.DataFrame, where: _Where) -> pd.DataFrame:
    """The checked rows typed as in :attr:`BenchData.frame`; duplicate keys rejected."""
    df = df[list(BENCH_COLUMNS)].reset_index(drop=True)
    for col in _LABELS:  # the text dtype pandas gives CSV labels, whatever the format
        df[col] = df[col].astype(str)
    df["run"] = df["run"].to_numpy(dtype=float).astype(np.int64)
    for col in _NUMERIC[1:]:
        df[col] = df[col].to_numpy(dtype=float)
    key = ["damper", "test", "run", "frequency_hz"]
    dup = df.duplicated(subset=key, keep="first").to_numpy()
    if dup.any():
        b = int(np.argmax(dup))
        row = df.iloc[b]
        same = np.ones(len(df), bool)
        for c in key:
            same &= (df[c] == row[c]).to_numpy()
        a = int(np.argmax(same))
        at_b, at_a = where([b, a])
        raise InputError(
            f"{source}: {at_b}: columns 'damper','test','run','frequency_hz': duplicate of {at_a} "
            f"({row['damper']} {row['test']} run {row['run']} at {row['frequency_hz']:g} Hz)")
    return df


def _validated(source, df: pd.DataFrame, where: _Where, explain: _Explain) -> pd.DataFrame:
    """The checks every format shares: labels, numbers, run ids, duplicates (docs/data.md 1).

    ``df`` holds the seven contract columns: labels as text (NaN or None where missing), the
    rest as numbers (NaN where a cell is not a number).
    """
    _clean_labels(df)
    found = _bad_masks(df)
    if found:
        _raise_first(source, found, where, explain)
    return _finish(source, df, where)


def _check_header(source, names: list, at: str) -> None:
    """Every contract column exactly once among ``names`` (stripped header cells)."""
    for col in BENCH_COLUMNS:
        count = names.count(col)
        if count == 0:
            raise InputError(f"{source}: {at}: missing column '{col}' (required: {','.join(BENCH_COLUMNS)})")
        if count > 1:
            raise InputError(f"{source}: {at}: column '{col}' appears {count} times")


def load_bench(path, sheet: str | None = None) -> BenchData:
    """Read and validate bench recordings (the long-format contract, ``formats.md`` section 2).

    Parameters
    ----------
    path : str or path-like
        The format follows the name's ending: ``.xlsx`` (or ``.xlsm``) an Excel workbook,
        ``.parquet`` (or ``.pq``) a Parquet file, anything else CSV (``.csv``; ``.gz``: gzip).
        CSV: UTF-8 (a byte-order mark is allowed), header required, separated by commas, or by
        semicolons or tabs when the header line says so (then decimal commas are read too).
        Excel: every sheet holds the long layout (header row first), concatenated in workbook
        order. Columns may come in any order; extra columns are ignored. Several dampers and
        tests may share one file; any frequency grid is accepted, runs of one test need not
        share it, and the amplitude may vary with frequency.
    sheet : str, optional
        Read only this sheet of a workbook (an error for other formats).

    Returns
    -------
    BenchData

    Raises
    ------
    InputError
        One line naming the file, the place (CSV: the 1-based file line, header = line 1;
        Excel: the sheet and the row as Excel numbers it; Parquet: the 0-based row index) and
        the column, for the earliest bad row: a missing column; an empty, non-numeric, NaN or
        infinite value (in a workbook also a text cell in a number column); ``frequency_hz``,
        ``amplitude_mm_pp`` or ``stiffness_n_per_m`` <= 0; a ``run`` that is not an integer
        (``3.0`` is read as 3; ``1.5`` is rejected); an empty damper or test label; a CSV row
        with more fields than the header; two rows with the same (damper, test, run,
        frequency_hz) (both named); an empty file, sheet or header without rows; a missing
        sheet; a missing or unreadable file.

    Notes
    -----
    Every format goes through the same checks on a DataFrame (:func:`_validated`); the readers
    only differ in how they turn cells into values and name a row. A plain CSV's happy path is one
    typed ``pandas.read_csv`` and vectorised checks; only when a check fails is the file re-read
    as text to say exactly what is wrong, and where.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a bench file (.csv, .csv.gz, .xlsx, .parquet)")
    name = p.name.lower()
    if name.endswith((".xlsx", ".xlsm")):
        return BenchData(source=str(p), frame=_load_xlsx(p, sheet))
    if sheet is not None:
        raise InputError(f"{p}: sheet {sheet!r} named, but only .xlsx workbooks have sheets")
    if name.endswith(".xls"):
        raise InputError(f"{p}: old Excel .xls workbooks are not read; save it as .xlsx")
    if name.endswith((".parquet", ".pq")):
        return BenchData(source=str(p), frame=_load_parquet(p))
    return BenchData(source=str(p), frame=_load_csv(p))


# --- CSV ------------------------------------------------------------------------------------------

_DELIMITERS = (",", ";", "\t")
_DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab"}


def _open_text(path: Path):
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="")
    return open(path, encoding="utf-8-sig", newline="")


def _blank(record: list) -> bool:
    # what pandas' skip_blank_lines skips: an empty or all-whitespace line (no delimiter)
    return len(record) == 0 or (len(record) == 1 and not record[0].strip())


def _first_record(path: Path, delimiter: str) -> tuple[int, list[str]] | None:
    """(line number, fields) of the first non-blank record, or None for a file of blank lines."""
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end = 0
        for rec in reader:
            start, end = end + 1, reader.line_num
            if not _blank(rec):
                return start, rec
    return None


def _read_header(path: Path) -> tuple[int, list[str], str]:
    """(line number, field names, delimiter) of the first non-blank line; errors as one line.

    The delimiter is the one of ``, ; tab`` that splits the header into the most contract
    columns (ties: the comma): European spreadsheets write ``;`` with decimal commas.
    """
    best = None
    for d in _DELIMITERS:
        first = _first_record(path, d)
        if first is None:
            raise InputError(f"{path}: empty file, expected the header line {','.join(BENCH_COLUMNS)}")
        n = len(set(BENCH_COLUMNS) & {h.strip() for h in first[1]})
        if best is None or n > best[0]:
            best = (n, first[0], first[1], d)
        if n == len(BENCH_COLUMNS):
            break
    return best[1], best[2], best[3]


def _record_lines(path: Path, rows, delimiter: str = ",") -> dict[int, int]:
    """First physical line (1-based) of data records ``rows`` (0-based, pandas' row order).

    Only called to report an error, so a plain Python pass over the file is fine; it follows
    quoted fields that span lines, which pandas' row index cannot.
    """
    wanted, out = set(int(r) for r in rows), {}
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end, k = 0, -2  # -2: the header is still to come
        for rec in reader:
            start, end = end + 1, reader.line_num
            if _blank(rec):
                continue
            k += 1
            if k in wanted:
                out[k] = start
                if len(out) == len(wanted):
                    break
    return out


def _too_many_fields(path: Path, n_fields: int, delimiter: str) -> InputError | None:
    """The first record with more fields than the header (error path only)."""
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end, header = 0, True
        for rec in reader:
            start, end = end + 1, reader.line_num
            if _blank(rec):
                continue
            if header:
                header = False
            elif len(rec) > n_fields:
                return InputError(f"{path}: line {start}: expected {n_fields} fields (as in the header), saw {len(rec)}")
    return None


def _read_frame(path: Path, header: list[str], dtypes: dict, delimiter: str) -> pd.DataFrame:
    """The file's contract columns, renamed to :data:`BENCH_COLUMNS`; other columns read as text.

    ``dtypes`` maps contract names to str or float. A row with more fields than the header is an
    error (pandas would silently shift or drop them); only a trailing empty field on every row
    (a trailing comma) passes, as pandas drops it without loss.
    """
    names = {h: h.strip() for h in header}
    dtype = defaultdict(lambda: str, {h: dtypes[c] for h, c in names.items() if c in dtypes})
    kw = dict(sep=delimiter, index_col=False, dtype=dtype, skip_blank_lines=True, encoding="utf-8-sig",
              compression="gzip" if path.suffix == ".gz" else None)
    if dtypes["run"] is str:
        kw.update(keep_default_na=False)
    try:
        with warnings.catch_warnings():
            # "Length of header or names does not match length of data": fields would be lost
            warnings.simplefilter("error", pd.errors.ParserWarning)
            df = pd.read_csv(path, **kw)
    except (pd.errors.ParserError, pd.errors.ParserWarning) as e:
        raise (_too_many_fields(path, len(header), delimiter) or InputError(
            f"{path}: malformed CSV: {str(e).strip().splitlines()[-1]}")) from None
    except UnicodeDecodeError:
        raise _not_utf8(path) from None
    except (OSError, EOFError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    df = df.rename(columns={h: c for h, c in names.items() if c in BENCH_COLUMNS})
    return df[list(BENCH_COLUMNS)]


def _not_utf8(path: Path) -> InputError:
    """Name the line of the first byte that is not UTF-8 (error path only)."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rb") as fh:
        data = fh.read()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        return InputError(f"{path}: line {line}: not UTF-8 text (byte 0x{data[e.start]:02x})")
    return InputError(f"{path}: not UTF-8 text")


# 4.573,2: a dot between groups of three digits before a decimal comma (thousands separator)
_GROUPED = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+,\d*([eE][+-]?\d+)?$")


def _decimal_comma_numbers(s: pd.Series) -> np.ndarray:
    """Text with a decimal comma to float64; NaN where it is not such a number.

    A dot is accepted only as a thousands separator before a decimal comma (``4.573,2``);
    anywhere else it is ambiguous (``1.234``: 1.234 or 1234?) and the value is refused.
    """
    t = s.str.strip()
    grouped = t.str.match(_GROUPED).to_numpy(dtype=bool)
    dotted = t.str.contains(".", regex=False).to_numpy(dtype=bool)
    t = t.where(~grouped, t.str.replace(".", "", regex=False)).str.replace(",", ".", regex=False)
    x = pd.to_numeric(t, errors="coerce").to_numpy(dtype=float)
    return np.where(dotted & ~grouped, np.nan, x)


def _explain_csv(text: pd.DataFrame, df: pd.DataFrame, decimal_comma: bool) -> _Explain:
    def explain(col: str, i: int) -> str:
        s = str(text[col].iloc[i]).strip()
        if s == "" or col in _LABELS:
            return "empty value"
        if col == "run":
            return f"expected an integer run id, got {s!r}"
        x = float(df[col].iloc[i])
        if np.isfinite(x):
            return f"must be > 0, got {s}"
        if np.isinf(x) or s.lower().lstrip("+-") == "nan":
            return f"value {s!r} is not finite"
        if decimal_comma and "." in s:
            return f"expected a number with a decimal comma, got {s!r} (a dot is read only between thousands)"
        return f"expected a number, got {s!r}"
    return explain


def _load_csv(p: Path) -> pd.DataFrame:
    try:
        header_line, header, delim = _read_header(p)
    except UnicodeDecodeError:
        raise _not_utf8(p) from None
    except (OSError, EOFError) as e:
        raise InputError(f"{p}: cannot read: {e}") from None
    except csv.Error as e:
        raise InputError(f"{p}: malformed CSV: {e}") from None
    _check_header(p, [h.strip() for h in header], f"line {header_line}")

    def where(rows):
        lines = _record_lines(p, rows, delim)
        return [f"line {lines.get(r, r + 2)}" for r in rows]

    if delim == ",":
        fast = {c: (str if c in _LABELS else float) for c in BENCH_COLUMNS}
        try:
            df = _read_frame(p, header, fast, delim)
            _clean_labels(df)
            clean = not _bad_masks(df)
        except InputError:
            raise
        except ValueError:
            clean = False  # a non-numeric value: the text pass says which
        if clean:
            if len(df) == 0:
                raise InputError(f"{p}: line {header_line}: header only, no data rows")
            return _finish(p, df, where)
    # the text pass: labels such as "NA" are text (NaN to the typed reader), and a semicolon or
    # tab file may write decimal commas
    text = _read_frame(p, header, dict.fromkeys(BENCH_COLUMNS, str), delim)
    if len(text) == 0:
        raise InputError(f"{p}: line {header_line}: header only, no data rows")
    decimal_comma = delim != "," and any(text[c].str.contains(",", regex=False).any() for c in _NUMERIC)
    parse = _decimal_comma_numbers if decimal_comma else (
        lambda s: pd.to_numeric(s, errors="coerce").to_numpy(dtype=float))
    df = pd.DataFrame({c: (text[c] if c in _LABELS else parse(text[c])) for c in BENCH_COLUMNS})
    return _validated(p, df, where, _explain_csv(text, df, decimal_comma))


# --- Excel ----------------------------------------------------------------------------------------

def _is_blank_cell(v) -> bool:
    return v is None or (isinstance(v, str) and not v.strip())


def _cell_label(v):
    """A label cell as text; None for a cell that cannot be a label (empty, date, TRUE/FALSE)."""
    if isinstance(v, str):
        return v  # stripped later, with the other formats' labels
    if type(v) is int:
        return str(v)
    if type(v) is float:
        return str(int(v)) if v.is_integer() else repr(v)
    return None


def _cell_number(v) -> float:
    # only number cells are numbers: a text cell is refused, never parsed (bool is not a number)
    return float(v) if type(v) in (int, float) else np.nan


def _describe_cell(v) -> str:
    if isinstance(v, bool):
        return str(v).upper()
    if isinstance(v, (_dt.date, _dt.time, _dt.timedelta)):
        return f"a date/time cell ({v})"
    if isinstance(v, str):
        return f"text {v.strip()!r}"
    return repr(v)


def _explain_cell(raw: dict) -> _Explain:
    def explain(col: str, i: int) -> str:
        v = raw[col][i]
        if _is_blank_cell(v):
            return "empty value"
        if col in _LABELS:
            hint = ("; Excel turns labels such as 2-1 into dates: format the column as Text"
                    if isinstance(v, (_dt.date, _dt.time, _dt.timedelta)) else "")
            return f"expected a text label, got {_describe_cell(v)}{hint}"
        if type(v) not in (int, float):
            return f"expected a number, got {_describe_cell(v)}"
        if col == "run":
            return f"expected an integer run id, got {v!r}"
        if not math.isfinite(v):
            return f"value {v!r} is not finite"
        return f"must be > 0, got {v:g}"
    return explain


def _read_sheet(path: Path, ws, name: str):
    """The contract columns of one sheet: (raw cells per column, Excel row numbers)."""
    if hasattr(ws, "reset_dimensions"):
        ws.reset_dimensions()  # a writer's stale dimension tag must not cut rows off
    rows = ws.iter_rows(values_only=True)
    header_row = header = None
    data, numbers = [], []
    for r, row in enumerate(rows, start=1):
        if all(_is_blank_cell(v) for v in row):
            continue
        if header is None:
            header_row, header = r, row
        else:
            data.append(row)
            numbers.append(r)
    at = f"sheet {name!r}"
    if header is None:
        raise InputError(f"{path}: {at}: empty sheet, expected a header row {','.join(BENCH_COLUMNS)}")
    names = ["" if v is None else str(v).strip() for v in header]
    _check_header(path, names, f"{at}, row {header_row}")
    if not data:
        raise InputError(f"{path}: {at}, row {header_row}: header only, no data rows")
    raw = {}
    for col in BENCH_COLUMNS:
        i = names.index(col)
        raw[col] = [row[i] if i < len(row) else None for row in data]
    return raw, numbers


def _load_xlsx(p: Path, sheet: str | None) -> pd.DataFrame:
    import zipfile

    import openpyxl
    from openpyxl.utils.exceptions import InvalidFileException

    try:
        wb = openpyxl.load_workbook(p, read_only=True, data_only=True)
    except (zipfile.BadZipFile, InvalidFileException, KeyError, OSError, ValueError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{p}: cannot read as an Excel workbook: {msg}") from None
    try:
        # chart sheets hold no cells: not part of the data
        names = [n for n in wb.sheetnames if hasattr(wb[n], "iter_rows")]
        if sheet is not None:
            if sheet not in names:
                raise InputError(f"{p}: no sheet {sheet!r}; sheets: {', '.join(names) or '(none)'}")
            names = [sheet]
        if not names:
            raise InputError(f"{p}: no worksheet")
        parts = [(n, *_read_sheet(p, wb[n], n)) for n in names]
    finally:
        wb.close()
    raw = {c: [v for _, cols, _ in parts for v in cols[c]] for c in BENCH_COLUMNS}
    sheet_of = np.concatenate([np.full(len(rows), k) for k, (_, _, rows) in enumerate(parts)])
    row_of = np.concatenate([rows for _, _, rows in parts])

    def where(rows):
        return [f"sheet {parts[sheet_of[r]][0]!r}, row {row_of[r]}" for r in rows]

    df = pd.DataFrame({c: (pd.Series([_cell_label(v) for v in raw[c]], dtype=object) if c in _LABELS
                           else np.array([_cell_number(v) for v in raw[c]], dtype=float))
                       for c in BENCH_COLUMNS})
    return _validated(p, df, where, _explain_cell(raw))


# --- Parquet --------------------------------------------------------------------------------------

def _load_parquet(p: Path) -> pd.DataFrame:
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    try:
        meta = pq.read_metadata(p)
        schema = meta.schema.to_arrow_schema()
    except (pa.ArrowException, OSError) as e:
        raise InputError(f"{p}: cannot read as Parquet: {str(e).strip().splitlines()[0]}") from None
    _check_header(p, [n.strip() for n in schema.names], "schema")
    if meta.num_rows == 0:  # before the types: a writer may type an empty column as null
        raise InputError(f"{p}: no data rows")
    text_types = (pa.types.is_string, pa.types.is_large_string, getattr(pa.types, "is_string_view", lambda t: False))
    for col in BENCH_COLUMNS:
        t = schema.field(schema.names.index(col)).type
        base = t.value_type if pa.types.is_dictionary(t) else t
        if col in _LABELS:
            ok = any(is_text(base) for is_text in text_types) or pa.types.is_integer(base)
            want = "text"
        else:
            ok = pa.types.is_integer(base) or pa.types.is_floating(base) or pa.types.is_decimal(base)
            want = "a number (integer or floating point)"
        if not ok:
            raise InputError(f"{p}: column '{col}': Parquet type {t}, expected {want}")
    try:
        table = pq.read_table(p, columns=list(BENCH_COLUMNS))
    except (pa.ArrowException, OSError) as e:
        raise InputError(f"{p}: cannot read as Parquet: {str(e).strip().splitlines()[0]}") from None
    if table.num_rows == 0:
        raise InputError(f"{p}: no data rows")
    null = {c: table.column(c).is_null().to_numpy(zero_copy_only=False) for c in BENCH_COLUMNS}
    df = pd.DataFrame({c: (pc.cast(table.column(c), pa.string()).to_pandas() if c in _LABELS
                           else pc.cast(table.column(c), pa.float64()).to_numpy(zero_copy_only=False))
                       for c in BENCH_COLUMNS})

    def where(rows):
        return [f"row index {r}" for r in rows]

    def explain(col, i):
        if null[col][i] or col in _LABELS:
            return "empty value" + (" (null)" if null[col][i] else "")
        x = float(df[col].iloc[i])
        if col == "run":
            return f"expected an integer run id, got {x:g}"
        if not math.isfinite(x):
            return f"value {x} is not finite"
        return f"must be > 0, got {x:g}"

    return _validated(p, df, where, explain)


# --- phase wrapping -----------------------------------------------------------------------------

def _phase_unwrapped_deg(phase_deg: np.ndarray) -> np.ndarray:
    """Phases (n_runs, n_freq) [deg] taken modulo 360 about each line's circular mean.

    The contract says phase is not wrapped, but a writer using atan2 turns 180.4 deg into
    -179.6 deg; that 360-deg jump must not read as scatter. Each line is then shifted by a whole
    turn so that its median lies in (-90, 270]. Unwrapped data are returned unchanged (to rounding).
    """
    rad = np.radians(phase_deg)
    centre = np.angle(np.nansum(np.exp(1j * rad), axis=0))  # 0 for a line with no reading
    out = centre + np.mod(rad - centre + np.pi, 2 * np.pi) - np.pi
    med = _nanmedian0(out)
    out -= 2 * np.pi * np.floor((np.nan_to_num(med) + np.pi / 2) / (2 * np.pi))
    return np.where(np.isnan(phase_deg), np.nan,
                    np.where(np.abs(out - rad) < 1e-9, phase_deg, np.degrees(out)))


# --- quality check (thesis 2.5) -----------------------------------------------------------------

def _stats(x: np.ndarray, n: np.ndarray) -> dict:
    """Across-run mean, min, max, sample std (NaN where n < 2) and CV of x (n_runs, n_freq)."""
    mean = np.nanmean(x, axis=0)
    lo, hi = np.nanmin(x, axis=0), np.nanmax(x, axis=0)
    ss = np.nansum((x - mean) ** 2, axis=0)
    std = np.full(mean.shape, np.nan)
    ok = n >= 2
    std[ok] = np.sqrt(ss[ok] / (n[ok] - 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        cv = 100.0 * (hi - lo) / (2.0 * np.abs(mean))
    return {"mean": mean, "min": lo, "max": hi, "std": std, "cv": cv}


def quality_table(test: TestData) -> pd.DataFrame:
    """Per-line spread across runs (thesis section 2.5).

    Parameters
    ----------
    test : TestData

    Returns
    -------
    DataFrame, one row per frequency line, columns
        ``frequency_hz`` [Hz], ``amplitude_mm_pp`` [mm p-p], ``n_runs`` (runs with that line);
        ``magnitude_mean``, ``magnitude_min``, ``magnitude_max``, ``magnitude_std`` [N/m] and
        ``magnitude_cv`` [%]; the same five for ``phase_`` [deg, %], taken modulo 360 about each
        line's circular mean (a reading written as -179.6 counts as 180.4). ``std`` is the sample
        standard deviation (ddof = 1; NaN with a single run). ``cv`` is the thesis's coefficient
        of variation ``100 (max - min) / (2 |mean|)`` (0 with a single run; ``|mean|`` so that a
        phase near or below 0 deg cannot give a negative CV).
    """
    n = test.present.sum(axis=0)
    out = {"frequency_hz": test.freq_hz, "amplitude_mm_pp": test.amplitude_mm_pp, "n_runs": n}
    for name, x in (("magnitude", test.magnitude), ("phase", _phase_unwrapped_deg(test.phase_deg))):
        for stat, v in _stats(x, n).items():
            out[f"{name}_{stat}"] = v
    return pd.DataFrame(out)


# --- robust standardisation ----------------------------------------------------------------------

def _q(n: np.ndarray) -> np.ndarray:
    n = np.asarray(n)
    big = _PHI_075 * (1.0 - 1.2 / np.maximum(n, 1))
    return np.where(n < _Q_SMALL.size, _Q_SMALL[np.minimum(n, _Q_SMALL.size - 1)], big)


def _k(n: np.ndarray) -> np.ndarray:
    n = np.asarray(n)
    big = np.sqrt(np.abs(1.0 - 0.55 / np.maximum(n, 1)))
    return np.where(n < _K_SMALL.size, _K_SMALL[np.minimum(n, _K_SMALL.size - 1)], big)


def _nanmedian0(a: np.ndarray) -> np.ndarray:
    """nanmedian over axis 0, NaN (and no warning) for all-NaN columns.

    np.nanmedian goes through masked arrays and is ~10x slower on these small blocks.
    """
    s = np.sort(a, axis=0)  # NaN sorts last
    n = np.sum(~np.isnan(a), axis=0)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[None, :], axis=0)[0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0)[None, :] - (n == 0), axis=0)[0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def _window(a: np.ndarray, h: int) -> np.ndarray:
    """Stack ``a`` (n_rows, n_freq) with its shifts by -h..h lines: (n_rows (2h + 1), n_freq), NaN-padded."""
    rows, nf = a.shape
    out = np.full((2 * h + 1, rows, nf), np.nan)
    for j, s in enumerate(range(-h, h + 1)):
        if s >= 0:
            out[j, :, :nf - s] = a[:, s:]
        else:
            out[j, :, -s:] = a[:, :nf + s]
    return out.reshape(-1, nf)


def _window_sum(v: np.ndarray, h: int) -> np.ndarray:
    """Sum of ``v`` (n_freq,) over lines j-h..j+h (truncated at the ends)."""
    c = np.concatenate([[0.0], np.cumsum(v)])
    j = np.arange(v.size)
    return c[np.minimum(j + h + 1, v.size)] - c[np.maximum(j - h, 0)]


def _pooled_scale(u: np.ndarray, floor: float) -> np.ndarray:
    """Robust sigma per line from ``u = |r| / q(n)`` (n_runs, n_freq), shape (n_freq,).

    The median of u pooled over the narrowest window of lines (+-0 to +-3) holding >= _ROBUST_POOL
    values, else the widest; floored at ``floor``; NaN where no line nearby has two runs.
    """
    scale = np.full(u.shape[1], np.nan)
    for h in range(_MAX_HALF_WINDOW, -1, -1):  # narrowest window that has enough residuals wins
        w = _window(u, h)
        enough = np.sum(~np.isnan(w), axis=0) >= _ROBUST_POOL
        take = enough | (h == _MAX_HALF_WINDOW)
        if take.any():
            med = _nanmedian0(w[:, take])
            scale[take] = np.where(np.isnan(med), scale[take], med)
    return np.maximum(scale, floor)  # NaN stays NaN


def _centres(x: np.ndarray, group: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Median and run count of each value's group at its line, both shaped like x (n_runs, n_freq).

    Without ``group`` a line is one group; with it (1 = the minority branch at a split line,
    0 elsewhere) each branch of a split line has its own centre.
    """
    if group is None:
        return (np.broadcast_to(_nanmedian0(x), x.shape),
                np.broadcast_to(np.sum(~np.isnan(x), axis=0), x.shape))
    one = group == 1
    x1, x0 = np.where(one, x, np.nan), np.where(one, np.nan, x)
    centre = np.where(one, _nanmedian0(x1), _nanmedian0(x0))
    count = np.where(one, np.sum(~np.isnan(x1), axis=0), np.sum(~np.isnan(x0), axis=0))
    return centre, count


def _robust_z(x: np.ndarray, floor: float, group: np.ndarray | None = None) -> np.ndarray:
    """Calibrated robust z-scores of x (n_runs, n_freq), NaN where a group has < 3 runs.

    Centre: the median across the runs of each line (of each branch, at a split line: ``group``).
    Scale: the median of ``|x - centre| / q(n)`` pooled over the nearest lines holding
    >= _ROBUST_POOL residuals (at most +-3 lines), where q(n) is that median for n Gaussian runs,
    so the scale estimates sigma for any n >= 2. z = (x - centre) / (scale k(n)) has unit
    variance for clean Gaussian runs.
    """
    centre, n = _centres(x, group)
    r = x - centre
    u = np.where(n >= 2, np.abs(r) / _q(n), np.nan)
    z = r / (_pooled_scale(u, floor) * _k(n))
    return np.where(n >= 3, z, np.nan)


def _components(test: TestData) -> tuple[np.ndarray, np.ndarray]:
    # log-magnitude and phase [rad]: a complex relative error eps moves them by Re eps, Im eps
    return np.log(test.magnitude), np.radians(_phase_unwrapped_deg(test.phase_deg))


# --- response branches -------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Branches:
    """How the runs of one test split into two response branches (docs/data.md section 3b).

    Near a resonance a damper with a softening, weakly damped response can settle on either of two
    steady states (a fold), so at those lines the runs form two tight groups far apart, while
    elsewhere they agree.

    Attributes
    ----------
    split : bool
        True when the test has two branches.
    freq_hz : ndarray, shape (n_split,)
        The lines where the runs split [Hz], ascending (empty when not split).
    separation : ndarray, shape (n_split,)
        At each of them, the empty gap between the two groups in robust sigma (>= :data:`BRANCH_GAP`).
    minority : tuple of tuple of int
        At each of them, the ids of the smaller group's runs.
    runs : tuple
        ``(minority ids, majority ids)`` at the most balanced split line (ties: the widest gap);
        ``()`` when not split.
    kept : str
        What the cleaned data hold: ``"both"`` (every run of both branches; each run is scored
        against its own branch at the split lines, and the noise model sees the scatter between
        the branches), ``""`` when not split.

    Arrays are read-only.
    """

    split: bool = False
    freq_hz: np.ndarray = field(default_factory=lambda: _readonly([], float))
    separation: np.ndarray = field(default_factory=lambda: _readonly([], float))
    minority: tuple = ()
    runs: tuple = ()
    kept: str = ""

    @property
    def band_hz(self) -> tuple[float, float] | None:
        """(lowest, highest) split line [Hz], or None."""
        return (float(self.freq_hz[0]), float(self.freq_hz[-1])) if self.split else None

    def as_dict(self) -> dict:
        """JSON-ready: ``split``, ``band_hz``, ``lines_hz``, ``separation``, ``runs``,
        ``minority_runs`` (per line) and ``kept`` (None when not split)."""
        return {"split": self.split, "band_hz": None if self.band_hz is None else list(self.band_hz),
                "lines_hz": [float(f) for f in self.freq_hz],
                "separation": [round(float(s), 1) for s in self.separation],
                "runs": [list(g) for g in self.runs],
                "minority_runs": [list(g) for g in self.minority],
                "kept": self.kept or None}


_NO_BRANCHES = Branches()


def _line_splits(x: np.ndarray, floor: float):
    """Best two-group split of each line of x (n_runs, n_freq) along its values.

    Returns ``(separation, cut, n, m)``, each (n_freq,): the widest empty gap between the sorted
    values that leaves >= m runs on each side, in robust sigma (the scale of :func:`run_scores`),
    0 where no split is allowed; the gap's midpoint; the runs present; the minimum group size.
    """
    n = np.sum(~np.isnan(x), axis=0)
    u = np.where(n >= 2, np.abs(x - _nanmedian0(x)) / _q(n), np.nan)
    scale = _pooled_scale(u, floor)
    m = np.maximum(BRANCH_MIN_RUNS, np.ceil(BRANCH_MIN_FRACTION * n)).astype(int)
    o = np.sort(x, axis=0)  # NaN last
    k = np.arange(1, x.shape[0])[:, None]  # the cut between sorted values k - 1 and k: k runs below it
    ok = (k >= m) & (n - k >= m)
    with np.errstate(invalid="ignore"):
        sep = np.where(ok, np.diff(o, axis=0) / scale, 0.0)
    sep = np.nan_to_num(sep, nan=0.0)  # no scale (no line nearby with two runs): no split
    best_k = np.argmax(sep, axis=0) if sep.size else np.zeros(x.shape[1], int)
    cols = np.arange(x.shape[1])
    best = sep[best_k, cols] if sep.size else np.zeros(x.shape[1])
    cut = 0.5 * (o[best_k, cols] + o[np.minimum(best_k + 1, x.shape[0] - 1), cols])
    return best, cut, n, m


def _branch_groups(test: TestData, floor: float, comps=None) -> tuple[Branches, np.ndarray | None]:
    """:class:`Branches` of a test and the group of every value (1: minority branch at a split
    line, 0 elsewhere; int8 (n_runs, n_freq)), or None when the test does not split.
    ``comps``: the test's :func:`_components`, when already at hand."""
    comps = _components(test) if comps is None else comps
    (sep0, cut0, n, m), (sep1, cut1, _, _) = (_line_splits(c, floor) for c in comps)
    phase = sep1 > sep0  # the component that splits the line more clearly decides its groups
    sep = np.where(phase, sep1, sep0)
    split = sep >= BRANCH_GAP
    n_split, n_testable = int(split.sum()), int(np.sum(n >= 2 * m))
    if n_split == 0 or n_split > BRANCH_MAX_LINE_FRACTION * n_testable:
        return _NO_BRANCHES, None
    x = np.where(phase, comps[1], comps[0])
    present = ~np.isnan(x)
    upper = present & (x > np.where(phase, cut1, cut0))
    n_up = upper.sum(axis=0)
    up_is_minority = n_up <= n - n_up
    minor = np.where(up_is_minority, upper, present & ~upper) & split
    group = minor.astype(np.int8)
    lines = np.flatnonzero(split)
    size = minor.sum(axis=0)
    main = lines[np.lexsort((-sep[lines], -size[lines]))[0]]  # most balanced, then widest gap
    ids = test.runs
    branches = Branches(
        split=True, freq_hz=_readonly(test.freq_hz[lines], float), separation=_readonly(sep[lines], float),
        minority=tuple(tuple(int(r) for r in ids[minor[:, j]]) for j in lines),
        runs=(tuple(int(r) for r in ids[minor[:, main]]),
              tuple(int(r) for r in ids[present[:, main] & ~minor[:, main]])),
        kept="both")
    return branches, group


def find_branches(test: TestData, *, floor: float = NOISE_FLOOR) -> Branches:
    """Detect two response branches among a test's runs (docs/data.md section 3b).

    A line splits when its runs, sorted by log-magnitude or by phase, leave an empty gap of at
    least :data:`BRANCH_GAP` robust sigma with at least ``max(BRANCH_MIN_RUNS,
    BRANCH_MIN_FRACTION n)`` runs on each side. The test has two branches when 1 to
    :data:`BRANCH_MAX_LINE_FRACTION` of the lines that could split do: confined to a band, as a
    fold near a resonance is; a group of bad runs that differs on most lines is not a branch.

    Parameters
    ----------
    test : TestData
    floor : float
        Lower bound of the robust scale, as in :func:`run_scores`.

    Returns
    -------
    Branches
    """
    return _branch_groups(test, floor)[0]


# --- outlier runs (thesis 2.6) -------------------------------------------------------------------

def _scores(test: TestData, floor: float):
    """(run scores, branches, groups, components): see :func:`run_scores`, :func:`_branch_groups`."""
    comps = _components(test)
    branches, group = _branch_groups(test, floor, comps)
    out = np.full(test.runs.size, -np.inf)
    for c in comps:
        z2 = _robust_z(c, floor, group) ** 2
        count = np.sum(~np.isnan(z2), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(np.where(count > 0, np.nansum(z2, axis=1) / np.maximum(count, 1), np.nan))
        out = np.fmax(out, rms)  # fmax: NaN only when both are
    return np.where(np.isinf(out), np.nan, out), branches, group, comps


def run_scores(test: TestData, *, floor: float = NOISE_FLOOR) -> np.ndarray:
    """Outlier score of each whole run: the RMS over lines of its robust z-scores, taking the worse
    of log-magnitude and phase.

    Parameters
    ----------
    test : TestData
    floor : float
        Lower bound of the robust scale (log-magnitude and rad), so identical runs give finite z.

    Returns
    -------
    ndarray, shape (n_runs,)
        ``max(sqrt(mean_j z_mag_ij^2), sqrt(mean_j z_phase_ij^2))`` over the lines j of run i that
        at least three runs share (z is undefined with fewer); NaN for a run with no such line.
        A clean run scores about 1. Taking the worse component (not their mean) keeps a curve that
        is off in magnitude only, or in phase only, from being diluted by the other. In a test
        with two response branches (:func:`find_branches`) a run is standardised against its own
        branch at the split lines, so a branch is not scored as a group of outliers.
    """
    return _scores(test, floor)[0]


@dataclass(frozen=True, eq=False)
class CleanedTest:
    """A test after outlier-run removal.

    Attributes
    ----------
    data : TestData
        The kept runs.
    removed_runs : tuple of int
        Ids of the removed runs, ascending.
    scores : ndarray, shape (n_runs,)
        Run score of every run of the *input* test (its ``runs`` order); see :func:`run_scores`.
    branches : Branches
        Response branches of the input test; when ``branches.split``, ``branches.kept == "both"``:
        :attr:`data` holds the runs of both branches (none removed for its branch), and the noise
        model sees the scatter between them (docs/data.md section 3b says why).
    """

    data: TestData
    removed_runs: tuple[int, ...]
    scores: np.ndarray
    branches: Branches = _NO_BRANCHES


def _check_threshold(z_threshold) -> float:
    z = float(z_threshold)
    if not (math.isfinite(z) and z > 0):
        raise InputError(f"z threshold {z_threshold!r}: must be a finite number > 0")
    return z


def _outliers(scores: np.ndarray, z_threshold: float) -> np.ndarray:
    """Indices of removed runs: score > threshold, worst first, keeping >= 3 runs and a majority."""
    n = scores.size
    max_remove = max(0, n - max(3, n // 2 + 1))  # the median/MAD centre needs a clean majority
    flagged = np.flatnonzero(np.nan_to_num(scores, nan=-np.inf) > z_threshold)
    worst_first = flagged[np.argsort(-scores[flagged], kind="stable")]
    return np.sort(worst_first[:max_remove])


def remove_outlier_runs(test: TestData, z_threshold: float = DEFAULT_Z_THRESHOLD) -> CleanedTest:
    """Remove whole outlier curves by the Z-score method (thesis section 2.6).

    Each line's log-magnitude and phase are standardised across runs with a robust centre
    (median) and scale (MAD, pooled over neighbouring lines and corrected for the number of
    runs), so an outlier cannot hide by inflating sigma; each run is scored by the RMS over lines
    of its z-scores, the worse of magnitude and phase (:func:`run_scores`), and removed if the
    score exceeds ``z_threshold``. When the runs settle on two response branches
    (:func:`find_branches`), each run is standardised against its own branch at the split lines:
    the minority branch is kept and reported, not removed; isolated outliers still are.

    Parameters
    ----------
    test : TestData
    z_threshold : float
        Default :data:`DEFAULT_Z_THRESHOLD` = 3. A clean run is flagged with probability ~0 when
        its noise is independent from line to line, and at worst (one common offset on all
        lines) 0.54 % for many runs, 3.2 % with 12 runs, 8 % with 4-5; Z = 2, the thesis's
        other choice, flags 9-16 % of good runs in that case.

    Returns
    -------
    CleanedTest
        At most ``n_runs - max(3, n_runs // 2 + 1)`` runs are removed (the worst scores first),
        so at least three runs and a majority remain; a test of three runs or fewer is never cut.
        ``branches`` says whether the test split and that both branches were kept.
    """
    z = _check_threshold(z_threshold)
    scores, branches, _, _ = _scores(test, NOISE_FLOOR)
    out = _outliers(scores, z)
    scores = _readonly(scores, float)
    if out.size == 0:
        return CleanedTest(test, (), scores, branches)
    kept = np.delete(test.runs, out)
    return CleanedTest(test.select_runs(kept), tuple(int(r) for r in test.runs[out]), scores, branches)


# --- noise model for the likelihood -------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class NoiseModel:
    """Scatter of ONE run about the test's mean curve, per frequency line.

    Attributes
    ----------
    freq_hz : ndarray, shape (n_freq,)
        The test's lines [Hz].
    sigma_logmag : ndarray, shape (n_freq,)
        Standard deviation of ``ln |F/X|`` of one run (dimensionless: a relative error).
    sigma_phase : ndarray, shape (n_freq,)
        Standard deviation of the phase of one run [rad].
    n_runs : ndarray of int, shape (n_freq,)
        Runs of the input test present at each line.
    dof_logmag, dof_phase : ndarray of int, shape (n_freq,)
        Degrees of freedom behind each sigma: ``sum_k (n_k - 1)`` over the lines k pooled into
        it (after the glitch screen, so they may differ between the components); 0 where
        ``single_run_sigma`` was used. The likelihood's Student-t degrees of freedom.

    Sigmas are finite and >= :data:`NOISE_FLOOR`.
    """

    freq_hz: np.ndarray
    sigma_logmag: np.ndarray
    sigma_phase: np.ndarray
    n_runs: np.ndarray
    dof_logmag: np.ndarray
    dof_phase: np.ndarray


def _pooled_sigma(x: np.ndarray, floor: float, single_run_sigma: float, group: np.ndarray | None = None,
                  split: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-line sigma and its degrees of freedom of x (n_runs, n_freq): classical pooled variance
    after a robust value screen.

    ``group``/``split`` describe response branches (:func:`_branch_groups`): the screen centres each
    branch on its own median (a branch is not a glitch), a split line keeps the scatter about its
    overall mean (both branches), uses its own lines only and is left out of its neighbours' pools.
    """
    z = _robust_z(x, floor, group)
    glitch = (np.abs(z) > _VALUE_Z) & (np.sum(~np.isnan(x), axis=0) >= _VALUE_MIN_RUNS)  # NaN z: False
    x = np.where(glitch, np.nan, x)
    n = np.sum(~np.isnan(x), axis=0)
    mean = np.where(n > 0, np.nansum(x, axis=0) / np.maximum(n, 1), 0.0)
    ss = np.nansum((x - mean) ** 2, axis=0)
    dof = np.maximum(n - 1, 0).astype(float)
    alone = np.zeros(n.size, bool) if split is None else split
    ss_pool, dof_pool = np.where(alone, 0.0, ss), np.where(alone, 0.0, dof)
    ss_w, dof_w = ss.copy(), dof.copy()
    done = (dof >= _POOL_DOF) | alone
    for h in range(1, _MAX_HALF_WINDOW + 1):  # the narrowest window with enough dof, else the widest
        s_h, d_h = _window_sum(ss_pool, h), _window_sum(dof_pool, h)
        take = ~done & ((d_h >= _POOL_DOF) | (h == _MAX_HALF_WINDOW))
        ss_w[take], dof_w[take] = s_h[take], d_h[take]
        done |= take
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.where(dof_w > 0, np.sqrt(ss_w / dof_w), single_run_sigma)
    return np.maximum(sigma, floor), np.rint(dof_w).astype(np.int64)


def noise_model(test: TestData, *, z_threshold: float = DEFAULT_Z_THRESHOLD, floor: float = NOISE_FLOOR,
                single_run_sigma: float = SINGLE_RUN_SIGMA) -> NoiseModel:
    """Repeatability of one run, per line, from the scatter of the repeats.

    Steps, for log-magnitude and phase [rad] separately:

    1. whole outlier runs are set aside as in :func:`remove_outlier_runs` (``z_threshold``);
    2. single values more than 8 robust sigma from their line's median (their branch's median,
       at a line where the runs split into two branches) are dropped, on lines with >= 4 runs;
    3. ``sigma_j^2 = sum_k SS_k / sum_k (n_k - 1)`` over the lines k within +-h of line j, with
       ``SS_k`` the sum of squared deviations from line k's mean and h the smallest half-width
       (0 to 3 lines) that gives >= 10 degrees of freedom -- h = 0 from 11 runs on;
       unbiased for sigma^2 whatever the number of runs. A line where the runs split into two
       branches keeps the scatter of both about their common mean, pools nothing and is pooled
       into no other line;
    4. lines with no degree of freedom within +-3 lines (a single run) get ``single_run_sigma``;
       every sigma is at least ``floor``.

    Parameters
    ----------
    test : TestData
    z_threshold : float
        Run-score threshold of step 1.
    floor : float
        Lower bound, default :data:`NOISE_FLOOR` (0.2 %, 0.002 rad).
    single_run_sigma : float
        Default :data:`SINGLE_RUN_SIGMA` (5 %, 0.05 rad) where no repeat is available.

    Returns
    -------
    NoiseModel
        Shapes (n_freq,) on ``test.freq_hz``; all sigmas finite and > 0; ``dof_*`` the degrees
        of freedom of step 3 (0 where step 4 applied).
    """
    z = _check_threshold(z_threshold)
    if not (math.isfinite(floor) and floor > 0 and math.isfinite(single_run_sigma) and single_run_sigma > 0):
        raise InputError("noise_model: floor and single_run_sigma must be finite and > 0")
    scores, branches, group, comps = _scores(test, floor)
    keep = np.ones(test.runs.size, bool)
    keep[_outliers(scores, z)] = False
    logmag, phase = (c[keep] for c in comps)
    group = None if group is None else group[keep]
    split = np.isin(test.freq_hz, branches.freq_hz) if branches.split else None
    sig_m, dof_m = _pooled_sigma(logmag, floor, single_run_sigma, group, split)
    sig_p, dof_p = _pooled_sigma(phase, floor, single_run_sigma, group, split)
    return NoiseModel(
        freq_hz=_readonly(test.freq_hz, float),
        sigma_logmag=_readonly(sig_m, float),
        sigma_phase=_readonly(sig_p, float),
        n_runs=_readonly(test.present.sum(axis=0), np.int64),
        dof_logmag=_readonly(dof_m, np.int64),
        dof_phase=_readonly(dof_p, np.int64),
    )


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
        they match no line). JSON-serialisable.
    """
    z = _check_threshold(z_threshold)
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
    return out


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
    if entry.get("unmatched"):
        vals = ", ".join(f"run {u['run']} at {u['frequency_hz']:g} Hz (line {u['nearest_line_hz']:g})"
                         for u in entry["unmatched"][:5])
        more = f" and {len(entry['unmatched']) - 5} more" if len(entry["unmatched"]) > 5 else ""
        notes.append(f"unmatched frequencies, left out: {vals}{more}")
    return notes


# --- writing ------------------------------------------------------------------------------------

def test_label(amplitude_mm_pp: float) -> str:
    """The thesis's label of a constant-amplitude test: ``0.5 -> "0.5-0.5"``, ``1 -> "1-1"``."""
    a = f"{float(amplitude_mm_pp):g}"
    return f"{a}-{a}"


test_label.__test__ = False  # a library function, not a pytest test


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
    DataFrame with :data:`BENCH_COLUMNS`, phase in degrees in (-90, 270]: the passive band
    (0, 180) plus 90 deg either side, so noise about 0 or 180 deg is never wrapped by a turn.
    """
    fuu = np.atleast_2d(fuu)
    n_runs, n_freq = fuu.shape
    runs = np.arange(1, n_runs + 1) if runs is None else np.asarray(runs)
    amp = np.broadcast_to(np.asarray(amplitude_mm_pp, dtype=float), (n_freq,))
    phase = np.degrees(np.angle(fuu))
    phase = np.where(phase <= -90.0, phase + 360.0, phase)  # contract: not wrapped near 180 deg
    return pd.DataFrame({
        "damper": damper,
        "test": test,
        "run": np.repeat(runs, n_freq),
        "frequency_hz": np.tile(np.asarray(freq_hz, dtype=float), n_runs),
        "amplitude_mm_pp": np.tile(amp, n_runs),
        "stiffness_n_per_m": np.abs(fuu).ravel(),
        "phase_deg": phase.ravel(),
    }, columns=list(BENCH_COLUMNS))


def write_bench(frame: pd.DataFrame, path) -> None:
    """Write bench rows as CSV, atomically (no partial file on interruption)."""
    with atomic_path(path, ".csv") as tmp:
        frame.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")


def rows_digest(bench: BenchData, damper: str, test: str | None = None) -> str:
    """sha256 of a damper's (or one test's) rows: independent of row order and of the file's format
    (a CSV, a workbook and a Parquet file of the same rows agree). What a stored result was made from."""
    import hashlib

    f = bench.frame
    sel = f[(f["damper"] == damper) & ((f["test"] == test) if test is not None else True)]
    sel = sel[list(BENCH_COLUMNS)].sort_values(["test", "run", "frequency_hz"], kind="mergesort")
    return hashlib.sha256(sel.to_csv(index=False, float_format="%.17g").encode()).hexdigest()
