"""Forward-model throughput: frequency lines per second, vectorised vs Appendix C's loop.

Usage: python benchmarks/forward.py [--sets 4096] [--repeat 20]

Prints lines/s of :func:`sbcal.dynamic_stiffness` for a batch of parameter sets on the standard
37-line grid, the same for the per-frequency-loop transcription (:mod:`sbcal.model.reference`) measured
in the same run on a subset of sets, and their ratio. Targets (issue 2): >= 1e7 lines/s on one
core and >= 300x the loop.
"""

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from sbcal import STANDARD_GRID_HZ, dynamic_stiffness  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.reference import dynamic_stiffness_loop  # noqa: E402

from _timing import best_time  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=4096)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--loop-sets", type=int, default=30)
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


if __name__ == "__main__":
    main()
