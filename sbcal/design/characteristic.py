"""A damper's characteristic (IEC 61897) as posterior draws, from a stored calibration.

The characteristic test of IEC 61897 sweeps the damper over a frequency range at a constant clamp
velocity (or amplitude) and reads its impedance, the power it dissipates and its resonances. From a run
store it is drawn one of two ways (``docs/compare.md``):

* **From a test's posterior** (``<runs>/<damper>/<test>/<paramset>/``), when the excitation is a constant
  amplitude the damper was tested at: per posterior draw, the damper's *true mean curve* on the test's
  lines, the model curve plus the test's model discrepancy given the runs
  (:func:`sbcal.inference.discrepancy.true_mean_draws`: the likelihood's discrepancy given the run mean,
  whose error has the runs' own covariance over the lines). Where the model follows the runs (``s`` small)
  the curve is the model's; where it misses them the curve follows the run means with their error. Every
  piece is stored with the run (model curves, runs, noise): no model solve.
* **From the cable law** (``<runs>/<damper>/cable-<state>/``), at any excitation: per draw the
  distributed cable at every line (:func:`sbcal.design.predict.predict`'s solver, the damper's own
  geometry and offsets, no bench effects), with its harmonic refit's correction where the refit was used
  (:mod:`sbcal.design.harmonics`), plus the cable fit's model error when its remainder is
  ``partial`` (:func:`sbcal.design.predict.model_error_of`); lines that bend the arms outside the calibrated
  curvature range are marked ``extrapolated`` as ``predict`` marks them.

A posterior that did not converge, or whose law is not settled, is refused: its draws are not a result.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.labels import DRY, parse_label
from ..inference.discrepancy import true_mean_draws
from ..model.damper import Damper
from .cable_run import subset_indices
from .predict import clamp_amplitude
from .resonance import resonance_draws


__all__ = ["Characteristic", "from_test", "from_cable", "power", "constant_tests"]


@dataclass(frozen=True, eq=False)
class Characteristic:
    """Posterior draws of one damper's characteristic at one excitation.

    Attributes
    ----------
    damper, state : str
        The damper and its cable state.
    source : str
        Where the draws come from: ``"test 1-1"`` or ``"cable law bouc_wen"``.
    run : str
        The stored run's directory.
    mode : str
        ``"amplitude"`` or ``"velocity"``.
    level : float
        Amplitude [mm p-p] or velocity [m/s].
    freq_hz : ndarray, shape (F,)
        Lines [Hz], increasing.
    x0 : ndarray, shape (F,)
        Clamp amplitude per line [m, 0-peak].
    fuu : ndarray of complex, shape (S, F)
        Draws of the dynamic stiffness [N/m] (the impedance is ``fuu / (i omega)``).
    resonances : tuple of dict
        :func:`sbcal.design.resonance.resonance_draws` of ``fuu``.
    extrapolated : ndarray of bool, shape (F,)
        Lines outside the calibrated curvature range (cable law only).
    discrepancy : str
        How the model's misfit is carried: ``"test posterior"`` (the test's discrepancy given its runs),
        ``"model error (partial)"`` (the cable fit's), or ``"none"`` (a complete cable fit).
    n_runs : int
        Runs per line behind the draws (the median over lines; 0 for the cable law).
    damper_values : dict
        The damper's geometry, as the run stored it.
    """

    damper: str
    state: str
    source: str
    run: str
    mode: str
    level: float
    freq_hz: np.ndarray
    x0: np.ndarray
    fuu: np.ndarray
    resonances: tuple
    extrapolated: np.ndarray
    discrepancy: str
    n_runs: int
    damper_values: dict

    @property
    def label(self) -> str:
        return f"{self.damper} {self.state}" if self.state != DRY else self.damper


def power(freq_hz, fuu, x0) -> np.ndarray:
    """Power dissipated [W]: ``P = 0.5 Re(F V*) = 0.5 omega Im(f_uu) X0^2``, shape of ``fuu``."""
    omega = 2 * np.pi * np.asarray(freq_hz, float)
    return 0.5 * omega * np.imag(fuu) * np.asarray(x0, float) ** 2


def _in_range(freq_hz, freq_range):
    f = np.asarray(freq_hz, float)
    if freq_range is None:
        return np.ones(f.shape, bool)
    lo, hi = freq_range
    return (f >= lo * (1 - 1e-9)) & (f <= hi * (1 + 1e-9))


def constant_tests(runs, damper: str, state: str, paramset: str) -> dict:
    """``{amplitude [mm p-p]: run directory}`` of a damper's finished constant-amplitude tests in one state."""
    from ..inference.store import run_dirs

    out = {}
    for test, d in run_dirs(runs, damper, paramset):
        p = parse_label(test)
        if p and p.constant and p.state == state:
            out[p.below_mm_pp] = d
    return out


def from_test(directory, *, freq_range=None, n_draws: int = 1000, rng: np.random.Generator) -> Characteristic:
    """The characteristic at a test's own constant amplitude from its stored posterior (module docstring).

    Parameters
    ----------
    directory : path-like
        ``<runs>/<damper>/<test>/<paramset>``.
    freq_range : (float, float), optional
        Keep the lines in this range [Hz] (default: all).
    n_draws : int
        Posterior draws used (a random subset).
    rng : numpy.random.Generator
        Picks the subset and draws the discrepancy.

    Raises
    ------
    InputError
        No finished run, a posterior that did not converge, not a constant-amplitude test, fewer than
        three lines in the range.
    """
    from ..inference.runs import read_run

    d = Path(directory)
    idata, summary = read_run(d)
    test = d.parent.name
    label = parse_label(test)
    if label is None or not label.constant:
        raise InputError(f"{d}: test {test!r} is not a constant-amplitude test (A-A[-state])")
    if not summary.get("converged", False):
        raise InputError(f"{d}/summary.json: the posterior did not converge ({summary.get('reason') or 'see r_hat_max, ess_bulk_min'}); "
                         "its draws are not a result: sample it again with more steps")
    f = np.asarray(idata.constant_data["freq_hz"], float)
    keep = _in_range(f, freq_range)
    if keep.sum() < 3:
        raise InputError(f"{d}: {int(keep.sum())} line(s) of test {test} in {freq_range[0]:g}-{freq_range[1]:g} Hz; "
                         "at least 3 are needed")
    post, pp = idata.posterior, idata.posterior_predictive
    n_total = post.sizes["chain"] * post.sizes["draw"]
    idx = subset_indices(n_total, int(n_draws), rng)
    mu = np.stack([np.asarray(pp[v], float).reshape(n_total, -1)[idx] for v in ("model_logmag", "model_phase")])
    s = np.stack([np.asarray(post[v], float).ravel()[idx] for v in ("sigma_mag", "sigma_phase")])
    obs = idata.observed_data
    y = np.stack([np.asarray(obs[v], float) for v in ("logmag", "phase")])  # (2, runs, F)
    n = np.sum(np.isfinite(y[0]), axis=0).astype(float)
    noise = np.concatenate([np.asarray(idata.constant_data[v], float) ** 2 for v in ("noise_logmag", "noise_phase")])
    F = f.size  # magnitude and phase as one vector of 2F columns: their errors are correlated
    scale = np.concatenate([np.repeat(s[q][:, None], F, axis=1) for q in (0, 1)], axis=1)  # (S, 2F)
    true = true_mean_draws(np.concatenate(mu, axis=1), scale, np.concatenate(y, axis=1), noise,
                           wrap=np.repeat([False, True], F), rng=rng)
    true = true.reshape(-1, 2, F).transpose(1, 0, 2)  # (2, S, F)
    fuu = np.exp(true[0] + 1j * true[1])[:, keep]
    f = f[keep]
    x0 = clamp_amplitude("amplitude", label.below_mm_pp, f)
    cfg = summary.get("config", {})
    return Characteristic(
        damper=str(cfg.get("damper", d.parent.parent.name)), state=label.state, source=f"test {test}", run=str(d),
        mode="amplitude", level=label.below_mm_pp, freq_hz=f, x0=x0, fuu=fuu,
        resonances=tuple(resonance_draws(f, fuu, x0)), extrapolated=np.zeros(f.size, bool),
        discrepancy="test posterior", n_runs=int(np.median(n[keep])), damper_values=dict(cfg.get("damper_values", {})))


def from_cable(directory, *, mode: str, level: float, freq_hz, n_draws: int = 300,
               rng: np.random.Generator) -> Characteristic:
    """The characteristic at any excitation from a stored cable-law posterior (module docstring).

    Parameters
    ----------
    directory : path-like
        ``<runs>/<damper>/cable-<state>``.
    mode, level : str, float
        ``"amplitude"`` [mm p-p] or ``"velocity"`` [m/s].
    freq_hz : array_like, shape (F,)
        Lines [Hz].
    n_draws : int
    rng : numpy.random.Generator

    Raises
    ------
    InputError
        No such run, no stored calibration damper, a posterior that did not converge.
    """
    from .cable_run import cable_params, load_cable_run, subset
    from .harmonics import harmonic_correction
    from .predict import evaluate, model_error_of

    cable = load_cable_run(directory)
    if warning := cable.convergence_warning():
        raise InputError(f"{warning}; its draws are not a result")
    damper = cable.calibration
    if not isinstance(damper, Damper):
        raise InputError(f"{cable.path}/summary.json: no damper_values (a cable run stored before sbcal kept them)")
    f = np.unique(np.asarray(freq_hz, float))
    idx = subset(cable, int(n_draws), rng)
    params = cable_params(cable, idx, bench_effects=False, own_offsets=True)
    x0 = clamp_amplitude(mode, level, f)
    c = harmonic_correction(cable.law, (), damper, f, x0, params)[0] if cable.harmonic else None
    r = evaluate(cable.law, (), damper, f, x0, params, idx.size, correction=c)
    fuu = r["fuu"]
    discrepancy = "none"
    try:
        err = model_error_of(cable)
    except InputError:
        err = None
    if err is not None and (np.any(err.logmag_sd > 0) or np.any(err.phase_sd_deg > 0)):
        sd_m, sd_p = err.at(2e3 * x0)
        e = rng.standard_normal((2,) + fuu.shape)
        fuu = fuu * np.exp(e[0] * sd_m + 1j * e[1] * sd_p)
        discrepancy = "model error (partial)"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        cmax = np.nanmedian(r["cmax"], axis=0)
    from dataclasses import asdict

    values = {k: v for k, v in asdict(damper).items() if k != "tolerance"}
    return Characteristic(
        damper=cable.damper, state=cable.state, source=f"cable law {cable.law}", run=str(cable.path), mode=mode,
        level=float(level), freq_hz=f, x0=x0, fuu=fuu, resonances=tuple(resonance_draws(f, fuu, x0)),
        extrapolated=cable.range_status(cmax) != 0, discrepancy=discrepancy, n_runs=0, damper_values=values)
