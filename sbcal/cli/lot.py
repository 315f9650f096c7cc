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
    out = args.output or batch_dir(args.runs)
    write_batch(out, doc, draws)
    print(headline(doc))
    if doc["converged"]:
        from ..report.lot import forest_figure

        forest_figure(doc, f"{out}/forest.png")
        print(_table(doc))
    print(f"stored in {out}/ (summary.json, population.csv, units.csv, population.nc, forest.png)")
    return 0


def _table(doc) -> str:
    rows = ["  unit            P(outlier)  ESS   " + "  ".join(f"{d:>24}" for d in doc["per_unit"][0]["values"])]
    for u in doc["per_unit"]:
        cells = "  ".join(f"{v['own'][1]:>9.4g} -> {v['shrunk'][1]:<11.4g}" for v in u["values"].values())
        flag = "  FLAGGED" if u["flagged"] else ""
        rows.append(f"  {u['unit']:<15} {u['outlier_probability']:>10.2f}  {u['ess_median']:>4.0f}   {cells}{flag}")
    rows.append("  (each unit's own median -> shrunk towards the lot; P(outlier): posterior probability of the "
                "two-component population; ESS: its draws' effective size under the population)")
    return "\n".join(rows)
