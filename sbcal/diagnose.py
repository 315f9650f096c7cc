"""Missing physics: locate where the model and the recordings differ, name the physics left out,
model it and show the fit improve (``docs/diagnose.md``).

1. **Baseline**: the per-test model (``theta1``: EJ, beta, a1, a2) with the noise-only likelihood (no
   model-error scales: the model must explain the runs within the bench's scatter), sampled per test.
2. **Locate**: the residual of each test's run mean, line by line, standardised by the likelihood's
   t of the run mean and the posterior spread of the model, ``z``. A line is *off* when ``|z|``
   exceeds the t quantile that keeps the family-wise false-alarm rate over all lines at ``alpha``
   (Bonferroni); neighbouring off lines form a band. The **global check** adds up the residual as a
   whole (the normal scores of every ``z``, squared, against chi-square with the lines' degrees of
   freedom less the fitted parameters): an effect spread thinly over every line, none of them beyond
   the per-line alarm, still shows there. Structure statistics point at candidate physics.
3. **Name**: each screened catalogue extension is refitted (``strand_slip``: the cable law of
   :mod:`sbcal.cable_fit`, every fitted family, jointly over the amplitudes of each cable state; the
   best family by PSIS-LOO) and compared with the baseline by PSIS-LOO grouped by run.
4. **Verdict**: ``none`` when neither the lines nor the global check find a misfit; else the best
   extension when it beats the baseline clearly (``delta_elpd > clear_se * se``) *and* removes at least
   ``min_explained`` of the misfit (the squared z in the located bands; without bands, the global
   excess over chance); else ``unexplained``.
5. **Secondary**: on the verdict's model the misfit is located again; where some remains, the
   measurement-chain effects that compose with it (:data:`sbcal.cable_fit.SECONDARY`,
   :data:`sbcal.extensions.CHAIN`) are screened and refitted on top, and the same rule names a
   ``secondary`` effect (else null).
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy import stats

from .bench import DEFAULT_Z_THRESHOLD, remove_outlier_runs, rows_digest
from .cable_fit import (SECONDARY, CableFit, cable_config, cable_likelihood, cable_seed, compare_families, compared_laws,
                        sample_cable, state_tests, store_cable)
from .calibrate import likelihood_for
from .damper import Damper
from .errors import InputError
from .extensions import CHAIN, EXTENSIONS, model_for
from .fem import arm_curvatures
from .hysteresis import FITTED_LAWS
from .likelihood import JointLikelihood
from .priors import Prior, extension_prior
from .progress import progress_bar
from .runs import versions
from .sampler import SamplerConfig, sample
from .seeds import job_seed
from .stats import elpd_difference, loo
from .workers import default_workers, one_blas_thread

__all__ = ["DiagnoseConfig", "diagnose", "curves_frame"]

_QUANTITIES = ("magnitude", "phase")


@dataclass(frozen=True)
class DiagnoseConfig:
    """Settings of :func:`diagnose` (the defaults are what ``sbcal diagnose`` uses).

    Attributes
    ----------
    alpha : float
        Family-wise false-alarm rate of the per-line check over all lines of all tests.
    global_alpha : float
        False-alarm rate of the global check of the residual as a whole.
    clear_se : float
        An extension beats the model below it clearly when ``delta_elpd > clear_se * se``.
    min_explained : float
        ... and removes at least this share of the misfit (in the bands; without bands, of the
        global excess over chance).
    screen_t : float
        Screening: |t| of the EJ-versus-amplitude trend that admits ``strand_slip``.
    screen_share : float
        Screening: share of the misfit a signature explains (phase linear in omega: ``sensor_delay``;
        ``-omega^2 m``: ``fixture_mass``) that admits the extension.
    screen_corr : float
        Screening: lag-1 correlation of the residuals over frequency (structured misfit) that admits
        the extensions without a specific signature, or curvature correlation for strand slip.
    laws : tuple of str
        The cable-law families fitted for ``strand_slip`` (:data:`sbcal.hysteresis.FITTED_LAWS`), those
        of them a damper's cable states have the tests for (:func:`sbcal.cable_fit.compared_laws`).
    secondary : bool
        Search for a second effect on top of the verdict's.
    draws : int
        Posterior draws kept per ensemble.
    max_steps, cable_max_steps : int
        Step caps of the engine for a per-test fit and for a cable-law fit (the policy and everything
        else are the engine's: :data:`sbcal.sampler.POLICY`).
    workers : int
        Processes: fits run in parallel, one per process.
    z_threshold : float
        Outlier-run threshold of the cleaning (:func:`sbcal.bench.remove_outlier_runs`); the pipeline
        sets it from its own settings, so every stage cleans alike.
    """

    alpha: float = 0.05
    global_alpha: float = 0.01
    clear_se: float = 4.0
    min_explained: float = 0.8
    screen_t: float = 3.0
    screen_share: float = 0.05
    screen_corr: float = 0.3
    laws: tuple = FITTED_LAWS
    secondary: bool = True
    draws: int = 250
    max_steps: int = 20000
    cable_max_steps: int = 8000
    workers: int = field(default_factory=default_workers)
    z_threshold: float = DEFAULT_Z_THRESHOLD

    def sampler(self, ndim: int, joint: bool = False) -> SamplerConfig:
        if joint:  # the cable fit's own settings, capped as here
            return cable_config(ndim, workers=1, max_steps=self.cable_max_steps, max_draws=self.draws)
        return SamplerConfig(nwalkers=max(16, 2 * ndim + 2), max_draws=self.draws, max_steps=self.max_steps,
                             workers=1)


# --- models: a primary effect, maybe with secondary ones on top ----------------------------------

def _name(primary: str, secondary=()) -> str:
    return "+".join((primary,) + tuple(secondary))


def _per_test_prior(primary: str, secondary, damper: Damper, prior_path) -> Prior:
    prior = extension_prior(primary, damper, base_path=prior_path)
    boxes = {n: prior.box(n) for n in prior.names}
    for e in secondary:
        ext = extension_prior(e, damper, base_path=prior_path)
        boxes.update({n: ext.box(n) for n in ext.names if n not in boxes})
    return Prior.from_boxes(_name(primary, secondary), boxes)


def _jobs(primary, secondary, damper, bench, tests, seed, config, prior_path) -> list:
    """Fit jobs of one model: one per test, or for strand slip one per cable state and law family.

    A job is ``(key, target, stream, config)``: key ``(model name, test)`` or ``(model name, state,
    law)``; the stream keyed by what the fit is (a cable fit's is :func:`sbcal.cable_fit.cable_seed`,
    the same as ``sbcal cable``'s), so no fit's draws depend on which other fits run.
    """
    name = _name(primary, secondary)
    jobs = []
    if primary == "strand_slip":
        for state, members in sorted(state_tests(tests).items()):
            for law in compared_laws(config.laws, tests):
                like = cable_likelihood(damper, bench, members, law, effects=secondary, prior_path=prior_path,
                                        z_threshold=config.z_threshold)
                jobs.append(((name, state, law), like, cable_seed(seed, damper.name, state, law, tuple(secondary))))
    else:
        prior = _per_test_prior(primary, secondary, damper, prior_path)
        model = model_for(primary, secondary)
        for t in tests:
            data = remove_outlier_runs(bench.test(damper.name, t), config.z_threshold).data
            jobs.append(((name, t), likelihood_for(damper, data, prior, model=model),
                         job_seed(seed, "diagnose", damper.name, name, t)))
    return [(key, target, s, config) for key, target, s in jobs]


# --- fits ----------------------------------------------------------------------------------------

def _fit(job):
    """One posterior through the engine (a test's, or a cable state's: :func:`sbcal.cable_fit.sample_cable`).
    Module-level: picklable."""
    key, like, ss, config = job
    with one_blas_thread():
        if isinstance(like, JointLikelihood):
            return key, sample_cable(like, seed=ss, config=config.sampler(like.prior.ndim, True))
        return key, sample(like, seed=ss, config=config.sampler(like.prior.ndim))


def _posterior(like, res) -> dict:
    """An engine result -> what the diagnosis needs: model curves, pointwise log-likelihood, convergence."""
    params = res.flat()
    joint = isinstance(like, JointLikelihood)
    mus = like.predict(params) if joint else [like.predict(params)]
    mu_mean, mu_var, mu_median = [], [], []
    for mu in mus:
        # phase draws about the first draw, so a wrap cannot corrupt the mean
        d = mu.copy()
        d[1] = mu[1, :1] + np.remainder(mu[1] - mu[1, :1] + np.pi, 2 * np.pi) - np.pi
        mu_mean.append(d.mean(axis=1))
        mu_var.append(d.var(axis=1))
        mu_median.append(np.median(d, axis=1))
    return dict(params=params, names=like.prior.names, log_lik=res.log_likelihood, mu_mean=mu_mean, mu_var=mu_var,
                mu_median=mu_median, convergence=res.convergence_dict(), converged=res.converged,
                result=res, like=like, n_params=like.prior.ndim)


def _run_fits(jobs, config, label) -> dict:
    """Run fits, ``config.workers`` at a time (the costly cable fits first); ``{key: fit}``."""
    jobs = sorted(jobs, key=lambda j: not isinstance(j[1], JointLikelihood))
    likes = {j[0]: j[1] for j in jobs}
    out = {}
    with progress_bar(label, total=len(jobs), unit="fit") as bar:
        if config.workers > 1 and len(jobs) > 1:
            with ProcessPoolExecutor(max_workers=config.workers) as pool:
                for key, res in pool.map(_fit, jobs):
                    out[key] = _posterior(likes[key], res)
                    bar.update(1)
        else:
            for job in jobs:
                key, res = _fit(job)
                out[key] = _posterior(likes[key], res)
                bar.update(1)
    return out


def _choose_law(fits: dict, name: str) -> tuple[dict, dict | None]:
    """For a cable model, keep the best family's fits (by PSIS-LOO summed over cable states):
    ``{(name, state): fit}``, and the comparison (None for per-test models)."""
    cable = {k: f for k, f in fits.items() if k[0] == name and len(k) == 3}
    if not cable:
        return {k: f for k, f in fits.items() if k[0] == name}, None
    by_law = {}
    for (_, state, law), f in cable.items():
        by_law.setdefault(law, {})[state] = CableFit(damper="", state=state, law=law, tests=(), effects=(),
                                                     result=f["result"], like=f["like"], loo=loo(f["log_lik"]))
    comparison = compare_families(by_law)
    for law in comparison["families"]:
        comparison["families"][law]["converged"] = all(cable[(name, s, law)]["converged"] for s in by_law[law])
    best = comparison["best"]
    kept = {(name, state): dict(f, law=law) for (_, state, law), f in cable.items() if law == best}
    return kept, comparison


# --- locate --------------------------------------------------------------------------------------

def _check(likes, mu_mean, mu_var, alpha: float, n_params: int):
    """Standardised residuals per test ``(2, n_freq)``, the off-line thresholds, coverage and the global check.

    The run mean's residual is standardised by the noise-only likelihood's t of the run mean given the
    runs' deviations (:meth:`TestLikelihood.mean_scale`) widened by the posterior spread of the model;
    the band of a new run is the likelihood's new-run t (:meth:`TestLikelihood.new_run`), likewise
    widened. The global check: the normal scores of every z (through its t), squared and summed,
    against chi-square with the number of values less ``n_params``.
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
        scores.append(stats.norm.isf(stats.t.sf(np.abs(zt), dof)))  # |z| as the normal deviate of equal tail
        # 90 % predictive band of a new run against every recorded run
        _, new_scale, new_dof = (a[:, 0] for a in lk.new_run({}, mu))
        half = stats.t.ppf(0.95, new_dof) * np.sqrt(new_scale ** 2 + v)
        dev = lk.y - m[:, None, :]
        dev[1] = np.remainder(dev[1] + np.pi, 2 * np.pi) - np.pi
        ok = (np.abs(dev) <= half[:, None, :]) & lk.present[None]
        inside += int(ok.sum())
        total += 2 * int(lk.present.sum())
    u = np.concatenate([s.ravel() for s in scores])
    u = np.where(np.isfinite(u), u, 40.0)  # a tail beyond double precision: far beyond chance
    dof = max(u.size - n_params, 1)
    chi2 = float(np.sum(u ** 2))
    glob = {"chi2": chi2, "dof": int(dof), "p_value": float(stats.chi2.sf(chi2, dof)), "excess": chi2 - dof}
    return z, thr, inside / total, glob


def _bands(tests, likes, z, thr) -> list:
    """Neighbouring off lines (a gap of one line allowed) as bands, per test and quantity."""
    bands = []
    for t, lk, zt, th in zip(tests, likes, z, thr):
        th = np.broadcast_to(th, zt.shape)
        for q, name in enumerate(_QUANTITIES):
            off = np.flatnonzero(np.abs(zt[q]) > th[q])
            if off.size == 0:
                continue
            for g in np.split(off, np.flatnonzero(np.diff(off) > 2) + 1):
                lines = np.arange(g[0], g[-1] + 1)
                bands.append({"test": t, "quantity": name, "f_lo": float(lk.freq_hz[g[0]]),
                              "f_hi": float(lk.freq_hz[g[-1]]), "lines": [int(i) for i in lines],
                              "max_abs_z": float(np.max(np.abs(zt[q, lines])))})
    return bands


def _band_sq(bands, tests, z) -> float:
    index = {t: i for i, t in enumerate(tests)}
    return float(sum(np.sum(z[index[b["test"]]][_QUANTITIES.index(b["quantity"]), b["lines"]] ** 2) for b in bands))


def _band_rms(bands, tests, z) -> list:
    index = {t: i for i, t in enumerate(tests)}
    return [float(np.sqrt(np.mean(z[index[b["test"]]][_QUANTITIES.index(b["quantity"]), b["lines"]] ** 2)))
            for b in bands]


def _share(resid, weight_sq, regressor) -> tuple[float, float]:
    """Share of ``sum w r^2`` explained by ``r ~ c * regressor`` (weighted, through 0), and ``c``."""
    w = weight_sq
    num, den = np.sum(w * resid * regressor), np.sum(w * regressor * regressor)
    if den <= 0:
        return 0.0, 0.0
    c = num / den
    return float(max(0.0, 1 - np.sum(w * (resid - c * regressor) ** 2) / np.sum(w * resid * resid))), float(c)


def _signatures(tests, likes, mu_mean, mu_var, z) -> dict:
    """Statistics of a model's residuals that point at measurement-chain effects."""
    ac = [np.corrcoef(zt[q, :-1], zt[q, 1:])[0, 1] for zt in z for q in (0, 1) if zt.shape[1] > 2 and np.std(zt[q]) > 0]
    out = {"lag1_correlation": float(np.nanmean(ac)) if ac else 0.0}
    ph_r, ph_w, ph_x, c_r, c_w, c_x = [], [], [], [], [], []
    for lk, m, v in zip(likes, mu_mean, mu_var):
        r = lk.residual(m[:, None, :])[:, 0]
        w = 1.0 / (lk.sigma ** 2 / lk.n + v)
        omega = 2 * np.pi * lk.freq_hz
        ph_r.append(r[1]), ph_w.append(w[1]), ph_x.append(-omega)
        reg = -omega ** 2 / np.exp(m[0] + 1j * m[1])  # d ln f / d m: log-magnitude and phase parts
        c_r.append(r.ravel()), c_w.append(w.ravel()), c_x.append(np.concatenate([reg.real, reg.imag]))
    share, delay = _share(np.concatenate(ph_r), np.concatenate(ph_w), np.concatenate(ph_x))
    out["phase_linear"] = {"share": share, "delay_s": delay}
    share, mass = _share(np.concatenate(c_r), np.concatenate(c_w), np.concatenate(c_x))
    out["magnitude_omega2"] = {"share": share, "mass_kg": mass}
    return out


def _rocking_signature(fits, tests, likes, mean, var, h: float = 0.05) -> tuple[float, float]:
    """Share of a cable model's misfit that clamp rocking explains to first order, and its value [rad/m].

    The regressor is ``d ln f / d r`` at ``r = 0`` of the verdict's cable model at its posterior median
    (central difference, step ``h`` rad/m), per state's tests.
    """
    from .cable_fit import CableForward

    index = {t: i for i, t in enumerate(tests)}
    r_all, w_all, x_all = [], [], []
    for (_, state), fit in sorted(fits.items()):
        like, fwd = fit["like"], fit["like"].model
        med = {n: np.array([np.median(v)]) for n, v in fit["params"].items()}
        rocking = CableForward(fwd.law, fwd.amplitude_mm_pp, fwd.segments, ("base_rocking",), fwd.sections)
        freq = np.concatenate([lk.freq_hz for lk in like.likes])
        lo, hi = (rocking(like.damper, freq, **med, rocking_rad_per_m=np.array([r]))[0] for r in (-h, h))
        d = np.log(hi / lo) / (2 * h)  # a ratio near 1: no phase wrap
        for t, piece in zip(state_tests(tests)[state], np.split(d, np.cumsum([lk.freq_hz.size for lk in like.likes])[:-1])):
            lk = likes[index[t]]
            r_all.append(lk.residual(mean[t][:, None, :])[:, 0].ravel())
            w_all.append((1.0 / (lk.sigma ** 2 / lk.n + var[t])).ravel())
            x_all.append(np.concatenate([piece.real, piece.imag]))
    x = np.concatenate(x_all)
    if not np.all(np.isfinite(x)):
        return 0.0, 0.0
    return _share(np.concatenate(r_all), np.concatenate(w_all), x)


def _statistics(damper, tests, likes, fits, z) -> dict:
    """The structure statistics of the baseline's residuals (module docstring)."""
    out = _signatures(tests, likes, [fits[t]["mu_mean"][0] for t in tests], [fits[t]["mu_var"][0] for t in tests], z)
    trend = {}  # EJ trend with amplitude within each cable state (constant-amplitude tests)
    for g, members in sorted(state_tests(tests).items()):
        amp, ej = [], []
        for t, lk in zip(tests, likes):
            a = lk.amplitude_mm_pp
            if t in members and np.all(np.isfinite(a)) and np.allclose(a, a[0]):
                amp.append(a[0])
                ej.append(np.median(fits[t]["params"]["EJ"]))
        if len(amp) >= 3 and np.ptp(np.log(amp)) > 0:
            res = stats.linregress(np.log(amp), np.log(ej))
            tval = res.slope / res.stderr if res.stderr > 0 else np.inf * np.sign(res.slope)
            trend[g] = {"slope": float(res.slope), "t": float(tval), "n_tests": len(amp)}
    out["amplitude_trend"] = trend
    rho = []  # misfit versus the predicted cable curvature (rms over both arms' ends), Spearman per test
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


def _screen_one(eid, stat, config) -> tuple[bool, str]:
    sig = EXTENSIONS[eid].signature
    if sig == "amplitude_trend":
        ts = [abs(v["t"]) for v in stat.get("amplitude_trend", {}).values()]
        t_max = max(ts) if ts else 0.0
        kept = t_max >= config.screen_t or stat.get("curvature_correlation", 0.0) >= config.screen_corr
        return kept, f"|t| of the EJ-amplitude trend {t_max:.1f}, curvature correlation {stat.get('curvature_correlation', 0.0):.2f}"
    if sig in ("phase_linear", "magnitude_omega2"):
        share = stat[sig]["share"]
        return share >= config.screen_share, f"share of the misfit explained by the signature {share:.2f}"
    return stat["lag1_correlation"] >= config.screen_corr, f"lag-1 correlation of the residuals {stat['lag1_correlation']:.2f}"


def _screen(stat: dict, config: DiagnoseConfig, effects) -> dict:
    """Which extensions the structure statistics admit, and why."""
    return {e: dict(zip(("kept", "why"), _screen_one(e, stat, config))) for e in effects}


# --- parameters in words -------------------------------------------------------------------------

def _quantiles(v) -> dict:
    q = np.quantile(v, [0.05, 0.5, 0.95])
    return {"median": float(q[1]), "q05": float(q[0]), "q95": float(q[2])}


_UNITS = {"EJ_min": "N m^2", "delta_EJ": "N m^2", "chi_slip": "1/m", "chi_micro": "1/m", "chi_macro": "1/m",
          "sharpness": "1", "density_exponent": "1", "macro_ratio": "1", "beta_material": "1",
          "fixture_mass_kg": "kg", "delay_s": "s", "beta_viscous": "1", "beta1": "1", "beta2": "1",
          "rocking_rad_per_m": "rad/m", "ej_exponent": "1", "EJ": "N m^2", "beta": "1", "a1": "m", "a2": "m"}


def _scale_factor(estimates, se) -> float:
    """The Birge ratio of estimates of one value: ``sqrt(chi2 / (K - 1))`` about their precision-weighted
    mean (1 for one estimate). Above 1 they disagree beyond their errors; the Particle Data Group then
    widens the combined error by it, as :func:`_combined` and :func:`_parameters` do."""
    m, s = np.asarray(estimates, float), np.maximum(np.asarray(se, float), 1e-300)
    if m.size < 2:
        return 1.0
    w = 1 / s ** 2
    mean = np.sum(w * m) / np.sum(w)
    return float(np.sqrt(np.sum(w * (m - mean) ** 2) / (m.size - 1)))


def _combined(per_test: dict) -> dict:
    """Precision-weighted combination of per-test (or per-cable-state) posteriors (normal
    approximation), its error widened by their :func:`_scale_factor` where they disagree."""
    m = np.array([v["mean"] for v in per_test.values()])
    s = np.array([max(v["sd"], 1e-300) for v in per_test.values()])
    w = 1 / s ** 2
    factor = _scale_factor(m, s)
    mean, sd = float(np.sum(w * m) / np.sum(w)), float(max(1.0, factor) / np.sqrt(np.sum(w)))
    return {"median": mean, "q05": mean - 1.645 * sd, "q95": mean + 1.645 * sd, "scale_factor": factor}


def _test_estimates(fit: dict, name: str, tests) -> dict:
    """Each test's own estimate of a value a joint fit shares between them: one Gauss-Newton step
    from the posterior median on that test's run means alone (the other parameters held), with its
    noise-only standard error; ``{test: (estimate, se)}`` for the fit's ``tests`` (in its order)."""
    like = fit["like"]
    med = {n: np.atleast_1d(np.median(v)) for n, v in fit["params"].items()}
    _, lo, hi = like.prior.box(name)
    h = 1e-6 * (hi - lo)
    h = h if med[name][0] + h <= hi else -h
    base, moved = like.predict(med), like.predict(dict(med, **{name: med[name] + h}))
    out = {}
    for t, lk, a, b in zip(tests, like.likes, base, moved):
        r = lk.residual(a)[:, 0]
        jac = (r - lk.residual(b)[:, 0]) / h  # d(model)/d(value), phase wrapped by residual()
        w = lk.n / lk.sigma ** 2  # 1 / variance of a run mean
        info = float(np.sum(w * jac ** 2))
        if info > 0:  # a test the value does not move says nothing about it
            out[t] = (float(med[name][0] + np.sum(w * jac * r) / info), float(1 / np.sqrt(info)))
    return out


def _parameters(effect: str, fits: dict, keys, baseline_names, tests=None) -> dict:
    """The extension's own parameters with 90 % intervals, and what they mean on the bench.

    A value shared by several tests or cable states comes with its ``scale_factor``
    (:func:`_scale_factor` of the tests' or states' own estimates, ``tests`` naming a joint fit's tests;
    in ``values`` the largest applied): where it exceeds 1 the interval is widened by it about the
    combined value, so that a model that fits some tests worse than others does not give a value more
    precisely than the tests agree on it."""
    own = [n for n in fits[keys[0]]["names"] if n not in baseline_names]
    out = {"effect": effect, "values": {}, "per_test": {}}
    if effect.split("+")[0] == "strand_slip":
        out["per_group"] = {}
        for key in keys:  # one parameter set per cable state; "values" is the state with the most tests
            fit = fits[key]
            out["per_group"][key[1]] = {n: dict(_quantiles(fit["params"][n]), unit=_UNITS.get(n, "")) for n in own}
        main = max(keys, key=lambda k: len(fits[k]["mu_mean"]))
        out["values"] = out["per_group"][main[1]]
        out["law"] = fits[main]["law"]
        out["words"] = "; ".join(f"{g} cable: " + _words(effect, v, fits[(keys[0][0], g)]["law"])
                                 for g, v in out["per_group"].items())
        return out
    for n in own:
        per = {}
        for key in keys:
            v = fits[key]["params"][n]
            per[key[1]] = {"mean": float(v.mean()), "sd": float(v.std()), **_quantiles(v)}
            if tests is not None and isinstance(fits[key]["like"], JointLikelihood):
                # one value for a cable state's tests: do the tests, each on its own, agree on it?
                own_est = _test_estimates(fits[key], n, state_tests(tests)[key[1]])
                factor = _scale_factor(*zip(*own_est.values()))
                per[key[1]].update(sd=per[key[1]]["sd"] * max(1.0, factor), scale_factor=factor,
                                   tests={t: e for t, (e, _) in own_est.items()})
        combined = _combined(per)
        # the largest factor applied: between the states', or within a state between its tests
        combined["scale_factor"] = max([combined["scale_factor"]] + [v.get("scale_factor", 1.0) for v in per.values()])
        out["values"][n] = dict(combined, unit=_UNITS.get(n, ""))
        for t, v in per.items():
            out["per_test"].setdefault(t, {})[n] = {k: v[k] for k in ("median", "q05", "q95", "scale_factor", "tests")
                                                    if k in v}
    out["words"] = _words(effect, out["values"])
    return out


def _words(effect: str, v: dict, law: str = "") -> str:
    def iv(name, scale=1.0, fmt="{:.3g}"):
        d = v[name]
        wide = (f" (widened {d['scale_factor']:.1f}x: the tests' own estimates disagree beyond their noise)"
                if d.get("scale_factor", 1.0) > 1 else "")
        return (f"{fmt.format(d['median'] * scale)} [{fmt.format(d['q05'] * scale)}, "
                f"{fmt.format(d['q95'] * scale)}]{wide}")
    parts = []
    for e in effect.split("+"):
        if e == "sensor_delay":
            parts.append(f"phase lags grow linearly with frequency: a {iv('delay_s', 1e3)} ms delay between the force "
                         "and displacement channels (90 % interval)")
        elif e == "fixture_mass":
            parts.append(f"the stiffness drops by omega^2 times {iv('fixture_mass_kg', 1e3, '{:.0f}')} g: a mass on "
                         "the table that the empty-table calibration did not cancel")
        elif e == "viscous_damping":
            parts.append(f"the loss factor grows with frequency: a viscous part of {iv('beta_viscous')} at 10 Hz "
                         "(proportional to f) on top of the hysteretic one")
        elif e == "asymmetric_damping":
            parts.append(f"the arms damp differently: loss factor {iv('beta1')} on arm 1 (mass 1), {iv('beta2')} on arm 2")
        elif e == "base_rocking":
            parts.append(f"the table rotates as it moves: {iv('rocking_rad_per_m')} mrad of tilt per mm of vertical "
                         "motion")
        elif e == "frequency_dependent_stiffness":
            parts.append(f"the cable's EJ changes with frequency as (f / 10 Hz)^s, s = {iv('ej_exponent')}: "
                         "a viscoelastic cable")
        elif e == "strand_slip":
            stuck = {k: v["EJ_min"][k] + v["delta_EJ"][k] for k in ("median", "q05", "q95")}
            parts.append(f"the cable's wires slip with curvature ({law} law, one law for every amplitude): EJ "
                         f"{stuck['median']:.3g} N m^2 when stuck, falling towards {iv('EJ_min')} N m^2 in full slip, "
                         f"with friction loss on top of the loss factor {iv('beta_material')} of the strand itself")
    return "; ".join(parts)


# --- models' checks and summaries ------------------------------------------------------------------

def _model_curves(fits, keys, tests, joint: bool):
    """Per test: posterior mean, variance and median of the model curves ``(2, n_freq)``."""
    mean, var, med = {}, {}, {}
    for key in keys:
        fit = fits[key]
        ts = state_tests(tests)[key[1]] if joint else [key[1]]
        for t, m, v, d in zip(ts, fit["mu_mean"], fit["mu_var"], fit["mu_median"]):
            mean[t], var[t], med[t] = m, v, d
    return mean, var, med


def _check_model(name, fits, keys, tests, likes, n_runs, config):
    """A fitted model's predictive check and PSIS-LOO: ``(z, thresholds, coverage, elpd_i, global)``."""
    joint = name.split("+")[0] == "strand_slip"
    mean, var, _ = _model_curves(fits, keys, tests, joint)
    n_params = sum(fits[k]["n_params"] for k in keys)
    z, thr, coverage, glob = _check(likes, [mean[t] for t in tests], [var[t] for t in tests], config.alpha, n_params)
    parts = {}
    for key in keys:
        e = loo(fits[key]["log_lik"]).pointwise
        if joint:
            ts = state_tests(tests)[key[1]]
            for t, piece in zip(ts, np.split(e, np.cumsum([n_runs[t] for t in ts])[:-1])):
                parts[t] = piece
        else:
            parts[key[1]] = e
    return z, thr, coverage, np.concatenate([parts[t] for t in tests]), glob


def _summary(name, fits, keys, check, ref_i, bands, tests) -> dict:
    """Numbers of one model from its :func:`_check_model`: ELPD, misfit, coverage, convergence."""
    z, thr, coverage, elpd_i, glob = check
    out = {"effect": name, "elpd": float(elpd_i.sum()),
           "elpd_se": float(np.sqrt(elpd_i.size * np.var(elpd_i))),
           "coverage_90": coverage,
           "lines_off": int(sum(np.sum(np.abs(zt) > th) for zt, th in zip(z, thr))),
           "n_lines": int(sum(zt.size for zt in z)),
           "rms_z": float(np.sqrt(np.mean(np.concatenate([zt.ravel() for zt in z]) ** 2))),
           "band_rms_z": _band_rms(bands, tests, z),
           "global": glob,
           "converged": all(fits[k]["converged"] for k in keys),
           "r_hat_max": max(fits[k]["convergence"]["r_hat_max"] for k in keys),
           "ess_bulk_min": min(fits[k]["convergence"]["ess_bulk_min"] for k in keys),
           "tau_max": max(fits[k]["convergence"]["tau_max"] for k in keys),
           "steps_max": max(fits[k]["convergence"]["n_steps"] for k in keys),
           "not_converged": {" ".join(k[:2]): fits[k]["convergence"]["reason"] for k in keys if not fits[k]["converged"]}}
    if ref_i is not None:
        d, se = elpd_difference(ref_i, elpd_i)
        out.update(delta_elpd=d, se=se)
    return out


def _misfit(bands, tests, z, glob) -> float:
    """The misfit an extension must remove: squared z in the bands, else the global excess over chance."""
    return _band_sq(bands, tests, z) if bands else max(glob["excess"], 0.0)


def _explained(bands, tests, z_ref, glob_ref, z_new, glob_new) -> float:
    before = _misfit(bands, tests, z_ref, glob_ref)
    if before <= 0:
        return 0.0
    after = _band_sq(bands, tests, z_new) if bands else max(glob_new["excess"], 0.0)
    return float(1 - after / before)


# --- the diagnosis -------------------------------------------------------------------------------

def _compare(candidates, spec_of, fits_all, ref_check, bands, tests, likes, n_runs, config):
    """Check and rank candidate models against a reference model's check; ``(ranking, summaries, checks, kept)``."""
    z_ref, _, _, ref_i, glob_ref = ref_check
    ranking, summaries, checks, kept, laws = [], {}, {}, {}, {}
    for e in candidates:
        name = spec_of(e)
        keys_fits, comparison = _choose_law(fits_all, name)
        kept[e] = keys_fits
        keys = sorted(keys_fits)
        checks[e] = _check_model(name, keys_fits, keys, tests, likes, n_runs, config)
        s = _summary(name, keys_fits, keys, checks[e], ref_i, bands, tests)
        s["explained"] = _explained(bands, tests, z_ref, glob_ref, checks[e][0], checks[e][4])
        if comparison is not None:
            s["law"] = comparison
            laws[e] = comparison
        summaries[e] = s
        ranking.append({"effect": e, "delta_elpd": s["delta_elpd"], "se": s["se"], "explained": s["explained"],
                        "converged": s["converged"], "r_hat_max": s["r_hat_max"], "ess_bulk_min": s["ess_bulk_min"]})
    ranking.sort(key=lambda r: -r["delta_elpd"])
    return ranking, summaries, checks, kept, laws


def _decide(misfit: bool, ranking, config) -> str | None:
    if not misfit:
        return None
    best = ranking[0] if ranking else None
    if best and best["delta_elpd"] > config.clear_se * best["se"] and best["explained"] >= config.min_explained:
        return best["effect"]
    return "unexplained"


def _composable(primary: str) -> tuple:
    """The effects that can ride on top of ``primary``."""
    if primary == "strand_slip":
        return tuple(SECONDARY)
    if primary in ("baseline",) + CHAIN:
        return tuple(e for e in CHAIN if e != primary)
    if primary == "base_rocking":
        return CHAIN
    return ()


def diagnose(damper: Damper, bench, tests=None, *, seed: int = 0, config: DiagnoseConfig = DiagnoseConfig(),
             progress: bool = True, effects=None, prior_path=None, store=None) -> dict:
    """Locate, name, model and show the physics a damper's recordings have and the model lacks.

    Parameters
    ----------
    damper : Damper
    bench : BenchData
    tests : sequence of str, optional
        Test labels (default: all of the damper's tests).
    seed : int
        Seeds every fit, each through a stream keyed by what it is (:func:`sbcal.seeds.job_seed`): the
        same seed, the same numbers; a cable fit's are ``sbcal cable``'s.
    config : DiagnoseConfig
    progress : bool
        Progress bars on stderr (when it is a terminal).
    effects : sequence of str, optional
        Restrict the catalogue (default: all of :data:`sbcal.extensions.EXTENSIONS`).
    prior_path : path-like, optional
        The prior file of the base parameters (``--priors``; default the bundled ``priors/default.toml``).
    store : path-like, optional
        A run store: a strand-slip verdict's cable-law posteriors are written to
        ``<store>/<damper>/cable-<state>/`` (the fit ``sbcal cable`` makes).

    Returns
    -------
    dict
        JSON-ready: ``verdict``, ``ranking``, ``bands``, ``parameters``, ``before``, ``after``,
        ``secondary``, ``law``, ``global``, ``statistics``, ``screen``, ``per_test``, ``rule``,
        ``settings`` (see ``docs/diagnose.md``); and ``curves`` (for :func:`curves_frame`).
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

    # 1-2. baseline and locate
    jobs = _jobs("baseline", (), damper, bench, tests, seed, config, prior_path)
    likes = [j[1] for j in jobs]
    fits = _run_fits(jobs, config, label("per-test fits"))
    base_fits = {k[1]: v for k, v in fits.items()}
    base_keys = [("baseline", t) for t in tests]
    n_runs = {t: lk.y.shape[1] for t, lk in zip(tests, likes)}
    base_check = _check_model("baseline", fits, base_keys, tests, likes, n_runs, config)
    z0, thr0, _, base_i, glob0 = base_check
    bands = _bands(tests, likes, z0, thr0)
    misfit = bool(bands) or glob0["p_value"] < config.global_alpha
    statistics = _statistics(damper, tests, likes, base_fits, z0)
    screen = _screen(statistics, config, EXTENSIONS)
    before = _summary("baseline", fits, base_keys, base_check, None, bands, tests)

    # 3. name: refit the screened candidates
    candidates = [e for e in catalogue if screen[e]["kept"]] if misfit else []
    all_jobs = []
    for e in candidates:
        all_jobs += _jobs(e, (), damper, bench, tests, seed, config, prior_path)
    if all_jobs:
        fits.update(_run_fits(all_jobs, config, label(f"{len(candidates)} candidate extension(s)")))
    ranking, summaries, checks, kept, laws = _compare(candidates, lambda e: e, fits, base_check, bands, tests,
                                                      likes, n_runs, config)

    # 4. verdict
    verdict = _decide(misfit, ranking, config) or "none"
    shown = verdict if verdict in EXTENSIONS else (ranking[0]["effect"] if ranking else None)
    after = summaries[shown] if shown else before
    shown_fits = kept.get(shown, {})
    per_test = []
    if shown:
        z_after, _, _, after_i, _ = checks[shown]
        start = 0
        for t, zb, za in zip(tests, z0, z_after):
            n = n_runs[t]
            d, se = elpd_difference(base_i[start:start + n], after_i[start:start + n])
            start += n
            per_test.append({"test": t, "delta_elpd": d, "se": se, "rms_z_before": float(np.sqrt(np.mean(zb ** 2))),
                             "rms_z_after": float(np.sqrt(np.mean(za ** 2)))})

    # 5. secondary: locate again on the verdict's model, refit what composes with it
    secondary = None
    if config.secondary and verdict in EXTENSIONS and _composable(verdict):
        secondary = _secondary(verdict, shown_fits, checks[verdict], damper, bench, tests, likes, n_runs, config,
                               seed, prior_path, label)

    if store is not None and verdict == "strand_slip":
        _store_cables(damper, shown_fits, store, seed, laws.get("strand_slip"), tests)

    result = {
        "damper": damper.name, "tests": tests, "seed": seed, "verdict": verdict,
        "bench": {"path": str(bench.source), "rows_sha256": rows_digest(bench, damper.name)},
        "rule": (f"a misfit when a line of the baseline is off (|z| beyond the t quantile at family-wise alpha = "
                 f"{config.alpha:g} over all lines) or the residual as a whole exceeds chance (chi-square of the lines' "
                 f"normal scores, p < {config.global_alpha:g}); then the best extension if delta_elpd > "
                 f"{config.clear_se:g} se and it removes >= {config.min_explained:.0%} of the misfit (squared z in the "
                 f"bands; without bands, the global excess over chance); else unexplained; no misfit: none. The same "
                 "rule names a secondary effect on the verdict's model."),
        "ranking": ranking,
        "bands": [{k: b[k] for k in ("test", "quantity", "f_lo", "f_hi", "max_abs_z")} for b in bands],
        "global": glob0,
        "parameters": _parameters(shown, shown_fits, sorted(shown_fits), base_fits[tests[0]]["names"]) if shown else {},
        "law": laws.get("strand_slip"),
        "before": before,
        "after": after,
        "secondary": secondary,
        "per_test": per_test,
        "residuals": {t: {"freq_hz": lk.freq_hz.tolist(), "z_before": zb.tolist(),
                          "z_after": (checks[shown][0][i] if shown else zb).tolist()}
                      for i, (t, lk, zb) in enumerate(zip(tests, likes, z0))},
        "curves": _curves(tests, likes, fits, base_keys, shown, shown_fits),
        "statistics": statistics,
        "screen": screen,
        "settings": asdict(config),
        "versions": versions(),
        "wall_s": time.perf_counter() - t0,
    }
    return result


def _secondary(primary, primary_fits, primary_check, damper, bench, tests, likes, n_runs, config, seed, prior_path,
               label) -> dict | None:
    """The second effect on top of the verdict's model (module docstring, step 5), or None."""
    z1, thr1, _, _, glob1 = primary_check
    bands1 = _bands(tests, likes, z1, thr1)
    misfit = bool(bands1) or glob1["p_value"] < config.global_alpha
    joint = primary == "strand_slip"
    mean, var, _ = _model_curves(primary_fits, sorted(primary_fits), tests, joint)
    sig = _signatures(tests, likes, [mean[t] for t in tests], [var[t] for t in tests], z1)
    options = _composable(primary)
    screen = _screen(sig, config, options)
    if joint and "base_rocking" in options:
        # no shape of its own to test the residuals for: the share its linearisation explains
        share, value = _rocking_signature(primary_fits, tests, likes, mean, var)
        sig["rocking_linear"] = {"share": share, "rocking_rad_per_m": value}
        screen["base_rocking"] = {"kept": share >= config.screen_share,
                                  "why": f"share of the misfit explained by the linearised rocking {share:.2f}"}
    candidates = [e for e in options if screen[e]["kept"]] if misfit else []
    out = {"effect": None, "misfit": misfit, "bands": len(bands1), "global": glob1, "screen": screen,
           "statistics": sig, "ranking": []}
    if not candidates:
        return out
    if joint:  # on top of the verdict's cable law only
        config = replace(config, laws=(next(iter(primary_fits.values()))["law"],))
    jobs = []
    for e in candidates:
        jobs += _jobs(primary, (e,), damper, bench, tests, seed, config, prior_path)
    fits = _run_fits(jobs, config, label(f"secondary: {len(candidates)} candidate(s)"))
    fits.update({k: v for k, v in primary_fits.items()})
    ranking, summaries, checks, kept, _ = _compare(candidates, lambda e: _name(primary, (e,)), fits, primary_check,
                                                   bands1, tests, likes, n_runs, config)
    choice = _decide(True, ranking, config)
    out["ranking"] = ranking
    best = ranking[0]["effect"]
    out["after"] = summaries[best]
    out["before"] = _summary(primary, primary_fits, sorted(primary_fits), primary_check, None, bands1, tests)
    if choice in options:
        out["effect"] = choice
        base_names = tuple(n for n in next(iter(primary_fits.values()))["names"])
        out["parameters"] = _parameters(choice, kept[choice], sorted(kept[choice]), base_names, tests)
        out["residuals"] = {t: {"z_before": zb.tolist(), "z_after": za.tolist()}
                            for t, zb, za in zip(tests, z1, checks[choice][0])}
    return out


def _curves(tests, likes, fits, base_keys, shown, shown_fits) -> dict:
    """Posterior-median model curves per test of the baseline and the shown model (log-magnitude, phase)."""
    out = {}
    _, _, base = _model_curves(fits, base_keys, tests, False)
    models = {"baseline": base}
    if shown:
        _, _, med = _model_curves(shown_fits, sorted(shown_fits), tests, shown == "strand_slip")
        models[shown] = med
    for name, med in models.items():
        out[name] = {t: {"freq_hz": lk.freq_hz.tolist(), "amplitude_mm_pp": lk.amplitude_mm_pp.tolist(),
                         "logmag": med[t][0].tolist(), "phase": med[t][1].tolist()} for t, lk in zip(tests, likes)}
    out["data"] = {t: {"logmag": lk.ybar[0].tolist(), "phase": lk.ybar[1].tolist()} for t, lk in zip(tests, likes)}
    return out


def curves_frame(doc: dict):
    """The fitted curves of a diagnosis (baseline and verdict model, posterior median per line) in the
    bench CSV columns (``run`` 0) plus ``model``: a DataFrame for ``sbcal diagnose --curves``."""
    import pandas as pd

    from .bench import curves_to_frame

    frames = []
    for model, per_test in doc["curves"].items():
        if model == "data":
            continue
        for t, c in per_test.items():
            fuu = np.exp(np.asarray(c["logmag"]) + 1j * np.asarray(c["phase"]))
            frame = curves_to_frame(doc["damper"], t, c["freq_hz"], np.asarray(c["amplitude_mm_pp"]), fuu[None, :],
                                    runs=[0])
            frame["model"] = model
            frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _store_cables(damper, fits, store, seed, comparison, tests) -> None:
    """Write the verdict's cable-law posteriors as ``<store>/<damper>/cable-<state>/``."""
    from pathlib import Path

    groups = state_tests(tests)
    for (name, state), f in sorted(fits.items()):
        fit = CableFit(damper=damper.name, state=state, law=f["law"], tests=tuple(groups[state]), effects=(),
                       result=f["result"], like=f["like"], loo=loo(f["log_lik"]))
        store_cable(fit, Path(store) / damper.name / f"cable-{state}",
                    meta={"seed": seed, "made_by": "sbcal diagnose", "damper_values": asdict(damper)},
                    comparison=comparison)

