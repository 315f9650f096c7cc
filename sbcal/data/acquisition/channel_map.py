"""The channel map of ``sbcal import`` (TOML, ``docs/import.md``): which channels are force and base
motion, their sensitivities and units, where each dwell's frequency and requested amplitude come
from, and the damper/test/run labels, read into frozen dataclasses.

Every bad key or value raises :class:`InputError` with one line ``FILE: [section] key: problem``;
a step table in its own CSV file is reported by its line.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

from ...core._io import read_toml
from ...core.errors import InputError
from .units import BASE_QUANTITIES, known_units, parse_unit, same_unit


__all__ = ["Label", "Sensor", "Step", "FrequencySource", "Analysis", "ChannelMap", "load_channel_map",
           "check_units"]

FREQUENCY_SOURCES = ("property", "table", "channel", "signal")
_HZ = ("hz", "1/s", "s-1", "s^-1")  # spellings of the frequency channel's unit


@dataclass(frozen=True)
class Label:
    """A label given literally or read from a block's (file's or group's) property.

    Attributes
    ----------
    value : str, int, float or None
        The literal value.
    property : str or None
        The name of the property holding it (when ``value`` is None).
    """

    value: str | int | float | None = None
    property: str | None = None

    def resolve(self, properties: dict, default=None, what: str = ""):
        """The label's value for a block.

        Parameters
        ----------
        properties : dict
            The block's properties (file properties overlaid by the group's).
        default
            Returned when the label is neither literal nor a property (an empty ``Label()``).
        what : str
            The start of the error message, e.g. ``"run1.tdms, group 'Dwell': label 'test'"``.

        Raises
        ------
        InputError
            The property is absent from ``properties``.
        """
        if self.value is not None:
            return self.value
        if self.property is None:
            return default
        if self.property not in properties:
            have = ", ".join(f"'{k}'" for k in properties) or "none"
            raise InputError(f"{what}: no property '{self.property}' (properties: {have})")
        return properties[self.property]


@dataclass(frozen=True)
class Sensor:
    """Force or base-motion channels and how to turn their stored values into SI.

    Attributes
    ----------
    channels : tuple of str
        Channel names; several force channels are summed (base motion has one).
    unit : str
        The unit of ``sensitivity * stored value``.
    sensitivity : tuple of float
        Multiplies each channel's stored value, one per channel (1 when the file holds physical values; negative
        flips the sign): two load cells may have their own calibrations.
    file_unit : str or None
        The unit the file's own unit property must name; None: not checked.
    range : float or None
        The ADC full scale in stored units (clipping check); None: detected from flat tops.
    quantity : str
        ``"force"``, or the base motion: ``"acceleration"``, ``"velocity"``, ``"displacement"``.
    si_factor : tuple of float
        Per channel, ``sensitivity`` times the unit's SI factor: stored value * si_factor is in N, m/s^2, m/s or m.
    """

    channels: tuple[str, ...]
    unit: str
    sensitivity: tuple[float, ...]
    file_unit: str | None
    range: float | None
    quantity: str
    si_factor: tuple[float, ...]


@dataclass(frozen=True)
class Step:
    """One row of a step table: a dwell from ``start_s`` [s, from the block's first sample] to the
    next step's start, at ``frequency_hz`` [Hz], with an optional requested amplitude [mm p-p]."""

    start_s: float
    frequency_hz: float
    amplitude_mm_pp: float | None = None


@dataclass(frozen=True)
class FrequencySource:
    """Where each dwell's frequency comes from.

    Attributes
    ----------
    source : str
        ``"property"`` (each block is one dwell at the frequency in ``property`` [Hz]), ``"table"``
        (``steps``), ``"channel"`` (the commanded frequency [Hz] in ``channel``; a dwell is a run of one
        value) or ``"signal"`` (estimated from the base signal).
    property, channel : str or None
    steps : tuple of Step
        Increasing ``start_s``.
    """

    source: str
    property: str | None = None
    channel: str | None = None
    steps: tuple[Step, ...] = ()


@dataclass(frozen=True)
class Analysis:
    """Settings of the dwell analysis (``[analysis]``; defaults shown)."""

    window_periods: int = 4
    min_windows: int = 10
    settle_tolerance: float = 2e-3
    harmonics: int = 9
    groups: str = "*"
    time_channel: str = "time"


@dataclass(frozen=True)
class ChannelMap:
    """A parsed channel map.

    Attributes
    ----------
    path : str
        The map file, for messages.
    damper, test : Label
    run : Label or None
        None: the importer numbers the files 1, 2, ... in the order given.
    force, base : Sensor
    frequency : FrequencySource
    amplitude : Label
        The requested amplitude [mm p-p], literal or a property; empty (``Label()``) when it comes from
        ``amplitude_channel`` or from the step table's ``amplitude_mm_pp``.
    amplitude_channel : str or None
        A channel holding the requested amplitude [mm p-p] (its median over a dwell).
    analysis : Analysis
    """

    path: str
    damper: Label
    test: Label
    run: Label | None
    force: Sensor
    base: Sensor
    frequency: FrequencySource
    amplitude: Label
    amplitude_channel: str | None = None
    analysis: Analysis = field(default_factory=Analysis)

    def channels(self) -> tuple[str, ...]:
        """Every channel the map reads: force, base, frequency and amplitude channels, in that order."""
        names = [*self.force.channels, *self.base.channels, self.frequency.channel, self.amplitude_channel]
        return tuple(dict.fromkeys(n for n in names if n is not None))


# --- reading -----------------------------------------------------------------------------------------

class _Section:
    """One table of the map: typed access to its keys, errors as ``FILE: [section] key: problem``."""

    def __init__(self, path: str, name: str, doc, known: tuple[str, ...]):
        self.path, self.name = path, name
        if not isinstance(doc, dict):
            raise InputError(f"{path}: [{name}]: expected a table, got {_kind(doc)}")
        for key in doc:
            if key not in known:
                raise InputError(f"{path}: [{name}] {key}: unknown key (known: {', '.join(known)})")
        self.doc = doc

    def error(self, key: str, problem: str) -> InputError:
        return InputError(f"{self.path}: [{self.name}] {key}: {problem}")

    def has(self, key: str) -> bool:
        return key in self.doc

    def text(self, key: str, default=None, *, required: bool = False) -> str | None:
        if key not in self.doc:
            if required:
                raise self.error(key, "missing")
            return default
        v = self.doc[key]
        if not isinstance(v, str) or not v.strip():
            raise self.error(key, f"expected a non-empty string, got {_kind(v)}")
        return v

    def number(self, key: str, default=None, *, check=None, need: str = "") -> float | None:
        """A finite number; ``check(x)`` False raises ``need`` (e.g. "must be > 0")."""
        if key not in self.doc:
            return default
        return _number(self.doc[key], check, need, lambda p: self.error(key, p))

    def integer(self, key: str, default: int, minimum: int) -> int:
        if key not in self.doc:
            return default
        v = self.doc[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"expected an integer, got {_kind(v)}")
        if v < minimum:
            raise self.error(key, f"must be >= {minimum}, got {v}")
        return v


def _kind(v) -> str:
    """How a TOML value is described in a message."""
    if isinstance(v, str):
        return repr(v)
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, (int, float)):
        return f"the number {v}"
    return {dict: "a table", list: "an array"}.get(type(v), f"a {type(v).__name__}")


def _number(v, check, need: str, error) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise error(f"expected a number, got {_kind(v)}")
    if not math.isfinite(v):
        raise error("must be finite")
    if check is not None and not check(v):
        raise error(f"{need}, got {v}")
    return float(v)


def _positive(x) -> bool:
    return x > 0


def _label(path: str, doc: dict, key: str, *, required: bool) -> Label | None:
    if key not in doc:
        if required:
            raise InputError(f"{path}: [labels] {key}: missing")
        return None
    v = doc[key]
    if isinstance(v, str) and v.strip():
        return Label(value=v)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return Label(value=v)
    if isinstance(v, dict) and list(v) == ["property"]:
        prop = v["property"]
        if not isinstance(prop, str) or not prop.strip():
            raise InputError(f"{path}: [labels] {key}: property: expected a non-empty string, got {_kind(prop)}")
        return Label(property=prop)
    raise InputError(f'{path}: [labels] {key}: expected a string, a number or {{property = "name"}}, got {_kind(v)}')


def _sensor(path: str, doc, name: str) -> Sensor:
    if name == "force":
        s = _Section(path, name, doc, ("channels", "channel", "unit", "sensitivity", "file_unit", "range"))
        if s.has("channels") == s.has("channel"):
            raise s.error("channels", "give either channels (a list, summed) or channel (one name)")
        if s.has("channel"):
            channels = (s.text("channel"),)
        else:
            v = s.doc["channels"]
            if not isinstance(v, list) or not v or not all(isinstance(c, str) and c.strip() for c in v):
                raise s.error("channels", f"expected a non-empty list of channel names, got {_kind(v)}")
            if len(set(v)) < len(v):
                raise s.error("channels", "a channel is named twice")
            channels = tuple(v)
    else:
        s = _Section(path, name, doc, ("channel", "quantity", "unit", "sensitivity", "file_unit", "range"))
        channels = (s.text("channel", required=True),)
    unit = s.text("unit", required=True)
    try:
        quantity, factor = parse_unit(unit)
    except InputError as e:
        raise s.error("unit", str(e)) from None
    if name == "force":
        if quantity != "force":
            raise s.error("unit", f"'{unit}' is not a force unit (known: {known_units('force')})")
    else:
        if quantity not in BASE_QUANTITIES and not s.has("quantity"):
            raise s.error("unit", f"'{unit}' is a unit of {quantity}, not of base motion "
                                  f"(known: {', '.join(known_units(q) for q in BASE_QUANTITIES)})")
        given = s.text("quantity", default=quantity)
        if given not in BASE_QUANTITIES:
            raise s.error("quantity", f"'{given}' is not one of {', '.join(BASE_QUANTITIES)}")
        if quantity != given:
            raise s.error("unit", f"'{unit}' is not a unit of {given} (known: {known_units(given)})")
    sensitivity = _sensitivities(s, len(channels))
    file_unit = s.text("file_unit", default=unit if all(v == 1.0 for v in sensitivity) else None)
    full_scale = s.number("range", check=_positive, need="must be > 0")
    return Sensor(channels=channels, unit=unit, sensitivity=sensitivity, file_unit=file_unit, range=full_scale,
                  quantity=quantity, si_factor=tuple(v * factor for v in sensitivity))


def _sensitivities(s: "_Section", n: int) -> tuple[float, ...]:
    """``sensitivity``: one number for every channel, or a list of one per channel; never 0."""
    v = s.doc.get("sensitivity", 1.0)
    values = v if isinstance(v, list) else [v] * n
    if isinstance(v, list) and len(v) != n:
        raise s.error("sensitivity", f"a list of {len(v)} for {n} channel(s): give one per channel, or one number")
    return tuple(_number(x, lambda x: x != 0, "must not be 0", lambda p: s.error("sensitivity", p)) for x in values)


def _steps_from_rows(rows, error) -> tuple[Step, ...]:
    """Steps from ``(where, row dict)``; ``error(where, key, problem)`` makes the InputError."""
    steps = []
    for where, row in rows:
        for key in ("start_s", "frequency_hz"):
            if key not in row:
                raise error(where, key, "missing")
        start = _number(row["start_s"], lambda x: x >= 0, "must be >= 0", lambda p: error(where, "start_s", p))
        freq = _number(row["frequency_hz"], _positive, "must be > 0", lambda p: error(where, "frequency_hz", p))
        amp = None
        if "amplitude_mm_pp" in row:
            amp = _number(row["amplitude_mm_pp"], _positive, "must be > 0",
                          lambda p: error(where, "amplitude_mm_pp", p))
        if steps and start <= steps[-1].start_s:
            raise error(where, "start_s", f"{start:g} is not after the previous step's {steps[-1].start_s:g}")
        if steps and (amp is None) != (steps[-1].amplitude_mm_pp is None):
            raise error(where, "amplitude_mm_pp", "give it on every step or on none")
        steps.append(Step(start_s=start, frequency_hz=freq, amplitude_mm_pp=amp))
    if not steps:
        raise error(None, "table", "no steps")
    return tuple(steps)


def _steps_inline(s: _Section) -> tuple[Step, ...]:
    rows = s.doc["table"]
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise s.error("table", f"expected an array of {{start_s = ..., frequency_hz = ...}} or a CSV file name, "
                               f"got {_kind(rows)}")
    known = ("start_s", "frequency_hz", "amplitude_mm_pp")
    for i, row in enumerate(rows, 1):
        for key in row:
            if key not in known:
                raise s.error(f"table[{i}].{key}", f"unknown key (known: {', '.join(known)})")

    def error(where, key, problem):
        return s.error(key if where is None else f"table[{where}].{key}", problem)

    return _steps_from_rows(enumerate(rows, 1), error)


def _steps_csv(s: _Section) -> tuple[Step, ...]:
    """The step table in a CSV file named relative to the map: columns ``start_s``, ``frequency_hz`` and
    optionally ``amplitude_mm_pp``; errors name the file and line."""
    table = Path(s.path).parent / s.doc["table"]
    try:
        text = table.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise s.error("table", f"no such file: {table}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise s.error("table", f"cannot read {table}: {e}") from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), 1) if line.strip() and not line.startswith("#")]
    if not lines:
        raise InputError(f"{table}: empty (expected a header start_s,frequency_hz[,amplitude_mm_pp])")
    reader = csv.reader(line for _, line in lines)
    header = [h.strip() for h in next(reader)]
    known = ("start_s", "frequency_hz", "amplitude_mm_pp")
    for h in header:
        if h not in known:
            raise InputError(f"{table}, line {lines[0][0]}: unknown column '{h}' (known: {', '.join(known)})")
    for h in known[:2]:
        if h not in header:
            raise InputError(f"{table}, line {lines[0][0]}: column '{h}' missing")

    def error(where, key, problem):
        return InputError(f"{table}: {problem}" if where is None else f"{table}, line {where}: {key}: {problem}")

    rows = []
    for (n, _), cells in zip(lines[1:], reader):
        if len(cells) != len(header):
            raise InputError(f"{table}, line {n}: {len(cells)} cells, the header has {len(header)}")
        row = {}
        for h, c in zip(header, cells):
            try:
                row[h] = float(c)
            except ValueError:
                raise InputError(f"{table}, line {n}: {h}: not a number: '{c.strip()}'") from None
        rows.append((n, row))
    return _steps_from_rows(rows, error)


def _frequency(path: str, doc) -> FrequencySource:
    s = _Section(path, "frequency", doc, ("source", "property", "channel", "table"))
    source = s.text("source", required=True)
    if source not in FREQUENCY_SOURCES:
        raise s.error("source", f"'{source}' is not one of {', '.join(FREQUENCY_SOURCES)}")
    for key in ("property", "channel", "table"):
        if s.has(key) and key != source:
            raise s.error(key, f"only with source = '{key}' (source is '{source}')")
        if key == source and not s.has(key):
            raise s.error(key, f"missing (source = '{source}' needs it)")
    if source == "table":
        steps = _steps_csv(s) if isinstance(s.doc["table"], str) else _steps_inline(s)
        return FrequencySource(source=source, steps=steps)
    return FrequencySource(source=source, property=s.text("property"), channel=s.text("channel"))


def _amplitude(path: str, doc: dict, frequency: FrequencySource) -> tuple[Label, str | None]:
    in_table = bool(frequency.steps) and frequency.steps[0].amplitude_mm_pp is not None
    if "amplitude" not in doc:
        if in_table:
            return Label(), None
        raise InputError(f"{path}: [amplitude]: missing (mm_pp, property or channel: the requested amplitude)")
    s = _Section(path, "amplitude", doc["amplitude"], ("mm_pp", "property", "channel"))
    given = [k for k in ("mm_pp", "property", "channel") if s.has(k)]
    if not given:
        raise InputError(f"{path}: [amplitude]: empty (give one of mm_pp, property, channel)")
    if len(given) > 1:
        raise s.error(given[1], f"give only one of mm_pp, property, channel ({given[0]} is given too)")
    if in_table:
        raise s.error(given[0], "the step table already gives amplitude_mm_pp")
    if s.has("mm_pp"):
        return Label(value=s.number("mm_pp", check=_positive, need="must be > 0")), None
    if s.has("property"):
        return Label(property=s.text("property")), None
    return Label(), s.text("channel")


def _analysis(path: str, doc) -> Analysis:
    s = _Section(path, "analysis", doc, ("window_periods", "min_windows", "settle_tolerance", "harmonics",
                                         "groups", "time_channel"))
    d = Analysis()
    return Analysis(
        window_periods=s.integer("window_periods", d.window_periods, 1),
        min_windows=s.integer("min_windows", d.min_windows, 2),  # a standard error needs two windows
        settle_tolerance=s.number("settle_tolerance", d.settle_tolerance, check=lambda x: 0 < x < 1,
                                  need="must be between 0 and 1 (relative)"),
        harmonics=s.integer("harmonics", d.harmonics, 1),
        groups=s.text("groups", d.groups),
        time_channel=s.text("time_channel", d.time_channel),
    )


def load_channel_map(path) -> ChannelMap:
    """Read a channel map (``docs/import.md``, "The channel map").

    Parameters
    ----------
    path : str or path-like
        The TOML file; a step table given as a file name is read relative to it.

    Returns
    -------
    ChannelMap

    Raises
    ------
    InputError
        One line ``FILE: [section] key: problem`` for a missing, unknown or bad key or value.
    """
    path = str(path)
    doc = read_toml(path)
    sections = ("labels", "force", "base", "frequency", "amplitude", "analysis")
    for key in doc:
        if key not in sections:
            raise InputError(f"{path}: [{key}]: unknown section (known: {', '.join(sections)})")
    for key in sections[:4]:
        if key not in doc:
            raise InputError(f"{path}: [{key}]: missing")
    labels = _Section(path, "labels", doc["labels"], ("damper", "test", "run")).doc
    frequency = _frequency(path, doc["frequency"])
    amplitude, amplitude_channel = _amplitude(path, doc, frequency)
    return ChannelMap(
        path=path,
        damper=_label(path, labels, "damper", required=True),
        test=_label(path, labels, "test", required=True),
        run=_label(path, labels, "run", required=False),
        force=_sensor(path, doc["force"], "force"),
        base=_sensor(path, doc["base"], "base"),
        frequency=frequency,
        amplitude=amplitude,
        amplitude_channel=amplitude_channel,
        analysis=_analysis(path, doc.get("analysis", {})),
    )


def check_units(block, cmap: ChannelMap) -> None:
    """Check the file's own unit properties against the map.

    A force or base channel whose unit property is set must name the sensor's ``file_unit`` (the same
    unit in any spelling); a frequency channel's must be Hz. Channels without a unit property, and
    sensors without ``file_unit`` (a sensitivity other than 1 and no ``file_unit`` given), are not checked.

    Parameters
    ----------
    block : Block
        From :func:`sbcal.data.acquisition.sources.open_blocks`.
    cmap : ChannelMap

    Raises
    ------
    InputError
        One line naming the file, group, channel, both units and the map key.
    """
    for section, sensor in (("force", cmap.force), ("base", cmap.base)):
        if sensor.file_unit is None:
            continue
        key = ("file_unit" if any(v != 1.0 for v in sensor.sensitivity) or sensor.file_unit != sensor.unit
               else "unit")
        for channel in sensor.channels:
            unit = block.unit(channel)
            if unit and unit.strip() and not same_unit(unit, sensor.file_unit):
                raise InputError(f"{block.where(channel)}: unit '{unit}' in the file, but {cmap.path} "
                                 f"[{section}] {key} is '{sensor.file_unit}'")
    channel = cmap.frequency.channel
    if channel is not None:
        unit = block.unit(channel)
        if unit and unit.strip() and "".join(unit.split()).lower() not in _HZ:
            raise InputError(f"{block.where(channel)}: unit '{unit}' in the file, but {cmap.path} "
                             f"[frequency] channel must hold Hz")
