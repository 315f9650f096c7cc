"""The engine's start on real targets: its local ascents one by one beside side by side (one vectorised call a round).

Usage: python benchmarks/engine_start.py [--damper damper1] [--effects fixture_mass sensor_delay ...] [--seed 0]

For each per-test diagnosis target of the damper (the effects' models, every test), the start's points
(``sbcal.inference.start.start_points``: ``START_ASCENTS`` + 1), then the ascents from
those points two ways in the same run, interleaved target by target: one after the other (each its own calls)
and side by side (``ascend`` on all of them). Reports the wall time of each, their ratio, the target's calls
and the largest difference of the ends (0 when a batch's rows are evaluated as alone). One process, one BLAS
thread; run it on an idle machine.
"""

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.diagnosis.fits import DiagnoseConfig, fit_jobs  # noqa: E402
from sbcal.inference import start  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.extensions import EXTENSIONS  # noqa: E402


class Counted:
    """A target that counts its calls and points."""

    def __init__(self, target):
        self.target, self.prior, self.calls, self.points = target, target.prior, 0, 0

    def __call__(self, z):
        self.calls += 1
        self.points += len(np.atleast_2d(z))
        return self.target(z)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--damper", default="damper1")
    ap.add_argument("--effects", nargs="+", default=["fixture_mass", "sensor_delay", "viscous_damping"],
                    choices=[e for e, ext in EXTENSIONS.items() if not ext.joint])  # per-test models only
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    damper = resolve_damper(args.damper)
    data = clean_bench(load_bench(default_bench_path()), dampers=[damper.name])
    config = DiagnoseConfig(workers=1)
    t_one = t_side = 0.0
    calls_one = calls_side = points_one = points_side = 0
    worst = 0.0
    n = 0
    for effect in args.effects:
        jobs = fit_jobs(effect, (), damper=damper, data=data, tests=data.tests(damper.name), seed=args.seed,
                        config=config, prior_path=None)
        for job in jobs:
            sc = config.sampler(job.target.prior.ndim)
            starts = start.start_points(job.target, np.random.default_rng(job.stream), sc)
            one, side = Counted(job.target), Counted(job.target)
            t0 = time.perf_counter()
            ends_one = [start.ascend(one, z[None])[0] for z in starts]
            t1 = time.perf_counter()
            ends_side = start.ascend(side, starts)
            t2 = time.perf_counter()
            t_one, t_side = t_one + t1 - t0, t_side + t2 - t1
            calls_one, calls_side = calls_one + one.calls, calls_side + side.calls
            points_one, points_side = points_one + one.points, points_side + side.points
            worst = max(worst, max(float(np.abs(a[0] - b[0]).max()) for a, b in zip(ends_one, ends_side)))
            n += 1
            print(f"{job.key}: one by one {t1 - t0:.3f} s ({one.calls} calls), side by side {t2 - t1:.3f} s "
                  f"({side.calls} calls)", flush=True)
    print(f"{n} targets, {len(starts)} ascents each: one by one {t_one:.2f} s, {calls_one} calls, {points_one} points; "
          f"side by side {t_side:.2f} s, {calls_side} calls, {points_side} points; "
          f"{t_one / t_side:.1f}x; largest difference of the ends {worst:.1e} (in z)")


if __name__ == "__main__":
    main()
