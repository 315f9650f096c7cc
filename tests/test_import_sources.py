"""Raw recordings for ``sbcal import`` (docs/import.md): the channel map, units, and a reader per file
type (TDMS contiguous and interleaved, HDF5, MDF4, CSV), each on a file made here."""

import re
import struct
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from sbcal import InputError
from sbcal.data.acquisition import sources
from sbcal.data.acquisition.channel_map import (Analysis, ChannelMap, FrequencySource, Label, Sensor, Step,
                                                check_units, load_channel_map)
from sbcal.data.acquisition.sources import Block, open_blocks
from sbcal.data.acquisition.units import parse_unit, same_unit

DOCS = Path(__file__).resolve().parents[1] / "docs" / "import.md"
RATE = 512.0
N = 3000
NAMES = ("Force A", "Force B", "Table acceleration", "Drive frequency")


def signals(n=N):
    """Distinct, recognisable values per channel: channel k holds 1000 k + sample index."""
    i = np.arange(n, dtype=np.float64)
    return {name: 1000.0 * k + i for k, name in enumerate(NAMES)}


def one_line(e) -> str:
    msg = str(e.value)
    assert "\n" not in msg
    return msg


# --- units ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, quantity, factor", [
    ("m/s^2", "acceleration", 1.0), ("m/s²", "acceleration", 1.0), ("m s^-2", "acceleration", 1.0),
    ("m/s2", "acceleration", 1.0), ("g", "acceleration", 9.80665), ("mm/s^2", "acceleration", 1e-3),
    ("N", "force", 1.0), ("kN", "force", 1e3), ("lbf", "force", 4.4482216152605),
    ("m/s", "velocity", 1.0), ("mm/s", "velocity", 1e-3), ("in/s", "velocity", 0.0254),
    ("m", "displacement", 1.0), ("mm", "displacement", 1e-3), ("um", "displacement", 1e-6),
    ("µm", "displacement", 1e-6), ("in", "displacement", 0.0254), (" mm s^-1 ", "velocity", 1e-3),
])
def test_units_tolerant_spelling(text, quantity, factor):
    assert parse_unit(text) == (quantity, pytest.approx(factor, rel=1e-15))


def test_unknown_unit_and_same_unit():
    with pytest.raises(InputError, match=r"unknown unit 'furlong' \(known: N, kN"):
        parse_unit("furlong")
    assert same_unit("m/s^2", "m s^-2") and same_unit("µm", "um") and same_unit("V", " v ")
    assert not same_unit("g", "m/s^2") and not same_unit("mm", "mm/s") and not same_unit("V", "N")


# --- the channel map ------------------------------------------------------------------------------

def docs_example() -> str:
    """The full channel map of docs/import.md."""
    return re.search(r"```toml\n(.*?)```", DOCS.read_text(), re.S).group(1)


def test_docs_example_parses(tmp_path):
    path = tmp_path / "channels.toml"
    path.write_text(docs_example())
    cmap = load_channel_map(path)
    assert cmap == ChannelMap(
        path=str(path), damper=Label(value="damper1"), test=Label(property="test"), run=Label(property="run"),
        force=Sensor(channels=("Force A", "Force B"), unit="N", sensitivity=(1.0, 1.0), file_unit="N", range=20000.0,
                     quantity="force", si_factor=(1.0, 1.0)),
        base=Sensor(channels=("Table acceleration",), unit="m/s^2", sensitivity=(1.0,), file_unit="m/s^2",
                    range=1000.0, quantity="acceleration", si_factor=(1.0,)),
        frequency=FrequencySource(source="channel", channel="Drive frequency"),
        amplitude=Label(property="amplitude_mm_pp"), amplitude_channel=None, analysis=Analysis())
    assert cmap.channels() == NAMES
    assert cmap.test.resolve({"test": "2-1"}, what="x") == "2-1"
    with pytest.raises(InputError, match=r"^f.tdms, group 'G': no property 'run' \(properties: 'test'\)$"):
        cmap.run.resolve({"test": "2-1"}, what="f.tdms, group 'G'")


BASE_MAP = {
    "labels": 'damper = "damper1"\ntest = "2-1"\n',
    "force": 'channels = ["Force A", "Force B"]\nunit = "N"\n',
    "base": 'channel = "Table acceleration"\nunit = "m/s^2"\n',
    "frequency": 'source = "channel"\nchannel = "Drive frequency"\n',
    "amplitude": "mm_pp = 2.0\n",
}


def write_map(tmp_path, **sections) -> Path:
    """A map of BASE_MAP with sections replaced (None: left out); a key "raw" is put first, verbatim."""
    parts = {**BASE_MAP, **sections}
    raw = parts.pop("raw", "")
    text = raw + "".join(f"[{name}]\n{body}\n" for name, body in parts.items() if body is not None)
    path = tmp_path / "map.toml"
    path.write_text(text)
    return path


def test_small_map_defaults(tmp_path):
    cmap = load_channel_map(write_map(tmp_path, force='channel = "F"\nunit = "kN"\nsensitivity = 2.0\n',
                                      base='channel = "x"\nunit = "mm"\n'))
    assert cmap.run is None and cmap.analysis == Analysis()
    assert cmap.force == Sensor(channels=("F",), unit="kN", sensitivity=(2.0,), file_unit=None, range=None,
                                quantity="force", si_factor=(2000.0,))
    assert cmap.base.quantity == "displacement" and cmap.base.si_factor == (1e-3,) and cmap.base.file_unit == "mm"
    assert cmap.amplitude == Label(value=2.0) and cmap.amplitude_channel is None


def test_step_tables_inline_and_csv(tmp_path):
    inline = ('source = "table"\ntable = [{start_s = 0.0, frequency_hz = 4.0, amplitude_mm_pp = 2.0},\n'
              '  {start_s = 30, frequency_hz = 4.5, amplitude_mm_pp = 1.5}]\n')
    cmap = load_channel_map(write_map(tmp_path, frequency=inline, amplitude=None))
    assert cmap.frequency == FrequencySource(source="table", steps=(Step(0.0, 4.0, 2.0), Step(30.0, 4.5, 1.5)))
    assert cmap.amplitude == Label() and cmap.amplitude_channel is None
    (tmp_path / "tables").mkdir()
    (tmp_path / "tables" / "steps.csv").write_text("# a comment\nstart_s,frequency_hz\n0,4\n\n20.5,5\n")
    cmap = load_channel_map(write_map(tmp_path, frequency='source = "table"\ntable = "tables/steps.csv"\n'))
    assert cmap.frequency.steps == (Step(0.0, 4.0), Step(20.5, 5.0))
    array_of_tables = ('source = "table"\n[[frequency.table]]\nstart_s = 0\nfrequency_hz = 4\n'
                       '[[frequency.table]]\nstart_s = 10\nfrequency_hz = 6\n')
    cmap = load_channel_map(write_map(tmp_path, frequency=None, raw="[frequency]\n" + array_of_tables))
    assert cmap.frequency.steps == (Step(0.0, 4.0), Step(10.0, 6.0))


@pytest.mark.parametrize("edit, message", [
    ({"labels": 'damper = "d"\n'}, "[labels] test: missing"),
    ({"labels": 'damper = "d"\ntest = "t"\ndampr = "x"\n'}, "[labels] dampr: unknown key (known: damper, test, run)"),
    ({"labels": 'damper = "d"\ntest = true\n'}, '[labels] test: expected a string, a number or {property = "name"}'),
    ({"labels": 'damper = "d"\ntest = {prop = "x"}\n'}, "[labels] test: expected a string"),
    ({"labels": 'damper = "d"\ntest = {property = 3}\n'}, "[labels] test: property: expected a non-empty string"),
    ({"force": 'channels = []\nunit = "N"\n'}, "[force] channels: expected a non-empty list of channel names"),
    ({"force": 'channels = ["A", "A"]\nunit = "N"\n'}, "[force] channels: a channel is named twice"),
    ({"force": 'channels = ["A"]\nchannel = "B"\nunit = "N"\n'}, "[force] channels: give either"),
    ({"force": 'channels = ["A"]\n'}, "[force] unit: missing"),
    ({"force": 'channels = ["A"]\nunit = "m/s^2"\n'}, "[force] unit: 'm/s^2' is not a force unit"),
    ({"force": 'channels = ["A"]\nunit = "furlong"\n'}, "[force] unit: unknown unit 'furlong'"),
    ({"force": 'channels = ["A"]\nunit = "N"\nsensitivity = 0\n'}, "[force] sensitivity: must not be 0, got 0"),
    ({"force": 'channels = ["A"]\nunit = "N"\nsensitivity = "2"\n'}, "[force] sensitivity: expected a number"),
    ({"force": 'channels = ["A"]\nunit = "N"\nsensitivity = nan\n'}, "[force] sensitivity: must be finite"),
    ({"force": 'channels = ["A", "B"]\nunit = "N"\nsensitivity = [1.0]\n'},
     "[force] sensitivity: a list of 1 for 2 channel(s)"),
    ({"force": 'channels = ["A", "B"]\nunit = "N"\nsensitivity = [1.0, 0]\n'}, "[force] sensitivity: must not be 0"),
    ({"force": 'channels = ["A"]\nunit = "N"\nrange = -1\n'}, "[force] range: must be > 0, got -1"),
    ({"force": 'channels = ["A"]\nunit = "N"\nfile_unit = ""\n'}, "[force] file_unit: expected a non-empty string"),
    ({"base": 'unit = "g"\n'}, "[base] channel: missing"),
    ({"base": 'channels = ["x"]\nunit = "g"\n'}, "[base] channels: unknown key"),
    ({"base": 'channel = "x"\nunit = "g"\nquantity = "jerk"\n'}, "[base] quantity: 'jerk' is not one of"),
    ({"base": 'channel = "x"\nunit = "g"\nquantity = "velocity"\n'}, "[base] unit: 'g' is not a unit of velocity"),
    ({"base": 'channel = "x"\nunit = "N"\n'},
     "[base] unit: 'N' is a unit of force, not of base motion (known: g, m/s^2"),
    ({"frequency": 'channel = "f"\n'}, "[frequency] source: missing"),
    ({"frequency": 'source = "guess"\n'}, "[frequency] source: 'guess' is not one of property, table, channel, signal"),
    ({"frequency": 'source = "channel"\n'}, "[frequency] channel: missing (source = 'channel' needs it)"),
    ({"frequency": 'source = "channel"\nchannel = "f"\nproperty = "p"\n'},
     "[frequency] property: only with source = 'property' (source is 'channel')"),
    ({"frequency": 'source = "table"\ntable = []\n'}, "[frequency] table: no steps"),
    ({"frequency": 'source = "table"\ntable = 3\n'}, "[frequency] table: expected an array of"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 0, frequency_hz = 0}]\n'},
     "[frequency] table[1].frequency_hz: must be > 0, got 0"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 0}]\n'}, "[frequency] table[1].frequency_hz: missing"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 0, freq = 4}]\n'}, "[frequency] table[1].freq: unknown key"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 5, frequency_hz = 4}, {start_s = 5, frequency_hz = 5}]\n'},
     "[frequency] table[2].start_s: 5 is not after the previous step's 5"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 0, frequency_hz = 4, amplitude_mm_pp = 1}, '
                   '{start_s = 5, frequency_hz = 5}]\n'},
     "[frequency] table[2].amplitude_mm_pp: give it on every step or on none"),
    ({"frequency": 'source = "table"\ntable = "nowhere.csv"\n'}, "[frequency] table: no such file"),
    ({"frequency": 'source = "table"\ntable = [{start_s = 0, frequency_hz = 4, amplitude_mm_pp = 1}]\n'},
     "[amplitude] mm_pp: the step table already gives amplitude_mm_pp"),
    ({"amplitude": None}, "[amplitude]: missing (mm_pp, property or channel"),
    ({"amplitude": ""}, "[amplitude]: empty (give one of mm_pp, property, channel)"),
    ({"amplitude": 'mm_pp = 2.0\nproperty = "a"\n'}, "[amplitude] property: give only one of mm_pp, property, channel"),
    ({"amplitude": "mm_pp = -2.0\n"}, "[amplitude] mm_pp: must be > 0, got -2.0"),
    ({"raw": "[analysis]\nwindow_periods = 2.5\n"},
     "[analysis] window_periods: expected an integer, got the number 2.5"),
    ({"raw": "[analysis]\nmin_windows = 1\n"}, "[analysis] min_windows: must be >= 2, got 1"),
    ({"raw": "[analysis]\nsettle_tolerance = 2\n"}, "[analysis] settle_tolerance: must be between 0 and 1"),
    ({"raw": "[analysis]\nharmonics = 0\n"}, "[analysis] harmonics: must be >= 1, got 0"),
    ({"raw": '[analysis]\ngroups = ""\n'}, "[analysis] groups: expected a non-empty string"),
    ({"raw": "[analysis]\nwindows = 3\n"}, "[analysis] windows: unknown key"),
    ({"raw": "[extra]\nx = 1\n"}, "[extra]: unknown section (known: labels, force, base"),
    ({"force": None}, "[force]: missing"),
    ({"force": None, "raw": "force = 3\n"}, "[force]: expected a table, got the number 3"),
])
def test_bad_map_keys(tmp_path, edit, message):
    path = write_map(tmp_path, **edit)
    with pytest.raises(InputError) as e:
        load_channel_map(path)
    assert one_line(e).startswith(f"{path}: ") and message in str(e.value), str(e.value)


def test_invalid_toml(tmp_path):
    path = write_map(tmp_path, raw="[analysis\n")
    with pytest.raises(InputError, match="invalid TOML"):
        load_channel_map(path)


@pytest.mark.parametrize("text, message", [
    ("start_s,frequency_hz\n0,4\n10,abc\n", "steps.csv, line 3: frequency_hz: not a number: 'abc'"),
    ("start_s,frequency_hz\n0,4\n\n0,5\n", "steps.csv, line 4: start_s: 0 is not after the previous step's 0"),
    ("start_s,frequency\n0,4\n", "steps.csv, line 1: unknown column 'frequency'"),
    ("start_s\n0\n", "steps.csv, line 1: column 'frequency_hz' missing"),
    ("start_s,frequency_hz\n0,4,5\n", "steps.csv, line 2: 3 cells, the header has 2"),
    ("start_s,frequency_hz\n", "steps.csv: no steps"),
])
def test_bad_step_csv(tmp_path, text, message):
    (tmp_path / "steps.csv").write_text(text)
    with pytest.raises(InputError) as e:
        load_channel_map(write_map(tmp_path, frequency='source = "table"\ntable = "steps.csv"\n'))
    assert message in one_line(e)


# --- readers --------------------------------------------------------------------------------------

def check_block(block, data, rate=RATE, n=N):
    assert block.rate_hz == pytest.approx(rate, rel=1e-9) and block.n_samples == n
    for name, x in data.items():
        for start, stop in ((0, 7), (n // 3 - 2, n // 3 + 2), (n - 5, n), (0, n), (10, 10)):
            got = block.read(name, start, stop)
            assert got.dtype == np.float64 and np.array_equal(got, x[start:stop])


def write_tdms(path, data, *, segments=5, root=None, group=None, props=None):
    nptdms = pytest.importorskip("nptdms")
    edges = np.linspace(0, len(next(iter(data.values()))), segments + 1).astype(int)
    with nptdms.TdmsWriter(path) as w:
        for a, b in zip(edges[:-1], edges[1:]):
            w.write_segment([nptdms.RootObject(root or {}), nptdms.GroupObject("Dwells", group or {})]
                            + [nptdms.ChannelObject("Dwells", k, x[a:b], (props or {}).get(k, {}))
                               for k, x in data.items()])


def test_tdms_contiguous(tmp_path):
    data = signals()
    props = {k: {"wf_increment": 1 / RATE, "unit_string": u} for k, u in zip(NAMES, ("N", "N", "m/s^2", "Hz"))}
    path = tmp_path / "run.tdms"
    write_tdms(path, data, segments=7, root={"damper": "damper1", "run": 1, "test": "2-1"},
               group={"run": 4, "amplitude_mm_pp": 2.0}, props=props)
    with open_blocks(path) as blocks:
        (b,) = blocks
        assert b.name == "Dwells" and b.source == str(path) and b.channels() == NAMES
        assert b.properties == {"damper": "damper1", "run": 4, "test": "2-1", "amplitude_mm_pp": 2.0}
        assert b.unit("Table acceleration") == "m/s^2"
        check_block(b, data)


def _tdms_string(text: str) -> bytes:
    raw = text.encode()
    return struct.pack("<I", len(raw)) + raw


def write_interleaved_tdms(path, data, rate, segments):
    """A TDMS file with interleaved float64 data (npTDMS's writer writes contiguous data only): the
    segment layout of NI's TDMS file format reference, little-endian."""
    n = len(next(iter(data.values())))
    edges = np.linspace(0, n, segments + 1).astype(int)
    toc = (1 << 1) | (1 << 2) | (1 << 3) | (1 << 5)  # metadata, new object list, raw data, interleaved
    with open(path, "wb") as f:
        for a, b in zip(edges[:-1], edges[1:]):
            meta = struct.pack("<I", 2 + len(data))
            meta += _tdms_string("/") + struct.pack("<II", 0xFFFFFFFF, 0)
            meta += _tdms_string("/'G'") + struct.pack("<II", 0xFFFFFFFF, 0)
            for name in data:
                meta += _tdms_string(f"/'G'/'{name}'") + struct.pack("<IIIQ", 20, 10, 1, b - a)  # float64, b-a values
                meta += struct.pack("<I", 1) + _tdms_string("wf_increment") + struct.pack("<Id", 10, 1 / rate)
            raw = np.column_stack([x[a:b] for x in data.values()]).astype("<f8").tobytes()
            f.write(b"TDSm" + struct.pack("<IIQQ", toc, 4713, len(meta) + len(raw), len(meta)) + meta + raw)


def test_tdms_interleaved(tmp_path):
    pytest.importorskip("nptdms")
    data = signals()
    path = tmp_path / "interleaved.tdms"
    write_interleaved_tdms(path, data, RATE, segments=6)
    with open_blocks(path) as (b,):
        assert b.name == "G" and b.channels() == NAMES and b.unit("Force A") is None
        check_block(b, data)


def test_tdms_time_channel_checked_in_slices(tmp_path, monkeypatch):
    monkeypatch.setattr(sources, "_CHUNK", 64)  # the check reads the time in slices: cross several
    data = {"time": np.arange(N) / RATE, **signals()}
    write_tdms(tmp_path / "t.tdms", data)
    with open_blocks(tmp_path / "t.tdms") as (b,):
        assert b.channels() == NAMES
        check_block(b, signals())
    stamps = np.datetime64("2026-01-01T08:00:00") + (data["time"] * 1e9).astype("timedelta64[ns]")
    write_tdms(tmp_path / "stamps.tdms", {**data, "time": stamps})  # LabVIEW's timestamps: seconds from the first
    with open_blocks(tmp_path / "stamps.tdms") as (b,):
        # npTDMS gives timestamps in microseconds: the rate is good to 1 us over the record
        assert b.rate_hz == pytest.approx(RATE, rel=1e-6) and b.channels() == NAMES
    data["time"][1500:] -= 1.5 / RATE  # a step back at sample 1500
    write_tdms(tmp_path / "t.tdms", data)
    with pytest.raises(InputError) as e:
        with open_blocks(tmp_path / "t.tdms"):
            pass
    assert one_line(e).startswith(f"{tmp_path / 't.tdms'}, group 'Dwells', channel 'time': time not strictly "
                                  f"increasing at sample 1500: 2.92675781 s after 2.92773438 s")


def test_tdms_group_sampled_differently(tmp_path):
    data = signals()
    props = {k: {"wf_increment": 1 / RATE} for k in NAMES}
    props["Force B"] = {"wf_increment": 2 / RATE}
    write_tdms(tmp_path / "a.tdms", data, props=props)
    with pytest.raises(InputError, match=r"group 'Dwells': channels sampled differently: 'Force A' at 512 Hz, "
                                         r"'Force B' at 256 Hz"):
        with open_blocks(tmp_path / "a.tdms"):
            pass
    props["Force B"] = {"wf_increment": 1 / RATE}
    data["Force B"] = data["Force B"][:-1]
    write_tdms(tmp_path / "a.tdms", data, props=props)
    with pytest.raises(InputError, match=r"channels of different length: 'Force A' has 3000 samples, 'Force B' 2999"):
        with open_blocks(tmp_path / "a.tdms"):
            pass
    del props["Force A"]
    data["Force B"] = signals()["Force B"]
    write_tdms(tmp_path / "a.tdms", data, props=props)
    with pytest.raises(InputError, match=r"channel 'Force A': no sampling rate \(no wf_increment property and no "
                                         r"'time' channel\)"):
        with open_blocks(tmp_path / "a.tdms"):
            pass


def test_tdms_groups_left_out_are_not_checked(tmp_path):
    nptdms = pytest.importorskip("nptdms")
    data = signals()
    path = tmp_path / "r.tdms"
    with nptdms.TdmsWriter(path) as w:
        w.write_segment([nptdms.ChannelObject("Dwell", k, x, {"wf_increment": 1 / RATE}) for k, x in data.items()]
                        + [nptdms.ChannelObject("Settings", "gain", np.ones(3)),  # no rate: not a record
                           nptdms.ChannelObject("Settings", "name", ["a", "b"])])
    with pytest.raises(InputError, match=r"group 'Settings', channel 'gain': no sampling rate"):
        with open_blocks(path):
            pass
    cmap = load_channel_map(write_map(tmp_path, raw='[analysis]\ngroups = "Dwell*"\n'))
    with open_blocks(path, cmap) as (b,):
        assert b.name == "Dwell"
        check_block(b, data)


def write_h5(path, data, time=None):
    with h5py.File(path, "w") as f:
        f.attrs.update(damper="damper1", test="2-1", run=1)
        for name, rate in (("dwell 1", RATE), ("dwell 2", 2 * RATE)):
            g = f.create_group(name)
            g.attrs["run"] = 7
            if time is None:
                g.attrs["sample_rate_hz"] = rate
            else:
                g.create_dataset("time", data=time / (rate / RATE))
            for k, x in data.items():
                g.create_dataset(k, data=x).attrs["unit"] = {"Force": "N", "Drive": "Hz"}.get(k[:5], "V")
        f.create_group("settings").attrs["note"] = "no datasets: not a block"


def test_hdf5_documented_layout(tmp_path):
    data = signals()
    write_h5(tmp_path / "r.h5", data)
    with open_blocks(tmp_path / "r.h5") as blocks:
        assert [b.name for b in blocks] == ["dwell 1", "dwell 2"]
        assert blocks[0].properties == {"damper": "damper1", "test": "2-1", "run": 7, "sample_rate_hz": RATE}
        assert blocks[0].unit("Force B") == "N" and blocks[1].unit("Table acceleration") == "V"
        check_block(blocks[0], data)
        check_block(blocks[1], data, rate=2 * RATE)
    write_h5(tmp_path / "t.hdf5", data, time=np.arange(N) / RATE + 3.0)
    with open_blocks(tmp_path / "t.hdf5") as blocks:
        assert sorted(blocks[1].channels()) == sorted(NAMES)  # h5py lists datasets by name
        check_block(blocks[1], data, rate=2 * RATE)


def test_hdf5_groups_pattern_and_bad_time(tmp_path):
    data = signals()
    write_h5(tmp_path / "r.h5", data)
    cmap = load_channel_map(write_map(tmp_path, raw='[analysis]\ngroups = "* 2"\n'))
    with open_blocks(tmp_path / "r.h5", cmap) as blocks:
        assert [b.name for b in blocks] == ["dwell 2"]
    cmap = load_channel_map(write_map(tmp_path, raw='[analysis]\ngroups = "run*"\n'))
    with pytest.raises(InputError, match=r"r.h5: no group matches 'run\*' \(groups: 'dwell 1', 'dwell 2'\)"):
        with open_blocks(tmp_path / "r.h5", cmap):
            pass
    t = np.arange(N) / RATE
    t[2000:] += 0.2 / RATE  # one interval 20 % long
    write_h5(tmp_path / "t.h5", data, time=t)
    with pytest.raises(InputError, match=r"group 'dwell 1', channel 'time': sampling not uniform at sample 2000"):
        with open_blocks(tmp_path / "t.h5"):
            pass


def write_mf4(path, groups):
    """groups: [(acq_name, timestamps, {name: (samples, unit)})]"""
    asammdf = pytest.importorskip("asammdf")
    mdf = asammdf.MDF(version="4.10")
    for name, t, chans in groups:
        mdf.append([asammdf.Signal(x, t, name=k, unit=u) for k, (x, u) in chans.items()], acq_name=name,
                   comment='<CGcomment><TX>dwell</TX><common_properties><e name="run">5</e>'
                           '</common_properties></CGcomment>' if name == "dwell 2" else "plain")
    mdf.header.comment = ('<HDcomment><TX>bench</TX><common_properties><e name="test">2-1</e>'
                          '<e name="run">1</e></common_properties></HDcomment>')
    mdf.header.author = "lab"
    mdf.save(path, overwrite=True)
    mdf.close()


def test_mdf4(tmp_path):
    data = signals()
    t = 10.0 + np.arange(N) / RATE
    chans = {k: (x, "N" if k.startswith("Force") else "") for k, x in data.items()}
    short = {k: (x[:1000], u) for k, (x, u) in list(chans.items())[:2]}
    write_mf4(tmp_path / "r.mf4", [("dwell 1", t, chans), ("dwell 2", t[:1000] * 2, short)])
    with open_blocks(tmp_path / "r.mf4") as blocks:
        assert [b.name for b in blocks] == ["dwell 1", "dwell 2"]
        assert blocks[0].properties == {"test": "2-1", "run": "1", "author": "lab"}
        assert blocks[1].properties == {"test": "2-1", "run": "5", "author": "lab"}
        assert blocks[0].channels() == NAMES and blocks[1].channels() == NAMES[:2]
        assert blocks[0].unit("Force A") == "N" and blocks[0].unit("Table acceleration") is None
        check_block(blocks[0], data)
        check_block(blocks[1], {k: x[:1000] for k, x in list(data.items())[:2]}, rate=RATE / 2, n=1000)


@pytest.mark.parametrize("glitch, message", [
    (lambda t: t.__setitem__(700, t[699]),
     r"time not strictly increasing at sample 700: 11.3652344 s after 11.3652344 s"),
    (lambda t: t.__setitem__(slice(700, None), t[700:] + 1),
     r"sampling not uniform at sample 700 \(t = 12.3671875 s\)"),
])
def test_mdf4_bad_time(tmp_path, glitch, message):
    t = 10.0 + np.arange(N) / RATE
    glitch(t)
    write_mf4(tmp_path / "r.mf4", [("dwell 1", t, {"F": (signals()["Force A"], "N")})])
    with pytest.raises(InputError) as e:
        with open_blocks(tmp_path / "r.mf4"):
            pass
    assert re.search(message, one_line(e)) and str(e.value).startswith(f"{tmp_path / 'r.mf4'}, group 'dwell 1'")


def write_csv(path, data, t, sep=",", header=None):
    cols = ["time [s]"] + [f"{k} [{'N' if k.startswith('Force') else 'm/s^2'}]" for k in data]
    rows = [sep.join(header or cols)] + [sep.join(repr(float(v)) for v in row)
                                         for row in zip(t, *data.values())]
    path.write_text("\n".join(rows) + "\n")


def test_csv(tmp_path):
    data = signals()
    write_csv(tmp_path / "r.csv", data, np.arange(N) / RATE)
    with open_blocks(tmp_path / "r.csv") as (b,):
        assert b.name == "" and b.properties == {} and b.channels() == NAMES
        assert b.unit("Force A") == "N" and b.unit("Table acceleration") == "m/s^2"
        check_block(b, data)
    write_csv(tmp_path / "ms.csv", data, 1e3 * np.arange(N) / RATE, sep=";",
              header=["t [ms]", *NAMES])
    text = (tmp_path / "ms.csv").read_text()
    (tmp_path / "ms.csv").write_text("\ufeff" + text + "\n\n")  # a spreadsheet's byte order mark, blank lines
    cmap = load_channel_map(write_map(tmp_path, raw='[analysis]\ntime_channel = "t"\n'))
    with open_blocks(tmp_path / "ms.csv", cmap) as (b,):
        assert b.unit("Force A") is None
        check_block(b, data)


def test_csv_bad_time_and_cells(tmp_path):
    data = signals()
    t = np.arange(N) / RATE
    t[40] = t[38]
    write_csv(tmp_path / "r.csv", data, t)
    with pytest.raises(InputError) as e:
        with open_blocks(tmp_path / "r.csv"):
            pass
    assert one_line(e) == (f"{tmp_path / 'r.csv'}: time not strictly increasing at sample 40 (line 42): "
                           f"0.07421875 s after 0.076171875 s")
    t = np.arange(N) / RATE
    t[40:] += 0.5 / RATE
    write_csv(tmp_path / "r.csv", data, t)
    with pytest.raises(InputError, match=r"sampling not uniform at sample 40 \(line 42\)"):
        with open_blocks(tmp_path / "r.csv"):
            pass
    lines = (tmp_path / "r.csv").read_text().splitlines()
    lines[5] = lines[5].replace(",", ",x", 1)
    (tmp_path / "r.csv").write_text("\n".join(lines))
    with pytest.raises(InputError, match=r"r.csv, line 6, column 'Force A': not a number: 'x"):
        with open_blocks(tmp_path / "r.csv"):
            pass
    write_csv(tmp_path / "r.csv", data, t, header=["Time", *NAMES])
    with pytest.raises(InputError, match=r"r.csv: no time column 'time' \(columns, closest first: 'Time'"):
        with open_blocks(tmp_path / "r.csv"):
            pass


# --- what every reader shares: missing channels, units, files, packages ---------------------------

def test_missing_channel_named_with_the_closest(tmp_path):
    data = signals()
    data["Force  B"] = data.pop("Force B")
    write_h5(tmp_path / "r.h5", data)
    cmap = load_channel_map(write_map(tmp_path))
    with pytest.raises(InputError) as e:
        with open_blocks(tmp_path / "r.h5", cmap):
            pass
    assert one_line(e) == (f"{tmp_path / 'r.h5'}, group 'dwell 1': no channel 'Force B' (channels, closest first: "
                           f"'Force  B', 'Force A', 'Drive frequency', 'Table acceleration')")


def test_check_units(tmp_path):
    data = signals()
    write_h5(tmp_path / "r.h5", data)  # forces in N, the frequency in Hz, the others in V
    volts = load_channel_map(write_map(tmp_path, base='channel = "Table acceleration"\nunit = "m s^-2"\n'
                                                      'sensitivity = 9.81\nfile_unit = "v"\n'))
    same = load_channel_map(write_map(tmp_path))
    with open_blocks(tmp_path / "r.h5", volts) as blocks:
        check_units(blocks[0], volts)  # N is N, "v" is "V", Hz is Hz
    with pytest.raises(InputError) as e:
        with open_blocks(tmp_path / "r.h5", same) as blocks:
            check_units(blocks[0], same)
    assert one_line(e) == (f"{tmp_path / 'r.h5'}, group 'dwell 1', channel 'Table acceleration': unit 'V' in the "
                           f"file, but {same.path} [base] unit is 'm/s^2'")
    write_csv(tmp_path / "r.csv", data, np.arange(N) / RATE)  # Drive frequency [m/s^2]
    with pytest.raises(InputError, match=r"r.csv, channel 'Drive frequency': unit 'm/s\^2' in the file, but .* "
                                         r"\[frequency\] channel must hold Hz"):
        with open_blocks(tmp_path / "r.csv", same) as (b,):
            check_units(b, same)


def test_files_refused(tmp_path):
    with pytest.raises(InputError, match=r"r.txt: unknown file type '.txt' \(accepted: .tdms, .h5, .hdf5, .mf4, "
                                         r".mdf, .csv\)"):
        with open_blocks(tmp_path / "r.txt"):
            pass
    with pytest.raises(InputError, match=r"nothing.h5: no such file"):
        with open_blocks(tmp_path / "nothing.h5"):
            pass
    for ext in (".h5", ".tdms", ".mf4"):
        (tmp_path / f"junk{ext}").write_bytes(b"not a recording" * 100)
        with pytest.raises(InputError, match=rf"junk{ext}: not a readable (HDF5|TDMS|MDF) file"):
            with open_blocks(tmp_path / f"junk{ext}"):
                pass


@pytest.mark.parametrize("module, ext, message", [
    ("nptdms", ".tdms", 'needs npTDMS: pip install "sbcal[tdms]"'),
    ("asammdf", ".mf4", 'needs asammdf: pip install "sbcal[mdf]"'),
])
def test_missing_reader_package(tmp_path, monkeypatch, module, ext, message):
    path = tmp_path / f"r{ext}"
    path.write_bytes(b"")
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    with pytest.raises(InputError) as e:
        with open_blocks(path):
            pass
    assert one_line(e) == f"reading {path} {message}"


def test_block_read_checks_its_range():
    b = Block(source="f.csv", name="", properties={}, rate_hz=1.0, n_samples=3, units={"x": None},
              read=lambda k, a, b: np.arange(3)[a:b])
    assert b.read("x", 1, 3).tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match=r"f.csv, channel 'x': samples \[2, 4\) outside \[0, 3\)"):
        b.read("x", 2, 4)


# --- UFF 58: FRFs as ready lines ------------------------------------------------------------------

def stiffness(f):
    """A damper-like dynamic stiffness [N/m]: a mass-spring with loss."""
    w = 2 * np.pi * f
    return 3e4 * (1 + 0.1j) - 1.2 * w ** 2


def write_uff(path, frfs, units=None):
    """frfs: [(numerator type, denominator type, data, {label keys})]; units: a dataset 164 (length, force)."""
    pyuff = pytest.importorskip("pyuff")
    f = np.linspace(0.0, 40.0, 81)  # from 0 Hz, as analysers write
    sets = [] if units is None else [pyuff.prepare_164(units_code=9, units_description="user", temp_mode=1,
                                                       length=units[0], force=units[1], temp=1.0, temp_offset=273.15)]
    for i, (num, den, data, labels) in enumerate(frfs):
        with np.errstate(divide="ignore", invalid="ignore"):  # the 0 Hz point of a motion FRF
            values = data(f)
        sets.append(pyuff.prepare_58(binary=i % 2, func_type=4, rsp_node=1, rsp_dir=3, ref_node=2, ref_dir=3,
                                     data=values, x=f, id1=f"frf {i}", abscissa_spacing=1,
                                     abscissa_spec_data_type=18, ordinate_spec_data_type=num,
                                     orddenom_spec_data_type=den, **labels))
    sets.append(pyuff.prepare_58(binary=0, func_type=6, rsp_node=1, rsp_dir=3, ref_node=2, ref_dir=3,
                                 data=np.ones(len(f)), x=f, abscissa_spacing=1, abscissa_spec_data_type=18,
                                 ordinate_spec_data_type=0, orddenom_spec_data_type=0))  # a coherence: skipped
    pyuff.UFF(str(path)).write_sets(sets, mode="add")


def test_uff_frfs_to_stiffness(tmp_path):
    from sbcal.data.acquisition.uff import read_uff_lines

    def w(f):
        return 2 * np.pi * f

    write_uff(tmp_path / "frf.uff", [
        (12, 13, lambda f: -w(f) ** 2 / stiffness(f) / 9.80665, {"ordinate_axis_units_lab": "g"}),  # accelerance in g/N
        (13, 11, lambda f: stiffness(f) / (1j * w(f)), {}),  # mechanical impedance, SI
        (8, 9, lambda f: 1e3 / stiffness(f), {"ordinate_axis_units_lab": "mm"}),  # receptance in mm/N
        (9, 8, lambda f: stiffness(f), {}),  # dynamic stiffness
    ])
    lines = read_uff_lines(tmp_path / "frf.uff")
    assert [p["function"] for _, _, p in lines] == ["accelerance", "mechanical impedance", "receptance",
                                                    "dynamic stiffness"]
    for freq, h, props in lines:
        assert freq[0] == 0.5 and len(freq) == 80  # 0 Hz dropped
        np.testing.assert_allclose(h, stiffness(freq), rtol=1e-6)
    assert lines[0][2]["inverted"] and not lines[1][2]["inverted"]
    assert lines[0][2]["id1"] == "frf 0" and lines[0][2]["rsp_dir"] == 3 and lines[0][2]["dataset"] == 1


def test_uff_units_dataset_and_refusals(tmp_path, monkeypatch):
    from sbcal.data.acquisition.uff import read_uff_lines

    # mm and N (dataset 164: a value in the file's units / factor = SI): receptance in mm/N
    write_uff(tmp_path / "mm.uff", [(8, 13, lambda f: 1e3 / stiffness(f), {})], units=(1000.0, 1.0))
    (freq, h, props), = read_uff_lines(tmp_path / "mm.uff")
    np.testing.assert_allclose(h, stiffness(freq), rtol=1e-6)
    assert props["units"] == "dataset 164 (units code 9)" and props["dataset"] == 2
    write_uff(tmp_path / "tr.uff", [(12, 12, lambda f: np.ones(len(f)), {})])
    with pytest.raises(InputError, match=r"tr.uff, dataset 1: an FRF of acceleration over acceleration, not force "
                                         r"against base motion"):
        read_uff_lines(tmp_path / "tr.uff")
    write_uff(tmp_path / "gen.uff", [(1, 13, lambda f: -(2 * np.pi * f) ** 2 / stiffness(f),
                                      {"ordinate_axis_units_lab": "m/s^2"})])  # general: the label says
    (freq, h, props), = read_uff_lines(tmp_path / "gen.uff")
    np.testing.assert_allclose(h, stiffness(freq), rtol=1e-6)
    assert props["function"] == "accelerance"
    write_uff(tmp_path / "st.uff", [(2, 13, lambda f: np.ones(len(f)), {})])
    with pytest.raises(InputError, match=r"st.uff, dataset 1: ordinate numerator: neither force nor base motion "
                                         r"\(specific data type 2, units label 'NONE'\)"):
        read_uff_lines(tmp_path / "st.uff")
    write_uff(tmp_path / "lab.uff", [(12, 13, lambda f: np.ones(len(f)), {"ordinate_axis_units_lab": "N"})])
    with pytest.raises(InputError, match=r"ordinate numerator: units label 'N' is not a unit of acceleration"):
        read_uff_lines(tmp_path / "lab.uff")
    (tmp_path / "none.uff").write_text("not a universal file\n")
    with pytest.raises(InputError, match=r"none.uff: no frequency response function \(dataset 58, function type 4\)"):
        read_uff_lines(tmp_path / "none.uff")
    monkeypatch.setitem(sys.modules, "pyuff", None)
    with pytest.raises(InputError, match=r'needs pyuff: pip install "sbcal\[uff\]"'):
        read_uff_lines(tmp_path / "mm.uff")


def test_a_file_that_is_not_a_recording(tmp_path):
    """Text in a .tdms file (npTDMS finds no segment): one line saying so, not an empty group list."""
    pytest.importorskip("nptdms")
    (tmp_path / "x.tdms").write_text("garbage\n")
    with pytest.raises(InputError, match=r"x.tdms: no group with numeric channels: an empty recording, or not a "
                                         r"\.tdms file"):
        with open_blocks(tmp_path / "x.tdms"):
            pass
