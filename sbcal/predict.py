"""A new damper from the calibrated cable: the posterior predictive of its dynamic stiffness.

The cable's hysteresis law is a property of the messenger cable, not of the damper it was measured
on: a stored cable-law posterior (``<runs>/<damper>/cable-<state>/``, written by ``sbcal cable``;
:func:`sbcal.cable_fit.store_cable`) predicts any damper built with that cable (``docs/predict.md``).
For each of ``n_draws`` posterior draws (a random subset) the new damper's geometry is drawn within
the tolerances its file states (:meth:`sbcal.damper.Damper.tolerances`: uniform within +- the percent,
5 % on the mass offsets by default), and the distributed cable (:class:`sbcal.cable.CableModel`) is
solved at every line, following a stepped-sine sweep up the grid (continuation; folds reported):

* constant clamp amplitude (the thesis's tests): ``X0 = amplitude_mm_pp / 2 * 1e-3`` m at every line;
* constant clamp velocity (IEC 61897's characteristic test, e.g. 0.1 m/s): ``X0 = v / omega``.

Per line: the dynamic stiffness ``|f_uu|`` and its phase, the dissipated power
``P = 0.5 omega Im(f_uu) X0^2``, each as median and 90 % band over the draws, and whether the line
is *extrapolated*: the median over draws of the largest curvature amplitude along the arms lies more
than :data:`EXTRAPOLATION_MARGIN` above the largest the calibration's tests reached (or below their
smallest): the law is used where no calibration data constrained it.

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

*Model error*: the cable law is a model, and the calibration's run means leave its posterior median
curve by a margin the posterior does not carry (the likelihood has no discrepancy term: the posterior
of the law is far narrower than its misfit). By default (``model_error``) the bands add that margin as
the calibration showed it: per calibrated amplitude the rms residual of the calibration's run means
about the median model curve, in ln|f| and in phase (:class:`ModelError`), interpolated in ln(amplitude)
to each line's amplitude (held constant beyond the calibrated amplitudes), as independent normal
errors on every draw and line. The resonances and the design sweeps are those of the model curves.

The calibration damper's mass offsets ``a1``, ``a2`` in the posterior are that damper's: they are
used (instead of tolerance draws) only when the predicted damper is the calibration damper (same name
and geometry). Measurement-chain effects fitted with the cable (sensor delay, fixture mass, base
rocking) belong to the bench; they are left out unless ``bench_effects`` (to compare with recordings
from the same bench).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .plotting import pyplot, save_png
from ._io import atomic_path, write_json
from .damper import FILE_KEYS, GEOMETRY, Damper, resolve_damper, with_value
from .errors import InputError
from .labels import parse_label

__all__ = [
    "QUANTILES",
    "EXTRAPOLATION_MARGIN",
    "RESONANCE_STEP",
    "PROMINENCE",
    "TRACK_STEP",
    "CableRun",
    "load_cable_run",
    "ModelError",
    "model_error_of",
    "Resonance",
    "Prediction",
    "SweepResult",
    "predict",
    "sweep",
    "parse_sweep",
    "prediction_dir",
    "store_prediction",
    "write_csv",
    "read_prediction",
    "store_sweep",
    "read_sweep",
    "stored_predictions",
    "plot_prediction",
    "plot_sweep",
    "CableImpedance",
    "impedance_from_cable",
]

QUANTILES = (0.05, 0.5, 0.95)
"""The band's lower end, the median and the upper end (a 90 % band)."""

EXTRAPOLATION_MARGIN = 0.10
"""A line is extrapolated when its largest arm curvature exceeds the calibrated maximum by more than
this fraction (or falls below the calibrated minimum by as much): a margin for the difference between
the posterior median's state, which the calibrated range is taken from, and the median over draws."""

RESONANCE_STEP = 0.005
"""Step of the fine grid of the resonance search in ln f (0.5 % in frequency)."""

PROMINENCE = 0.05
"""Least prominence of a peak of the median resistance curve in ln R (5 %) to count as a resonance."""

_CHUNK = 40_000  # (set, line) pairs per cable-model call: bounds the solver's scratch memory
_MODES = {"amplitude": "amplitude_mm_pp", "velocity": "velocity_m_s"}
_EFFECT_PARAMS = ("delay_s", "fixture_mass_kg", "rocking_rad_per_m")


# --- the stored cable ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CableRun:
    """A stored cable-law posterior, read once.

    Attributes
    ----------
    path : Path
        The run directory (``<runs>/<damper>/cable-<state>``).
    summary : dict
        Its ``summary.json``.
    draws : dict of str -> ndarray, shape (n_draws,)
        Posterior draws by parameter (chains pooled).
    law : str
        The law's family (:data:`sbcal.hysteresis.LAWS`).
    calibration : Damper or None
        The calibration damper, from the stored ``damper_values`` (None when not stored).
    curvature_range : tuple of float
        Least and largest curvature amplitude [1/m] the calibration's tests reached (``tests_reached``;
        NaN when not stored).
    """

    path: Path
    summary: dict
    draws: dict
    law: str
    calibration: Damper | None
    curvature_range: tuple

    @property
    def damper(self) -> str:
        return str(self.summary.get("damper", self.path.parent.name))

    @property
    def state(self) -> str:
        return str(self.summary.get("state", self.path.name.removeprefix("cable-")))

    @property
    def n_draws(self) -> int:
        return int(next(iter(self.draws.values())).size)

    def constant_amplitudes(self) -> list:
        """The amplitudes [mm p-p] of the calibration's constant-amplitude tests (``A-A``), sorted."""
        out = set()
        for t in self.summary.get("tests", []):
            p = parse_label(t)
            if p and p.constant:
                out.add(p.below_mm_pp)
        return sorted(out)

    def convergence_warning(self) -> str:
        """'' when the posterior converged, else one line saying which parameters did not."""
        from .sampler import POLICY

        s = self.summary
        if s.get("converged", False):
            return ""
        bad = [n for n, p in s.get("parameters", {}).items()
               if not (p.get("r_hat", np.inf) <= POLICY["rhat_max"]
                       and min(p.get("ess_bulk", 0), p.get("ess_tail", 0)) >= POLICY["ess_min"])]
        which = (f"R-hat > {POLICY['rhat_max']} or ESS < {POLICY['ess_min']:.0f} for {', '.join(bad)}" if bad
                 else "every parameter passes R-hat and ESS")
        why = str(s.get("reason") or "no reason stored").split(":")[0].split(";")[0]  # its first clause
        return (f"{self.path}: the cable posterior did not converge ({why}; {which}): the bands may be too "
                "narrow or misplaced")


def load_cable_run(run) -> CableRun:
    """Read a stored cable-law posterior (see :class:`CableRun`); ``run`` a directory or a CableRun.

    Raises
    ------
    InputError
        One line: no such directory, no cable-law run in it, its posterior missing.
    """
    from .cable_fit import read_cable
    from .hysteresis import law_for

    if isinstance(run, CableRun):
        return run
    path = Path(run)
    if not path.is_dir():
        raise InputError(f"{path}: no such cable run (a directory written by 'sbcal cable', "
                         "e.g. runs/damper1/cable-dry)")
    if not (path / "posterior.nc").is_file():
        if (path / "summary.json").is_file():
            raise InputError(f"{path}: posterior.nc is missing")
        raise InputError(f"{path}: no cable-law run here (summary.json missing; 'sbcal cable' writes one)")
    try:
        summary, draws = read_cable(path)
    except (OSError, ValueError, KeyError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: cannot read the cable posterior ({e})") from None
    law = summary["law"]
    try:
        needed = ("EJ_min", "beta_material") + law_for(law).parameter_names
    except (KeyError, ValueError, InputError):
        raise InputError(f"{path}: summary.json: unknown law {law!r}") from None
    missing = [n for n in needed if n not in draws]
    if missing:
        raise InputError(f"{path}: posterior.nc has no draws of {missing[0]!r} (the {law} law needs {', '.join(needed)})")
    values = summary.get("damper_values")
    calibration = None
    if isinstance(values, dict):
        names = {f.name for f in dataclasses.fields(Damper)}
        kw = {k: v for k, v in values.items() if k in names}
        kw["tolerance"] = tuple(tuple(t) for t in kw.get("tolerance", ()))
        try:
            calibration = Damper(**kw)
        except TypeError:
            calibration = None
    reached = summary.get("tests_reached") or {}
    if reached:
        rng = (min(float(r["curvature_min"]) for r in reached.values()),
               max(float(r["curvature_max"]) for r in reached.values()))
    else:
        rng = (float("nan"), float("nan"))
    return CableRun(path=path, summary=summary, draws={k: np.asarray(v, float) for k, v in draws.items()},
                    law=law, calibration=calibration, curvature_range=rng)


def _is_calibration_damper(cable: CableRun, damper: Damper) -> bool:
    c = cable.calibration
    if c is None or c.name != damper.name:
        return False
    return all(np.isclose(getattr(c, k), getattr(damper, k), rtol=1e-12, atol=0.0) for k in GEOMETRY)


# --- the draws -------------------------------------------------------------------------------------

def _streams(seed):
    """Independent generators: the posterior subset and the geometry draws."""
    choice, geometry = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(choice), np.random.default_rng(geometry)


def _subset(cable: CableRun, n_draws: int, rng) -> np.ndarray:
    """Indices of the posterior draws used (all of them, in order, when n_draws >= the stored number)."""
    n = cable.n_draws
    if n_draws >= n:
        return np.arange(n)
    return np.sort(rng.choice(n, size=n_draws, replace=False))


def _cable_params(cable: CableRun, idx, bench_effects: bool, own_offsets: bool) -> dict:
    from .hysteresis import law_for

    names = ["EJ_min", "beta_material", *law_for(cable.law).parameter_names]
    if own_offsets:
        names += [n for n in ("a1", "a2") if n in cable.draws]
    if bench_effects:
        names += [n for n in _EFFECT_PARAMS if n in cable.draws]
    return {n: cable.draws[n][idx] for n in names}


def _tolerance(designs, own_offsets: bool) -> dict:
    """The tolerances drawn: the damper's (:meth:`Damper.tolerances`), without fields that are zero in
    every design and, for the calibration damper, without its offsets (the posterior's)."""
    return {k: float(v) for k, v in designs[0].tolerances().items()
            if any(getattr(d, k) != 0.0 for d in designs) and not (own_offsets and k in ("a1", "a2"))}


def _unit_draws(tolerance: dict, n: int, rng) -> dict:
    """``U(-1, 1)`` per toleranced field (sorted by name, so a seed fixes every field's draws)."""
    return {k: rng.uniform(-1.0, 1.0, n) for k in sorted(tolerance)}


def _geometry(damper: Damper, tolerance: dict, units: dict) -> dict:
    """Per-draw geometry ``nominal + |nominal| pct/100 u`` of the toleranced fields (zero stays zero)."""
    out = {}
    for k, u in units.items():
        v = getattr(damper, k)
        if v != 0.0:
            out[k] = v + abs(v) * tolerance[k] / 100.0 * u
    return out


# --- solving -----------------------------------------------------------------------------------------

def _x0(mode: str, level: float, freq_hz):
    """Clamp amplitude per line [m, 0-peak] of one test condition."""
    f = np.asarray(freq_hz, float)
    if mode == "amplitude":
        return np.full(f.shape, level / 2 * 1e-3)
    return level / (2 * np.pi * f)


def _evaluate(law: str, effects, damper: Damper, freq_hz, x0, params: dict, n_sets: int) -> dict:
    """The cable at every (set, line) of one sweep, in chunks of sets (bounded memory).

    Returns ``fuu`` (S, F) complex (NaN where a set is outside the law's domain or Newton did not
    converge), ``cmax`` (S, F) the largest curvature amplitude along the arms [1/m], ``fold`` and
    ``converged`` (S, F) bool.
    """
    from .cable_fit import CableForward

    f = np.asarray(freq_hz, float)
    fwd = CableForward(law, 2e3 * x0, np.zeros(f.size, dtype=int), tuple(effects))
    step = max(1, _CHUNK // f.size)
    parts = []
    for start in range(0, n_sets, step):
        sub = {k: v[start:start + step] for k, v in params.items()}
        st, fm = fwd.state(damper, f, continuation=True, **sub)
        conv = st.converged & np.isfinite(fm)
        parts.append((np.where(conv, fm, np.nan), np.where(conv, st.curvature_range[..., 1], np.nan), st.fold, conv))
    fuu, cmax, fold, conv = (np.concatenate(p, axis=0) for p in zip(*parts))
    return {"fuu": fuu, "cmax": cmax, "fold": fold, "converged": conv}


def _quantiles(x, axis=0) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN lines stay NaN
        return np.nanquantile(x, QUANTILES, axis=axis)


def _fine_grid(freq_hz) -> np.ndarray:
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


def _resonances(f_fine, fuu, x0, level: float) -> list:
    """Resonances (see the module docstring) from ``f_uu`` (S, F_fine) on the geometric grid ``f_fine``
    at clamp amplitudes ``x0`` (F_fine,) [m]."""
    from scipy.signal import find_peaks

    omega = 2 * np.pi * f_fine
    with np.errstate(divide="ignore", invalid="ignore"):
        resistance = fuu.imag / omega
        logr = np.where(resistance > 0, np.log(np.where(resistance > 0, resistance, 1.0)), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(logr, axis=0)
    ok = np.isfinite(med)
    if ok.sum() < 3:
        return []
    med = np.where(ok, med, np.nanmin(med[ok]))
    peaks, _ = find_peaks(med, prominence=PROMINENCE)
    # windows between the minima of the median curve that separate neighbouring peaks
    bounds = [0] + [int(a + np.argmin(med[a:b + 1])) for a, b in zip(peaks[:-1], peaks[1:])] + [f_fine.size - 1]
    h = np.log(f_fine[1] / f_fine[0])
    filled = np.where(np.isfinite(logr), logr, -np.inf)
    rows = np.arange(filled.shape[0])
    out = []
    for k in range(peaks.size):  # a handful of peaks; vectorised over the draws
        a, b = bounds[k], bounds[k + 1]
        sub = filled[:, a:b + 1]
        # each draw's local maximum nearest the median's peak (a window may also hold a rising edge)
        top = np.zeros(sub.shape, dtype=bool)
        top[:, 1:-1] = (sub[:, 1:-1] >= sub[:, :-2]) & (sub[:, 1:-1] > sub[:, 2:]) & np.isfinite(sub[:, 1:-1])
        dist = np.where(top, np.abs(np.arange(sub.shape[1]) - (peaks[k] - a))[None, :], sub.shape[1])
        j = np.argmin(dist, axis=1)
        jj = np.clip(j, 1, sub.shape[1] - 2)
        y0, y1, y2 = sub[rows, jj - 1], sub[rows, jj], sub[rows, jj + 1]
        interior = top[rows, j] & np.isfinite(y0) & np.isfinite(y2)
        if not interior.any():
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            curv = y0 - 2 * y1 + y2
            delta = np.clip(np.where(curv < 0, 0.5 * (y0 - y2) / np.where(curv < 0, curv, -1.0), 0.0), -0.5, 0.5)
        fk = f_fine[a + jj] * np.exp(delta * h)
        rk = np.exp(y1 - 0.25 * (y0 - y2) * delta)  # the parabola's top
        xk = np.interp(np.log(fk), np.log(f_fine), x0)
        pk = 0.5 * rk * (2 * np.pi * fk * xk) ** 2
        fq, pq = _quantiles(fk[interior]), _quantiles(pk[interior])
        out.append(Resonance(level=float(level), index=len(out) + 1, freq_hz=tuple(map(float, fq)),
                             power_w=tuple(map(float, pq)), share=float(interior.mean())))
    return out


def _flags(top, calibrated) -> np.ndarray:
    """Extrapolated lines from the median over draws of the largest arm curvature ``top`` (..., F)."""
    lo, hi = calibrated
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return np.zeros(top.shape, dtype=bool)
    return (top > hi * (1 + EXTRAPOLATION_MARGIN)) | (top < lo / (1 + EXTRAPOLATION_MARGIN))


# --- the model's error, as the calibration showed it ------------------------------------------------

@dataclass(frozen=True)
class ModelError:
    """The calibration's residual scale per amplitude: rms over its lines at that amplitude of the run
    means about the median model curve (draws of the posterior through the calibration's own model).

    Attributes
    ----------
    amplitude_mm_pp : ndarray, shape (K,)
        The calibrated amplitudes, increasing.
    logmag_sd : ndarray, shape (K,)
        rms residual of ln|f| [1].
    phase_sd_deg : ndarray, shape (K,)
        rms residual of the phase [deg].
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


def model_error_of(run, *, n_draws: int = 50, seed: int = 0) -> ModelError:
    """:class:`ModelError` of a stored cable fit: its model on its own lines (the calibration damper, its
    tests' amplitudes, each test one sweep, its measurement-chain effects) for ``n_draws`` posterior
    draws, the median curve against the stored run means.

    Raises
    ------
    InputError
        The run does not store the calibration damper's values or its lines.
    """
    from .stats import read_netcdf

    cable = load_cable_run(run)
    if cable.calibration is None:
        raise InputError(f"{cable.path}: summary.json has no damper_values: the calibration's residuals cannot be formed")
    idata = read_netcdf(cable.path / "posterior.nc")
    try:
        const, obs = idata.constant_data, idata.observed_data
        f = np.asarray(const["freq_hz"], float)
        amp = np.asarray(const["amplitude_mm_pp"], float)
        test = np.asarray(const["line_test"]).astype(str)
        ybar = np.stack([np.asarray(obs["logmag_mean"], float), np.asarray(obs["phase_mean"], float)])
    except (AttributeError, KeyError) as e:
        raise InputError(f"{cable.path}: posterior.nc lacks the calibration's lines ({e})") from None
    idx = _subset(cable, n_draws, _streams(seed)[0])
    params = {n: cable.draws[n][idx] for n in cable.summary.get("parameters", cable.draws) if n in cable.draws}
    seg = np.concatenate([[0], np.cumsum(test[1:] != test[:-1])])
    from .cable_fit import CableForward

    fwd = CableForward(cable.law, amp, seg, tuple(cable.summary.get("effects", ())))
    step = max(1, _CHUNK // f.size)
    fm = np.concatenate([fwd.state(cable.calibration, f, continuation=True,
                                   **{k: v[i:i + step] for k, v in params.items()})[1]
                         for i in range(0, idx.size, step)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mu = np.stack([np.nanmedian(np.log(np.abs(fm)), axis=0), np.nanmedian(np.angle(fm), axis=0)])
    r = ybar - mu
    r[1] = np.remainder(r[1] + np.pi, 2 * np.pi) - np.pi
    levels = np.unique(amp)
    sd = np.array([[np.sqrt(np.nanmean(r[q, amp == a] ** 2)) for a in levels] for q in (0, 1)])
    return ModelError(amplitude_mm_pp=levels, logmag_sd=sd[0], phase_sd_deg=np.degrees(sd[1]))


_ERROR_SAMPLES = 4000  # (draw, model-error) samples per line behind the bands with model error


def _bands(fuu, x0, f, error, rng):
    """Quantiles (3, F) of |f|, phase [deg] and power from the draws ``fuu`` (S, F), with the model
    error ``(logmag_sd, phase_sd_rad)`` per line (each (F,)) added when given."""
    mag, phase = np.abs(fuu), np.angle(fuu)  # a passive draw's phase lies in (0, pi): no wrap
    if error is not None:
        reps = max(1, -(-_ERROR_SAMPLES // fuu.shape[0]))
        sd_m, sd_p = error
        e = rng.standard_normal((2, reps) + fuu.shape)
        # the phase error is added, not wrapped: about 180 deg it may pass it, as measured phases do
        mag, phase = (mag[None] * np.exp(e[0] * sd_m)).reshape(-1, f.size), (phase[None] + e[1] * sd_p).reshape(-1, f.size)
    return (_quantiles(mag), _quantiles(np.degrees(phase)), _quantiles(0.5 * 2 * np.pi * f * mag * np.sin(phase) * x0**2))


# --- the prediction ---------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Prediction:
    """The posterior predictive of a damper built with a calibrated cable (:func:`predict`).

    Attributes
    ----------
    damper : str
        The predicted damper's name.
    damper_values : dict
        Its nominal values (the :class:`sbcal.damper.Damper` fields).
    cable : str
        The cable run directory.
    cable_damper, state, law : str
        The calibration damper, the cable state and the law family.
    mode : str
        ``"amplitude"`` (constant clamp amplitude) or ``"velocity"`` (constant clamp velocity).
    levels : ndarray, shape (L,)
        The test conditions: amplitudes [mm p-p] or velocities [m/s].
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
        The line bends the arms outside the calibrated range (:data:`EXTRAPOLATION_MARGIN`).
    fold_share, converged_share : ndarray, shape (L, F)
        Fraction of the draws with two steady states at the line (the sweep's branch is used), and
        with a converged solve (the others are left out of the quantiles).
    resonances : tuple of Resonance
        Every condition's resonances (``level`` says whose).
    calibrated_curvature : tuple of float
        The calibrated curvature range [1/m] (least, largest).
    n_draws : int
        Posterior draws used (each with its own geometry draw).
    seed : int
    tolerance_pct : dict
        +- tolerance [%] per damper field drawn (uniform).
    own_offsets : bool
        The posterior's ``a1``, ``a2`` were used (the calibration damper itself).
    bench_effects : bool
        The calibration bench's measurement-chain effects were applied.
    model_error : dict or None
        The :class:`ModelError` added to the bands (``as_dict()``), None when not.
    warnings : tuple of str
    versions : dict
    """

    damper: str
    damper_values: dict
    cable: str
    cable_damper: str
    state: str
    law: str
    mode: str
    levels: np.ndarray
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
    n_draws: int
    seed: int
    tolerance_pct: dict
    own_offsets: bool
    bench_effects: bool
    model_error: dict | None = None
    warnings: tuple = ()
    versions: dict = field(default_factory=dict)

    def labels(self) -> list:
        """The ``test`` label of each condition: ``1-1`` (1 mm p-p), ``v0.1`` (0.1 m/s)."""
        from .bench import test_label

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
        return {
            "damper": self.damper, "damper_values": self.damper_values, "cable": self.cable,
            "cable_damper": self.cable_damper, "state": self.state, "law": self.law, "mode": self.mode,
            "levels": [float(v) for v in self.levels], "tests": self.labels(),
            "freq_hz": self.freq_hz.tolist(),
            "curvature_max": self.curvature_max.tolist(), "fold_share": self.fold_share.tolist(),
            "converged_share": self.converged_share.tolist(),
            "resonances": [dataclasses.asdict(r) for r in self.resonances],
            "calibrated_curvature": list(self.calibrated_curvature),
            "extrapolated_lines": int(self.extrapolated.sum()),
            "n_draws": self.n_draws, "seed": self.seed, "tolerance_pct": self.tolerance_pct,
            "own_offsets": self.own_offsets, "bench_effects": self.bench_effects, "model_error": self.model_error,
            "warnings": list(self.warnings), "versions": self.versions,
        }


def _levels(cable: CableRun, amplitude_mm_pp, velocity_m_s):
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


def _frequencies(freq_hz) -> np.ndarray:
    from .fem import STANDARD_GRID_HZ

    if freq_hz is None:
        return STANDARD_GRID_HZ.copy()
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise InputError("frequencies: expected finite values > 0 [Hz]")
    return np.unique(f)  # one stepped-sine sweep up


def _draw_checks(n_draws):
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
        Frequency lines [Hz] (default :data:`sbcal.fem.STANDARD_GRID_HZ`); sorted, one sweep up.
    n_draws : int
        Posterior draws used (a random subset; all when the posterior has fewer).
    seed : int
        Fixes the subset and the geometry draws.
    bench_effects : bool
        Apply the calibration bench's fitted measurement-chain effects.
    model_error : bool
        Add the calibration's residual scale to the bands (:func:`model_error_of`; module docstring).
        Off, the bands are the posterior's and the tolerances' alone.

    Returns
    -------
    Prediction

    Raises
    ------
    InputError
        A missing run or damper file, amplitudes or velocities <= 0, bad frequencies.
    """
    from .runs import versions

    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    mode, levels = _levels(cable, amplitude_mm_pp, velocity_m_s)
    f = _frequencies(freq_hz)
    n_draws = _draw_checks(n_draws)
    own = _is_calibration_damper(cable, damper)
    pick, geo = _streams(seed)
    idx = _subset(cable, n_draws, pick)
    n = idx.size
    errors, notes = None, []
    if model_error:
        try:
            errors = model_error_of(cable, seed=seed)
        except InputError as e:
            notes.append(f"no model error in the bands: {e}")
    noise = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
    tolerance = _tolerance([damper], own)
    params = dict(_cable_params(cable, idx, bench_effects, own),
                  **_geometry(damper, tolerance, _unit_draws(tolerance, n, geo)))
    effects = tuple(cable.summary.get("effects", ())) if bench_effects else ()
    fine = _fine_grid(f)
    shape = (levels.size, f.size)
    out = {k: np.empty((levels.size, 3, f.size)) for k in ("stiffness", "phase", "power")}
    cmax, extra = np.empty(shape), np.zeros(shape, dtype=bool)
    fold, conv = np.empty(shape), np.empty(shape)
    amps = np.empty(shape)
    resonances = []
    for i, level in enumerate(levels):  # a handful of test conditions; each call is vectorised
        x0 = _x0(mode, level, f)
        r = _evaluate(cable.law, effects, damper, f, x0, params, n)
        err = errors.at(2e3 * x0) if errors is not None else None
        out["stiffness"][i], out["phase"][i], out["power"][i] = _bands(r["fuu"], x0, f, err, noise)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            cmax[i] = np.nanmedian(r["cmax"], axis=0)
        extra[i] = _flags(cmax[i], cable.curvature_range)
        fold[i], conv[i] = r["fold"].mean(axis=0), r["converged"].mean(axis=0)
        amps[i] = 2e3 * x0
        xf = _x0(mode, level, fine)
        rf = _evaluate(cable.law, effects, damper, fine, xf, params, n)
        resonances += _resonances(fine, rf["fuu"], xf, level)
    notes = [w for w in (cable.convergence_warning(),) if w] + notes
    if not np.all(np.isfinite(cable.curvature_range)):
        notes.append(f"{cable.path}: no calibrated curvature range stored (tests_reached): extrapolation not assessed")
    if conv.min() < 1:
        notes.append(f"the cable model did not converge for {100 * (1 - conv.mean()):.2g} % of the (draw, line) "
                     "pairs: left out of the bands")
    values = {k: v for k, v in dataclasses.asdict(damper).items() if k not in ("tolerance",)}
    return Prediction(
        damper=damper.name, damper_values=values, cable=str(cable.path), cable_damper=cable.damper,
        state=cable.state, law=cable.law, mode=mode, levels=levels, freq_hz=f, amplitude_mm_pp=amps,
        stiffness_n_per_m=out["stiffness"], phase_deg=out["phase"], power_w=out["power"], curvature_max=cmax,
        extrapolated=extra, fold_share=fold, converged_share=conv, resonances=tuple(resonances),
        calibrated_curvature=tuple(float(v) for v in cable.curvature_range), n_draws=int(n), seed=int(seed),
        tolerance_pct={k: float(v) for k, v in tolerance.items()}, own_offsets=own, bench_effects=bool(bench_effects),
        model_error=errors.as_dict() if errors is not None else None, warnings=tuple(notes), versions=versions())


# --- design sweeps ----------------------------------------------------------------------------------

def parse_sweep(spec: str) -> tuple[str, np.ndarray]:
    """``"cable.length1_m=0.15:0.30:7"`` -> ``("cable.length1_m", 7 values from 0.15 to 0.30)``."""
    key, sep, rng = str(spec).partition("=")
    key = key.strip()
    parts = rng.split(":")
    if not sep or len(parts) != 3:
        raise InputError(f"--sweep {spec!r}: expected NAME=START:STOP:N (e.g. cable.length1_m=0.15:0.30:7)")
    if key not in FILE_KEYS:
        raise InputError(f"--sweep {spec!r}: unknown damper field {key!r}; known: {', '.join(FILE_KEYS)}")
    try:
        start, stop, n = float(parts[0]), float(parts[1]), float(parts[2])
    except ValueError:
        raise InputError(f"--sweep {spec!r}: START, STOP and N must be numbers") from None
    if not (np.isfinite(start) and np.isfinite(stop)) or n != int(n) or n < 2:
        raise InputError(f"--sweep {spec!r}: expected finite START and STOP and an integer N >= 2")
    return key, np.linspace(start, stop, int(n))


@dataclass(frozen=True, eq=False)
class SweepResult:
    """Resonances and peak dissipated power against one design variable (:func:`sweep`).

    Attributes
    ----------
    damper, field : str
        The base damper's name and the swept damper-file field (``"cable.length1_m"``).
    values : ndarray, shape (V,)
        The field's values (SI, as in the damper file).
    cable, cable_damper, state, law, mode : str
        As in :class:`Prediction`.
    levels : ndarray, shape (L,)
        The test conditions (amplitudes [mm p-p] or velocities [m/s]).
    resonance_hz : ndarray, shape (V, L, K, 3)
        The :data:`QUANTILES` of the frequency [Hz] of resonance track k (NaN at values where the
        track has no resonance). A track follows one resonance across the values (:data:`TRACK_STEP`);
        tracks are numbered by their median frequency.
    resonance_share : ndarray, shape (V, L, K)
        Fraction of the draws that have it.
    peak_power_w : ndarray, shape (V, L, 3)
        Quantiles of each draw's largest dissipated power over the band [W].
    extrapolated : ndarray of bool, shape (V, L)
        Some line of the band bends the arms outside the calibrated range.
    fold_share : ndarray, shape (V, L)
        Fraction of (draw, line) pairs with two steady states.
    n_draws, seed, tolerance_pct, own_offsets, bench_effects, warnings, versions
        As in :class:`Prediction`.
    """

    damper: str
    field: str
    values: np.ndarray
    cable: str
    cable_damper: str
    state: str
    law: str
    mode: str
    levels: np.ndarray
    resonance_hz: np.ndarray
    resonance_share: np.ndarray
    peak_power_w: np.ndarray
    extrapolated: np.ndarray
    fold_share: np.ndarray
    n_draws: int
    seed: int
    tolerance_pct: dict
    own_offsets: bool
    bench_effects: bool
    warnings: tuple = ()
    versions: dict = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """One row per (value, condition): ``resonance<k>_hz`` (median), ``_q05``, ``_q95``, ``_share``,
        ``peak_power_w`` (median), ``_q05``, ``_q95``, ``extrapolated``."""
        level = _MODES[self.mode]
        rows = []
        for v, value in enumerate(self.values):
            for i, lv in enumerate(self.levels):
                row = {"damper": self.damper, "field": self.field, "value": float(value), level: float(lv)}
                for k in range(self.resonance_hz.shape[2]):
                    q = self.resonance_hz[v, i, k]
                    row.update({f"resonance{k + 1}_hz": q[1], f"resonance{k + 1}_q05": q[0],
                                f"resonance{k + 1}_q95": q[2], f"resonance{k + 1}_share": self.resonance_share[v, i, k]})
                p = self.peak_power_w[v, i]
                row.update({"peak_power_w": p[1], "peak_power_q05": p[0], "peak_power_q95": p[2],
                            "extrapolated": bool(self.extrapolated[v, i])})
                rows.append(row)
        return pd.DataFrame(rows)

    def summary(self) -> dict:
        return {"damper": self.damper, "field": self.field, "values": self.values.tolist(), "cable": self.cable,
                "cable_damper": self.cable_damper, "state": self.state, "law": self.law, "mode": self.mode,
                "levels": self.levels.tolist(), "resonance_hz": _jsonable(self.resonance_hz),
                "resonance_share": _jsonable(self.resonance_share), "peak_power_w": _jsonable(self.peak_power_w),
                "extrapolated": self.extrapolated.tolist(), "fold_share": self.fold_share.tolist(),
                "n_draws": self.n_draws, "seed": self.seed, "tolerance_pct": self.tolerance_pct,
                "own_offsets": self.own_offsets, "bench_effects": self.bench_effects, "warnings": list(self.warnings),
                "versions": self.versions}


def _jsonable(a):
    """NaN -> None, nested lists."""
    a = np.asarray(a, float)
    return [_jsonable(x) for x in a] if a.ndim else (None if not np.isfinite(a) else float(a))


def _unjson(x) -> np.ndarray:
    return np.array(json.loads(json.dumps(x).replace("null", "NaN")), dtype=float)


TRACK_STEP = 0.4
"""A resonance at the next design value continues a track when its frequency is within this distance
in ln f of the track's last one (a factor 1.5); otherwise it starts a track of its own. The closest
pairs are joined first, so neighbouring modes keep their tracks; a sweep too coarse for a mode to move
less than that between values splits its track."""


def _tracks(per_value: list) -> list:
    """Follow resonances across design values: ``per_value[v]`` the resonances at value v (by
    frequency); returns tracks ``[(v, Resonance), ...]``, sorted by their median frequency. Greedy:
    the closest (track, resonance) pairs in ln f are joined first."""
    tracks, last = [], []  # last: (ln f of the track's latest resonance, value index) per track
    for v, found in enumerate(per_value):
        lf = [np.log(r.freq_hz[1]) for r in found]
        pairs = sorted((abs(a - b[0]), t, j) for t, b in enumerate(last) for j, a in enumerate(lf)
                       if b[1] == v - 1 and abs(a - b[0]) <= TRACK_STEP)
        used_t, used_j = set(), set()
        for _, t, j in pairs:
            if t not in used_t and j not in used_j:
                tracks[t].append((v, found[j]))
                last[t] = (lf[j], v)
                used_t.add(t)
                used_j.add(j)
        for j, r in enumerate(found):
            if j not in used_j:
                tracks.append([(v, r)])
                last.append((lf[j], v))
    return sorted(tracks, key=lambda tr: np.median([r.freq_hz[1] for _, r in tr]))


def sweep(run, damper, field_key: str, values, *, amplitude_mm_pp=None, velocity_m_s=None, freq_hz=None,
          n_draws: int = 200, seed: int = 0, bench_effects: bool = False) -> SweepResult:
    """Resonance frequencies and peak dissipated power against one damper-file field.

    Every value gets the same posterior draws and the same relative geometry draws (common random
    numbers: the curves against the value are smooth); each value's damper is the base ``damper``
    with the field replaced (and toleranced like the nominal value). All (value, draw) sets of one
    test condition are solved in one vectorised pass.

    Parameters
    ----------
    run, damper, amplitude_mm_pp, velocity_m_s, n_draws, seed, bench_effects
        As :func:`predict`.
    field_key : str
        A damper-file field (:data:`sbcal.damper.FILE_KEYS`), e.g. ``"cable.length1_m"``, ``"mass2.mass_kg"``.
    values : array_like, shape (V,)
        Its values [SI].
    freq_hz : array_like, optional
        The band searched for resonances (its least and largest value; default 4-40 Hz).

    Returns
    -------
    SweepResult
    """
    from .runs import versions

    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    if field_key not in FILE_KEYS:
        raise InputError(f"sweep: unknown damper field {field_key!r}; known: {', '.join(FILE_KEYS)}")
    attr = FILE_KEYS[field_key]
    if attr == "ej_static":
        raise InputError(f"sweep: {field_key} does not change a prediction (the cable's rigidity is the calibration's)")
    vals = np.atleast_1d(np.asarray(values, dtype=float))
    if vals.ndim != 1 or vals.size == 0:
        raise InputError("sweep: expected one or more values")
    designs = [with_value(damper, field_key, v, where="sweep") for v in vals]  # checked as the file reader checks
    mode, levels = _levels(cable, amplitude_mm_pp, velocity_m_s)
    fine = _fine_grid(_frequencies(freq_hz))
    n_draws = _draw_checks(n_draws)
    own = _is_calibration_damper(cable, damper) and attr not in ("a1", "a2")
    pick, geo = _streams(seed)
    idx = _subset(cable, n_draws, pick)
    n, nv = idx.size, vals.size
    tolerance = _tolerance(designs, own)
    units = _unit_draws(tolerance, n, geo)
    per_value = [_geometry(d, tolerance, units) for d in designs]
    names = sorted(set().union(*per_value) | {attr})
    params = {k: np.tile(v, nv) for k, v in _cable_params(cable, idx, bench_effects, own).items()}
    for k in names:
        params[k] = np.concatenate([g.get(k, np.full(n, getattr(d, k))) for g, d in zip(per_value, designs)])
    effects = tuple(cable.summary.get("effects", ())) if bench_effects else ()
    nl = levels.size
    res = [[[] for _ in range(nl)] for _ in range(nv)]
    peak = np.full((nv, nl, 3), np.nan)
    extra = np.zeros((nv, nl), dtype=bool)
    fold = np.zeros((nv, nl))
    conv = np.ones((nv, nl))
    for i, level in enumerate(levels):
        xf = _x0(mode, level, fine)
        r = _evaluate(cable.law, effects, damper, fine, xf, params, n * nv)
        power = (0.5 * 2 * np.pi * fine * r["fuu"].imag * xf**2).reshape(nv, n, fine.size)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            peak[:, i] = _quantiles(np.nanmax(power, axis=2), axis=1).T
            top = np.nanmedian(r["cmax"].reshape(nv, n, -1), axis=1)
        extra[:, i] = _flags(top, cable.curvature_range).any(axis=1)
        fold[:, i] = r["fold"].reshape(nv, -1).mean(axis=1)
        conv[:, i] = r["converged"].reshape(nv, -1).mean(axis=1)
        fuu = r["fuu"].reshape(nv, n, fine.size)
        for v in range(nv):  # peak finding per design value (a handful); vectorised over the draws
            res[v][i] = _resonances(fine, fuu[v], xf, level)
    tracks = [_tracks([res[v][i] for v in range(nv)]) for i in range(nl)]
    k_max = max((len(t) for t in tracks), default=0)
    hz = np.full((nv, nl, k_max, 3), np.nan)
    share = np.zeros((nv, nl, k_max))
    for i, level_tracks in enumerate(tracks):
        for k, track in enumerate(level_tracks):
            for v, r_ in track:
                hz[v, i, k], share[v, i, k] = r_.freq_hz, r_.share
    notes = [w for w in (cable.convergence_warning(),) if w]
    if conv.min() < 1:
        notes.append(f"the cable model did not converge for {100 * (1 - conv.mean()):.2g} % of the (draw, line) pairs")
    return SweepResult(damper=damper.name, field=field_key, values=vals, cable=str(cable.path),
                       cable_damper=cable.damper, state=cable.state, law=cable.law, mode=mode, levels=levels,
                       resonance_hz=hz, resonance_share=share, peak_power_w=peak, extrapolated=extra,
                       fold_share=fold, n_draws=int(n), seed=int(seed),
                       tolerance_pct={k: float(v) for k, v in tolerance.items()}, own_offsets=own,
                       bench_effects=bool(bench_effects), warnings=tuple(notes), versions=versions())


# --- the store -------------------------------------------------------------------------------------

def prediction_dir(cable_run, damper: str, state: str) -> Path:
    """``<runs>/<calibration damper>/predict-<damper>-<state>``: beside the cable run it comes from."""
    return Path(cable_run).parent / f"predict-{damper}-{state}"


def write_csv(result, path) -> None:
    """Write a :class:`Prediction` or :class:`SweepResult` (its ``to_frame()``) as CSV, atomically;
    ``extrapolated`` as ``true``/``false``."""
    _write_csv(result.to_frame(), path)


def _write_csv(frame: pd.DataFrame, path) -> None:
    out = frame.copy()
    out["extrapolated"] = out["extrapolated"].map({True: "true", False: "false"})
    with atomic_path(path, ".csv") as tmp:
        out.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")


def store_prediction(pred: Prediction, directory=None, *, meta: dict | None = None, figure: bool = True) -> Path:
    """Write ``prediction.csv``, ``prediction.png`` and (last) ``summary.json``, each atomically, into
    ``directory`` (default :func:`prediction_dir`); returns the directory."""
    d = Path(directory) if directory is not None else prediction_dir(pred.cable, pred.damper, pred.state)
    _write_csv(pred.to_frame(), d / "prediction.csv")
    if figure:
        plot_prediction(pred, d / "prediction.png")
    write_json(d / "summary.json", dict(pred.summary(), **(meta or {})), indent=1)
    return d


def _read_summary(directory, what: str) -> dict:
    p = Path(directory) / "summary.json"
    if not p.is_file():
        raise InputError(f"{directory}: no stored {what} (summary.json missing)")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not valid JSON ({e.msg}, line {e.lineno})") from None


def read_prediction(directory) -> Prediction:
    """A stored prediction (:func:`store_prediction`) back as a :class:`Prediction`."""
    s = _read_summary(directory, "prediction")
    try:
        frame = pd.read_csv(Path(directory) / "prediction.csv")
        f = np.asarray(s["freq_hz"], float)
        nl, nf = len(s["levels"]), f.size
        by = {t: g for t, g in frame.groupby("test", sort=False)}

        def col(name):
            return np.stack([by[t][name].to_numpy(float) for t in s["tests"]]).reshape(nl, nf)

        def band(stem, mid):
            return np.stack([col(f"{stem}_q05"), col(mid), col(f"{stem}_q95")], axis=1)

        extra = np.stack([by[t]["extrapolated"].astype(str).str.lower().eq("true").to_numpy() for t in s["tests"]])
        return Prediction(
            damper=s["damper"], damper_values=s["damper_values"], cable=s["cable"], cable_damper=s["cable_damper"],
            state=s["state"], law=s["law"], mode=s["mode"], levels=np.asarray(s["levels"], float), freq_hz=f,
            amplitude_mm_pp=col("amplitude_mm_pp"), stiffness_n_per_m=band("stiffness", "stiffness_n_per_m"),
            phase_deg=band("phase", "phase_deg"), power_w=band("power", "power_w"),
            curvature_max=np.asarray(s["curvature_max"], float), extrapolated=extra,
            fold_share=np.asarray(s["fold_share"], float), converged_share=np.asarray(s["converged_share"], float),
            resonances=tuple(Resonance(**{**r, "freq_hz": tuple(r["freq_hz"]), "power_w": tuple(r["power_w"])})
                             for r in s["resonances"]),
            calibrated_curvature=tuple(s["calibrated_curvature"]), n_draws=s["n_draws"], seed=s["seed"],
            tolerance_pct=s["tolerance_pct"], own_offsets=s["own_offsets"], bench_effects=s["bench_effects"],
            model_error=s.get("model_error"), warnings=tuple(s["warnings"]), versions=s.get("versions", {}))
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise InputError(f"{directory}: not a prediction written by sbcal predict ({type(e).__name__}: {e})") from None


def store_sweep(result: SweepResult, directory=None, *, meta: dict | None = None, figure: bool = True) -> Path:
    """Write ``sweep.csv``, ``sweep.png`` and (last) ``summary.json`` into ``directory`` (default
    ``<prediction_dir>/sweep-<field>``); returns the directory."""
    d = Path(directory) if directory is not None else (
        prediction_dir(result.cable, result.damper, result.state) / f"sweep-{result.field}")
    _write_csv(result.to_frame(), d / "sweep.csv")
    if figure:
        plot_sweep(result, d / "sweep.png")
    write_json(d / "summary.json", dict(result.summary(), **(meta or {})), indent=1)
    return d


def read_sweep(directory) -> SweepResult:
    """A stored sweep (:func:`store_sweep`) back as a :class:`SweepResult`."""
    s = _read_summary(directory, "sweep")
    try:
        nv, nl = len(s["values"]), len(s["levels"])
        hz = _unjson(s["resonance_hz"]).reshape(nv, nl, -1, 3)
        return SweepResult(
            damper=s["damper"], field=s["field"], values=np.asarray(s["values"], float), cable=s["cable"],
            cable_damper=s["cable_damper"], state=s["state"], law=s["law"], mode=s["mode"],
            levels=np.asarray(s["levels"], float), resonance_hz=hz,
            resonance_share=_unjson(s["resonance_share"]).reshape(nv, nl, -1),
            peak_power_w=_unjson(s["peak_power_w"]).reshape(nv, nl, 3),
            extrapolated=np.asarray(s["extrapolated"], bool), fold_share=np.asarray(s["fold_share"], float),
            n_draws=s["n_draws"], seed=s["seed"], tolerance_pct=s["tolerance_pct"], own_offsets=s["own_offsets"],
            bench_effects=s["bench_effects"], warnings=tuple(s["warnings"]), versions=s.get("versions", {}))
    except (KeyError, ValueError, TypeError) as e:
        raise InputError(f"{directory}: not a sweep written by sbcal predict ({type(e).__name__}: {e})") from None


def stored_predictions(damper_dir) -> list:
    """Every stored prediction beside a damper's cable runs: ``[(directory, Prediction or None,
    [SweepResult, ...])]``, sorted by directory name."""
    out = []
    root = Path(damper_dir)
    for d in sorted(root.glob("predict-*")) if root.is_dir() else []:
        if not d.is_dir():
            continue
        pred = read_prediction(d) if (d / "summary.json").is_file() else None
        sweeps = [read_sweep(s) for s in sorted(d.glob("sweep-*")) if (s / "summary.json").is_file()]
        if pred is not None or sweeps:
            out.append((d, pred, sweeps))
    return out


# --- figures -----------------------------------------------------------------------------------------

def _save(fig, path) -> Path:
    return save_png(fig, path, dpi=90)


def _spans(f, mask):
    """Contiguous runs of True lines as (lo, hi) frequency spans, half a line step either side."""
    f = np.asarray(f, float)
    edges = np.concatenate([[f[0] - (f[1] - f[0]) / 2 if f.size > 1 else f[0] * 0.98],
                            (f[1:] + f[:-1]) / 2, [f[-1] + (f[-1] - f[-2]) / 2 if f.size > 1 else f[0] * 1.02]])
    out, start = [], None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((edges[start], edges[i]))
            start = None
    return out


def plot_prediction(pred: Prediction, path, *, observed: dict | None = None) -> Path:
    """Magnitude, phase and dissipated power per condition: median, 90 % band, resonances (triangles
    with their 90 % range), extrapolated lines shaded (hatched). ``observed``: ``{level: (freq_hz,
    stiffness_n_per_m, phase_deg)}`` recorded run means to overlay."""
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    unit = "mm p-p" if pred.mode == "amplitude" else "m/s"
    f = pred.freq_hz
    shaded = False
    for i, lv in enumerate(pred.levels):
        color = f"C{i % 10}"
        label = f"{lv:g} {unit}"
        for ax, q in zip(axes, (pred.stiffness_n_per_m[i], pred.phase_deg[i], pred.power_w[i])):
            ax.fill_between(f, q[0], q[2], color=color, alpha=0.22, lw=0)
            ax.plot(f, q[1], color=color, lw=1.3, label=label if ax is axes[0] else None)
            for lo, hi in _spans(f, pred.extrapolated[i]):
                ax.axvspan(lo, hi, facecolor="none", edgecolor=color, hatch="///", alpha=0.5, lw=0,
                           label="extrapolated (beyond the calibrated curvature)" if not shaded and ax is axes[0] else None)
                shaded = True
        for r in pred.resonances:
            if r.level == lv:
                f05, f50, f95 = r.freq_hz
                axes[2].errorbar([f50], [r.power_w[1]], xerr=[[f50 - f05], [f95 - f50]], fmt="v", color=color, ms=6,
                                 capsize=3)
        if observed and lv in observed:
            fo, mo, po = (np.asarray(a, float) for a in observed[lv])
            x0 = _x0(pred.mode, lv, fo)
            axes[0].plot(fo, mo, ".", color=color, mec="k", mew=0.4, ms=6)
            axes[1].plot(fo, po, ".", color=color, mec="k", mew=0.4, ms=6)
            axes[2].plot(fo, 0.5 * 2 * np.pi * fo * mo * np.sin(np.radians(po)) * x0**2, ".", color=color, mec="k",
                         mew=0.4, ms=6)
    axes[0].set(yscale="log", ylabel="|F/X| [N/m]")
    axes[1].set(ylabel="phase [deg]")
    axes[2].set(yscale="log", ylabel="dissipated power [W]", xlabel="frequency [Hz]")
    mode = "constant amplitude" if pred.mode == "amplitude" else "constant velocity"
    axes[0].set_title(f"{pred.damper}: predicted with the {pred.cable_damper} {pred.state} cable ({pred.law}), "
                      f"{mode}; median and 90 % band of {pred.n_draws} draws" + ("; dots: recorded" if observed else ""),
                      fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def plot_sweep(result: SweepResult, path) -> Path:
    """Resonance frequencies (top) and peak dissipated power (bottom) against the design value, median
    and 90 % band per condition; values whose band bends the arms beyond the calibration hatched."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    x = result.values
    unit = "mm p-p" if result.mode == "amplitude" else "m/s"
    markers = "os^Dv<>p"
    for i, lv in enumerate(result.levels):
        color = f"C{i % 10}"
        for k in range(result.resonance_hz.shape[2]):
            q = result.resonance_hz[:, i, k]
            if not np.isfinite(q[:, 1]).any():
                continue
            axes[0].fill_between(x, q[:, 0], q[:, 2], color=color, alpha=0.18, lw=0)
            axes[0].plot(x, q[:, 1], color=color, marker=markers[k % len(markers)], ms=4, lw=1.2,
                         label=f"{lv:g} {unit}, resonance {k + 1}")
        p = result.peak_power_w[:, i]
        axes[1].fill_between(x, p[:, 0], p[:, 2], color=color, alpha=0.22, lw=0)
        axes[1].plot(x, p[:, 1], color=color, lw=1.3, label=f"{lv:g} {unit}")
        for lo, hi in _spans(x, result.extrapolated[:, i]):
            for ax in axes:
                ax.axvspan(lo, hi, facecolor="none", edgecolor=color, hatch="///", alpha=0.5, lw=0)
    axes[0].set(ylabel="resonance frequency [Hz]", title=f"{result.damper}: sweep of {result.field} "
                f"({result.cable_damper} {result.state} cable, {result.n_draws} draws; hatched: extrapolated)")
    axes[1].set(ylabel="peak dissipated power [W]", yscale="log", xlabel=result.field)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, ncol=2)
    axes[0].title.set_fontsize(9)
    fig.tight_layout()
    return _save(fig, path)


# --- the damper as a span sees it ------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CableImpedance:
    """A damper built with a calibrated cable as :class:`sbcal.span.Impedance`: one row per draw.

    ``impedance(freq_hz (F,), amplitude_m (S, F) or (1, F)) -> complex (S, F)``: ``f_uu`` [N/m] at
    the clamp amplitude ``amplitude_m`` [m, 0-peak] per draw and line, each (draw, line) its own
    steady state (no sweep history: the span has none). Module-level, picklable.

    Attributes
    ----------
    damper : Damper
        Nominal geometry (the draws' geometry is in ``params``).
    law : str
    params : dict of str -> ndarray, shape (S,)
        The cable draws and the geometry draws.
    """

    damper: Damper
    law: str
    params: dict
    model: object = field(init=False, repr=False)

    def __post_init__(self):
        from .cable import CableModel
        from .hysteresis import law_for

        object.__setattr__(self, "model", CableModel(law_for(self.law)))

    @property
    def n_draws(self) -> int:
        return int(next(iter(self.params.values())).size)

    def __call__(self, freq_hz, amplitude_m):
        f = np.atleast_1d(np.asarray(freq_hz, float))
        a = np.asarray(amplitude_m, float)
        amp = 2e3 * np.broadcast_to(a.reshape(-1, f.size), (self.n_draws, f.size))
        return self.model.dynamic_stiffness(self.damper, f, amp, **self.params)


def impedance_from_cable(run, damper, *, n_draws: int = 200, seed: int = 0) -> CableImpedance:
    """The span's :class:`sbcal.span.Impedance` of a damper built with a calibrated cable.

    Draws as :func:`predict` (posterior subset, geometry within the damper's tolerances; same
    ``seed``, same draws); draws the cable model cannot evaluate (outside the law's domain) are
    dropped. No bench effects: the span sees the damper itself.
    """
    cable = load_cable_run(run)
    damper = damper if isinstance(damper, Damper) else resolve_damper(damper)
    n_draws = _draw_checks(n_draws)
    own = _is_calibration_damper(cable, damper)
    pick, geo = _streams(seed)
    idx = _subset(cable, n_draws, pick)
    tolerance = _tolerance([damper], own)
    params = dict(_cable_params(cable, idx, False, own),
                  **_geometry(damper, tolerance, _unit_draws(tolerance, idx.size, geo)))
    imp = CableImpedance(damper=damper, law=cable.law, params=params)
    probe = imp(np.array([10.0]), np.array([[1e-4]]))[:, 0]
    keep = np.isfinite(probe)
    if not keep.any():
        raise InputError(f"{cable.path}: no posterior draw gives a finite dynamic stiffness")
    if not keep.all():
        imp = CableImpedance(damper=damper, law=cable.law, params={k: v[keep] for k, v in params.items()})
    return imp
