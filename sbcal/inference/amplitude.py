"""The amplitude map: EJ (and beta) versus test amplitude, with propagated uncertainty.

Two laws for the flexural rigidity, A the base amplitude [mm p-p]:

    power law:   EJ(A) = k (A / 1 mm)^(-n)
    saturating:  EJ(A) = EJ_inf + c (A / 1 mm)^(-n)

Errors in variables: each test i enters through its posterior of ``log EJ``, summarised by its
mean ``m_i`` and standard deviation ``s_i`` (the posterior is close to normal in log EJ, where its
prior is flat), and the tests scatter around the law with a learned scale ``scatter``::

    m_i ~ N(log EJ(A_i), s_i^2 + scatter^2)

so a test known poorly counts less, and the law's intervals widen when the per-test posteriors
widen. (k, n, scatter), resp. (EJ_inf, c, n, scatter), are sampled by the engine
(:func:`sbcal.inference.sampler.sample`). The forms are compared by PSIS-LOO over tests
(:func:`sbcal.inference.stats.elpd_difference`); the saturating form, which contains the power law, is preferred
only when its ELPD exceeds the power law's by more than 4 and by more than twice the standard error of
the difference (:data:`PREFER_MIN_NATS`, :data:`PREFER_MIN_SE`; the simpler law wins ties). The loss
factor's trend is fitted with the power law ``beta(A) = k A^(-n)`` (n may be negative: damping grows
with A). A per-test posterior that did not converge still enters, and the map says so
(``inputs_not_converged``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..core.plotting import pyplot, save_png
from ..core.seeds import job_seed
from .priors import Prior
from .runs import posterior_draws
from .sampler import SamplerConfig, sample
from .stats import elpd_difference, loo
from .store import SUMMARY, damper_dir, dampers, map_path, run_dirs


__all__ = ["TestPoint", "LawFit", "fit_law", "amplitude_map", "map_from_store", "stored_maps", "law_curve", "plot_map",
           "points_from_table", "points_from_runs", "joint_powerlaw", "joint_from_runs"]

# The saturating law contains the power law (EJ_inf -> 0), so on power-law data its ELPD difference is
# near zero and its sign is Monte Carlo noise: a 1-SE rule chose it on 1 of 6 exact power laws (seed 6
# of tests/test_amplitude.py, 0.52 +- 0.44 nats) and flipped under other library versions. Below 4
# nats two models predict alike and the SE of the difference is itself unreliable (Sivula, Magnusson,
# Matamoros and Vehtari 2022, "Uncertainty in Bayesian leave-one-out cross-validation based model
# comparison"); data that saturate give 12-17 nats at 3-7 SE.
PREFER_MIN_NATS = 4.0
PREFER_MIN_SE = 2.0

LEVEL = 0.90  # interval level of every reported interval


@dataclass(frozen=True)
class TestPoint:
    """One test's posterior summary of a positive parameter in log space.

    Attributes: damper, test, amplitude (mm p-p), mean and sd of the log of the parameter,
    the median and 90 % interval in natural units (for tables and plots), and whether the test's
    posterior converged.
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
    converged: bool = True


def _interval(v) -> list:
    q = np.quantile(v, [0.5, (1 - LEVEL) / 2, (1 + LEVEL) / 2])
    return [float(q[0]), float(q[1]), float(q[2])]


_LAW_NAMES = {"powerlaw": ("k", "n", "scatter"), "saturating": ("EJ_inf", "c", "n", "scatter")}


def _law_mean(law, a, p):
    """log of the law at amplitudes ``a`` (1, n_tests) for parameter sets ``p`` (by name): (n, n_tests)."""
    col = {k: np.asarray(v, float)[:, None] for k, v in p.items()}
    if law == "powerlaw":
        return np.log(col["k"]) - col["n"] * np.log(a)
    return np.log(col["EJ_inf"] + col["c"] * a ** (-col["n"]))


class _Target:
    """The engine's target (picklable, vectorised): the log prior plus ``log_likelihood`` of the parameters
    by name; -inf outside the prior's support and where the likelihood is not finite. A subclass sets
    ``prior`` and defines ``log_likelihood(params) -> (n,)``."""

    def __call__(self, z):
        return self.prior.log_posterior(z, self.log_likelihood)


class _LawTarget(_Target):
    """Log-posterior of a law's parameters given test points."""

    def __init__(self, law, a, m, s, prior):
        self.law, self.a, self.m, self.s, self.prior = law, a, m, s, prior

    def pointwise_log_likelihood(self, params):
        mu = _law_mean(self.law, self.a, params)
        var = self.s**2 + np.asarray(params["scatter"], float)[:, None] ** 2
        return -0.5 * ((self.m - mu) ** 2 / var + np.log(2 * np.pi * var))

    def log_likelihood(self, params):
        return self.pointwise_log_likelihood(params).sum(axis=1)


@dataclass(frozen=True)
class LawFit:
    """Posterior of one law.

    Attributes
    ----------
    law : str
        ``"powerlaw"`` or ``"saturating"``.
    draws : dict of str -> ndarray, shape (n_draws,)
        Natural-unit draws: k, n, scatter (power law) or EJ_inf, c, n, scatter (saturating).
    loo : sbcal.inference.stats.Loo
        PSIS-LOO over tests.
    result : sbcal.inference.sampler.SampleResult
        The engine's result (convergence, chains).
    """

    law: str
    draws: dict
    loo: object
    result: object

    def curve(self, a) -> np.ndarray:
        """Draws of the law at amplitudes ``a``: shape (n_draws, len(a))."""
        return np.exp(_law_mean(self.law, np.asarray(a, float)[None, :], self.draws))

    def summary(self) -> dict:
        out = {name: _interval(v) for name, v in self.draws.items()}
        out.update(elpd_loo=self.loo.elpd, elpd_se=self.loo.se, convergence=self.result.convergence_dict())
        return out


def fit_law(points, law: str, *, seed, ceiling: float | None = None,
            config: SamplerConfig = SamplerConfig()) -> LawFit:
    """Fit one law to test points by errors in variables (module docstring).

    Parameters
    ----------
    points : sequence of TestPoint
        At least 3, at distinct amplitudes.
    law : {"powerlaw", "saturating"}
    seed : int or numpy.random.SeedSequence
    ceiling : float, optional
        Upper bound of EJ_inf (the damper's EJ_static); default 10x the largest median.
    config : SamplerConfig
    """
    if law not in _LAW_NAMES:
        raise InputError(f"unknown law {law!r}")
    if len(points) < 3 or len({p.amplitude for p in points}) < 3:
        raise InputError(f"the {law} fit needs tests at 3 or more amplitudes, got {len(points)}")
    a = np.array([p.amplitude for p in points])[None, :]
    m = np.array([p.mean_log for p in points])[None, :]
    s = np.array([p.sd_log for p in points])[None, :]
    lo, hi = np.exp(m.min() - 10), np.exp(m.max() + 10)
    top = ceiling if ceiling else 10 * np.exp(m.max())
    # flat priors on log k (log EJ_inf, log c), on n, and on log scatter in [1e-4, 2]
    boxes = {"n": (False, -3.0, 3.0), "scatter": (True, 1e-4, 2.0)}
    if law == "powerlaw":
        boxes["k"] = (True, lo, hi)
    else:
        boxes.update(EJ_inf=(True, lo, top), c=(True, lo, hi), n=(False, 0.0, 3.0))
    prior = Prior.from_boxes(law, boxes)
    res = sample(_LawTarget(law, a, m, s, prior), seed=seed, config=config)
    return LawFit(law=law, draws=res.flat(), loo=loo(res.log_likelihood), result=res)


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
    for r in records:
        if parameter not in r.draws or (r.amplitude is None and not mixed) or not include(r.test):
            continue
        v = np.log(r.draws[parameter])
        q = np.quantile(r.draws[parameter], [0.5, (1 - LEVEL) / 2, (1 + LEVEL) / 2])
        out.append(TestPoint(damper, r.test, r.amplitude, float(v.mean()), float(v.std(ddof=1)), *map(float, q),
                             converged=bool(r.summary.get("converged", False))))
    return out


def points_from_runs(runs_dir, damper: str, parameter: str = "EJ", paramset: str = "theta1",
                     include=lambda test: True, mixed: bool = False) -> list:
    """Test points of one damper from stored runs: tests with one constant amplitude only, unless
    ``mixed`` (then mixed-amplitude tests come with ``amplitude = None``)."""
    return _points(posterior_draws(runs_dir, damper, paramset, (parameter,)), damper, parameter, include, mixed)


def amplitude_map(ej_points, beta_points=(), *, seed=0, ej_static: float | None = None,
                  config: SamplerConfig = SamplerConfig()):
    """Fit both laws to EJ and the power law to beta (each fit's stream keyed by its name under ``seed``:
    an int, or a damper's map stream from :func:`map_from_store`).

    Returns ``(doc, fits)``: ``doc`` is the ``sbcal map --json`` document, ``fits`` the two (by law)
    :class:`LawFit` of EJ (for plots).

    Returns ``{"powerlaw": {"k": [median, lo, hi], "n": [...], "scatter": [...], "elpd_loo", "elpd_se",
    "convergence"}, "saturating": {"EJ_inf", "c", "n", "scatter", "reduction_factor", ...},
    "preferred": "powerlaw|saturating", "criterion": str, "beta": {...}, "tests": [...], "converged"}``
    with every interval a 90 % one; ``converged`` is false when any of the fits is not.
    """
    pl = fit_law(ej_points, "powerlaw", seed=job_seed(seed, "EJ", "powerlaw"), config=config)
    sat = fit_law(ej_points, "saturating", seed=job_seed(seed, "EJ", "saturating"), ceiling=ej_static, config=config)
    diff, se = elpd_difference(pl.loo, sat.loo)
    preferred = "saturating" if diff > max(PREFER_MIN_NATS, PREFER_MIN_SE * se) else "powerlaw"
    doc = {
        "powerlaw": pl.summary(),
        "saturating": sat.summary(),
        "inputs_not_converged": [p.test for p in ej_points if not p.converged],
        "preferred": preferred,
        "criterion": (f"PSIS-LOO over tests: elpd(saturating) - elpd(powerlaw) = {diff:.2f} +- {se:.2f}; "
                      f"the saturating law is preferred only when the difference exceeds {PREFER_MIN_NATS:g} and "
                      f"{PREFER_MIN_SE:g} standard errors"),
        "tests": [{"damper": p.damper, "test": p.test, "amplitude_mm_pp": p.amplitude,
                   "ej_nm2": [p.median, p.lo, p.hi]} for p in ej_points],
    }
    if ej_static:
        doc["saturating"]["reduction_factor"] = _interval(ej_static / sat.draws["EJ_inf"])
    fits = [pl, sat]
    if len(beta_points) >= 3:
        bl = fit_law(beta_points, "powerlaw", seed=job_seed(seed, "beta", "powerlaw"), config=config)
        fits.append(bl)
        doc["beta"] = {"powerlaw": bl.summary(),
                       "tests": [{"damper": p.damper, "test": p.test, "amplitude_mm_pp": p.amplitude,
                                  "beta": [p.median, p.lo, p.hi]} for p in beta_points]}
    else:
        doc["beta"] = {}
    doc["converged"] = all(f.result.converged for f in fits) and not doc["inputs_not_converged"]
    return doc, {"powerlaw": pl, "saturating": sat}


def _summaries_digest(runs_dir, damper: str, paramset: str) -> dict:
    """sha256 of every finished run's summary.json of a damper: what a map is made from."""
    import hashlib

    return {t: hashlib.sha256((d / SUMMARY).read_bytes()).hexdigest() for t, d in run_dirs(runs_dir, damper, paramset)}


def map_from_store(runs_dir, damper: str, paramset: str = "theta1", *, seed: int = 0, include_oiled: bool = False,
                   reuse: bool = True, config: SamplerConfig = SamplerConfig()) -> tuple[dict | None, str]:
    """The amplitude map of one damper from its stored posteriors, stored as ``map.json`` + ``map.nc``.

    The map is redone only when the posteriors it rests on (their summaries' digests), its settings,
    the seed or the sbcal version changed. Mixed-amplitude tests (``2-1``) never enter the fit (they
    have no single amplitude); oiled tests are kept out unless ``include_oiled``; both are listed
    under ``"excluded"``. The saturating law's ceiling is the damper's ``ej_static`` as its stored
    runs describe it.

    Returns
    -------
    (doc, status)
        The ``map.json`` document (None when the damper has no tests at 3 or more amplitudes) and
        ``"reused"`` or ``"redone (...)"``.
    """
    from ..core._io import write_json
    from ..core.version import __version__
    from .runs import write_map

    root = damper_dir(runs_dir, damper)
    inputs = {"posteriors": _summaries_digest(runs_dir, damper, paramset), "paramset": paramset,
              "settings": {"include_oiled": include_oiled}, "seed": seed, "sbcal": __version__}
    path = map_path(runs_dir, damper)
    stored = json.loads(path.read_text()) if path.is_file() else None
    why = [k for k in inputs if not stored or stored.get("inputs", {}).get(k) != inputs[k]]
    if reuse and stored is not None and not why:
        return stored, "reused"
    keep = (lambda t: True) if include_oiled else (lambda t: "oiled" not in t)
    records = list(posterior_draws(runs_dir, damper, paramset, ("EJ", "beta")))  # every run read once
    ej = _points(records, damper, "EJ", keep)
    if len({p.amplitude for p in ej}) < 3:
        return None, "skipped (tests at fewer than 3 amplitudes)"
    beta = _points(records, damper, "beta", keep)
    statics = {r.summary.get("config", {}).get("damper_values", {}).get("ej_static") for r in records}
    ceiling = statics.pop() if len(statics) == 1 else None  # runs of one damper description
    doc, fits = amplitude_map(ej, beta, seed=job_seed(seed, "map", damper), ej_static=ceiling, config=config)
    every = _points(records, damper, "EJ", mixed=True)
    used = {p.test for p in ej}
    doc["excluded"] = [{"test": p.test, "amplitude_mm_pp": p.amplitude, "ej_nm2": [p.median, p.lo, p.hi]}
                       for p in every if p.test not in used]
    doc["damper"] = damper
    doc["inputs"] = inputs
    write_map(root, {law: fit.result for law, fit in fits.items()})
    write_json(path, doc, indent=1)
    reason = ", ".join("per-test posteriors changed" if k == "posteriors" else f"{k} changed" for k in why)
    return doc, f"redone ({reason or 'asked'})" if stored is not None else "redone (not stored yet)"


def stored_maps(runs_dir) -> dict:
    """``{damper: map.json document}`` of every stored map in a run store, with its law draws under
    ``"draws"`` (``{law: {parameter: ndarray}}``, from ``map.nc``) for plots."""
    from .runs import read_map

    out = {}
    for d in dampers(runs_dir):
        path = map_path(runs_dir, d)
        if path.is_file():
            doc = json.loads(path.read_text())
            doc["draws"] = read_map(damper_dir(runs_dir, d))
            out[d] = doc
    return out


def law_curve(law: str, draws: dict, a) -> np.ndarray:
    """Draws of a law at amplitudes ``a`` [mm p-p]: shape (n_draws, len(a))."""
    return np.exp(_law_mean(law, np.asarray(a, float)[None, :], draws))


def plot_map(docs: dict, path) -> None:
    """EJ and beta versus amplitude for every damper (maps as :func:`stored_maps` gives them), with the
    power law's 90 % band; a PNG. Without a loss factor anywhere (a ``--table`` of EJ only) the EJ panel alone."""
    plt = pyplot()

    with_beta = any(doc.get("beta", {}).get("tests") for doc in docs.values())
    fig, axes = plt.subplots(1, 2 if with_beta else 1, figsize=(11, 4.2) if with_beta else (6.5, 4.2), squeeze=False)
    axes = axes[0]
    grid = np.geomspace(0.08, 2.5, 100)
    for i, (name, doc) in enumerate(docs.items()):
        color = f"C{i % 10}"  # every damper of the store, however many
        draws = doc.get("draws", {}).get("powerlaw")
        if draws:
            lo, mid, hi = np.quantile(law_curve("powerlaw", draws, grid), [0.05, 0.5, 0.95], axis=0)
            axes[0].fill_between(grid, lo, hi, color=color, alpha=0.2)
            axes[0].plot(grid, mid, color=color, lw=1, label=f"{name}: k A^-n, 90 % band")
        t = doc["tests"]
        a = np.array([x["amplitude_mm_pp"] for x in t])
        v = np.array([x["ej_nm2"] for x in t])
        axes[0].errorbar(a, v[:, 0], yerr=[v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]], fmt="o", color=color, ms=4,
                         label=f"{name}: per-test EJ (median, 90 %)")
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
    if with_beta:
        axes[1].set(xscale="log", xlabel="base amplitude A [mm p-p]", ylabel="loss factor beta [-]", title="Loss factor")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


def _per_test(name: str, test: str) -> str:
    """The joint model's name of a per-test parameter, e.g. ``beta[0.5-0.5]``."""
    return f"{name}[{test}]"


_PER_TEST = ("beta", "sigma_mag", "sigma_phase")


class _JointTarget(_Target):
    """All constant-amplitude tests of a damper at once: ``EJ_i = k A_i^-n``, shared a1, a2, and a
    loss factor and model-error scales per test (``beta[<test>]`` ...): the engine's target. Each
    test's likelihood gets its parameters by name."""

    def __init__(self, likes, tests, amplitudes, prior):
        self.likes, self.tests, self.amplitudes, self.prior = likes, list(tests), np.asarray(amplitudes, float), prior

    def _test_params(self, p, i):
        t = self.tests[i]
        out = {"EJ": p["k"] * self.amplitudes[i] ** (-p["n"]), "a1": p["a1"], "a2": p["a2"]}
        out.update({q: p[_per_test(q, t)] for q in _PER_TEST})
        return out

    def log_likelihood(self, p):
        return sum(like.log_likelihood(self._test_params(p, i)) for i, like in enumerate(self.likes))

    def pointwise_log_likelihood(self, p):
        return np.concatenate([like.pointwise_log_likelihood(self._test_params(p, i))
                               for i, like in enumerate(self.likes)], axis=1)


def joint_powerlaw(damper, data, tests, *, seed: int, start=None, config: SamplerConfig | None = None,
                   progress=None) -> dict:
    """One posterior over all given tests of a damper with EJ on the power law (k, n sampled).

    Parameters
    ----------
    damper : Damper
    data : CleanBench
        The cleaned recordings (:class:`sbcal.data.clean_bench.CleanBench`); each test's kept runs enter.
    tests : sequence of str
        Constant-amplitude tests (3 or more amplitudes).
    seed : int
    start : dict, optional
        Starting values by name: ``k``, ``n`` and per test ``beta``, ``sigma_mag``, ``sigma_phase``
        (``{"beta": {test: value}}``, e.g. from the two-stage fit); default: the prior's mid-box.
    config : SamplerConfig, optional
        Default: 32 walkers per ensemble (the model has 4 + 3 per test parameters).
    progress : str, optional

    Returns
    -------
    dict with ``k``, ``n`` ([median, lo, hi], 90 %), ``beta`` per test, ``a1``, ``a2``, ``r_hat``
    (max over parameters), ``convergence``, ``converged``, ``n_steps``, ``wall_s``.
    """
    from .calibrate import test_likelihood

    config = config or SamplerConfig(nwalkers=32)
    likes, amps = [], []
    for t in tests:
        like = test_likelihood(damper, data, t)
        amp = np.unique(like.amplitude_mm_pp)
        if amp.size != 1:
            raise InputError(f"test {t!r} has no single amplitude: keep it out of the joint fit")
        likes.append(like)
        amps.append(float(amp[0]))
    if len(set(amps)) < 3:
        raise InputError(f"the joint fit needs tests at 3 or more amplitudes, got {sorted(set(amps))}")
    p1 = likes[0].prior
    boxes = {"k": p1.box("EJ"), "n": (False, -1.0, 3.0), "a1": p1.box("a1"), "a2": p1.box("a2")}
    for t in tests:
        for q in _PER_TEST:
            boxes[_per_test(q, t)] = p1.box(q)
    prior = Prior.from_boxes("joint_powerlaw", boxes)
    target = _JointTarget(likes, tests, amps, prior)
    s = start or {}
    guess = {"k": s.get("k", 10.0), "n": s.get("n", 0.4), "a1": damper.a1, "a2": damper.a2}
    for t in tests:
        for q, default in zip(_PER_TEST, (0.3, 0.1, 0.1)):
            guess[_per_test(q, t)] = s.get(q, {}).get(t, default)
    res = sample(target, seed=job_seed(seed, "map_joint", damper.name), config=config, start=guess,
                 progress=progress)
    draws = res.flat()
    return {
        "k": _interval(draws["k"]), "n": _interval(draws["n"]),
        "a1": _interval(draws["a1"]), "a2": _interval(draws["a2"]),
        "beta": {t: _interval(draws[_per_test("beta", t)]) for t in tests},
        "tests": list(tests), "amplitudes_mm_pp": amps,
        "r_hat": res.r_hat_max, "ess_bulk_k_n": min(res.ess_bulk["k"], res.ess_bulk["n"]),
        "convergence": res.convergence_dict(), "converged": res.converged,
        "n_steps": res.n_steps, "wall_s": res.wall_s, "seed": seed,
    }


def joint_from_runs(damper, data, runs_dir, two_stage: dict, paramset: str = "theta1", *, seed: int = 0,
                    progress=None) -> dict:
    """:func:`joint_powerlaw` over the tests of a two-stage map (``two_stage`` = its document),
    started from its fit and the stored per-test posteriors; adds a comparison with the two-stage k, n."""
    from .runs import read_summary
    from .store import run_dir

    tests = [t["test"] for t in two_stage["tests"]]
    start = {"k": two_stage["powerlaw"]["k"][0], "n": two_stage["powerlaw"]["n"][0],
             "beta": {}, "sigma_mag": {}, "sigma_phase": {}}
    for t in tests:
        s = read_summary(run_dir(runs_dir, damper.name, t, paramset))
        if s:
            for key in ("beta", "sigma_mag", "sigma_phase"):
                if key in s["parameters"]:
                    start[key][t] = s["parameters"][key]["median"]
    joint = joint_powerlaw(damper, data, tests, seed=seed, start=start, progress=progress)
    two = two_stage["powerlaw"]
    overlap = all(joint[p][1] <= two[p][2] and two[p][1] <= joint[p][2] for p in ("k", "n"))
    joint["comparison"] = (
        f"two-stage k {two['k'][0]:.3g} [{two['k'][1]:.3g}, {two['k'][2]:.3g}], n {two['n'][0]:.3f} "
        f"[{two['n'][1]:.3f}, {two['n'][2]:.3f}]; the 90 % intervals {'overlap' if overlap else 'do not overlap'}; "
        f"width of n's interval, two-stage / joint: {(two['n'][2] - two['n'][1]) / max(joint['n'][2] - joint['n'][1], 1e-12):.1f} "
        "(the joint model shares a1, a2 across tests and takes the law as exact: no scatter of tests about it)")
    return joint
