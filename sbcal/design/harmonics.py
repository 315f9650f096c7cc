"""A harmonic refit's correction where a cable run is used: predict, sweep, compare and span.

A cable fit whose harmonic refit was used (:mod:`sbcal.inference.harmonic_refit`; ``CableRun.harmonic``) was
fitted with the cable's multi-harmonic solve on the lines that need it: a slipping cable's base force is not a
sine, and the first harmonic of the real force differs from the first-harmonic model's by a few percent at the
largest amplitudes. Its draws describe the cable only *with* that correction, so every use of them applies it:
``c = f_uu / f_uu_first`` per line (the multi-harmonic solve over the first-harmonic model), made as the refit
made its own, at the median of the draws (one correction for every draw: the refit measured how little it
changes across the posterior).

* At known lines and amplitudes (``sbcal predict``'s conditions, ``compare``'s characteristic, one design of a
  sweep): :func:`harmonic_correction`, solved at those lines, carried onto a finer grid by :func:`on_grid`.
* Where the amplitude is only known inside a root finder (``sbcal span``'s energy balance, ``sbcal design``):
  :class:`HarmonicTable`, solved once on a grid of lines and clamp amplitudes over the band asked for, and
  interpolated in ln f and ln(amplitude) (its log-magnitude and phase).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.damper import Damper

__all__ = ["TABLE_AMPLITUDES_MM", "TABLE_STEP", "HarmonicTable", "harmonic_correction", "harmonic_table", "on_grid"]

TABLE_AMPLITUDES_MM = np.geomspace(0.01, 20.0, 14)
"""Clamp amplitudes [mm p-p] of :class:`HarmonicTable` (a factor 1.8 apart): from below any slip to beyond
every bench; held at the end values outside."""

TABLE_STEP = 0.05
"""Largest step in ln f between the lines of :class:`HarmonicTable` (5 %: the correction changes on the scale of
a resonance's width, ~10 % at the damper's loss factors)."""


def harmonic_correction(law: str, effects, damper: Damper, freq_hz, x0, params: dict) -> tuple[np.ndarray, int]:
    """The correction at the lines ``freq_hz`` (F,) [Hz] and clamp amplitudes ``x0`` (F,) [m, 0-peak], at the
    median of the draws ``params`` (each ``(S,)``). ``(c, unsolved)``: complex ``(F,)``, 1 where the multi-harmonic
    solve did not converge, and how many such lines."""
    from ..inference.cable_fit import CableForward

    f = np.asarray(freq_hz, float)
    fwd = CableForward(law, 2e3 * np.broadcast_to(np.asarray(x0, float), f.shape), np.zeros(f.size, dtype=int),
                       tuple(effects))
    median = {k: np.atleast_1d(np.nanmedian(v)) for k, v in params.items()}
    c, solved = fwd.harmonic_correction(damper, f, **median)
    return c, int((~solved).sum())


def on_grid(c, freq_hz, fine) -> np.ndarray:
    """A per-line correction ``c`` (..., F) of the lines ``freq_hz`` (F,) carried onto the lines ``fine`` (linear
    in ln f, its log-magnitude and phase; the end values beyond the ends): (..., len(fine))."""
    lf, lg = np.log(freq_hz), np.log(fine)
    c = np.asarray(c, complex)
    mag, ph = np.log(np.abs(c)).reshape(-1, c.shape[-1]), np.unwrap(np.angle(c)).reshape(-1, c.shape[-1])
    out = np.exp([np.interp(lg, lf, m) + 1j * np.interp(lg, lf, p) for m, p in zip(mag, ph)])
    return out.reshape(c.shape[:-1] + (np.size(fine),))


@dataclass(frozen=True, eq=False)
class HarmonicTable:
    """The correction on a grid of lines and clamp amplitudes; :meth:`at` interpolates it. Picklable.

    Attributes
    ----------
    freq_hz : ndarray, shape (F,)
        Lines [Hz], increasing.
    amplitude_mm_pp : ndarray, shape (A,)
        Clamp amplitudes [mm p-p], increasing.
    c : ndarray of complex, shape (A, F)
        ``f_uu / f_uu_first`` at each (amplitude, line); 1 where the solve did not converge.
    unsolved : int
        How many (amplitude, line) pairs did not converge.
    """

    freq_hz: np.ndarray
    amplitude_mm_pp: np.ndarray
    c: np.ndarray
    unsolved: int = 0

    def covers(self, freq_hz) -> bool:
        """Whether the lines ``freq_hz`` lie within the table's."""
        f = np.asarray(freq_hz, float)
        return bool(f.min() >= self.freq_hz[0] * (1 - 1e-12) and f.max() <= self.freq_hz[-1] * (1 + 1e-12))

    def at(self, freq_hz, amplitude_mm_pp) -> np.ndarray:
        """The correction at the lines ``freq_hz`` (F,) [Hz] and amplitudes ``amplitude_mm_pp`` (..., F) [mm p-p]:
        complex (..., F), linear in ln f and ln(amplitude) in its log-magnitude and phase (the end values beyond
        the table)."""
        f = np.atleast_1d(np.asarray(freq_hz, float))
        rows = on_grid(self.c, self.freq_hz, f)                       # (A, F)
        mag, ph = np.log(np.abs(rows)), np.unwrap(np.angle(rows), axis=0)
        la = np.log(np.asarray(amplitude_mm_pp, float))
        grid = np.log(self.amplitude_mm_pp)
        la = np.clip(la, grid[0], grid[-1])
        hi = np.clip(np.searchsorted(grid, la), 1, grid.size - 1)     # (..., F)
        w = (la - grid[hi - 1]) / (grid[hi] - grid[hi - 1])
        col = np.broadcast_to(np.arange(f.size), la.shape)
        lo_m, hi_m = mag[hi - 1, col], mag[hi, col]
        lo_p, hi_p = ph[hi - 1, col], ph[hi, col]
        return np.exp((1 - w) * lo_m + w * hi_m + 1j * ((1 - w) * lo_p + w * hi_p))


def harmonic_table(law: str, effects, damper: Damper, freq_hz, params: dict, *,
                   amplitudes_mm_pp=TABLE_AMPLITUDES_MM, step: float = TABLE_STEP) -> HarmonicTable:
    """:class:`HarmonicTable` over the band of ``freq_hz`` (its least and largest line, in steps of at most ``step``
    in ln f) and the clamp amplitudes ``amplitudes_mm_pp``, at the median of the draws ``params``: one multi-harmonic
    solve of every (amplitude, line) pair."""
    f = np.asarray(freq_hz, float)
    lo, hi = float(f.min()), float(f.max())
    n = max(2, int(np.ceil(np.log(hi / lo) / step)) + 1) if hi > lo else 1
    grid = np.geomspace(lo, hi, n)
    a = np.asarray(amplitudes_mm_pp, float)
    # one sweep per amplitude, as predict solves a condition (a line the solve misses is continued from its
    # neighbours in frequency at the same amplitude)
    rows = [harmonic_correction(law, effects, damper, grid, np.full(grid.size, ak / 2e3), params) for ak in a]
    c = np.array([r[0] for r in rows])
    if n == 1:  # one line: a flat table in f
        grid, c = np.array([lo, lo * (1 + 1e-9)]), np.repeat(c, 2, axis=1)
    return HarmonicTable(freq_hz=grid, amplitude_mm_pp=a, c=c, unsolved=sum(r[1] for r in rows))
