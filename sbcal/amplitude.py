"""The amplitude map: EJ (and beta) versus test amplitude, with propagated uncertainty.

Two laws for the flexural rigidity, A the base amplitude [mm p-p]:

    power law:   EJ(A) = k (A / 1 mm)^(-n)
    saturating:  EJ(A) = EJ_inf + c (A / 1 mm)^(-n)

Errors in variables: each test i enters through its posterior of ``log EJ``, summarised by its
mean ``m_i`` and standard deviation ``s_i`` (the posterior is close to normal in log EJ, where its
prior is flat), and the tests scatter around the law with a learned scale ``tau``::

    m_i ~ N(log EJ(A_i), s_i^2 + tau^2)

so a test known poorly counts less, and the law's intervals widen when the per-test posteriors
widen. (k, n, tau), resp. (EJ_inf, c, n, tau), are sampled with emcee. The forms are compared by
PSIS-LOO over tests; the saturating form is preferred only when its ELPD exceeds the power law's by
more than the standard error of the difference (the simpler law wins ties). The loss factor's trend
is fitted with the power law ``beta(A) = k A^(-n)`` (n may be negative: damping grows with A).
"""

from __future__ import annotations

from dataclasses import dataclass

import emcee
import numpy as np
import pandas as pd

from .errors import InputError
from .runs import loo_pointwise, posterior_draws

__all__ = ["TestPoint", "LawFit", "fit_law", "amplitude_map", "map_dampers", "plot_map", "points_from_table",
           "points_from_runs", "joint_powerlaw", "joint_from_runs"]

LEVEL = 0.90  # interval level of every reported interval


@dataclass(frozen=True)
class TestPoint:
    """One test's posterior summary of a positive parameter in log space.

    Attributes: damper, test, amplitude (mm p-p), mean and sd of the log of the parameter,
    the median and 90 % interval in natural units (for tables and plots).
    """

    __test__ = False  # a bench test's point, not a pytest class

    damper: str
    test: str
    amplitude: float
    mean_log: float
    sd_log: float
    median: float
    lo: float
    hi: float


def _interval(v) -> list:
    q = np.quantile(v, [0.5, (1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return [float(q[0]), float(q[1]), float(q[2])]


def _powerlaw(a, th):
    # th: (n, 3) = log k, n, log tau
    return th[:, :1] - th[:, 1:2] * np.log(a)


def _saturating(a, th):
    # th: (n, 4) = log EJ_inf, log c, n, log tau
    return np.log(np.exp(th[:, :1]) + np.exp(th[:, 1:2]) * a ** (-th[:, 2:3]))


class _LawPosterior:
    """log-posterior of a law's parameters given test points (picklable, vectorised)."""

    def __init__(self, law, a, m, s, lower, upper):
        self.law, self.a, self.m, self.s = law, a, m, s
        self.lower, self.upper = lower, upper

    def pointwise(self, th):
        mu = (_powerlaw if self.law == "powerlaw" else _saturating)(self.a, th)
        var = self.s**2 + np.exp(th[:, -1:]) ** 2
        return -0.5 * ((self.m - mu) ** 2 / var + np.log(2 * np.pi * var))

    def __call__(self, th):
        th = np.atleast_2d(th)
        out = np.full(len(th), -np.inf)
        ok = np.all((th > self.lower) & (th < self.upper), axis=1)
        if ok.any():
            out[ok] = self.pointwise(th[ok]).sum(axis=1)
        return out


@dataclass(frozen=True)
class LawFit:
    """Posterior draws of one law.

    Attributes
    ----------
    law : str
        ``"powerlaw"`` or ``"saturating"``.
    draws : dict of str -> ndarray, shape (n_draws,)
        Natural-unit draws: k, n, tau (power law) or EJ_inf, c, n, tau (saturating).
    elpd_loo, elpd_se : float
        PSIS-LOO over tests.
    pointwise : ndarray, shape (n_draws, n_tests)
    """

    law: str
    draws: dict
    elpd_loo: float
    elpd_se: float
    pointwise: np.ndarray

    def curve(self, a) -> np.ndarray:
        """Draws of the law at amplitudes ``a``: shape (n_draws, len(a))."""
        a = np.asarray(a, float)[None, :]
        d = self.draws
        if self.law == "powerlaw":
            return d["k"][:, None] * a ** (-d["n"][:, None])
        return d["EJ_inf"][:, None] + d["c"][:, None] * a ** (-d["n"][:, None])

    def summary(self) -> dict:
        return {name: _interval(v) for name, v in self.draws.items()}


def fit_law(points, law: str, *, seed: int, ceiling: float | None = None, nwalkers: int = 32,
            steps: int = 3000) -> LawFit:
    """Fit one law to test points by errors in variables (module docstring).

    Parameters
    ----------
    points : sequence of TestPoint
        At least 3, at distinct amplitudes.
    law : {"powerlaw", "saturating"}
    seed : int
    ceiling : float, optional
        Upper bound of EJ_inf (the damper's EJ_static); default 10x the largest median.
    """
    if len(points) < 3 or len({p.amplitude for p in points}) < 3:
        raise InputError(f"the {law} fit needs tests at 3 or more amplitudes, got {len(points)}")
    a = np.array([p.amplitude for p in points])[None, :]
    m = np.array([p.mean_log for p in points])[None, :]
    s = np.array([p.sd_log for p in points])[None, :]
    top = np.log(ceiling if ceiling else 10 * np.exp(m.max()))
    # flat priors on log k, n in [-3, 3], log tau in [log 1e-4, log 2]; EJ_inf below the ceiling
    if law == "powerlaw":
        lower = np.array([m.min() - 10, -3.0, np.log(1e-4)])
        upper = np.array([m.max() + 10, 3.0, np.log(2.0)])
        slope, icpt = np.polyfit(np.log(a[0]), m[0], 1)
        start = np.array([icpt, -slope, np.log(max(np.std(m) * 0.1, 1e-3))])
    elif law == "saturating":
        lower = np.array([m.min() - 10, m.min() - 10, 0.0, np.log(1e-4)])
        upper = np.array([top, m.max() + 10, 3.0, np.log(2.0)])
        start = np.array([m.min() - 0.7, m.min() - 0.7, 0.7, np.log(max(np.std(m) * 0.1, 1e-3))])
    else:
        raise InputError(f"unknown law {law!r}")
    post = _LawPosterior(law, a, m, s, lower, upper)
    rng = np.random.default_rng(seed)
    start = np.clip(start, lower + 1e-3, upper - 1e-3)
    p0 = start + 1e-3 * rng.standard_normal((nwalkers, len(start)))
    sampler = emcee.EnsembleSampler(nwalkers, len(start), post, vectorize=True)
    state = emcee.State(p0, random_state=np.random.RandomState(rng.integers(2**32)).get_state())
    sampler.run_mcmc(state, steps, progress=False)
    chain = sampler.get_chain(discard=steps // 3, thin=5, flat=True)
    pw = post.pointwise(chain)
    loo_i = loo_pointwise(pw)
    elpd, se = float(loo_i.sum()), float(np.sqrt(len(loo_i) * np.var(loo_i)))
    if law == "powerlaw":
        draws = {"k": np.exp(chain[:, 0]), "n": chain[:, 1], "tau": np.exp(chain[:, 2])}
    else:
        draws = {"EJ_inf": np.exp(chain[:, 0]), "c": np.exp(chain[:, 1]), "n": chain[:, 2], "tau": np.exp(chain[:, 3])}
    return LawFit(law=law, draws=draws, elpd_loo=elpd, elpd_se=se, pointwise=pw)


def points_from_table(path) -> list:
    """Test points from a plain table: columns ``amplitude_mm_pp``, ``ej_nm2``, optional ``ej_sd``.

    Without ``ej_sd`` the values are taken as exact (the scatter ``tau`` absorbs any misfit).
    """
    try:
        t = pd.read_csv(path)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable CSV table ({str(e).splitlines()[0]})") from None
    for col in ("amplitude_mm_pp", "ej_nm2"):
        if col not in t.columns:
            raise InputError(f"{path}: column '{col}': missing")
    points = []
    for i, row in t.iterrows():
        line = i + 2
        vals = {}
        for col in ("amplitude_mm_pp", "ej_nm2") + (("ej_sd",) if "ej_sd" in t.columns else ()):
            v = pd.to_numeric(pd.Series([row[col]]), errors="coerce").iloc[0]
            if not np.isfinite(v) or (v <= 0 and col != "ej_sd") or v < 0:
                raise InputError(f"{path}: line {line}, column '{col}': expected a positive finite number, got {row[col]!r}")
            vals[col] = float(v)
        ej = vals["ej_nm2"]
        sd = vals.get("ej_sd", 0.0)
        sd_log = max(sd / ej, 1e-9)  # delta method: sd of log EJ
        points.append(TestPoint("table", f"line {line}", vals["amplitude_mm_pp"], float(np.log(ej)), sd_log,
                                ej, ej * np.exp(-1.645 * sd_log), ej * np.exp(1.645 * sd_log)))
    return points


def _points(records, damper: str, parameter: str, include=lambda test: True, mixed: bool = False) -> list:
    """Test points from ``posterior_draws`` records (see :func:`points_from_runs`)."""
    out = []
    for test, amplitude, draws in records:
        if parameter not in draws or (amplitude is None and not mixed) or not include(test):
            continue
        v = np.log(draws[parameter])
        q = np.quantile(draws[parameter], [0.5, (1 - LEVEL) / 2, (1 + LEVEL) / 2])
        out.append(TestPoint(damper, test, amplitude, float(v.mean()), float(v.std(ddof=1)), *map(float, q)))
    return out


def points_from_runs(runs_dir, damper: str, parameter: str = "EJ", paramset: str = "theta1",
                     include=lambda test: True, mixed: bool = False) -> list:
    """Test points of one damper from stored runs: tests with one constant amplitude only, unless
    ``mixed`` (then mixed-amplitude tests come with ``amplitude = None``)."""
    return _points(posterior_draws(runs_dir, damper, paramset, (parameter,)), damper, parameter, include, mixed)


def amplitude_map(ej_points, beta_points=(), *, seed: int = 0, ej_static: float | None = None):
    """Fit both laws to EJ and the power law to beta.

    Returns ``(doc, fits)``: ``doc`` is the ``sbcal map --json`` document, ``fits`` the two
    :class:`LawFit` of EJ (for plots).

    Returns ``{"powerlaw": {"k": [median, lo, hi], "n": [...], "tau": [...], "elpd_loo", "elpd_se"},
    "saturating": {"EJ_inf", "c", "n", "tau", "reduction_factor", "elpd_loo", "elpd_se"},
    "preferred": "powerlaw|saturating", "criterion": str, "beta": {...}, "tests": [...]}`` with
    every interval a 90 % one.
    """
    pl = fit_law(ej_points, "powerlaw", seed=seed)
    sat = fit_law(ej_points, "saturating", seed=seed + 1, ceiling=ej_static)
    d_i = loo_pointwise(sat.pointwise) - loo_pointwise(pl.pointwise)
    diff, se = float(d_i.sum()), float(np.sqrt(len(d_i) * np.var(d_i)))
    preferred = "saturating" if diff > se else "powerlaw"
    doc = {
        "powerlaw": {**pl.summary(), "elpd_loo": pl.elpd_loo, "elpd_se": pl.elpd_se},
        "saturating": {**sat.summary(), "elpd_loo": sat.elpd_loo, "elpd_se": sat.elpd_se},
        "preferred": preferred,
        "criterion": (f"PSIS-LOO over tests: elpd(saturating) - elpd(powerlaw) = {diff:.2f} +- {se:.2f}; "
                      "the saturating law is preferred only when the difference exceeds its standard error"),
        "tests": [{"damper": p.damper, "test": p.test, "amplitude_mm_pp": p.amplitude,
                   "ej_nm2": [p.median, p.lo, p.hi]} for p in ej_points],
    }
    if ej_static:
        doc["saturating"]["reduction_factor"] = _interval(ej_static / sat.draws["EJ_inf"])
    if len(beta_points) >= 3:
        bl = fit_law(beta_points, "powerlaw", seed=seed + 2)
        doc["beta"] = {"powerlaw": {**bl.summary(), "elpd_loo": bl.elpd_loo, "elpd_se": bl.elpd_se},
                       "tests": [{"damper": p.damper, "test": p.test, "amplitude_mm_pp": p.amplitude,
                                  "beta": [p.median, p.lo, p.hi]} for p in beta_points]}
    else:
        doc["beta"] = {}
    return doc, {"powerlaw": pl, "saturating": sat}


def map_dampers(runs_dir, paramset: str = "theta1", *, seed: int = 0, include_oiled: bool = False,
                ej_static=lambda name: None) -> dict:
    """:func:`amplitude_map` for every damper in a run store with tests at 3+ amplitudes.

    Mixed-amplitude tests (``2-1``) never enter the fit (they have no single amplitude); oiled
    tests are kept out unless ``include_oiled``. Both are still listed under ``"excluded"``.
    """
    from pathlib import Path

    root = Path(runs_dir)
    docs = {}
    for d in sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []:
        keep = (lambda t: True) if include_oiled else (lambda t: "oiled" not in t)
        records = list(posterior_draws(root, d, paramset, ("EJ", "beta")))  # every run read once
        ej = _points(records, d, "EJ", keep)
        if len({p.amplitude for p in ej}) < 3:
            continue
        beta = _points(records, d, "beta", keep)
        doc, fits = amplitude_map(ej, beta, seed=seed, ej_static=ej_static(d))
        every = _points(records, d, "EJ", mixed=True)
        used = {p.test for p in ej}
        doc["excluded"] = [{"test": p.test, "amplitude_mm_pp": p.amplitude, "ej_nm2": [p.median, p.lo, p.hi]}
                           for p in every if p.test not in used]
        doc["_fits"] = fits
        docs[d] = doc
    return docs


def plot_map(docs: dict, path) -> None:
    """EJ and beta versus amplitude for every damper, with the power law's 90 % band; a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ._io import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    grid = np.geomspace(0.08, 2.5, 100)
    for (name, doc), color in zip(docs.items(), ("C0", "C1", "C2", "C3")):
        fit = doc.get("_fits", {}).get("powerlaw")
        if fit is not None:
            lo, mid, hi = np.quantile(fit.curve(grid), [0.05, 0.5, 0.95], axis=0)
            axes[0].fill_between(grid, lo, hi, color=color, alpha=0.2)
            axes[0].plot(grid, mid, color=color, lw=1, label=f"{name}: k A^-n, 90 % band")
        t = doc["tests"]
        a = np.array([x["amplitude_mm_pp"] for x in t])
        v = np.array([x["ej_nm2"] for x in t])
        axes[0].errorbar(a, v[:, 0], yerr=[v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]], fmt="o", color=color, ms=4,
                         label=f"{name}: per-test posterior (median, 90 %)")
        for x in doc.get("excluded", []):
            if x["amplitude_mm_pp"] is not None:
                axes[0].plot(x["amplitude_mm_pp"], x["ej_nm2"][0], "x", color=color, ms=6)
        bt = doc.get("beta", {}).get("tests", [])
        if bt:
            a = np.array([x["amplitude_mm_pp"] for x in bt])
            v = np.array([x["beta"] for x in bt])
            axes[1].errorbar(a, v[:, 0], yerr=[v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]], fmt="o-", color=color, ms=4,
                             label=name)
    axes[0].set(xscale="log", yscale="log", xlabel="base amplitude A [mm p-p]", ylabel="EJ [N m$^2$]",
                title="Flexural rigidity (x: excluded tests)")
    axes[1].set(xscale="log", xlabel="base amplitude A [mm p-p]", ylabel="loss factor beta [-]", title="Loss factor")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


class _JointPosterior:
    """All constant-amplitude tests of a damper at once: ``EJ_i = k A_i^-n``, shared a1, a2, and a
    loss factor and model-error scales per test. Sampled coordinates: log k, n, a1, a2, then per
    test beta, log sigma_mag, log sigma_phase. Picklable; ``__call__`` is emcee's vectorised log_prob."""

    def __init__(self, likes, amplitudes, prior):
        self.likes, self.amplitudes, self.prior = likes, np.asarray(amplitudes, float), prior

    def log_likelihood(self, th):
        k, n, a1, a2 = np.exp(th[:, 0]), th[:, 1], th[:, 2], th[:, 3]
        total = np.zeros(len(th))
        for i, (like, amp) in enumerate(zip(self.likes, self.amplitudes)):
            j = 4 + 3 * i
            x = np.column_stack([th[:, j], a1, a2, k * amp ** (-n), np.exp(th[:, j + 1]), np.exp(th[:, j + 2])])
            total += like.log_likelihood(x)
        return total

    def __call__(self, th):
        th = np.atleast_2d(th)
        out = self.prior.log_prob(th)
        ok = np.isfinite(out)
        if ok.any():
            lp = self.log_likelihood(th[ok])
            out[ok] = np.where(np.isfinite(lp), lp, -np.inf)
        return out


def joint_powerlaw(damper, bench, tests, *, seed: int, start=None, config=None, progress=None) -> dict:
    """One emcee run over all given tests of a damper with EJ on the power law (k, n sampled).

    Parameters
    ----------
    damper : Damper
    bench : BenchData
    tests : sequence of str
        Constant-amplitude tests (3 or more amplitudes).
    seed : int
    start : dict, optional
        Starting values: ``k``, ``n`` and per test ``beta``, ``sigma_mag``, ``sigma_phase``
        (e.g. from the two-stage fit); default a least-squares start.
    config : SamplerConfig, optional
        Default: 2 ensembles of 64 walkers, 50 autocorrelation times, at most 20000 steps.

    Returns
    -------
    dict with ``k``, ``n`` ([median, lo, hi], 90 %), ``beta`` per test, ``a1``, ``a2``, ``r_hat``
    (max over parameters), ``converged``, ``n_steps``, ``wall_s``.
    """
    import time
    from concurrent.futures import ProcessPoolExecutor
    from dataclasses import replace

    from scipy.optimize import minimize

    from .calibrate import test_likelihood
    from .priors import Prior
    from .runs import rhat_ess
    from .sampler import SamplerConfig, _run_ensemble

    t0 = time.perf_counter()
    config = config or SamplerConfig(nwalkers=64, n_ensembles=2, max_steps=20000, max_draws=2000)
    likes, amps = [], []
    for t in tests:
        like, cleaned = test_likelihood(damper, bench, t)
        amp = np.unique(cleaned.data.amplitude_mm_pp)
        if amp.size != 1:
            raise InputError(f"test {t!r} has no single amplitude: keep it out of the joint fit")
        likes.append(like)
        amps.append(float(amp[0]))
    if len(set(amps)) < 3:
        raise InputError(f"the joint fit needs tests at 3 or more amplitudes, got {sorted(set(amps))}")
    p1 = likes[0].prior
    ia1, ia2, ib = (p1.names.index(n) for n in ("a1", "a2", "beta"))
    ej_lo, ej_hi = p1.lower[p1.names.index("EJ")], p1.upper[p1.names.index("EJ")]
    names = ["log_k", "n", "a1", "a2"] + [f"{v}_{t}" for t in tests for v in ("beta", "log_sigma_mag", "log_sigma_phase")]
    lower = [np.log(ej_lo), -1.0, p1.lower[ia1], p1.lower[ia2]] + [p1.lower[ib], np.log(1e-4), np.log(1e-4)] * len(tests)
    upper = [np.log(ej_hi), 3.0, p1.upper[ia1], p1.upper[ia2]] + [p1.upper[ib], 0.0, 0.0] * len(tests)
    prior = Prior(paramset="joint_powerlaw", names=tuple(names), log_scale=np.zeros(len(names), bool),
                  lower=np.array(lower), upper=np.array(upper))
    post = _JointPosterior(likes, amps, prior)
    s = start or {}
    z0 = np.array([np.log(s.get("k", 10.0)), s.get("n", 0.4), damper.a1, damper.a2]
                  + [v for t in tests for v in (s.get("beta", {}).get(t, 0.3), np.log(s.get("sigma_mag", {}).get(t, 0.1)),
                                                 np.log(s.get("sigma_phase", {}).get(t, 0.1)))])
    width = prior.z_upper - prior.z_lower
    z0 = np.clip(z0, prior.z_lower + 1e-6 * width, prior.z_upper - 1e-6 * width)
    res = minimize(lambda z: -post(z)[0], z0, method="L-BFGS-B", bounds=list(zip(prior.z_lower, prior.z_upper)),
                   options={"maxiter": 2000})
    if np.isfinite(res.fun):
        z0 = res.x
    nwalkers = max(config.nwalkers, 2 * prior.ndim + 2)
    seqs = np.random.SeedSequence(seed).spawn(config.n_ensembles)
    jobs = [(post, z0, ss, nwalkers + nwalkers % 2, replace(config, workers=1), progress, e) for e, ss in enumerate(seqs)]
    if config.workers > 1:
        with ProcessPoolExecutor(max_workers=min(config.workers, len(jobs))) as pool:
            runs = list(pool.map(_run_ensemble, jobs))
    else:
        runs = [_run_ensemble(j) for j in jobs]
    n_draws = min(len(r[0]) for r in runs)
    x = np.stack([r[0][:n_draws] for r in runs])  # (chains, draws, ndim)
    diag = rhat_ess(x, names)
    flat = x.reshape(-1, x.shape[-1])
    out = {
        "k": _interval(np.exp(flat[:, 0])), "n": _interval(flat[:, 1]),
        "a1": _interval(flat[:, 2]), "a2": _interval(flat[:, 3]),
        "beta": {t: _interval(flat[:, 4 + 3 * i]) for i, t in enumerate(tests)},
        "tests": list(tests), "amplitudes_mm_pp": amps,
        "r_hat": max(d["r_hat"] for d in diag.values()),
        "ess_bulk_k_n": min(diag["log_k"]["ess_bulk"], diag["n"]["ess_bulk"]),
        "converged": all(r[7] for r in runs) and max(d["r_hat"] for d in diag.values()) <= 1.01,
        "n_steps": [int(r[4]) for r in runs], "wall_s": time.perf_counter() - t0, "seed": seed,
    }
    return out


def joint_from_runs(damper, bench, runs_dir, two_stage: dict, paramset: str = "theta1", *, seed: int = 0,
                    progress=None) -> dict:
    """:func:`joint_powerlaw` over the tests of a two-stage map (``two_stage`` = its document),
    started from its fit and the stored per-test posteriors; adds a comparison with the two-stage k, n."""
    from .runs import read_summary, run_dir

    tests = [t["test"] for t in two_stage["tests"]]
    start = {"k": two_stage["powerlaw"]["k"][0], "n": two_stage["powerlaw"]["n"][0],
             "beta": {}, "sigma_mag": {}, "sigma_phase": {}}
    for t in tests:
        s = read_summary(run_dir(runs_dir, damper.name, t, paramset))
        if s:
            for key in ("beta", "sigma_mag", "sigma_phase"):
                if key in s["parameters"]:
                    start[key][t] = s["parameters"][key]["median"]
    joint = joint_powerlaw(damper, bench, tests, seed=seed, start=start, progress=progress)
    two = two_stage["powerlaw"]
    overlap = all(joint[p][1] <= two[p][2] and two[p][1] <= joint[p][2] for p in ("k", "n"))
    joint["comparison"] = (
        f"two-stage k {two['k'][0]:.3g} [{two['k'][1]:.3g}, {two['k'][2]:.3g}], n {two['n'][0]:.3f} "
        f"[{two['n'][1]:.3f}, {two['n'][2]:.3f}]; the 90 % intervals {'overlap' if overlap else 'do not overlap'}; "
        f"width of n's interval, two-stage / joint: {(two['n'][2] - two['n'][1]) / max(joint['n'][2] - joint['n'][1], 1e-12):.1f} "
        "(the joint model shares a1, a2 across tests and takes the law as exact: no scatter of tests about it)")
    return joint
