"""The dwells of a stepped-sine recording (``docs/import.md``, "How lines are computed"): where each drive
frequency starts and ends, from a step table, a commanded-frequency channel or the base signal itself (streamed
through a ``read(start, stop)`` callable, so a long record is never held whole). Each dwell's line is
:func:`sbcal.data.acquisition.lines.analyse_dwell`'s.

Pure signal processing on SI arrays, no file I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .lines import EDGE_EPS  # the same rule for a step's first sample as for a window's

__all__ = ["Dwell", "dwells_from_channel", "dwells_from_signal", "dwells_from_steps"]

_MAX_JITTER = 0.05        # cycles of one dwell differ by less than 5 %
_RAMP_CYCLES, _RAMP_REL, _RAMP_MIN = 16, 0.05, 1e-3   # a ramp of the drive: fewer cycles, within 5 % of the dwell,
                                                      # its periods converging to the dwell's by 0.1 % at least


@dataclass(frozen=True)
class Dwell:
    """One dwell: samples ``[start, stop)`` of a block at one drive frequency.

    Attributes
    ----------
    start, stop : int
        Sample indices in the block.
    freq_hz : float or None
        The nominal frequency [Hz]; None: estimate it from the base signal (:func:`analyse_dwell`).
    estimate_hz : float or None
        A first estimate [Hz] where the dwell was found in the signal (:func:`dwells_from_signal`).
    """

    start: int
    stop: int
    freq_hz: float | None
    estimate_hz: float | None = None


# --- finding dwells ------------------------------------------------------------------------------------------------

def dwells_from_steps(starts_s, freqs_hz, n_samples: int, rate_hz: float) -> list[Dwell]:
    """Dwells of a step table: each step from its start to the next one's (the last to the block's end).

    Parameters
    ----------
    starts_s : array_like, shape (n_steps,)
        Start of each step [s] from the block's first sample, increasing.
    freqs_hz : array_like, shape (n_steps,)
        Drive frequency of each step [Hz]; 0 (shaker off) gives no dwell.
    n_samples : int
        Samples in the block.
    rate_hz : float
        Sampling rate [Hz].

    Returns
    -------
    list of Dwell
        One per step with a positive frequency, clipped to the block: a step past the block's end is an
        empty dwell, which :func:`analyse_dwell` reports as too short.
    """
    starts = np.asarray(starts_s, dtype=float)
    freqs = np.asarray(freqs_hz, dtype=float)
    if starts.shape != freqs.shape or starts.ndim != 1:
        raise ValueError("starts_s and freqs_hz must be 1-D and of one length")
    if np.any(np.diff(starts) <= 0):
        raise ValueError("step starts must increase")
    edges = np.ceil(np.append(starts, np.inf) * rate_hz - EDGE_EPS)
    edges = np.clip(edges, 0, n_samples).astype(np.int64)
    return [Dwell(int(edges[k]), int(edges[k + 1]), float(freqs[k])) for k in range(freqs.size) if freqs[k] > 0]


def dwells_from_channel(read: Callable[[int, int], np.ndarray], n_samples: int, rate_hz: float,
                        chunk: int = 2**20, *, rel_change: float = 1e-3) -> list[Dwell]:
    """Dwells from a commanded-frequency channel: runs of one value.

    Parameters
    ----------
    read : callable
        ``read(start, stop)`` returns the channel's samples ``[start, stop)`` [Hz]; called chunk by chunk.
    n_samples : int
        Samples in the channel.
    rate_hz : float
        Sampling rate [Hz].
    chunk : int
        Samples read at a time.
    rel_change : float
        A change from one sample to the next by more than this fraction starts a new dwell.

    Returns
    -------
    list of Dwell
        Runs of positive finite values (0 or NaN: shaker off), each at its mean value; runs shorter than one
        period of their own frequency (transition samples) are not dwells.
    """
    dwells: list[Dwell] = []
    run = [-1, 0.0, math.inf, -math.inf]   # the open run: start (-1: none), sum, smallest and largest value
    prev = math.nan                        # the last sample read

    def close(stop: int) -> None:
        start, total, low, high = run
        if start >= 0:
            f = low if low == high else total / (stop - start)     # a commanded value exactly, else the mean
            if (stop - start) * f >= rate_hz:
                dwells.append(Dwell(start, stop, float(f)))

    for lo in range(0, n_samples, chunk):
        v = np.asarray(read(lo, min(n_samples, lo + chunk)), dtype=float)
        on = np.isfinite(v) & (v > 0)
        before = np.concatenate(([prev], v[:-1]))
        on_before = np.isfinite(before) & (before > 0)
        with np.errstate(invalid="ignore"):
            jump = on & on_before & (np.abs(v - before) > rel_change * np.abs(before))
        edges = np.append(np.flatnonzero((on != on_before) | jump), v.size)
        last = 0
        for i in edges:
            if i > last and run[0] >= 0:
                part = v[last:i]
                run[1] += float(part.sum())
                run[2], run[3] = min(run[2], float(part.min())), max(run[3], float(part.max()))
            if i < v.size:
                close(lo + i)
                run[:] = [lo + i if on[i] else -1, 0.0, math.inf, -math.inf]
            last = i
        prev = v[-1] if v.size else prev
    close(n_samples)
    return dwells


def dwells_from_signal(read: Callable[[int, int], np.ndarray], n_samples: int, rate_hz: float,
                       chunk: int = 2**20, *, min_freq_hz: float = 2.0, max_freq_hz: float = 100.0,
                       rel_change: float = 5e-3, min_cycles: int = 6) -> list[Dwell]:
    """Dwells of a stepped sine found in the base signal: runs of cycles of one period.

    The signal, smoothed by a moving average over a quarter of the shortest period, crosses its mid level (the
    sensor's offset) upwards once a cycle: a Schmitt trigger at +-half the local amplitude, the crossing time
    from a straight line through the samples between the two thresholds. Consecutive cycles of one period
    (within ``rel_change``, widened to 5 x the local period jitter, at most 5 %; the mean of the last 8 periods
    checked too) form a dwell; at its ends, crossings off the straight line through the others are left out,
    and one more cycle (the one a step may fall in). Pauses (no drive) give no or erratic crossings and end a
    dwell; so does a step.

    Parameters
    ----------
    read : callable
        ``read(start, stop)`` returns the base channel's samples ``[start, stop)``; called chunk by chunk
        (each chunk with a margin of about ``1 / min_freq_hz + 3`` s on both sides).
    n_samples : int
        Samples in the channel.
    rate_hz : float
        Sampling rate [Hz].
    chunk : int
        Samples per chunk.
    min_freq_hz, max_freq_hz : float
        Range of the drive frequencies [Hz] (the envelope's span; the smoothing, which passes 90 % of a sine at
        ``max_freq_hz``).
    rel_change : float
        Periods within this fraction are one frequency.
    min_cycles : int
        Fewest cycles of one period that make a dwell (an analysable one needs ``min_windows x window_periods``).

    Returns
    -------
    list of Dwell
        From a rising crossing to the dwell's last one, ``freq_hz=None`` (estimated in :func:`analyse_dwell`)
        and ``estimate_hz`` the mean frequency of its last two thirds of cycles [Hz].
    """
    block = max(1, round(0.05 * rate_hz))                     # envelope blocks of 50 ms
    reach = math.ceil(0.5 / min_freq_hz / (block / rate_hz))  # +- half the longest period
    settle = reach + math.ceil(2.5 / (block / rate_hz))       # the offset: median over +-2.5 s more
    smooth = max(1, round(rate_hz / (4 * max_freq_hz))) // 2 * 2 + 1
    margin = ((settle + 1) * block + math.ceil(rate_hz / min_freq_hz) + smooth + block - 1) // block * block
    step = max(1, chunk // block) * block                      # chunk edges on block edges: the same envelope
    found = [np.empty(0)]
    for lo in range(0, n_samples, step):
        hi = min(n_samples, lo + step)
        a, b = max(0, lo - margin), min(n_samples, hi + margin)
        x = np.asarray(read(a, b), dtype=float)
        c, owner = _rising_crossings(x, block, reach, settle, smooth)
        keep = (owner + a >= lo) & (owner + a < hi)
        found.append(c[keep] + a)
    c = np.concatenate(found)
    # the frequency of the last two thirds of each run (its first cycles may be the drive's ramp)
    runs = [(i, j, rate_hz * (j - k) / (c[j] - c[k])) for i, j in _segments(c, rel_change, min_cycles)
            for k in [i + (j - i) // 3]]
    return [Dwell(int(math.ceil(c[i])), int(math.floor(c[j])) + 1, None, float(f))
            for i, j, f in runs if f <= 1.2 * max_freq_hz]        # faster ones: smoothed noise in a pause


def _rising_crossings(x: np.ndarray, block: int, reach: int, settle: int,
                      smooth: int) -> tuple[np.ndarray, np.ndarray]:
    """Rising crossings of the mid level [samples, fractional] and the sample that triggered each."""
    n = x.size
    if n < max(3, smooth):
        return np.empty(0), np.empty(0, np.int64)
    cs = np.concatenate(([0.0], np.cumsum(x)))
    half = smooth // 2                                          # centred moving average: no delay
    y = np.empty(n)
    y[half:n - half] = (cs[smooth:] - cs[:-smooth]) / smooth
    y[:half], y[n - half:] = y[half], y[n - half - 1]
    nb = -(-n // block)
    yb = np.concatenate([y, np.full(nb * block - n, y[-1])]).reshape(nb, block)
    # over about one longest period (2 reach + 1 blocks): the mid level between the extremes (the same at every
    # crossing of a steady sine, unlike a mean over a fraction of a period), its median over +-settle blocks (a
    # sensor's offset: steady across dwell edges, where a span holds part of a period), and the amplitude from
    # the RMS (not set by noise peaks), of the spans just before and just after a block the smaller one (a
    # dwell's last cycles keep their crossings when the next dwell is stronger, its first ones when the last was)
    span = 2 * reach + 1
    mean = ndimage.uniform_filter1d(yb.mean(axis=1), span, mode="nearest")
    square = ndimage.uniform_filter1d((yb * yb).mean(axis=1), span, mode="nearest")
    amp = np.sqrt(2 * np.maximum(square - mean * mean, 0.0))
    mid = 0.5 * (ndimage.maximum_filter1d(yb.max(axis=1), span, mode="nearest")
                 + ndimage.minimum_filter1d(yb.min(axis=1), span, mode="nearest"))
    mid = ndimage.median_filter(mid, 2 * settle + 1, mode="nearest")
    index = np.arange(nb)
    amp = np.minimum(amp[np.clip(index - reach, 0, nb - 1)], amp[np.clip(index + reach, 0, nb - 1)])
    y -= np.repeat(mid, block)[:n]
    thr = np.repeat(0.5 * amp, block)[:n]
    high = y > thr
    ev = np.flatnonzero(high | (y < -thr))
    state = high[ev]
    k = np.flatnonzero(state[1:] & ~state[:-1])
    i_lo, i_hi = ev[k], ev[k + 1]                              # last sample below -thr, first above +thr
    if i_lo.size == 0:
        return np.empty(0), np.empty(0, np.int64)
    # the least-squares line through the samples between the thresholds, where a sine is nearly straight:
    # its zero is the crossing (noise averaged over the segment; offsets and harmonics the same every cycle);
    # then again over the samples symmetric about that crossing (a growing or fading amplitude makes the
    # thresholds' segment lopsided, and the curve's bend would shift the line's zero)
    yy = np.append(y, 0.0)
    jy = np.arange(n + 1, dtype=float) * yy
    cross = _line_zero(yy, jy, i_lo, i_hi)
    half = np.minimum(cross - i_lo, i_hi - cross).astype(np.int64)
    near = np.round(cross).astype(np.int64)
    ok = half >= 1
    cross[ok] = np.clip(_line_zero(yy, jy, near[ok] - half[ok], near[ok] + half[ok]), i_lo[ok], i_hi[ok])
    return cross, i_hi


def _line_zero(yy: np.ndarray, jy: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Zero of the least-squares line through samples lo..hi (inclusive, increasing, disjoint) of y; ``yy`` is y
    with a 0 appended, ``jy`` the sample index times ``yy``."""
    idx = np.empty(2 * lo.size, np.int64)
    idx[0::2], idx[1::2] = lo, hi + 1
    s_y = np.add.reduceat(yy, idx)[0::2]
    s_jy = np.add.reduceat(jy, idx)[0::2]
    m = (hi - lo + 1).astype(float)
    centre = 0.5 * (lo + hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        zero = centre - s_y / m / ((s_jy - centre * s_y) / (m * (m * m - 1) / 12))
    return np.where(np.isfinite(zero), zero, centre)          # a flat segment (a pause): its middle


def _segments(c: np.ndarray, rel_change: float, min_cycles: int) -> list[tuple[int, int]]:
    """Runs of cycles of one period among crossings ``c``: pairs (i, j), the run from c[i] to c[j]."""
    p = np.diff(c)
    if p.size < max(min_cycles, 3):
        return []
    # each cycle's period jitter: the median change from cycle to cycle over the 16 cycles before it or the 16
    # after it, the larger (SNR differs between dwells: a dwell's own cycles at its ends), changes beyond 10 %
    # (pause noise, steps) counted as 10 %; a tolerance of 5 jitters, at most 5 % (noise in a pause never
    # holds 6 cycles that close)
    rel = np.minimum(np.abs(np.diff(p)) / p[:-1], 0.1)
    rel = np.append(rel, rel[-1])
    n = p.size
    centred = ndimage.median_filter(rel, 17, mode="mirror")
    index = np.arange(n)
    jitter = 1.4826 / math.sqrt(2) * np.maximum(centred[np.clip(index - 8, 0, n - 1)],
                                                 centred[np.clip(index + 8, 0, n - 1)])
    tol_cycle = np.clip(5 * jitter, rel_change, _MAX_JITTER).tolist()
    tol_mean = np.clip(5 * jitter / 8, rel_change, _MAX_JITTER).tolist()   # the mean of 8 periods: 8x less noisy
    pl, cl = p.tolist(), c.tolist()
    raw, i = [], 0
    while i < n:
        total, j = pl[i], i + 1
        while j < n:
            ref = total / (j - i)
            if abs(pl[j] - ref) > tol_cycle[j] * ref:
                break
            if j - i >= 8 and abs((cl[j + 1] - cl[j - 7]) / 8 - ref) > tol_mean[j] * ref:
                break
            total += pl[j]
            j += 1
        if j - i >= 3:
            raw.append((i, j))
        i = j
    raw = _join(raw, cl, tol_mean, rel)
    runs = []
    for i, j in raw:
        if j - i >= min_cycles:
            first, last = _trim_ends(c, i, j, rel_change)
            # the cycles next to a step may hold samples of both dwells: a dwell starts one cycle late and ends
            # one early (but at the record's ends)
            first, last = (first + 1 if first > 0 else first), (last - 1 if last < n else last)
            if last > first:
                runs.append((first, last))
    return runs


def _join(raw: list[tuple[int, int]], cl: list[float], tol_mean: list[float],
          rel: np.ndarray) -> list[tuple[int, int]]:
    """Runs (i, j) of crossings cl joined where they are one dwell, at most 2.2 periods apart: of one period
    (within the mean's tolerance; a missed or extra crossing split them), or a short run (< 16 cycles) within
    5 % whose periods converge to the other's before it or diverge from it after it, by more than their noise
    (the drive ramped up or down: such crossings are not periodic)."""
    def period(run):
        return (cl[run[1]] - cl[run[0]]) / (run[1] - run[0])

    def ends(run):            # mean periods of its first two and its last two cycles
        i, j = run
        return (cl[i + 2] - cl[i]) / 2, (cl[j] - cl[j - 2]) / 2

    def ramp(short, long, before):
        if short[1] - short[0] >= _RAMP_CYCLES or abs(period(short) / period(long) - 1) > _RAMP_REL:
            return False
        first, last = ends(short)
        near, far = (last, first) if before else (first, last)
        ref = period(long)
        jitter = 1.4826 / math.sqrt(2) * float(np.median(rel[long[0]:long[1] - 1]))   # the dwell's own
        return abs(far - ref) - abs(near - ref) > max(_RAMP_MIN, 3 * jitter) * ref

    out: list[tuple[int, int]] = []
    for run in raw:
        if out and cl[run[0]] - cl[out[-1][1]] <= 2.2 * period(run):
            last = out[-1]
            if abs(period(last) / period(run) - 1) <= tol_mean[run[0]] or ramp(last, run, True) \
                    or ramp(run, last, False):
                out[-1] = (last[0], run[1])
                continue
        out.append(run)
    return out


def _trim_ends(c: np.ndarray, i: int, j: int, rel_change: float) -> tuple[int, int]:
    """Crossings c[i..j] of one run less those among its last (first) 6 off the straight line through its
    middle (the crossings 6 and a third of the run away from either end) by more than 4 x their scatter and half
    a step of rel_change: the cycles of a next or last frequency drift off it by the step x a period each, and a
    ramp's crossings by their phase shift."""
    first, last = i, j
    m = j - i + 1
    edge = max(6, m // 3)
    if m - 6 - edge < 6:
        return first, last
    k = np.arange(i, j + 1, dtype=float)
    cc = c[i:j + 1]
    for end in (True, False):
        fit = slice(edge, m - 6) if end else slice(6, m - edge)
        slope, icpt = np.polyfit(k[fit], cc[fit], 1)
        r = cc - (slope * k + icpt)
        limit = 4 * 1.4826 * float(np.median(np.abs(r[fit] - np.median(r[fit])))) + 0.5 * rel_change * slope
        if end:
            while last > j - 6 and abs(r[last - i]) > limit:
                last -= 1
        else:
            while first < i + 6 and abs(r[first - i]) > limit:
                first += 1
    return first, last
