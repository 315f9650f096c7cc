"""The line of one dwell (``docs/import.md``, "How lines are computed"): whole-period windows fitted by least
squares, where the dwell has settled, the first harmonics of force and base displacement, their ratio's standard
error from the period-to-period variation, the force's distortion; and the clipping check of a channel.

Pure signal processing on SI arrays, no file I/O. Each window of whole drive periods is fitted by least squares
over its own sample times with a constant, a linear drift and the harmonics below 0.45 x the sampling rate; the
first harmonics of the windows tell where the dwell has settled, and the settled windows give the line (the ratio
of the mean force and displacement harmonics), its standard error (batch means over 10-40 batches of windows) and
the force's distortion.

Phase convention: ``x(t) = Re(X exp(+i w t))``, ``t`` from the dwell's first sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import linalg, stats

from .units import BASE_QUANTITIES

__all__ = ["DwellLine", "EDGE_EPS", "Unsettled", "analyse_dwell", "clipped"]

_NYQUIST_USE = 0.45       # harmonics up to 0.45 fs: a DAS's anti-alias filter attenuates above that
_MAX_BATCHES = 40         # batch means: 10-40 batches keep the t quantile near 2 and catch slow wander
_USE_FLOOR = 1e-3         # the used part: within this x settle_tolerance of the level (or c sigma) ...
_DRIFT_ALPHA = 2.7e-3     # two-sided level of the drift test per component (3 sigma) ...
_LEAD_SIGMAS = 2.0        # leading settled windows farther than this from the level are not used
_USE_ALPHA = 1.2e-2       # ... and for the windows used (2.5 sigma): a drift hidden by 3 sigma is up to 10 SE
_BAND_ALPHA = 5e-3        # chance, per dwell and component, that noise alone puts a window outside the band
_TAPER = 0.02             # a trailing fall of the base amplitude by more than 2 % is the drive tapering off
_CHUNK_ELEMENTS = 2**20   # windows gathered per matrix product: 8 MB
EDGE_EPS = 1e-7           # [samples] a sample this close before a window edge counts as on it
_COARSE_SAMPLES = 2**18   # the base's last samples whose spectrum gives the first frequency guess


@dataclass(frozen=True)
class DwellLine:
    """The line one settled dwell gives.

    Attributes
    ----------
    freq_hz : float
        The frequency used [Hz]: the nominal one, or the estimate refined from the base's phase drift.
    h : complex
        ``F1 / X1`` [N/m].
    x1 : complex
        First harmonic of the base displacement [m] (amplitude; ``2 |x1|`` is peak to peak).
    f1 : complex
        First harmonic of the force [N].
    se_logmag : float
        Standard error of ``ln |h|`` (a relative error), from the variation between the ``windows``
        batches of settled periods.
    se_phase : float
        Standard error of the phase of ``h`` [rad].
    windows : int
        Batches K behind the standard errors (Student t with K - 1 degrees of freedom).
    distortion : float
        The force's harmonic distortion ``sqrt(sum_{k=2..H} |F_k|^2) / |F_1|``.
    settled_s : float
        Time from the dwell's start to its first settled window [s].
    used_s : float
        Duration analysed [s]: ``windows * window_periods`` periods.
    used_start_s : float
        Time from the dwell's start to the first window used [s] (>= ``settled_s``).
    window_periods : int
        Periods per batch (the requested window, scaled up on long dwells to keep K <= 40).
    harmonics : int
        H: the harmonics fitted (those below 0.45 x the sampling rate, at most the requested number).
    """

    freq_hz: float
    h: complex
    x1: complex
    f1: complex
    se_logmag: float
    se_phase: float
    windows: int
    distortion: float
    settled_s: float
    used_s: float
    used_start_s: float
    window_periods: int
    harmonics: int


@dataclass(frozen=True)
class Unsettled:
    """A dwell that gives no line, and why.

    Attributes
    ----------
    reason : str
        One line, starting ``dwell at F Hz:``.
    settled_windows : int
        Windows found settled (fewer than needed; 0 where none were judged).
    freq_hz : float or None
        The frequency [Hz] the dwell was analysed at, if known.
    """

    reason: str
    settled_windows: int
    freq_hz: float | None = None


# --- window fits ---------------------------------------------------------------------------------------------------

def _window_edges(n: int, period_samples: float, periods: int) -> np.ndarray:
    """Sample edges of the windows of ``periods`` whole periods: window k holds the samples with
    ``k periods T <= t < (k + 1) periods T``."""
    span = periods * period_samples
    n_win = int(math.floor((n + EDGE_EPS) / span))
    return np.ceil(np.arange(n_win + 1) * span - EDGE_EPS).astype(np.int64)


def _basis(length: int, period_samples: float, n_harm: int) -> np.ndarray:
    """Columns 1, a centred ramp, cos and sin of harmonics 1..n_harm over samples 0..length-1; shape
    (length, 2 + 2 n_harm)."""
    j = np.arange(length, dtype=float)
    basis = np.empty((length, 2 + 2 * n_harm))
    basis[:, 0] = 1.0
    basis[:, 1] = (j - 0.5 * (length - 1)) / length
    cycles = np.outer(j, np.arange(1, n_harm + 1)) / period_samples
    phase = 2 * np.pi * (cycles - np.floor(cycles))            # reduced first: exact phases for long windows
    basis[:, 2::2], basis[:, 3::2] = np.cos(phase), np.sin(phase)
    return basis


def _fit_windows(signals: list[np.ndarray], period_samples: float, periods: int,
                 n_harm: int) -> tuple[np.ndarray, np.ndarray]:
    """Harmonics of each whole-period window of each signal, by least squares over its own samples.

    Every window is fitted in its local sample index with one basis (windows differ in length by at most one
    sample: two Gram matrices); the complex amplitudes are then turned to the dwell's time origin.

    Returns
    -------
    harmonics : ndarray of complex, shape (n_signals, n_windows, n_harm)
        ``X_k`` of ``Re(X_k exp(i k w t))``, ``t`` from the signals' first sample.
    edges : ndarray of int, shape (n_windows + 1,)
        Window edges [samples].
    """
    n = signals[0].size
    edges = _window_edges(n, period_samples, periods)
    starts, lengths = edges[:-1], np.diff(edges)
    l_max = int(lengths.max())
    basis = _basis(l_max, period_samples, n_harm)
    ncol = basis.shape[1]
    proj = np.empty((len(signals), starts.size, ncol))
    rows = max(1, _CHUNK_ELEMENTS // l_max)
    inside = int(np.searchsorted(starts, n - l_max, side="right"))   # windows whose l_max samples exist
    for s, x in enumerate(signals):
        view = sliding_window_view(x, l_max)
        for lo in range(0, inside, rows):
            hi = min(inside, lo + rows)
            np.matmul(view[starts[lo:hi]], basis, out=proj[s, lo:hi])
        for k in range(inside, starts.size):
            proj[s, k] = x[starts[k]:edges[k + 1]] @ basis[:lengths[k]]
    coef = np.empty_like(proj)
    for length in np.unique(lengths):
        sel = np.flatnonzero(lengths == length)
        if length < l_max:            # the one sample beyond a shorter window came along in the product
            extra = sel[sel < inside]
            for s, x in enumerate(signals):
                proj[s, extra] -= sliding_window_view(x, l_max - length)[starts[extra] + length] @ basis[length:]
        gram = linalg.cho_factor(basis[:length].T @ basis[:length])
        coef[:, sel] = linalg.cho_solve(gram, proj[:, sel].reshape(-1, ncol).T).T.reshape(len(signals), -1, ncol)
    local = coef[..., 2::2] - 1j * coef[..., 3::2]
    turns = np.outer(starts, np.arange(1, n_harm + 1)) / period_samples
    return local * np.exp(-2j * np.pi * (turns - np.floor(turns))), edges


# --- settling ------------------------------------------------------------------------------------------------------

def _noise_sd(v: np.ndarray) -> tuple[float, float]:
    """Window-to-window noise of a series and its degrees of freedom, from its second differences.

    Second differences are blind to a level and a linear drift and see a slow curve hardly at all; those
    beyond 5 MAD of their median (a transient, a glitch) are left out and the rest give an RMS (efficient
    where a MAD alone is not: a band of 4 sigma from the MAD of 20 windows is often 2 sigma)."""
    d = v[2:] - 2 * v[1:-1] + v[:-2]
    d = d[np.isfinite(d)]
    if d.size < 2:
        return 0.0, 1.0
    dev = np.abs(d - np.median(d))
    d = d[dev <= 5 * 1.4826 * np.median(dev)]
    if d.size < 2:
        return 0.0, 1.0
    # white noise: var(d) = 6 sigma^2; d is MA(2) (correlations -2/3, 1/6), which halves its dof
    return float(np.sqrt(np.mean(d * d) / 6)), max(1.0, d.size / 1.94)


@dataclass(frozen=True)
class _Settling:
    start: int          # first settled window
    stop: int           # one past the last window analysed (a trailing taper of the drive left out)
    use: int            # first window used for the line
    reason: str         # "" when settled


def _settle(h: np.ndarray, amp: np.ndarray, tol: float, min_windows: int, periods: int) -> _Settling:
    """Where the windows' ``h`` has settled.

    The drive's end: trailing windows whose base amplitude fell by more than 2 % (or 4 sigma) below the dwell's
    median are a taper, left out. Settled: from some window to that end, ``ln h`` within max(tol, c sigma) of its
    level (c: the t quantile that noise alone exceeds in one window of the dwell with chance 0.5 %) and no drift
    beyond max(tol, q se) (3 sigma). Used for the line: the settled windows that also pass with a floor of
    0.1 % of tol and a 2.5-sigma drift test, without leading windows beyond 2 sigma (where at least
    ``min_windows`` remain): a transient's tail hidden in the tolerance would bias the line beyond its SE.
    """
    n = h.size
    with np.errstate(divide="ignore", invalid="ignore"):
        la = np.log(amp)
    stop = n
    finite = np.isfinite(la)
    if finite.any():
        plateau = float(np.median(la[finite]))
        fall = max(_TAPER, 4 * _noise_sd(la[finite])[0])
        while stop > 0 and not la[stop - 1] >= plateau - fall:
            stop -= 1
    if stop < min_windows:
        what = "no base motion at the dwell frequency" if not finite.any() else (
            f"the drive falls off: {stop} windows of {periods} periods before it does, {min_windows} needed")
        return _Settling(stop, stop, stop, what)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.log(h[:stop] / h[stop - 1])
    zs = (z.real, z.imag)
    noise = [_noise_sd(v) for v in zs]
    # white noise scatters ln|h| and the phase alike: neither is taken below their pool (one estimate from 20
    # windows is low by half a few times in a thousand)
    pooled = math.sqrt(0.5 * (noise[0][0] ** 2 + noise[1][0] ** 2))
    sd = [max(s, pooled) for s, _ in noise]
    dof = min(d for _, d in noise)
    # the band's t quantile (the sd is itself estimated): noise alone leaves a window outside with chance
    # _BAND_ALPHA per dwell
    c = max(4.0, float(stats.t.isf(_BAND_ALPHA / 2 / stop, dof)))

    def first_inside(lo: int, level: list[float], band: list[float]) -> int:
        """The first window >= lo after the last one outside the band about level."""
        with np.errstate(invalid="ignore"):
            out = ~((np.abs(zs[0] - level[0]) <= band[0]) & (np.abs(zs[1] - level[1]) <= band[1]))
        bad = np.flatnonzero(out[lo:])
        return lo + int(bad[-1]) + 1 if bad.size else lo

    def steady(lo: int, floor: float, alpha: float) -> tuple[int, list[float] | None]:
        """First window of the steady end from lo on; the drift left (None if none) when too few remain."""
        q = float(stats.t.isf(alpha / 2, dof))
        band = [max(floor, c * s) for s in sd]
        level = [float(np.median(v[stop - min_windows:stop])) for v in zs]
        start = first_inside(lo, level, band)
        if stop - start >= 2:   # again about the median of all of it (a transient's tail would pull a mean)
            start = first_inside(lo, [float(np.median(v[start:stop])) for v in zs], band)
        while stop - start >= min_windows:   # drop early windows while the steady part still drifts
            m = stop - start
            k = np.arange(m) - 0.5 * (m - 1)
            change = [float(k @ v[start:stop]) / float(k @ k) * (m - 1) for v in zs]
            if all(abs(d) <= max(floor, q * s * math.sqrt(12 * (m - 1) / (m * (m + 1))))
                   for d, s in zip(change, sd)):
                return start, None
            if m - max(1, m // 10) < min_windows:
                return start, change
            start += max(1, m // 10)
        return start, None

    start, drift = steady(0, tol, _DRIFT_ALPHA)
    if drift is not None:
        return _Settling(start, stop, start, (
            f"still drifting: ln|h| changes by {100 * drift[0]:+.2g} % and the phase by "
            f"{math.degrees(drift[1]):+.2g} deg over the last {stop - start} windows of {periods} periods"))
    if stop - start < min_windows:
        band = [max(tol, c * s) for s in sd]
        return _Settling(start, stop, start, (
            f"not settled: h stays within {100 * band[0]:.2g} % and {math.degrees(band[1]):.2g} deg of its final "
            f"value over the last {stop - start} windows of {periods} periods only, {min_windows} needed"))
    use, drift = steady(start, _USE_FLOOR * tol, _USE_ALPHA)
    if drift is not None or stop - use < min_windows:
        use = start
    # and the leading windows still beyond 2 sigma: a transient's tail inside the band would bias the line by
    # up to 4 sigma / n, more than its SE; noise alone costs a tenth of a window on average
    level = [float(np.median(v[use:stop])) for v in zs]
    while stop - use > min_windows and any(abs(v[use] - lv) > max(_USE_FLOOR * tol, _LEAD_SIGMAS * s)
                                           for v, lv, s in zip(zs, level, sd)):
        use += 1
    return _Settling(start, stop, use, "")


# --- one dwell -----------------------------------------------------------------------------------------------------

def _coarse_frequency(x: np.ndarray, rate_hz: float) -> float | None:
    """The strongest spectral line of the signal's last samples (Hann window, interpolated) [Hz]."""
    seg = x[-min(x.size, _COARSE_SAMPLES):]
    if seg.size < 16:
        return None
    t = np.arange(seg.size) - 0.5 * (seg.size - 1)
    seg = seg - seg.mean() - t * (t @ seg) / (t @ t)      # a sensor's offset and drift off the low bins
    spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size)))
    if spec.size < 5 or not np.any(spec[2:-1] > 0):
        return None
    k = 2 + int(np.argmax(spec[2:-1]))
    a, b, c = spec[k - 1], spec[k], spec[k + 1]
    delta = 2 * (c - a) / (a + 2 * b + c)       # exact for one tone under a Hann window (+-0.5 bin)
    return float((k + delta) * rate_hz / seg.size)


def _first_bad(x: np.ndarray) -> int | None:
    """Index of the first NaN or infinite sample."""
    bad = np.flatnonzero(~np.isfinite(x))
    return int(bad[0]) if bad.size else None


def analyse_dwell(force, base, rate_hz: float, freq_hz: float | None, *, quantity: str, window_periods: int = 4,
                  min_windows: int = 10, settle_tolerance: float = 2e-3, harmonics: int = 9,
                  freq_guess_hz: float | None = None) -> DwellLine | Unsettled:
    """The line of one dwell: first harmonics over its settled whole periods, their standard error, the force's
    distortion.

    Parameters
    ----------
    force : array_like, shape (n,)
        Force [N] (the load cells summed), one dwell.
    base : array_like, shape (n,)
        Base motion of the same samples, in its ``quantity``: acceleration [m/s^2], velocity [m/s] or
        displacement [m].
    rate_hz : float
        Sampling rate [Hz].
    freq_hz : float or None
        The drive frequency [Hz]; None: estimated from the base (its spectrum's peak, then refined from the
        drift of the base's phase across the settled windows).
    quantity : {"acceleration", "velocity", "displacement"}
        What ``base`` measures.
    window_periods : int
        Whole periods per window (settling is judged window by window).
    min_windows : int
        Settled windows a dwell needs.
    settle_tolerance : float
        Band about the settled ``ln h`` (relative magnitude and radians) a settled window stays in, widened to
        ~4-5x the window-to-window noise where that is larger.
    harmonics : int
        Harmonics fitted (those up to 0.45 x ``rate_hz``); the distortion is over harmonics 2..H.
    freq_guess_hz : float, optional
        A first guess where ``freq_hz`` is None (:attr:`Dwell.estimate_hz`), instead of the spectrum's peak.

    Returns
    -------
    DwellLine or Unsettled
        Unsettled where the dwell is too short, holds non-finite samples, has no base motion, or has fewer than
        ``min_windows`` settled windows (still settling or drifting).
    """
    if quantity not in BASE_QUANTITIES:
        raise ValueError(f"quantity: expected one of {', '.join(BASE_QUANTITIES)}, got {quantity!r}")
    if window_periods < 1 or min_windows < 2:
        raise ValueError("window_periods must be >= 1 and min_windows >= 2")
    force = np.ascontiguousarray(force, dtype=float)
    base = np.ascontiguousarray(base, dtype=float)
    if force.shape != base.shape or force.ndim != 1:
        raise ValueError("force and base must be 1-D arrays of one length")
    f = freq_hz if freq_hz is not None else freq_guess_hz
    where = f"dwell at {f:.4g} Hz" if f else "dwell"
    for name, x in (("force", force), ("base", base)):
        i = _first_bad(x)
        if i is not None:
            return Unsettled(f"{where}: {name} sample {i} at {i / rate_hz:.4g} s is not finite", 0, f)
    need = min_windows * window_periods

    def short(f: float) -> Unsettled | None:
        held = force.size * f / rate_hz
        if held >= need:
            return None
        return Unsettled(f"dwell at {f:.4g} Hz: {force.size / rate_hz:.3g} s holds {math.floor(held)} periods, "
                         f"{need} needed", 0, f)

    if f is not None and (too_short := short(f)):
        return too_short
    if force.size == 0 or not np.any(base != base[0]):
        return Unsettled(f"{where}: no base motion", 0, f)
    if f is None:
        f = _coarse_frequency(base, rate_hz)
        if f is None or f <= 0:
            return Unsettled(f"{where}: no drive frequency found in the base signal", 0, None)
        where = f"dwell at {f:.4g} Hz"
        if too_short := short(f):
            return too_short
    # harmonics below 0.45 fs, and a window of at least twice as many samples as fitted columns
    n_harm = min(harmonics, math.floor(_NYQUIST_USE * rate_hz / f),
                 math.floor(window_periods * rate_hz / f / 4 - 1))
    if n_harm < 1:
        return Unsettled(f"{where}: {window_periods} periods hold {window_periods * rate_hz / f:.3g} samples at "
                         f"{rate_hz:.6g} Hz, too few for a fit", 0, f)
    for _ in range(4 if freq_hz is None else 1):
        f_fit = f
        spectra, edges = _fit_windows([force, base], rate_hz / f, window_periods, n_harm)
        b1 = spectra[1, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            h = spectra[0, :, 0] / b1
        st = _settle(h, np.abs(b1), settle_tolerance, min_windows, window_periods)
        if st.reason:
            return Unsettled(f"{where}: {st.reason}", st.stop - st.start, f)
        if freq_hz is not None:
            break
        # the base's phase turns at 2 pi (f_true - f) across the windows: the frequency's correction
        centre = 0.5 * (edges[st.use:st.stop] + edges[st.use + 1:st.stop + 1]) / rate_hz
        phase = np.unwrap(np.angle(b1[st.use:st.stop]))
        slope = np.polyfit(centre - centre.mean(), phase, 1)[0]
        f_new = f + slope / (2 * np.pi)
        if abs(f_new - f) * (centre[-1] - centre[0]) < 1e-7:     # phase slip across the dwell < 1e-7 cycle
            break
        f = f_new
    return _line(spectra, st, f_fit, quantity, window_periods)


def _line(spectra: np.ndarray, st: _Settling, f: float, quantity: str, window_periods: int) -> DwellLine:
    """The line from the settled windows: ratio of mean harmonics, batch-means standard errors, distortion."""
    n_used = st.stop - st.use
    per = 1 if n_used <= _MAX_BATCHES else math.ceil(n_used / _MAX_BATCHES)
    k = n_used // per
    first = st.stop - k * per                                    # the few windows left over: the earliest
    batches = spectra[:, first:st.stop].reshape(spectra.shape[0], k, per, -1).mean(axis=2)
    mean = batches.mean(axis=1)                                  # (2, n_harm)
    f1, b1 = mean[0, 0], mean[1, 0]
    # delta method for the ratio of means: d ln h = dF/F - dB/B, per batch
    u = batches[0, :, 0] / f1 - batches[1, :, 0] / b1
    se = np.std(np.stack([u.real, u.imag]), axis=1, ddof=1) / math.sqrt(k)
    w = 2 * np.pi * f
    x1 = {"acceleration": b1 / -(w * w), "velocity": b1 / (1j * w), "displacement": b1}[quantity]
    distortion = math.sqrt(float(np.sum(np.abs(mean[0, 1:]) ** 2))) / float(abs(f1))
    period_s = 1.0 / f
    return DwellLine(freq_hz=float(f), h=complex(f1 / x1), x1=complex(x1), f1=complex(f1),
                     se_logmag=float(se[0]), se_phase=float(se[1]), windows=int(k), distortion=distortion,
                     settled_s=st.start * window_periods * period_s,
                     used_s=k * per * window_periods * period_s,
                     used_start_s=first * window_periods * period_s,
                     window_periods=per * window_periods, harmonics=int(spectra.shape[2]))


# --- clipping ------------------------------------------------------------------------------------------------------

_FULL_SCALE_MARGIN = 2.0**-14     # an ADC's top code is full scale less one LSB: 2^-15 of it at 16 bits


def clipped(x, rate_hz: float, freq_hz: float, full_scale: float | None = None) -> int | None:
    """The first clipped sample of a sine-driven signal, or None.

    A run of samples at the record's maximum (or minimum) value longer than 1.5 x the plateau the top of a
    sampled, quantised sine of this amplitude and frequency can hold (``2 sqrt(2 q / A) fs / w`` samples, ``q``
    the quantum seen near the extremes) is clipped; so is ``|x| >= full_scale`` (less 2^-14) when given.

    Parameters
    ----------
    x : array_like, shape (n,)
        The channel as stored (before summing channels: the quantum is the ADC's).
    rate_hz, freq_hz : float
        Sampling rate and drive frequency [Hz].
    full_scale : float, optional
        The ADC's range in the same units.

    Returns
    -------
    int or None
        Index of the first clipped sample.
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return None
    first = []
    if full_scale is not None:
        over = np.flatnonzero(np.abs(x) >= full_scale * (1 - _FULL_SCALE_MARGIN))
        first += over[:1].tolist()
    top, bottom = float(np.max(x)), float(np.min(x))
    amp = 0.5 * (top - bottom)
    if amp > 0:
        near = x[(x >= top - 0.02 * amp) | (x <= bottom + 0.02 * amp)]
        steps = np.diff(np.unique(near))
        q = float(steps.min()) if steps.size else 0.0
        allowed = 1.5 * 2 * math.sqrt(2 * q / amp) * rate_hz / (2 * np.pi * freq_hz) + 2
        for value in (top, bottom):
            at = np.concatenate(([False], x == value, [False])).astype(np.int8)
            d = np.diff(at)
            run_start, run_stop = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
            long = np.flatnonzero(run_stop - run_start > allowed)
            first += run_start[long[:1]].tolist()
    return int(min(first)) if first else None
