"""Could the diagnosis take the sample stage's stored posteriors as its baseline? No: they are another model.

Usage: python benchmarks/diagnose_baseline.py --runs RUNS [--damper damper1] [--tests 0.1-0.1 0.5-0.5 2-2]

``RUNS`` is a run store made by ``sbcal run`` (or ``sbcal sample``) on the bundled data. For each test
this fits the diagnosis's own per-test baseline (theta1 under the noise-only likelihood, as ``sbcal
diagnose`` does, seed 0) and evaluates the stored posterior (theta1 *with* the model-error scales) under
that same noise-only likelihood. It prints EJ (median, 90 %) of both and the PSIS-LOO ELPD of both:
the ELPD the stored draws lose is what every extension's ELPD difference would gain if they were the
baseline. It also times the baseline fits (2 processes, as a diagnosis runs them).
"""

import argparse
import time

import numpy as np

from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import default_bench_path, load_bench
from sbcal.diagnosis.fits import DiagnoseConfig, fit_jobs, run_fits
from sbcal.inference.stats import loo, read_netcdf
from sbcal.inference.store import POSTERIOR, run_dir
from sbcal.model.damper import resolve_damper


def _interval(v) -> str:
    return f"{np.median(v):.3f} [{np.quantile(v, 0.05):.3f}, {np.quantile(v, 0.95):.3f}]"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True, help="run store of 'sbcal run' on the bundled data")
    ap.add_argument("--damper", default="damper1")
    ap.add_argument("--tests", nargs="+", default=None, help="default: all of the damper's")
    args = ap.parse_args(argv)
    damper = resolve_damper(args.damper)
    data = clean_bench(load_bench(default_bench_path()), dampers=[damper.name])
    tests = args.tests or data.tests(damper.name)
    config = DiagnoseConfig(workers=2)
    t0 = time.perf_counter()
    jobs = fit_jobs("baseline", (), damper=damper, data=data, tests=tests, seed=0, config=config, prior_path=None)
    fits = run_fits(jobs, config, None)
    print(f"{damper.name}: {len(jobs)} noise-only baseline fits in {time.perf_counter() - t0:.1f} s")
    lost = 0.0
    for job in jobs:
        t, fit = job.key[1], fits[job.key]
        post = read_netcdf(run_dir(args.runs, damper.name, t, "theta1") / POSTERIOR).posterior
        draws = {k: np.asarray(post[k]).ravel() for k in ("beta", "a1", "a2", "EJ")}
        idx = np.linspace(0, draws["EJ"].size - 1, 1000).astype(int)  # evenly over the chains
        stored = loo(job.target.pointwise_log_likelihood({k: v[idx] for k, v in draws.items()})[None]).pointwise.sum()
        own = fit["loo"].pointwise.sum()
        lost += own - stored
        print(f"{t}: EJ baseline {_interval(fit['params']['EJ'])}, stored {_interval(draws['EJ'])} N m^2; "
              f"stored sigma_mag {np.median(np.asarray(post['sigma_mag'])):.3f}; ELPD baseline {own:.1f}, "
              f"stored draws {stored:.1f} (lost {own - stored:.1f})")
    print(f"ELPD the stored draws lose over these tests: {lost:.0f} nats")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
