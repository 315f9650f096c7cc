"""The harmonic refit: a cable fit with the multi-harmonic solve on the lines where the first harmonic misses.

A cable fit uses the describing-function model (:class:`sbcal.model.cable.CableModel`); where the slipping
cable distorts the base force, the bench's first harmonic is the multi-harmonic solve's
(:class:`sbcal.model.cable_harmonics.HarmonicBalance`), not the first-harmonic model's. The solve costs
0.3-1.6 s per 37-line sweep at one parameter set, too much for every draw of a posterior, so the refit
carries it as a per-line correction ``c = f_uu / f_uu_first`` (the solve over the first-harmonic model,
both at one parameter set) made at the current estimate and iterated to a fixed point:

1. ``c`` at the plain fit's posterior median, on the lines to correct (1 elsewhere);
2. the mode of the posterior with the model ``c f_uu_first(theta)`` (:func:`sbcal.inference.cable_fit.polish_mode`
   from the last estimate), then ``c`` again at that mode; until ``c`` moves by less than
   :data:`RESOLVE` of each line's standard error (magnitude and phase), at most ``max_rounds`` rounds (8);
3. the posterior with the last ``c`` (the engine, from the mode).

The assumption: ``c`` changes little across the posterior's width (it is a smooth function of the law's
parameters, which the bench pins to a few per cent); ``c_spread`` in the record measures it: the median over
six posterior draws of the largest change of ``c`` from the one the fit used, in the lines' standard errors
(on the lines where the solve converged at the draw). A line whose solve does not converge at a new estimate
keeps its last correction.

Which lines: where the bench file carries the measured distortion, the harmonic switch's
(:func:`sbcal.inference.distortion.harmonic_switch`: the gap is resolved and the recordings are distorted as
the law predicts), and the refit is used when its posterior converged; without a measured distortion, every
line whose predicted gap the data resolve (``> 2`` standard errors of the line's mean), and the refit is used
when its PSIS-LOO beats the plain fit's by more than twice the standard error of the difference. A screen
first, after the first round: the corrected model's mode must beat the plain one's log-posterior by
:data:`SCREEN_NATS` (the same parameters: a likelihood ratio) before the fixed point goes on and its
posterior is sampled.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.seeds import job_seed
from .cable_fit import CableFit, cable_config, polish_mode, sample_cable
from .distortion import HARMONICS, RESOLVED, line_standard_errors
from .likelihood import JointLikelihood
from .stats import elpd_difference, loo


__all__ = ["RESOLVE", "SCREEN_NATS", "correction_at", "lines_to_correct", "harmonic_fixed_point", "RefitPlan", "plan_refit",
           "sample_refit", "refit_harmonics"]

RESOLVE = 0.25
"""The fixed point stops when the correction moves by less than this share of every corrected line's standard
error of the mean (magnitude and phase): below what the data resolve, and above the mode search's own
scatter (L-BFGS-B from the last mode moved the correction by 0.1-0.2 standard errors from round to round on
the tests' bench, measured)."""

SCREEN_NATS = 2.0
"""The corrected model's mode must beat the plain model's by this much log-posterior before its posterior
is sampled (equal numbers of parameters: AIC's difference of 4)."""

_SPREAD_DRAWS = 6  # posterior draws at which the correction's spread is measured


def _flat(per_test: dict, tests) -> np.ndarray:
    """A per-test JSON list (``None``: NaN) over the concatenated lines."""
    return np.array([np.nan if v is None else float(v) for t in tests for v in per_test[t]])


def correction_at(like: JointLikelihood, params: dict, lines, previous=None) -> tuple[np.ndarray, np.ndarray]:
    """The multi-harmonic solve over the first-harmonic model at one parameter set, per line.

    Parameters
    ----------
    like : JointLikelihood
        A cable state's likelihood (its forward model :class:`sbcal.inference.cable_fit.CableForward`).
    params : dict
        Natural values by name (floats).
    lines : ndarray of bool, shape (n_lines,)
        Where to correct.
    previous : ndarray of complex, shape (n_lines,), optional
        The correction kept on a line where the solve does not converge at ``params`` (default 1).

    Returns
    -------
    c : ndarray of complex, shape (n_lines,)
        ``f_uu / f_uu_first`` of the cable on ``lines`` where the solve converged, ``previous`` (or 1) where it
        did not, 1 off ``lines``.
    solved : ndarray of bool, shape (n_lines,)
        The solve converged.
    """
    ratio, solved = like.model.harmonic_correction(like.damper, like.freq_hz, harmonics=HARMONICS,
                                                   **like.model_params({k: np.atleast_1d(v) for k, v in params.items()}))
    lines = np.asarray(lines, bool)
    kept = np.ones(lines.size, complex) if previous is None else np.asarray(previous, complex)
    return np.where(lines, np.where(solved, ratio, kept), 1.0 + 0j), solved


def lines_to_correct(fit: CableFit) -> tuple[np.ndarray, str]:
    """The lines a refit corrects and what decides it: ``(mask (n_lines,), "measured distortion" | "PSIS-LOO")``."""
    h = fit.harmonics
    if "switch" in h:
        return _flat(h["switch"], fit.tests) > 0, "measured distortion"
    gap = _flat(h["gap"], fit.tests)
    with np.errstate(invalid="ignore"):
        return gap > RESOLVED * line_standard_errors(fit.like)[0], "PSIS-LOO"


def _at(prior, z) -> dict:
    """Natural values by name (floats) at sampled coordinates ``z`` (ndim,)."""
    return dict(zip(prior.names, prior.to_natural(z[None])[0]))


def _with(like: JointLikelihood, c) -> JointLikelihood:
    return JointLikelihood(like.likes, like.prior, replace(like.model, correction=c))


def _change(c_new, c_old, sigma, lines) -> float:
    """The largest move of the correction on ``lines``, in standard errors of the line's mean."""
    if not lines.any():
        return 0.0
    r = c_new[lines] / c_old[lines]
    return float(max(np.max(np.abs(np.log(np.abs(r))) / sigma[0, lines]),
                     np.max(np.abs(np.angle(r)) / sigma[1, lines])))


def harmonic_fixed_point(like: JointLikelihood, start: dict, lines, max_rounds: int = 8):
    """The corrected model's mode and its correction, iterated to a fixed point (module docstring, 1-2).

    Parameters
    ----------
    like : JointLikelihood
        The plain (first-harmonic) likelihood of a cable state.
    start : dict
        Natural values by name where the first correction is made (the plain fit's posterior median).
    lines : ndarray of bool, shape (n_lines,)
    max_rounds : int

    Returns
    -------
    z : ndarray, shape (ndim,)
        The mode in sampled coordinates.
    c : ndarray of complex, shape (n_lines,)
        The correction at that mode.
    changes : list of float
        Each round's move of the correction, in standard errors of the lines' means (the last decides).
    """
    prior, sigma = like.prior, line_standard_errors(like)
    z = prior.z_of(start)[0]
    c, _ = correction_at(like, start, lines)
    changes = []
    while len(changes) < max_rounds:
        z, _ = polish_mode(_with(like, c), z)
        c_new, _ = correction_at(like, _at(prior, z), lines, previous=c)
        changes.append(_change(c_new, c, sigma, lines))
        c = c_new
        if changes[-1] < RESOLVE:
            break
    return z, c, changes


@dataclass(frozen=True)
class RefitPlan:
    """A refit past its screen (:func:`plan_refit`), to be sampled (:func:`sample_refit`).

    Attributes
    ----------
    z : ndarray, shape (ndim,)
        The corrected model's mode in sampled coordinates (the engine's start).
    c : ndarray of complex, shape (n_lines,)
        The correction at the fixed point.
    lines : ndarray of bool, shape (n_lines,)
        The lines corrected.
    record : dict
        The refit's record so far (JSON-ready; :func:`refit_harmonics`).
    """

    z: np.ndarray
    c: np.ndarray
    lines: np.ndarray
    record: dict


def plan_refit(fit: CableFit, *, max_rounds: int = 8) -> CableFit | RefitPlan | None:
    """The refit's work before its posterior (one core's: polishes, rounds of the multi-harmonic solve): the
    lines, the screen and the fixed point (module docstring, 1-2).

    Returns
    -------
    None, CableFit or RefitPlan
        None where no line needs the solve; the plain fit with its ``refit`` record (``used`` False) where the
        screen fails; else the plan that :func:`sample_refit` samples.
    """
    like = fit.like
    lines, basis = lines_to_correct(fit)
    if not lines.any():
        return None
    prior = like.prior
    median = fit.median()
    _, lp_plain = polish_mode(like, prior.z_of(median)[0])
    # one round, then the screen (a correction the data do not want fails it at once), then the fixed point
    z, c, changes = harmonic_fixed_point(like, median, lines, 1)
    screen = float(_with(like, c)(z[None])[0]) - lp_plain
    record = {"lines": int(lines.sum()), "basis": basis, "screen": screen}
    if basis == "PSIS-LOO" and screen <= SCREEN_NATS:
        return replace(fit, refit={**record, "rounds": 1, "change": changes[-1], "changes": changes,
                                   "fixed_point": bool(changes[-1] < RESOLVE),
                                   "largest_correction": float(np.max(np.abs(c[lines] - 1))), "used": False,
                                   "reason": f"the corrected mode's log-posterior is {screen:+.1f} nats against the plain "
                                             f"one's after one round (the screen asks more than +{SCREEN_NATS:g})"})
    if changes[-1] >= RESOLVE and max_rounds > 1:
        z, c, more = harmonic_fixed_point(like, _at(prior, z), lines, max_rounds - 1)
        changes += more
    record.update(rounds=len(changes), change=changes[-1], changes=changes, fixed_point=bool(changes[-1] < RESOLVE),
                  largest_correction=float(np.max(np.abs(c[lines] - 1))))
    return RefitPlan(z=z, c=c, lines=lines, record=record)


def sample_refit(fit: CableFit, plan: RefitPlan, *, seed, workers: int = 2, max_steps: int | None = None,
                 progress: str | None = None) -> CableFit:
    """The posterior of a planned refit (module docstring, 3) and whether it replaces the plain fit: the refit
    where used, else the plain fit, either with the whole ``refit`` record (:func:`refit_harmonics`)."""
    like, prior = fit.like, fit.like.prior
    z, c, lines, record = plan.z, plan.c, plan.lines, dict(plan.record)
    corrected = _with(like, c)
    stream = job_seed(seed, "cable", fit.damper, fit.state, fit.law, *fit.effects, "harmonics")
    res = sample_cable(corrected, seed=stream, config=cable_config(prior.ndim, workers=workers, max_steps=max_steps),
                       start=_at(prior, z), progress=progress)
    out = CableFit(damper=fit.damper, state=fit.state, law=fit.law, tests=fit.tests, effects=fit.effects, result=res,
                   like=corrected, loo=loo(res.log_likelihood))
    d, se = elpd_difference(fit.loo, out.loo)
    flat, sigma = res.flat(), line_standard_errors(like)
    spread = []  # the correction at a few draws against the one the fit used
    n = next(iter(flat.values())).size
    for i in np.linspace(0, n - 1, _SPREAD_DRAWS).astype(int):
        ci, solved = correction_at(like, {k: float(v[i]) for k, v in flat.items()}, lines)
        spread.append(_change(ci, c, sigma, lines & solved))
    spread = float(np.median(spread))
    basis = record["basis"]
    used = bool(res.converged) and record["fixed_point"] and (basis == "measured distortion" or d > 2 * se)
    reason = ("posterior not converged" if not res.converged else
              f"the correction did not settle in {record['rounds']} rounds" if not record["fixed_point"] else
              "the recordings' distortion confirms the law's" if basis == "measured distortion" else
              f"PSIS-LOO {d:+.1f} +- {se:.1f} nats" + ("" if used else ": not above twice its standard error"))
    record.update(c_spread=spread, delta_elpd=d, se=se, converged=bool(res.converged), used=used, reason=reason)
    return replace(out, refit=record) if used else replace(fit, refit=record)


def refit_harmonics(fit: CableFit, *, seed, workers: int = 2, max_rounds: int = 8, max_steps: int | None = None,
                    progress: str | None = None) -> CableFit | None:
    """The cable fit refitted with the multi-harmonic solve where it is needed (module docstring):
    :func:`plan_refit`, then :func:`sample_refit` where the screen passes.

    Parameters
    ----------
    fit : CableFit
        The plain (first-harmonic) fit of one cable state.
    seed : int
        The user's seed; the refit's stream is keyed by what it is.
    workers, max_steps : int
        As :func:`sbcal.inference.cable_fit.cable_config`.
    max_rounds : int
        Rounds of the fixed point at most.
    progress : str, optional

    Returns
    -------
    CableFit or None
        None where no line needs the solve. Otherwise the refit, whose ``refit`` record says (JSON-ready):
        ``lines`` (how many), ``basis``, ``rounds``, ``change`` (the last move of the correction, in standard
        errors; ``changes``: every round's), ``fixed_point`` (it fell below :data:`RESOLVE`), ``screen`` (mode log-posterior, corrected
        minus plain), ``c_spread``, ``delta_elpd``/``se`` (refit minus plain, PSIS-LOO), ``largest_correction``
        (``|c - 1|``), ``used`` (whether the refit replaces the plain fit) and ``reason``. Where the screen
        fails, the returned fit is the plain one with the record (``used`` False, no posterior sampled).
    """
    plan = plan_refit(fit, max_rounds=max_rounds)
    if not isinstance(plan, RefitPlan):
        return plan
    return sample_refit(fit, plan, seed=seed, workers=workers, max_steps=max_steps, progress=progress)
