"""Cleaning a test's runs: the quality table (thesis section 2.5), robust standardisation, response
branches and outlier-run removal (section 2.6), described in ``docs/data.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..core.errors import InputError
from .bench import TestData, nanmedian0, readonly


__all__ = [
    "DEFAULT_Z_THRESHOLD", "NOISE_FLOOR", "BRANCH_GAP", "BRANCH_MIN_FRACTION", "BRANCH_MIN_RUNS",
    "BRANCH_MAX_LINE_FRACTION", "MAX_HALF_WINDOW", "VALUE_Z", "VALUE_MIN_RUNS", "Branches", "CleanedTest",
    "quality_table", "run_scores", "find_branches", "remove_outlier_runs", "window_sum", "robust_z", "score_runs",
    "check_threshold", "outliers",
]

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
MAX_HALF_WINDOW = 3   # pool at most +-3 neighbouring lines
VALUE_Z = 8.0         # single values beyond 8 robust sigma (a glitch, not noise) leave the noise model
VALUE_MIN_RUNS = 4    # ... judged only on lines with >= 4 runs (with 3 the robust scale is too noisy)

# Median |x_i - median(x)| and RMS of (x_i - median(x)) for n iid N(0, 1) values, n = 2..15
# (simulation, 2e7 residuals per n; n = 2 is exact: 0.6745/sqrt(2) and 1/sqrt(2)). Beyond 15:
# q = 0.6745 (1 - 1.2/n), k = sqrt(1 - 0.55/n) (within 1 %). The exact zero residual of the
# median itself for odd n is why q(3) < q(2).
_Q_SMALL = np.array([np.nan, np.nan, 0.4769, 0.3138, 0.4864, 0.4906, 0.5276, 0.5518, 0.5632,
                     0.5826, 0.5877, 0.6013, 0.6038, 0.6130, 0.6150, 0.6224])
_K_SMALL = np.array([np.nan, np.nan, 0.7071, 0.8842, 0.8934, 0.9417, 0.9387, 0.9617, 0.9583,
                     0.9715, 0.9689, 0.9776, 0.9750, 0.9811, 0.9794, 0.9838])
_PHI_075 = 0.6744897501960817  # median of |N(0, 1)|



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
    med = nanmedian0(out)
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


def _window(a: np.ndarray, h: int) -> np.ndarray:
    """Stack ``a`` (n_rows, n_freq) with its shifts by -h..h lines: (n_rows (2h + 1), n_freq), NaN-padded."""
    rows, nf = a.shape
    out = np.full((2 * h + 1, rows, nf), np.nan)
    for j, s in enumerate(range(-h, h + 1)):
        if abs(s) >= nf:  # a shift past every line (a test of fewer lines than the window): all NaN
            continue
        if s >= 0:
            out[j, :, :nf - s] = a[:, s:]
        else:
            out[j, :, -s:] = a[:, :nf + s]
    return out.reshape(-1, nf)


def window_sum(v: np.ndarray, h: int) -> np.ndarray:
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
    for h in range(MAX_HALF_WINDOW, -1, -1):  # narrowest window that has enough residuals wins
        w = _window(u, h)
        enough = np.sum(~np.isnan(w), axis=0) >= _ROBUST_POOL
        take = enough | (h == MAX_HALF_WINDOW)
        if take.any():
            med = nanmedian0(w[:, take])
            scale[take] = np.where(np.isnan(med), scale[take], med)
    return np.maximum(scale, floor)  # NaN stays NaN


def _centres(x: np.ndarray, group: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Median and run count of each value's group at its line, both shaped like x (n_runs, n_freq).

    Without ``group`` a line is one group; with it (1 = the minority branch at a split line,
    0 elsewhere) each branch of a split line has its own centre.
    """
    if group is None:
        return (np.broadcast_to(nanmedian0(x), x.shape),
                np.broadcast_to(np.sum(~np.isnan(x), axis=0), x.shape))
    one = group == 1
    x1, x0 = np.where(one, x, np.nan), np.where(one, np.nan, x)
    centre = np.where(one, nanmedian0(x1), nanmedian0(x0))
    count = np.where(one, np.sum(~np.isnan(x1), axis=0), np.sum(~np.isnan(x0), axis=0))
    return centre, count


def robust_z(x: np.ndarray, floor: float, group: np.ndarray | None = None) -> np.ndarray:
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
    freq_hz: np.ndarray = field(default_factory=lambda: readonly([], float))
    separation: np.ndarray = field(default_factory=lambda: readonly([], float))
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
    u = np.where(n >= 2, np.abs(x - nanmedian0(x)) / _q(n), np.nan)
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
        split=True, freq_hz=readonly(test.freq_hz[lines], float), separation=readonly(sep[lines], float),
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

def score_runs(test: TestData, floor: float):
    """(run scores, branches, groups, components): see :func:`run_scores`, :func:`_branch_groups`."""
    comps = _components(test)
    branches, group = _branch_groups(test, floor, comps)
    out = np.full(test.runs.size, -np.inf)
    for c in comps:
        z2 = robust_z(c, floor, group) ** 2
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
    return score_runs(test, floor)[0]


@dataclass(frozen=True, eq=False)
class CleanedTest:
    """A test after outlier-run removal.

    What :func:`remove_outlier_runs` decides for one test; the pipeline stores the decision
    (:class:`sbcal.data.clean_bench.CleanBench`).

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


def check_threshold(z_threshold) -> float:
    """The outlier z threshold as a float; InputError unless finite and > 0."""
    z = float(z_threshold)
    if not (math.isfinite(z) and z > 0):
        raise InputError(f"z threshold {z_threshold!r}: must be a finite number > 0")
    return z


def outliers(scores: np.ndarray, z_threshold: float) -> np.ndarray:
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
    z = check_threshold(z_threshold)
    scores, branches, _, _ = score_runs(test, NOISE_FLOOR)
    out = outliers(scores, z)
    scores = readonly(scores, float)
    if out.size == 0:
        return CleanedTest(test, (), scores, branches)
    kept = np.delete(test.runs, out)
    return CleanedTest(test.select_runs(kept), tuple(int(r) for r in test.runs[out]), scores, branches)
