"""Where to put the damper: the worst-case margin over the band against its position."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .conductor import Conductor
from .span import Impedance, SpanResult, checked_positions, energy_balance, jsonable
from .vibration import strouhal_band


__all__ = ["Placement", "position_grid", "optimise_position"]

# ---------------------------------------------------------------------------------------------
# Placement


@dataclass(frozen=True, eq=False)
class Placement:
    """Worst-case margin over the band against the damper position.

    Attributes
    ----------
    positions_m : ndarray, shape (P,)
        Positions evaluated [m from the suspension clamp].
    margin : ndarray, shape (P,)
        The ``quantile`` of the worst-case margin over draws, per position.
    margin_median : ndarray, shape (P,)
    quantile : float
    ends : int
    best_position_m, best_margin : float
        The position with the largest ``margin`` and that margin.
    suffices : bool
        ``best_margin >= 1``: this many dampers (``ends``) keep the stress under the limit.
    best : SpanResult
        The balance at the best position.
    """

    positions_m: np.ndarray
    margin: np.ndarray
    margin_median: np.ndarray
    quantile: float
    ends: int
    best_position_m: float
    best_margin: float
    suffices: bool
    best: SpanResult

    def to_frame(self):
        import pandas as pd

        return pd.DataFrame({"position_m": self.positions_m, f"margin_q{round(100 * self.quantile):02d}": self.margin,
                             "margin_median": self.margin_median})

    def to_dict(self) -> dict:
        return {"positions_m": jsonable(self.positions_m), "margin": jsonable(self.margin),
                "margin_median": jsonable(self.margin_median), "quantile": self.quantile, "ends": self.ends,
                "best_position_m": self.best_position_m, "best_margin": jsonable(self.best_margin),
                "suffices": self.suffices}


def position_grid(conductor: Conductor, *, ends: int = 1, wind=(1.0, 7.0), n_freq: int = 60, freq_hz=None,
                  n: int = 40) -> np.ndarray:
    """The default candidate positions [m]: ``n`` points from 5 % to 100 % of the band's shortest
    wavelength (within the span, or half of it with dampers at both ends)."""
    freq = strouhal_band(conductor, wind, n_freq)[0] if freq_hz is None else np.asarray(freq_hz, float)
    lam_min = conductor.wave_speed_m_s / np.max(freq)
    top = conductor.span_length_m / (ends if ends in (1, 2) else 1)
    return np.linspace(0.05, 1.0, int(n)) * min(lam_min, 0.99 * top)


def optimise_position(conductor: Conductor, impedance: Impedance, positions_m=None, *, ends: int = 1,
                      quantile: float = 0.1, wind=(1.0, 7.0), n_freq: int = 60, freq_hz=None,
                      wave: str = "travelling") -> Placement:
    """The damper position that maximises the worst-case margin over the band.

    One damper per equipped span end. Each position is a full vectorised balance over draws and
    frequencies; positions are a short outer design loop.

    Parameters
    ----------
    positions_m : array_like, shape (P,), optional
        Candidate distances from the suspension clamp [m]; default 40 points from 5 % to 100 % of
        the shortest wavelength of the band (within the span).
    quantile : float
        Which quantile over draws of the worst-case margin is maximised (0.1: the margin that 90 %
        of the posterior exceeds; 0.5: the median).
    ends, wind, n_freq, freq_hz, wave
        As in :func:`energy_balance`.
    """
    if not 0 < quantile < 1:
        raise InputError(f"quantile: expected a number in (0, 1), got {quantile!r}")
    if positions_m is None:
        positions_m = position_grid(conductor, ends=ends, wind=wind, n_freq=n_freq, freq_hz=freq_hz)
    pos = np.atleast_1d(np.asarray(positions_m, dtype=float))
    checked_positions(conductor, pos, ends)
    margins, medians, results = [], [], []
    for x in pos:
        r = energy_balance(conductor, impedance, float(x), ends=ends, wind=wind, n_freq=n_freq, freq_hz=freq_hz,
                           wave=wave)
        m = r.margin
        margins.append(float(np.quantile(m, quantile)))
        medians.append(float(np.median(m)))
        results.append(r)
    margins = np.array(margins)
    i = int(np.argmax(margins))
    return Placement(positions_m=pos, margin=margins, margin_median=np.array(medians), quantile=quantile,
                     ends=ends, best_position_m=float(pos[i]), best_margin=float(margins[i]),
                     suffices=bool(margins[i] >= 1.0), best=results[i])
