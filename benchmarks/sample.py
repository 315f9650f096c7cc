"""Time to a converged posterior for one test (theta1), beside two point-fit baselines.

Usage: python benchmarks/sample.py [--test 0.5-0.5] [--damper damper1] [--seed 1] [--bench PATH]

(a) The thesis's workflow: the per-frequency-loop model (Appendix C, sbcal.model.reference) under a
    genetic algorithm with population 500 (scipy's differential evolution stands in for MATLAB's
    ``ga``), run to MATLAB ``ga``'s own stopping rule: stop when the relative change of the best
    fitness over the last 50 generations, ``|f(g-50) - f(g)| / (50 max(1, |f(g)|))``, is at most
    FunctionTolerance 1e-6 (ga's default "totalChange" stall test), or after 500 generations.
(b) Our vectorised point fit (sbcal.inference.point_fit.fit_thesis_cost, the same search on the vectorised model), population
    500, stopped by the same rule.
(c) The full posterior: sbcal.inference.sampler.sample with the default configuration (the convergence policy:
    4 ensembles, R-hat <= 1.01, bulk and tail ESS >= 400, >= 50 autocorrelation times), on 2 cores.

Targets (issue 11, 2-core machine): (c) <= 5 s (goal 3 s), >= 30x faster than (a), within 10x of (b).
"""

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.optimize import differential_evolution  # noqa: E402

from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.inference.calibrate import test_likelihood  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.inference.point_fit import fit_thesis_cost  # noqa: E402
from sbcal.model.reference import dynamic_stiffness_loop  # noqa: E402
from sbcal.inference.sampler import sample  # noqa: E402

POPULATION, MAX_GENERATIONS, STALL, FUNCTION_TOLERANCE = 500, 500, 50, 1e-6


class MatlabStall:
    """MATLAB ``ga``'s stopping rule as a scipy callback (returns True to stop)."""

    def __init__(self):
        self.best = []

    def __call__(self, intermediate_result):
        self.best.append(float(intermediate_result.fun))
        if len(self.best) <= STALL:
            return False
        change = abs(self.best[-STALL - 1] - self.best[-1]) / (STALL * max(1.0, abs(self.best[-1])))
        return change <= FUNCTION_TOLERANCE


def thesis_workflow(like, seed):
    """(a): the per-frequency loop model under the GA, to MATLAB's stall rule; (seconds, generations, cost)."""
    prior = like.prior
    names = prior.model_names
    a = np.exp(like.ybar[0])
    ph = np.degrees(like.ybar[1])
    w3 = np.gradient(like.freq_hz)
    w3 = w3 / w3.mean()

    def cost(v):
        p = dict(zip(names, v))
        fuu = dynamic_stiffness_loop(like.damper, like.freq_hz, EJ=p["EJ"], beta1=p["beta"], beta2=p["beta"],
                                     a1=p["a1"], a2=p["a2"])
        return np.sqrt(0.3 * np.sum(w3 * ((a - abs(fuu)) / a) ** 2)
                       + 0.7 * np.sum(w3 * ((ph - np.degrees(np.angle(fuu))) / ph) ** 2))

    bounds = [prior.box(n)[1:] for n in names]
    stall = MatlabStall()
    t0 = time.perf_counter()
    res = differential_evolution(cost, bounds, popsize=int(np.ceil(POPULATION / len(names))), maxiter=MAX_GENERATIONS,
                                 tol=0, seed=seed, polish=False, init="sobol", callback=stall)
    return time.perf_counter() - t0, len(stall.best), float(res.fun)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--test", default="0.5-0.5")
    ap.add_argument("--damper", default="damper1")
    ap.add_argument("--bench")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    damper = resolve_damper(args.damper)
    bench = load_bench(args.bench or default_bench_path())
    data = clean_bench(bench, dampers=[damper.name])
    like = test_likelihood(damper, data, args.test)
    print(f"{damper.name} {args.test}: {like.y.shape[1]} runs x {like.freq_hz.size} lines "
          f"({len(data.removed_runs(damper.name, args.test))} outlier runs removed)")

    t_c_runs = []
    for k in range(3):  # the posterior three times (different seeds): its wall time varies with tau
        res = sample(like, seed=args.seed + k)
        t_c_runs.append(res.wall_s)
        print(f"(c) posterior, seed {args.seed + k}: {res.wall_s:.2f} s, {res.n_steps} steps x {res.n_chains} "
              f"ensembles; converged {res.converged}; " + "; ".join(
                  f"{n} {np.median(res.draws[n]):.4g} R-hat {res.r_hat[n]:.4f} ESS bulk {res.ess_bulk[n]:.0f} "
                  f"tail {res.ess_tail[n]:.0f}" for n in ("EJ", "beta")))
    t_c = float(np.median(t_c_runs))

    stall = MatlabStall()
    fit = fit_thesis_cost(like, seed=args.seed, population=POPULATION, generations=MAX_GENERATIONS, tol=0,
                          polish=False, callback=stall)
    print(f"(b) vectorised point fit, population {POPULATION}, MATLAB stall rule: {fit.wall_s:.2f} s, "
          f"{fit.generations} generations, {fit.n_evaluations} evaluations, cost {fit.cost:.5g}; "
          + ", ".join(f"{n}={v:.4g}" for n, v in zip(fit.names, fit.x)))

    t_a, gens, cost = thesis_workflow(like, args.seed)
    print(f"(a) thesis workflow: loop model + GA, population {POPULATION}, MATLAB stall rule: {t_a:.0f} s, "
          f"{gens} generations, cost {cost:.5g}")
    print(f"ratios: (a)/(c) = {t_a / t_c:.0f}x (target >= 30x); (c)/(b) = {t_c / fit.wall_s:.1f}x (target <= 10x); "
          f"(c) median {t_c:.2f} s <= 5 s: {t_c <= 5} (goal 3 s)")


if __name__ == "__main__":
    main()
