"""Raw recordings to bench lines (``docs/import.md``): files -> blocks -> dwells -> first harmonics -> rows.

One pass per block: the dwells are found (:mod:`.dwells`, from the channel map's frequency source), each dwell's
samples are read, checked (finite, not clipped) and analysed on whole periods; a dwell that has not settled is
warned about and dropped. The rows carry the contract's columns and the measured ones
(:data:`sbcal.data.bench.MEASURED_COLUMNS`); nothing is written until every file has been read, and the file is
written atomically after it has been read back through :func:`sbcal.data.readers.load_bench`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ...core._io import atomic_path
from ...core.errors import InputError
from ...core.progress import progress_bar
from ..bench import BENCH_COLUMNS, FREQ_REL_TOL, MEASURED_COLUMNS
from .channel_map import ChannelMap, check_units
from .dwells import Dwell, dwells_from_channel, dwells_from_signal, dwells_from_steps
from .lines import DwellLine, analyse_dwell, clipped
from .sources import EXTENSIONS, open_blocks
from .uff import read_uff_lines


__all__ = ["AMPLITUDE_TOLERANCE", "UFF_EXTENSIONS", "ImportResult", "import_recordings", "write_import"]

AMPLITUDE_TOLERANCE = 0.05
"""An achieved base amplitude this far (relative) from the requested one is a warning (the line is kept: the
model takes the amplitude requested, the file keeps both)."""

UFF_EXTENSIONS = (".uff", ".unv")
"""Universal files: their FRFs (datasets 58) are lines already, taken as they are (no dwell to analyse)."""


@dataclass(frozen=True, eq=False)
class ImportResult:
    """The lines of the imported recordings.

    Attributes
    ----------
    frame : DataFrame
        Bench rows: :data:`BENCH_COLUMNS` then :data:`MEASURED_COLUMNS`, one per settled dwell, sorted by damper,
        test, run and frequency.
    warnings : tuple of str
        One line per dwell dropped (not settled), per duplicate, per line without a fixture match.
    """

    frame: pd.DataFrame
    warnings: tuple


def _read(block, channel: str, start: int, stop: int) -> np.ndarray:
    """Samples [start, stop) of a channel, refused in one line if any is NaN or infinite."""
    x = block.read(channel, start, stop)
    bad = ~np.isfinite(x)
    if bad.any():
        i = start + int(np.argmax(bad))
        raise InputError(f"{block.where(channel)}: {x[i - start]} at sample {i} "
                         f"(t = {i / block.rate_hz:.6g} s): the recording holds NaN or infinite values")
    return x


def _dwells(block, cmap: ChannelMap) -> list:
    """The block's dwells from the channel map's frequency source."""
    src, n, rate = cmap.frequency, block.n_samples, block.rate_hz
    if src.source == "property":
        value = block.properties.get(src.property)
        try:
            f = float(value)
        except (TypeError, ValueError):
            f = math.nan
        if not (math.isfinite(f) and f > 0):
            have = ", ".join(sorted(block.properties)) or "none"
            raise InputError(f"{block.where()}: property {src.property!r} (the dwell's frequency, [frequency] "
                             f"property): {'missing' if value is None else repr(value)}; properties: {have}")
        return [Dwell(0, n, f)]
    if src.source == "table":
        return dwells_from_steps([s.start_s for s in src.steps], [s.frequency_hz for s in src.steps], n, rate)
    if src.source == "channel":
        return dwells_from_channel(lambda a, b: _read(block, src.channel, a, b), n, rate)
    base = cmap.base.channels[0]
    return dwells_from_signal(lambda a, b: _read(block, base, a, b), n, rate)


def _sensor(block, sensor, dwell: Dwell, freq_hz: float) -> np.ndarray:
    """One sensor's signal over a dwell in SI units (its channels summed), each channel checked for clipping."""
    total = np.zeros(dwell.stop - dwell.start)
    for ch, factor in zip(sensor.channels, sensor.si_factor):
        x = _read(block, ch, dwell.start, dwell.stop)
        k = clipped(x, block.rate_hz, freq_hz, full_scale=sensor.range)
        if k is not None:
            i = dwell.start + k
            raise InputError(f"{block.where(ch)}: clipped at sample {i} (t = {i / block.rate_hz:.6g} s, the line at "
                             f"{freq_hz:g} Hz): the signal saturates the input range; record it with a larger range")
        total += x * factor
    return total


def _requested_amplitude(block, cmap: ChannelMap, dwell: Dwell, step_amplitude) -> float | None:
    """The commanded amplitude [mm p-p] of a dwell: a table step's, the map's literal or property, or the median
    of the amplitude channel over the dwell; None when the map names none."""
    if step_amplitude is not None:
        return float(step_amplitude)
    if cmap.amplitude_channel:
        return float(np.median(_read(block, cmap.amplitude_channel, dwell.start, dwell.stop)))
    if cmap.amplitude is None or (cmap.amplitude.value is None and cmap.amplitude.property is None):
        return None
    value = cmap.amplitude.resolve(block.properties, what=f"{block.where()}: [amplitude]")
    return float(value)


def _step_amplitude(cmap: ChannelMap, dwell: Dwell, rate_hz: float):
    if cmap.frequency.source != "table":
        return None
    t = dwell.start / rate_hz
    steps = [s for s in cmap.frequency.steps if s.start_s <= t + 0.5 / rate_hz]
    return steps[-1].amplitude_mm_pp if steps else None


def _row(labels: dict, line: DwellLine, requested: float | None) -> dict:
    h = line.h
    phase = math.degrees(math.atan2(h.imag, h.real))
    if phase <= -90.0:  # the contract's (-90, 270]: noise about 180 deg is never wrapped by a turn
        phase += 360.0
    achieved = 2e3 * abs(line.x1)
    return dict(labels, frequency_hz=line.freq_hz, amplitude_mm_pp=requested if requested else achieved,
                stiffness_n_per_m=abs(h), phase_deg=phase, stiffness_se_n_per_m=line.se_logmag * abs(h),
                phase_se_deg=math.degrees(line.se_phase), se_windows=line.windows, distortion=line.distortion,
                amplitude_achieved_mm_pp=achieved)


def _block_lines(block, cmap: ChannelMap, labels: dict, warnings: list, bar) -> list[dict]:
    """The rows of one block's settled dwells."""
    check_units(block, cmap)
    a = cmap.analysis
    rows = []
    for dwell in _dwells(block, cmap):
        nominal = dwell.freq_hz or dwell.estimate_hz  # a dwell found in the signal: its first estimate
        duration = (dwell.stop - dwell.start) / block.rate_hz
        at = f"{block.where()}: the dwell at {nominal:.4g} Hz (t = {dwell.start / block.rate_hz:.6g} s)"
        needed = a.min_windows * a.window_periods
        if duration * nominal < needed:
            if cmap.frequency.source == "signal":
                warnings.append(f"{at}: {duration:.3g} s holds {duration * nominal:.3g} periods, {needed} needed: dropped")
                continue
            raise InputError(f"{at}: {duration:.3g} s holds {duration * nominal:.3g} periods, {needed} needed "
                             f"({a.min_windows} windows of {a.window_periods}); record longer dwells or lower "
                             "[analysis] min_windows / window_periods")
        force, base = (_sensor(block, sensor, dwell, nominal) for sensor in (cmap.force, cmap.base))
        result = analyse_dwell(force, base, block.rate_hz, dwell.freq_hz, freq_guess_hz=dwell.estimate_hz,
                               quantity=cmap.base.quantity,
                               window_periods=a.window_periods, min_windows=a.min_windows,
                               settle_tolerance=a.settle_tolerance, harmonics=a.harmonics)
        bar.update(dwell.stop - dwell.start)
        if not isinstance(result, DwellLine):
            warnings.append(f"{block.where()}: t = {dwell.start / block.rate_hz:.6g} s: {result.reason}: dropped")
            continue
        requested = _requested_amplitude(block, cmap, dwell, _step_amplitude(cmap, dwell, block.rate_hz))
        row = _row(labels, result, requested)
        if requested and abs(row["amplitude_achieved_mm_pp"] / requested - 1) > AMPLITUDE_TOLERANCE:
            warnings.append(f"{at}: base amplitude {row['amplitude_achieved_mm_pp']:.4g} mm p-p achieved, "
                            f"{requested:g} requested")
        rows.append(row)
    return rows


def _labels(block, cmap: ChannelMap, default_run: int) -> dict:
    where = block.where()
    damper = cmap.damper.resolve(block.properties, what=f"{where}: [labels] damper")
    test = cmap.test.resolve(block.properties, what=f"{where}: [labels] test")
    run = default_run if cmap.run is None else cmap.run.resolve(block.properties, what=f"{where}: [labels] run")
    try:
        run_id = int(float(run))
        if run_id != float(run):
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"{where}: [labels] run: expected an integer run id, got {run!r}") from None
    return dict(damper=str(damper).strip(), test=str(test).strip(), run=run_id)


def _uff_rows(p: Path, cmap: ChannelMap, first_run: int) -> list[dict]:
    """The FRFs of a universal file as rows: one run per FRF (numbered on from ``first_run`` unless the map
    names a run property), no measured noise or distortion (the file holds none), the map's amplitude."""
    rows = []
    for k, (freq, h, props) in enumerate(read_uff_lines(p)):
        where = f"{p}: dataset {props.get('dataset', k + 1)}"
        labels = _labels(_Props(where, props), cmap, first_run + k)
        amplitude = cmap.amplitude.resolve(props, what=f"{where}: [amplitude]") if (
            cmap.amplitude is not None and (cmap.amplitude.value is not None or cmap.amplitude.property)) else None
        if amplitude is None:
            raise InputError(f"{where}: an FRF carries no base amplitude: give [amplitude] mm_pp (or property) in "
                             f"{cmap.path}")
        for f, v in zip(freq, h):
            phase = math.degrees(math.atan2(v.imag, v.real))
            rows.append(dict(labels, frequency_hz=float(f), amplitude_mm_pp=float(amplitude), stiffness_n_per_m=abs(v),
                             phase_deg=phase + 360.0 if phase <= -90.0 else phase))
    return rows


@dataclass(frozen=True)
class _Props:
    """What :func:`_labels` needs of a record: where it is (for messages) and its properties."""

    place: str
    properties: dict

    def where(self) -> str:
        return self.place


def _read_files(paths, cmap: ChannelMap, warnings: list, what: str, quiet: bool) -> list[dict]:
    rows, record = [], 0
    for index, path in enumerate(paths, start=1):
        p = Path(path)
        if not p.is_file():
            raise InputError(f"{p}: no such file" if not p.exists() else f"{p}: is not a file")
        if p.suffix.lower() not in EXTENSIONS + UFF_EXTENSIONS:
            raise InputError(f"{p}: unknown file type '{p.suffix}' (accepted: {', '.join(EXTENSIONS + UFF_EXTENSIONS)})")
        if p.suffix.lower() in UFF_EXTENSIONS:
            new = _uff_rows(p, cmap, record + 1)
            record += len({r["run"] for r in new})
            rows += new
            continue
        with open_blocks(p, cmap) as blocks:
            total = sum(b.n_samples for b in blocks)
            label = None if quiet else f"{what} {p.name}"
            with progress_bar(label, total=total, unit="sample") as bar:
                for block in blocks:
                    record += 1
                    # one run per file when each group is a dwell, else one per record
                    labels = _labels(block, cmap, index if cmap.frequency.source == "property" else record)
                    rows += _block_lines(block, cmap, labels, warnings, bar)
    return rows


def _dedupe(frame: pd.DataFrame, warnings: list) -> pd.DataFrame:
    """One row per (damper, test, run, line): a dwell repeated at the same frequency keeps its first reading."""
    frame = frame.sort_values(["damper", "test", "run", "frequency_hz"], kind="mergesort").reset_index(drop=True)
    same = np.zeros(len(frame), bool)
    if len(frame) > 1:
        f = frame["frequency_hz"].to_numpy()
        key = frame[["damper", "test", "run"]].astype(str).agg("\x00".join, axis=1).to_numpy()
        same[1:] = (key[1:] == key[:-1]) & (np.abs(np.diff(f)) <= FREQ_REL_TOL * f[1:])
    for i in np.flatnonzero(same):
        r = frame.iloc[i]
        warnings.append(f"{r['damper']} {r['test']} run {r['run']}: a second dwell at {r['frequency_hz']:g} Hz: "
                        "the first kept")
    return frame[~same].reset_index(drop=True)


def _subtract_fixture(frame: pd.DataFrame, fixture: pd.DataFrame, warnings: list) -> pd.DataFrame:
    """The bare fixture's complex force per line taken off every run's line (``docs/import.md``).

    The fixture's lines (all its runs, averaged as complex numbers) are matched by frequency within
    :data:`FREQ_REL_TOL`; a line without a match is dropped with a warning. Standard errors add in quadrature,
    each taken as isotropic in the complex plane (``|h| sqrt((se_l^2 + se_p^2) / 2)``).
    """
    def complex_of(df):
        return df["stiffness_n_per_m"].to_numpy() * np.exp(1j * np.radians(df["phase_deg"].to_numpy()))

    def spread(df, h):
        se_l = df["stiffness_se_n_per_m"].to_numpy() / df["stiffness_n_per_m"].to_numpy()
        se_p = np.radians(df["phase_se_deg"].to_numpy())
        return np.abs(h) * np.sqrt((se_l ** 2 + se_p ** 2) / 2)

    fh, fs = complex_of(fixture), spread(fixture, complex_of(fixture))
    ff = fixture["frequency_hz"].to_numpy()
    order = np.argsort(ff)
    ff, fh, fs = ff[order], fh[order], fs[order]
    # the fixture's lines: clusters of its dwells within the tolerance, averaged
    cut = np.append(True, np.diff(ff) > FREQ_REL_TOL * ff[1:])
    group = np.cumsum(cut) - 1
    n = np.bincount(group)
    line_f = np.bincount(group, ff) / n
    line_h = (np.bincount(group, fh.real) + 1j * np.bincount(group, fh.imag)) / n
    line_s = np.sqrt(np.bincount(group, fs ** 2)) / n

    f = frame["frequency_hz"].to_numpy()
    j = np.abs(f[:, None] - line_f[None, :]).argmin(axis=1)  # the nearest fixture line (tens of lines)
    ok = np.abs(line_f[j] - f) <= FREQ_REL_TOL * f
    for i in np.flatnonzero(~ok):
        r = frame.iloc[i]
        warnings.append(f"{r['damper']} {r['test']} run {r['run']}: no fixture line near {r['frequency_hz']:g} Hz: "
                        "dropped")
    frame = frame[ok].reset_index(drop=True)
    j = j[ok]
    h = complex_of(frame)
    s = np.hypot(spread(frame, h), line_s[j])
    h = h - line_h[j]
    phase = np.degrees(np.angle(h))
    frame["stiffness_n_per_m"] = np.abs(h)
    frame["phase_deg"] = np.where(phase <= -90.0, phase + 360.0, phase)
    frame["stiffness_se_n_per_m"] = s
    frame["phase_se_deg"] = np.degrees(s / np.abs(h))
    return frame


def import_recordings(paths, cmap: ChannelMap, *, fixture=(), quiet: bool = False) -> ImportResult:
    """Lines of raw recordings as bench rows with their measured noise and distortion.

    Parameters
    ----------
    paths : sequence of path-like
        Raw recordings (``.tdms``, ``.h5``/``.hdf5``, ``.mf4``/``.mdf``, ``.csv``); each file's groups are records
        (:func:`sbcal.data.acquisition.sources.open_blocks`).
    cmap : ChannelMap
        Which channels are force and base motion, where each dwell's frequency comes from, the labels.
    fixture : sequence of path-like
        Recordings of the bare fixture (no damper), read with the same map; their complex force per line is
        subtracted from every line.
    quiet : bool
        No progress bars.

    Returns
    -------
    ImportResult

    Raises
    ------
    InputError
        One line: a missing file or channel, a unit that disagrees with the file's, a NaN or infinite sample, a
        clipped channel (the line named), a non-monotonic time column, a dwell shorter than the periods the
        analysis needs, no settled dwell at all.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("import: no recording given")
    warnings: list[str] = []
    rows = _read_files(paths, cmap, warnings, "import", quiet)
    if not rows:
        raise InputError(f"{paths[0]}" + (f" (and {len(paths) - 1} more)" if len(paths) > 1 else "") +
                         ": no settled dwell: nothing to write" + (f" ({warnings[0]})" if warnings else ""))
    frame = _dedupe(pd.DataFrame(rows), warnings)
    if fixture:
        fix_rows = _read_files([Path(p) for p in fixture], cmap, warnings, "fixture", quiet)
        if not fix_rows:
            raise InputError(f"{fixture[0]}: the fixture recording has no settled dwell")
        frame = _subtract_fixture(frame, pd.DataFrame(fix_rows), warnings)
    frame = frame.reindex(columns=list(BENCH_COLUMNS + MEASURED_COLUMNS))  # UFF lines have no measured values
    return ImportResult(frame=frame, warnings=tuple(warnings))


def write_import(result: ImportResult, path) -> None:
    """Write the imported lines as a bench CSV, atomically, after reading them back with the bench reader (so a
    file that ``sbcal run`` would refuse is never written)."""
    from ..readers import load_bench

    with atomic_path(path, ".csv") as tmp:
        result.frame.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
        load_bench(tmp)
