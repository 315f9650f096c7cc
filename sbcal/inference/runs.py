"""Stored runs: ArviZ netCDF + ``summary.json`` (ArviZ itself is reached through :mod:`sbcal.inference.stats`).

A test's run (where: :mod:`sbcal.inference.store`): ``posterior.nc`` (groups posterior, sample_stats,
log_likelihood, posterior_predictive, observed_data, constant_data; attrs hold the config as
JSON, the seed, the convergence verdict and package versions) and ``summary.json`` beside it. Both
are written atomically; ``summary.json`` is written last, so a directory without it holds no
finished run.

Dims: ``chain`` is an independently seeded emcee ensemble; ``draw`` runs over its walkers'
thinned draws, walker after walker (the engine's chain structure, so ArviZ's R-hat, ESS and LOO
relative efficiency read them as the engine does). ``run`` is a bench run id, ``freq`` a frequency line.
"""

from __future__ import annotations

import json
import platform
from pathlib import Path
from typing import NamedTuple

import numpy as np
import xarray as xr

from ..core._io import atomic_path, write_json
from ..core.errors import InputError
from .stats import arviz_version, inference_data, read_netcdf
from .store import POSTERIOR, SUMMARY, run_dirs


__all__ = ["to_inference_data", "summarize", "write_run", "read_summary", "read_run", "versions",
           "posterior_draws", "parameter_summary", "StoredTest", "write_map", "read_map", "write_inference_data"]

SUMMARY_QUANTILES = (0.05, 0.5, 0.95)


def versions() -> dict:
    """Versions of Python, sbcal and every library that can move a stored number.

    numpy and scipy (the model, the solves, the random streams), emcee (the sampler's moves), pandas
    (reading the bench files), ArviZ (R-hat, ESS, PSIS-LOO) and xarray (the netCDF store it writes
    through). Under one set of these the same seed gives the same numbers, bit for bit.
    """
    from importlib.metadata import version

    import pandas
    import scipy

    from ..core.version import __version__

    return {"sbcal": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "emcee": version("emcee"), "pandas": pandas.__version__,
            "arviz": arviz_version(), "xarray": xr.__version__}


def to_inference_data(result, like, *, runs, removed_runs, seed: int, seed_key: str, rng, meta: dict):
    """Pack a :class:`sbcal.inference.sampler.SampleResult` and its likelihood into InferenceData.

    Parameters
    ----------
    result : SampleResult
        With the pointwise log-likelihood by run (the engine computes it on the kept draws).
    like : TestLikelihood
        The likelihood sampled (data, noise model, model).
    runs : array_like of int, shape (n_runs,)
        Ids of the runs in ``like`` (the cleaned runs).
    removed_runs : sequence of int
        Outlier runs removed before fitting.
    seed : int
        The user's seed.
    seed_key : str
        The job's key under it (:func:`sbcal.core.seeds.seed_key`).
    rng : numpy.random.Generator
        The stream of the posterior-predictive draws (the job's own).
    meta : dict
        Anything JSON-serialisable to keep (damper, test, config, command line ...).
    """
    n_chain, n_draw = result.log_prob.shape
    params = result.flat()
    pred = like.predictive(params, rng).reshape(2, n_chain, n_draw, -1).astype(np.float32)
    model = like.predict(params).reshape(2, n_chain, n_draw, -1).astype(np.float32)
    runs = np.asarray(runs, dtype=int)
    freq = like.freq_hz
    attrs = {
        "sbcal_config": json.dumps(meta, sort_keys=True),
        "seed": int(seed),
        "seed_key": seed_key,
        "versions": json.dumps(versions(), sort_keys=True),
        "removed_runs": json.dumps([int(r) for r in removed_runs]),
        "convergence": json.dumps(result.convergence_dict(), sort_keys=True),
    }
    obs = np.where(like.present, like.y, np.nan)
    idata = inference_data(
        posterior=dict(result.draws),
        sample_stats={"lp": result.log_prob},
        log_likelihood={"runs": result.log_likelihood},
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


def parameter_summary(result) -> dict:
    """Per parameter: median, 90 % interval and the engine's diagnostics (JSON-ready)."""
    out = {}
    for n in result.names:
        q05, q50, q95 = np.quantile(result.draws[n], SUMMARY_QUANTILES)
        out[n] = {"median": float(q50), "q05": float(q05), "q95": float(q95), "r_hat": result.r_hat[n],
                  "ess_bulk": result.ess_bulk[n], "ess_tail": result.ess_tail[n], "tau": result.tau[n]}
    return out


def summarize(idata, result, *, point_fit: dict | None = None) -> dict:
    """The ``summary.json`` document (other programs read it: keep the keys).

    R-hat and ESS are the engine's, computed by ArviZ on the very draws stored in ``idata``: the
    numbers ``arviz.summary`` prints for the stored run.
    """
    doc = {
        "parameters": parameter_summary(result),
        "acceptance": float(np.mean(result.acceptance)),
        "wall_s": float(result.wall_s),
        "seed": int(idata.posterior.attrs["seed"]),
        "seed_key": idata.posterior.attrs["seed_key"],
        **result.convergence_dict(),
        "n_draws": int(result.log_prob.size),
        "removed_runs": json.loads(idata.posterior.attrs["removed_runs"]),
        "config": json.loads(idata.posterior.attrs["sbcal_config"]),
        "versions": json.loads(idata.posterior.attrs["versions"]),
    }
    if point_fit is not None:
        doc["ga"] = point_fit
    return doc


def write_run(idata, summary: dict, directory) -> Path:
    """Write ``posterior.nc`` then ``summary.json`` into ``directory``, each atomically."""
    d = Path(directory)
    with atomic_path(d / POSTERIOR, ".nc") as tmp:
        idata.to_netcdf(str(tmp))
    write_json(d / SUMMARY, summary, indent=2, sort_keys=True)
    return d


def read_summary(directory) -> dict | None:
    """The run's summary, or None when the directory holds no finished run."""
    p = Path(directory) / SUMMARY
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
    return read_netcdf(Path(directory) / POSTERIOR), s


class StoredTest(NamedTuple):
    """One finished run of :func:`posterior_draws`: ``test`` label, ``amplitude`` [mm p-p] (None when
    it changes along the grid, as in ``2-1``), ``draws`` (name -> flattened draws), ``summary``."""

    test: str
    amplitude: float | None
    draws: dict
    summary: dict


def posterior_draws(runs_dir, damper: str, paramset: str, parameters):
    """Yield a :class:`StoredTest` for every finished run of a damper, each run read once.

    ``draws`` maps each of ``parameters`` that the run has to its flattened posterior draws.
    """
    for _, d in run_dirs(runs_dir, damper, paramset):
        idata, summary = read_run(d)
        amp = np.asarray(idata.constant_data["amplitude_mm_pp"])
        amplitude = float(amp[0]) if np.allclose(amp, amp[0]) else None
        yield StoredTest(d.parent.name, amplitude, {p: np.asarray(idata.posterior[p]).ravel()
                                                    for p in parameters if p in idata.posterior}, summary)


def write_map(directory, results: dict) -> Path:
    """Store the amplitude map's law posteriors as ``map.nc``: variables ``<law>__<parameter>``
    (chain, draw), each law's convergence as JSON in the attributes. Written atomically."""
    posterior = {f"{law}__{n}": v for law, res in results.items() for n, v in res.draws.items()}
    idata = inference_data(posterior=posterior)
    idata.posterior.attrs["convergence"] = json.dumps({law: res.convergence_dict() for law, res in results.items()},
                                                      sort_keys=True)
    path = Path(directory) / "map.nc"
    with atomic_path(path, ".nc") as tmp:
        idata.to_netcdf(str(tmp))
    return path


def read_map(directory) -> dict:
    """The law draws of a stored ``map.nc``: ``{law: {parameter: flattened draws}}`` ({} when absent)."""
    path = Path(directory) / "map.nc"
    if not path.is_file():
        return {}
    post = read_netcdf(path).posterior
    out = {}
    for name in post.data_vars:
        law, _, param = name.partition("__")
        out.setdefault(law, {})[param] = np.asarray(post[name]).ravel()
    return out


def write_inference_data(path, groups: dict, *, attrs: dict | None = None) -> Path:
    """Write groups (``arviz.from_dict`` arguments: ``posterior``, ``log_likelihood``, ``dims`` ...) as
    a netCDF file, atomically; ``attrs`` go on every group (strings and numbers)."""
    idata = inference_data(**groups)
    for group in idata.groups():
        idata[group].attrs.update(attrs or {})
    path = Path(path)
    with atomic_path(path, ".nc") as tmp:
        idata.to_netcdf(str(tmp))
    return path
