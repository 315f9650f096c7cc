"""Bench recordings as arrays: the long-format contract (``docs/formats.md``; one row per run and
frequency line: ``damper, test, run, frequency_hz, amplitude_mm_pp, stiffness_n_per_m, phase_deg``,
phase in degrees, convention exp(+i w t)), one test's runs matched to its lines, and writing.

Data flow: :func:`sbcal.data.readers.load_bench` (read any format, validate with one set of checks)
-> :meth:`BenchData.test` (one damper and test as arrays, each run's frequencies matched to the
test's lines) -> :mod:`sbcal.data.cleaning` (quality, thesis section 2.5; outlier runs, section 2.6;
response branches) -> :func:`sbcal.data.noise.noise_model` (per-line scatter of one run, for the
likelihood). The rules and the statistics are described in ``docs/data.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pandas as pd

from ..core._io import atomic_path
from ..core.errors import InputError


__all__ = [
    "BENCH_COLUMNS", "MEASURED_COLUMNS", "SE_DEFAULT_DOF", "THESIS_TESTS", "FREQ_REL_TOL", "FREQ_STEP_FRACTION", "FREQ_NEAR_REL", "TestData", "BenchData",
    "test_label", "curves_to_frame", "write_bench", "rows_digest", "readonly", "nanmedian0",
]

BENCH_COLUMNS = (
    "damper", "test", "run", "frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m", "phase_deg",
)

MEASURED_COLUMNS = (
    "stiffness_se_n_per_m", "phase_se_deg", "se_windows", "distortion", "amplitude_achieved_mm_pp",
)
"""Optional columns a bench file may carry per row (``sbcal import`` writes them; ``docs/formats.md``): the
standard errors of the line's magnitude [N/m] and phase [deg] from its period-to-period variation, the number of
whole-period windows behind them (degrees of freedom ``se_windows - 1``), the force's harmonic distortion
``sqrt(sum_{h>=2} |F_h|^2) / |F_1|`` and the base amplitude achieved [mm p-p]. Blank where not measured; files
without them read as before."""

SE_DEFAULT_DOF = 9
"""Degrees of freedom of a measured standard error whose row has no ``se_windows`` (10 windows, as
``sbcal import`` takes at least)."""

THESIS_TESTS = ("0.1-0.1", "0.2-0.2", "0.3-0.3", "0.4-0.4", "0.5-0.5", "1-1", "2-2", "2-1", "1-1-oiled")
"""The seed thesis's test labels in its own order (Table 4.5)."""

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


# --- arrays of one test ------------------------------------------------------------------------

_MEASURED_FIELDS = ("se_logmag", "se_phase", "se_dof", "distortion")

def readonly(a, dtype=None) -> np.ndarray:
    """A read-only copy of ``a`` as an array (of ``dtype`` when given)."""
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
    se_logmag, se_phase : ndarray, shape (n_runs, n_freq), or None
        Measured standard errors of ``ln |F/X|`` [1] and of the phase [rad] of each run's line (the bench file's
        :data:`MEASURED_COLUMNS`); NaN where not measured; None when the file has no such column.
    se_dof : ndarray of int, shape (n_runs, n_freq), or None
        Degrees of freedom behind them (``se_windows - 1``; 0 where not measured).
    distortion : ndarray, shape (n_runs, n_freq), or None
        Measured harmonic distortion of the force [1]; NaN where not measured.

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
    se_logmag: np.ndarray | None = None
    se_phase: np.ndarray | None = None
    se_dof: np.ndarray | None = None
    distortion: np.ndarray | None = None

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "runs", readonly(self.runs, np.int64))
        for name in ("freq_hz", "amplitude_mm_pp", "magnitude", "phase_deg"):
            set_(self, name, readonly(self.__dict__[name], float))
        for name in _MEASURED_FIELDS:
            if self.__dict__[name] is not None:
                set_(self, name, readonly(self.__dict__[name], np.int64 if name == "se_dof" else float))
                if self.__dict__[name].shape != self.magnitude.shape:
                    raise ValueError(f"TestData: {name} must have the shape of magnitude")
        set_(self, "unmatched", tuple((int(r), float(f), float(c)) for r, f, c in self.unmatched))
        n_runs, n_freq = self.runs.size, self.freq_hz.size
        if self.runs.ndim != 1 or self.freq_hz.ndim != 1 or self.amplitude_mm_pp.shape != (n_freq,):
            raise ValueError("TestData: runs, freq_hz and amplitude_mm_pp must be 1-D, the last two of equal length")
        if self.magnitude.shape != (n_runs, n_freq) or self.phase_deg.shape != (n_runs, n_freq):
            raise ValueError(f"TestData: magnitude and phase_deg must have shape {(n_runs, n_freq)}")

    @property
    def measured_noise(self) -> bool:
        """Whether any line carries a measured standard error."""
        return self.se_logmag is not None and bool(np.isfinite(self.se_logmag).any())

    def line_distortion(self) -> np.ndarray | None:
        """The measured force distortion per line: the median over the runs that have it, shape (n_freq,), NaN
        where none does; None when nothing was measured."""
        if self.distortion is None or not np.isfinite(self.distortion).any():
            return None
        return nanmedian0(self.distortion)

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
        cut = np.ix_(rows, cols)
        measured = {k: (None if self.__dict__[k] is None else self.__dict__[k][cut]) for k in _MEASURED_FIELDS}
        return TestData(self.damper, self.test, ids, self.freq_hz[cols], self.amplitude_mm_pp[cols],
                        self.magnitude[cut], self.phase_deg[cut], tuple(u for u in self.unmatched if u[0] in keep),
                        **measured)


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
        :data:`BENCH_COLUMNS` and those of :data:`MEASURED_COLUMNS` the file has: ``run`` int64, labels
        stripped of surrounding blanks, the rest float64 (the contract's all finite; a measured value NaN where
        not measured).
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

        def grid(col, fill=np.nan):
            g = np.full((runs.size, centres.size), fill)
            if col in f:
                g[ri, line[ok]] = f[col].to_numpy(dtype=float)[idx][ok]
            return g

        measured = {}
        if "stiffness_se_n_per_m" in f:  # the reader allows it only with phase_se_deg
            with np.errstate(invalid="ignore"):
                measured["se_logmag"] = grid("stiffness_se_n_per_m") / grids[1]
            measured["se_phase"] = np.radians(grid("phase_se_deg"))
            windows = grid("se_windows") if "se_windows" in f else np.full(measured["se_phase"].shape, np.nan)
            dof = np.where(np.isfinite(windows), windows - 1, SE_DEFAULT_DOF)
            measured["se_dof"] = np.where(np.isfinite(measured["se_phase"]), dof, 0).astype(np.int64)
        if "distortion" in f:
            measured["distortion"] = grid("distortion")
        # every line has at least one run by construction: the median is defined everywhere
        return TestData(damper, test, runs, centres, nanmedian0(grids[0]), grids[1], grids[2], tuple(unmatched),
                        **measured)


def nanmedian0(a: np.ndarray) -> np.ndarray:
    """nanmedian over axis 0, NaN (and no warning) for all-NaN columns.

    np.nanmedian goes through masked arrays and is ~10x slower on these small blocks.
    """
    s = np.sort(a, axis=0)  # NaN sorts last
    n = np.sum(~np.isnan(a), axis=0)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[None, :], axis=0)[0]
    hi = np.take_along_axis(s, np.maximum(n // 2, 0)[None, :] - (n == 0), axis=0)[0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


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
    sel = sel[[c for c in BENCH_COLUMNS + MEASURED_COLUMNS if c in f]].sort_values(["test", "run", "frequency_hz"], kind="mergesort")
    return hashlib.sha256(sel.to_csv(index=False, float_format="%.17g").encode()).hexdigest()
