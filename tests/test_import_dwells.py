"""Dwell analysis of raw stepped-sine recordings (sbcal.data.acquisition.dwells and .lines): exact first harmonics on whole
periods, settling, honest standard errors, distortion, finding dwells, clipping."""

import math

import numpy as np
import pytest

from sbcal.data.acquisition.dwells import dwells_from_channel, dwells_from_signal, dwells_from_steps
from sbcal.data.acquisition.lines import DwellLine, Unsettled, analyse_dwell, clipped

H_TRUE = 2.0e4 * np.exp(0.4j)     # N/m
X1 = 1.0e-3 * np.exp(0.3j)        # m
HARMONICS = ((3, 0.15), (5, 0.10))  # force harmonics relative to |F1|
THD = math.hypot(0.15, 0.10)


def _base_first(quantity, w):
    return {"acceleration": -w * w * X1, "velocity": 1j * w * X1, "displacement": X1}[quantity]


def _dwell(rate, f, seconds, *, quantity="acceleration", noise=0.0, rng=None, base_transient=0.0,
           force_transient=0.0, transient_periods=2.0, harmonics=HARMONICS):
    """One dwell: force with harmonics 3 and 5, an offset and a drift; base motion a sine plus a decaying free
    transient at 1.37 f, an offset and a drift; the force's first harmonic may settle by (1 + a exp(-t/tau));
    white noise of sd ``noise`` x the first harmonic's amplitude on both channels."""
    t = np.arange(round(seconds * rate)) / rate
    w = 2 * np.pi * f
    b1 = _base_first(quantity, w)
    f1 = H_TRUE * X1
    decay = np.exp(-t * f / transient_periods)
    base = (b1 * np.exp(1j * w * t)).real + base_transient * abs(b1) * decay * np.sin(1.37 * w * t)
    force = (f1 * np.exp(1j * w * t)).real * (1 + force_transient * decay)
    for k, r in harmonics:
        force += (r * abs(f1) * np.exp(0.7j * k + 1j * k * w * t)).real
    force += 3.0 + 0.2 * t
    base += 0.3 * abs(b1) + 0.05 * abs(b1) * t
    if noise:
        force += noise * abs(f1) * rng.standard_normal(t.size)
        base += noise * abs(b1) * rng.standard_normal(t.size)
    return force, base


# --- exact first harmonics ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("rate, f", [(2560.0, 7.3), (2560.0, 37.0), (10000.0, 4.0)])
@pytest.mark.parametrize("given", [True, False])
def test_first_harmonic_is_exact_on_non_integer_periods(rate, f, given):
    """Periods of 350.7, 69.19 and 2500 samples, the frequency given or estimated: least squares over each
    window's own samples is exact; the offsets, the drifts and the base's transient (left out as unsettled) do
    not bias h."""
    force, base = _dwell(rate, f, 20.0, base_transient=0.5, transient_periods=2.0)
    line = analyse_dwell(force, base, rate, f if given else None, quantity="acceleration")
    assert isinstance(line, DwellLine), line
    rel, tol = abs(line.h / H_TRUE - 1), (1e-6 if given else 1e-5)
    assert rel < tol and abs(np.angle(line.h / H_TRUE)) < 1e-5
    assert abs(line.x1 / X1 - 1) < tol
    assert abs(line.freq_hz / f - 1) < 1e-8
    assert line.distortion == pytest.approx(THD, rel=1e-6)
    assert line.settled_s > 0 and line.used_start_s >= line.settled_s    # the transient's windows left out
    assert 10 <= line.windows <= 40 and line.window_periods % 4 == 0
    assert line.used_s == pytest.approx(line.windows * line.window_periods / line.freq_hz)


@pytest.mark.parametrize("quantity", ["velocity", "displacement"])
def test_base_quantity_to_displacement(quantity):
    force, base = _dwell(5000.0, 13.7, 10.0, quantity=quantity)
    line = analyse_dwell(force, base, 5000.0, None, quantity=quantity)
    assert abs(line.h / H_TRUE - 1) < 1e-8 and abs(line.x1 / X1 - 1) < 1e-8


def test_harmonics_only_below_045_of_the_sampling_rate():
    force, base = _dwell(2560.0, 300.0, 2.0, harmonics=((3, 0.15),))     # a DAS filters what is above Nyquist
    line = analyse_dwell(force, base, 2560.0, 300.0, quantity="acceleration")
    assert line.harmonics == 3 and line.distortion == pytest.approx(0.15, rel=1e-6)
    assert abs(line.h / H_TRUE - 1) < 1e-6


# --- standard errors ---------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_two_standard_errors_cover_the_noise_free_line():
    """400 dwells, 4 noise levels, 4-40 Hz, 4-30 s, a force transient to settle. With K = 10-40 batches, +-2 SE
    covers ~93-95 % (Student t, K - 1 dof). Binomial sd of a coverage of 0.95 over 400 dwells: 0.011, so
    0.90-0.98 is -4.6 to +2.8 sd about 0.95 (and -3 to +4.6 sd about 0.933, the t coverage at K = 15)."""
    rng = np.random.default_rng(27)
    rate = 2560.0
    z = []
    for i in range(400):
        f = float(np.exp(rng.uniform(np.log(4.0), np.log(40.0))))
        seconds = max(float(rng.uniform(4.0, 30.0)), 60.0 / f)
        force, base = _dwell(rate, f, seconds, noise=(0.05, 0.2, 0.5, 1.0)[i % 4], rng=rng, force_transient=0.3,
                             transient_periods=1.0)
        line = analyse_dwell(force, base, rate, f, quantity="acceleration")
        assert isinstance(line, DwellLine), line
        r = line.h / H_TRUE
        z.append((math.log(abs(r)) / line.se_logmag, np.angle(r) / line.se_phase))
    cover = np.mean(np.abs(np.array(z)) <= 2, axis=0)
    assert 0.90 <= cover[0] <= 0.98 and 0.90 <= cover[1] <= 0.98, cover


def test_standard_error_scales_with_noise():
    rng = np.random.default_rng(1)
    se = []
    for noise in (0.02, 0.2):
        force, base = _dwell(2560.0, 11.0, 30.0, noise=noise, rng=rng)
        se.append(analyse_dwell(force, base, 2560.0, 11.0, quantity="acceleration").se_logmag)
    assert 5 < se[1] / se[0] < 20


# --- settling ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_still_drifting_dwell_is_unsettled(noise):
    """A force transient decaying with a 20-period time constant across a 100-period dwell (0.7 % at its end)."""
    force, base = _dwell(2560.0, 12.0, 100 / 12.0, noise=noise, rng=np.random.default_rng(2), force_transient=1.0,
                         transient_periods=20.0)
    result = analyse_dwell(force, base, 2560.0, 12.0, quantity="acceleration")
    assert isinstance(result, Unsettled)
    assert result.reason.startswith("dwell at 12 Hz: ") and ("not settled" in result.reason
                                                             or "drifting" in result.reason)
    assert result.settled_windows < 10


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_transient_in_the_first_third_is_left_out(noise):
    """A 50 % transient decaying over 4 periods in a 150-period dwell: settled after ~22 periods (0.2 %)."""
    rng = np.random.default_rng(3)
    force, base = _dwell(2560.0, 9.0, 150 / 9.0, noise=noise, rng=rng, force_transient=0.5, transient_periods=4.0)
    line = analyse_dwell(force, base, 2560.0, 9.0, quantity="acceleration")
    assert isinstance(line, DwellLine), line
    assert 16 <= line.used_start_s * 9.0 <= 50
    if noise:
        assert abs(math.log(abs(line.h / H_TRUE))) < 4 * line.se_logmag
    else:
        assert abs(line.h / H_TRUE - 1) < 1e-6


def test_noise_does_not_unsettle_a_settled_dwell():
    rng = np.random.default_rng(4)
    for i in range(60):
        f = float(rng.uniform(4.0, 40.0))
        force, base = _dwell(2560.0, f, float(rng.uniform(50, 400)) / f, noise=(0.01, 0.1, 0.5)[i % 3], rng=rng)
        assert isinstance(analyse_dwell(force, base, 2560.0, f, quantity="acceleration"), DwellLine)


def test_too_short_dwell():
    force, base = _dwell(2560.0, 12.0, 3.1)
    result = analyse_dwell(force, base, 2560.0, 12.0, quantity="acceleration")
    assert result == Unsettled("dwell at 12 Hz: 3.1 s holds 37 periods, 40 needed", 0, 12.0)


def test_non_finite_samples_and_no_base_motion():
    force, base = _dwell(2560.0, 12.0, 5.0)
    force[1000] = np.nan
    result = analyse_dwell(force, base, 2560.0, 12.0, quantity="acceleration")
    assert result.reason == "dwell at 12 Hz: force sample 1000 at 0.3906 s is not finite"
    result = analyse_dwell(np.ones(20000), np.zeros(20000), 2560.0, 12.0, quantity="acceleration")
    assert "no base motion" in result.reason


def test_taper_at_the_end_of_the_drive_is_left_out():
    """The base tapered to zero over the last 2 periods (the force with it), as a stepped sine ends a dwell."""
    rate, f = 2560.0, 8.0
    force, base = _dwell(rate, f, 12.0)
    t = np.arange(force.size) / rate
    end = t[-1] - 2 / f
    env = np.clip(1 - (t - end) * f / 2, 0, 1)
    line = analyse_dwell((force - 3.0 - 0.2 * t) * env, base * env, rate, f, quantity="acceleration")
    assert isinstance(line, DwellLine), line
    assert abs(line.h / H_TRUE - 1) < 1e-6


# --- finding dwells ----------------------------------------------------------------------------------------------

def _stepped(rate, freqs, seconds, pause, rng, noise):
    """A stepped sine: base acceleration (1 mm, 3rd harmonic 20 %, an offset, white noise) and force, dwells
    separated by pauses of zero drive, each ramped up from rest over 8 periods (or, pause 0, phase-continuous
    steps); the drive-frequency channel."""
    scale = (2 * np.pi * 4.0) ** 2 * 1e-3
    base, force, drive, truth, phase = [], [], [], [], 0.0
    n = 0
    for k, (f, s) in enumerate(zip(freqs, seconds)):
        if pause:
            m = round(pause * rate)
            base.append(np.zeros(m)), force.append(np.zeros(m)), drive.append(np.zeros(m))
            n += m
        m = round(s * rate)
        w = 2 * np.pi * f
        theta = phase + w * np.arange(m) / rate
        # displacement 1 mm env(t) cos(theta), env a smoothstep over 8 periods: acceleration (env'' - env w^2) cos
        # - 2 env' w sin (a ramp's crossings are not periodic)
        u = np.clip(np.arange(m) / rate * f / 8, 0, 1) if pause else np.ones(m)
        env, d1, d2 = 3 * u**2 - 2 * u**3, (6 * u - 6 * u**2) * f / 8, (6 - 12 * u) * (f / 8) ** 2 * (u < 1)
        base.append(1e-3 * ((d2 - env * w * w) * np.cos(theta) - 2 * d1 * w * np.sin(theta)
                            - 0.2 * env * w * w * np.cos(3 * theta)))
        h = 2e4 * (1 + 0.05 * k) * np.exp(1j * (0.2 + 0.03 * k))
        force.append(env * (h * 1e-3 * np.exp(1j * theta)).real)
        drive.append(np.full(m, f))
        truth.append((n, n + m, f, h))
        n += m
        phase = 0.0 if pause else theta[-1] + 2 * np.pi * f / rate
    base, force, drive = (np.concatenate(v) for v in (base, force, drive))
    base += 0.05 * scale + noise * scale * rng.standard_normal(n)
    force += 1.0 + noise * 20.0 * rng.standard_normal(n)
    return base, force, drive, truth


@pytest.mark.parametrize("rate", [2560.0, 10000.0])
@pytest.mark.parametrize("pause", [0.0, 0.25, 0.5])
def test_dwells_found_in_the_signal(rate, pause):
    rng = np.random.default_rng(int(rate + 100 * pause))
    freqs = np.exp(rng.permutation(np.linspace(np.log(4), np.log(40), 5)) + rng.uniform(-0.05, 0.05, 5))
    freqs = np.repeat(freqs, 2) * np.tile([1.0, 1.03], 5)             # steps of 3 % too
    base, force, _, truth = _stepped(rate, freqs, rng.uniform(4.0, 8.0, freqs.size), pause, rng, 0.05)
    calls = []

    def read(a, b):
        calls.append(b - a)
        return base[a:b]

    found = dwells_from_signal(read, base.size, rate, chunk=2**16)
    assert max(calls) < 2**16 + 2 * 4 * rate                         # streamed
    assert len(found) == len(truth)
    for d, (start, stop, f, h) in zip(found, truth):
        period = rate / f
        assert d.freq_hz is None and abs(d.estimate_hz / f - 1) < 2e-3
        assert start <= d.start <= start + (12 if pause else 4.5) * period   # a ramp of 8 periods
        assert stop - 4 * period <= d.stop <= stop + 0.05 * period      # not into the pause or the next dwell
        if d.stop - d.start >= 44 * period:
            line = analyse_dwell(force[d.start:d.stop], base[d.start:d.stop], rate, None,
                                 quantity="acceleration", freq_guess_hz=d.estimate_hz)
            assert isinstance(line, DwellLine), line
            assert abs(line.freq_hz / f - 1) < 1e-4
            assert abs(math.log(abs(line.h / (-h)))) < 5 * line.se_logmag + 1e-6
    again = dwells_from_signal(lambda a, b: base[a:b], base.size, rate, chunk=2**20)
    assert [(d.start, d.stop) for d in again] == [(d.start, d.stop) for d in found]
    assert [d.estimate_hz for d in again] == pytest.approx([d.estimate_hz for d in found], rel=1e-12)


def test_dwells_from_channel_and_steps():
    rate = 1000.0
    drive = np.concatenate([np.zeros(300), np.full(5000, 4.0), [7.3], np.full(4000, 12.5), np.full(3000, 12.6),
                            np.full(200, np.nan), np.full(3000, 40.0)])
    found = dwells_from_channel(lambda a, b: drive[a:b], drive.size, rate, chunk=777)
    assert [(d.start, d.stop, d.freq_hz) for d in found] == [
        (300, 5300, 4.0), (5301, 9301, 12.5), (9301, 12301, 12.6), (12501, 15501, 40.0)]
    steps = dwells_from_steps([0.0, 1.0, 2.5, 9.0], [4.0, 0.0, 7.0, 8.0], 5000, rate)
    assert [(d.start, d.stop, d.freq_hz) for d in steps] == [(0, 1000, 4.0), (2500, 5000, 7.0), (5000, 5000, 8.0)]


# --- clipping ----------------------------------------------------------------------------------------------------

def test_clipping():
    rate, f, full = 10000.0, 4.0, 10.0
    t = np.arange(round(2.0 * rate)) / rate
    lsb = 2 * full / 2**16
    small = np.round(0.01 * full * np.sin(2 * np.pi * f * t + 0.3) / lsb) * lsb      # 1 % of full scale, 16 bit
    assert clipped(small, rate, f, full_scale=full) is None
    sine = 0.5 * full * np.sin(2 * np.pi * f * t + 0.3)
    cut = np.clip(sine, -0.95 * 0.5 * full, 0.95 * 0.5 * full)
    assert clipped(cut, rate, f) == int(np.flatnonzero(np.abs(sine) >= 0.95 * 0.5 * full)[0])
    assert clipped(np.clip(sine * 3, -full, full), rate, f, full_scale=full) is not None
    assert clipped(sine, rate, f, full_scale=full) is None
