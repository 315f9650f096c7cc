"""The virtual bench's raw recordings (sbcal/simulate/raw_bench.py; docs/virtual_bench.md, "Raw recordings").

A few lines of the bundled dry cable at 0.2 mm, 128 steps per period, short holds. The files open with
npTDMS and h5py with the channels, units and properties the channel map reads; the noise-free series'
first harmonic (least squares over the held steady state, computed here) is the run's truth; the truth
is the CSV bench's reading of the same draws (to the integration's settling gap); noise, offsets and
the ADC are what was asked; the CLI writes the files and refuses what it cannot record.
"""

import tomllib

import h5py
import numpy as np
import pandas as pd
import pytest

import sbcal.simulate.raw_bench as rb
from sbcal.cli import main
from sbcal.core.errors import InputError
from sbcal.data.bench import BENCH_COLUMNS, write_bench
from sbcal.simulate.raw_bench import (CHANNELS, FORCE_SPLIT, GROUP, record_raw, truth_frame, write_channel_map,
                                      write_raw, write_tdms)
from sbcal.simulate.virtual_bench import BenchConfig, SlipLaw, record

F = np.array([5.0, 12.0, 30.0])
TEST = "0.2-0.2"
SLIP = "strand_slip=law:lognormal_iwan,delta_EJ:42,chi_median:0.006,log_spread:2.1,time:1,steps_per_period:128"
DRY = SlipLaw(law="lognormal_iwan", params=(("delta_EJ", 42.0), ("chi_median", 0.006), ("log_spread", 2.1)),
              time_domain=True, steps_per_period=128)
PARAMS = {"EJ": 4.4, "beta": 0.11}
EFFECTS = {"strand_slip": DRY, "fixture_mass": 0.02, "sensor_delay": 2e-4, "base_rocking": 0.3}
HOLD = 12
# the CSV bench's draws without its line noise and outliers: its reading is then the integration's own
CONFIG = BenchConfig(params=PARAMS, effects=EFFECTS, runs=2, logmag_noise=(0.0, 0.0), phase_noise_deg=(0.0, 0.0),
                     outlier_probability=0.0)


@pytest.fixture(scope="module")
def clean(damper1):
    return record_raw(damper1, CONFIG, TEST, rng=np.random.default_rng(5), freq_hz=F, hold_periods=HOLD, noise=0.0,
                      offsets=0.0)


def _first_harmonics(run):
    """Per line, F1 / X1 from least squares (a constant and harmonics 1..9) over the held steady state:
    force = Force A + Force B, X1 = A1 / (-omega^2); and X1 itself."""
    force = run.channels["Force A"] + run.channels["Force B"]
    accel = run.channels["Table acceleration"]
    h, x1 = [], []
    for k, f in enumerate(run.freq_hz):
        lo, hi = np.ceil(run.hold_s[k] * run.rate_hz).astype(int)
        wt = 2 * np.pi * f * (np.arange(lo, hi) / run.rate_hz - run.start_s[k])
        basis = np.column_stack([np.ones_like(wt)] + [g(j * wt) for j in range(1, 10) for g in (np.cos, np.sin)])
        (_, fa, fb, *_), (_, aa, ab, *_) = (np.linalg.lstsq(basis, y[lo:hi], rcond=None)[0] for y in (force, accel))
        x = (aa - 1j * ab) / -(2 * np.pi * f) ** 2
        h.append((fa - 1j * fb) / x)
        x1.append(x)
    return np.array(h), np.array(x1)


def test_noise_free_first_harmonic_is_the_truth(clean):
    for run in clean:
        h, x1 = _first_harmonics(run)
        rel, deg = np.abs(h / run.f_uu - 1), np.degrees(np.abs(np.angle(h / run.f_uu)))
        print(f"run {run.run}: |h / truth - 1| = {rel.max():.1e}, phase {deg.max():.1e} deg")
        assert np.all(rel < 1e-4) and np.all(deg < 0.01)
        # the table acceleration is the commanded motion's exact derivative: X1 is the amplitude asked
        np.testing.assert_allclose(x1, run.amplitude_mm_pp / 2 * 1e-3, rtol=1e-9)
        np.testing.assert_allclose(run.channels["Force A"] * FORCE_SPLIT["Force B"],
                                   run.channels["Force B"] * FORCE_SPLIT["Force A"], rtol=1e-12, atol=1e-15)


def test_truth_is_the_csv_benchs_reading_of_the_same_draws(damper1, clean):
    # the same seed draws the same re-clamping scatter (1.5 % on EJ: far above the tolerance); the truth
    # is the held period's first harmonic, the CSV bench's the last 4-period window's: a settling gap
    frame = record(damper1, CONFIG, [TEST], rng=np.random.default_rng(5), freq_hz=F)
    truth = truth_frame(clean)
    assert list(truth.columns) == list(BENCH_COLUMNS) + ["distortion"] and truth.run.tolist() == [1, 1, 1, 2, 2, 2]
    np.testing.assert_allclose(truth.distortion, np.concatenate([r.distortion for r in clean]))
    np.testing.assert_allclose(truth.stiffness_n_per_m, frame.stiffness_n_per_m, rtol=5e-4)
    np.testing.assert_allclose(truth.phase_deg, frame.phase_deg, atol=0.03)
    assert np.abs(truth.stiffness_n_per_m[:3].to_numpy() / truth.stiffness_n_per_m[3:].to_numpy() - 1).max() > 1e-3


def test_the_record_is_a_stepped_sine(clean):
    run = clean[0]
    t = np.arange(run.channels["Drive frequency"].size) / run.rate_hz
    drive = run.channels["Drive frequency"]
    for k, f in enumerate(F):
        on = (t >= run.start_s[k]) & (t < run.hold_s[k, 1])
        assert np.all(drive[on] == f) and np.all(run.channels["Drive amplitude"][on] == 0.2)
    assert set(np.unique(drive)) == {0.0, *F}
    # at rest before the first line and after the last taper
    first = t < run.start_s[0]
    assert first.sum() == np.ceil(0.25 * run.rate_hz) and np.all(run.channels["Force A"][first] == 0)
    assert run.channels["Table acceleration"][-10:].tolist() == [0.0] * 10
    assert run.properties == {"damper": "damper1", "test": TEST, "run": 1, "amplitude_mm_pp": 0.2}


@pytest.mark.parametrize("fmt", ["tdms", "hdf5"])
def test_files_hold_the_channels_units_and_properties(clean, tmp_path, fmt):
    run = clean[1]
    nptdms = pytest.importorskip("nptdms") if fmt == "tdms" else None
    path = write_raw(tmp_path, run, fmt)
    assert path.name == f"damper1_{TEST}_run2{'.tdms' if fmt == 'tdms' else '.h5'}"
    if fmt == "tdms":
        with nptdms.TdmsFile.open(path) as tdms:
            assert dict(tdms.properties) == run.properties
            (group,) = tdms.groups()
            assert group.name == GROUP and [c.name for c in group.channels()] == list(CHANNELS)
            for c in group.channels():
                assert c.properties["unit_string"] == CHANNELS[c.name]
                assert c.properties["wf_increment"] == 1 / run.rate_hz and c.properties["wf_start_offset"] == 0.0
                np.testing.assert_array_equal(c[:], run.channels[c.name])
    else:
        with h5py.File(path, "r") as h5:
            assert {k: (v.decode() if isinstance(v, bytes) else v) for k, v in h5.attrs.items()} == run.properties
            assert list(h5) == [GROUP] and h5[GROUP].attrs["sample_rate_hz"] == run.rate_hz
            assert set(h5[GROUP]) == set(CHANNELS)
            for name, unit in CHANNELS.items():
                assert h5[GROUP][name].attrs["unit"] == unit
                np.testing.assert_array_equal(h5[GROUP][name][:], run.channels[name])


def test_tdms_is_written_in_segments(clean, tmp_path):
    nptdms = pytest.importorskip("nptdms")
    run = clean[0]
    write_tdms(tmp_path / "r.tdms", run, segment_samples=10_000)
    n = run.channels["Force A"].size
    assert (tmp_path / "r.tdms").read_bytes().count(b"TDSm") == -(-n // 10_000) > 2
    with nptdms.TdmsFile.open(tmp_path / "r.tdms") as tdms:
        np.testing.assert_array_equal(tdms[GROUP]["Force B"][:], run.channels["Force B"])
        assert tdms[GROUP]["Force B"].properties["unit_string"] == "N"


def test_noise_offsets_and_adc(damper1, tmp_path):
    # the same physics (no scatter, same seed) recorded clean and through the chain: the difference is
    # an offset, white noise of the asked size, and the ADC's steps within its range
    cfg = BenchConfig(params=PARAMS, effects={"strand_slip": DRY}, runs=1).ideal()
    kw = dict(freq_hz=F[:2], hold_periods=HOLD)
    (ref,) = record_raw(damper1, cfg, TEST, rng=np.random.default_rng(2), noise=0.0, offsets=0.0, **kw)
    (run,) = record_raw(damper1, cfg, TEST, rng=np.random.default_rng(2), noise=2e-3, offsets=0.05, adc_bits=16,
                        full_scale={"acceleration": 2.0}, **kw)
    np.testing.assert_array_equal(run.f_uu, ref.f_uu)
    assert run.full_scale["acceleration"] == 2.0 and run.full_scale["force"] >= 1.25 * np.abs(ref.channels["Force A"]).max()
    for name in ("Force A", "Force B", "Table acceleration"):
        x, clean_x = run.channels[name], ref.channels[name]
        rms = np.sqrt(np.mean(clean_x**2))
        d = x - clean_x
        print(f"{name}: offset {d.mean() / rms:.3f}, noise {d.std() / rms:.2e} (of the RMS)")
        assert abs(d.std() / rms / 2e-3 - 1) < 0.1 and 0 < abs(d.mean()) / rms < 0.25
        fs = run.full_scale["force" if name.startswith("Force") else "acceleration"]
        lsb = 2 * fs / 2**16
        np.testing.assert_allclose(x / lsb, np.round(x / lsb), atol=1e-6)
        assert x.max() < fs and x.min() >= -fs
    for name in ("Drive frequency", "Drive amplitude"):  # the controller's command: exact
        np.testing.assert_array_equal(run.channels[name], ref.channels[name])
    write_channel_map(tmp_path / "channels.toml", full_scale=run.full_scale)
    doc = tomllib.loads((tmp_path / "channels.toml").read_text())
    assert doc["force"]["range"] == run.full_scale["force"] and doc["base"]["range"] == 2.0


def test_channel_map_reads_the_files(tmp_path):
    write_channel_map(tmp_path / "channels.toml")
    doc = tomllib.loads((tmp_path / "channels.toml").read_text())
    assert doc["labels"] == {"damper": {"property": "damper"}, "test": {"property": "test"},
                             "run": {"property": "run"}}
    assert doc["force"] == {"channels": ["Force A", "Force B"], "unit": "N"}
    assert doc["base"] == {"channel": "Table acceleration", "quantity": "acceleration", "unit": "m/s^2"}
    assert doc["frequency"] == {"source": "channel", "channel": "Drive frequency"}
    assert doc["amplitude"] == {"channel": "Drive amplitude"}


@pytest.mark.parametrize("config, options, match", [
    (BenchConfig(params=PARAMS, effects={"strand_slip": 0.006}), {}, "need the time-domain strand slip"),
    (BenchConfig(params=PARAMS, effects={"strand_slip": DRY, "fixture_resonance": 23.0}), {},
     "fixture_resonance: the raw recordings do not take it"),
    (CONFIG, {"rate_hz": 500.0}, "rate_hz: expected more than 2 x 9 harmonics x the highest line = 540 Hz"),
    (CONFIG, {"hold_periods": 0}, "hold_periods: expected an integer >= 1"),
    (CONFIG, {"noise": -1e-3}, "noise: expected a finite value >= 0"),
    (CONFIG, {"adc_bits": 1}, "adc_bits: expected an integer 2..32"),
    (CONFIG, {"full_scale": {"force": 0.0}}, "full_scale: expected force and/or acceleration > 0"),
])
def test_bad_settings_are_one_line(damper1, config, options, match):
    with pytest.raises(InputError, match=match) as info:
        record_raw(damper1, config, TEST, rng=np.random.default_rng(0), freq_hz=F, **options)
    assert "\n" not in str(info.value)


# --- the CLI ---------------------------------------------------------------------------------------

ARGV = ["bench", "--damper", "damper1", "--effect", SLIP, "--set", "EJ=4.4", "--set", "beta=0.11", "--tests", TEST,
        "--runs-per-test", "1", "--seed", "3"]


@pytest.mark.parametrize("fmt, ext", [("tdms", ".tdms"), ("hdf5", ".h5")])
def test_cli_writes_raw_files_the_map_and_the_truth(damper1, tmp_path, monkeypatch, capsys, fmt, ext):
    if fmt == "tdms":
        pytest.importorskip("nptdms")
    monkeypatch.setattr(rb, "STANDARD_GRID_HZ", F)  # three lines, not the 37 of the standard grid
    out = tmp_path / "truth.csv"
    rc = main(ARGV + ["--raw", str(tmp_path / "raw"), "--raw-format", fmt, "--hold-periods", "8",
                      "--sensor-noise", "0", "-o", str(out)])
    assert rc == 0 and "wrote 1 raw files" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "raw").iterdir()) == ["channels.toml", f"damper1_{TEST}_run1{ext}"]
    cfg = BenchConfig(params=PARAMS, effects={"strand_slip": DRY}, runs=1)
    expected = tmp_path / "expected.csv"
    write_bench(truth_frame(record_raw(damper1, cfg, TEST, rng=np.random.default_rng(3), hold_periods=8, noise=0.0)),
                expected)
    assert out.read_bytes() == expected.read_bytes()


def test_cli_without_raw_is_the_csv_bench(tmp_path):
    # the bench CSV for a seed is record()'s frame, as before the raw options existed (the bundled data's
    # regeneration in tests/test_virtual_bench.py pins the draws themselves)
    out, expected = tmp_path / "b.csv", tmp_path / "e.csv"
    argv = ["bench", "--damper", "damper2", "--effect", "fixture_mass=0.05", "--tests", "2-1", "--runs-per-test", "3"]
    assert main(argv + ["--seed", "11", "-o", str(out)]) == 0
    d = __import__("sbcal").model.damper.resolve_damper("damper2")
    write_bench(record(d, BenchConfig(effects={"fixture_mass": 0.05}, runs=3), ["2-1"], rng=np.random.default_rng(11)),
                expected)
    assert out.read_bytes() == expected.read_bytes()
    assert len(pd.read_csv(out)) == 3 * 37


@pytest.mark.parametrize("extra, match", [
    (["--raw", "RAW"], "--raw: the raw recordings need the time-domain strand slip"),
    (["--sample-rate", "5000"], "--sample-rate: only with --raw DIR"),
])
def test_cli_refuses_raw_without_the_time_domain(tmp_path, capsys, extra, match):
    out = tmp_path / "b.csv"
    argv = ["bench", "--damper", "damper1", "--effect", "strand_slip=0.006", "--runs-per-test", "1", "-o", str(out)]
    rc = main(argv + [str(tmp_path / "raw") if a == "RAW" else a for a in extra])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists() and not (tmp_path / "raw").exists()


def test_cli_names_the_option_of_a_bad_setting(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(rb, "STANDARD_GRID_HZ", F)
    rc = main(ARGV + ["--raw", str(tmp_path / "raw"), "--raw-format", "hdf5", "--sample-rate", "400", "-o", str(tmp_path / "b.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "--sample-rate: expected more than 2 x 9 harmonics" in err and err.count("\n") == 1
