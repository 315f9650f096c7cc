"""The damper as a span sees it: the clamp impedance of a damper built with a calibrated cable, per
posterior draw, over the span's frequencies (what :mod:`sbcal.design.span` reads).

Its band holds what ``sbcal predict``'s band holds, by the same switches: the cable posterior (a
subset of its draws), the damper file's tolerances (geometry drawn per draw) and, unless switched
off, the calibration's model discrepancy (:func:`sbcal.design.predict.model_error_of`: per
calibrated amplitude the spread of the run means about the model beyond their noise, in ln|f| and in
phase; zero for a fit whose remainder is ``complete``): each (draw, line) gets its own standard-normal
pair ``z``, fixed by the seed and the lines, scaled by the discrepancy at the clamp amplitude the
balance asks for. The same ``z`` at every amplitude of one
(draw, line) keeps K* a smooth function of the amplitude (the balance's roots need one), and the same
seed gives the same ``z`` at every damper position and design (common random numbers: comparisons
between positions or designs are not blurred by the Monte Carlo). Where the cable run's harmonic refit was
used, ``f_uu`` carries its multi-harmonic correction as ``sbcal predict``'s does (:mod:`sbcal.design.harmonics`),
tabulated over lines and clamp amplitudes and interpolated at the amplitude the balance asks for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from ..model.damper import Damper, resolve_damper
from .cable_run import (cable_params, drawn_geometry, drawn_tolerances, is_calibration_damper, load_cable_run, streams,
                        subset, unit_draws)
from .harmonics import harmonic_table
from .predict import ModelError, draw_checks, model_error_of


__all__ = ["CableImpedance", "impedance_from_cable"]

_CHUNK = 40_000  # (state, line) pairs per cable solve of :meth:`CableImpedance.stacked`: bounds its memory

# --- the damper as a span sees it ------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CableImpedance:
    """A damper built with a calibrated cable as :class:`sbcal.design.span.Impedance`: one row per draw.

    ``impedance(freq_hz (F,), amplitude_m (S, F) or (1, F)) -> complex (S, F)``: ``f_uu`` [N/m] at
    the clamp amplitude ``amplitude_m`` [m, 0-peak] per draw and line, each (draw, line) its own
    steady state (no sweep history: the span has none); :meth:`curvature_max` the arms' curvature in
    those states. Module-level, picklable.

    Attributes
    ----------
    damper : Damper
        Nominal geometry (the draws' geometry is in ``params``).
    law : str
    params : dict of str -> ndarray, shape (S,)
        The cable draws and the geometry draws.
    model_error : ModelError or None
        The calibration's model discrepancy added per (draw, line) (module docstring); None: the
        posterior and the tolerances alone.
    error_seed : int
        Seeds the standard-normal pairs of the model error (with the lines' count: one set per band).
    harmonic : bool
        The cable run's harmonic refit was used: ``f_uu`` carries its correction, from a
        :class:`sbcal.design.harmonics.HarmonicTable` at the draws' median over the band first asked for (made
        then, once per band: the span's clamp amplitude is known only inside its root finder).
    tables : list of HarmonicTable
        Those made so far.
    """

    damper: Damper
    law: str
    params: dict
    model_error: ModelError | None = None
    error_seed: int = 0
    harmonic: bool = False
    tables: list = field(default_factory=list, repr=False, compare=False)
    model: object = field(init=False, repr=False)

    def __post_init__(self):
        from ..model.cable import CableModel
        from ..model.laws import law_for

        object.__setattr__(self, "model", CableModel(law_for(self.law)))

    @property
    def n_draws(self) -> int:
        return int(next(iter(self.params.values())).size)

    def _grid(self, freq_hz, amplitude_m):
        """Lines (F,) [Hz] and amplitudes (S, F) [mm p-p] from the span's (F,) and (S or 1, F) [m, 0-peak]."""
        f = np.atleast_1d(np.asarray(freq_hz, float))
        a = np.asarray(amplitude_m, float)
        return f, 2e3 * np.broadcast_to(a.reshape(-1, f.size), (self.n_draws, f.size))

    def __call__(self, freq_hz, amplitude_m):
        f, a = self._grid(freq_hz, amplitude_m)
        return self._with_error(self.model.dynamic_stiffness(self.damper, f, a, **self.params) * self._harmonic(f, a), a)

    def _harmonic(self, f, amplitude_mm):
        """The harmonic refit's correction at the lines ``f`` (F,) and amplitudes [mm p-p] (..., F); 1 without."""
        if not self.harmonic:
            return 1.0
        table = next((t for t in self.tables if t.covers(f)), None)
        if table is None:
            table = harmonic_table(self.law, (), self.damper, f, self.params)
            self.tables.append(table)
        return table.at(f, amplitude_mm)

    def stacked(self, freq_hz, amplitude_m):
        """:meth:`__call__` at K trial amplitudes at once: ``amplitude_m`` (K, S or 1, F) [m, 0-peak]
        -> (K, S, F). One cable solve per chunk of at most :data:`_CHUNK` (state, line) pairs instead
        of K solves (each solve has a fixed cost that dominates small posteriors)."""
        f = np.atleast_1d(np.asarray(freq_hz, float))
        a = np.asarray(amplitude_m, float)
        a = 2e3 * np.broadcast_to(a, (a.shape[0], self.n_draws, f.size))
        step = max(1, _CHUNK // (self.n_draws * f.size))
        out = []
        for k0 in range(0, a.shape[0], step):
            blk = a[k0:k0 + step]
            n = blk.shape[0]
            params = {name: np.tile(v, n) for name, v in self.params.items()}
            k = self.model.dynamic_stiffness(self.damper, f, blk.reshape(-1, f.size), **params)
            out.append(self._with_error(k.reshape(blk.shape) * self._harmonic(f, blk), blk))
        return np.concatenate(out)

    def _with_error(self, k, amplitude_mm):
        """``k`` (..., S, F) with the model error at the clamp amplitudes [mm p-p] of the same shape: the
        same standard-normal pair per (draw, line) whatever the amplitude (module docstring)."""
        if self.model_error is None:
            return k
        z = np.random.default_rng([self.error_seed, k.shape[-1]]).standard_normal((2, self.n_draws, k.shape[-1]))
        sd_mag, sd_phase = self.model_error.at(amplitude_mm)
        # a passive damper's loss cannot change sign: the phase error stops at 0 and at 180 deg
        phase = np.clip(np.angle(k) + z[1] * sd_phase, 0.0, np.pi)
        return np.abs(k) * np.exp(z[0] * sd_mag) * np.exp(1j * phase)

    def curvature_max(self, freq_hz, amplitude_m) -> np.ndarray:
        """The largest curvature amplitude along the arms [1/m], shape (S, F), in the states of
        :meth:`__call__` (same arguments); NaN where the solve did not converge."""
        st = self.model.state(self.damper, *self._grid(freq_hz, amplitude_m), **self.params)
        return np.where(st.converged, st.curvature_range[..., 1], np.nan)


def impedance_from_cable(run, damper, *, n_draws: int = 200, seed: int = 0,
                         model_error: bool = True) -> CableImpedance:
    """The span's :class:`sbcal.design.span.Impedance` of a damper built with a calibrated cable.

    Draws as :func:`predict` (posterior subset, geometry within the damper's tolerances; same
    ``seed``, same draws); draws the cable model cannot evaluate (outside the law's domain) are
    dropped. No bench effects: the span sees the damper itself. With ``model_error`` (default, as
    ``sbcal predict``) the calibration's model discrepancy is added (module docstring) when the run
    stores one (:attr:`CableImpedance.model_error` says whether it did); a used harmonic refit's
    correction is applied (:attr:`CableImpedance.harmonic`).
    """
    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    n_draws = draw_checks(n_draws)
    own = is_calibration_damper(cable, damper)
    pick, geo = streams(seed)
    idx = subset(cable, n_draws, pick)
    tolerance = drawn_tolerances([damper], own)
    params = dict(cable_params(cable, idx, False, own),
                  **drawn_geometry(damper, tolerance, unit_draws(tolerance, idx.size, geo)))
    errors = None
    if model_error and cable.summary.get("discrepancy") is not None:
        errors = model_error_of(cable)
    imp = CableImpedance(damper=damper, law=cable.law, params=params)
    probe = imp(np.array([10.0]), np.array([[1e-4]]))[:, 0]
    keep = np.isfinite(probe)
    if not keep.any():
        raise InputError(f"{cable.path}: no posterior draw gives a finite dynamic stiffness")
    params = {k: v[keep] for k, v in params.items()}
    return CableImpedance(damper=damper, law=cable.law, params=params, model_error=errors, error_seed=int(seed),
                          harmonic=cable.harmonic)
