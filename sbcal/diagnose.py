"""Missing physics: locate where the model and the recordings differ, name the physics left out,
model it and show the fit improve (``docs/diagnose.md``).

1. **Baseline**: the per-test model (``theta1``: EJ, beta, a1, a2) with the noise-only likelihood
   (no model-error scales: the model must explain the run means within the bench's scatter),
   sampled per test.
2. **Locate**: posterior predictive residuals of each test's run mean, line by line, standardised
   by the noise model and the posterior spread, ``z = (ybar - E mu) / sqrt(sigma^2 / n + Var mu)``;
   a line is off when ``|z|`` exceeds the Student-t quantile that keeps the family-wise false-alarm
   rate over *all* lines tested at ``alpha`` (Bonferroni); neighbouring off lines form a band.
   Structure statistics: lag-1 correlation of z over frequency, EJ trend with amplitude, correlation
   of the misfit with the cable's predicted curvature, the share of the phase misfit linear in
   omega, and of the misfit a ``-omega^2 m`` term explains.
3. **Name**: each catalogue extension (:mod:`sbcal.extensions`) whose signature statistic is present
   is refitted (jointly over the amplitudes of a cable for ``strand_slip``) and compared with the
   baseline by PSIS-LOO, the log-likelihood grouped by run (a run is one curve), with the standard
   error of the difference.
4. **Verdict**: ``none`` when the baseline has no off line; else the best extension when it beats the
   baseline clearly (``delta_elpd > clear_se * se``) *and* removes at least ``min_explained`` of the
   misfit in the located bands; else ``unexplained`` (the bands are the answer).
"""

from __future__ import annotations

import os
import re
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares
from scipy.stats import qmc

from .bench import remove_outlier_runs, rows_digest
from .calibrate import likelihood_for
from .damper import Damper
from .errors import InputError
from .extensions import EXTENSIONS, model_for
from .fem import arm_curvatures
from .likelihood import JointLikelihood
from .priors import extension_prior
from .progress import progress_bar
from .runs import versions
from .sampler import SamplerConfig, sample
from .stats import elpd_difference, loo

__all__ = ["DiagnoseConfig", "diagnose"]

_QUANTITIES = ("magnitude", "phase")
_LABEL = re.compile(r"^\d+(?:\.\d+)?-\d+(?:\.\d+)?(?:-(.+))?$")


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`diagnose` (the defaults are what ``sbcal diagnose`` uses).

    Attributes
    ----------
    alpha : float
        Family-wise false-alarm rate of the predictive check over all lines of all tests.
    clear_se : float
        An extension beats the baseline clearly when ``delta_elpd > clear_se * se``.
    min_explained : float
        ... and removes at least this share of the baseline's squared misfit in the located bands.
    screen_t : float
        Screening: |t| of the EJ-versus-amplitude trend that admits ``strand_slip``.
    screen_share : float
        Screening: share of the misfit a signature explains (phase linear in omega: ``sensor_delay``;
        ``-omega^2 m``: ``fixture_mass``) that admits the extension.
    screen_corr : float
        Screening: lag-1 correlation of the residuals over frequency (structured misfit) that
        admits the extensions without a specific signature, or curvature correlation for strand slip.
    draws : int
        Posterior draws kept per ensemble.
    max_steps, joint_max_steps : int
        Step caps of the engine for a per-test fit and for a joint one (the policy and everything
        else are the engine's: :data:`sbcal.sampler.POLICY`).
    workers : int
        Processes (per-test fits run in parallel; a joint fit runs its ensembles in parallel).
    """

    alpha: float = 0.05
    clear_se: float = 4.0
    min_explained: float = 0.8
    screen_t: float = 3.0
    screen_share: float = 0.05
    screen_corr: float = 0.3
    draws: int = 250
    max_steps: int = 20000
    joint_max_steps: int = 6000
    workers: int = field(default_factory=lambda: min(2, os.cpu_count() or 1))

    def sampler(self, ndim: int, joint: bool = False) -> SamplerConfig:
        return SamplerConfig(nwalkers=max(16, 2 * ndim + 2), max_draws=self.draws,
                             max_steps=self.joint_max_steps if joint else self.max_steps,
                             workers=self.workers if joint else 1)


# --- fits --------------------------------------------------------------------------------------

def _group(test: str) -> str:
    """Cable state of a test label: the suffix after the amplitudes (``1-1-oiled`` -> ``oiled``)."""
    m = _LABEL.match(test)
    return (m.group(1) or "") if m else test


def _residual_batch(like: JointLikelihood, params: dict) -> np.ndarray:
    """Standardised residuals of the run means, all tests, ``(n, n_values)``."""
    out = []
    for lk, mu in zip(like.likes, like.predict(params)):
        r = lk.residual(mu) / np.sqrt(lk.sigma ** 2 / lk.n)[:, None, :]
        out.append(np.moveaxis(r, 1, 0).reshape(mu.shape[1], -1))
    r = np.concatenate(out, axis=1)
    return np.where(np.isfinite(r), r, 1e3)


def _start_joint(like: JointLikelihood, rng: np.random.Generator) -> np.ndarray:
    """A global start for a joint fit: the best of a Sobol design, refined by least squares."""
    prior = like.prior
    lo, hi = prior.z_lower, prior.z_upper
    u = qmc.Sobol(prior.ndim, seed=rng).random(512)
    z = lo + (hi - lo) * u
    lp = np.concatenate([like(z[i:i + 128]) for i in range(0, len(z), 128)])
    starts = z[np.argsort(-lp)[:4]]
    step = 1e-6 * (hi - lo)

    def fun(zz):
        return _residual_batch(like, prior.params(zz))[0]

    def jac(zz):
        h = np.where(zz + step <= hi, step, -step)
        r = _residual_batch(like, prior.params(np.vstack([zz, zz + np.diag(h)])))
        return ((r[1:] - r[0]) / h[:, None]).T

    best, best_lp = starts[0], -np.inf
    for z0 in starts:
        z0 = np.clip(z0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        res = least_squares(fun, z0, jac=jac, bounds=(lo, hi), loss="soft_l1", f_scale=3.0, max_nfev=80)
        v = like(res.x)[0]
        if v > best_lp:
            best, best_lp = res.x, v
    return best


def _fit(job):
    """One posterior through the engine (a test's, or a joint one). Module-level: picklable."""
    key, like, ss, config = job
    joint = isinstance(like, JointLikelihood)
    start = None
    if joint:  # a joint fit's box is wide and its mode narrow: a global least-squares start
        s0, s1 = ss.spawn(2)
        start, ss = _start_joint(like, np.random.default_rng(s0)), s1
    res = sample(like, seed=ss, config=config.sampler(like.prior.ndim, joint), start=start)
    return key, _posterior(like, res)


def _posterior(like, res) -> dict:
    """An engine result -> what the diagnosis needs: model curves, pointwise log-likelihood, convergence."""
    params = res.flat()
    likes = like.likes if isinstance(like, JointLikelihood) else [like]
    mus = like.predict(params) if isinstance(like, JointLikelihood) else [like.predict(params)]
    mu_mean, mu_var = [], []
    for mu in mus:
        # phase draws about the first draw, so a wrap cannot corrupt the mean
        d = mu.copy()
        d[1] = mu[1, :1] + np.remainder(mu[1] - mu[1, :1] + np.pi, 2 * np.pi) - np.pi
        mu_mean.append(d.mean(axis=1))
        mu_var.append(d.var(axis=1))
    return dict(params=params, names=like.prior.names, log_lik=res.log_likelihood, mu_mean=mu_mean, mu_var=mu_var,
                convergence=res.convergence_dict(), converged=res.converged, wall_s=res.wall_s, likes=len(likes))


def _run_fits(jobs, config, label):
    """Run fits: per-test ones in ``config.workers`` processes, joint ones one by one (each runs its
    ensembles in parallel); a progress bar over the fits. Returns ``{key: fit}``."""
    single = [j for j in jobs if not isinstance(j[1], JointLikelihood)]
    joint = [j for j in jobs if isinstance(j[1], JointLikelihood)]
    out = {}
    with progress_bar(label, total=len(jobs), unit="fit") as bar:
        if config.workers > 1 and len(single) > 1:
            with ProcessPoolExecutor(max_workers=config.workers) as pool:
                for key, fit in pool.map(_fit, single):
                    out[key] = fit
                    bar.update(1)
        else:
            for job in single:
                key, fit = _fit(job)
                out[key] = fit
                bar.update(1)
        for job in joint:
            key, fit = _fit(job)
            out[key] = fit
            bar.update(1)
    return out


# --- locate ------------------------------------------------------------------------------------

def _check(likes, mu_mean, mu_var, alpha: float):
    """Standardised residuals per test ``(2, n_freq)``, the off-line threshold per test, and coverage.

    The run mean's residual is standardised by the noise-only likelihood's t of the run mean given the
    runs' deviations (:meth:`TestLikelihood.mean_scale`) widened by the posterior spread of the model;
    the band of a new run is the likelihood's new-run t (:meth:`TestLikelihood.new_run`), likewise widened.
    """
    n_lines = sum(2 * lk.freq_hz.size for lk in likes)
    z, thr, inside, total = [], [], 0, 0
    for lk, m, v in zip(likes, mu_mean, mu_var):
        mu = m[:, None, :]
        r = lk.residual(mu)[:, 0]
        scale, dof = (a[:, 0] for a in lk.mean_scale({}, mu))
        z.append(r / np.sqrt(scale ** 2 + v))
        thr.append(stats.t.ppf(1 - alpha / (2 * n_lines), dof))  # (2, n_freq)
        # 90 % predictive band of a new run against every recorded run
        _, new_scale, new_dof = (a[:, 0] for a in lk.new_run({}, mu))
        half = stats.t.ppf(0.95, new_dof) * np.sqrt(new_scale ** 2 + v)
        dev = lk.y - m[:, None, :]
        dev[1] = np.remainder(dev[1] + np.pi, 2 * np.pi) - np.pi
        ok = (np.abs(dev) <= half[:, None, :]) & lk.present[None]
        inside += int(ok.sum())
        total += 2 * int(lk.present.sum())
    return z, thr, inside / total


def _bands(tests, likes, z, thr) -> list:
    """Neighbouring off lines (a gap of one line allowed) as bands, per test and quantity."""
    bands = []
    for t, lk, zt, th in zip(tests, likes, z, thr):
        th = np.broadcast_to(th, zt.shape)
        for q, name in enumerate(_QUANTITIES):
            off = np.flatnonzero(np.abs(zt[q]) > th[q])
            if off.size == 0:
                continue
            groups = np.split(off, np.flatnonzero(np.diff(off) > 2) + 1)
            for g in groups:
                lines = np.arange(g[0], g[-1] + 1)
                bands.append({"test": t, "quantity": name, "f_lo": float(lk.freq_hz[g[0]]),
                              "f_hi": float(lk.freq_hz[g[-1]]), "lines": [int(i) for i in lines],
                              "max_abs_z": float(np.max(np.abs(zt[q, lines])))})
    return bands


def _band_rms(bands, tests, z) -> list:
    index = {t: i for i, t in enumerate(tests)}
    return [float(np.sqrt(np.mean(z[index[b["test"]]][_QUANTITIES.index(b["quantity"]), b["lines"]] ** 2)))
            for b in bands]


def _band_sq(bands, tests, z) -> float:
    index = {t: i for i, t in enumerate(tests)}
    return float(sum(np.sum(z[index[b["test"]]][_QUANTITIES.index(b["quantity"]), b["lines"]] ** 2) for b in bands))


def _share(resid, weight_sq, regressor) -> tuple[float, float]:
    """Share of ``sum w r^2`` explained by ``r ~ c * regressor`` (weighted, through 0), and ``c``."""
    w = weight_sq
    num, den = np.sum(w * resid * regressor), np.sum(w * regressor * regressor)
    if den <= 0:
        return 0.0, 0.0
    c = num / den
    return float(max(0.0, 1 - np.sum(w * (resid - c * regressor) ** 2) / np.sum(w * resid * resid))), float(c)


def _statistics(damper, tests, likes, fits, z) -> dict:
    """The structure statistics of the baseline's residuals (module docstring)."""
    # lag-1 correlation of z over frequency, mean over tests and quantities
    ac = [np.corrcoef(zt[q, :-1], zt[q, 1:])[0, 1] for zt in z for q in (0, 1) if zt.shape[1] > 2 and np.std(zt[q]) > 0]
    out = {"lag1_correlation": float(np.nanmean(ac)) if ac else 0.0}
    # phase residual linear in omega (a delay) and a -omega^2 m term on f (a mass)
    ph_r, ph_w, ph_x, c_r, c_w, c_x = [], [], [], [], [], []
    for lk, t in zip(likes, tests):
        m, v = fits[t]["mu_mean"][0], fits[t]["mu_var"][0]
        r = lk.residual(m[:, None, :])[:, 0]
        w = 1.0 / (lk.sigma ** 2 / lk.n + v)
        omega = 2 * np.pi * lk.freq_hz
        ph_r.append(r[1]), ph_w.append(w[1]), ph_x.append(-omega)
        f_model = np.exp(m[0] + 1j * m[1])
        reg = -omega ** 2 / f_model  # d ln f / d m, real and imaginary parts = log-magnitude and phase
        c_r.append(r.ravel()), c_w.append(w.ravel()), c_x.append(np.concatenate([reg.real, reg.imag]))
    share, tau = _share(np.concatenate(ph_r), np.concatenate(ph_w), np.concatenate(ph_x))
    out["phase_linear"] = {"share": share, "delay_s": tau}
    share, mass = _share(np.concatenate(c_r), np.concatenate(c_w), np.concatenate(c_x))
    out["magnitude_omega2"] = {"share": share, "mass_kg": mass}
    # EJ trend with amplitude within each cable state (constant-amplitude tests)
    trend = {}
    for g in sorted({_group(t) for t in tests}):
        amp, ej = [], []
        for t, lk in zip(tests, likes):
            a = lk.amplitude_mm_pp
            if _group(t) == g and np.all(np.isfinite(a)) and np.allclose(a, a[0]):
                amp.append(a[0])
                ej.append(np.median(fits[t]["params"]["EJ"]))
        if len(amp) >= 3 and np.ptp(np.log(amp)) > 0:
            res = stats.linregress(np.log(amp), np.log(ej))
            tval = res.slope / res.stderr if res.stderr > 0 else np.inf * np.sign(res.slope)
            trend[g or "default"] = {"slope": float(res.slope), "t": float(tval), "n_tests": len(amp)}
    out["amplitude_trend"] = trend
    # misfit versus the predicted cable curvature (rms over both arms' ends), Spearman per test
    rho = []
    for t, lk in zip(tests, likes):
        p = {n: float(np.median(v)) for n, v in fits[t]["params"].items()}
        chi = arm_curvatures(damper, lk.freq_hz, ej1=p["EJ"], ej2=p["EJ"], beta1=p["beta"], beta2=p["beta"],
                             xc=(np.nan_to_num(lk.amplitude_mm_pp, nan=1.0) / 2e3)[None, :], a1=p["a1"], a2=p["a2"])
        curv = np.sqrt(np.mean(np.abs(chi[0]) ** 2, axis=(1, 2)))
        mis = np.sum(z[tests.index(t)] ** 2, axis=0)
        if np.ptp(curv) > 0 and np.ptp(mis) > 0:
            rho.append(stats.spearmanr(curv, mis).statistic)
    out["curvature_correlation"] = float(np.mean(rho)) if rho else 0.0
    return out


def _screen(stat: dict, config: DiagnoseConfig) -> dict:
    """Which extensions the structure statistics admit, and why."""
    out = {}
    for eid, ext in EXTENSIONS.items():
        if ext.signature == "amplitude_trend":
            ts = [abs(v["t"]) for v in stat["amplitude_trend"].values()]
            t_max = max(ts) if ts else 0.0
            kept = t_max >= config.screen_t or stat["curvature_correlation"] >= config.screen_corr
            why = f"|t| of the EJ-amplitude trend {t_max:.1f}, curvature correlation {stat['curvature_correlation']:.2f}"
        elif ext.signature in ("phase_linear", "magnitude_omega2"):
            share = stat[ext.signature]["share"]
            kept = share >= config.screen_share
            why = f"share of the misfit explained by the signature {share:.2f}"
        else:
            kept = stat["lag1_correlation"] >= config.screen_corr
            why = f"lag-1 correlation of the residuals {stat['lag1_correlation']:.2f}"
        out[eid] = {"kept": bool(kept), "why": why}
    return out


# --- name, model and show ----------------------------------------------------------------------

def _quantiles(v) -> dict:
    q = np.quantile(v, [0.05, 0.5, 0.95])
    return {"median": float(q[1]), "q05": float(q[0]), "q95": float(q[2])}


_UNITS = {"EJ_slip": "N m^2", "EJ_stick": "N m^2", "chi_slip": "1/m", "slip_exponent": "1", "beta_material": "1",
          "beta_friction": "1", "fixture_mass_kg": "kg", "delay_s": "s", "beta_viscous": "1", "beta1": "1",
          "beta2": "1", "rocking_rad_per_m": "rad/m", "ej_exponent": "1", "EJ": "N m^2", "beta": "1", "a1": "m",
          "a2": "m"}


def _combined(per_test: dict) -> dict:
    """Precision-weighted combination of per-test posteriors (normal approximation)."""
    m = np.array([v["mean"] for v in per_test.values()])
    s = np.array([max(v["sd"], 1e-300) for v in per_test.values()])
    w = 1 / s ** 2
    mean, sd = float(np.sum(w * m) / np.sum(w)), float(1 / np.sqrt(np.sum(w)))
    return {"median": mean, "q05": mean - 1.645 * sd, "q95": mean + 1.645 * sd}


def _parameters(effect: str, fits: dict, keys, baseline_names) -> dict:
    """The extension's own parameters with 90 % intervals, and what they mean on the bench."""
    own = [n for n in fits[keys[0]]["names"] if n not in baseline_names]
    out = {"effect": effect, "values": {}, "per_test": {}}
    if EXTENSIONS[effect].joint:
        # one parameter set per cable state; "values" is the state with the most tests (the dry cable)
        out["per_group"] = {}
        for key in keys:
            fit = fits[key]
            out["per_group"][key[1] or "default"] = {
                n: dict(_quantiles(fit["params"][n]), unit=_UNITS.get(n, "")) for n in own}
        main = max(keys, key=lambda k: len(fits[k]["mu_mean"]))
        out["values"] = out["per_group"][main[1] or "default"]
        out["words"] = "; ".join((f"{g} cable: " if len(keys) > 1 else "") + _words(effect, v)
                                 for g, v in out["per_group"].items())
        return out
    for n in own:
        per = {}
        for key in keys:
            v = fits[key]["params"][n]
            per[key[1]] = {"mean": float(v.mean()), "sd": float(v.std()), **_quantiles(v)}
        out["values"][n] = dict(_combined(per), unit=_UNITS.get(n, ""))
        for t, v in per.items():
            out["per_test"].setdefault(t, {})[n] = {k: v[k] for k in ("median", "q05", "q95")}
    out["words"] = _words(effect, out["values"])
    return out


def _words(effect: str, v: dict) -> str:
    def iv(name, scale=1.0, fmt="{:.3g}"):
        d = v[name]
        return (f"{fmt.format(d['median'] * scale)} [{fmt.format(d['q05'] * scale)}, "
                f"{fmt.format(d['q95'] * scale)}]")
    if effect == "sensor_delay":
        return (f"phase lags grow linearly with frequency: a {iv('delay_s', 1e3)} ms delay between the force "
                "and displacement channels (90 % interval)")
    if effect == "fixture_mass":
        return (f"the stiffness drops by omega^2 times {iv('fixture_mass_kg', 1e3, '{:.0f}')} g: a mass on the "
                "table that the empty-table calibration did not cancel")
    if effect == "viscous_damping":
        return (f"the loss factor grows with frequency: a viscous part of {iv('beta_viscous')} at 10 Hz "
                "(proportional to f) on top of the hysteretic one")
    if effect == "asymmetric_damping":
        return f"the arms damp differently: loss factor {iv('beta1')} on arm 1 (mass 1), {iv('beta2')} on arm 2"
    if effect == "base_rocking":
        return (f"the table rotates as it moves: {iv('rocking_rad_per_m')} mrad of tilt per mm of vertical "
                "motion")
    if effect == "frequency_dependent_stiffness":
        return (f"the cable's EJ changes with frequency as (f / 10 Hz)^s, s = {iv('ej_exponent')}: "
                "a viscoelastic cable")
    if effect == "strand_slip":
        return (f"the cable's wires slip at large curvature: EJ falls from {iv('EJ_stick')} N m^2 (stuck) to "
                f"{iv('EJ_slip')} N m^2 (slipping), half-way at a curvature amplitude of "
                f"{iv('chi_slip', 1e3)} x 10^-3 /m, and friction adds up to {iv('beta_friction')} to the loss "
                f"factor {iv('beta_material')} of the stuck cable; one law for every amplitude")
    return ""


def _check_model(effect, fits, keys, tests, likes, n_runs, config):
    """A fitted model's predictive check and PSIS-LOO: ``(z, thresholds, coverage, elpd_i)`` (see :func:`_check`)."""
    mu_mean, mu_var = {}, {}
    joint = effect != "baseline" and EXTENSIONS[effect].joint
    for key in keys:
        fit = fits[key]
        ts = [t for t in tests if _group(t) == key[1]] if joint else [key[1]]
        for t, m, v in zip(ts, fit["mu_mean"], fit["mu_var"]):
            mu_mean[t], mu_var[t] = m, v
    z, thr, coverage = _check(likes, [mu_mean[t] for t in tests], [mu_var[t] for t in tests], config.alpha)
    return z, thr, coverage, _pointwise(fits, keys, tests, joint, n_runs)


def _summary(effect, fits, keys, check, base_i, bands, tests) -> dict:
    """Before/after numbers of one model from its :func:`_check_model`: ELPD, misfit in the bands, coverage."""
    z, thr, coverage, elpd_i = check
    out = {"effect": effect, "elpd": float(elpd_i.sum()),
           "elpd_se": float(np.sqrt(elpd_i.size * np.var(elpd_i))),
           "coverage_90": coverage,
           "lines_off": int(sum(np.sum(np.abs(zt) > th) for zt, th in zip(z, thr))),
           "n_lines": int(sum(zt.size for zt in z)),
           "rms_z": float(np.sqrt(np.mean(np.concatenate([zt.ravel() for zt in z]) ** 2))),
           "band_rms_z": _band_rms(bands, tests, z),
           "converged": all(fits[k]["converged"] for k in keys),
           "r_hat_max": max(fits[k]["convergence"]["r_hat_max"] for k in keys),
           "ess_bulk_min": min(fits[k]["convergence"]["ess_bulk_min"] for k in keys),
           "tau_max": max(fits[k]["convergence"]["tau_max"] for k in keys),
           "steps_max": max(fits[k]["convergence"]["n_steps"] for k in keys),
           "not_converged": {f"{k[0]} {k[1]}".strip(): fits[k]["convergence"]["reason"] for k in keys
                             if not fits[k]["converged"]}}
    if base_i is not None:
        d, se = elpd_difference(base_i, elpd_i)
        out.update(delta_elpd=d, se=se)
    return out


def _pointwise(fits, keys, tests, joint: bool, n_runs: dict) -> np.ndarray:
    """PSIS-LOO pointwise ELPD of a model, runs of all tests in test order (``n_runs``: runs per test)."""
    parts = {}
    for key in keys:
        e = loo(fits[key]["log_lik"]).pointwise
        if joint:
            ts = [t for t in tests if _group(t) == key[1]]
            for t, piece in zip(ts, np.split(e, np.cumsum([n_runs[t] for t in ts])[:-1])):
                parts[t] = piece
        else:
            parts[key[1]] = e
    return np.concatenate([parts[t] for t in tests])


def _likes(damper, bench, tests, effect, prior_path=None):
    out = []
    for t in tests:
        data = remove_outlier_runs(bench.test(damper.name, t)).data
        out.append(likelihood_for(damper, data, extension_prior(effect, damper, base_path=prior_path),
                                  model=model_for(effect, data.amplitude_mm_pp)))
    return out


def _jobs(effect, damper, bench, tests, ss, config, prior_path=None):
    """Fit jobs of one model: one per test, or one per cable state for a joint extension."""
    likes = _likes(damper, bench, tests, effect, prior_path)
    if effect != "baseline" and EXTENSIONS[effect].joint:
        jobs = []
        for g in sorted({_group(t) for t in tests}):
            members = [lk for t, lk in zip(tests, likes) if _group(t) == g]
            amp = np.concatenate([lk.amplitude_mm_pp for lk in members])
            like = JointLikelihood(members, extension_prior(effect, damper, base_path=prior_path), model_for(effect, amp))
            jobs.append(((effect, g), like, ss.spawn(1)[0], config))
        return jobs, likes
    return [((effect, t), lk, s, config) for t, lk, s in zip(tests, likes, ss.spawn(len(tests)))], likes


def diagnose(damper: Damper, bench, tests=None, *, seed: int = 0, config: DiagnoseConfig = DiagnoseConfig(),
             progress: bool = True, effects=None, prior_path=None) -> dict:
    """Locate, name, model and show the physics a damper's recordings have and the model lacks.

    Parameters
    ----------
    damper : Damper
    bench : BenchData
    tests : sequence of str, optional
        Test labels (default: all of the damper's tests).
    seed : int
        Seeds every fit (through ``numpy.random.SeedSequence``): the same seed, the same numbers.
    config : DiagnoseConfig
    progress : bool
        Progress bars on stderr (when it is a terminal).
    effects : sequence of str, optional
        Restrict the catalogue (default: all of :data:`sbcal.extensions.EXTENSIONS`).
    prior_path : path-like, optional
        The prior file of the base parameters (``--priors``; default the bundled ``priors/default.toml``).

    Returns
    -------
    dict
        JSON-ready: ``verdict``, ``ranking``, ``bands``, ``parameters``, ``before``, ``after``, and
        ``statistics``, ``screen``, ``per_test``, ``rule``, ``settings`` (see ``docs/diagnose.md``).
    """
    t0 = time.perf_counter()
    available = bench.tests(damper.name)
    tests = list(available if tests is None else tests)
    for t in tests:
        if t not in available:
            raise InputError(f"{bench.source}: damper {damper.name!r} has no test {t!r} (has: {', '.join(available)})")
    if not tests:
        raise InputError(f"{bench.source}: no tests for damper {damper.name!r}")
    catalogue = list(EXTENSIONS if effects is None else effects)
    for e in catalogue:
        if e not in EXTENSIONS:
            raise InputError(f"unknown effect {e!r}; known: {', '.join(EXTENSIONS)}")
    label = (lambda stage: f"diagnose {damper.name}: {stage}") if progress else (lambda stage: None)
    root = np.random.SeedSequence(seed)
    seqs = dict(zip(["baseline"] + list(EXTENSIONS), root.spawn(len(EXTENSIONS) + 1)))

    # 1-2. baseline and locate
    jobs, likes = _jobs("baseline", damper, bench, tests, seqs["baseline"], config, prior_path)
    fits = _run_fits(jobs, config, label("per-test fits"))
    base_fits = {k[1]: v for k, v in fits.items()}
    base_keys = [("baseline", t) for t in tests]
    n_runs = {t: lk.y.shape[1] for t, lk in zip(tests, likes)}
    base_check = _check_model("baseline", fits, base_keys, tests, likes, n_runs, config)
    z0_, thr0, _, base_i = base_check
    bands = _bands(tests, likes, z0_, thr0)
    statistics = _statistics(damper, tests, likes, base_fits, z0_)
    screen = _screen(statistics, config)
    before = _summary("baseline", fits, base_keys, base_check, None, bands, tests)

    # 3. name: refit the screened candidates (all of them only if the baseline fails its check)
    candidates = [e for e in catalogue if screen[e]["kept"]] if bands else []
    ranking, summaries, checks = [], {}, {}
    all_jobs = []
    for e in candidates:
        jobs_e, _ = _jobs(e, damper, bench, tests, seqs[e], config, prior_path)
        all_jobs += jobs_e
    if all_jobs:
        fits.update(_run_fits(all_jobs, config, label(f"{len(candidates)} candidate extension(s)")))
    keys_of = {e: [k for k in fits if k[0] == e] for e in candidates}
    for e in candidates:
        checks[e] = _check_model(e, fits, keys_of[e], tests, likes, n_runs, config)
        s = _summary(e, fits, keys_of[e], checks[e], base_i, bands, tests)
        s["explained"] = (1 - _band_sq(bands, tests, checks[e][0]) / _band_sq(bands, tests, z0_)) if bands else 0.0
        summaries[e] = s
        ranking.append({"effect": e, "delta_elpd": s["delta_elpd"], "se": s["se"], "explained": s["explained"]})
    ranking.sort(key=lambda r: -r["delta_elpd"])

    # 4. verdict
    if not bands:
        verdict = "none"
    elif ranking and ranking[0]["delta_elpd"] > config.clear_se * ranking[0]["se"] \
            and ranking[0]["explained"] >= config.min_explained:
        verdict = ranking[0]["effect"]
    else:
        verdict = "unexplained"
    shown = verdict if verdict in EXTENSIONS else (ranking[0]["effect"] if ranking else None)
    after = summaries[shown] if shown else before
    per_test = []
    if shown:
        z_after, _, _, after_i = checks[shown]
        start = 0
        for t, zb, za in zip(tests, z0_, z_after):
            n = n_runs[t]
            d, se = elpd_difference(base_i[start:start + n], after_i[start:start + n])
            start += n
            per_test.append({"test": t, "delta_elpd": d, "se": se,
                             "rms_z_before": float(np.sqrt(np.mean(zb ** 2))),
                             "rms_z_after": float(np.sqrt(np.mean(za ** 2)))})
    result = {
        "damper": damper.name, "tests": tests, "seed": seed, "verdict": verdict,
        "bench": {"path": str(bench.source), "rows_sha256": rows_digest(bench, damper.name)},
        "rule": (f"none if no line of the baseline is off (|z| beyond the t quantile at family-wise alpha = "
                 f"{config.alpha:g} over all lines); else the best extension if delta_elpd > {config.clear_se:g} se "
                 f"and it removes >= {config.min_explained:.0%} of the squared misfit in the bands; else unexplained"),
        "ranking": ranking,
        "bands": [{k: b[k] for k in ("test", "quantity", "f_lo", "f_hi", "max_abs_z")} for b in bands],
        "parameters": _parameters(shown, fits, keys_of[shown], base_fits[tests[0]]["names"]) if shown else {},
        "before": before,
        "after": after,
        "per_test": per_test,
        "residuals": {t: {"freq_hz": lk.freq_hz.tolist(), "z_before": zb.tolist(),
                          "z_after": (checks[shown][0][i] if shown else zb).tolist()}
                      for i, (t, lk, zb) in enumerate(zip(tests, likes, z0_))},
        "statistics": statistics,
        "screen": screen,
        "settings": asdict(config),
        "versions": versions(),
        "wall_s": time.perf_counter() - t0,
    }
    return result
