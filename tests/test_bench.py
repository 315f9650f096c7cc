"""Bench CSV reader (the contract of formats.md section 2), quality check, outlier runs, noise model."""

import gzip

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import sbcal
from sbcal import InputError
from sbcal.data import bench, cleaning, readers, summary
from sbcal.data.bench import BENCH_COLUMNS, TestData
from sbcal.data.cleaning import DEFAULT_Z_THRESHOLD, NOISE_FLOOR, quality_table, remove_outlier_runs, run_scores
from sbcal.data.noise import SINGLE_RUN_SIGMA, noise_model
from sbcal.data.readers import load_bench

GRID = sbcal.STANDARD_GRID_HZ
HEADER = ",".join(BENCH_COLUMNS)


def curves(damper, n_runs, rng, sigma_mag=0.03, sigma_phase=0.02, freq=GRID, offset_mag=0.0, EJ=9.0, beta=0.3):
    """n_runs noisy copies of the model's f_uu: iid log-magnitude / phase [rad] noise per line,
    plus an optional common per-run log-magnitude offset of sd ``offset_mag``."""
    fuu = sbcal.dynamic_stiffness(damper, freq, EJ=EJ, beta=beta)[0]
    shape = (n_runs, len(freq))
    log_noise = sigma_mag * rng.standard_normal(shape) + offset_mag * rng.standard_normal((n_runs, 1))
    return fuu * np.exp(log_noise + 1j * sigma_phase * rng.standard_normal(shape))


def noisy_test(damper, n_runs, rng, **kw) -> TestData:
    c = curves(damper, n_runs, rng, **kw)
    freq = kw.get("freq", GRID)
    return TestData("d", "t", np.arange(1, n_runs + 1), freq, np.ones(len(freq)), np.abs(c),
                    np.degrees(np.angle(c)))


def write(tmp_path, text, name="b.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def frame_of(damper, rng):
    """Two dampers, four tests (one with amplitude stepping with frequency), 3-5 runs each."""
    parts = []
    for name, n_runs, label, amp in (("damperA", 5, "1-1", 1.0), ("damperA", 4, "0.5-0.5", 0.5),
                                     ("damperA", 3, "2-1", np.where(GRID <= 10, 2.0, 1.0)),
                                     ("damperB", 3, "custom", 0.3)):
        parts.append(bench.curves_to_frame(name, label, GRID, amp, curves(damper, n_runs, rng)))
    return pd.concat(parts, ignore_index=True)


# --- reading --------------------------------------------------------------------------------------

def test_roundtrip_several_dampers_and_tests(tmp_path, damper1, rng):
    df = frame_of(damper1, rng)
    p = tmp_path / "b.csv"
    bench.write_bench(df, p)
    b = load_bench(p)
    assert b.source == str(p)
    assert list(b.frame.columns) == list(BENCH_COLUMNS) and len(b.frame) == len(df)
    assert b.frame["run"].dtype == np.int64
    assert b.dampers() == ["damperA", "damperB"]
    assert b.tests("damperA") == ["0.5-0.5", "1-1", "2-1"]  # thesis order, not sorted
    assert b.tests("damperB") == ["custom"]
    t = b.test("damperA", "1-1")
    assert (t.damper, t.test) == ("damperA", "1-1")
    np.testing.assert_array_equal(t.runs, [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(t.freq_hz, GRID)
    assert t.magnitude.shape == t.phase_deg.shape == (5, GRID.size) and t.present.all()
    src = df[(df.damper == "damperA") & (df.test == "1-1")]
    np.testing.assert_allclose(t.magnitude.ravel(), src.stiffness_n_per_m, rtol=1e-9)
    np.testing.assert_allclose(t.phase_deg.ravel(), src.phase_deg, rtol=1e-9, atol=1e-9)


def test_thesis_order_then_other_labels_sorted():
    frame = pd.DataFrame({"damper": "d", "test": ["zeta", "1-1-oiled", "alpha", "2-1", "0.1-0.1", "2-2"],
                          "run": 1, "frequency_hz": 5.0, "amplitude_mm_pp": 1.0, "stiffness_n_per_m": 1.0,
                          "phase_deg": 90.0})
    b = bench.BenchData("mem", frame)
    assert b.tests("d") == ["0.1-0.1", "2-2", "2-1", "1-1-oiled", "alpha", "zeta"]


def test_gzip_reads_the_same(tmp_path, damper1, rng):
    df = frame_of(damper1, rng)
    plain = tmp_path / "b.csv"
    bench.write_bench(df, plain)
    gz = tmp_path / "b.csv.gz"
    gz.write_bytes(gzip.compress(plain.read_bytes()))
    pd.testing.assert_frame_equal(load_bench(gz).frame, load_bench(plain).frame)


def test_extra_columns_any_order_blank_lines_and_bom(tmp_path):
    text = ("\ufeffnote,phase_deg,run,test,damper,stiffness_n_per_m,amplitude_mm_pp,frequency_hz,temp_c\n"
            '"two\nlines, and a comma",170.5,1,1-1,d1,1000,1,4,21.5\n'
            "\n"
            "x,-0.5,2,1-1,d1,1100,1,4,oops\n"          # phase slightly below 0: accepted
            "  \n"
            "y,180.4,2,1-1,d1,1200,1,4.5,\n")           # slightly above 180: accepted
    b = load_bench(write(tmp_path, text))
    assert list(b.frame.columns) == list(BENCH_COLUMNS)
    t = b.test("d1", "1-1")
    np.testing.assert_array_equal(t.runs, [1, 2])
    np.testing.assert_allclose(t.phase_deg, [[170.5, np.nan], [-0.5, 180.4]])


def test_mixed_grids_and_amplitude_stepping(tmp_path, damper1, rng):
    f1 = GRID
    f2 = np.array([4.25, 6.0, 10.0, 12.0, 41.0])          # another grid, partly shared

    def amp(f):  # test 2-1: 2 mm p-p to 10 Hz, then 1 mm
        return np.where(f <= 10, 2.0, 1.0)

    df = pd.concat([bench.curves_to_frame("d1", "2-1", f1, amp(f1), curves(damper1, 2, rng, freq=f1)),
                    bench.curves_to_frame("d1", "2-1", f2, amp(f2), curves(damper1, 1, rng, freq=f2), runs=[7])])
    p = tmp_path / "b.csv"
    bench.write_bench(df, p)
    t = load_bench(p).test("d1", "2-1")
    union = np.union1d(f1, f2)
    np.testing.assert_array_equal(t.freq_hz, union)
    np.testing.assert_array_equal(t.runs, [1, 2, 7])
    np.testing.assert_array_equal(t.amplitude_mm_pp, amp(union))
    np.testing.assert_array_equal(t.present[0], np.isin(union, f1))
    np.testing.assert_array_equal(t.present[2], np.isin(union, f2))
    assert np.isnan(t.magnitude[~t.present]).all() and np.isnan(t.phase_deg[~t.present]).all()
    assert np.isfinite(t.magnitude[t.present]).all()
    q = quality_table(t)
    np.testing.assert_array_equal(q["n_runs"], t.present.sum(axis=0))
    assert sorted(np.unique(t.amplitude_mm_pp)) == [1.0, 2.0]


def test_run_written_as_integral_float_and_text_labels(tmp_path):
    text = HEADER + "\nNA,None,3.0,4,1,1000,170\nNA,None,3e0,5,1,1000,170\n"
    b = load_bench(write(tmp_path, text))
    assert b.dampers() == ["NA"] and b.tests("NA") == ["None"]  # labels are text, never NaN
    np.testing.assert_array_equal(b.test("NA", "None").runs, [3])


GOOD_ROWS = ["d1,1-1,1,4.0,1.0,1000,170", "d1,1-1,1,4.5,1.0,1100,169", "d1,1-1,2,4.0,1.0,1010,171"]


def with_row(k, row):
    rows = list(GOOD_ROWS)
    rows[k] = row
    return HEADER + "\n" + "\n".join(rows) + "\n"


@pytest.mark.parametrize("text, line, column, problem", [
    (HEADER.replace(",stiffness_n_per_m", "") + "\nd1,1-1,1,4,1,170\n", 1, "stiffness_n_per_m", "missing column"),
    (with_row(1, "d1,1-1,1,abc,1.0,1100,169"), 3, "frequency_hz", "expected a number, got 'abc'"),
    (with_row(1, "d1,1-1,1,4.5,1.0,nan,169"), 3, "stiffness_n_per_m", "'nan' is not finite"),
    (with_row(2, "d1,1-1,2,4.0,1.0,1010,inf"), 4, "phase_deg", "'inf' is not finite"),
    (with_row(0, "d1,1-1,1,4.0,,1000,170"), 2, "amplitude_mm_pp", "empty value"),
    (with_row(1, "d1,1-1,1,4.5,1.0,1100,"), 3, "phase_deg", "empty value"),
    (with_row(1, "d1,1-1,1,4.5,1.0"), 3, "stiffness_n_per_m", "empty value"),    # too few fields
    (with_row(1, "d1,1-1,1,0,1.0,1100,169"), 3, "frequency_hz", "must be > 0, got 0"),
    (with_row(1, "d1,1-1,1,-4.5,1.0,1100,169"), 3, "frequency_hz", "must be > 0, got -4.5"),
    (with_row(1, "d1,1-1,1,4.5,0,1100,169"), 3, "amplitude_mm_pp", "must be > 0"),
    (with_row(1, "d1,1-1,1,4.5,1.0,-1100,169"), 3, "stiffness_n_per_m", "must be > 0"),
    (with_row(1, "d1,1-1,1.5,4.5,1.0,1100,169"), 3, "run", "expected an integer run id, got '1.5'"),
    (with_row(1, "d1,1-1,a,4.5,1.0,1100,169"), 3, "run", "expected an integer run id, got 'a'"),
    (with_row(2, " ,1-1,2,4.0,1.0,1010,171"), 4, "damper", "empty value"),
])
def test_rejections_name_file_line_and_column(tmp_path, text, line, column, problem):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as e:
        load_bench(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: line {line}: ") and f"'{column}'" in msg and problem in msg, msg
    assert "\n" not in msg


def test_first_bad_row_wins_and_counts_the_rest(tmp_path):
    text = HEADER + "\n" + GOOD_ROWS[0] + "\nd1,1-1,1,4.5,1.0,1100,x\nd1,1-1,2,-4,1.0,1100,1\n"
    with pytest.raises(InputError, match=r"line 3: column 'phase_deg': expected a number, got 'x' "
                                         r"\(first of 2 bad rows\)"):
        load_bench(write(tmp_path, text))


def test_line_numbers_count_blank_lines_and_multiline_fields(tmp_path):
    text = ("note," + HEADER + "\n\n" + '"a\nb",' + GOOD_ROWS[0] + "\n\n" + "c," + GOOD_ROWS[1].replace("1100", "0")
            + "\n")
    # line 1 header, 2 blank, 3-4 one record, 5 blank, 6 the bad row
    with pytest.raises(InputError, match=r"b\.csv: line 6: column 'stiffness_n_per_m': must be > 0"):
        load_bench(write(tmp_path, text))


def test_duplicate_rows_name_both_lines(tmp_path):
    text = HEADER + "\n" + "\n".join(GOOD_ROWS) + "\n d1 ,1-1,1,4.5,1.0,1111,169\n"
    p = write(tmp_path, text)
    with pytest.raises(InputError) as e:
        load_bench(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: line 5: ") and "duplicate of line 3" in msg and "'frequency_hz'" in msg
    assert "run 1" in msg and "\n" not in msg


@pytest.mark.parametrize("text, match", [
    ("", r"empty file"),
    ("\n\n", r"empty file"),
    (HEADER + "\n", r"line 1: header only, no data rows"),
    (HEADER + "\n" + GOOD_ROWS[0] + ",extra\n" + GOOD_ROWS[1] + "\n", r"line 2: expected 7 fields .*saw 8"),
    (HEADER + "\n" + GOOD_ROWS[0] + "\n" + GOOD_ROWS[1] + ",x\n", r"line 3: expected 7 fields .*saw 8"),
    (HEADER + ",run\n", r"line 1: column 'run' appears 2 times"),
])
def test_file_level_rejections(tmp_path, text, match):
    p = write(tmp_path, text)
    with pytest.raises(InputError, match=match) as e:
        load_bench(p)
    assert str(e.value).startswith(str(p)) and "\n" not in str(e.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_bench(tmp_path / "missing.csv")
    latin = tmp_path / "latin.csv"
    latin.write_bytes((HEADER + "\n" + GOOD_ROWS[0] + "\nd\xe9,1-1,1,5,1,1,1\n").encode("latin-1"))
    with pytest.raises(InputError, match=r"latin\.csv: line 3: not UTF-8"):
        load_bench(latin)
    fake = tmp_path / "fake.csv.gz"
    fake.write_text(HEADER + "\n")
    with pytest.raises(InputError, match=r"fake\.csv\.gz: cannot read"):
        load_bench(fake)


def test_absent_damper_or_test_lists_what_exists(tmp_path):
    b = load_bench(write(tmp_path, HEADER + "\n" + "\n".join(GOOD_ROWS) + "\n"))
    with pytest.raises(InputError, match=r"damper 'd1' has no test '2-2'; tests: 1-1"):
        b.test("d1", "2-2")
    with pytest.raises(InputError, match=r"no damper 'd9'; dampers: d1"):
        b.test("d9", "1-1")


def test_default_bench_path_points_into_the_package():
    p = readers.default_bench_path()
    assert p.parent.name == "data" and p.parent.parent.name == "sbcal" and p.name in ("bench.csv", "bench.csv.gz")


def test_load_100k_rows_fast(tmp_path, damper1):
    """The happy path is vectorised: 100k rows load in well under a second."""
    import time

    rng = np.random.default_rng(3)
    parts = [bench.curves_to_frame(f"d{k}", t, GRID, 1.0, curves(damper1, 30, rng))
             for k in range(10) for t in bench.THESIS_TESTS]
    p = tmp_path / "big.csv"
    bench.write_bench(pd.concat(parts, ignore_index=True), p)
    t0 = time.perf_counter()
    b = load_bench(p)
    elapsed = time.perf_counter() - t0
    assert len(b.frame) == 99_900 and elapsed < 1.5, elapsed


# --- arrays of one test ---------------------------------------------------------------------------

def test_select_runs_and_read_only_arrays():
    mag = np.array([[1.0, 2.0, np.nan], [1.5, np.nan, np.nan], [1.2, 2.2, 3.3]])
    t = TestData("d", "t", [1, 4, 9], [4.0, 5.0, 6.0], [1.0, 1.0, 2.0], mag, mag * 0 + 90)
    s = t.select_runs([4, 1])
    np.testing.assert_array_equal(s.runs, [1, 4])
    np.testing.assert_array_equal(s.freq_hz, [4.0, 5.0])   # line 6 Hz only in run 9: dropped
    np.testing.assert_array_equal(s.magnitude, [[1.0, 2.0], [1.5, np.nan]])
    with pytest.raises(InputError, match="no run 5; runs: 1, 4, 9"):
        t.select_runs([5])
    with pytest.raises(ValueError):
        t.magnitude[0, 0] = 7.0


# --- quality check ---------------------------------------------------------------------------------

def test_quality_table_hand_values():
    mag = np.array([[90.0, 10.0], [100.0, np.nan], [110.0, 30.0]])
    ph = np.array([[170.0, -2.0], [172.0, np.nan], [174.0, 4.0]])
    t = TestData("d", "t", [1, 2, 3], [4.0, 5.0], [1.0, 1.0], mag, ph)
    q = quality_table(t)
    assert list(q["n_runs"]) == [3, 2]
    np.testing.assert_allclose(q["magnitude_mean"], [100.0, 20.0])
    np.testing.assert_allclose(q["magnitude_min"], [90.0, 10.0])
    np.testing.assert_allclose(q["magnitude_max"], [110.0, 30.0])
    np.testing.assert_allclose(q["magnitude_std"], [10.0, np.sqrt(200.0)])
    np.testing.assert_allclose(q["magnitude_cv"], [100 * 20 / 200, 100 * 20 / 40])   # thesis CV
    np.testing.assert_allclose(q["phase_cv"], [100 * 4 / (2 * 172), 100 * 6 / 2])    # |mean| = 1 deg
    one = quality_table(t.select_runs([1]))
    assert np.isnan(one["magnitude_std"]).all() and (one["magnitude_cv"] == 0).all()


# --- outlier runs ----------------------------------------------------------------------------------

def test_planted_outlier_runs_are_removed_clean_ones_kept(damper1):
    rng = np.random.default_rng(101)
    c = curves(damper1, 15, rng, sigma_mag=0.03, sigma_phase=0.02)
    c[3] *= np.exp(0.18)                                         # run 4: 6 sigma stiffer on every line
    c[10, GRID <= 15] *= np.exp(1j * 0.12)                        # run 11: 6 sigma phase lead at 4-15 Hz
    t = TestData("d", "t", np.arange(1, 16), GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
    cleaned = remove_outlier_runs(t)
    assert cleaned.removed_runs == (4, 11)
    np.testing.assert_array_equal(cleaned.data.runs, np.delete(np.arange(1, 16), [3, 10]))
    assert cleaned.scores.shape == (15,)
    assert (np.delete(cleaned.scores, [3, 10]) < DEFAULT_Z_THRESHOLD).all()


def test_robust_scale_does_not_let_outliers_mask_each_other(damper1):
    """Three identical outlier curves among ten: a mean/std z-score would let them inflate sigma."""
    rng = np.random.default_rng(7)
    c = curves(damper1, 10, rng)
    c[[2, 5, 8]] = c[0] * np.exp(0.3)                            # 10 sigma
    t = TestData("d", "t", np.arange(1, 11), GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
    assert remove_outlier_runs(t).removed_runs == (3, 6, 9)
    # the classical z of the same offset: ~0.2 / sd with the outliers in sd -> well under 3
    x = np.log(np.abs(c))
    classical = np.abs((x - x.mean(0)) / x.std(0, ddof=1))[[2, 5, 8]].mean()
    assert classical < 2


def test_never_cut_below_three_runs_or_a_majority():
    # the rule itself: worst scores first, at most n - max(3, n // 2 + 1) runs
    assert list(cleaning.outliers(np.array([5.0, 4.0, 0.5, 6.0, 0.9]), 3.0)) == [0, 3]     # n = 5: keep 3
    assert list(cleaning.outliers(np.array([5.0, 4.0, 7.0]), 3.0)) == []                   # n = 3: never
    assert list(cleaning.outliers(np.array([5.0, 4.0, 7.0, 3.5, 8.0, 1.0]), 3.0)) == [2, 4]  # n = 6: keep 4
    assert list(cleaning.outliers(np.array([np.nan, 9.0, 1.0, 1.0, 1.0]), 3.0)) == [1]     # NaN: not scored


def test_three_runs_with_an_outlier_are_left_alone(damper1):
    rng = np.random.default_rng(5)
    c = curves(damper1, 3, rng)
    c[0] *= np.exp(0.5)
    t = TestData("d", "t", [1, 2, 3], GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
    cleaned = remove_outlier_runs(t)
    assert cleaned.removed_runs == () and cleaned.data is t
    assert cleaned.scores[0] > DEFAULT_Z_THRESHOLD  # flagged, but too few runs to cut


def test_no_outlier_independent_noise_removes_none(damper1):
    """Clean runs with independent line noise score ~1 (RMS of 74 unit z): P(score > 3) ~ 0."""
    rng = np.random.default_rng(2024)
    scores = []
    for _ in range(20):
        t = noisy_test(damper1, 8, rng)
        cleaned = remove_outlier_runs(t)
        assert cleaned.removed_runs == ()
        scores.append(cleaned.scores)
    scores = np.concatenate(scores)
    assert 0.8 < scores.mean() < 1.2 and scores.max() < 2


def test_false_positive_rate_with_whole_curve_noise(damper1):
    """Worst case for clean runs: each run is the truth times one common complex factor, with
    independent magnitude and phase offsets, so the score is max(|z_mag|, |z_phase|).
    docs/data.md: 0.54 % flagged at Z = 3 for many runs, ~3.2 % with 12 runs (the scale is
    estimated from 12 values), ~12 % at Z = 2. Over 1200 runs the Z = 3 rate must stay under 6 %
    (+5 binomial sd) and well under the Z = 2 rate."""
    rng = np.random.default_rng(99)
    fuu = sbcal.dynamic_stiffness(damper1, GRID, EJ=9.0, beta=0.3)[0]
    s3, s2 = [], []
    for _ in range(100):
        c = fuu * np.exp(0.03 * rng.standard_normal((12, 1)) + 1j * 0.02 * rng.standard_normal((12, 1)))
        t = TestData("d", "t", np.arange(12), GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
        sc = run_scores(t)
        s3.append(sc > 3)
        s2.append(sc > 2)
    rate3, rate2 = np.mean(s3), np.mean(s2)
    assert rate3 < 0.06 and rate2 > 2 * rate3, (rate3, rate2)


def test_bad_threshold():
    t = TestData("d", "t", [1], [4.0], [1.0], [[1.0]], [[90.0]])
    for z in (0, -1, np.nan, np.inf):
        with pytest.raises(InputError, match="must be a finite number > 0"):
            remove_outlier_runs(t, z)


def test_small_sample_factors_match_simulation():
    """The tabulated median |x - median| and RMS (x - median) of n Gaussian runs (q(n), k(n))."""
    rng = np.random.default_rng(0)
    for n in (2, 3, 6, 15, 16, 25):
        x = rng.standard_normal((400_000 // n, n))
        r = (x - np.median(x, axis=1, keepdims=True)).ravel()
        assert cleaning._q(np.array(n)) == pytest.approx(np.median(np.abs(r)), rel=0.015)
        assert cleaning._k(np.array(n)) == pytest.approx(np.sqrt(np.mean(r ** 2)), rel=0.01)


# --- noise model -----------------------------------------------------------------------------------

def chi2_band(dof, n_lines, p=1e-4):
    """Two-sided band of sigma_hat / sigma for n_lines independent chi2(dof)/dof estimates."""
    a = p / n_lines
    return np.sqrt(stats.chi2.ppf(a / 2, dof) / dof), np.sqrt(stats.chi2.ppf(1 - a / 2, dof) / dof)


def mean_var_ratio_tol(dof_per_line, n_lines, k=4.0):
    """k standard errors of the mean of n_lines independent chi2(dof)/dof variables."""
    return k * np.sqrt(2.0 / dof_per_line / n_lines)


def test_noise_model_recovers_known_sigma(damper1):
    rng = np.random.default_rng(42)
    sig_mag = np.where(GRID <= 15, 0.05, 0.02)    # larger scatter at low frequency, as in the thesis
    t = noisy_test(damper1, 16, rng, sigma_mag=sig_mag, sigma_phase=0.02)
    nm = noise_model(t)
    np.testing.assert_array_equal(nm.freq_hz, GRID)
    np.testing.assert_array_equal(nm.n_runs, np.full(GRID.size, 16))
    lo, hi = chi2_band(15, GRID.size)             # 16 runs -> 15 dof per line, no pooling
    for est, true in ((nm.sigma_logmag, sig_mag), (nm.sigma_phase, 0.02)):
        ratio = est / true
        assert ((lo < ratio) & (ratio < hi)).all(), ratio
        assert abs(np.mean(ratio ** 2) - 1) < mean_var_ratio_tol(15, GRID.size)


def test_noise_model_robust_to_an_outlier_run_and_a_glitch(damper1):
    rng = np.random.default_rng(8)
    c = curves(damper1, 12, rng, sigma_mag=0.03, sigma_phase=0.02)
    clean = TestData("d", "t", np.arange(12), GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
    c2 = c.copy()
    c2[5] *= np.exp(0.3 + 0.2j)                   # a whole outlier run, 10 sigma
    c2[2, 20] *= np.exp(0.5)                      # one glitch: a single value 17 sigma off
    dirty = TestData("d", "t", np.arange(12), GRID, np.ones(GRID.size), np.abs(c2), np.degrees(np.angle(c2)))
    nm, ref = noise_model(dirty), noise_model(clean)
    lo, hi = chi2_band(10, GRID.size)             # 11 clean runs left at worst
    for est, true in ((nm.sigma_logmag, 0.03), (nm.sigma_phase, 0.02)):
        assert ((lo < est / true) & (est / true < hi)).all()
        assert abs(np.mean((est / true) ** 2) - 1) < mean_var_ratio_tol(10, GRID.size)
    assert nm.sigma_logmag[20] < 2 * ref.sigma_logmag[20]
    # without the robust steps the same data would give ~sqrt(0.3^2 / 12 + 0.03^2) ~ 0.09
    assert np.std(np.log(np.abs(c2)), axis=0, ddof=1).mean() > 2 * 0.03


@pytest.mark.parametrize("n_runs, dof", [(2, 7), (3, 10), (5, 12)])
def test_noise_model_pools_neighbours_with_few_runs(damper1, n_runs, dof):
    """Few runs: lines pool +-h neighbours until >= 10 dof (2 runs: +-3 lines, 7 dof)."""
    rng = np.random.default_rng(n_runs)
    ratios = []
    for _ in range(10):
        nm = noise_model(noisy_test(damper1, n_runs, rng, sigma_mag=0.03, sigma_phase=0.02))
        assert np.isfinite(nm.sigma_logmag).all() and (nm.sigma_logmag >= NOISE_FLOOR).all()
        ratios.append((nm.sigma_logmag[3:-3] / 0.03) ** 2)
    ratios = np.concatenate(ratios)
    # pooled windows overlap, so lines are not independent: count each run-set once per window
    n_independent = 10 * (GRID.size - 6) * (n_runs - 1) / dof
    assert abs(ratios.mean() - 1) < mean_var_ratio_tol(dof, n_independent)


def test_noise_model_single_run_and_identical_runs():
    mag = np.full((1, 5), 1000.0)
    t = TestData("d", "t", [1], np.arange(4.0, 9.0), np.ones(5), mag, mag * 0 + 90)
    nm = noise_model(t)
    np.testing.assert_array_equal(nm.sigma_logmag, SINGLE_RUN_SIGMA)
    np.testing.assert_array_equal(nm.sigma_phase, SINGLE_RUN_SIGMA)
    same = TestData("d", "t", [1, 2, 3, 4], np.arange(4.0, 9.0), np.ones(5), np.repeat(mag, 4, 0),
                    np.full((4, 5), 90.0))
    nm = noise_model(same)
    np.testing.assert_array_equal(nm.sigma_logmag, NOISE_FLOOR)   # never zero
    np.testing.assert_array_equal(nm.n_runs, 4)


def test_noise_model_sparse_lines_stay_finite():
    """A line only one run has borrows its neighbours' scatter; no line is ever NaN or zero."""
    rng = np.random.default_rng(1)
    mag = 1000 * np.exp(0.03 * rng.standard_normal((4, 9)))
    mag[1:, 4] = np.nan
    t = TestData("d", "t", [1, 2, 3, 4], np.arange(4.0, 13.0), np.ones(9), mag, np.where(np.isnan(mag), np.nan, 90.0))
    nm = noise_model(t)
    assert nm.n_runs[4] == 1
    assert np.isfinite(nm.sigma_logmag).all() and (nm.sigma_logmag > 0).all()
    assert 0.3 * 0.03 < nm.sigma_logmag[4] < 3 * 0.03


def test_phase_written_wrapped_near_180_is_not_scatter(damper1):
    """A writer using atan2 turns 180.4 deg into -179.6 deg: statistics must not see 360 deg."""
    rng = np.random.default_rng(12)
    fuu = sbcal.dynamic_stiffness(damper1, GRID, EJ=9.0, beta=0.05)[0]   # 178 deg at 4 Hz
    c = fuu * np.exp(0.03 * rng.standard_normal((10, GRID.size)) + 0.03j * rng.standard_normal((10, GRID.size)))
    cont = np.degrees(np.angle(c))
    cont = np.where(cont < -90, cont + 360, cont)                        # continuous about 180
    wrapped = np.degrees(np.angle(c))                                    # (-180, 180]
    assert (wrapped[:, 0] < 0).any() and (wrapped[:, 0] > 0).any()       # the case is exercised
    a = TestData("d", "t", np.arange(10), GRID, np.ones(GRID.size), np.abs(c), cont)
    b = TestData("d", "t", np.arange(10), GRID, np.ones(GRID.size), np.abs(c), wrapped)
    pd.testing.assert_frame_equal(quality_table(a), quality_table(b), rtol=1e-9)
    np.testing.assert_allclose(run_scores(a), run_scores(b), rtol=1e-9)
    np.testing.assert_allclose(noise_model(b).sigma_phase, noise_model(a).sigma_phase, rtol=1e-9)
    assert noise_model(b).sigma_phase[0] < 0.1
    # and our own writer keeps the phase continuous about 180 deg
    df = bench.curves_to_frame("d", "t", GRID, 1.0, c)
    np.testing.assert_allclose(df.phase_deg, cont.ravel(), rtol=1e-12)
    assert df.phase_deg.between(-90, 270).all()


# --- response branches -----------------------------------------------------------------------------

# A weakly damped damper (beta = 0.05) resonates sharply near 16 Hz. The second branch: at the two
# lines just above that resonance the response is the one of a stiffer cable (EJ 10.5 instead of 9),
# as when the runs jump onto the other state of a fold: 1.0 in log-magnitude and 65-100 deg apart,
# ~30 sigma of the 0.03 / 0.02 noise; elsewhere the two branches agree.
BAND = (GRID >= 16) & (GRID <= 17)


def branch_test(damper, n_a, n_b, rng, bad=(), band=BAND, bad_offset=0.25) -> TestData:
    a = sbcal.dynamic_stiffness(damper, GRID, EJ=9.0, beta=0.05)[0]
    b = np.where(band, sbcal.dynamic_stiffness(damper, GRID, EJ=10.5, beta=0.05)[0], a)
    fuu = np.where(np.arange(n_a + n_b)[:, None] < n_a, a, b)
    c = fuu * np.exp(0.03 * rng.standard_normal(fuu.shape) + 0.02j * rng.standard_normal(fuu.shape))
    for i in bad:
        c[i] *= np.exp(bad_offset)                               # a whole bad curve (0.25: 8 sigma stiffer)
    return TestData("d", "t", np.arange(1, n_a + n_b + 1), GRID, np.ones(GRID.size), np.abs(c),
                    np.degrees(np.angle(c)))


def plain_scores(t):
    """The run scores without branch detection (every line one group): what removal used to see."""
    return np.fmax(*[np.sqrt(np.nanmean(cleaning.robust_z(x, NOISE_FLOOR) ** 2, axis=1))
                     for x in cleaning._components(t)])


def test_two_branches_are_reported_not_removed(damper1):
    t = branch_test(damper1, 12, 8, np.random.default_rng(11))
    assert (plain_scores(t)[12:] > 5).all()                      # the case: a branch looks like 8 outliers
    c = remove_outlier_runs(t)
    assert c.removed_runs == () and c.data is t
    assert (c.scores < DEFAULT_Z_THRESHOLD).all()
    b = c.branches
    assert b.split and b.kept == "both" and b.band_hz == (16.0, 17.0)
    np.testing.assert_array_equal(b.freq_hz, [16.0, 17.0])
    assert b.runs == (tuple(range(13, 21)), tuple(range(1, 13)))
    assert b.minority == (tuple(range(13, 21)),) * 2 and (b.separation >= cleaning.BRANCH_GAP).all()
    assert cleaning.find_branches(t).runs == b.runs


def test_isolated_bad_run_is_removed_and_no_branch(damper1):
    t = branch_test(damper1, 20, 0, np.random.default_rng(12), bad=[6])
    c = remove_outlier_runs(t)
    assert c.removed_runs == (7,) and not c.branches.split and c.branches.runs == ()
    assert c.branches.as_dict() == {"split": False, "band_hz": None, "lines_hz": [], "separation": [], "runs": [],
                                    "minority_runs": [], "kept": None}


@pytest.mark.parametrize("bad", [3, 16])                      # in the majority branch, in the minority
def test_branches_and_an_isolated_bad_run(damper1, bad):
    t = branch_test(damper1, 12, 8, np.random.default_rng(13), bad=[bad])
    c = remove_outlier_runs(t)
    assert c.branches.split and c.branches.runs[0] == tuple(range(13, 21))
    assert c.removed_runs == (bad + 1,)
    assert (np.delete(c.scores, bad) < DEFAULT_Z_THRESHOLD).all()


def n_split_lines(t):
    return int(np.sum(np.fmax(*[cleaning._line_splits(x, NOISE_FLOOR)[0] for x in cleaning._components(t)])
                      >= cleaning.BRANCH_GAP))


def test_a_group_of_bad_curves_is_not_a_branch(damper1):
    """Five of twenty runs 20 sigma off on every line split every line: not a band, so outliers."""
    t = branch_test(damper1, 20, 0, np.random.default_rng(14), bad=[2, 5, 8, 11, 14], bad_offset=0.6)
    assert n_split_lines(t) > cleaning.BRANCH_MAX_LINE_FRACTION * GRID.size   # the case: many lines split
    assert not cleaning.find_branches(t).split
    assert remove_outlier_runs(t).removed_runs == (3, 6, 9, 12, 15)


def test_a_split_over_too_many_lines_is_not_a_branch(damper1):
    """A second group differing on 12 of 37 lines (> a quarter) is left to outlier removal."""
    wide = (GRID >= 16) & (GRID <= 27)
    t = branch_test(damper1, 14, 6, np.random.default_rng(15), band=wide)
    assert n_split_lines(t) == 12
    assert not cleaning.find_branches(t).split
    assert len(remove_outlier_runs(t).removed_runs) == 6


def test_small_groups_are_not_branches(damper1):
    """Two runs (< BRANCH_MIN_RUNS) on the other state are two outliers, not a branch."""
    t = branch_test(damper1, 18, 2, np.random.default_rng(16))
    x = np.log(t.magnitude[:, BAND])
    assert (np.abs(x[18:] - np.median(x[:18], axis=0)) > 0.9).all()  # the case: 30 sigma off, at the band only
    assert not cleaning.find_branches(t).split
    assert remove_outlier_runs(t).removed_runs == (19, 20)


def test_no_branches_in_clean_tests(damper1):
    """Simulated without branches (docs/data.md 3b: 2000 Gaussian tests per size, 6-30 runs), no
    test's widest gap reached 5 robust sigma, and the rule asks for 6; with Student-t3 tails up to
    0.1 % split. Of 400 clean Gaussian tests here (6-24 runs, line noise plus a curve-level offset)
    at most one may split: at 0.1 % that is +3 binomial sd."""
    rng = np.random.default_rng(17)
    split = 0
    for k in range(400):
        t = noisy_test(damper1, (6, 8, 12, 24)[k % 4], rng, offset_mag=0.02)
        split += cleaning.find_branches(t).split
    assert split <= 1, split


def test_noise_model_sees_both_branches(damper1):
    """All runs kept: at a split line sigma is the scatter of both branches about their common
    mean (what the run mean's standard error needs), not a branch's own; elsewhere unchanged."""
    t = branch_test(damper1, 12, 8, np.random.default_rng(18))
    nm = noise_model(t)
    x = np.log(t.magnitude)
    np.testing.assert_allclose(nm.sigma_logmag[BAND], x[:, BAND].std(axis=0, ddof=1), rtol=1e-9)
    assert (nm.sigma_logmag[BAND] > 0.4).all() and (nm.sigma_logmag[~BAND] < 0.06).all()
    np.testing.assert_array_equal(nm.dof_logmag, 19)
    # the glitch screen judges each run against its own branch: no branch value is dropped
    assert (nm.dof_phase == 19).all()


def _planted_outliers(i: int, j: int, n: int = 24, n_freq: int = 37) -> list:
    """The runs the bundled data's generator made outliers: its draws replayed (record()'s order:
    five scatter draws per run, the noise on both channels, then the outlier coin per run)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("mk", Path(bench.__file__).parents[2] / "scripts" / "make_default_data.py")
    mk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mk)
    rng = np.random.default_rng([mk.SEED, i, j])
    rng.standard_normal(5 * n)
    rng.standard_normal(2 * n * n_freq)
    return [int(r) + 1 for r in np.flatnonzero(rng.random(n) < 0.03)]


def test_bundled_data_have_no_branches_and_lose_only_their_outliers():
    """The bundled recordings come from the stepped-sine virtual bench: each run follows the branch
    a sweep up the grid gives, so no test splits into two response branches, and the cleaning
    removes the outlier runs the generator planted (and at most one more run per test)."""
    s = summary.bench_summary(load_bench(readers.default_bench_path()))
    assert not any(s[d][t]["branches"]["split"] for d in s for t in s[d])
    for i, d in enumerate(s):
        for j, t in enumerate(s[d]):
            planted = set(_planted_outliers(i, j))
            removed = set(s[d][t]["removed_runs"])
            assert planted <= removed and len(removed - planted) <= 1, (d, t, planted, removed)


def test_cli_prints_branches(tmp_path, damper1, capsys):
    from sbcal.cli import main

    t = branch_test(damper1, 12, 8, np.random.default_rng(11))
    p = tmp_path / "b.csv"
    fuu = t.magnitude * np.exp(1j * np.radians(t.phase_deg))
    bench.write_bench(bench.curves_to_frame("d", "1-1", GRID, 1.0, fuu), p)
    assert main(["data", "--bench", str(p)]) == 0
    out = capsys.readouterr().out
    assert ("^ two response branches at 16, 17 Hz: runs 13,14,15,16,17,18,19,20 vs 12 others; "
            "both branches kept") in out


# --- degrees of freedom of the noise model ------------------------------------------------------------

@pytest.mark.parametrize("n_runs", [16, 5, 3, 2])
def test_noise_model_degrees_of_freedom(damper1, n_runs):
    """dof = sum of (n_k - 1) over the pooled lines: the narrowest window of +-h lines (h <= 3,
    truncated at the grid's ends) with >= 10 of them. Interior lines: 15 with 16 runs (no pooling),
    12 with 5 (+-1 line), 10 with 3 (+-2), 7 with 2 (+-3)."""
    nm = noise_model(noisy_test(damper1, n_runs, np.random.default_rng(n_runs)))
    n_lines = GRID.size
    expected = []
    for j in range(n_lines):
        for h in range(4):
            dof = (n_runs - 1) * (min(j + h, n_lines - 1) - max(j - h, 0) + 1)
            if dof >= 10 or h == 3:
                expected.append(dof)
                break
    assert nm.dof_logmag.dtype == np.int64 and nm.dof_logmag.shape == GRID.shape
    np.testing.assert_array_equal(nm.dof_logmag, expected)
    np.testing.assert_array_equal(nm.dof_phase, expected)
    assert expected[18] == {16: 15, 5: 12, 3: 10, 2: 7}[n_runs]


def test_noise_model_dof_zero_for_a_single_run_and_less_after_a_glitch(damper1):
    one = TestData("d", "t", [1], np.arange(4.0, 9.0), np.ones(5), np.full((1, 5), 1e3), np.full((1, 5), 90.0))
    nm = noise_model(one)
    np.testing.assert_array_equal(nm.dof_logmag, 0)
    np.testing.assert_array_equal(nm.dof_phase, 0)
    rng = np.random.default_rng(8)
    c = curves(damper1, 12, rng)
    c[2, 20] *= np.exp(0.5)                                      # a glitch in magnitude only
    t = TestData("d", "t", np.arange(12), GRID, np.ones(GRID.size), np.abs(c), np.degrees(np.angle(c)))
    nm = noise_model(t)
    assert nm.dof_logmag[20] == 10 and nm.dof_phase[20] == 11
    assert (np.delete(nm.dof_logmag, 20) == 11).all()
