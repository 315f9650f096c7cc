"""Bench recordings: the CSV contract (``shared/spec/formats.md`` section 2), quality check,
outlier-run removal and the repeatability noise model.

Long format, one row per (run, frequency line): ``damper, test, run, frequency_hz,
amplitude_mm_pp, stiffness_n_per_m, phase_deg`` (phase in degrees, convention exp(+i w t)).

Data flow: :func:`load_bench` (validate) -> :meth:`BenchData.test` (one damper and test as
arrays) -> :func:`quality_table` (thesis section 2.5) -> :func:`remove_outlier_runs` (section
2.6, whole curves) -> :func:`noise_model` (per-line scatter of one run, for the likelihood).
The rules and the statistics are described in ``docs/data.md``.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import warnings
from collections import defaultdict
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path

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
    "TestData",
    "BenchData",
    "CleanedTest",
    "NoiseModel",
    "load_bench",
    "default_bench_path",
    "quality_table",
    "run_scores",
    "remove_outlier_runs",
    "noise_model",
    "CV_BANDS_HZ",
    "bench_summary",
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
    """The runs of one (damper, test) on the union of their frequency lines.

    Attributes
    ----------
    damper, test : str
    runs : ndarray of int, shape (n_runs,)
        Run ids, ascending.
    freq_hz : ndarray, shape (n_freq,)
        Union of the runs' frequency lines [Hz], ascending.
    amplitude_mm_pp : ndarray, shape (n_freq,)
        Commanded base displacement per line [mm p-p], the median over the runs that have it.
    magnitude : ndarray, shape (n_runs, n_freq)
        Dynamic stiffness |F/X| [N/m]; NaN only where that run lacks that line.
    phase_deg : ndarray, shape (n_runs, n_freq)
        Phase of F/X [deg], not wrapped; NaN where :attr:`magnitude` is.

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

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "runs", _readonly(self.runs, np.int64))
        for name in ("freq_hz", "amplitude_mm_pp", "magnitude", "phase_deg"):
            set_(self, name, _readonly(self.__dict__[name], float))
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
        is unchanged (it is a property of the test, not of a run).

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
        return TestData(self.damper, self.test, ids, self.freq_hz[cols], self.amplitude_mm_pp[cols],
                        self.magnitude[np.ix_(rows, cols)], self.phase_deg[np.ix_(rows, cols)])


def _test_order(label: str):
    # thesis labels first, in the thesis's order; anything else after, sorted
    return (THESIS_TESTS.index(label), "") if label in THESIS_TESTS else (len(THESIS_TESTS), label)


@dataclass(frozen=True, eq=False)
class BenchData:
    """Validated bench recordings of one file.

    Attributes
    ----------
    source : str
        The file read.
    frame : DataFrame
        The validated rows in file order, the seven :data:`BENCH_COLUMNS` only: ``run`` int64,
        labels stripped of surrounding blanks, the rest float64 (all finite).
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
        runs, ri = np.unique(run, return_inverse=True)
        freqs, fi = np.unique(freq, return_inverse=True)
        grids = []
        for col in ("amplitude_mm_pp", "stiffness_n_per_m", "phase_deg"):
            g = np.full((runs.size, freqs.size), np.nan)
            g[ri, fi] = f[col].to_numpy()[idx]
            grids.append(g)
        # every line has at least one run by construction: the median is defined everywhere
        return TestData(damper, test, runs, freqs, _nanmedian0(grids[0]), grids[1], grids[2])


# --- reading and validating the CSV ------------------------------------------------------------

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


def _open_text(path: Path):
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="")
    return open(path, encoding="utf-8-sig", newline="")


def _blank(record: list) -> bool:
    # what pandas' skip_blank_lines skips: an empty or all-whitespace line (no delimiter)
    return len(record) == 0 or (len(record) == 1 and not record[0].strip())


def _read_header(path: Path) -> tuple[int, list[str]]:
    """(line number, field names) of the first non-blank line; errors as one line."""
    with _open_text(path) as fh:
        reader = csv.reader(fh)
        end = 0
        for rec in reader:
            start, end = end + 1, reader.line_num
            if not _blank(rec):
                return start, rec
    raise InputError(f"{path}: empty file, expected the header line {','.join(BENCH_COLUMNS)}")


def _record_lines(path: Path, rows) -> dict[int, int]:
    """First physical line (1-based) of data records ``rows`` (0-based, pandas' row order).

    Only called to report an error, so a plain Python pass over the file is fine; it follows
    quoted fields that span lines, which pandas' row index cannot.
    """
    wanted, out = set(int(r) for r in rows), {}
    with _open_text(path) as fh:
        reader = csv.reader(fh)
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


_NUMERIC = BENCH_COLUMNS[2:]
_POSITIVE = ("frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m")


def _too_many_fields(path: Path, n_fields: int) -> InputError | None:
    """The first record with more fields than the header (error path only)."""
    with _open_text(path) as fh:
        reader = csv.reader(fh)
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


def _read_frame(path: Path, header: list[str], dtypes: dict) -> pd.DataFrame:
    """The file's contract columns, renamed to :data:`BENCH_COLUMNS`; other columns read as text.

    ``dtypes`` maps contract names to str or float. A row with more fields than the header is an
    error (pandas would silently shift or drop them); only a trailing empty field on every row
    (a trailing comma) passes, as pandas drops it without loss.
    """
    names = {h: h.strip() for h in header}
    dtype = defaultdict(lambda: str, {h: dtypes[c] for h, c in names.items() if c in dtypes})
    kw = dict(index_col=False, dtype=dtype, skip_blank_lines=True, encoding="utf-8-sig",
              compression="gzip" if path.suffix == ".gz" else None)
    if dtypes["run"] is str:
        kw.update(keep_default_na=False)
    try:
        with warnings.catch_warnings():
            # "Length of header or names does not match length of data": fields would be lost
            warnings.simplefilter("error", pd.errors.ParserWarning)
            df = pd.read_csv(path, **kw)
    except (pd.errors.ParserError, pd.errors.ParserWarning) as e:
        raise (_too_many_fields(path, len(header)) or InputError(
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


def _clean_labels(df: pd.DataFrame) -> None:
    """Strip blanks around damper and test labels (in place); few unique labels make it cheap."""
    for col in ("damper", "test"):
        uniq = pd.unique(df[col].dropna())
        if any(u != u.strip() for u in uniq):
            df[col] = df[col].str.strip()


def _problems(df: pd.DataFrame, text: pd.DataFrame | None) -> list:
    """[(column, bad-row mask, problem(row) -> str)] of the failing checks, in column order.

    ``text`` is the file read as strings (to explain a problem) or None (fast path: masks only).
    """
    def raw(col, i):
        return text[col].iloc[i].strip() if text is not None else "?"

    checks = []
    for col in ("damper", "test"):
        s = df[col]
        empty = [u for u in pd.unique(s) if not isinstance(u, str) or not u]  # NaN or ""
        checks.append((col, s.isin(empty).to_numpy() | s.isna().to_numpy(), lambda i: "empty value"))
    run = df["run"].to_numpy(dtype=float)
    bad_run = ~np.isfinite(run) | (run != np.round(run)) | (np.abs(run) > _MAX_RUN_ID)

    def run_problem(i):
        s = raw("run", i)
        return "empty value" if s == "" else f"expected an integer run id, got {s!r}"

    checks.append(("run", bad_run, run_problem))
    for col in _NUMERIC[1:]:
        x = df[col].to_numpy(dtype=float)
        bad = ~np.isfinite(x)
        if col in _POSITIVE:
            bad |= x <= 0  # NaN compares False: already flagged

        def problem(i, col=col, x=x):
            s = raw(col, i)
            if s == "":
                return "empty value"
            if np.isfinite(x[i]):
                return f"must be > 0, got {s}"
            parsed = pd.to_numeric(pd.Series([s]), errors="coerce").iloc[0]
            if np.isnan(parsed) and s.lower().lstrip("+-") != "nan":
                return f"expected a number, got {s!r}"
            return f"value {s!r} is not finite"

        checks.append((col, bad, problem))
    return [c for c in checks if c[1].any()]


def _raise_first(path: Path, found: list) -> None:
    """InputError for the earliest bad row of ``found`` (ties: column order)."""
    row, k = min((int(np.argmax(mask)), k) for k, (_, mask, _) in enumerate(found))
    col, _, describe = found[k]
    n_bad = int(np.logical_or.reduce([m for _, m, _ in found]).sum())
    line = _record_lines(path, [row]).get(row, row + 2)
    more = f" (first of {n_bad} bad rows)" if n_bad > 1 else ""
    raise InputError(f"{path}: line {line}: column '{col}': {describe(row)}{more}")


def load_bench(path) -> BenchData:
    """Read and validate bench recordings (the CSV contract, ``formats.md`` section 2).

    Parameters
    ----------
    path : str or path-like
        A ``.csv`` file, or ``.csv.gz`` (gzip). UTF-8 (a byte-order mark is allowed), comma
        separated, header required. Columns may come in any order; extra columns are ignored;
        blank lines are skipped. Several dampers and tests may share one file; any frequency grid
        is accepted, runs of one test need not share it, and the amplitude may vary with frequency.

    Returns
    -------
    BenchData

    Raises
    ------
    InputError
        One line naming the file, the 1-based file line (header = line 1) and the column, for
        the earliest bad row: a missing column; an empty, non-numeric, NaN or infinite value;
        ``frequency_hz``, ``amplitude_mm_pp`` or ``stiffness_n_per_m`` <= 0; a ``run`` that is
        not an integer (``3.0`` and ``3e0`` are read as 3; ``1.5`` and ``a`` are rejected); an
        empty damper or test label; a row with more fields than the header; two rows with the
        same (damper, test, run, frequency_hz) (both lines are named); an empty file or a header
        with no data rows; a missing, unreadable or non-UTF-8 file.

    Notes
    -----
    The happy path is one typed ``pandas.read_csv`` and vectorised checks. Only when a check
    fails is the file re-read as text to say exactly what is wrong, and where.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a CSV file")
    try:
        header_line, header = _read_header(p)
    except UnicodeDecodeError:
        raise _not_utf8(p) from None
    except (OSError, EOFError) as e:
        raise InputError(f"{p}: cannot read: {e}") from None
    except csv.Error as e:
        raise InputError(f"{p}: malformed CSV: {e}") from None
    names = [h.strip() for h in header]
    for col in BENCH_COLUMNS:
        count = names.count(col)
        if count == 0:
            raise InputError(f"{p}: line {header_line}: missing column '{col}' "
                             f"(required: {','.join(BENCH_COLUMNS)})")
        if count > 1:
            raise InputError(f"{p}: line {header_line}: column '{col}' appears {count} times")
    fast = {c: (str if c in ("damper", "test") else float) for c in BENCH_COLUMNS}
    try:
        df = _read_frame(p, header, fast)
        _clean_labels(df)
        clean = not _problems(df, None)
    except InputError:
        raise
    except ValueError:
        clean = False  # a non-numeric value: the text pass says which
    if not clean:
        # labels such as "NA" are valid text but NaN to the typed reader: the text pass decides
        text = _read_frame(p, header, dict.fromkeys(BENCH_COLUMNS, str))
        df = pd.DataFrame({c: (text[c] if c in ("damper", "test")
                               else pd.to_numeric(text[c], errors="coerce").astype(float))
                           for c in BENCH_COLUMNS})
        _clean_labels(df)
        found = _problems(df, text)
        if found:
            _raise_first(p, found)
    if len(df) == 0:
        raise InputError(f"{p}: line {header_line}: header only, no data rows")

    df = df[list(BENCH_COLUMNS)].reset_index(drop=True)
    df["run"] = df["run"].to_numpy(dtype=float).astype(np.int64)
    key = ["damper", "test", "run", "frequency_hz"]
    dup = df.duplicated(subset=key, keep="first").to_numpy()
    if dup.any():
        b = int(np.argmax(dup))
        row = df.iloc[b]
        same = np.ones(len(df), bool)
        for c in key:
            same &= (df[c] == row[c]).to_numpy()
        a = int(np.argmax(same))
        lines = _record_lines(p, [a, b])
        raise InputError(
            f"{p}: line {lines.get(b, b + 2)}: columns 'damper','test','run','frequency_hz': duplicate of line "
            f"{lines.get(a, a + 2)} ({row['damper']} {row['test']} run {row['run']} at {row['frequency_hz']:g} Hz)")
    return BenchData(source=str(p), frame=df)


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


# --- robust standardisation, outlier runs (thesis 2.6) ------------------------------------------

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


def _robust_z(x: np.ndarray, floor: float) -> np.ndarray:
    """Calibrated robust z-scores of x (n_runs, n_freq), NaN where a line has < 3 runs.

    Centre: the median across runs of each line. Scale: the median of ``|x - centre| / q(n)``
    pooled over the nearest lines holding >= _ROBUST_POOL residuals (at most +-3 lines), where
    q(n) is that median for n Gaussian runs, so the scale estimates sigma for any n >= 2.
    z = (x - centre) / (scale k(n)) has unit variance for clean Gaussian runs.
    """
    n = np.sum(~np.isnan(x), axis=0)
    r = x - _nanmedian0(x)
    u = np.where(n >= 2, np.abs(r) / _q(n), np.nan)
    scale = np.full(x.shape[1], np.nan)
    for h in range(_MAX_HALF_WINDOW, -1, -1):  # narrowest window that has enough residuals wins
        w = _window(u, h)
        enough = np.sum(~np.isnan(w), axis=0) >= _ROBUST_POOL
        take = enough | (h == _MAX_HALF_WINDOW)
        if take.any():
            med = _nanmedian0(w[:, take])
            scale[take] = np.where(np.isnan(med), scale[take], med)
    scale = np.maximum(scale, floor)  # NaN stays NaN: no line with two runs nearby
    z = r / (scale * _k(n))
    return np.where(n >= 3, z, np.nan)


def _components(test: TestData) -> tuple[np.ndarray, np.ndarray]:
    # log-magnitude and phase [rad]: a complex relative error eps moves them by Re eps, Im eps
    return np.log(test.magnitude), np.radians(_phase_unwrapped_deg(test.phase_deg))


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
        is off in magnitude only, or in phase only, from being diluted by the other.
    """
    out = np.full(test.runs.size, -np.inf)
    for c in _components(test):
        z2 = _robust_z(c, floor) ** 2
        count = np.sum(~np.isnan(z2), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(np.where(count > 0, np.nansum(z2, axis=1) / np.maximum(count, 1), np.nan))
        out = np.fmax(out, rms)  # fmax: NaN only when both are
    return np.where(np.isinf(out), np.nan, out)


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
    """

    data: TestData
    removed_runs: tuple[int, ...]
    scores: np.ndarray


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
    score exceeds ``z_threshold``.

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
    """
    z = _check_threshold(z_threshold)
    scores = run_scores(test)
    out = _outliers(scores, z)
    scores = _readonly(scores, float)
    if out.size == 0:
        return CleanedTest(test, (), scores)
    kept = np.delete(test.runs, out)
    return CleanedTest(test.select_runs(kept), tuple(int(r) for r in test.runs[out]), scores)


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
    dof_logmag, dof_phase : ndarray, shape (n_freq,)
        Degrees of freedom behind each sigma: ``sum (n_k - 1)`` over the pooled lines (0 where the
        single-run default stands in). The likelihood's Student-t takes them.

    Sigmas are finite and >= :data:`NOISE_FLOOR`.
    """

    freq_hz: np.ndarray
    sigma_logmag: np.ndarray
    sigma_phase: np.ndarray
    n_runs: np.ndarray
    dof_logmag: np.ndarray
    dof_phase: np.ndarray


def _pooled_sigma(x: np.ndarray, floor: float, single_run_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-line sigma of x (n_runs, n_freq) and its degrees of freedom: classical pooled variance
    after a robust value screen."""
    z = _robust_z(x, floor)
    glitch = (np.abs(z) > _VALUE_Z) & (np.sum(~np.isnan(x), axis=0) >= _VALUE_MIN_RUNS)  # NaN z: False
    x = np.where(glitch, np.nan, x)
    n = np.sum(~np.isnan(x), axis=0)
    mean = np.where(n > 0, np.nansum(x, axis=0) / np.maximum(n, 1), 0.0)
    ss = np.nansum((x - mean) ** 2, axis=0)
    dof = np.maximum(n - 1, 0).astype(float)
    ss_w, dof_w = ss.copy(), dof.copy()
    done = dof >= _POOL_DOF
    for h in range(1, _MAX_HALF_WINDOW + 1):  # the narrowest window with enough dof, else the widest
        s_h, d_h = _window_sum(ss, h), _window_sum(dof, h)
        take = ~done & ((d_h >= _POOL_DOF) | (h == _MAX_HALF_WINDOW))
        ss_w[take], dof_w[take] = s_h[take], d_h[take]
        done |= take
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.where(dof_w > 0, np.sqrt(ss_w / dof_w), single_run_sigma)
    return np.maximum(sigma, floor), dof_w


def noise_model(test: TestData, *, z_threshold: float = DEFAULT_Z_THRESHOLD, floor: float = NOISE_FLOOR,
                single_run_sigma: float = SINGLE_RUN_SIGMA) -> NoiseModel:
    """Repeatability of one run, per line, from the scatter of the repeats.

    Steps, for log-magnitude and phase [rad] separately:

    1. whole outlier runs are set aside as in :func:`remove_outlier_runs` (``z_threshold``);
    2. single values more than 8 robust sigma from their line's median (glitches) are dropped,
       on lines with at least 4 runs;
    3. ``sigma_j^2 = sum_k SS_k / sum_k (n_k - 1)`` over the lines k within +-h of line j, with
       ``SS_k`` the sum of squared deviations from line k's mean and h the smallest half-width
       (0 to 3 lines) that gives >= 10 degrees of freedom -- h = 0 from 11 runs on;
       unbiased for sigma^2 whatever the number of runs;
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
        Shapes (n_freq,) on ``test.freq_hz``; all sigmas finite and > 0.
    """
    z = _check_threshold(z_threshold)
    if not (math.isfinite(floor) and floor > 0 and math.isfinite(single_run_sigma) and single_run_sigma > 0):
        raise InputError("noise_model: floor and single_run_sigma must be finite and > 0")
    keep = np.ones(test.runs.size, bool)
    keep[_outliers(run_scores(test, floor=floor), z)] = False
    logmag, phase = (c[keep] for c in _components(test))
    (s_mag, d_mag), (s_ph, d_ph) = (_pooled_sigma(c, floor, single_run_sigma) for c in (logmag, phase))
    return NoiseModel(
        freq_hz=_readonly(test.freq_hz, float),
        sigma_logmag=_readonly(s_mag, float),
        sigma_phase=_readonly(s_ph, float),
        n_runs=_readonly(test.present.sum(axis=0), np.int64),
        dof_logmag=_readonly(d_mag, float),
        dof_phase=_readonly(d_ph, float),
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
    """Per damper and test: runs, grid, amplitudes, CV bands, outlier runs (what ``sbcal data`` shows).

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
        undefined) and ``cv_median_pct`` = ``{"raw"|"clean": {"magnitude"|"phase": {band: median
        CV [%] or None}}}`` over :data:`CV_BANDS_HZ`. JSON-serialisable.
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
            }
    return out


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
