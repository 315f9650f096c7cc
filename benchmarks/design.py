"""Design and life: the wall time of one service-life estimate with bands, of a design search of free
damper fields (with 1 and 2 workers), and the search's best against a random search of the same space.

Usage: python benchmarks/design.py --cable RUN [--budget 120] [--random 100] [--workers 1 2] [--seed 0]

``RUN`` is a stored cable fit (``runs/damper1/cable-dry`` from ``sbcal run`` on the bundled data). On
Drake with damper 1 as the starting design:

1. **Life**: ``span_study`` with damper 1 at 1.1 m, 200 draws, 60 lines, and the service life under a
   Weibull climate (k = 2, c = 4.5 m/s), against the same study without the life (the baseline,
   measured in the same run). Target (issue): one life estimate with bands under 30 s.
2. **Design**: four free fields (both masses, both arm lengths) under a total-mass and an arm-length
   constraint, ``--budget`` designs on the default search grid (20 draws, 30 lines, 12 positions), then
   the start and the best evaluated as ``sbcal span --optimise`` (200 draws, 60 lines); once per
   ``--workers`` value. Target: under 10 minutes on 2 cores. Also how the time scales with the workers.
3. **Random search**: ``--random`` designs drawn uniformly in the same box (the same seed), the
   feasible ones evaluated on the same search grid: its best objective against the search's best.
"""

import argparse
import time

import numpy as np

from sbcal.core.workers import one_blas_thread
from sbcal.design.conductor import resolve_conductor
from sbcal.design.search import Search, design, evaluate_design
from sbcal.design.space import parse_space
from sbcal.design.span_study import span_study
from sbcal.model.damper import resolve_damper

SPACE = {"vary": {"mass1.mass_kg": [1.5, 4.5], "mass2.mass_kg": [1.0, 4.0],
                  "cable.length1_m": [0.12, 0.30], "cable.length2_m": [0.10, 0.25]},
         "constraints": {"total_mass_kg_max": 9.0, "arm_length_sum_m_max": 0.5}}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cable", required=True, metavar="RUN")
    ap.add_argument("--budget", type=int, default=120)
    ap.add_argument("--random", type=int, default=100)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-life", action="store_true", help="skip part 1")
    args = ap.parse_args()

    c, start = resolve_conductor("drake"), resolve_damper("damper1")
    if not args.skip_life:
        span_study(c, args.cable, position_m=1.1, n_freq=4, n_draws=4)  # warm up: imports, the run's first read
        t0 = time.perf_counter()
        span_study(c, args.cable, position_m=1.1)
        t_span = time.perf_counter() - t0
        t0 = time.perf_counter()
        study = span_study(c, args.cable, position_m=1.1, climate="weibull:k=2,c=4.5")
        t_life = time.perf_counter() - t0
        print(f"life: span study with the life {t_life:.1f} s, without {t_span:.1f} s "
              f"(ratio {t_life / t_span:.2f}); years {study.life.to_dict()['years']}, bare "
              f"{study.life.years_bare:.3g}")

    space = parse_space(SPACE, start, "benchmark space")
    found = None
    for w in args.workers:
        t0 = time.perf_counter()
        res = design(c, args.cable, start, space, budget=args.budget, seed=args.seed, workers=w, progress=False)
        wall = time.perf_counter() - t0
        search_best = max(r["objective"] for r in res.records if not r["extrapolated"])
        print(f"design: {len(space.fields)} free fields, {len(res.records)} designs "
              f"({res.optimiser['generations']} generations), workers {w}: {wall:.0f} s "
              f"({wall / len(res.records):.2f} s per design incl. the final pair); start q10 "
              f"{res.start['objective']:.4f}, best q10 {res.best['objective']:.4f} at {res.best['fields']}; "
              f"search-grid best {search_best:.4f}")
        found = found or (res, search_best)
    res, search_best = found

    if args.random <= 0:
        return
    rng = np.random.default_rng(args.seed)
    lo, hi = np.array(space.lower), np.array(space.upper)
    grid = Search()
    t0 = time.perf_counter()
    best, n_eval = -np.inf, 0
    for x in lo + (hi - lo) * rng.random((args.random, lo.size)):
        d = space.damper(start, x)
        if not space.feasible(d):
            continue
        r = evaluate_design(c, args.cable, d, n_draws=grid.n_draws, n_freq=grid.n_freq, n_positions=grid.n_positions,
                            seed=args.seed)
        n_eval += 1
        if not r["extrapolated"]:
            best = max(best, r["objective"])
    print(f"random search: {args.random} designs drawn, {n_eval} feasible evaluated in "
          f"{time.perf_counter() - t0:.0f} s (1 process): best q10 {best:.4f} against the search's {search_best:.4f} "
          f"({'search at least as good' if search_best >= best else 'RANDOM SEARCH BETTER'})")


if __name__ == "__main__":
    with one_blas_thread():  # as every sbcal command runs (sbcal/core/workers.py)
        main()
