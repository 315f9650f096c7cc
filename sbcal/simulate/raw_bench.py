"""Raw recordings of the virtual bench: the time series a shaker's acquisition system writes.

The time-domain bench (``strand_slip=...,time:1``; :mod:`sbcal.simulate.virtual_bench`) integrates the
cable from rest at every line and keeps only its first harmonic. Here every run keeps the time series
instead, laid out as a stepped sine on a data acquisition system's clock (``docs/virtual_bench.md``,
"Raw recordings"), so that ``sbcal import`` can be tested end to end on physics richer than the fitted
model. Per line ``k`` (frequency ``f``, ``omega = 2 pi f``, base amplitude ``x0``), from its start ``t_k``:

1. the integration of :func:`sbcal.model.cable_time.time_response` (``keep_series``): the base ramped up
   from rest over :data:`sbcal.simulate.virtual_bench.RAMP_PERIODS` periods, settled, ``P`` periods in all;
2. ``hold_periods`` of steady state: the integration's last whole period repeated (periodic to its
   settling tolerance, 1e-5);
3. a taper of the base amplitude to zero over :data:`TAPER_PERIODS` periods (the same C2 quintic as
   the ramp, downwards; the force is the steady one times that envelope: not analysed), and a pause.

The force is resampled onto the DAS clock (``rate_hz``) by an interpolating spline through the
integration's samples (quintic by default); the table acceleration is exact: the second time derivative
of the commanded base motion ``x_b = x0 env(theta) cos(theta)``, ``theta = omega (t - t_k)``, which is
how ``time_response`` builds the base. Measurement chain: the force split 0.55/0.45 over two load
cells, the bench's fixture mass and sensor delay applied to the force channels (the same ``f_meas`` as
:func:`sbcal.simulate.virtual_bench.response`), white sensor noise and a constant offset per channel
(standard deviations relative to the channel's RMS over the run), optional ADC quantisation and
saturation. Every draw comes from the caller's generator, after :func:`record`'s re-clamping scatter:
the runs' physics are those of the CSV bench's first test for the same seed.

The truth of each line (:attr:`RawRun.f_uu`) is the integration's own first harmonic of the force over
that of the base motion (last window), read through the fixture mass and the sensor delay.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..core._io import atomic_path
from ..core.errors import InputError
from ..core.progress import progress_bar
from ..data.bench import BENCH_COLUMNS, curves_to_frame
from ..model.damper import Damper
from ..model.fem import STANDARD_GRID_HZ
from .effects import BENCH_HARMONICS
from .virtual_bench import (RAMP_PERIODS, BenchConfig, integrate_slip, reclamping, slip_law_params, table_and_channels,
                            test_amplitude, with_defaults)


__all__ = [
    "CHANNELS", "FORCE_SPLIT", "TAPER_PERIODS", "GROUP", "FORMATS", "RawRun", "iter_raw", "measure",
    "record_raw", "truth_frame", "write_tdms", "write_hdf5", "write_raw", "write_channel_map",
]

CHANNELS = {"Force A": "N", "Force B": "N", "Table acceleration": "m/s^2", "Drive frequency": "Hz",
            "Drive amplitude": "mm p-p"}
"""The channels of a raw run and their units (``unit_string`` in TDMS, ``unit`` in HDF5)."""

FORCE_SPLIT = {"Force A": 0.55, "Force B": 0.45}
"""The share of the base force each load cell carries (they sum to the force)."""

TAPER_PERIODS = 2
"""Periods of the base's taper to zero after the hold."""

GROUP = "stepped_sine"
"""The one group (TDMS, HDF5) of a raw file."""

FORMATS = {"tdms": ".tdms", "hdf5": ".h5"}
"""File formats of :func:`write_raw` and their extensions."""

_SENSORS = ("Force A", "Force B", "Table acceleration")  # channels with noise, offsets and an ADC
_QUANTITY = {"Force A": "force", "Force B": "force", "Table acceleration": "acceleration"}


@dataclass(frozen=True, eq=False)
class RawRun:
    """One run of a test as the acquisition system recorded it, and its truth.

    Attributes
    ----------
    damper, test : str
    run : int
        Run number within the test, from 1.
    rate_hz : float
        Sampling rate of the channels [Hz].
    channels : dict of str to ndarray, shape (n_samples,)
        :data:`CHANNELS`, float64, sample ``n`` at ``n / rate_hz`` s. ``Drive frequency`` [Hz] and
        ``Drive amplitude`` [mm p-p] are the controller's command: the line's values from the start of its
        ramp to the end of its hold, 0 during the taper and the pauses.
    properties : dict
        ``damper``, ``test``, ``run``, and ``amplitude_mm_pp`` where the test's amplitude is constant.
    freq_hz, amplitude_mm_pp : ndarray, shape (n_freq,)
        The lines [Hz] and their commanded amplitude [mm p-p].
    f_uu : ndarray of complex, shape (n_freq,)
        Truth: the integration's first harmonic of the force over the base motion's [N/m], through the
        fixture mass and the sensor delay (what the channels hold, noise aside).
    distortion : ndarray, shape (n_freq,)
        Truth: the force's ``sqrt(sum_{h=2..9} |F_h|^2) / |F_1|`` as recorded (the same chain).
    start_s : ndarray, shape (n_freq,)
        Start of each line (its ramp from rest) [s].
    hold_s : ndarray, shape (n_freq, 2)
        Start and end of each line's held steady state (``hold_periods`` whole periods) [s].
    full_scale : dict of str to float, or None
        ADC full scale per quantity (``force`` [N], ``acceleration`` [m/s^2]) when quantised.
    """

    damper: str
    test: str
    run: int
    rate_hz: float
    channels: dict
    properties: dict
    freq_hz: np.ndarray
    amplitude_mm_pp: np.ndarray
    f_uu: np.ndarray
    distortion: np.ndarray
    start_s: np.ndarray
    hold_s: np.ndarray
    full_scale: dict | None = None

    @property
    def units(self) -> dict:
        """Channel name -> unit (:data:`CHANNELS`)."""
        return dict(CHANNELS)


# --- checks ------------------------------------------------------------------------------------

def _check(config: BenchConfig, f, rate_hz, hold_periods, pause_s, noise, offsets, adc_bits, full_scale,
           spline_degree):
    slip = config.effects.get("strand_slip")
    if slip is None or not slip.time_domain:
        raise InputError("raw recordings need the time-domain strand slip (effect strand_slip=...,time:1)")
    if "fixture_resonance" in config.effects:
        raise InputError("effect fixture_resonance: the raw recordings do not take it (a hysteretic fixture mode "
                         "has no time-domain form)")
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise InputError("freq_hz: expected finite frequencies > 0 [Hz], shape (n_freq,)")
    need = 2 * BENCH_HARMONICS * f.max()
    if not (math.isfinite(rate_hz) and rate_hz > need):
        raise InputError(f"rate_hz: expected more than 2 x {BENCH_HARMONICS} harmonics x the highest line = {need:g} Hz, "
                         f"got {rate_hz!r}")
    if not isinstance(hold_periods, (int, np.integer)) or isinstance(hold_periods, bool) or hold_periods < 1:
        raise InputError(f"hold_periods: expected an integer >= 1, got {hold_periods!r}")
    for name, v in (("pause_s", pause_s), ("noise", noise), ("offsets", offsets)):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{name}: expected a finite value >= 0, got {v!r}")
    if adc_bits is not None and (not isinstance(adc_bits, (int, np.integer)) or isinstance(adc_bits, bool)
                                 or not 2 <= adc_bits <= 32):
        raise InputError(f"adc_bits: expected an integer 2..32 or None, got {adc_bits!r}")
    for key, v in (full_scale or {}).items():
        if key not in ("force", "acceleration") or not (math.isfinite(v) and v > 0):
            raise InputError(f"full_scale: expected force and/or acceleration > 0, got {key}={v!r}")
    if spline_degree not in (3, 5):
        raise InputError(f"spline_degree: expected 3 or 5, got {spline_degree!r}")


# --- one run's physics -------------------------------------------------------------------------

def _integrate(damper: Damper, config: BenchConfig, f, amp, run: dict, ej_scale: float, chi0_scale: float,
               label: str):
    """``time_response`` of one run with the series kept, its parameters mapped as the CSV bench maps them
    (:func:`sbcal.simulate.virtual_bench.response`, time domain)."""
    slip = config.effects["strand_slip"]
    lp = slip_law_params(slip, damper, np.array([run["EJ"]]), ej_scale, chi0_scale)
    geometry = {k: v for k, v in run.items() if k not in ("EJ", "beta")}
    return integrate_slip(damper, f, amp, slip, lp, ej_min=np.array([run["EJ"] * ej_scale]),
                          beta=np.array([run["beta"]]), rocking=config.effects.get("base_rocking", 0.0),
                          geometry=geometry, keep_series=True, label=label)


def _smoothstep(u):
    """The C2 quintic ``q(u) = u^3 (10 - 15 u + 6 u^2)`` on [0, 1] (0 below, 1 above) and its two derivatives
    (``time_response``'s ramp)."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10 - 15 * u + 6 * u * u), 30 * u * u * (1 - u) ** 2, 60 * u * (1 - u) * (1 - 2 * u)


def _base(theta, x0, end_theta):
    """The commanded base motion of a line and its second derivative in theta at phase times ``theta``
    [rad]: ``x0 env cos(theta)``, ``env`` the ramp up over
    :data:`sbcal.simulate.virtual_bench.RAMP_PERIODS` periods times the taper
    down over :data:`TAPER_PERIODS` periods from ``end_theta`` (the end of the hold)."""
    up_span, down_span = 2 * np.pi * RAMP_PERIODS, 2 * np.pi * TAPER_PERIODS
    u, du, ddu = _smoothstep(theta / up_span)
    q, dq, ddq = _smoothstep((theta - end_theta) / down_span)
    d, dd, ddd = 1.0 - q, -dq / down_span, -ddq / down_span**2
    du, ddu = du / up_span, ddu / up_span**2
    env, d_env, dd_env = u * d, du * d + u * dd, ddu * d + 2 * du * dd + u * ddd
    cos, sin = np.cos(theta), np.sin(theta)
    return x0 * env * cos, x0 * (dd_env * cos - 2 * d_env * sin - env * cos)


def _force_spline(force, steps, periods, hold_periods, end_theta, degree):
    """The line's force [N] as a spline in phase time: the integration's samples (0 at rest at theta = 0),
    the last period repeated over the hold and, tapered, over the taper; zero after."""
    from scipy.interpolate import make_interp_spline

    last = force[(periods - 1) * steps:periods * steps]
    dt = 2 * np.pi / steps
    taper = np.tile(last, TAPER_PERIODS)
    theta_taper = end_theta + np.arange(1, taper.size + 1) * dt
    taper = taper * (1.0 - _smoothstep((theta_taper - end_theta) / (2 * np.pi * TAPER_PERIODS))[0])
    zeros = np.zeros(degree + 1)  # at rest after the taper: the spline ends flat, not on its end conditions
    g = np.concatenate([[0.0], force[:periods * steps], np.tile(last, hold_periods), taper, zeros])
    return make_interp_spline(np.arange(g.size) * dt, g, k=degree), (g.size - 1) * dt


def _held_harmonics(r, periods):
    """The force's harmonics 1..9 [N] (n_freq, 9) and the base's first harmonic [m] (n_freq,) over each
    line's last whole period, the one the hold repeats (a rectangular DFT, as ``time_response`` takes its
    windows; a period's phase times are ``theta = 2 pi m / steps``, m = 1 .. steps, modulo 2 pi)."""
    steps = r.steps_per_period
    phasor = np.exp(-2j * np.pi * np.outer(np.arange(1, BENCH_HARMONICS + 1), np.arange(1, steps + 1)) / steps)
    rows = [(p - 1) * steps + np.arange(steps) for p in periods]
    force = np.stack([r.force[0, k, j] for k, j in enumerate(rows)])
    base = np.stack([r.base[0, k, j] for k, j in enumerate(rows)])
    return 2 / steps * force @ phasor.T, 2 / steps * base @ phasor[0]


def _layout(f, periods, hold_periods, pause_s):
    """Start of each line [s] and the record's duration [s]: a pause, then each line and a pause."""
    duration = (periods + hold_periods + TAPER_PERIODS) / f
    start = pause_s + np.concatenate([[0.0], np.cumsum(duration + pause_s)[:-1]])
    return start, float(start[-1] + duration[-1] + pause_s)


def _nice_range(peak):
    """The smallest 1-2-5 decade value at least 1.25 x ``peak`` (an ADC range picked for the signal)."""
    need = 1.25 * max(peak, 1e-300)
    decade = 10.0 ** math.floor(math.log10(need))
    return next(m * decade for m in (1, 2, 5, 10) if m * decade >= need)


def measure(channels: dict, rng: np.random.Generator, *, noise: float, offsets: float, adc_bits: int | None = None,
            full_scale: dict | None = None) -> tuple[dict, dict]:
    """The measurement chain of the sensor channels: white noise and a constant offset per channel, then an ADC.

    Parameters
    ----------
    channels : dict
        ``{name: ndarray (n,)}`` holding at least the sensor channels (Force A, Force B, Table acceleration),
        noise-free; not modified.
    rng : numpy.random.Generator
        Per sensor channel in that order: its offset, then its noise.
    noise, offsets, adc_bits, full_scale
        As :func:`iter_raw`.

    Returns
    -------
    channels : dict
        A new dict: the sensor channels measured, the others as given.
    full_scale : dict
        The ADC ranges used (``{}`` without an ADC).
    """
    out = dict(channels)
    for name in _SENSORS:
        x = channels[name]
        rms = float(np.sqrt(np.mean(x * x)))
        out[name] = x + rms * (offsets * rng.standard_normal() + noise * rng.standard_normal(x.size))
    scales = {}
    if adc_bits is not None:
        peaks = {q: max(np.abs(out[c]).max() for c in _SENSORS if _QUANTITY[c] == q)
                 for q in ("force", "acceleration")}
        scales = {q: float((full_scale or {}).get(q) or _nice_range(peaks[q])) for q in peaks}
        for name in _SENSORS:
            fs = scales[_QUANTITY[name]]
            lsb = 2 * fs / 2.0**adc_bits
            out[name] = np.clip(np.round(out[name] / lsb) * lsb, -fs, fs - lsb)
    return out, scales


def _one_run(damper, config, f, amp, run, ej_scale, chi0_scale, number, test, rng, *, rate_hz, hold_periods,
             pause_s, noise, offsets, adc_bits, full_scale, spline_degree) -> RawRun:
    """Run ``number`` of a test (parameters ``run``, scatter factors ``ej_scale``, ``chi0_scale``): the
    integration, the stepped sine on the clock, the measurement chain, the truth (:func:`iter_raw`)."""
    r = _integrate(damper, config, f, amp, run, ej_scale, chi0_scale, f"{test} run {number}")
    steps = r.steps_per_period
    periods = r.periods[0]
    omega = 2 * np.pi * f
    x0 = amp / 2 * 1e-3
    mass = config.effects.get("fixture_mass", 0.0)
    delay = config.effects.get("sensor_delay", 0.0)
    start, duration = _layout(f, periods, hold_periods, pause_s)
    n = int(math.ceil(duration * rate_hz))
    force, accel, drive_f, drive_a = (np.zeros(n) for _ in range(4))
    for k in range(f.size):
        end_theta = 2 * np.pi * (periods[k] + hold_periods)
        spline, last_theta = _force_spline(r.force[0, k], steps, periods[k], hold_periods, end_theta, spline_degree)
        # the line's samples: from its start to the end of its taper (the force channels later by the delay)
        lo = int(math.ceil(start[k] * rate_hz))
        hi = int(math.ceil((start[k] + (end_theta + 2 * np.pi * TAPER_PERIODS) / omega[k] + delay) * rate_hz))
        theta = omega[k] * (np.arange(lo, hi) / rate_hz - start[k])
        _, a = _base(theta, x0[k], end_theta)
        accel[lo:hi] += a * omega[k] ** 2
        late = theta - omega[k] * delay  # the force channels lag the table by the sensor delay
        inside = (late >= 0) & (late <= last_theta)
        f_line = np.where(inside, spline(np.clip(late, 0.0, last_theta)), 0.0)
        if mass:
            f_line += mass * omega[k] ** 2 * _base(late, x0[k], end_theta)[1]
        force[lo:hi] += f_line
        dwell = (theta >= 0) & (theta < end_theta)
        drive_f[lo:hi][dwell], drive_a[lo:hi][dwell] = f[k], amp[k]
    channels = {name: share * force for name, share in FORCE_SPLIT.items()}
    channels["Table acceleration"] = accel
    channels, scales = measure(channels, rng, noise=noise, offsets=offsets, adc_bits=adc_bits, full_scale=full_scale)
    channels["Drive frequency"], channels["Drive amplitude"] = drive_f, drive_a
    harmonics, x1 = _held_harmonics(r, periods)
    truth = table_and_channels(harmonics[None, :, 0] / x1, omega[None, :], config.effects)[0]
    distortion = np.sqrt((np.abs(harmonics[:, 1:]) ** 2).sum(axis=1)) / np.abs(truth * x1)
    properties = {"damper": damper.name, "test": test, "run": int(number)}
    if np.all(amp == amp[0]):
        properties["amplitude_mm_pp"] = float(amp[0])
    hold = np.stack([start + periods / f, start + (periods + hold_periods) / f], axis=1)
    return RawRun(damper=damper.name, test=test, run=int(number), rate_hz=float(rate_hz), channels=channels,
                  properties=properties, freq_hz=f.copy(), amplitude_mm_pp=amp.copy(), f_uu=truth,
                  distortion=distortion, start_s=start, hold_s=hold, full_scale=scales or None)


# --- the runs of a test ------------------------------------------------------------------------

def iter_raw(damper: Damper, config: BenchConfig, test: str, *, rng: np.random.Generator, freq_hz=None,
             rate_hz: float = 2560.0, hold_periods: int = 40, pause_s: float = 0.25, noise: float = 1e-3,
             offsets: float = 0.02, adc_bits: int | None = None, full_scale: dict | None = None,
             spline_degree: int = 5, progress: str | None = None):
    """The raw recordings of ``config.runs`` runs of one test, one at a time (module docstring).

    Parameters
    ----------
    damper : Damper
        Supplies the geometry; its ``name`` fills the ``damper`` property.
    config : BenchConfig
        Must hold the time-domain strand slip (``SlipLaw(time_domain=True)``); its re-clamping scatter
        is drawn as :func:`sbcal.simulate.virtual_bench.record` draws it (the line noise and outliers of the
        CSV bench are not: the sensor noise below takes their place). ``fixture_resonance`` is refused.
    test : str
        Test label (:func:`sbcal.simulate.virtual_bench.test_amplitude`).
    rng : numpy.random.Generator
        The scatter first (all runs), then per run the offsets and the noise.
    freq_hz : array_like, shape (n_freq,), optional
        The lines in the order played [Hz] (default :data:`sbcal.model.fem.STANDARD_GRID_HZ`).
    rate_hz : float
        Sampling rate [Hz]; more than ``2 x 9 x`` the highest line.
    hold_periods : int
        Whole periods of steady state held after the integration settled.
    pause_s : float
        Pause before the first line, between lines and after the last [s].
    noise : float
        White sensor noise per channel (Force A, Force B, Table acceleration): standard deviation over the
        channel's RMS over the run.
    offsets : float
        Constant offset per channel: drawn ``N(0, offsets)`` times the channel's RMS.
    adc_bits : int, optional
        Quantise the three sensor channels to ``adc_bits`` over ``[-full_scale, full_scale)`` and saturate.
    full_scale : dict, optional
        ``{"force": N, "acceleration": m/s^2}`` ADC ranges (both force channels share one); a missing one is
        the smallest 1-2-5 value >= 1.25 x the peak.
    spline_degree : {5, 3}
        Degree of the interpolating spline through the integration's force samples.
    progress : str, optional
        Label of a progress bar over the runs (None: no bar).

    Yields
    ------
    RawRun
        Runs 1 .. ``config.runs``.

    Raises
    ------
    InputError
        Not the time-domain strand slip, ``fixture_resonance``, a bad setting, or a line that does not
        settle or whose time steps fail (named).
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng: expected a numpy.random.Generator (np.random.default_rng(seed))")
    f = STANDARD_GRID_HZ.copy() if freq_hz is None else np.atleast_1d(np.asarray(freq_hz, dtype=float))
    _check(config, f, float(rate_hz), hold_periods, pause_s, noise, offsets, adc_bits, full_scale, spline_degree)
    amp = test_amplitude(test, f)
    runs, ej_scale, chi0_scale = reclamping(damper, config, with_defaults(damper, config.params), rng)
    with progress_bar(progress, total=config.runs, unit="run") as bar:
        for i in range(config.runs):
            run = {k: float(np.asarray(v, dtype=float).reshape(-1)[i if np.size(v) > 1 else 0])
                   for k, v in runs.items()}
            yield _one_run(damper, config, f, amp, run, float(ej_scale[i]), float(chi0_scale[i]), i + 1, test, rng,
                           rate_hz=float(rate_hz), hold_periods=int(hold_periods), pause_s=float(pause_s),
                           noise=float(noise), offsets=float(offsets), adc_bits=adc_bits, full_scale=full_scale,
                           spline_degree=spline_degree)
            bar.update(1)


def record_raw(damper: Damper, config: BenchConfig, test: str, **options) -> list[RawRun]:
    """Every run of :func:`iter_raw` (the same keyword options) as a list."""
    return list(iter_raw(damper, config, test, **options))


def truth_frame(runs) -> pd.DataFrame:
    """The truth lines of raw runs (:attr:`RawRun.f_uu`) as bench CSV rows: :data:`BENCH_COLUMNS` and the force's
    ``distortion`` (:attr:`RawRun.distortion`, one of the bench file's measured columns)."""
    frames = []
    for r in runs:
        frame = curves_to_frame(r.damper, r.test, r.freq_hz, r.amplitude_mm_pp, r.f_uu[None, :], runs=[r.run])
        frame["distortion"] = r.distortion
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)[list(BENCH_COLUMNS) + ["distortion"]]


# --- files -------------------------------------------------------------------------------------

def write_tdms(path, run: RawRun, *, segment_samples: int = 2**15) -> None:
    """Write a raw run as an NI TDMS file, atomically, in segments of ``segment_samples`` (as a DAS streams).

    File properties: :attr:`RawRun.properties`; one group :data:`GROUP`; per channel ``wf_increment`` [s],
    ``wf_start_offset`` (0 s) and ``unit_string``.
    """
    try:
        from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
    except ImportError:
        raise InputError(f'writing {path} needs npTDMS: pip install "sbcal[tdms]"') from None
    n = next(iter(run.channels.values())).size
    with atomic_path(path, ".tdms") as tmp, TdmsWriter(str(tmp)) as writer:
        for lo in range(0, max(n, 1), segment_samples):
            first = lo == 0
            objects = [RootObject(properties=dict(run.properties)), GroupObject(GROUP)] if first else []
            for name, unit in CHANNELS.items():
                props = {"wf_increment": 1.0 / run.rate_hz, "wf_start_offset": 0.0, "unit_string": unit} if first else None
                objects.append(ChannelObject(GROUP, name, run.channels[name][lo:lo + segment_samples], properties=props))
            writer.write_segment(objects)


def write_hdf5(path, run: RawRun) -> None:
    """Write a raw run as HDF5 in the documented layout, atomically: file attributes the properties, one
    group :data:`GROUP` with attribute ``sample_rate_hz``, one 1-D dataset per channel with attribute ``unit``."""
    import h5py

    with atomic_path(path, ".h5") as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.attrs.update(run.properties)
            group = h5.create_group(GROUP)
            group.attrs["sample_rate_hz"] = run.rate_hz
            for name, unit in CHANNELS.items():
                group.create_dataset(name, data=run.channels[name]).attrs["unit"] = unit


def write_raw(directory, run: RawRun, fmt: str = "tdms") -> Path:
    """Write a raw run as ``DIRECTORY/<damper>_<test>_run<k>.tdms`` (or ``.h5``); returns the path."""
    if fmt not in FORMATS:
        raise InputError(f"raw format {fmt!r}: expected one of {', '.join(FORMATS)}")
    path = Path(directory) / f"{run.damper}_{run.test}_run{run.run}{FORMATS[fmt]}"
    (write_tdms if fmt == "tdms" else write_hdf5)(path, run)
    return path


def write_channel_map(path, *, full_scale: dict | None = None) -> None:
    """Write the channel map (``docs/import.md``) that reads the raw files, atomically.

    Labels from the file properties, force the sum of ``Force A`` and ``Force B`` [N], base the table
    acceleration [m/s^2], each dwell where ``Drive frequency`` is constant and non-zero, the requested
    amplitude from ``Drive amplitude``; ``full_scale`` (:attr:`RawRun.full_scale`) gives the ADC ranges.
    """
    scales = full_scale or {}

    def range_line(quantity):
        return [f"range = {scales[quantity]!r}"] if quantity in scales else []

    lines = [
        "# The channel map of the virtual bench's raw files (sbcal bench --raw; docs/virtual_bench.md).",
        "[labels]", 'damper = {property = "damper"}', 'test = {property = "test"}', 'run = {property = "run"}', "",
        "[force]", f"channels = {json.dumps(['Force A', 'Force B'])}", f"unit = {json.dumps(CHANNELS['Force A'])}",
        *range_line("force"), "",
        "[base]", 'channel = "Table acceleration"', 'quantity = "acceleration"',
        f"unit = {json.dumps(CHANNELS['Table acceleration'])}", *range_line("acceleration"), "",
        "[frequency]", 'source = "channel"', 'channel = "Drive frequency"', "",
        "[amplitude]", 'channel = "Drive amplitude"', "",
    ]
    with atomic_path(path, ".toml") as tmp:
        tmp.write_text("\n".join(lines), encoding="utf-8")
