"""A lot's cable law as a population (``sbcal batch``): the units' stored cable fits -> the design's cable run.

Every unit of a lot that ``sbcal cable`` (or ``sbcal run``) fitted stores, per cable state, a posterior of
its strand-slip law (``<runs>/<unit>/cable-<state>``). The law's parameters (``EJ_min``, ``beta_material``
and the law's own) are pooled by the per-test population's model and reweighting
(:mod:`sbcal.inference.population`, :func:`sbcal.inference.batch.fit_population`), each parameter a block of
one dimension, in the coordinates its prior box samples: a mean and a unit scatter per parameter, the
two-component outlier population, no new forward solve. The units' posterior correlations between the
law's parameters (a stiffer stuck strand against an earlier slip) are kept: a unit's draws are pooled as
stored rows. The population has no correlation *between* parameters: twelve units do not support the
21 correlations of seven parameters, and a law's own trade-offs live in each unit's posterior.

The design's cable run (:func:`design_cable`, under :func:`sbcal.inference.store.batch_dir`
``/cable-<state>``) is the **next unit**: one draw of the member population per hyper-posterior draw, kept
where it lies in the prior box the units were fitted under and in the law's domain (the share kept is
stored). It is written in the cable-run format that ``sbcal predict``, ``sbcal span`` and ``sbcal design``
read (:func:`sbcal.design.cable_run.load_cable_run`), so a span study can take "a damper of this design"
instead of one unit: its bands then carry the unit-to-unit scatter of the law. With it: the design's
damper (the units' shared values, named ``<design>-design``), the tests the units share, the curvature
range every unit's calibration reached (the intersection: no unit's law is used beyond its data without
being marked), and the model discrepancy per amplitude as the root mean square of the units'.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core._io import write_json
from ..core.errors import InputError
from .batch import DESIGN_EXEMPT, Lot, admit, fit_population
from .store import POSTERIOR, SUMMARY, cable_dir, cable_dirs


__all__ = ["CableLot", "cable_states", "read_cable_lot", "design_cable", "write_design_cable", "NEXT_PER_DRAW"]

NEXT_PER_DRAW = 3
"""Next units drawn for the design's cable run per hyper-posterior draw the population's summary keeps
(before the box and domain: 1 200 of its 400)."""

MIN_KEPT = 0.5
"""Below this share of next-unit draws inside the prior box and the law's domain the design's run is
stored with a warning: the population reaches far outside what the units were fitted under."""


@dataclass(frozen=True)
class CableLot:
    """The units' cable fits of one state, as a :class:`~sbcal.inference.batch.Lot` of one "test".

    Attributes
    ----------
    state, law : str
    lot : Lot
        ``tests == ("",)``: each parameter is one dimension, labelled by its name.
    summaries : dict
        Unit -> its cable run's ``summary.json``.
    """

    state: str
    law: str
    lot: Lot
    summaries: dict


def cable_states(runs, units) -> tuple[list, dict]:
    """The cable states every unit has a finished fit of, and ``{state: units without it}`` for the others."""
    have = {u: {s for s, _ in cable_dirs(runs, u)} for u in units}
    every = set().union(*have.values()) if have else set()
    common = sorted(s for s in every if all(s in h for h in have.values()))
    partial = {s: [u for u in units if s not in have[u]] for s in sorted(every - set(common))}
    return common, partial


def read_cable_lot(runs, units, state: str) -> CableLot:
    """The lot's cable fits of ``state`` (one-line InputError for a lot whose laws cannot be pooled)."""
    from ..model.laws import law_for
    from .cable_fit import read_cable

    draws, summaries, excluded, seen = {}, {}, {}, {"design": None, "design_of": None, "boxes": {}}
    law = names = None
    for u in units:
        d = cable_dir(runs, u, state)
        if not (d / SUMMARY).is_file():
            raise InputError(f"{d}: no cable fit of state {state!r} for unit {u!r} ('sbcal cable --damper {u}' makes one)")
        s, post = read_cable(d)
        if law is None:
            law, first = s["law"], u
            names = ("EJ_min", "beta_material", *law_for(law).parameter_names)
        elif s["law"] != law:
            raise InputError(f"{d}/{SUMMARY}: law {s['law']!r}, unit {first!r} has {law!r}: a population pools one "
                             "law (fit every unit's state with one: sbcal cable --law LAW)")
        if not s.get("converged", False):
            excluded[u] = f"cable-{state} posterior did not converge"
            continue
        try:
            values = {k: v for k, v in s["damper_values"].items() if k not in DESIGN_EXEMPT}
            priors = {p: s["prior"]["parameters"][p] for p in names}
        except (KeyError, TypeError, AttributeError) as e:
            raise InputError(f"{d}/{SUMMARY}: key {e}: missing or malformed (not a run written by sbcal cable)") from None
        admit(seen, u, values, priors, design_where=str(d), prior_where=f"{d}/{SUMMARY}")
        missing = [p for p in names if p not in post]
        if missing:
            raise InputError(f"{d}/{POSTERIOR}: no draws of {missing[0]!r} (the {law} law needs {', '.join(names)})")
        draws[u] = {(p, ""): np.asarray(post[p], float) for p in names}
        summaries[u] = s
    kept = tuple(draws)
    if len(kept) < 3:
        why = "".join(f"; {u} left out: {r}" for u, r in excluded.items())
        raise InputError(f"{runs}: {len(kept)} unit(s) with a converged cable-{state} fit "
                         f"({', '.join(kept) or 'none'}); a population needs at least 3{why}")
    lot = Lot(units=kept, tests=("",), params=names, boxes=seen["boxes"], draws=draws, design=seen["design"],
              excluded=excluded, paramset=f"cable-{state}")
    return CableLot(state=state, law=law, lot=lot, summaries=summaries)


def _inside(law: str, params: tuple, boxes: dict, values: dict) -> np.ndarray:
    """Which next-unit draws lie in every prior box and in the law's domain (a mask over the draws)."""
    from ..model.laws import law_for

    law_ = law_for(law)
    ok = law_.valid(**{n: values[n] for n in law_.parameter_names})
    for p in params:
        _, lo, hi = boxes[p]
        ok &= (values[p] >= lo) & (values[p] <= hi)
    return ok


def _shared_tests(summaries: dict) -> list:
    common = set.intersection(*(set(s.get("tests", [])) for s in summaries.values()))
    first = next(iter(summaries.values())).get("tests", [])
    return [t for t in first if t in common]


def _reached(summaries: dict, tests) -> dict:
    """Per shared test, the curvature range every unit's calibration reached (the intersection)."""
    out = {}
    for t in tests:
        ranges = [s.get("tests_reached", {}).get(t) for s in summaries.values()]
        if any(r is None for r in ranges):
            continue
        lo = max(float(r["curvature_min"]) for r in ranges)
        hi = min(float(r["curvature_max"]) for r in ranges)
        if lo <= hi:
            out[t] = {"curvature_min": lo, "curvature_max": hi}
    return out


def _discrepancy(summaries: dict):
    """The model discrepancy per amplitude: the root mean square of the units' (on the first unit's
    amplitudes, interpolated in log amplitude); None when a unit stores none."""
    docs = [s.get("discrepancy") for s in summaries.values()]
    if any(not isinstance(d, dict) for d in docs):
        return None
    amp = np.asarray(docs[0]["amplitude_mm_pp"], float)
    out = {"amplitude_mm_pp": amp.tolist()}
    for key in ("logmag_sd", "phase_sd_deg"):
        sq = [np.interp(np.log(amp), np.log(np.asarray(d["amplitude_mm_pp"], float)), np.asarray(d[key], float)) ** 2
              for d in docs]
        out[key] = np.sqrt(np.mean(sq, axis=0)).tolist()
    return out


def design_cable(cl: CableLot, *, seed: int, progress: str | None = None) -> tuple[dict, dict, dict]:
    """Pool the lot's cable law and make the design's cable run.

    Returns
    -------
    summary : dict
        The design's cable run's ``summary.json`` (a cable run: ``law``, ``state``, ``tests``,
        ``tests_reached``, ``discrepancy``, ``damper_values``, ``converged`` ...; and ``population``: the
        population document of :func:`~sbcal.inference.batch.fit_population`).
    next_unit : dict
        Parameter -> the next unit's draws ``(n,)`` inside the prior box and the law's domain.
    hyper : dict
        The hyper-parameters' draws ``(n_chains, n_draws)`` by name.
    """
    lot = cl.lot
    doc, draws = fit_population(lot, seed=seed, progress=progress, stream=("cable", cl.state),
                                next_per_draw=NEXT_PER_DRAW)
    values = {p: np.asarray(draws["next_unit"][p], float) for p in lot.params}
    ok = _inside(cl.law, lot.params, lot.boxes, values)
    next_unit = {p: v[ok] for p, v in values.items()}
    first = cl.summaries[lot.units[0]]
    source = str(first["damper_values"].get("source") or "")
    base = Path(source).stem if source else lot.units[0]
    name = f"{base}-design"
    tests = _shared_tests(cl.summaries)
    qualifiers = {u: (s.get("remainder") or {}).get("qualifier") for u, s in cl.summaries.items()}
    summary = {
        "damper": name, "state": cl.state, "law": cl.law, "effects": [], "tests": tests, "kind": "design",
        "units": list(lot.units), "n_units": len(lot.units), "members": doc["members"], "excluded": lot.excluded,
        "n_draws": int(ok.sum()), "kept_fraction": float(ok.mean()),
        "tests_reached": _reached(cl.summaries, tests), "discrepancy": _discrepancy(cl.summaries),
        "remainder": {"qualifier": "partial" if "partial" in qualifiers.values() else "complete", "units": qualifiers},
        "damper_values": {**first["damper_values"], "name": name},
        "prior": {"parameters": {p: {"dist": "loguniform" if b[0] else "uniform", "lower": b[1], "upper": b[2]}
                                 for p, b in lot.boxes.items()}},
        "parameters": {p: {"median": float(np.median(v)), "q05": float(np.quantile(v, 0.05)),
                           "q95": float(np.quantile(v, 0.95))} for p, v in next_unit.items()},
        "converged": doc["converged"], "reason": doc["reason"],
        "population": doc, "seed": doc["seed"], "seed_key": doc["seed_key"], "versions": doc["versions"],
        "made_by": "sbcal batch",
    }
    return summary, next_unit, draws["hyper"]


def write_design_cable(out, summary: dict, next_unit: dict, hyper: dict) -> Path:
    """Store the design's cable run in ``out`` (``posterior.nc``: the next unit's draws, one chain;
    ``population.nc``: the hyper-parameters; ``summary.json`` last). Returns ``out``."""
    from .runs import write_inference_data

    out = Path(out)
    write_inference_data(out / POSTERIOR, {"posterior": {p: np.asarray(v)[None, :] for p, v in next_unit.items()}})
    write_inference_data(out / "population.nc", {"posterior": {k: np.asarray(v) for k, v in hyper.items()}})
    write_json(out / SUMMARY, summary, indent=1)
    return out
