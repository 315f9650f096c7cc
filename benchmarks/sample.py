"""Time to a converged posterior for one test (theta1), beside two point-fit baselines.

Usage: python benchmarks/sample.py [--test 0.5-0.5] [--damper damper1] [--seed 1] [--bench PATH]

(a) The thesis's workflow: the per-frequency-loop model (Appendix C, sbcal.reference) under a
    genetic algorithm with population 500. A few generations are timed and extrapolated to the
    thesis's budget of up to 500 generations (said so in the output).
(b) Our vectorised differential-evolution point fit (sbcal.ga) with the same population, run to
    its own convergence (tol 1e-6, at most 500 generations).
(c) The full posterior: sbcal.sampler.sample with the default configuration, checked for
    R-hat <= 1.01 and bulk ESS >= 1000 for EJ and beta.

Targets (issue 4, 2-core machine): (c) <= 10 s, >= 30x faster than (a), within 10x of (b).
"""

import argparse
import os
import time
import warnings

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.optimize import differential_evolution  # noqa: E402

from sbcal.bench import default_bench_path, load_bench  # noqa: E402
from sbcal.calibrate import test_likelihood  # noqa: E402
from sbcal.damper import resolve_damper  # noqa: E402
from sbcal.ga import fit_ga  # noqa: E402
from sbcal.reference import dynamic_stiffness_loop  # noqa: E402
from sbcal.sampler import sample  # noqa: E402


def thesis_ga_per_generation(like, population, generations, seed):
    """Seconds per generation of a GA on the per-frequency-loop model (not vectorised)."""
    prior = like.prior
    names = prior.model_names
    im = [prior.names.index(n) for n in names]
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

    bounds = list(zip(prior.lower[im], prior.upper[im]))
    t0 = time.perf_counter()
    res = differential_evolution(cost, bounds, popsize=int(np.ceil(population / len(im))), maxiter=generations,
                                 tol=0, seed=seed, polish=False, init="sobol")
    wall = time.perf_counter() - t0
    # the initial population is one generation's worth of evaluations
    return wall / (res.nit + 1), res.nfev / (res.nit + 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--test", default="0.5-0.5")
    ap.add_argument("--damper", default="damper1")
    ap.add_argument("--bench")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--ga-generations-timed", type=int, default=2)
    args = ap.parse_args()
    damper = resolve_damper(args.damper)
    bench = load_bench(args.bench or default_bench_path())
    like, cleaned = test_likelihood(damper, bench, args.test)
    print(f"{damper.name} {args.test}: {len(cleaned.data.runs)} runs x {like.freq_hz.size} lines "
          f"({len(cleaned.removed_runs)} outlier runs removed)")

    t_gen, evals = thesis_ga_per_generation(like, 500, args.ga_generations_timed, args.seed)
    t_a = 500 * t_gen
    print(f"(a) thesis workflow: loop model + GA, population 500: {t_gen:.2f} s/generation "
          f"({evals:.0f} evaluations), timed over {args.ga_generations_timed} generations; "
          f"extrapolated to 500 generations: {t_a:.0f} s")

    fit = fit_ga(like, seed=args.seed, population=500, generations=500)
    print(f"(b) vectorised DE point fit, population 500: {fit.wall_s:.2f} s, {fit.generations} generations, "
          f"{fit.n_evaluations} evaluations; " + ", ".join(f"{n}={v:.4g}" for n, v in zip(fit.names, fit.x)))

    from sbcal.runs import summarize, to_inference_data

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = sample(like, seed=args.seed)
    idata = to_inference_data(res, like, runs=cleaned.data.runs, removed_runs=cleaned.removed_runs,
                              seed=args.seed, meta={})
    s = summarize(idata, res)["parameters"]
    t_c = res.wall_s
    ok = all(s[n]["r_hat"] <= 1.01 and s[n]["ess_bulk"] >= 1000 for n in ("EJ", "beta"))
    print(f"(c) posterior (emcee, {res.x.shape[0]} ensembles): {t_c:.2f} s; " + "; ".join(
        f"{n} {s[n]['median']:.4g} [{s[n]['q05']:.4g}, {s[n]['q95']:.4g}] R-hat {s[n]['r_hat']:.4f} "
        f"ESS {s[n]['ess_bulk']:.0f}" for n in ("EJ", "beta")) + f"; converged: {ok}")
    print(f"ratios: (a)/(c) = {t_a / t_c:.0f}x (target >= 30x); (c)/(b) = {t_c / fit.wall_s:.1f}x "
          f"(target <= 10x); (c) <= 10 s: {t_c <= 10}")


if __name__ == "__main__":
    main()
