"""Simulation-based calibration (Talts et al. 2018) of the theta1 posterior, through the pipeline.

Usage: python benchmarks/calibration_coverage.py [--datasets 100] [--workers 2] [--seed 2026] [--runs 12]

For each data set: draw theta and the model-error scales from the prior, simulate a test (runs =
model + a discrepancy shared by the runs + run noise largest at 4-15 Hz, on a geometry unlike the
bundled dampers), and fit it exactly as ``sbcal sample`` does: the pipeline's noise model and
likelihood (:func:`sbcal.inference.calibrate.likelihood_for` on the runs as :class:`sbcal.data.bench.TestData`) and
the engine under the convergence policy. Records the rank of the true value among thinned posterior
draws. Prints, per parameter, the coverage of the central 50 % and 90 % intervals with their binomial
standard error, and a chi-square test of uniform ranks.
"""

import argparse
import os
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.stats import chisquare  # noqa: E402

from sbcal import STANDARD_GRID_HZ as F, dynamic_stiffness  # noqa: E402
from sbcal.data.bench import TestData  # noqa: E402
from sbcal.inference.calibrate import likelihood_for  # noqa: E402
from sbcal.model.damper import Damper  # noqa: E402
from sbcal.inference.priors import load_prior  # noqa: E402
from sbcal.inference.sampler import SamplerConfig, sample  # noqa: E402

DAMPER = Damper(name="sbc", m1=2.6, J1=0.012, a1=0.024, m2=2.1, J2=0.007, a2=-0.018, mc=0.9, Jc=0.0012,
                ac=0.0, L1=0.22, L2=0.17, mu=0.48, ej_static=100.0)
CONFIG = SamplerConfig(nwalkers=16, max_draws=500, de_population=30, de_generations=80, workers=1)
N_RANK = 99  # draws per rank: ranks take values 0..99


def one(args):
    k, seed, n_runs = args
    rng = np.random.default_rng(np.random.SeedSequence([seed, k]))
    prior = load_prior("theta1", DAMPER)
    truth = {n: float(v[0]) for n, v in prior.params(prior.sample(rng, 1)).items()}
    fuu = dynamic_stiffness(DAMPER, F, **{n: truth[n] for n in prior.model_names})[0]
    sig = np.stack([np.where(F < 15, 0.03, 0.012), np.where(F < 15, 0.02, 0.008)])
    mu = np.stack([np.log(np.abs(fuu)), np.angle(fuu)])
    delta = np.array([truth["sigma_mag"], truth["sigma_phase"]])[:, None] * rng.standard_normal((2, F.size))
    y = mu[:, None] + delta[:, None] + sig[:, None] * rng.standard_normal((2, n_runs, F.size))
    data = TestData("sbc", "sim", np.arange(1, n_runs + 1), F, np.full(F.size, 0.5), np.exp(y[0]), np.degrees(y[1]))
    like = likelihood_for(DAMPER, data, prior)
    res = sample(like, seed=int(rng.integers(2**31)), config=CONFIG)
    flat = res.flat()
    keep = np.linspace(0, flat[prior.names[0]].size - 1, N_RANK).round().astype(int)
    ranks = np.array([np.sum(flat[n][keep] < truth[n]) for n in prior.names])
    return ranks, res.converged


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--runs", type=int, default=12)
    args = ap.parse_args()
    jobs = [(k, args.seed, args.runs) for k in range(args.datasets)]
    with ProcessPoolExecutor(args.workers) as pool:
        out = list(pool.map(one, jobs))
    ranks = np.array([r for r, _ in out])
    n = len(ranks)
    names = load_prior("theta1", DAMPER).names
    print(f"{n} data sets of {args.runs} runs, {sum(c for _, c in out)} converged; ranks over {N_RANK} draws")
    for level in (0.5, 0.9):
        se = np.sqrt(level * (1 - level) / n)
        lo, hi = (1 - level) / 2 * (N_RANK + 1), (1 + level) / 2 * (N_RANK + 1)
        cov = np.mean((ranks >= lo) & (ranks < hi), axis=0)
        print(f"{int(level * 100)} % intervals: " + ", ".join(f"{nm} {c:.2f}" for nm, c in zip(names, cov))
              + f"  (nominal {level:.2f} +- {se:.2f} binomial s.e.)")
    bins = 10
    for j, nm in enumerate(names):
        counts = np.bincount(np.minimum(ranks[:, j] * bins // (N_RANK + 1), bins - 1), minlength=bins)
        print(f"rank histogram {nm:12s} {counts.tolist()}  chi2 p = {chisquare(counts).pvalue:.3f}")


if __name__ == "__main__":
    main()
