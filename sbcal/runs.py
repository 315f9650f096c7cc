"""Stored runs: ArviZ netCDF + ``summary.json``. The only module that imports ArviZ.

Layout: ``<out>/<damper>/<test>/<paramset>/posterior.nc`` (groups posterior, sample_stats,
log_likelihood, posterior_predictive, observed_data, constant_data; attrs hold the config as
JSON, the seed and package versions) and ``summary.json`` beside it. Both are written atomically;
``summary.json`` is written last, so a directory without it holds no finished run.

Dims: ``chain`` is an independently seeded emcee ensemble; ``draw`` runs over its walkers'
thinned draws, walker after walker. ``run`` is a bench run id, ``freq`` a frequency line.
"""

from __future__ import annotations

import json
import platform
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)  # ArviZ 0.x announces its 1.x refactor on import
    import arviz as az

from ._io import atomic_path, write_json
from .errors import InputError

__all__ = ["run_dir", "to_inference_data", "summarize", "write_run", "read_summary", "read_run", "versions",
           "loo_pointwise", "posterior_draws", "rhat_ess"]

SUMMARY_QUANTILES = (0.05, 0.5, 0.95)


def versions() -> dict:
    """Versions of sbcal and the libraries that shape its numbers."""
    import emcee
    import scipy

    from . import __version__

    return {"sbcal": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "emcee": emcee.__version__, "arviz": az.__version__}


def run_dir(out, damper: str, test: str, paramset: str) -> Path:
    """``<out>/<damper>/<test>/<paramset>``."""
    return Path(out) / damper / test / paramset


def to_inference_data(result, like, *, runs, removed_runs, seed: int, meta: dict) -> "az.InferenceData":
    """Pack a :class:`sbcal.sampler.SampleResult` and its likelihood into InferenceData.

    Parameters
    ----------
    result : SampleResult
    like : TestLikelihood
        The likelihood sampled (data, noise model, model).
    runs : array_like of int, shape (n_runs,)
        Ids of the runs in ``like`` (the cleaned runs).
    removed_runs : sequence of int
        Outlier runs removed before fitting.
    seed : int
    meta : dict
        Anything JSON-serialisable to keep (damper, test, config, command line ...).
    """
    n_chain, n_draw, ndim = result.x.shape
    flat = result.x.reshape(-1, ndim)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))  # own stream: predictive draws
    pred = like.predictive(flat, rng).reshape(2, n_chain, n_draw, -1).astype(np.float32)
    model = like.predict(flat).reshape(2, n_chain, n_draw, -1).astype(np.float32)
    loglik = like.pointwise_log_likelihood(flat).reshape(n_chain, n_draw, -1)
    runs = np.asarray(runs, dtype=int)
    freq = like.freq_hz
    attrs = {
        "sbcal_config": json.dumps(meta, sort_keys=True),
        "seed": int(seed),
        "versions": json.dumps(versions(), sort_keys=True),
        "removed_runs": json.dumps([int(r) for r in removed_runs]),
    }
    obs = np.where(like.present, like.y, np.nan)
    idata = az.from_dict(
        posterior={n: result.x[:, :, i] for i, n in enumerate(result.names)},
        sample_stats={"lp": result.log_prob},
        log_likelihood={"runs": loglik},
        posterior_predictive={"logmag": pred[0], "phase": pred[1], "model_logmag": model[0], "model_phase": model[1]},
        constant_data={"freq_hz": freq, "amplitude_mm_pp": like.amplitude_mm_pp,
                       "noise_logmag": like.sigma[0], "noise_phase": like.sigma[1], "n_runs": like.n},
        coords={"run": runs, "freq": freq},
        dims={"runs": ["run"], "logmag": ["freq"], "phase": ["freq"], "model_logmag": ["freq"],
              "model_phase": ["freq"], "freq_hz": ["freq"], "amplitude_mm_pp": ["freq"],
              "noise_logmag": ["freq"], "noise_phase": ["freq"], "n_runs": ["freq"]},
    )
    # observed runs carry a run axis, which from_dict's shared dims map cannot express
    observed = xr.Dataset({"logmag": (("run", "freq"), obs[0]), "phase": (("run", "freq"), obs[1])},
                          coords={"run": runs, "freq": freq}, attrs=attrs)
    idata.add_groups(observed_data=observed)
    for group in idata.groups():
        idata[group].attrs.update(attrs)
    return idata


def summarize(idata, result) -> dict:
    """The ``summary.json`` document (other programs read it: keep the keys)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rhat = az.rhat(idata, method="rank")
        ess = az.ess(idata, method="bulk")
    params = {}
    for i, n in enumerate(result.names):
        v = result.x[:, :, i].ravel()
        q05, q50, q95 = np.quantile(v, SUMMARY_QUANTILES)
        params[n] = {"median": float(q50), "q05": float(q05), "q95": float(q95),
                     "r_hat": float(rhat[n]), "ess_bulk": float(ess[n]), "tau": float(np.mean(result.tau[:, i]))}
    conv = all(p["r_hat"] <= 1.01 for p in params.values()) and result.converged
    return {
        "parameters": params,
        "acceptance": float(np.mean(result.acceptance)),
        "wall_s": float(result.wall_s),
        "seed": int(idata.posterior.attrs["seed"]),
        "converged": bool(conv),
        "n_steps": [int(s) for s in result.n_steps],
        "n_draws": int(result.x.shape[0] * result.x.shape[1]),
        "ga": result.init.as_dict(),
        "removed_runs": json.loads(idata.posterior.attrs["removed_runs"]),
        "config": json.loads(idata.posterior.attrs["sbcal_config"]),
        "versions": json.loads(idata.posterior.attrs["versions"]),
    }


def write_run(idata, summary: dict, directory) -> Path:
    """Write ``posterior.nc`` then ``summary.json`` into ``directory``, each atomically."""
    d = Path(directory)
    with atomic_path(d / "posterior.nc", ".nc") as tmp:
        idata.to_netcdf(str(tmp))
    write_json(d / "summary.json", summary, indent=2, sort_keys=True)
    return d


def read_summary(directory) -> dict | None:
    """The run's summary, or None when the directory holds no finished run."""
    p = Path(directory) / "summary.json"
    if not p.exists():
        return None
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not valid JSON ({e.msg}, line {e.lineno})") from None


def read_run(directory):
    """``(InferenceData, summary)`` of a finished run."""
    s = read_summary(directory)
    if s is None:
        raise InputError(f"{directory}: no finished run (summary.json missing)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        return az.from_netcdf(str(Path(directory) / "posterior.nc")), s


def loo_pointwise(log_lik) -> np.ndarray:
    """PSIS-LOO pointwise ELPD of a log-likelihood matrix ``(n_draws, n_points)``: shape (n_points,).

    Where the Pareto smoothing fails (a point whose log-likelihood spans thousands of nats over the
    draws: the weights fall on one draw and the tail fit is undefined) the plain importance-sampling
    estimate ``-log mean(exp(-log_lik))`` stands in; such points have Pareto k far above 0.7.
    """
    from scipy.special import logsumexp

    ll = np.asarray(log_lik, float)
    idata = az.from_dict(posterior={"_": np.zeros((1, ll.shape[0]))}, log_likelihood={"y": ll[None]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto-k warnings are reported by the callers that care
        with np.errstate(all="ignore"):
            res = az.loo(idata, pointwise=True)
    out = np.asarray(res.loo_i, dtype=float)
    bad = ~np.isfinite(out)
    if bad.any():
        out[bad] = -(logsumexp(-ll[:, bad], axis=0) - np.log(ll.shape[0]))
    return out


def posterior_draws(runs_dir, damper: str, paramset: str, parameters):
    """Yield ``(test, amplitude, draws)`` for every finished run of a damper, each run read once.

    ``amplitude`` is the test's amplitude [mm p-p] when it is the same on every line, else None
    (mixed-amplitude tests such as ``2-1``); ``draws`` maps each of ``parameters`` that the run has
    to its flattened posterior draws.
    """
    root = Path(runs_dir) / damper
    if not root.is_dir():
        return
    for d in sorted(p.parent for p in root.glob(f"*/{paramset}/summary.json")):
        idata, _ = read_run(d)
        amp = np.asarray(idata.constant_data["amplitude_mm_pp"])
        amplitude = float(amp[0]) if np.allclose(amp, amp[0]) else None
        yield d.parent.name, amplitude, {p: np.asarray(idata.posterior[p]).ravel()
                                         for p in parameters if p in idata.posterior}


def rhat_ess(x, names) -> dict:
    """Rank-normalised R-hat and bulk ESS per parameter of draws ``(n_chains, n_draws, ndim)``."""
    idata = az.from_dict(posterior={n: x[:, :, i] for i, n in enumerate(names)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r, e = az.rhat(idata), az.ess(idata, method="bulk")
    return {n: {"r_hat": float(r[n]), "ess_bulk": float(e[n])} for n in names}
