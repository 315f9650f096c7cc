"""Readers of raw recordings: NI TDMS, HDF5, ASAM MDF4 and CSV time series as :class:`Block` s.

A block is one equally sampled record (a TDMS group, an HDF5 group, an MDF4 channel group, a CSV
file) read in slices, so a file larger than memory is streamed: TDMS through npTDMS's index
(``TdmsFile.open``), HDF5 through h5py datasets; MDF4 channels are read whole (asammdf). The file
layouts are in ``docs/import.md``, "File layouts". npTDMS and asammdf are optional extras; a missing
one is a one-line :class:`InputError` naming the extra.
"""

from __future__ import annotations

import csv
import datetime as _dt
import difflib
import fnmatch
import importlib
import re
import xml.etree.ElementTree as ET
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Callable

import numpy as np

from ...core.errors import InputError


__all__ = ["Block", "open_blocks", "EXTENSIONS"]

EXTENSIONS = (".tdms", ".h5", ".hdf5", ".mf4", ".mdf", ".csv")
"""The file types :func:`open_blocks` reads."""

_CHUNK = 2 ** 20  # samples per read when a time channel is checked in slices
_UNIFORM = 0.01  # explicit time: each interval within 1 % of the typical one
_TIME_UNITS = {"": 1.0, "s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
_RATE_ATTRS = ("sample_rate_hz", "wf_increment")  # HDF5: a rate [Hz] or an interval [s]


class Block:
    """One equally sampled record, read channel by channel in slices.

    Attributes
    ----------
    source : str
        The file, for messages.
    name : str
        The group's name ("" for a CSV file).
    properties : dict
        The file's properties overlaid by the group's (str -> str, int, float or a tuple of them).
    rate_hz : float
        Sampling rate [Hz].
    n_samples : int
        Samples per channel.
    """

    def __init__(self, *, source: str, name: str, properties: dict, rate_hz: float, n_samples: int,
                 units: dict, read: Callable[[str, int, int], np.ndarray]):
        """``units``: channel name -> the file's unit property (None when absent), in file order;
        ``read(channel, start, stop)``: the stored values of samples [start, stop)."""
        self.source, self.name, self.properties = source, name, properties
        self.rate_hz, self.n_samples = float(rate_hz), int(n_samples)
        self._units, self._read = units, read

    def __repr__(self) -> str:
        return (f"Block({self.where()}, {len(self._units)} channels, {self.n_samples} samples at "
                f"{self.rate_hz:g} Hz)")

    def where(self, channel: str | None = None) -> str:
        """The block (and channel) for a message: ``"run1.tdms, group 'Dwell', channel 'Force A'"``."""
        s = self.source if not self.name else f"{self.source}, group '{self.name}'"
        return s if channel is None else f"{s}, channel '{channel}'"

    def channels(self) -> tuple[str, ...]:
        """The names of the numeric channels, in file order (without a time channel)."""
        return tuple(self._units)

    def require(self, channel: str) -> None:
        """Raise :class:`InputError` when ``channel`` is not in the block: the message names the file,
        the group, the channel and the channels it has, the closest names first."""
        if channel in self._units:
            return
        names = sorted(self._units, key=lambda n: -difflib.SequenceMatcher(None, channel.lower(), n.lower()).ratio())
        shown = ", ".join(f"'{n}'" for n in names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        raise InputError(f"{self.where()}: no channel '{channel}' (channels, closest first: {shown or 'none'})")

    def unit(self, channel: str) -> str | None:
        """The file's own unit property of ``channel``; None when absent or empty."""
        self.require(channel)
        return self._units[channel]

    def read(self, channel: str, start: int, stop: int) -> np.ndarray:
        """Samples [start, stop) of ``channel`` as stored (the file's own scaling applied).

        Returns
        -------
        ndarray of float64, shape (stop - start,)
        """
        self.require(channel)
        if not 0 <= start <= stop <= self.n_samples:
            raise ValueError(f"{self.where(channel)}: samples [{start}, {stop}) outside [0, {self.n_samples})")
        return np.asarray(self._read(channel, start, stop), dtype=np.float64)


@contextmanager
def open_blocks(path, cmap=None):
    """Open a raw recording and yield its blocks; the file is closed on leaving the ``with``.

    Parameters
    ----------
    path : str or path-like
        ``.tdms``, ``.h5``/``.hdf5``, ``.mf4``/``.mdf`` or ``.csv``.
    cmap : ChannelMap, optional
        Selects the groups (``analysis.groups``), names the time channel (``analysis.time_channel``) and
        lists the channels every block must have; None: every group, time channel ``"time"``.

    Yields
    ------
    list of Block

    Raises
    ------
    InputError
        One line: unknown file type, missing file or reader package, unreadable file, no matching group,
        a missing channel, channels of one group sampled differently, a time channel that is not strictly
        increasing or not uniform to 1 %.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in EXTENSIONS:
        raise InputError(f"{p}: unknown file type '{p.suffix}' (accepted: {', '.join(EXTENSIONS)})")
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    groups = "*" if cmap is None else cmap.analysis.groups
    time_channel = "time" if cmap is None else cmap.analysis.time_channel
    reader = {".tdms": _tdms, ".h5": _hdf5, ".hdf5": _hdf5, ".mf4": _mdf, ".mdf": _mdf, ".csv": _csv}[ext]
    with ExitStack() as stack:
        # groups left out are not checked: a settings group need not be a valid record
        seen = []

        def wanted(name: str) -> bool:
            seen.append(name)
            return not name or fnmatch.fnmatchcase(name, groups)

        blocks = reader(p, stack, time_channel, wanted)
        if not blocks:
            if not seen:
                raise InputError(f"{p}: no group with numeric channels: an empty recording, or not a {ext} file")
            have = ", ".join(f"'{name}'" for name in seen)
            raise InputError(f"{p}: no group matches '{groups}' (groups: {have})")
        for b in blocks:
            for channel in ([] if cmap is None else cmap.channels()):
                b.require(channel)
        yield blocks


# --- shared ------------------------------------------------------------------------------------------

def _need(module: str, package: str, extra: str, path):
    """Import an optional reader package; missing: the one-line install hint."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(f'reading {path} needs {package}: pip install "sbcal[{extra}]"') from None


def _plain(v):
    """A property value as str, int, float or a tuple of them (from numpy, bytes, timestamps)."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray):
        return _plain(v.reshape(-1)[0]) if v.size == 1 else tuple(_plain(x) for x in v.reshape(-1))
    if isinstance(v, np.datetime64):
        return str(v)
    if isinstance(v, np.generic):
        return _plain(v.item())
    if isinstance(v, (_dt.datetime, _dt.date)):
        return v.isoformat()
    if isinstance(v, (str, int, float)):
        return v
    return str(v)


def _props(*layers) -> dict:
    """Property dicts overlaid in order (later ones win), values made plain."""
    out = {}
    for layer in layers:
        out.update({str(k): _plain(v) for k, v in layer.items()})
    return out


_CHANNEL_OWN = ("wf_", "unit", "units", "nI_", "NI_", "sample_rate_hz")  # what describes a channel, not the record


def _shared(channel_props) -> dict:
    """The channel properties every channel of a block holds with one value (a stepped-sine logger that writes the
    dwell's frequency on each channel): the block's properties at the lowest priority. Sampling, unit and NI
    bookkeeping properties are the channels' own and are left out."""
    layers = [{str(k): _plain(v) for k, v in props.items() if not str(k).startswith(_CHANNEL_OWN)}
              for props in channel_props]
    if not layers:
        return {}
    first, rest = layers[0], layers[1:]
    return {k: v for k, v in first.items() if all(k in other and other[k] == v for other in rest)}


def _time_scale(unit, where: str) -> float:
    """Seconds per unit of a time channel (no unit: seconds)."""
    u = "" if unit is None else str(unit).strip().lower()
    if u not in _TIME_UNITS:
        raise InputError(f"{where}: unknown time unit '{unit}' (known: s, ms, us, ns)")
    return _TIME_UNITS[u]


def _rate_from_time(read: Callable[[int, int], np.ndarray], n: int, where: str, line=None) -> float:
    """The sampling rate [Hz] of an explicit time channel, checked in slices of :data:`_CHUNK`.

    ``read(start, stop)`` gives the times [s]; ``line(i)``, when given, names the file line of sample i.
    Not strictly increasing (or not finite), or an interval off the typical one (the median of the first
    slice's) by more than 1 %: InputError naming the sample and its time.
    """
    if n < 2:
        raise InputError(f"{where}: {n} sample(s), need at least 2 to know the sampling rate")

    def at(i):
        return f"sample {i}" + (f" (line {line(i)})" if line else "")

    typical = None
    for a in range(0, n - 1, _CHUNK):
        t = np.asarray(read(a, min(a + _CHUNK + 1, n)), dtype=np.float64)  # one sample of overlap
        d = np.diff(t)
        bad = np.flatnonzero(~(d > 0))
        if bad.size:
            i = bad[0]
            for j in (i, i + 1):
                if not np.isfinite(t[j]):
                    raise InputError(f"{where}: time is not a finite number at {at(a + j)}")
            raise InputError(f"{where}: time not strictly increasing at {at(a + i + 1)}: "
                             f"{t[i + 1]:.9g} s after {t[i]:.9g} s")
        if typical is None:
            typical = float(np.median(d))
        off = np.flatnonzero(np.abs(d - typical) > _UNIFORM * typical)
        if off.size:
            i = off[0]
            raise InputError(f"{where}: sampling not uniform at {at(a + i + 1)} (t = {t[i + 1]:.9g} s): interval "
                             f"{d[i]:.6g} s, typically {typical:.6g} s (more than 1 % apart)")
    t0, t1 = (float(read(i, i + 1)[0]) for i in (0, n - 1))
    return (n - 1) / (t1 - t0)


def _same_rate(rates: dict, where: str) -> float:
    """The one sampling rate of a group's channels (channel -> rate [Hz]); differing: InputError."""
    first = next(iter(rates))
    for name, rate in rates.items():
        if not abs(rate - rates[first]) <= 1e-9 * rates[first]:
            raise InputError(f"{where}: channels sampled differently: '{first}' at {rates[first]:.9g} Hz, "
                             f"'{name}' at {rate:.9g} Hz")
    return rates[first]


def _same_length(lengths: dict, where: str) -> int:
    first = next(iter(lengths))
    for name, n in lengths.items():
        if n != lengths[first]:
            raise InputError(f"{where}: channels of different length: '{first}' has {lengths[first]} samples, "
                             f"'{name}' {n}")
    return lengths[first]


def _interval_rate(value, where: str) -> float:
    """A rate [Hz] from an interval [s] property (``wf_increment``)."""
    try:
        dt = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: wf_increment {value!r} is not a number") from None
    if not dt > 0 or not np.isfinite(dt):
        raise InputError(f"{where}: wf_increment {dt!r} s must be > 0")
    return 1.0 / dt


# --- TDMS --------------------------------------------------------------------------------------------

def _tdms(path: Path, stack: ExitStack, time_channel: str, wanted) -> list[Block]:
    """One block per TDMS group, streamed (``TdmsFile.open`` reads the index, not the data)."""
    nptdms = _need("nptdms", "npTDMS", "tdms", path)
    try:
        f = stack.enter_context(nptdms.TdmsFile.open(str(path)))
    except Exception as e:  # a damaged file raises what the parser meets (ValueError, struct.error, ...)
        raise InputError(f"{path}: not a readable TDMS file ({e})") from None
    blocks = []
    for g in f.groups():
        where = f"{path}, group '{g.name}'"
        numeric = {c.name: c for c in g.channels() if c.dtype.kind in "iuf" and c.name != time_channel}
        time = next((c for c in g.channels() if c.name == time_channel and c.dtype.kind in "iufM"), None)
        if not numeric or not wanted(g.name):
            continue
        n = _same_length({name: len(c) for name, c in numeric.items()}, where)
        if all("wf_increment" in c.properties for c in numeric.values()):
            rate = _same_rate({name: _interval_rate(c.properties["wf_increment"], f"{where}, channel '{name}'")
                               for name, c in numeric.items()}, where)
        elif time is not None:
            rate = _tdms_time_rate(time, n, f"{where}, channel '{time_channel}'")
        else:
            name = next(name for name, c in numeric.items() if "wf_increment" not in c.properties)
            raise InputError(f"{where}, channel '{name}': no sampling rate (no wf_increment property and no "
                             f"'{time_channel}' channel)")
        units = {name: (c.properties.get("unit_string") or None) for name, c in numeric.items()}
        shared = _shared(c.properties for c in numeric.values())
        blocks.append(Block(source=str(path), name=g.name, properties=_props(shared, f.properties, g.properties),
                            rate_hz=rate, n_samples=n, units=units,
                            read=lambda name, a, b, chans=numeric: chans[name][a:b]))
    return blocks


def _tdms_time_rate(channel, n: int, where: str) -> float:
    """The rate of a TDMS time channel: seconds, or timestamps (as seconds since the first)."""
    if len(channel) != n:
        raise InputError(f"{where}: {len(channel)} samples, the channels have {n}")
    if channel.dtype.kind == "M":
        t0 = channel[0:1][0]
        return _rate_from_time(lambda a, b: (channel[a:b] - t0) / np.timedelta64(1, "s"), n, where)
    scale = _time_scale(channel.properties.get("unit_string"), where)
    return _rate_from_time(lambda a, b: channel[a:b] * scale, n, where)


# --- HDF5 --------------------------------------------------------------------------------------------

def _hdf5(path: Path, stack: ExitStack, time_channel: str, wanted) -> list[Block]:
    """One block per HDF5 group holding 1-D numeric datasets (the root only when no group does)."""
    import h5py

    try:
        f = stack.enter_context(h5py.File(path, "r"))
    except OSError as e:
        raise InputError(f"{path}: not a readable HDF5 file ({e})") from None
    found = []
    f.visititems(lambda name, obj: found.append(obj) if isinstance(obj, h5py.Group) else None)
    groups = [g for g in found if _h5_channels(g, h5py)]
    if not groups and _h5_channels(f, h5py):
        groups = [f]
    blocks = []
    for g in groups:
        name = g.name.lstrip("/")
        where = f"{path}, group '{name}'" if name else str(path)
        datasets = _h5_channels(g, h5py)
        time = datasets.pop(time_channel, None)
        if not datasets or not wanted(name):
            continue
        # the channels' shared attributes, then the file's, each parent's and the group's own
        chain = [_shared(d.attrs for d in datasets.values()), f.attrs] + [f[p].attrs for p in _ancestors(g.name)]
        props = _props(*chain)
        n = _same_length({k: d.shape[0] for k, d in datasets.items()}, where)
        rate = _h5_rate(datasets, props, time, n, where, time_channel)
        units = {k: _h5_unit(d) for k, d in datasets.items()}
        blocks.append(Block(source=str(path), name=name, properties=props, rate_hz=rate, n_samples=n,
                            units=units, read=lambda k, a, b, ds=datasets: ds[k][a:b]))
    return blocks


def _ancestors(name: str) -> list[str]:
    """``"/a/b"`` -> ``["/a", "/a/b"]``."""
    parts = [p for p in name.split("/") if p]
    return ["/" + "/".join(parts[:i]) for i in range(1, len(parts) + 1)]


def _h5_channels(group, h5py) -> dict:
    """The group's own 1-D numeric datasets, name -> dataset."""
    return {k: d for k, d in group.items()
            if isinstance(d, h5py.Dataset) and d.ndim == 1 and d.dtype.kind in "iuf"}


def _h5_unit(d) -> str | None:
    for key in ("unit", "units"):
        if key in d.attrs:
            return _plain(d.attrs[key]) or None
    return None


def _h5_rate_attr(attrs, where: str) -> float | None:
    """A rate [Hz] from ``sample_rate_hz`` or ``wf_increment`` [s] in ``attrs``; None when neither."""
    if "sample_rate_hz" in attrs:
        v = _plain(attrs["sample_rate_hz"])
        if isinstance(v, (int, float)) and v > 0 and np.isfinite(v):
            return float(v)
        raise InputError(f"{where}: sample_rate_hz {v!r} must be a number > 0")
    if "wf_increment" in attrs:
        return _interval_rate(_plain(attrs["wf_increment"]), where)
    return None


def _h5_rate(datasets: dict, props: dict, time, n: int, where: str, time_channel: str) -> float:
    """The rate from the datasets' own attributes, else the group's (or its parents'), else the time dataset."""
    own = {k: _h5_rate_attr(d.attrs, f"{where}, channel '{k}'") for k, d in datasets.items()}
    if all(r is not None for r in own.values()):
        return _same_rate(own, where)
    rate = _h5_rate_attr(props, where)
    if rate is not None:
        return rate
    if time is None:
        raise InputError(f"{where}: no sampling rate (attribute {' or '.join(_RATE_ATTRS)}, or a "
                         f"'{time_channel}' dataset)")
    twhere = f"{where}, channel '{time_channel}'"
    if time.shape[0] != n:
        raise InputError(f"{twhere}: {time.shape[0]} samples, the channels have {n}")
    scale = _time_scale(_h5_unit(time), twhere)
    return _rate_from_time(lambda a, b: time[a:b] * scale, n, twhere)


# --- MDF4 --------------------------------------------------------------------------------------------

def _mdf(path: Path, stack: ExitStack, time_channel: str, wanted) -> list[Block]:
    """One block per MDF4 channel group; the rate from its master (time) channel."""
    asammdf = _need("asammdf", "asammdf", "mdf", path)
    try:
        mdf = asammdf.MDF(str(path))
    except Exception as e:  # a damaged file raises what the parser meets (MdfException, ValueError, ...)
        raise InputError(f"{path}: not a readable MDF file ({e})") from None
    stack.callback(mdf.close)
    header = mdf.header
    file_props = {k: getattr(header, k) for k in ("author", "department", "project", "subject")
                  if getattr(header, k, "")}
    file_props.update(_mdf_common_properties(header.comment))
    blocks = []
    for i, group in enumerate(mdf.groups):
        cg = group.channel_group
        name = cg.acq_name or str(i)
        where = f"{path}, group '{name}'"
        index = {}
        for j, c in enumerate(group.channels):
            # masters (types 2, 3) are the time; integers and reals (data types 0-5) are signals
            if c.channel_type not in (2, 3) and c.data_type <= 5 and c.name != time_channel:
                index.setdefault(c.name, j)
        n = int(cg.cycles_nr)
        if not index or n == 0 or not wanted(name):
            continue
        master = mdf.get_master(i)
        if len(master) != n:
            raise InputError(f"{where}: no time channel")
        rate = _rate_from_time(lambda a, b, t=master: t[a:b], n, f"{where}, channel 'time'")
        del master  # only the rate is kept, not the group's whole time channel

        cache = {}

        def read(k, a, b, i=i, index=index, cache=cache):
            # asammdf reads a whole channel even for a record range (and its ranged read without timestamps
            # fails in 8.x): read each channel once and keep it while the file is open
            if k not in cache:
                cache[k] = np.asarray(mdf.get(k, group=i, index=index[k], samples_only=True)[0], dtype=np.float64)
            return cache[k][a:b]

        units = {k: (mdf.get_channel_unit(k, group=i, index=j) or None) for k, j in index.items()}
        blocks.append(Block(source=str(path), name=name,
                            properties=_props(file_props, _mdf_common_properties(cg.comment)),
                            rate_hz=rate, n_samples=n, units=units, read=read))
    return blocks


def _mdf_common_properties(comment) -> dict:
    """The ``<e name="...">value</e>`` entries of an MDF4 comment's ``common_properties`` (plain text: none)."""
    if not comment or not str(comment).lstrip().startswith("<"):
        return {}
    try:
        root = ET.fromstring(comment)
    except ET.ParseError:
        return {}
    return {e.get("name"): (e.text or "").strip() for props in root.iter("common_properties")
            for e in props.iter("e") if e.get("name")}


# --- CSV ---------------------------------------------------------------------------------------------

_HEADER_UNIT = re.compile(r"^(.*?)\s*\[(.*)\]$")


def _csv(path: Path, stack: ExitStack, time_channel: str, wanted) -> list[Block]:
    """A CSV file as one block (whatever ``wanted`` says: it has no groups): a header of channel names
    (``name [unit]``), a time column [s]."""
    import pandas as pd

    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:  # -sig: a spreadsheet's byte order mark
            first = fh.readline()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    sep = max((",", ";", "\t"), key=first.count)  # the delimiter the header uses most
    header = next(csv.reader([first], delimiter=sep), [])
    names, units = [], {}
    for col, cell in enumerate(header, 1):
        m = _HEADER_UNIT.match(cell.strip())
        name, unit = (m.group(1).strip(), m.group(2).strip()) if m else (cell.strip(), None)
        if not name:
            raise InputError(f"{path}, line 1, column {col}: no channel name")
        if name in units:
            raise InputError(f"{path}, line 1: channel '{name}' named twice")
        names.append(name)
        units[name] = unit or None
    if time_channel not in units:
        close = difflib.get_close_matches(time_channel, names, n=3, cutoff=0)
        raise InputError(f"{path}: no time column '{time_channel}' (columns, closest first: "
                         f"{', '.join(repr(c) for c in close)})")
    try:
        # blank lines kept as empty rows, so that row i is line i + 2 in messages
        df = pd.read_csv(path, sep=sep, header=0, names=names, skipinitialspace=True, skip_blank_lines=False,
                         encoding="utf-8-sig")
    except (ValueError, pd.errors.ParserError) as e:
        raise InputError(f"{path}: not a readable CSV file ({str(e).splitlines()[0]})") from None
    filled = np.flatnonzero(df.notna().any(axis=1).to_numpy())
    df = df.iloc[:filled[-1] + 1 if filled.size else 0]  # without trailing blank lines
    data = {}
    for name in names:
        col = df[name]
        values = pd.to_numeric(col, errors="coerce").to_numpy(dtype=np.float64)
        bad = np.flatnonzero(np.isnan(values) & col.notna().to_numpy())
        if bad.size:
            raise InputError(f"{path}, line {bad[0] + 2}, column '{name}': not a number: '{col.iloc[bad[0]]}'")
        data[name] = values
    time = data.pop(time_channel) * _time_scale(units.pop(time_channel), f"{path}, column '{time_channel}'")
    if not data:
        raise InputError(f"{path}: no channel besides the time column '{time_channel}'")
    rate = _rate_from_time(lambda a, b: time[a:b], len(time), str(path), line=lambda i: i + 2)
    return [Block(source=str(path), name="", properties={}, rate_hz=rate, n_samples=len(time), units=units,
                  read=lambda k, a, b: data[k][a:b])]
