"""``sbcal import`` end to end (issue 27; docs/import.md): the virtual bench's raw recordings of a slipping
cable, integrated in time (physics richer than the fitted model), written as TDMS, HDF5, MDF4 and CSV files,
imported, and compared with the integration's own first harmonics; the standard errors' coverage under sensor
noise over a seed sweep; the bare-fixture subtraction; every bad recording refused in one line with nothing
written; the imported file read by ``sbcal run`` unchanged.
"""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from sbcal.cli import main
from sbcal.data.acquisition import import_recordings, load_channel_map
from sbcal.simulate.raw_bench import FORCE_SPLIT, measure, record_raw, write_channel_map, write_hdf5, write_tdms
from sbcal.simulate.virtual_bench import BenchConfig, SlipLaw

pytest.importorskip("nptdms")

F = np.array([4.5, 8.0, 12.0, 19.0, 30.0, 40.0])
TEST = "2-2"
SLIP = SlipLaw(law="iwan5", params=(("chi_macro", 0.02), ("delta_EJ", 55.0)), time_domain=True)
CONFIG = BenchConfig(params={"EJ": 4.0, "beta": 0.1}, effects={"strand_slip": SLIP}, runs=1)
HOLD = 60  # periods held: >= 10 windows of 4 periods after the settling test


@pytest.fixture(scope="module")
def clean(damper1):
    """One noise-free run: the cable at 2 mm slips (distortion 3-8 %)."""
    (run,) = record_raw(damper1, CONFIG.ideal(), TEST, rng=np.random.default_rng(11), freq_hz=F, hold_periods=HOLD,
                        noise=0.0, offsets=0.0)
    return run


@pytest.fixture(scope="module")
def files(clean, tmp_path_factory):
    root = tmp_path_factory.mktemp("raw")
    write_tdms(root / "run1.tdms", clean)
    write_hdf5(root / "run1.h5", clean)
    write_channel_map(root / "channels.toml")
    return root


def _imported(path, files, *extra):
    out = path.parent / f"{path.stem}_{path.suffix[1:]}.csv"
    assert main(["import", str(path), "--map", str(files / "channels.toml"), "-o", str(out), "--quiet", *extra]) == 0
    return pd.read_csv(out)


def _errors(frame, run):
    h = frame["stiffness_n_per_m"].to_numpy() * np.exp(1j * np.radians(frame["phase_deg"].to_numpy()))
    ratio = h / run.f_uu
    return np.abs(ratio) - 1, np.degrees(np.angle(ratio))


@pytest.mark.parametrize("name", ["run1.tdms", "run1.h5"])
def test_noise_free_round_trip(files, clean, name):
    frame = _imported(files / name, files)
    np.testing.assert_allclose(frame["frequency_hz"], F)
    rel, deg = _errors(frame, clean)
    print(f"{name}: worst {np.abs(rel).max():.2e} and {np.abs(deg).max():.2e} deg")
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05  # the 0.1 % and 0.05 deg
    np.testing.assert_allclose(frame["distortion"], clean.distortion, rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(frame["amplitude_achieved_mm_pp"], 2.0, rtol=1e-6)
    assert (frame["amplitude_mm_pp"] == 2.0).all() and (frame["se_windows"] >= 10).all()


def test_every_reader_gives_the_same_lines(files, clean, tmp_path):
    """The run as MDF4 and as CSV (time column) imports to the TDMS file's lines."""
    asammdf = pytest.importorskip("asammdf")
    ref = _imported(files / "run1.tdms", files)
    t = np.arange(clean.channels["Force A"].size) / clean.rate_hz
    names = list(clean.channels)
    mdf = asammdf.MDF()
    mdf.append([asammdf.Signal(clean.channels[n], t, name=n, unit=clean.units[n]) for n in names])
    mdf.save(tmp_path / "run1.mf4", overwrite=True)
    csv = pd.DataFrame({"time [s]": t, **{f"{n} [{clean.units[n]}]": clean.channels[n] for n in names}})
    csv.to_csv(tmp_path / "run1.csv", index=False, float_format="%.17g")
    # labels from the map (MDF4 and CSV carry no file properties here)
    text = (files / "channels.toml").read_text()
    text = text.replace('damper = {property = "damper"}', 'damper = "damper1"').replace(
        'test = {property = "test"}', 'test = "2-2"').replace('run = {property = "run"}', "run = 1")
    (tmp_path / "channels.toml").write_text(text)
    for name in ("run1.mf4", "run1.csv"):
        got = _imported(tmp_path / name, tmp_path)
        np.testing.assert_allclose(got["stiffness_n_per_m"], ref["stiffness_n_per_m"], rtol=1e-9)
        np.testing.assert_allclose(got["phase_deg"], ref["phase_deg"], atol=1e-7)


def test_standard_errors_cover_the_truth_under_sensor_noise(clean, tmp_path):
    """+-2 SE holds the noise-free value in 90-98 % of lines, magnitude and phase each (40 seeds x 6 lines).

    The SE rests on K >= 10 batches (Student t, K - 1 dof): +-2 SE covers 92-95 %; with n = 240 the binomial
    sd of a coverage near 0.93 is 1.6 %, so 0.90-0.98 is the issue's band and about 2 sd either side.
    """
    write_channel_map(tmp_path / "channels.toml")
    cmap = load_channel_map(tmp_path / "channels.toml")
    z_mag, z_phase = [], []
    for seed in range(40):
        channels, _ = measure(clean.channels, np.random.default_rng(seed), noise=3e-3, offsets=0.02)
        write_tdms(tmp_path / "noisy.tdms", dataclasses.replace(clean, channels=channels))
        frame = import_recordings([tmp_path / "noisy.tdms"], cmap, quiet=True).frame
        rel, deg = _errors(frame, clean)
        z_mag.append(np.log1p(rel) / (frame["stiffness_se_n_per_m"] / frame["stiffness_n_per_m"]).to_numpy())
        z_phase.append(deg / frame["phase_se_deg"].to_numpy())
    z_mag, z_phase = np.concatenate(z_mag), np.concatenate(z_phase)
    cover = [float(np.mean(np.abs(z) <= 2)) for z in (z_mag, z_phase)]
    print(f"coverage of +-2 SE: magnitude {cover[0]:.3f}, phase {cover[1]:.3f}; rms z {np.sqrt(np.mean(z_mag**2)):.2f}, "
          f"{np.sqrt(np.mean(z_phase**2)):.2f}")
    assert all(0.90 <= c <= 0.98 for c in cover), cover


def test_the_bare_fixture_is_subtracted(clean, tmp_path):
    """A fixture of 0.8 kg recorded alone and under the damper: the import with --fixture gives the damper's own
    lines; without it, the lines carry the fixture's -omega^2 m."""
    mass = 0.8
    accel = clean.channels["Table acceleration"]
    bare = dict(clean.channels, **{n: share * mass * accel for n, share in FORCE_SPLIT.items()})
    loaded = dict(clean.channels, **{n: clean.channels[n] + share * mass * accel for n, share in FORCE_SPLIT.items()})
    write_tdms(tmp_path / "bare.tdms", dataclasses.replace(clean, channels=bare))
    write_tdms(tmp_path / "loaded.tdms", dataclasses.replace(clean, channels=loaded))
    write_channel_map(tmp_path / "channels.toml")
    heavy = _imported(tmp_path / "loaded.tdms", tmp_path)
    h = heavy["stiffness_n_per_m"].to_numpy() * np.exp(1j * np.radians(heavy["phase_deg"].to_numpy()))
    np.testing.assert_allclose(h, clean.f_uu - (2 * np.pi * F) ** 2 * mass, rtol=1e-3)
    own = _imported(tmp_path / "loaded.tdms", tmp_path, "--fixture", str(tmp_path / "bare.tdms"))
    rel, deg = _errors(own, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05


def test_run_accepts_the_imported_file(files, tmp_path):
    frame = _imported(files / "run1.tdms", files)
    out = files / "run1_tdms.csv"
    assert main(["data", "--bench", str(out)]) == 0
    assert main(["run", "--bench", str(out), "--until", "clean", "--runs", str(tmp_path / "runs"), "-o",
                 str(tmp_path / "report"), "--quiet"]) == 0
    assert len(frame) == F.size


# --- bad recordings: one line each, exit 2, nothing written -----------------------------------------

def _refused(capsys, tmp_path, raw, cmap, match):
    out = tmp_path / "out.csv"
    assert main(["import", *map(str, raw), "--map", str(cmap), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("sbcal: error: ") and "Traceback" not in err, err
    assert match in err, err
    assert not out.exists() and not list(tmp_path.glob(".out.csv*"))
    return err


def _variant(clean, tmp_path, name="bad.tdms", **channels):
    write_tdms(tmp_path / name, dataclasses.replace(clean, channels=dict(clean.channels, **channels)))
    return tmp_path / name


def test_a_missing_channel_is_named(clean, files, tmp_path, capsys):
    cmap = tmp_path / "channels.toml"
    cmap.write_text((files / "channels.toml").read_text().replace('"Force B"', '"Force C"'))
    err = _refused(capsys, tmp_path, [files / "run1.tdms"], cmap, "'Force C'")
    assert "Force B" in err  # the closest existing name


def test_a_unit_mismatch_is_named(files, tmp_path, capsys):
    cmap = tmp_path / "channels.toml"
    cmap.write_text((files / "channels.toml").read_text().replace('unit = "m/s^2"', 'unit = "g"'))
    _refused(capsys, tmp_path, [files / "run1.tdms"], cmap, "Table acceleration")


def test_a_clipped_signal_names_the_line(clean, files, tmp_path, capsys):
    """Load cell A saturates at 90 % of its largest force: the first line that reaches it is named."""
    a = clean.channels["Force A"]
    level = 0.9 * np.abs(a).max()
    peaks = [np.abs(a[int(lo * clean.rate_hz):int(hi * clean.rate_hz)]).max() for lo, hi in clean.hold_s]
    first = F[np.argmax(np.array(peaks) > level)]
    raw = _variant(clean, tmp_path, **{"Force A": np.clip(a, -level, level)})
    err = _refused(capsys, tmp_path, [raw], files / "channels.toml", "clipped")
    assert "Force A" in err and f"the line at {first:g} Hz" in err


def test_nan_samples_are_named(clean, files, tmp_path, capsys):
    a = clean.channels["Table acceleration"].copy()
    lo = int(np.ceil(clean.hold_s[1, 0] * clean.rate_hz))
    a[lo + 10:lo + 50] = np.nan
    raw = _variant(clean, tmp_path, **{"Table acceleration": a})
    err = _refused(capsys, tmp_path, [raw], files / "channels.toml", "NaN")
    assert "Table acceleration" in err and f"sample {lo + 10}" in err


def test_non_monotonic_time_is_named(clean, files, tmp_path, capsys):
    t = np.arange(4000) / clean.rate_hz
    t[1234] = t[1232]
    frame = pd.DataFrame({"time": t, **{n: clean.channels[n][:4000] for n in clean.channels}})
    frame.to_csv(tmp_path / "run1.csv", index=False)
    cmap = tmp_path / "channels.toml"
    cmap.write_text((files / "channels.toml").read_text().replace('damper = {property = "damper"}', 'damper = "d"')
                    .replace('test = {property = "test"}', 'test = "t"').replace('run = {property = "run"}', "run = 1"))
    err = _refused(capsys, tmp_path, [tmp_path / "run1.csv"], cmap, "1234")
    assert "time" in err


def test_a_dwell_shorter_than_the_periods_needed(clean, files, tmp_path, capsys):
    """The 40 Hz dwell cut to 20 periods (the analysis needs 10 windows of 4)."""
    drive = clean.channels["Drive frequency"].copy()
    k = F.size - 1
    start = int(np.ceil(clean.start_s[k] * clean.rate_hz))
    drive[start + int(20 / F[k] * clean.rate_hz):] = 0.0
    raw = _variant(clean, tmp_path, **{"Drive frequency": drive})
    err = _refused(capsys, tmp_path, [raw], files / "channels.toml", "40 Hz")
    assert "periods" in err and "needed" in err


def test_a_missing_file_and_a_bad_map(files, tmp_path, capsys):
    _refused(capsys, tmp_path, [tmp_path / "nope.tdms"], files / "channels.toml", "nope.tdms")
    cmap = tmp_path / "channels.toml"
    cmap.write_text((files / "channels.toml").read_text().replace('source = "channel"', 'source = "radio"'))
    _refused(capsys, tmp_path, [files / "run1.tdms"], cmap, "source")


def test_uff_frfs_become_runs(files, tmp_path):
    """Two accelerance FRFs (UFF 58) import as two runs of ready lines, without measured columns."""
    from .test_import_sources import stiffness, write_uff

    w = 2 * np.pi
    write_uff(tmp_path / "frf.uff", [(12, 13, lambda f: -(w * f) ** 2 / stiffness(f), {}),
                                     (12, 13, lambda f: -(w * f) ** 2 / stiffness(f), {})])
    cmap = tmp_path / "channels.toml"
    cmap.write_text((files / "channels.toml").read_text()
                    .replace('damper = {property = "damper"}', 'damper = "damper1"')
                    .replace('test = {property = "test"}', 'test = "2-2"').replace('run = {property = "run"}\n', "")
                    .replace('[amplitude]\nchannel = "Drive amplitude"', '[amplitude]\nmm_pp = 2.0'))
    out = tmp_path / "out.csv"
    assert main(["import", str(tmp_path / "frf.uff"), "--map", str(cmap), "-o", str(out), "--quiet"]) == 0
    frame = pd.read_csv(out)
    assert sorted(frame["run"].unique()) == [1, 2] and (frame["amplitude_mm_pp"] == 2.0).all()
    h = frame["stiffness_n_per_m"] * np.exp(1j * np.radians(frame["phase_deg"]))
    np.testing.assert_allclose(h, stiffness(frame["frequency_hz"].to_numpy()), rtol=1e-5)
    assert frame["stiffness_se_n_per_m"].isna().all()


def test_an_amplitude_off_the_request_is_a_warning(clean, files, tmp_path, capsys):
    """The shaker reached 2 mm where 2.5 were asked (the drive amplitude channel says 2.5): kept, warned."""
    raw = _variant(clean, tmp_path, **{"Drive amplitude": clean.channels["Drive amplitude"] * 1.25})
    out = tmp_path / "out.csv"
    assert main(["import", str(raw), "--map", str(files / "channels.toml"), "-o", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.count("sbcal: warning:") == F.size and "2 mm p-p achieved, 2.5 requested" in err
    frame = pd.read_csv(out)
    assert (frame["amplitude_mm_pp"] == 2.5).all()
    np.testing.assert_allclose(frame["amplitude_achieved_mm_pp"], 2.0, rtol=1e-6)


def test_the_readme_channel_map_reads(tmp_path):
    """The README's example map (the first ```toml block after "sbcal import") is a valid map."""
    from pathlib import Path

    text = (Path(__file__).parents[1] / "README.md").read_text()
    block = text[text.index("```toml", text.index("(`sbcal import`)")) + 7:]
    (tmp_path / "channels.toml").write_text(block[:block.index("```")])
    cmap = load_channel_map(tmp_path / "channels.toml")
    assert cmap.force.channels == ("Force A", "Force B") and cmap.base.quantity == "acceleration"
    assert cmap.frequency.source == "channel" and cmap.amplitude.value == 2.0


# --- the other frequency sources: the same lines -------------------------------------------------------

def _map_with(files, tmp_path, frequency: str, labels=True):
    text = (files / "channels.toml").read_text()
    head, tail = text.split("[frequency]")
    tail = tail[tail.index("[amplitude]"):]
    if not labels:
        head = head.replace('run = {property = "run"}\n', "")
    (tmp_path / "channels.toml").write_text(head + "[frequency]\n" + frequency + "\n\n" + tail)
    return tmp_path


def test_dwells_found_in_the_signal_give_the_same_lines(files, clean, tmp_path):
    """No drive channel: the frequencies estimated from the table acceleration itself."""
    root = _map_with(files, tmp_path, 'source = "signal"')
    frame = _imported(files / "run1.tdms", root)
    np.testing.assert_allclose(frame["frequency_hz"], F, rtol=1e-6)
    rel, deg = _errors(frame, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05


def test_a_step_table_gives_the_same_lines(files, clean, tmp_path):
    """The steps start at each line's start; a step runs into the next one's (its taper and the pause are
    dropped as the drive tapering off)."""
    steps = "\n".join(f"{float(s)!r},{float(f)!r}" for s, f in zip(clean.start_s, F))
    (tmp_path / "steps.csv").write_text("start_s,frequency_hz\n" + steps + "\n")
    root = _map_with(files, tmp_path, 'source = "table"\ntable = "steps.csv"')
    frame = _imported(files / "run1.tdms", root)
    np.testing.assert_allclose(frame["frequency_hz"], F)
    rel, deg = _errors(frame, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05


def test_one_group_per_dwell_with_its_frequency_property(clean, files, tmp_path):
    """An HDF5 file holding each dwell as its own group (attribute frequency_hz), as some loggers save a stepped
    sine: one file is one run."""
    import h5py

    with h5py.File(tmp_path / "dwells.h5", "w") as h5:
        h5.attrs.update(damper="damper1", test="2-2")
        for k, f in enumerate(F):
            lo, hi = (np.ceil(np.array([clean.start_s[k], clean.hold_s[k, 1]]) * clean.rate_hz)).astype(int)
            g = h5.create_group(f"dwell{k:02d}")
            g.attrs.update(frequency_hz=f, sample_rate_hz=clean.rate_hz)
            for name in ("Force A", "Force B", "Table acceleration"):
                g.create_dataset(name, data=clean.channels[name][lo:hi]).attrs["unit"] = clean.units[name]
    root = _map_with(files, tmp_path, 'source = "property"\nproperty = "frequency_hz"', labels=False)
    text = (root / "channels.toml").read_text().replace('[amplitude]\nchannel = "Drive amplitude"',
                                                        "[amplitude]\nmm_pp = 2.0")
    (root / "channels.toml").write_text(text)
    frame = _imported(tmp_path / "dwells.h5", root)
    assert (frame["run"] == 1).all()
    rel, deg = _errors(frame, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05


def test_load_cells_stored_in_volts_with_their_own_calibrations(clean, files, tmp_path):
    """Force A stored in volts at 200 N/V, Force B at 150 N/V: one sensitivity per channel gives the same lines."""
    raw = dataclasses.replace(clean, channels=dict(clean.channels, **{
        "Force A": clean.channels["Force A"] / 200.0, "Force B": clean.channels["Force B"] / 150.0}))
    write_tdms(tmp_path / "volts.tdms", raw)  # (the writer labels them N: the map below checks no file unit)
    text = (files / "channels.toml").read_text().replace('unit = "N"', 'unit = "N"\nsensitivity = [200.0, 150.0]')
    (tmp_path / "channels.toml").write_text(text)
    frame = _imported(tmp_path / "volts.tdms", tmp_path)
    rel, deg = _errors(frame, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05


def test_a_frequency_written_on_each_channel_of_a_dwell_group(clean, files, tmp_path):
    """A TDMS file of one group per dwell whose channels each carry the dwell's frequency (no group property)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    with TdmsWriter(str(tmp_path / "dwells.tdms")) as w:
        w.write_segment([RootObject({"damper": "damper1", "test": "2-2"})])
        for k, f in enumerate(F):
            lo, hi = (np.ceil(np.array([clean.start_s[k], clean.hold_s[k, 1]]) * clean.rate_hz)).astype(int)
            props = {"wf_increment": 1 / clean.rate_hz, "Frequency": float(f)}
            w.write_segment([GroupObject(f"dwell {k}")] + [
                ChannelObject(f"dwell {k}", name, clean.channels[name][lo:hi],
                              properties=dict(props, unit_string=clean.units[name]))
                for name in ("Force A", "Force B", "Table acceleration")])
    root = _map_with(files, tmp_path, 'source = "property"\nproperty = "Frequency"', labels=False)
    text = (root / "channels.toml").read_text().replace('[amplitude]\nchannel = "Drive amplitude"',
                                                        "[amplitude]\nmm_pp = 2.0")
    (root / "channels.toml").write_text(text)
    frame = _imported(tmp_path / "dwells.tdms", root)
    np.testing.assert_allclose(frame["frequency_hz"], F)
    rel, deg = _errors(frame, clean)
    assert np.abs(rel).max() < 1e-3 and np.abs(deg).max() < 0.05
