"""A damper designed for a line (``sbcal design``): the damper-file fields of a design space that
maximise the worst-case fatigue margin (or the service life) of a conductor span, with the damper
built with a calibrated cable, at its best position (``docs/design.md``).

The objective of a design is the 10 % quantile over the cable posterior (with the tolerances and the
model error of :mod:`sbcal.design.impedance`) of the worst-case margin over the wind band, with the
dampers at the position that maximises it (:func:`sbcal.design.placement.optimise_position`); with
``objective="life"`` the 10 % quantile of the service life there (:mod:`sbcal.design.life`).

The optimiser is SciPy's differential evolution: global and derivative-free (a design's objective is
a maximum over lines of root-found balances: continuous, not smooth), seeded by a NumPy generator
(the same seed, the same designs), constrained by :class:`scipy.optimize.NonlinearConstraint` (the
space's mass and length limits), and parallel by generation (``updating="deferred"``: each
generation's designs are independent jobs of :func:`sbcal.core.workers.run_jobs`, on local processes
or a Dask cluster). The starting damper is one member of the first generation, so the search never
ends below it. During the search each design is evaluated on a cheaper grid (:class:`Search`: fewer
draws, lines and positions, the same draws and errors for every design: common random numbers); the
starting and the chosen designs are then evaluated as ``sbcal span --optimise`` evaluates them (all
draws and lines), and those are the numbers reported. Designs whose arms bend beyond the calibrated
curvature at some line are kept in the table, marked, and never chosen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from ..model.damper import Damper
from .conductor import Conductor
from .space import DesignSpace


__all__ = ["OBJECTIVES", "QUANTILE", "Search", "DesignResult", "design", "evaluate_design"]

OBJECTIVES = ("margin", "life")
QUANTILE = 0.1
"""The quantile over draws an objective maximises (the margin or life that 90 % of the posterior exceeds)."""

_EXTRAPOLATION_PENALTY = 1e3  # added to the minimised -objective of a design outside the calibration


@dataclass(frozen=True)
class Search:
    """The cheaper grid each design of a search is evaluated on.

    Attributes
    ----------
    n_draws : int
        Posterior draws (a seeded subset: the same for every design).
    n_freq : int
        Lines in the wind band.
    n_positions : int
        Candidate damper positions (:func:`sbcal.design.placement.position_grid`).
    """

    n_draws: int = 20
    n_freq: int = 30
    n_positions: int = 12


def _quantiles(x) -> dict:
    """5 %, 10 %, 50 %, 95 % over draws; with infinite values (unlimited lives) without interpolation,
    which would turn inf - inf into NaN."""
    x = np.asarray(x, float)
    method = "inverted_cdf" if np.isinf(x).any() else "linear"
    q05, q10, q50, q95 = np.quantile(x, [0.05, QUANTILE, 0.5, 0.95], method=method)
    return {"median": float(q50), "q05": float(q05), "q95": float(q95), "q10": float(q10)}


def _resonances_hz(imp, freq, amplitude_m) -> list:
    """Median frequencies [Hz] of the damper's resonances (the peaks of its resistance Im K*/omega,
    as ``sbcal predict`` finds them) at the clamp amplitude ``amplitude_m`` [m, 0-peak] over the band."""
    from .predict import level_resonances

    fine = np.geomspace(freq.min(), freq.max(), 120)
    x0 = np.full(fine.size, amplitude_m)
    k = imp(fine, np.broadcast_to(x0, (1, fine.size)))
    return [r.freq_hz[1] for r in level_resonances(fine, k, x0, 2e3 * amplitude_m)]


def _scored(result, position_m: float, damper: Damper, life=None) -> dict:
    """One design's record at its position: the margin's quantiles and, with a life
    (:class:`sbcal.design.life.Life`), the life's; the objective is the q10 of the life when there is
    one, else of the margin. The one scoring of the search and of the final evaluation."""
    out = {"margin": _quantiles(result.margin), "position_m": position_m, "total_mass_kg": damper.total_mass}
    out["objective"] = out["margin"]["q10"]
    if life is not None:
        out["years"] = _quantiles(life.years_draws)
        out["objective"] = out["years"]["q10"]
    return out


@dataclass(frozen=True, eq=False)
class _Evaluate:
    """One design's objective on the search grid: a picklable job of :func:`run_jobs`."""

    conductor: Conductor
    cable: str
    start: Damper
    space: DesignSpace
    objective: str
    ends: int
    wind: tuple
    search: Search
    seed: int
    model_error: bool
    climate: object = None
    across: float = 1.0

    def __call__(self, x) -> dict:
        d = self.space.damper(self.start, x)
        return evaluate_design(self.conductor, self.cable, d, objective=self.objective, ends=self.ends, wind=self.wind,
                               n_draws=self.search.n_draws, n_freq=self.search.n_freq,
                               n_positions=self.search.n_positions, seed=self.seed, model_error=self.model_error,
                               climate=self.climate, across=self.across) | {
            "fields": {k: float(v) for k, v in zip(self.space.fields, x)}}


def evaluate_design(conductor: Conductor, cable, damper: Damper, *, objective: str = "margin", ends: int = 1,
                    wind=(1.0, 7.0), n_draws: int = 20, n_freq: int = 30, n_positions: int = 12, seed: int = 0,
                    model_error: bool = True, climate=None, across: float = 1.0) -> dict:
    """The objective of one damper design at its best position (module docstring).

    Returns
    -------
    dict
        ``objective`` (the :data:`QUANTILE` of the margin, or of the life in years), ``margin``
        {median, q05, q95, q10}, ``years`` (with ``objective="life"``: {median, q05, q95, q10}, inf
        for an unlimited life), ``position_m``, ``total_mass_kg``, ``resonances_hz`` (median, at the
        damper's median clamp amplitude on the span), ``extrapolated`` (some line bends the arms
        beyond, or below, the calibrated curvature).
    """
    from .cable_run import load_cable_run
    from .impedance import impedance_from_cable
    from .life import service_life
    from .placement import optimise_position, position_grid
    from .span_study import law_range_check

    run = load_cable_run(cable)
    imp = impedance_from_cable(run, damper, n_draws=n_draws, seed=seed, model_error=model_error)
    grid = position_grid(conductor, ends=ends, wind=wind, n_freq=n_freq, n=n_positions)
    place = optimise_position(conductor, imp, grid, ends=ends, quantile=QUANTILE, wind=wind, n_freq=n_freq)
    r = place.best
    life = service_life(r, climate, across=across) if objective == "life" else None
    out = _scored(r, place.best_position_m, damper, life)
    law_range, _ = law_range_check(run, imp, r)
    out["extrapolated"] = bool(law_range["extrapolated"] or law_range["below_range"])
    xd = np.nanmedian(r.damper_amplitude_m)
    out["resonances_hz"] = _resonances_hz(imp, r.freq_hz, xd) if np.isfinite(xd) and xd > 0 else []
    return out


@dataclass
class _Generations:
    """The map-like ``workers`` of :func:`scipy.optimize.differential_evolution`: each generation's
    designs through :func:`run_jobs`. It evaluates its own :class:`_Evaluate` (which keeps every
    design's record, not only the number the optimiser minimises) instead of the function scipy
    passes, which is that evaluator's objective."""

    evaluate: _Evaluate
    workers: int
    executor: object
    bar: object
    records: list = field(default_factory=list)

    def __call__(self, func, population):
        from ..core.workers import run_jobs

        xs = [np.asarray(x, float) for x in population]
        recs = run_jobs(self.evaluate, xs, workers=self.workers, executor=self.executor)
        self.records += recs
        self.bar.update(len(recs))
        return [_minimised(r) for r in recs]


def _minimised(rec: dict) -> float:
    """What the optimiser minimises: -objective (an unlimited life counts as a million years; no
    balance as the worst), plus a penalty outside the calibration."""
    v = rec["objective"]
    base = 1e6 if math.isnan(v) else -min(v, 1e6)
    return base + (_EXTRAPOLATION_PENALTY if rec["extrapolated"] else 0.0)


@dataclass(frozen=True, eq=False)
class DesignResult:
    """A design search (:func:`design`).

    Attributes
    ----------
    conductor : Conductor
    cable : str
        The stored cable run.
    space : DesignSpace
    objective : str
    start, best : dict
        ``{fields, objective, margin: {median, q05, q95, q10}, position_m, total_mass_kg, extrapolated}``
        (and ``years`` with the life objective), evaluated as ``sbcal span --optimise`` evaluates them.
    best_damper : Damper
        The chosen design (the starting damper when nothing beat it).
    records : list of dict
        Every design the search evaluated, on the search grid (:func:`evaluate_design`, with ``fields``).
    optimiser : dict
        Its name, settings and the search grid.
    seed : int
    ends : int
    warnings : tuple of str
    """

    conductor: Conductor
    cable: str
    space: DesignSpace
    objective: str
    start: dict
    best: dict
    best_damper: Damper
    records: list
    optimiser: dict
    seed: int
    ends: int
    climate: str = ""
    across: float = 1.0
    warnings: tuple = ()

    def to_frame(self):
        """``designs.csv``: one row per evaluated design (search grid)."""
        import pandas as pd

        rows = []
        for i, r in enumerate(self.records):
            row = {"design": i, **r["fields"], "objective": r["objective"],
                   **{f"margin_{k}": v for k, v in r["margin"].items()}}
            if "years" in r:
                row |= {f"years_{k}": v for k, v in r["years"].items()}
            row |= {"position_m": r["position_m"], "total_mass_kg": r["total_mass_kg"],
                    "resonances_hz": " ".join(f"{f:.4g}" for f in r["resonances_hz"]),
                    "extrapolated": r["extrapolated"]}
            rows.append(row)
        return pd.DataFrame(rows)

    def summary(self) -> dict:
        from ..inference.runs import versions

        return {"conductor": self.conductor.name, "cable": self.cable, "space": self.space.source,
                "vary": {k: [lo, hi] for k, lo, hi in zip(self.space.fields, self.space.lower, self.space.upper)},
                "constraints": dict(self.space.constraints), "objective": self.objective,
                "quantile": QUANTILE, "ends": self.ends, "climate": self.climate or None, "across": self.across,
                "start": self.start, "best": self.best, "best_damper": self.best_damper.name,
                "optimiser": self.optimiser, "evaluations": len(self.records), "seed": self.seed,
                "warnings": list(self.warnings), "versions": versions()}


def _final(conductor, cable, damper, *, objective, climate, across, ends, wind, n_freq, n_draws, seed,
           model_error) -> dict:
    """A design as ``sbcal span --optimise`` evaluates it (all draws and lines, 40 positions)."""
    from .span_study import span_study

    study = span_study(conductor, damper, cable=cable, ends=ends, wind=wind, n_freq=n_freq, n_draws=n_draws,
                       seed=seed, optimise=True, model_error=model_error,
                       climate=climate if objective == "life" else None, across=across)
    out = _scored(study.result, study.placement.best_position_m, damper, study.life)
    out["extrapolated"] = bool(study.extrapolated_hz or study.below_range_hz)
    return out


def _final_job(job):
    conductor, cable, damper, kw = job
    return _final(conductor, cable, damper, **kw)


def design(conductor: Conductor, cable, start: Damper, space: DesignSpace, *, objective: str = "margin",
           climate=None, across: float = 1.0, ends: int = 1, budget: int = 120, seed: int = 0, workers: int = 1,
           executor=None, wind=(1.0, 7.0), n_freq: int = 60, n_draws: int = 200, search: Search = Search(),
           model_error: bool = True, progress: bool = True) -> DesignResult:
    """Search the design space for the damper that maximises ``objective`` (module docstring).

    Parameters
    ----------
    conductor : Conductor
    cable : path-like
        A stored cable-law run (``runs/damper1/cable-dry``).
    start : Damper
        The starting damper: every field the space does not vary keeps its value.
    space : DesignSpace
    objective : {"margin", "life"}
        The 10 % quantile of the worst-case margin, or of the service life (needs ``climate``).
    climate, across
        The wind climate (:func:`sbcal.design.life.parse_climate`) and the share of the time the wind
        blows across the line, for ``objective="life"``.
    ends : {1, 2}
        Dampers at one span end or at both.
    budget : int
        Designs the search evaluates, at most (the starting design included).
    seed : int
        Seeds the optimiser, the posterior subset and the model-error draws.
    workers, executor
        Local processes, or a cluster's executor, for each generation's designs.
    wind, n_freq, n_draws, model_error
        As in :func:`sbcal.design.span_study.span_study`, for the final evaluation of the starting and
        the chosen designs.
    search : Search
        The cheaper grid of the search.
    progress : bool
        A progress bar over the designs.

    Returns
    -------
    DesignResult
    """
    from scipy.optimize import NonlinearConstraint, differential_evolution

    from ..core.progress import progress_bar
    from ..core.workers import run_jobs
    from .cable_run import load_cable_run

    if objective not in OBJECTIVES:
        raise InputError(f"objective: expected one of {', '.join(OBJECTIVES)}, got {objective!r}")
    if objective == "life" and climate is None:
        raise InputError("climate: the life objective needs a wind climate (e.g. weibull:k=2.0,c=4.5)")
    n = len(space.fields)
    pop = max(8, 4 * n)
    if int(budget) != budget or budget < pop:
        raise InputError(f"budget: expected an integer >= {pop} (one generation of {pop} designs for {n} free "
                         f"field{'s' if n > 1 else ''}), got {budget!r}")
    run = load_cable_run(cable)
    notes = [w for w in (run.convergence_warning(),) if w]
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    space.check_feasible(start, rng)
    x0 = np.array([getattr(start, _field(k)) for k in space.fields])
    in_box = bool(np.all((x0 >= space.lower) & (x0 <= space.upper)))
    if not in_box:
        notes.append("the starting damper lies outside the design space's box: it is not one of the designs searched")
    evaluate = _Evaluate(conductor=conductor, cable=str(run.path), start=start, space=space, objective=objective,
                         ends=ends, wind=tuple(wind), search=search, seed=int(seed), model_error=model_error,
                         climate=climate, across=float(across))
    popsize = math.ceil(pop / n)
    maxiter = max(0, int(budget) // (popsize * n) - 1)
    constraints = (NonlinearConstraint(lambda x: space.violations(space.damper(start, x)), -np.inf, 0.0)
                   if space.constraints else ())
    with progress_bar("design" if progress else None, total=popsize * n * (maxiter + 1), unit="design") as bar:
        gens = _Generations(evaluate=evaluate, workers=workers, executor=executor, bar=bar)
        res = differential_evolution(_never, space.bounds, popsize=popsize, maxiter=maxiter, rng=rng, polish=False,
                                     init="latinhypercube", updating="deferred", workers=gens,
                                     constraints=constraints, x0=x0 if in_box else None, tol=0.01)
    records = [r for r in gens.records if space.feasible(space.damper(start, list(r["fields"].values())))]
    usable = [r for r in records if not r["extrapolated"] and np.isfinite(r["objective"])]
    if not usable:
        raise InputError(f"{space.source}: every design the search evaluated bends the arms beyond the cable's "
                         "calibrated curvature (or has no balance): narrow the space or calibrate at larger amplitudes")
    best_rec = max(usable, key=lambda r: r["objective"])
    xb = np.array(list(best_rec["fields"].values()))
    # the starting damper itself keeps its name (and, for the calibration damper, its posterior offsets)
    best_damper = start if np.array_equal(xb, x0) else _named(space.damper(start, xb), start)
    kw = dict(objective=objective, climate=climate, across=float(across), ends=ends, wind=tuple(wind), n_freq=n_freq,
              n_draws=n_draws, seed=int(seed), model_error=model_error)
    final_start, final_best = run_jobs(_final_job, [(conductor, str(run.path), start, kw),
                                                     (conductor, str(run.path), best_damper, kw)],
                                       workers=workers, executor=executor)
    final_start["fields"] = {k: float(v) for k, v in zip(space.fields, x0)}
    final_best["fields"] = dict(best_rec["fields"])
    if final_best["objective"] < final_start["objective"]:
        notes.append(f"the search's best design ({final_best['objective']:.4g}) does not beat the starting one "
                     f"({final_start['objective']:.4g}) on the full evaluation: the starting damper is kept")
        final_best, best_damper = dict(final_start), start
    optimiser = {"name": "scipy.optimize.differential_evolution", "strategy": "best1bin", "popsize": popsize * n,
                 "maxiter": maxiter, "init": "latinhypercube", "updating": "deferred", "polish": False,
                 "generations": int(res.nit) + 1, "message": str(res.message),
                 "search": {"n_draws": search.n_draws, "n_freq": search.n_freq, "n_positions": search.n_positions},
                 "final": {"n_draws": n_draws, "n_freq": n_freq}}
    return DesignResult(conductor=conductor, cable=str(run.path), space=space, objective=objective, start=final_start,
                        best=final_best, best_damper=best_damper, records=records, optimiser=optimiser,
                        seed=int(seed), ends=ends, climate=climate.describe() if climate is not None else "",
                        across=float(across), warnings=tuple(notes))


def _never(x):  # scipy's own objective: never called (the generations evaluate their own)
    raise RuntimeError("the design search evaluates its designs through _Generations")


def _field(key: str) -> str:
    from ..model.damper import FILE_KEYS

    return FILE_KEYS[key]


def _named(damper: Damper, start: Damper) -> Damper:
    from dataclasses import replace

    return replace(damper, name=f"{start.name}-design", source="",
                   description=f"designed by sbcal design from {start.name}")
