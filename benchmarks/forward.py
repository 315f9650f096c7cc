"""Forward-model throughput: frequency lines per second, vectorised vs Appendix C's loop.

Usage: python benchmarks/forward.py [--sets 4096] [--repeat 20]

Prints lines/s of :func:`sbcal.dynamic_stiffness` for a batch of parameter sets on the standard
37-line grid, the same for the per-frequency-loop transcription (:mod:`sbcal.model.reference`) measured
in the same run on a subset of sets, and their ratio. Targets (issue 2): >= 1e7 lines/s on one
core and >= 300x the loop.

Then the time of one call at the sampler's batch sizes (``--batches``, default 1, 32 and 64 sets: emcee's
half-ensembles), the compiled condensation (:mod:`sbcal.model.fem_kernel`) beside the numpy formulation it
replaced (``tests/fem_reference.py``), in the same run: at these sizes the numpy one paid per operation,
not per line.
"""

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from sbcal import STANDARD_GRID_HZ, dynamic_stiffness  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.reference import dynamic_stiffness_loop  # noqa: E402

from _timing import best_time, positive_count  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.fem_reference import impedance_numpy  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=positive_count, default=4096)
    ap.add_argument("--repeat", type=positive_count, default=20)
    ap.add_argument("--loop-sets", type=positive_count, default=30)
    ap.add_argument("--batches", type=positive_count, nargs="+", default=[1, 32, 64], metavar="N",
                    help="sets per call of the small-batch rows (default 1 32 64)")
    args = ap.parse_args()

    d = resolve_damper("damper1")
    rng = np.random.default_rng(0)
    n, f = args.sets, STANDARD_GRID_HZ
    theta = dict(EJ=rng.uniform(1, 113, n), beta=rng.uniform(0, 2.5, n),
                 a1=d.a1 * rng.uniform(0.95, 1.05, n), a2=d.a2 * rng.uniform(0.95, 1.05, n))
    t_vec = best_time(lambda: dynamic_stiffness(d, f, **theta), args.repeat)
    lines = n * f.size
    rate_vec = lines / t_vec

    m = args.loop_sets

    def loop():
        for i in range(m):
            dynamic_stiffness_loop(d, f, EJ=theta["EJ"][i], beta1=theta["beta"][i], beta2=theta["beta"][i],
                                   a1=theta["a1"][i], a2=theta["a2"][i])

    t_loop = best_time(loop, 3)
    rate_loop = m * f.size / t_loop
    print(f"vectorised : {n} sets x {f.size} lines in {t_vec * 1e3:.2f} ms -> {rate_vec:.3g} lines/s")
    print(f"loop (App.C): {m} sets x {f.size} lines in {t_loop * 1e3:.1f} ms -> {rate_loop:.3g} lines/s")
    print(f"ratio      : {rate_vec / rate_loop:.0f}x  (targets: >= 1e7 lines/s, >= 300x)")
    print(f"vectorised, numpy formulation: {n} sets in "
          f"{best_time(lambda: impedance_numpy(d, f, **theta), args.repeat) * 1e3:.2f} ms")
    print("one call at the sampler's batch sizes (EJ, beta, a1, a2 per set; 37 lines):")
    print(f"{'sets':>6} {'compiled [us]':>14} {'numpy [us]':>11} {'ratio':>6}")
    for b in args.batches:
        small = {k: v[:b] for k, v in theta.items()}
        t_c = best_time(lambda: dynamic_stiffness(d, f, **small), 200 * args.repeat)
        t_n = best_time(lambda: impedance_numpy(d, f, **small), 200 * args.repeat)
        print(f"{b:>6} {t_c * 1e6:>14.1f} {t_n * 1e6:>11.1f} {t_n / t_c:>5.1f}x")


if __name__ == "__main__":
    main()
