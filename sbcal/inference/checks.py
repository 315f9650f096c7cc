"""Does a fitted model explain the run means within the bench's noise? The posterior predictive check
of the run means, the qualifier it gives a model, and the model discrepancy estimated from what is left.

One check serves three stages: the diagnosis locates a misfit with it (:mod:`sbcal.diagnosis.locate`),
judges what its verdict's model leaves (``complete``/``partial``: :func:`qualifier`), and every stored
cable fit carries its own verdict and :func:`discrepancy` (:func:`sbcal.inference.cable_fit.store_cable`),
which ``sbcal predict`` and ``sbcal span`` add to their bands (``docs/diagnose.md``, "What is left").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


__all__ = ["ALPHA", "GLOBAL_ALPHA", "Check", "curve_moments", "predictive_check", "qualifier", "discrepancy",
           "materiality"]

ALPHA = 0.05  # family-wise false-alarm rate of the per-line check, over all lines of all tests
GLOBAL_ALPHA = 0.01  # false-alarm rate of the global check of the residual as a whole


def curve_moments(mu):
    """Posterior mean, variance and median of model curves over draws.

    Parameters
    ----------
    mu : ndarray, shape (2, n_draws, n_freq)
        Log-magnitude and phase [rad] of each draw (``TestLikelihood.predict``).

    Returns
    -------
    mean, var, median : ndarray, shape (2, n_freq)
        The phase is taken about the first draw, so a wrap cannot corrupt the moments.
    """
    d = np.array(mu, dtype=float, copy=True)
    d[1] = d[1, :1] + np.remainder(d[1] - d[1, :1] + np.pi, 2 * np.pi) - np.pi
    return d.mean(axis=1), d.var(axis=1), np.median(d, axis=1)


@dataclass(frozen=True)
class Check:
    """A model's posterior predictive check of the run means (:func:`predictive_check`).

    Attributes
    ----------
    z : list of ndarray, shape (2, n_freq)
        Per test: standardised residual of the run mean, log-magnitude and phase.
    thresholds : list of ndarray, shape (2, n_freq)
        Per test: the |z| beyond which a line is off (Bonferroni over all lines at ``alpha``).
    coverage_90 : float
        Share of the recorded runs inside the model's 90 % predictive band of a new run.
    global_ : dict
        The global check: ``chi2``, ``dof``, ``p_value``, ``excess`` (chi2 - dof).
    scores : list of ndarray, shape (2, n_freq)
        Per test: each |z| as the normal deviate of equal tail probability (what the global check sums).
    """

    z: list
    thresholds: list
    coverage_90: float
    global_: dict
    scores: list

    def test_p_values(self) -> list:
        """Per test: the global check on that test's values alone (no parameters taken off)."""
        return [float(stats.chi2.sf(np.sum(u ** 2), u.size)) for u in self.scores]

    @property
    def lines_off(self) -> int:
        return int(sum(np.sum(np.abs(z) > t) for z, t in zip(self.z, self.thresholds)))

    @property
    def n_lines(self) -> int:
        return int(sum(z.size for z in self.z))

    @property
    def rms_z(self) -> float:
        return float(np.sqrt(np.mean(np.concatenate([z.ravel() for z in self.z]) ** 2)))


def predictive_check(likes, mu_mean, mu_var, alpha: float = ALPHA, n_params: int = 0) -> Check:
    """Standardised residuals of each test's run mean, the off-line thresholds, coverage and the global check.

    The run mean's residual is standardised by the noise-only likelihood's t of the run mean given the
    runs' deviations (:meth:`TestLikelihood.mean_scale`) widened by the posterior spread of the model;
    a line is off when ``|z|`` exceeds the t quantile that keeps the family-wise false-alarm rate over
    all lines at ``alpha``. The band of a new run is the likelihood's new-run t
    (:meth:`TestLikelihood.new_run`), likewise widened. The global check: the normal scores of every z
    (through its t), squared and summed, against chi-square with the number of values less ``n_params``.

    Parameters
    ----------
    likes : sequence of TestLikelihood
    mu_mean, mu_var : sequence of ndarray, shape (2, n_freq)
        Per test: posterior mean and variance of the model curves (:func:`curve_moments`).
    alpha : float
    n_params : int
        The model's fitted parameters (taken from the global check's degrees of freedom).
    """
    n_lines = sum(2 * lk.freq_hz.size for lk in likes)
    z, thr, inside, total, scores = [], [], 0, 0, []
    for lk, m, v in zip(likes, mu_mean, mu_var):
        mu = m[:, None, :]
        r = lk.residual(mu)[:, 0]
        scale, dof = (a[:, 0] for a in lk.mean_scale({}, mu))
        zt = r / np.sqrt(scale ** 2 + v)
        z.append(zt)
        thr.append(stats.t.ppf(1 - alpha / (2 * n_lines), dof))  # (2, n_freq)
        u = stats.norm.isf(stats.t.sf(np.abs(zt), dof))  # |z| as the normal deviate of equal tail
        scores.append(np.where(np.isfinite(u), u, 40.0))  # a tail beyond double precision: far beyond chance
        # 90 % predictive band of a new run against every recorded run
        _, new_scale, new_dof = (a[:, 0] for a in lk.new_run({}, mu))
        half = stats.t.ppf(0.95, new_dof) * np.sqrt(new_scale ** 2 + v)
        dev = lk.y - m[:, None, :]
        dev[1] = np.remainder(dev[1] + np.pi, 2 * np.pi) - np.pi
        ok = (np.abs(dev) <= half[:, None, :]) & lk.present[None]
        inside += int(ok.sum())
        total += 2 * int(lk.present.sum())
    u = np.concatenate([s.ravel() for s in scores])
    dof = max(u.size - n_params, 1)
    chi2 = float(np.sum(u ** 2))
    glob = {"chi2": chi2, "dof": int(dof), "p_value": float(stats.chi2.sf(chi2, dof)), "excess": chi2 - dof}
    return Check(z=z, thresholds=thr, coverage_90=inside / total, global_=glob, scores=scores)


def qualifier(check: Check, global_alpha: float = GLOBAL_ALPHA) -> str:
    """``complete`` when what the model leaves is consistent with the noise (no line off, the global check
    passes at ``global_alpha``), else ``partial``: the rule that finds a misfit, applied to the model."""
    return "partial" if check.lines_off or check.global_["p_value"] < global_alpha else "complete"


def discrepancy(likes, mu_mean, mu_var, *, partial: bool) -> dict:
    """The model discrepancy per amplitude: the run means' spread about the model beyond the noise.

    For each commanded amplitude (the lines of every test at it) and quantity, the method-of-moments
    variance ``delta^2 = max(0, mean(r^2) - mean(Var_t + Var_mu))``: the mean squared residual of the
    run mean less what the noise of the run mean (the variance of its t, :meth:`TestLikelihood.mean_scale`)
    and the posterior spread of the model explain. A white (nugget-only) Kennedy-O'Hagan discrepancy,
    estimated after the fit (``docs/diagnose.md``). Zero throughout for a ``complete`` model
    (``partial=False``): its remainder is noise, and a band must not widen by the noise twice.

    Returns
    -------
    dict
        ``amplitude_mm_pp`` (increasing), ``logmag_sd`` [1], ``phase_sd_deg`` [deg], lists of one length
        (lines without a commanded amplitude are left out), and ``partial``.
    """
    r2, noise, amps = [], [], []
    for lk, m, v in zip(likes, mu_mean, mu_var):
        mu = m[:, None, :]
        r = lk.residual(mu)[:, 0]
        scale, dof = (a[:, 0] for a in lk.mean_scale({}, mu))
        var_t = scale ** 2 * np.where(dof > 2, dof / np.maximum(dof - 2, 1e-9), 3.0)  # a t's variance (dof <= 2: capped)
        r2.append(r ** 2), noise.append(var_t + v), amps.append(lk.amplitude_mm_pp)
    r2, noise, amp = np.concatenate(r2, axis=1), np.concatenate(noise, axis=1), np.concatenate(amps)
    levels = np.unique(amp[np.isfinite(amp) & (amp > 0)])
    sd = np.zeros((2, levels.size))
    if partial:
        for k, a in enumerate(levels):
            at = amp == a
            sd[:, k] = np.sqrt(np.maximum(r2[:, at].mean(axis=1) - noise[:, at].mean(axis=1), 0.0))
    return {"amplitude_mm_pp": levels.tolist(), "logmag_sd": sd[0].tolist(), "phase_sd_deg": np.degrees(sd[1]).tolist(),
            "partial": bool(partial)}


def materiality(disc: dict, likes) -> dict:
    """Does what a ``partial`` model leaves matter to a user? Its discrepancy beside one run's noise.

    ``partial`` is a statistical statement: with many runs a remainder far below the bench's noise is
    detectable. What a user acts on is its size, and that is the discrepancy (:func:`discrepancy`): the sd
    per amplitude that ``sbcal predict`` and ``sbcal span`` add to their bands for the missing physics. The
    remainder is **immaterial** when, at every amplitude, it is below the median per-run noise of the
    lines in both quantities (``TestLikelihood.sigma``): smaller than the scatter of any single recording,
    and so widening a prediction's band by less than that scatter. The statement is then ``complete within
    X % and Y deg`` (X, Y the largest discrepancy sd); otherwise ``partial`` stands, with its size.

    Parameters
    ----------
    disc : dict
        :func:`discrepancy`'s (``logmag_sd`` [1], ``phase_sd_deg`` [deg] per amplitude).
    likes : sequence of TestLikelihood
        The tests it was estimated on.

    Returns
    -------
    dict
        JSON-ready: ``material`` (bool), ``within_pct`` and ``within_deg`` (the largest discrepancy sd, in % of
        |f| and deg), ``run_noise_pct`` and ``run_noise_deg`` (one run's median noise), ``qualifier`` (what a
        reader is told: ``complete within X % and Y deg`` or ``partial``), ``detail`` (why) and ``words``.
    """
    sigma = np.concatenate([lk.sigma for lk in likes], axis=1)  # (2, n_lines): one run's sd, ln|f| and phase [rad]
    run_mag, run_deg = float(np.nanmedian(sigma[0])), float(np.degrees(np.nanmedian(sigma[1])))
    mag, deg = max(disc["logmag_sd"], default=0.0), max(disc["phase_sd_deg"], default=0.0)
    material = bool(mag > run_mag or deg > run_deg)
    out = {"material": material, "within_pct": 100 * float(np.expm1(mag)), "within_deg": float(deg),
           "run_noise_pct": 100 * float(np.expm1(run_mag)), "run_noise_deg": run_deg}
    size = f"{out['within_pct']:.2g} % and {deg:.2g} deg"
    noise = f"one run's noise, {out['run_noise_pct']:.2g} % and {run_deg:.2g} deg"
    if material:
        out.update(qualifier="partial", detail=f"material: up to {size} beyond the noise, above {noise}")
        out["words"] = f"partial, {out['detail']}"
    else:
        out.update(qualifier=f"complete within {size}", detail=f"what is left is below {noise}, and predict and span carry it")
        out["words"] = f"{out['qualifier']}: {out['detail']}"
    return out
