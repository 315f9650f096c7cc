"""``sbcal batch``: the units of a run store as one design's population."""

from __future__ import annotations

import sys

from .options import quiet_option, seed_value


__all__ = ["add_batch", "cmd_batch"]


def add_batch(sub):
    p = sub.add_parser("batch", help="a lot of dampers as a population: the design, the unit scatter, the outliers",
                       description="Fit the population of the units (dampers) in a run store from their stored "
                                   "per-test posteriors, by reweighting (no new model solves): the design's "
                                   "parameters with bands, the unit-to-unit scatter, the next unit, each unit's "
                                   "shrunk estimate and its probability of being an outlier (docs/batch.md).")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store holding the units (default runs/)")
    p.add_argument("--dampers", nargs="+", metavar="UNIT", help="the units (default: every damper in the store)")
    p.add_argument("--params", nargs="+", default=["EJ", "beta"], metavar="NAME",
                   help="parameters of the population (default EJ beta)")
    p.add_argument("--tests", nargs="+", metavar="LABEL", help="tests (default: every test all units have)")
    p.add_argument("--paramset", default="theta1", metavar="SET", help="parameter set of the stored runs (default theta1)")
    p.add_argument("--cable-states", nargs="+", metavar="STATE",
                   help="cable states whose strand-slip law to pool into the design's cable run (<output>/cable-<state>, "
                        "for sbcal predict/span/design; default: every state all units have a cable fit of; none: skip)")
    p.add_argument("-o", "--output", metavar="DIR", help="where to write (default <runs>/batch)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    quiet_option(p)
    return p


def cmd_batch(args) -> int:
    from ..inference.batch import departures, fit_population, headline, read_lot, write_batch
    from ..inference.store import batch_dir

    lot = read_lot(args.runs, dampers=args.dampers, params=args.params, tests=args.tests, paramset=args.paramset)
    for unit, why in lot.excluded.items():
        print(f"sbcal batch: unit {unit} left out: {why}", file=sys.stderr)
    doc, draws = fit_population(lot, seed=args.seed, progress=None if args.quiet else "population",
                                departing=departures(args.runs, lot))
    doc["command"] = getattr(args, "command_line", "")
    states = _cable_states(args, lot.units)
    out = args.output or batch_dir(args.runs)
    write_batch(out, doc, draws)
    print(headline(doc))
    if doc["converged"]:
        from ..report.lot import forest_figure

        forest_figure(doc, f"{out}/forest.png")
        print(_table(doc))
    print(f"stored in {out}/ (summary.json, population.csv, units.csv, population.nc, forest.png)")
    for cl in states:
        _design_cable(args, cl, out)
    return 0


def _cable_states(args, units) -> list:
    """The cable lots to pool, read (and refused) before anything is written."""
    from ..inference.batch_cable import cable_states, read_cable_lot

    asked = args.cable_states
    if asked and [s.lower() for s in asked] == ["none"]:
        return []
    common, partial = cable_states(args.runs, units)
    if not asked:
        for state, lacking in partial.items():
            print(f"sbcal batch: cable state {state} not pooled: no cable fit of it for {', '.join(lacking)}",
                  file=sys.stderr)
    return [read_cable_lot(args.runs, units, s) for s in (asked or common)]


def _design_cable(args, cl, out) -> None:
    from ..inference.batch import headline
    from ..inference.batch_cable import MIN_KEPT, design_cable, write_design_cable
    from ..inference.store import design_cable_dir

    for unit, why in cl.lot.excluded.items():
        print(f"sbcal batch: unit {unit} left out of cable-{cl.state}: {why}", file=sys.stderr)
    summary, next_unit, hyper = design_cable(cl, seed=args.seed, progress=None if args.quiet else f"cable-{cl.state}")
    summary["command"] = getattr(args, "command_line", "")
    where = write_design_cable(design_cable_dir(out, cl.state), summary, next_unit, hyper)
    print(f"cable {cl.state} ({cl.law}): " + headline(summary["population"]))
    if not summary["converged"]:
        print(f"  {where}: stored for inspection only: the population did not converge (predict and span warn on it)")
        return
    if summary["kept_fraction"] < MIN_KEPT:
        print(f"  warning: {100 * (1 - summary['kept_fraction']):.0f} % of the next unit's draws fell outside the "
              "prior box or the law's domain and were dropped: the population reaches beyond what the units were "
              "fitted under")
    print(f"  the next unit of this design ({summary['n_draws']} draws) stored in {where}/: "
          f"sbcal predict --cable {where} --damper NEW.toml; sbcal span --damper {where}")


def _table(doc) -> str:
    rows = ["  unit            P(outlier)  ESS   " + "  ".join(f"{d:>24}" for d in doc["per_unit"][0]["values"])]
    for u in doc["per_unit"]:
        cells = "  ".join(f"{v['own'][1]:>9.4g} -> {v['shrunk'][1]:<11.4g}" for v in u["values"].values())
        flag = "  FLAGGED" if u["flagged"] else ""
        rows.append(f"  {u['unit']:<15} {u['outlier_probability']:>10.2f}  {u['ess_median']:>4.0f}   {cells}{flag}")
    rows.append("  (each unit's own median -> shrunk towards the lot; P(outlier): posterior probability of the "
                "two-component population; ESS: its draws' effective size under the population)")
    return "\n".join(rows)
