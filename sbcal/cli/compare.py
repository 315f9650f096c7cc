"""``sbcal compare``: did the damper change? Two characteristic tests as a probability (docs/compare.md)."""

from __future__ import annotations

import sys

from ..core.errors import InputError
from .options import quiet_option, seed_value


__all__ = ["add_compare", "cmd_compare"]


def add_compare(sub):
    p = sub.add_parser("compare", help="did the damper change? before/after characteristic tests, as a probability",
                       description="The characteristic of IEC 61897 (impedance, power dissipated, resonances) of two "
                                   "calibrated dampers or states, the change as a posterior, and with an acceptance "
                                   "file the probability that it stays within each tolerance and a decision: pass at "
                                   "P(within) >= 0.95, fail at P(beyond) >= 0.95, else inconclusive (docs/compare.md).")
    p.add_argument("--before", required=True, metavar="RUN",
                   help="<runs>/<damper>[@state] (a calibrated damper) or a bench file[@state] (calibrated first)")
    p.add_argument("--after", required=True, metavar="RUN", help="the same, after (fatigue, service, another unit)")
    p.add_argument("--spec", metavar="ACCEPTANCE.toml",
                   help="quantities, tolerances, excitation and frequency range (without: the change, no decision)")
    p.add_argument("--damper", metavar="NAME|PATH", help="the damper of a bench-file RUN that is not bundled")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="run store a bench-file RUN is calibrated into (default runs/)")
    p.add_argument("--paramset", default="theta1", metavar="SET", help="parameter set of the tests' posteriors (default theta1)")
    p.add_argument("--draws", type=int, default=1000, metavar="N", help="posterior draws per side (default 1000)")
    p.add_argument("-o", "--output", metavar="DIR", help="where to write (default <runs>/compare/<before>-vs-<after>)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    quiet_option(p)
    return p


def cmd_compare(args) -> int:
    from ..design.acceptance import read_acceptance
    from ..design.compare_runs import RunRef, compare_runs
    from ..design.compare_store import store_comparisons
    from ..inference.runs import versions
    from ..inference.store import compare_dir
    from ..pipeline import Settings, calibrate_bench

    if args.draws < 50:
        raise InputError(f"--draws {args.draws}: expected an integer >= 50")
    acc = read_acceptance(args.spec) if args.spec else None
    settings = Settings(paramset=args.paramset, seed=args.seed)
    amplitude = acc.level if acc is not None and acc.mode == "amplitude" else None

    def calibrate(path, state, text):
        store, name = calibrate_bench(path, state, runs=args.runs, settings=settings, damper=args.damper,
                                      amplitude=amplitude, progress=not args.quiet)
        return RunRef(str(store), name, state, text)

    comparisons, warnings = compare_runs(args.before, args.after, acc, paramset=args.paramset, n_draws=args.draws,
                                         seed=args.seed, calibrate=calibrate)
    for w in warnings:
        print(f"sbcal compare: warning: {w}", file=sys.stderr)
    before, after = comparisons[0].before, comparisons[0].after
    out = args.output or compare_dir(args.runs, f"{_tag(args.before, before)}-vs-{_tag(args.after, after)}")
    meta = {"before": args.before, "after": args.after, "spec": args.spec, "seed": args.seed, "draws": args.draws,
            "warnings": warnings, "command": getattr(args, "command_line", ""), "versions": versions()}
    store_comparisons(comparisons, out, meta=meta)
    for c in comparisons:
        print(c.headline())
        print(_table(c))
        for note in c.notes:
            print(f"  note: {note}")
    print(f"stored in {out}/ (summary.json, criteria.csv, curves.csv, compare.png)")
    return 0


def _tag(text: str, side) -> str:
    """A RUN's part of the output's name: the damper (a stored run) or the file's stem (a bench file), and the state."""
    from pathlib import Path

    path = text.partition("@")[0]
    name = Path(path).name.split(".")[0] if Path(path).is_file() else side.damper
    return name if side.state == "dry" else f"{name}-{side.state}"


def _table(c) -> str:
    import math

    rows = [f"  {'criterion':<42} {'change [q05, median, q95]':>30} {'tolerance':>10} {'P(within)':>9}  verdict"]
    for k in c.criteria:
        lo, med, hi = k.change
        band = f"{med:+7.1f} [{lo:+.1f}, {hi:+.1f}] {k.unit}" if math.isfinite(med) else "—"
        tol = f"±{k.tolerance:g}" if k.tolerance is not None else "—"
        p = f"{k.p_within:.2f}" if k.p_within is not None else "—"
        need = f" (about {k.runs_needed} runs per test would decide it)" if k.runs_needed else ""
        note = f" ({k.note})" if k.note else ""
        rows.append(f"  {k.name:<42} {band:>30} {tol:>10} {p:>9}  {k.verdict}{need}{note}")
    return "\n".join(rows)
