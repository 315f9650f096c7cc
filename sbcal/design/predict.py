"""A new damper from the calibrated cable: the posterior predictive of its dynamic stiffness.

The cable's hysteresis law is a property of the messenger cable, not of the damper it was measured
on: a stored cable-law posterior (``<runs>/<damper>/cable-<state>/``, written by ``sbcal cable``;
:func:`sbcal.inference.cable_fit.store_cable`) predicts any damper built with that cable (``docs/predict.md``).
For each of ``n_draws`` posterior draws (a random subset) the new damper's geometry is drawn within
the tolerances its file states (:meth:`sbcal.model.damper.Damper.tolerances`: uniform within +- the percent,
5 % on the mass offsets by default), and the distributed cable (:class:`sbcal.model.cable.CableModel`) is
solved at every line, following a stepped-sine sweep up the grid (continuation; folds reported):

* constant clamp amplitude (the thesis's tests): ``X0 = amplitude_mm_pp / 2 * 1e-3`` m at every line;
* constant clamp velocity (IEC 61897's characteristic test, e.g. 0.1 m/s): ``X0 = v / omega``.

Per line: the dynamic stiffness ``|f_uu|`` and its phase, the dissipated power
``P = 0.5 omega Im(f_uu) X0^2``, each as median and 90 % band over the draws, and whether the line
is *extrapolated*: the median over draws of the largest curvature amplitude along the arms lies outside
the calibrated curvature range (:meth:`CableRun.range_status`, the rule ``sbcal span`` applies too:
more than :data:`EXTRAPOLATION_MARGIN` above the largest curvature the calibration's tests reached, or
below their least): the law is used where no calibration data constrained it.

*Resonances* are the local maxima against frequency of the damper's mechanical resistance
``R = Re(F / V) = Im(f_uu) / omega`` [N s/m] at the test condition (the cable's state at that
amplitude or velocity): the frequencies where the damper takes the most power per unit squared clamp
velocity (``P = 0.5 R (omega X0)^2``; under constant velocity they are the maxima of the dissipated
power itself). ``R`` shows every mode of the damper where the power under constant amplitude, tilted
by ``omega^2``, hides the lower ones. They are found on a fine grid (steps of :data:`RESONANCE_STEP` in
ln f over the requested band): the peaks of the median curve of ``ln R`` over the draws (prominence
:data:`PROMINENCE`) define windows between the minima that separate them, and each draw's resonance is
its local maximum inside the window nearest the median's peak (refined by a parabola in ln R over
ln f); ``share`` is the fraction of draws that have one. Resonances are
numbered by frequency at each condition (a peak that appears or vanishes in a design sweep shifts
the numbers of those above it).

*Model error*: the cable law is a model, and the calibration's run means can leave its posterior curves
by more than the noise and the posterior explain (the likelihood has no discrepancy term: the posterior
of the law is then far narrower than its misfit). By default (``model_error``) the bands add that
excess as the calibration judged it: when the stored fit's remainder is ``partial``, per calibrated
amplitude the spread of the calibration's run means about the posterior curves beyond their noise, in
ln|f| and in phase (:class:`ModelError`, the run's ``discrepancy``, computed once when the cable run was
stored: :func:`sbcal.inference.checks.discrepancy`; read by :func:`model_error_of`); zero when the fit
is ``complete``. It is interpolated in ln(amplitude) to each line's amplitude (held constant beyond the
calibrated amplitudes) and added as independent normal errors on every draw and line. The bands are
those of the damper's true curve: a comparison with measured run means adds their own noise. The
resonances and the design sweeps are those of the model curves.

The calibration damper's mass offsets ``a1``, ``a2`` in the posterior are that damper's: they are
used (instead of tolerance draws) only when the predicted damper is the calibration damper (same name
and geometry). Measurement-chain effects fitted with the cable (sensor delay, fixture mass, base
rocking) belong to the bench; they are left out unless ``bench_effects`` (to compare with recordings
from the same bench).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..model.damper import Damper, resolve_damper
from .harmonics import harmonic_correction, on_grid
from .resonance import PROMINENCE, resonance_draws
from .cable_run import (EXTRAPOLATION_MARGIN, CableRun, cable_params, drawn_geometry, drawn_tolerances,
                        is_calibration_damper, load_cable_run, streams, subset, unit_draws)


__all__ = [
    "QUANTILES", "EXTRAPOLATION_MARGIN", "RESONANCE_STEP", "PROMINENCE", "ModelError", "model_error_of",
    "Resonance", "Prediction", "predict", "MODES", "clamp_amplitude", "evaluate", "nan_quantiles", "fine_grid",
    "level_resonances", "FromCable", "from_cable_fields", "checked_levels", "checked_frequencies", "draw_checks",
]

QUANTILES = (0.05, 0.5, 0.95)
"""The band's lower end, the median and the upper end (a 90 % band)."""

RESONANCE_STEP = 0.005
"""Step of the fine grid of the resonance search in ln f (0.5 % in frequency)."""


_CHUNK = 40_000  # (set, line) pairs per cable-model call: bounds the solver's scratch memory
MODES = {"amplitude": "amplitude_mm_pp", "velocity": "velocity_m_s"}
# --- solving -----------------------------------------------------------------------------------------

def clamp_amplitude(mode: str, level: float, freq_hz):
    """Clamp amplitude per line [m, 0-peak] of one test condition."""
    f = np.asarray(freq_hz, float)
    if mode == "amplitude":
        return np.full(f.shape, level / 2 * 1e-3)
    return level / (2 * np.pi * f)


def evaluate(law: str, effects, damper: Damper, freq_hz, x0, params: dict, n_sets: int, correction=None) -> dict:
    """The cable at every (set, line) of one sweep, in chunks of sets (bounded memory); ``correction``
    (complex, ``(F,)``) multiplies the cable's ``f_uu`` (:func:`sbcal.design.harmonics.harmonic_correction`).

    Returns ``fuu`` (S, F) complex (NaN where a set is outside the law's domain or Newton did not
    converge), ``cmax`` (S, F) the largest curvature amplitude along the arms [1/m], ``fold`` and
    ``converged`` (S, F) bool.
    """
    from ..inference.cable_fit import CableForward

    f = np.asarray(freq_hz, float)
    fwd = CableForward(law, 2e3 * x0, np.zeros(f.size, dtype=int), tuple(effects), correction=correction)
    step = max(1, _CHUNK // f.size)
    parts = []
    for start in range(0, n_sets, step):
        sub = {k: v[start:start + step] for k, v in params.items()}
        st, fm = fwd.state(damper, f, continuation=True, **sub)
        conv = st.converged & np.isfinite(fm)
        parts.append((np.where(conv, fm, np.nan), np.where(conv, st.curvature_range[..., 1], np.nan), st.fold, conv))
    fuu, cmax, fold, conv = (np.concatenate(p, axis=0) for p in zip(*parts))
    return {"fuu": fuu, "cmax": cmax, "fold": fold, "converged": conv}


def nan_quantiles(x, axis=0) -> np.ndarray:
    """The :data:`QUANTILES` of ``x`` along ``axis``, NaN left out (NaN where all are NaN)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN lines stay NaN
        return np.nanquantile(x, QUANTILES, axis=axis)


def fine_grid(freq_hz) -> np.ndarray:
    """The resonance search grid [Hz]: the band of ``freq_hz`` in log steps of :data:`RESONANCE_STEP`."""
    lo, hi = float(np.min(freq_hz)), float(np.max(freq_hz))
    n = max(3, int(np.ceil(np.log(hi / lo) / RESONANCE_STEP)) + 1)
    return np.geomspace(lo, hi, n)


@dataclass(frozen=True)
class Resonance:
    """One resonance of one test condition.

    Attributes
    ----------
    level : float
        The test condition: amplitude [mm p-p] or velocity [m/s].
    index : int
        1, 2, ... in increasing frequency.
    freq_hz : tuple of float
        (q05, median, q95) of the resonance frequency over the draws that have it [Hz].
    power_w : tuple of float
        (q05, median, q95) of the dissipated power at it [W].
    share : float
        Fraction of the draws that have it (a local maximum of the resistance in its window).
    """

    level: float
    index: int
    freq_hz: tuple
    power_w: tuple
    share: float


def level_resonances(f_fine, fuu, x0, level: float) -> list:
    """Resonances (:func:`sbcal.design.resonance.resonance_draws`) from ``f_uu`` (S, F_fine) on the grid
    ``f_fine`` at clamp amplitudes ``x0`` (F_fine,) [m], summarised over the draws that have them."""
    out = []
    for r in resonance_draws(f_fine, fuu, x0):
        has = np.isfinite(r["freq_hz"])
        if not has.any():
            continue
        fq, pq = nan_quantiles(r["freq_hz"][has]), nan_quantiles(r["power_w"][has])
        out.append(Resonance(level=float(level), index=len(out) + 1, freq_hz=tuple(map(float, fq)),
                             power_w=tuple(map(float, pq)), share=float(has.mean())))
    return out


# --- the model's error, as the calibration showed it ------------------------------------------------

@dataclass(frozen=True)
class ModelError:
    """The calibration's model discrepancy per amplitude: the spread of its run means at that amplitude
    about the posterior curves beyond their noise (zero for a ``complete`` fit), stored with the cable
    run (:func:`model_error_of`, :func:`sbcal.inference.checks.discrepancy`).

    Attributes
    ----------
    amplitude_mm_pp : ndarray, shape (K,)
        The calibrated amplitudes, increasing.
    logmag_sd : ndarray, shape (K,)
        Discrepancy sd of ln|f| [1].
    phase_sd_deg : ndarray, shape (K,)
        Discrepancy sd of the phase [deg].
    """

    amplitude_mm_pp: np.ndarray
    logmag_sd: np.ndarray
    phase_sd_deg: np.ndarray

    def at(self, amplitude_mm_pp) -> tuple[np.ndarray, np.ndarray]:
        """``(logmag_sd, phase_sd_rad)`` at amplitudes [mm p-p]: interpolated in ln(amplitude), held
        constant beyond the calibrated ones."""
        la = np.log(np.asarray(amplitude_mm_pp, float))
        grid = np.log(self.amplitude_mm_pp)
        return np.interp(la, grid, self.logmag_sd), np.radians(np.interp(la, grid, self.phase_sd_deg))

    def as_dict(self) -> dict:
        return {"amplitude_mm_pp": self.amplitude_mm_pp.tolist(), "logmag_sd": self.logmag_sd.tolist(),
                "phase_sd_deg": self.phase_sd_deg.tolist()}


def model_error_of(run) -> ModelError:
    """The :class:`ModelError` of a stored cable fit: the discrepancy its writer computed
    (``discrepancy`` of its ``summary.json``; :func:`sbcal.inference.cable_fit.store_cable`).

    Raises
    ------
    InputError
        One line: the summary has no such key (a run stored before it existed) or a malformed one.
    """
    cable = load_cable_run(run)
    where = f"{cable.path}/summary.json: key 'discrepancy'"
    doc = cable.summary.get("discrepancy")
    if doc is None:
        raise InputError(f"{where}: missing (a cable run stored before sbcal kept its discrepancy; "
                         "a new 'sbcal cable' run has it)")
    try:
        amp, mag, phase = (np.asarray(doc[k], float) for k in ("amplitude_mm_pp", "logmag_sd", "phase_sd_deg"))
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{where}: expected lists of numbers amplitude_mm_pp, logmag_sd, phase_sd_deg") from None
    if amp.ndim != 1 or amp.size == 0 or mag.shape != amp.shape or phase.shape != amp.shape \
            or not np.all(amp > 0) or np.any(np.diff(amp) <= 0):
        raise InputError(f"{where}: expected lists of one length, amplitude_mm_pp > 0 and increasing")
    return ModelError(amplitude_mm_pp=amp, logmag_sd=mag, phase_sd_deg=phase)


_ERROR_SAMPLES = 4000  # (draw, model-error) samples per line behind the bands with model error


def _bands(fuu, x0, f, error, rng):
    """Quantiles (3, F) of |f|, phase [deg] and power from the draws ``fuu`` (S, F), with the model
    error ``(logmag_sd, phase_sd_rad)`` per line (each (F,)) added when given and not zero."""
    mag, phase = np.abs(fuu), np.angle(fuu)  # a passive draw's phase lies in (0, pi): no wrap
    if error is not None and (np.any(error[0] > 0) or np.any(error[1] > 0)):  # none for a complete fit
        reps = max(1, -(-_ERROR_SAMPLES // fuu.shape[0]))
        sd_m, sd_p = error
        e = rng.standard_normal((2, reps) + fuu.shape)
        # the phase error is added, not wrapped: about 180 deg it may pass it, as measured phases do
        mag, phase = (mag[None] * np.exp(e[0] * sd_m)).reshape(-1, f.size), (phase[None] + e[1] * sd_p).reshape(-1, f.size)
    return (nan_quantiles(mag), nan_quantiles(np.degrees(phase)),
            nan_quantiles(0.5 * 2 * np.pi * f * mag * np.sin(phase) * x0**2))


# --- the prediction ---------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False, kw_only=True)
class FromCable:
    """What a prediction (:class:`Prediction`) and a design sweep (:class:`sbcal.design.sweep.SweepResult`)
    share: the damper, the stored cable it is built with, the test conditions and the draws.

    Attributes
    ----------
    damper : str
        The predicted damper's name (a sweep's base damper).
    cable : str
        The cable run directory.
    cable_damper, state, law : str
        The calibration damper, the cable state and the law family.
    mode : str
        ``"amplitude"`` (constant clamp amplitude) or ``"velocity"`` (constant clamp velocity).
    levels : ndarray, shape (L,)
        The test conditions: amplitudes [mm p-p] or velocities [m/s].
    n_draws : int
        Posterior draws used (each with its own geometry draw).
    seed : int
    tolerance_pct : dict
        +- tolerance [%] per damper field drawn (uniform).
    own_offsets : bool
        The posterior's ``a1``, ``a2`` were used (the calibration damper itself).
    bench_effects : bool
        The calibration bench's measurement-chain effects were applied.
    warnings : tuple of str
    versions : dict
    """

    damper: str
    cable: str
    cable_damper: str
    state: str
    law: str
    mode: str
    levels: np.ndarray
    n_draws: int
    seed: int
    tolerance_pct: dict
    own_offsets: bool
    bench_effects: bool
    warnings: tuple = ()
    versions: dict = field(default_factory=dict)

    def _summary(self) -> dict:
        """The shared fields, JSON-ready."""
        return {"damper": self.damper, "cable": self.cable, "cable_damper": self.cable_damper, "state": self.state,
                "law": self.law, "mode": self.mode, "levels": [float(v) for v in self.levels],
                "n_draws": self.n_draws, "seed": self.seed, "tolerance_pct": self.tolerance_pct,
                "own_offsets": self.own_offsets, "bench_effects": self.bench_effects,
                "warnings": list(self.warnings), "versions": self.versions}


def from_cable_fields(cable: CableRun, damper: Damper, *, mode: str, levels, n_draws: int, seed: int,
                      tolerance: dict, own: bool, bench_effects: bool, notes=()) -> dict:
    """The :class:`FromCable` fields of a result computed from ``cable``; the warnings lead with the
    run's own (posterior not converged, no calibrated curvature range), then ``notes``."""
    from ..inference.runs import versions

    of_run = tuple(w for w in (cable.convergence_warning(), cable.range_warning()) if w)
    return dict(damper=damper.name, cable=str(cable.path), cable_damper=cable.damper, state=cable.state,
                law=cable.law, mode=mode, levels=levels, n_draws=int(n_draws), seed=int(seed),
                tolerance_pct={k: float(v) for k, v in tolerance.items()}, own_offsets=bool(own),
                bench_effects=bool(bench_effects), warnings=of_run + tuple(notes), versions=versions())


@dataclass(frozen=True, eq=False, kw_only=True)
class Prediction(FromCable):
    """The posterior predictive of a damper built with a calibrated cable (:func:`predict`): the
    attributes of :class:`FromCable` (the damper, the cable run, the conditions, the draws) and these.

    Attributes
    ----------
    damper_values : dict
        The predicted damper's nominal values (the :class:`sbcal.model.damper.Damper` fields).
    freq_hz : ndarray, shape (F,)
        Frequency lines [Hz], increasing.
    amplitude_mm_pp : ndarray, shape (L, F)
        Clamp amplitude per line [mm p-p].
    stiffness_n_per_m, phase_deg, power_w : ndarray, shape (L, 3, F)
        ``|f_uu|`` [N/m], its phase [deg] and the dissipated power [W]: the :data:`QUANTILES`
        (q05, median, q95) over the draws, per condition and line.
    curvature_max : ndarray, shape (L, F)
        Median over the draws of the largest curvature amplitude along the arms [1/m].
    extrapolated : ndarray of bool, shape (L, F)
        The line bends the arms outside the calibrated range, above or below
        (:meth:`sbcal.design.cable_run.CableRun.range_status` not ``"ok"``).
    fold_share, converged_share : ndarray, shape (L, F)
        Fraction of the draws with two steady states at the line (the sweep's branch is used), and
        with a converged solve (the others are left out of the quantiles).
    resonances : tuple of Resonance
        Every condition's resonances (``level`` says whose).
    calibrated_curvature : tuple of float
        The calibrated curvature range [1/m] (least, largest).
    model_error : dict or None
        The :class:`ModelError` added to the bands (``as_dict()``), None when not.
    harmonic_correction : bool
        The run is a used harmonic refit's, and so every draw's curves carry the multi-harmonic solve's
        correction (:mod:`sbcal.design.harmonics`, at the draws' median; on the resonance search's grid carried
        over by :func:`~sbcal.design.harmonics.on_grid`).
    """

    damper_values: dict
    freq_hz: np.ndarray
    amplitude_mm_pp: np.ndarray
    stiffness_n_per_m: np.ndarray
    phase_deg: np.ndarray
    power_w: np.ndarray
    curvature_max: np.ndarray
    extrapolated: np.ndarray
    fold_share: np.ndarray
    converged_share: np.ndarray
    resonances: tuple
    calibrated_curvature: tuple
    model_error: dict | None = None
    harmonic_correction: bool = False

    def labels(self) -> list:
        """The ``test`` label of each condition: ``1-1`` (1 mm p-p), ``v0.1`` (0.1 m/s)."""
        from ..data.bench import test_label

        return [test_label(v) if self.mode == "amplitude" else f"v{v:g}" for v in self.levels]

    def to_frame(self) -> pd.DataFrame:
        """Bench CSV columns (``run`` = 0, the median) plus the bands, the power and ``extrapolated``."""
        rows = []
        for i, label in enumerate(self.labels()):
            s, p, w = self.stiffness_n_per_m[i], self.phase_deg[i], self.power_w[i]
            rows.append(pd.DataFrame({
                "damper": self.damper, "test": label, "run": 0, "frequency_hz": self.freq_hz,
                "amplitude_mm_pp": self.amplitude_mm_pp[i], "stiffness_n_per_m": s[1], "phase_deg": p[1],
                "stiffness_q05": s[0], "stiffness_q95": s[2], "phase_q05": p[0], "phase_q95": p[2],
                "power_w": w[1], "power_q05": w[0], "power_q95": w[2], "extrapolated": self.extrapolated[i]}))
        return pd.concat(rows, ignore_index=True)

    def summary(self) -> dict:
        """JSON-ready: everything but the per-line bands (those are in :meth:`to_frame`)."""
        return self._summary() | {
            "damper_values": self.damper_values, "tests": self.labels(), "freq_hz": self.freq_hz.tolist(),
            "curvature_max": self.curvature_max.tolist(), "fold_share": self.fold_share.tolist(),
            "converged_share": self.converged_share.tolist(),
            "resonances": [dataclasses.asdict(r) for r in self.resonances],
            "calibrated_curvature": list(self.calibrated_curvature),
            "extrapolated_lines": int(self.extrapolated.sum()), "model_error": self.model_error,
            "harmonic_correction": self.harmonic_correction,
        }


def checked_levels(cable: CableRun, amplitude_mm_pp, velocity_m_s):
    """``(mode, levels)``: amplitudes [mm p-p] or velocities [m/s], checked (default the run's constant ones)."""
    if amplitude_mm_pp is not None and velocity_m_s is not None:
        raise InputError("give amplitudes or velocities, not both")
    mode = "velocity" if velocity_m_s is not None else "amplitude"
    values = velocity_m_s if velocity_m_s is not None else amplitude_mm_pp
    if values is None:
        values = cable.constant_amplitudes()
        if not values:
            raise InputError(f"{cable.path}: no constant-amplitude calibration test to default to; give amplitudes")
    v = np.atleast_1d(np.asarray(values, dtype=float))
    what = "--amplitude" if mode == "amplitude" else "--velocity"
    unit = "mm p-p" if mode == "amplitude" else "m/s"
    if v.ndim != 1 or v.size == 0:
        raise InputError(f"{what}: expected one or more values [{unit}]")
    for x in v:
        if not (np.isfinite(x) and x > 0):
            raise InputError(f"{what} {x:g}: must be > 0 [{unit}]")
    return mode, v


def checked_frequencies(freq_hz) -> np.ndarray:
    """Frequencies [Hz] sorted and unique (the standard grid when None); InputError unless finite and > 0."""
    from ..model.fem import STANDARD_GRID_HZ

    if freq_hz is None:
        return STANDARD_GRID_HZ.copy()
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise InputError("frequencies: expected finite values > 0 [Hz]")
    return np.unique(f)  # one stepped-sine sweep up


def draw_checks(n_draws):
    """The number of posterior draws as an int; InputError unless an integer >= 2."""
    if int(n_draws) != n_draws or n_draws < 2:
        raise InputError(f"draws: expected an integer >= 2, got {n_draws!r}")
    return int(n_draws)


def predict(run, damper, *, amplitude_mm_pp=None, velocity_m_s=None, freq_hz=None, n_draws: int = 300,
            seed: int = 0, bench_effects: bool = False, model_error: bool = True) -> Prediction:
    """The posterior predictive of a damper built with a calibrated cable (module docstring).

    Parameters
    ----------
    run : path-like or CableRun
        A stored cable-law posterior (``<runs>/<damper>/cable-<state>``).
    damper : Damper, or str / path-like
        The new damper (a bundled name or a TOML path; its ``[tolerance]`` table is used).
    amplitude_mm_pp : float or sequence of float, optional
        Constant clamp amplitudes [mm p-p] (default: the calibration's constant-amplitude tests).
    velocity_m_s : float or sequence of float, optional
        Constant clamp velocities [m/s] instead (``X0 = v / omega``).
    freq_hz : array_like, optional
        Frequency lines [Hz] (default :data:`sbcal.model.fem.STANDARD_GRID_HZ`); sorted, one sweep up.
    n_draws : int
        Posterior draws used (a random subset; all when the posterior has fewer).
    seed : int
        Fixes the subset and the geometry draws.
    bench_effects : bool
        Apply the calibration bench's fitted measurement-chain effects.
    model_error : bool
        Add the calibration's model discrepancy to the bands (:func:`model_error_of`; module docstring).
        Off, or when the run stores none (a warning), the bands are the posterior's and the tolerances'
        alone.

    Returns
    -------
    Prediction

    Raises
    ------
    InputError
        A missing run or damper file, amplitudes or velocities <= 0, bad frequencies.
    """
    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    mode, levels = checked_levels(cable, amplitude_mm_pp, velocity_m_s)
    f = checked_frequencies(freq_hz)
    n_draws = draw_checks(n_draws)
    own = is_calibration_damper(cable, damper)
    pick, geo = streams(seed)
    idx = subset(cable, n_draws, pick)
    n = idx.size
    errors, notes = None, []
    if model_error:
        try:
            errors = model_error_of(cable)
        except InputError as e:
            notes.append(f"no model error in the bands: {e}")
    noise = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
    tolerance = drawn_tolerances([damper], own)
    params = dict(cable_params(cable, idx, bench_effects, own),
                  **drawn_geometry(damper, tolerance, unit_draws(tolerance, n, geo)))
    effects = tuple(cable.summary.get("effects", ())) if bench_effects else ()
    fine = fine_grid(f)
    shape = (levels.size, f.size)
    out = {k: np.empty((levels.size, 3, f.size)) for k in ("stiffness", "phase", "power")}
    cmax, extra = np.empty(shape), np.zeros(shape, dtype=bool)
    fold, conv = np.empty(shape), np.empty(shape)
    amps = np.empty(shape)
    resonances = []
    unsolved = 0
    for i, level in enumerate(levels):  # a handful of test conditions; each call is vectorised
        x0 = clamp_amplitude(mode, level, f)
        c = None
        if cable.harmonic:  # solved on the sweep's lines, carried onto the resonance search's fine grid
            c, k = harmonic_correction(cable.law, effects, damper, f, x0, params)
            unsolved += k
        r = evaluate(cable.law, effects, damper, f, x0, params, n, correction=c)
        err = errors.at(2e3 * x0) if errors is not None else None
        out["stiffness"][i], out["phase"][i], out["power"][i] = _bands(r["fuu"], x0, f, err, noise)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            cmax[i] = np.nanmedian(r["cmax"], axis=0)
        extra[i] = cable.range_status(cmax[i]) != 0
        fold[i], conv[i] = r["fold"].mean(axis=0), r["converged"].mean(axis=0)
        amps[i] = 2e3 * x0
        xf = clamp_amplitude(mode, level, fine)
        rf = evaluate(cable.law, effects, damper, fine, xf, params, n, correction=None if c is None else on_grid(c, f, fine))
        resonances += level_resonances(fine, rf["fuu"], xf, level)
    if unsolved:
        notes.append(f"the multi-harmonic solve of the harmonic refit's correction did not converge on {unsolved} "
                     "line(s): left uncorrected (first harmonic)")
    if conv.min() < 1:
        notes.append(f"the cable model did not converge for {100 * (1 - conv.mean()):.2g} % of the (draw, line) "
                     "pairs: left out of the bands")
    values = {k: v for k, v in dataclasses.asdict(damper).items() if k not in ("tolerance",)}
    return Prediction(
        **from_cable_fields(cable, damper, mode=mode, levels=levels, n_draws=n, seed=seed, tolerance=tolerance,
                            own=own, bench_effects=bench_effects, notes=notes),
        damper_values=values, freq_hz=f, amplitude_mm_pp=amps, stiffness_n_per_m=out["stiffness"],
        phase_deg=out["phase"], power_w=out["power"], curvature_max=cmax, extrapolated=extra, fold_share=fold,
        converged_share=conv, resonances=tuple(resonances),
        calibrated_curvature=tuple(float(v) for v in cable.curvature_range),
        model_error=errors.as_dict() if errors is not None else None, harmonic_correction=cable.harmonic)
