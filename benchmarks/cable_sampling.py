"""Time to a converged joint cable posterior, per damper, cable state and family, on the bundled data.

Usage: python benchmarks/cable_sampling.py [--dampers damper1 damper2] [--states dry oiled]
                                           [--laws bouc_wen iwan5] [--seed 1] [--workers 2]

Each (damper, cable state, family) is fitted by :func:`sbcal.inference.cable_fit.fit_cable` with its default
configuration (:func:`sbcal.inference.cable_fit.cable_config`: the engine's convergence policy, 4 ensembles,
R-hat <= 1.01, bulk and tail ESS >= 400, >= 50 autocorrelation times; ``--workers`` processes).
Prints per fit: the wall time (start search + sampling), the CPU time of this process and its
workers, the load average before and after (other work on the machine lengthens the wall time, not
the CPU time), the steps, the largest autocorrelation time, the largest R-hat, the least ESS, the
ELPD (PSIS-LOO by run) with its standard error, and per test the rms error of the posterior-median
curves against the run means (magnitude %, phase deg).
Target (the convergence issue): converged within 3 minutes per cable state on 2 cores.
"""

import argparse
import os
import resource
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.data.labels import state_tests  # noqa: E402
from sbcal.inference.cable_fit import fit_cable  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.laws import fitted_laws  # noqa: E402


def cpu_s() -> float:
    """CPU seconds of this process and its finished children (the sampler's workers)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def median_errors(fit) -> list:
    """Per test: rms of the posterior-median curve against the run means, (magnitude %, phase deg)."""
    like = fit.like
    mus = like.predict(fit.result.flat())
    out = []
    for lk, mu in zip(like.likes, mus):
        d = mu.copy()  # phase about the first draw, so a wrap cannot corrupt the median
        d[1] = mu[1, :1] + np.remainder(mu[1] - mu[1, :1] + np.pi, 2 * np.pi) - np.pi
        r = lk.residual(np.median(d, axis=1)[:, None, :])[:, 0]
        out.append((100 * np.sqrt(np.mean(np.expm1(r[0]) ** 2)), np.degrees(np.sqrt(np.mean(r[1] ** 2)))))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dampers", nargs="*", default=["damper1", "damper2"])
    ap.add_argument("--states", nargs="*", default=["dry", "oiled"])
    ap.add_argument("--laws", nargs="*", default=list(fitted_laws()))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    bench = load_bench(default_bench_path())
    print("wall = start search + sampling [s]; cpu [s] of this process and its workers; load = 1-min average")
    for name in args.dampers:
        damper = resolve_damper(name)
        groups = state_tests(bench.tests(name))
        for state in args.states:
            for law in args.laws:
                tests = groups[state]
                load0, c0, t0 = os.getloadavg()[0], cpu_s(), time.perf_counter()
                fit = fit_cable(damper, clean_bench(bench, dampers=[name]), tests, law, seed=args.seed, workers=args.workers)
                wall, cpu, load1 = time.perf_counter() - t0, cpu_s() - c0, os.getloadavg()[0]
                r = fit.result
                ess = min(r.ess_bulk_min, r.ess_tail_min)
                print(f"{name} {state} {law}: converged {r.converged}, wall {wall:.0f} (start {wall - r.wall_s:.0f}), "
                      f"cpu {cpu:.0f}, load {load0:.1f}->{load1:.1f}, steps {r.n_steps}, tau max {max(r.tau.values()):.1f}, "
                      f"R-hat max {r.r_hat_max:.4f}, ESS min {ess:.0f}, ELPD {fit.loo.elpd:.1f} +- {fit.loo.se:.1f}"
                      + (f"; {r.reason}" if r.reason else ""))
                print("    median curves, rms % / deg: " + ", ".join(
                    f"{t} {m:.2f}/{p:.2f}" for t, (m, p) in zip(tests, median_errors(fit))))
                print("    medians: " + ", ".join(f"{k}={v:.4g}" for k, v in fit.median().items()), flush=True)


if __name__ == "__main__":
    main()
