"""The bench file's optional measured columns (``sbcal import`` writes them): reading, checks, the noise model
that uses them, and the harmonic switch that compares measured with predicted distortion."""

import hashlib
import re

import numpy as np
import pandas as pd
import pytest

from sbcal.core.errors import InputError
from sbcal.data.bench import BENCH_COLUMNS, MEASURED_COLUMNS, SE_DEFAULT_DOF, TestData, rows_digest
from sbcal.data.noise import NOISE_FLOOR, SINGLE_RUN_SIGMA, noise_model
from sbcal.data.readers import load_bench
from sbcal.inference.distortion import harmonic_switch


HEADER = ",".join(BENCH_COLUMNS + MEASURED_COLUMNS)


def _rows(n_runs=2, freqs=(4.0, 5.0, 6.0), se=(20.0, 0.5), windows=12, distortion=0.05, stiffness=5000.0):
    out = [HEADER]
    for r in range(1, n_runs + 1):
        for f in freqs:
            out.append(f"d,2-2,{r},{f},2,{stiffness * (1 + 0.001 * r)},120,{se[0]},{se[1]},{windows},{distortion},1.98")
    return "\n".join(out) + "\n"


def _write(tmp_path, text, name="b.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_measured_columns_reach_the_test_arrays(tmp_path):
    t = load_bench(_write(tmp_path, _rows())).test("d", "2-2")
    assert t.se_logmag.shape == t.magnitude.shape
    np.testing.assert_allclose(t.se_logmag, 20.0 / t.magnitude)
    np.testing.assert_allclose(t.se_phase, np.radians(0.5))
    assert (t.se_dof == 11).all()
    np.testing.assert_allclose(t.distortion, 0.05)
    one = t.select_runs([2])
    assert one.se_logmag.shape == (1, 3) and one.measured_noise
    np.testing.assert_allclose(one.se_logmag, 20.0 / one.magnitude)


def test_files_without_them_read_as_before(tmp_path):
    text = "\n".join(",".join(line.split(",")[:7]) for line in _rows().splitlines()) + "\n"
    b = load_bench(_write(tmp_path, text))
    t = b.test("d", "2-2")
    assert t.se_logmag is None and t.distortion is None and not t.measured_noise
    assert list(b.frame.columns) == list(BENCH_COLUMNS)
    # the digest of a plain file is the contract columns' as before
    sel = b.frame.sort_values(["test", "run", "frequency_hz"], kind="mergesort")
    assert rows_digest(b, "d") == hashlib.sha256(sel.to_csv(index=False, float_format="%.17g").encode()).hexdigest()
    # ... and measured values change it: a stored run made from other noise is not fresh
    assert rows_digest(load_bench(_write(tmp_path, _rows(), "m.csv")), "d") != rows_digest(b, "d")


def test_blank_is_not_measured_and_windows_default(tmp_path):
    text = _rows().splitlines()
    parts = text[1].split(",")
    parts[7:12] = ["", "", "", "", ""]
    text[1] = ",".join(parts)
    text = [line.rsplit(",", 3)[0] + ",,0.05,1.98" if i > 1 else line for i, line in enumerate(text)]
    t = load_bench(_write(tmp_path, "\n".join(text) + "\n")).test("d", "2-2")
    assert np.isnan(t.se_logmag[0, 0]) and t.se_dof[0, 0] == 0 and np.isnan(t.distortion[0, 0])
    assert t.se_dof[0, 1] == SE_DEFAULT_DOF  # no se_windows: the default


@pytest.mark.parametrize("column, value, message", [
    ("stiffness_se_n_per_m", "-1", "column 'stiffness_se_n_per_m': must be >= 0"),
    ("phase_se_deg", "", "column 'phase_se_deg': blank, while 'stiffness_se_n_per_m' is given"),
    ("se_windows", "1", "column 'se_windows': must be an integer >= 2"),
    ("se_windows", "7.5", "column 'se_windows': must be an integer >= 2"),
    ("distortion", "abc", "column 'distortion': expected a number or a blank (not measured), got 'abc'"),
    ("distortion", "inf", "column 'distortion': expected a number"),
    ("amplitude_achieved_mm_pp", "0", "column 'amplitude_achieved_mm_pp': must be > 0"),
])
def test_bad_measured_values_are_named(tmp_path, column, value, message):
    lines = _rows().splitlines()
    names = lines[0].split(",")
    parts = lines[2].split(",")
    parts[names.index(column)] = value
    lines[2] = ",".join(parts)
    with pytest.raises(InputError, match=re.escape(f"line 3: {message}")):
        load_bench(_write(tmp_path, "\n".join(lines) + "\n"))


def test_one_standard_error_without_the_other_is_refused(tmp_path):
    frame = pd.read_csv(_write(tmp_path, _rows())).drop(columns="phase_se_deg")
    frame.to_csv(tmp_path / "half.csv", index=False)
    with pytest.raises(InputError, match="line 1: column 'stiffness_se_n_per_m' without 'phase_se_deg'"):
        load_bench(tmp_path / "half.csv")


def test_parquet_and_workbook_carry_them(tmp_path):
    frame = pd.read_csv(_write(tmp_path, _rows()))
    frame.to_parquet(tmp_path / "b.parquet")
    frame.to_excel(tmp_path / "b.xlsx", index=False)
    ref = load_bench(tmp_path / "b.csv").frame
    for name in ("b.parquet", "b.xlsx"):
        got = load_bench(tmp_path / name).frame
        pd.testing.assert_frame_equal(got, ref, check_dtype=False)
    frame.loc[1, "distortion"] = -0.1
    frame.to_parquet(tmp_path / "bad.parquet")
    with pytest.raises(InputError, match="row index 1: column 'distortion': must be >= 0"):
        load_bench(tmp_path / "bad.parquet")


def _single_run(se_logmag, se_phase, dof=19, n_freq=5):
    mag = np.full((1, n_freq), 5000.0)
    return TestData("d", "t", [1], np.arange(4.0, 4.0 + n_freq), np.full(n_freq, 2.0), mag, np.full((1, n_freq), 120.0),
                    se_logmag=np.full((1, n_freq), se_logmag), se_phase=np.full((1, n_freq), se_phase),
                    se_dof=np.full((1, n_freq), dof))


def test_a_single_run_gets_its_measured_noise_not_the_default():
    plain = noise_model(TestData("d", "t", [1], [4.0, 5.0], [2.0, 2.0], [[5e3, 5e3]], [[120.0, 120.0]]))
    np.testing.assert_allclose(plain.sigma_logmag, SINGLE_RUN_SIGMA)
    nm = noise_model(_single_run(0.004, 0.006))
    np.testing.assert_allclose(nm.sigma_logmag, 0.004)
    np.testing.assert_allclose(nm.sigma_phase, 0.006)
    assert (nm.dof_logmag == 19).all() and nm.measured.all()
    # below the floor the floor holds, as for every sigma
    np.testing.assert_allclose(noise_model(_single_run(1e-5, 1e-5)).sigma_logmag, NOISE_FLOOR)


def test_repeats_keep_their_scatter_unless_the_measured_error_is_larger():
    rng = np.random.default_rng(3)
    n_runs, n_freq = 12, 8
    lm = np.log(5000.0) + 0.02 * rng.standard_normal((n_runs, n_freq))
    ph = np.radians(120.0) + 0.02 * rng.standard_normal((n_runs, n_freq))

    def data(se):
        return TestData("d", "t", np.arange(1, n_runs + 1), np.arange(4.0, 4.0 + n_freq), np.full(n_freq, 2.0),
                        np.exp(lm), np.degrees(ph), se_logmag=np.full((n_runs, n_freq), se),
                        se_phase=np.full((n_runs, n_freq), se), se_dof=np.full((n_runs, n_freq), 9))

    base = noise_model(TestData("d", "t", np.arange(1, n_runs + 1), np.arange(4.0, 4.0 + n_freq),
                                np.full(n_freq, 2.0), np.exp(lm), np.degrees(ph)))
    small = noise_model(data(0.002))  # within-dwell noise below the run-to-run scatter: the repeats stand
    np.testing.assert_array_equal(small.sigma_logmag, base.sigma_logmag)
    assert not small.measured.any()
    large = noise_model(data(0.05))  # above it: the measured error, with its degrees of freedom
    np.testing.assert_allclose(large.sigma_logmag, 0.05)
    assert (large.dof_logmag == 9 * n_runs).all() and large.measured.all()


def test_harmonic_switch():
    predicted = np.array([0.10, 0.10, 0.10, 0.10, 0.005, np.nan])
    measured = np.array([0.09, 0.01, 0.30, np.nan, 0.004, 0.1])
    gap = np.array([0.03, 0.03, 0.03, 0.03, 0.0001, np.nan])
    switch, agrees = harmonic_switch(predicted, measured, gap, np.full(6, 0.005))
    # agrees only within a factor 2 either way; switched only where the gap is resolved (> 2 x 0.005)
    np.testing.assert_array_equal(agrees, [True, False, False, False, True, False])
    np.testing.assert_array_equal(switch, [True, False, False, False, False, False])


def test_a_test_of_fewer_lines_than_the_pooling_window_is_summarised(tmp_path):
    from sbcal.data.summary import bench_summary

    text = "\n".join(",".join(line.split(",")[:7]) for line in _rows(freqs=(4.0, 5.0)).splitlines()) + "\n"
    s = bench_summary(load_bench(_write(tmp_path, text)), 3.0)
    assert s["d"]["2-2"]["n_frequencies"] == 2


def test_the_likelihood_of_a_single_imported_run_uses_its_measured_noise(damper1):
    from sbcal.inference.calibrate import likelihood_for
    from sbcal.inference.priors import load_prior

    data = _single_run(0.01, 0.02, dof=29)
    data = TestData(data.damper, data.test, data.runs, data.freq_hz, data.amplitude_mm_pp, data.magnitude,
                    data.phase_deg, se_logmag=data.se_logmag, se_phase=data.se_phase, se_dof=data.se_dof,
                    distortion=np.full(data.magnitude.shape, 0.07))
    lk = likelihood_for(damper1, data, load_prior("theta1", damper1))
    np.testing.assert_allclose(lk.sigma, [[0.01] * 5, [0.02] * 5])
    np.testing.assert_allclose(lk.nu, 29.0)  # the measured error's degrees of freedom (one run: none of its own)
    np.testing.assert_allclose(lk.measured_distortion, 0.07)
