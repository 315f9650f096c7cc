"""A lot of dampers as a population (``sbcal batch``): the units' stored posteriors -> the design.

Reads every unit's per-test posteriors from a run store (:func:`read_lot`: one design, the same tests
and prior boxes, converged), fits the population by reweighting them
(:mod:`sbcal.inference.population`, the one sampling engine on its hyper-parameters) and stores
(:func:`write_batch`, under :func:`sbcal.inference.store.batch_dir`):

- ``summary.json``: the population per dimension (its median unit, the unit scatter, the next unit),
  per unit its shrunk estimate, outlier probability and reweighting ESS, the convergence, seed, versions;
- ``population.csv`` and ``units.csv``: the same as tables;
- ``population.nc``: the hyper-parameters' draws (ArviZ), for plots and later stages.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

from ..core._io import atomic_path, write_json
from ..core.errors import InputError
from ..core.seeds import job_seed, seed_key
from .population import (MIN_ESS, OUTLIER_SCALE, HyperPrior, PopulationModel, PopulationTarget, UnitDraws,
                         from_population_coordinates, outlier_probabilities, predictive_draws, shrunk_draws,
                         to_population_coordinates, unit_ess)
from .runs import posterior_draws, read_summary, versions, write_inference_data
from .sampler import SamplerConfig, sample
from .stats import read_netcdf
from .store import POSTERIOR, SUMMARY, batch_dir, run_dir
from .store import dampers as stored_dampers


__all__ = ["DEFAULT_PARAMS", "Lot", "read_lot", "admit", "fit_population", "departures", "line_departures", "write_batch", "read_batch",
           "headline", "OUTLIER_LINE", "DEPARTURE_RATE"]

DEFAULT_PARAMS = ("EJ", "beta")
OUTLIER_LINE = 0.5
"""A unit is named an outlier when its posterior probability of being one is at least this."""

MAX_DRAWS = 300
"""Joint draws kept per unit (its per-test draws paired at random): the reweighting's sample."""

DEPARTURE_RATE = 0.001
"""A unit's bench departs from the lot's at a line where its run mean lies outside the other units'
predictive interval of this two-sided tail probability (Student t with n - 2 degrees of freedom: for a unit
like the others, one line in a thousand by chance)."""

DESIGN_EXEMPT = ("name", "source", "description", "tolerance")
"""Damper fields that may differ between units of one design."""
_UNITS = {"EJ": "N m^2"}
_QUANT = (0.05, 0.5, 0.95)


@dataclass(frozen=True)
class Lot:
    """The units of one design with the tests they all have.

    Attributes
    ----------
    units : tuple of str
    tests : tuple of str
        By amplitude.
    params : tuple of str
    boxes : dict
        Parameter -> the prior box every unit was sampled under ``(log_scale, lower, upper)``.
    draws : dict
        Unit -> ``{(parameter, test): draws (n,)}``.
    design : dict
        The shared damper values (geometry, masses, nominal offsets).
    excluded : dict
        Unit -> why it was left out (an unconverged test).
    paramset : str
    """

    units: tuple
    tests: tuple
    params: tuple
    boxes: dict
    draws: dict
    design: dict
    excluded: dict
    paramset: str


def read_lot(runs, *, dampers=None, params=DEFAULT_PARAMS, tests=None, paramset: str = "theta1") -> Lot:
    """The lot in a run store (one-line InputError for a lot that cannot be one)."""
    if not Path(runs).is_dir():
        raise InputError(f"{runs}: no such run store (sbcal run --runs DIR writes one)")
    names = list(dampers) if dampers else stored_dampers(runs)
    params = tuple(dict.fromkeys(params))
    stored, excluded, seen = {}, {}, {"design": None, "design_of": None, "boxes": {}}
    for unit in names:
        found = list(posterior_draws(runs, unit, paramset, params))
        if not found:
            raise InputError(f"{runs}: no finished {paramset} posteriors of unit {unit!r} "
                             f"(run 'sbcal sample --all --damper ...' for it first)")
        bad = [t.test for t in found if not t.summary.get("converged", False)]
        if bad:
            excluded[unit] = f"posterior of {', '.join(bad)} did not converge"
            continue
        for t in found:
            missing = [p for p in params if p not in t.draws]
            if missing:
                raise InputError(f"{runs}/{unit}/{t.test}/{paramset}: parameter {missing[0]!r} not stored "
                                 f"(stored: {', '.join(t.summary['parameters'])})")
            try:
                cfg = t.summary["config"]
                values = {k: v for k, v in cfg["damper_values"].items() if k not in DESIGN_EXEMPT}
                priors = {p: cfg["prior"]["parameters"][p] for p in params}
            except (KeyError, TypeError, AttributeError) as e:
                raise InputError(f"{runs}/{unit}/{t.test}/{paramset}/{SUMMARY}: key {e}: missing or malformed "
                                 "(not a run written by sbcal sample)") from None
            admit(seen, unit, values, priors, design_where=f"{runs}/{unit}", prior_where=f"{runs}/{unit}/{t.test}/{paramset}")
        stored[unit] = {t.test: t for t in found}
    units = tuple(stored)
    if len(units) < 3:
        why = "".join(f"; {u} left out: {r}" for u, r in excluded.items())
        raise InputError(f"{runs}: {len(units)} unit(s) with finished {paramset} posteriors "
                         f"({', '.join(units) or 'none'}); a population needs at least 3{why}")
    common = set.intersection(*(set(s) for s in stored.values()))
    if tests:
        for t in tests:
            lacking = [u for u in units if t not in stored[u]]
            if lacking:
                raise InputError(f"{runs}: test {t!r} not stored for unit {lacking[0]!r}")
        chosen = list(dict.fromkeys(tests))
    else:
        chosen = sorted(common)
        if not chosen:
            raise InputError(f"{runs}: the units have no test in common")
    amp = {t: stored[units[0]][t].amplitude for t in chosen}
    chosen = tuple(sorted(chosen, key=lambda t: (amp[t] is None, amp[t] or 0.0, t)))
    draws = {u: {(p, t): stored[u][t].draws[p] for p in params for t in chosen} for u in units}
    return Lot(units=units, tests=chosen, params=params, boxes=seen["boxes"], draws=draws, design=seen["design"],
               excluded=excluded, paramset=paramset)


def admit(seen: dict, unit: str, values: dict, priors: dict, *, design_where: str, prior_where: str) -> None:
    """Check one stored result of a unit against the lot read so far, and record it.

    Parameters
    ----------
    seen : dict
        ``{"design": values or None, "design_of": unit, "boxes": {parameter: (log_scale, lower, upper)}}``,
        updated in place.
    values : dict
        The unit's damper values, the exempt fields (name, source, description, tolerance) left out.
    priors : dict
        Parameter -> its stored prior box (``{"dist", "lower", "upper"}``).

    Raises
    ------
    InputError
        One line: a damper field differs from the first unit's (units of different designs), or a prior
        box differs from the other units'.
    """
    if seen["design"] is None:
        seen["design"], seen["design_of"] = values, unit
    design = seen["design"]
    for key in sorted(set(design) | set(values)):
        if design.get(key) != values.get(key):
            raise InputError(f"{design_where}: damper field {key!r} is {values.get(key)!r}, unit "
                             f"{seen['design_of']!r} has {design.get(key)!r}: units of different designs")
    boxes = seen["boxes"]
    for p, box in priors.items():
        b = (box["dist"] == "loguniform", float(box["lower"]), float(box["upper"]))
        if boxes.setdefault(p, b) != b:
            raise InputError(f"{prior_where}: prior of {p!r} is {b[1]:g}..{b[2]:g}, other units' "
                             f"{boxes[p][1]:g}..{boxes[p][2]:g}: fit the lot under one prior")


def departures(runs, lot: Lot, *, rate: float = DEPARTURE_RATE) -> dict:
    """Where each unit's bench departs from the lot's (:func:`line_departures` of the stored run means)."""
    curves = {}
    for u in lot.units:
        for t in lot.tests:
            obs = read_netcdf(run_dir(runs, u, t, lot.paramset) / POSTERIOR).observed_data
            curves[u, t] = (np.asarray(obs["freq"]), {q: np.asarray(obs[q]).mean(axis=0) for q in ("logmag", "phase")})
    return line_departures(curves, lot.units, lot.tests, rate=rate)


def line_departures(curves: dict, units, tests, *, rate: float = DEPARTURE_RATE) -> dict:
    """Model-free departures: per test and line, a unit's run mean of ``ln |f|`` and of the phase against the
    other units' run means, ``t = (x - mean) / (sd sqrt(1 + 1/m))`` for ``m`` others, beyond the Student-t
    quantile of ``rate`` (two-sided) with ``m - 1`` degrees of freedom.

    Parameters
    ----------
    curves : dict
        ``(unit, test) -> (freq_hz (n,), {"logmag": (n,), "phase": (n,)})``: the unit's run means.

    Returns
    -------
    dict
        Unit -> test -> list of ``{"from_hz", "to_hz", "quantity", "direction", "z_max"}`` (adjacent departing
        lines merged); only lines every unit measured.
    """
    units = list(units)
    out = {u: {} for u in units}
    m_others = len(units) - 1
    if m_others < 2:
        return out
    limit = float(student_t.ppf(1 - rate / 2, m_others - 1))
    for t in tests:
        freq = np.array(sorted(set.intersection(*(set(np.round(curves[u, t][0], 6)) for u in units))))
        if not freq.size:
            continue
        means = {q: np.stack([np.interp(freq, curves[u, t][0], curves[u, t][1][q]) for u in units])
                 for q in ("logmag", "phase")}
        for k, u in enumerate(units):
            spans = []
            for q, m in means.items():
                others = np.delete(m, k, axis=0)
                sd = others.std(axis=0, ddof=1)
                zs = (m[k] - others.mean(axis=0)) / np.where(sd > 0, sd * np.sqrt(1 + 1 / m_others), np.inf)
                bad = np.flatnonzero(np.abs(zs) > limit)
                for run in np.split(bad, np.flatnonzero(np.diff(bad) > 1) + 1) if bad.size else []:
                    seg = zs[run]
                    spans.append({"from_hz": float(freq[run[0]]), "to_hz": float(freq[run[-1]]),
                                  "quantity": "magnitude" if q == "logmag" else "phase",
                                  "direction": "above" if seg.mean() > 0 else "below",
                                  "z_max": float(seg[np.argmax(np.abs(seg))])})
            out[u][t] = sorted(spans, key=lambda s: s["from_hz"])
    return out


def _unit_draws(lot: Lot, dims, rng: np.random.Generator) -> list[UnitDraws]:
    """Each unit's joint draws over ``dims`` (``(parameter, test)``): its tests' independent posteriors paired
    at random (a draw of their product), each test's parameters kept together (one stored draw of a test
    gives all of its parameters: their correlation is the unit's, e.g. a cable law's rigidity against its
    slip scale)."""
    out = []
    for u in lot.units:
        n = min(min(v.size for v in lot.draws[u].values()), MAX_DRAWS)
        rows = {}
        cols, logp = [], np.zeros(n)
        for p, t in dims:
            v = lot.draws[u][(p, t)]
            if t not in rows:
                rows[t] = rng.permutation(v.size)[:n]
            x, lp = to_population_coordinates(v[rows[t]], lot.boxes[p])
            cols.append(x)
            logp += lp
        out.append(UnitDraws(u, np.stack(cols, axis=1), logp))
    return out


def _mean_box(units: list[UnitDraws]) -> tuple:
    """A flat prior on each mean over the units' medians widened by twice their range plus one
    (a factor e in a log coordinate): wide against any lot, narrow enough for the start's search."""
    med = np.stack([np.median(u.x, axis=0) for u in units])
    lo, hi = med.min(axis=0), med.max(axis=0)
    pad = 2 * (hi - lo) + 1.0
    return tuple((float(a - b), float(c + b)) for a, c, b in zip(lo, hi, pad))


def _q(v) -> list:
    return [float(x) for x in np.quantile(v, _QUANT)]


def fit_population(lot: Lot, *, seed: int, config: SamplerConfig = SamplerConfig(), progress: str | None = None,
                   n_summary: int = 400, departing: dict | None = None, stream: tuple = (),
                   next_per_draw: int = 1) -> tuple[dict, dict]:
    """Fit the population of a lot.

    ``stream``: more of the job's name under ``seed`` (:func:`~sbcal.core.seeds.job_seed`), so two populations
    of one store (the per-test parameters, a cable state's law) draw independent random numbers.
    ``next_per_draw``: next units drawn per hyper-posterior draw kept (``n_summary`` of them).

    Returns
    -------
    doc : dict
        The ``summary.json`` document (:func:`headline` reads it).
    draws : dict
        Hyper-parameter draws by name ``(n_chains, n_draws)`` and the next unit's draws per dimension
        (natural units, ``(n_summary,)``), for :func:`write_batch`.
    """
    s_pair, s_sample, s_after = job_seed(seed, "batch", *stream).spawn(3)
    blocks = tuple((p, lot.tests) for p in lot.params)
    units = _unit_draws(lot, [(p, t) for p, tests in blocks for t in tests], np.random.default_rng(s_pair))
    model = PopulationModel(blocks=blocks, hyper=HyperPrior(mean_box=_mean_box(units)))
    target = PopulationTarget(model, units)
    med = np.stack([np.median(u.x, axis=0) for u in units])
    names = model.hyper_names()
    start = {**dict(zip(names["mean"], np.median(med, axis=0))),
             **dict(zip(names["scatter"], np.clip(med.std(axis=0, ddof=1), 1e-3, 5.0))),
             **{n: 0.5 for n in names["correlation"]}, **{n: 0.05 for n in names["outlier"]}}
    result = sample(target, seed=s_sample, config=config, start=start, progress=progress)
    flat = result.flat()
    rng = np.random.default_rng(s_after)
    pick = rng.choice(flat[result.names[0]].size, size=min(n_summary, flat[result.names[0]].size), replace=False)
    sub = {k: v[pick] for k, v in flat.items()}
    p_out, p_block = outlier_probabilities(target, sub)
    ess = unit_ess(target, sub)
    shrunk = shrunk_draws(target, sub, rng)
    nxt = np.concatenate([predictive_draws(model, sub, rng) for _ in range(next_per_draw)])

    population = []
    for i, (p, t) in enumerate(model.dims):
        label = model.label(p, t)
        mean_x = flat[f"{label}.mean"]
        tau = flat[f"{label}.scatter"]
        box = lot.boxes[p]
        # the unit scatter as a relative spread of the value: d ln x = dx (log) or (1 - u) dx (logit)
        rel = tau if box[0] else tau * (1 - (from_population_coordinates(mean_x, box) - box[1]) / (box[2] - box[1]))
        population.append({"parameter": p, "test": t, "unit": _UNITS.get(p, "1"),
                           "median_unit": _q(from_population_coordinates(mean_x, box)),
                           "scatter_percent": _q(100 * rel), "scatter_coordinate": _q(tau),
                           "next_unit": _q(from_population_coordinates(nxt[:, i], box))})
    per_unit = []
    for j, u in enumerate(units):
        values = {}
        for i, (p, t) in enumerate(model.dims):
            box = lot.boxes[p]
            values[model.label(p, t)] = {"own": _q(from_population_coordinates(u.x[:, i], box)),
                                         "shrunk": _q(from_population_coordinates(shrunk[j, :, i], box))}
        per_unit.append({"unit": u.name, "outlier_probability": float(p_out[j]),
                         "outlier_in": {p: float(p_block[k, j]) for k, p in enumerate(lot.params)} if p_block.size else {},
                         "ess_median": float(np.median(ess[:, j])), "ess_q05": float(np.quantile(ess[:, j], 0.05)),
                         "flagged": bool(np.median(ess[:, j]) < MIN_ESS), "values": values,
                         "departs": (departing or {}).get(u.name, {})})
    members = float(np.sum(1 - p_out))
    doc = {
        "units": list(lot.units), "n_units": len(lot.units), "members": members, "tests": list(lot.tests),
        "params": list(lot.params), "paramset": lot.paramset, "excluded": lot.excluded,
        "correlation": {p: _q(flat[n]) for p, n in zip([b[0] for b in blocks if len(b[1]) > 1], names["correlation"])},
        "outlier_fraction": _q(flat["outlier_fraction"]) if "outlier_fraction" in flat else None,
        "population": population, "per_unit": per_unit,
        "model": {"coordinates": {p: "log" if lot.boxes[p][0] else "logit of the prior box" for p in lot.params},
                  "structure": "normal per parameter block: a mean and a scatter per test, one correlation between tests",
                  "outliers": f"two-component: epsilon ~ Beta{model.hyper.outlier_beta}, an outlier's deviation along "
                              f"its block's common direction {OUTLIER_SCALE:g} x the scatter",
                  "scatter_prior": f"half-Cauchy({model.hyper.scatter_scale:g})", "mean_prior": "flat",
                  "min_ess": MIN_ESS, "draws_per_unit": int(target.x.shape[1])},
        "boxes": {p: list(b) for p, b in lot.boxes.items()},
        "design": lot.design,
        "seed": int(seed), "seed_key": seed_key("batch", *stream), "versions": versions(),
        "sampler": asdict(config), **result.convergence_dict(),
        "wall_s": float(result.wall_s),
    }
    draws = {"hyper": result.draws, "next_unit": {model.label(p, t): from_population_coordinates(nxt[:, i], lot.boxes[p])
                                                  for i, (p, t) in enumerate(model.dims)}}
    return doc, draws


def write_batch(out, doc: dict, draws: dict) -> None:
    """Store a lot's population under ``out`` (summary.json last)."""
    from pathlib import Path

    out = Path(out)
    write_inference_data(out / "population.nc", {"posterior": {k: np.asarray(v) for k, v in draws["hyper"].items()}})
    rows = [{"parameter": r["parameter"], "test": r["test"], "unit": r["unit"],
             **{f"median_unit_{k}": v for k, v in zip(("q05", "q50", "q95"), r["median_unit"])},
             **{f"scatter_percent_{k}": v for k, v in zip(("q05", "q50", "q95"), r["scatter_percent"])},
             **{f"next_unit_{k}": v for k, v in zip(("q05", "q50", "q95"), r["next_unit"])}} for r in doc["population"]]
    _write_csv(out / "population.csv", pd.DataFrame(rows))
    rows = []
    for u in doc["per_unit"]:
        for label, v in u["values"].items():
            rows.append({"unit": u["unit"], "dimension": label, "outlier_probability": u["outlier_probability"],
                         "ess_median": u["ess_median"], "flagged": u["flagged"],
                         **{f"own_{k}": x for k, x in zip(("q05", "q50", "q95"), v["own"])},
                         **{f"shrunk_{k}": x for k, x in zip(("q05", "q50", "q95"), v["shrunk"])}})
    _write_csv(out / "units.csv", pd.DataFrame(rows))
    write_json(out / SUMMARY, doc, indent=2)


def _write_csv(path, frame: pd.DataFrame) -> None:
    with atomic_path(path, ".csv") as tmp:
        frame.to_csv(tmp, index=False)


def read_batch(runs) -> dict | None:
    """The stored population of a run store's lot, or None."""
    return read_summary(batch_dir(runs))


def _fmt(q, digits=3) -> str:
    return f"{q[1]:.{digits}g} [{q[0]:.{digits}g}, {q[2]:.{digits}g}]"


def _hz(s) -> str:
    return f"{s['from_hz']:g} Hz" if s["from_hz"] == s["to_hz"] else f"{s['from_hz']:g}-{s['to_hz']:g} Hz"


def headline(doc: dict) -> str:
    """The lot in one line: the population at its first test, the scatter, the outliers (or why there is no result)."""
    n = doc["n_units"]
    if not doc["converged"]:
        return f"{n} units: population NOT CONVERGED ({doc['reason']}); no result"
    parts = []
    for p in doc["params"]:
        r = next(r for r in doc["population"] if r["parameter"] == p)
        unit = f" {r['unit']}" if r["unit"] != "1" else ""
        parts.append(f"population {p} {_fmt(r['median_unit'])}{unit}, unit scatter {_fmt(r['scatter_percent'], 2)} %"
                     + (f" (at {r['test']})" if len(doc["tests"]) > 1 else ""))
    line = f"{n} units: " + "; ".join(parts)
    outliers = [u for u in doc["per_unit"] if u["outlier_probability"] >= OUTLIER_LINE]
    for u in sorted(outliers, key=lambda u: -u["outlier_probability"]):
        p = max(u["outlier_in"], key=u["outlier_in"].get)
        label = PopulationModel.label(p, doc["tests"][0])
        line += f"; unit {u['unit']} is an outlier (P {u['outlier_probability']:.2f}): {p} {_fmt(u['values'][label]['own'])}"
        spans = [f"{s['quantity']} {s['direction']} at {_hz(s)} ({t})" for t, ss in u.get("departs", {}).items() for s in ss]
        if spans:
            line += ", its bench departs from the lot's: " + ", ".join(spans[:3]) + (" ..." if len(spans) > 3 else "")
    if not outliers:
        top = max(doc["per_unit"], key=lambda u: u["outlier_probability"])
        line += f"; no outlier (highest P {top['outlier_probability']:.2f}: unit {top['unit']})"
    flagged = [u["unit"] for u in doc["per_unit"] if u["flagged"]]
    if flagged:
        line += f"; FLAGGED (its draws cannot represent the population, ESS < {MIN_ESS:g}): {', '.join(flagged)}"
    if doc["excluded"]:
        line += "; left out: " + ", ".join(f"{u} ({r})" for u, r in doc["excluded"].items())
    return line
