"""The sampling engine's own cost per step: its compiled moves beside their numpy formulation, in one run.

Usage: python benchmarks/engine_step.py [--test 0.5-0.5] [--damper damper1] [--seed 1] [--repeat 200]

(a) One half-step's proposals for 4 ensembles of 24 walkers (12 moving each), at 4, 9 and 17 parameters:
    :func:`sbcal.inference.move_kernel.half_step` against ``tests/move_reference.py`` (the same proposals,
    numpy over stacked arrays), best of ``--repeat``.
(b) A test's posterior (sbcal.inference.sampler.sample, one process) with each, interleaved, twice: wall
    time, steps, a step's time and its part outside the likelihood (emcee's loop, the random numbers, the
    moves). The two give the same draws to rounding (the same random numbers).
"""

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sbcal.core.errors import InputError  # noqa: E402
from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.inference import sampler  # noqa: E402
from sbcal.inference.calibrate import test_likelihood  # noqa: E402
from sbcal.inference.move_kernel import half_step, stack_proposals  # noqa: E402
from sbcal.inference.proposal import BOX_TRIES, T_DOF, MapProposal  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402

from _timing import best_time, positive_count  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.move_reference import half_step_numpy  # noqa: E402


def arguments(ndim, rng, n_ens=4, walkers=24):
    """A half-step's inputs at ``ndim`` parameters: random walkers, proposals and random numbers."""
    half = walkers // 2
    coords = rng.standard_normal((n_ens * walkers, ndim))
    perms = np.stack([rng.permutation(walkers) for _ in range(n_ens)]) + walkers * np.arange(n_ens)[:, None]
    a = rng.standard_normal((ndim, ndim)) / np.sqrt(ndim)
    props = [MapProposal.ellipsoid(0.1 * rng.standard_normal(ndim), a @ a.T + np.eye(ndim)) for _ in range(n_ens)]
    tries = BOX_TRIES + 1
    # the prior box 3 sd out on every parameter: most first tries inside, some redrawn (a posterior near a bound)
    return (coords, perms[:, :half], perms[:, half:], rng.random((n_ens, 6, half)), rng.standard_normal((n_ens, half)),
            2.38 / np.sqrt(2 * ndim), 0.5, rng.standard_normal((n_ens, tries, half, ndim)),
            rng.chisquare(T_DOF, (n_ens, tries, half)), np.full(ndim, -4.0), np.full(ndim, 4.0),
            *stack_proposals(props, ndim, T_DOF))


class Timed:
    """A target that adds up the time spent in it while the ensembles step (the likelihood), to take it off."""

    def __init__(self, target):
        self.target, self.prior, self.seconds, self.stepping = target, target.prior, 0.0, False

    def __call__(self, z):
        t0 = time.perf_counter()
        out = self.target(z)
        if self.stepping:
            self.seconds += time.perf_counter() - t0
        return out

    def pointwise_log_likelihood(self, params):
        return self.target.pointwise_log_likelihood(params)


def stepped(target, seconds):
    """``sampler._advance`` timed: the wall time of the ensembles' steps goes to ``seconds[0]``."""
    advance = sampler._advance

    def run(job):
        target.stepping = True
        t0 = time.perf_counter()
        try:
            return advance((target,) + tuple(job[1:]))
        finally:
            seconds[0] += time.perf_counter() - t0
            target.stepping = False
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--test", default="0.5-0.5")
    ap.add_argument("--damper", default="damper1")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=positive_count, default=200)
    args = ap.parse_args(argv)
    try:
        damper = resolve_damper(args.damper)
        data = clean_bench(load_bench(default_bench_path()), dampers=[damper.name])
        like = test_likelihood(damper, data, args.test)
    except InputError as exc:  # an unknown damper or test: one line, exit 2
        ap.error(str(exc))
    rng = np.random.default_rng(args.seed)

    print("(a) one half-step, 4 ensembles x 12 moving walkers, 9 box tries each (best of "
          f"{args.repeat}; first call compiles):")
    t0 = time.perf_counter()
    half_step(*arguments(4, rng))
    print(f"    first call {time.perf_counter() - t0:.2f} s (compile or load from the disk cache)")
    for ndim in (4, 9, 17):
        inputs = arguments(ndim, rng)
        qc, lc = half_step(*inputs)
        qn, ln = half_step_numpy(*inputs)
        err = max(np.abs(qc - qn).max(), np.abs(lc - ln).max())
        tc = best_time(lambda: half_step(*inputs), args.repeat)
        tn = best_time(lambda: half_step_numpy(*inputs), args.repeat)
        print(f"    {ndim:2d} parameters: compiled {1e6 * tc:6.1f} us, numpy {1e6 * tn:6.1f} us, "
              f"{tn / tc:4.1f}x; largest difference {err:.1e}")

    config = sampler.SamplerConfig(workers=1)
    print(f"(b) {damper.name} {args.test}'s posterior, one process:")
    compiled, advance = sampler.half_step, sampler._advance
    results, per_step = {}, {}
    for name, fn in (("numpy", half_step_numpy), ("compiled", compiled)) * 2:  # interleaved, best of two
        target, seconds = Timed(like), [0.0]
        sampler.half_step, sampler._advance = fn, stepped(target, seconds)
        try:
            res = sampler.sample(target, seed=args.seed, config=config)
        finally:
            sampler.half_step, sampler._advance = compiled, advance
        results.setdefault(name, res)
        step = (seconds[0] - target.seconds) / res.n_steps
        per_step[name] = min(per_step.get(name, np.inf), step)
        print(f"    {name:8s}: {res.wall_s:.2f} s, {res.n_steps} steps, converged {res.converged}; a step "
              f"{1e6 * seconds[0] / res.n_steps:.0f} us, of which outside the likelihood {1e6 * step:.0f} us")
    print(f"    outside the likelihood, best of two: compiled {1e6 * per_step['compiled']:.0f} us a step, numpy "
          f"{1e6 * per_step['numpy']:.0f} us ({per_step['numpy'] / per_step['compiled']:.1f}x)")
    same = all(np.allclose(results["compiled"].draws[n], results["numpy"].draws[n], rtol=1e-9, atol=0)
               for n in results["compiled"].names)
    print(f"    the two engines' draws equal to 1e-9: {same}")


if __name__ == "__main__":
    main()
