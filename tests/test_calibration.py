"""Posterior predictive checks on data simulated from the model with known parameters.

Geometry (``other_damper``), parameter values and seeds differ from the bundled data. Tolerances
come from the number of trials: with K data sets and nominal coverage p, the count of intervals
that contain the truth is Binomial(K, p) when the posterior is calibrated; we fail only below the
count whose lower-tail probability is < 0.5 %.
"""

import numpy as np
import pytest
from scipy.stats import binom

from sbcal import STANDARD_GRID_HZ, dynamic_stiffness
from sbcal.likelihood import TestLikelihood
from sbcal.priors import load_prior
from sbcal.sampler import SamplerConfig, sample

F = STANDARD_GRID_HZ
FAST = SamplerConfig(nwalkers=16, n_ensembles=2, tau_factor=30, check_every=200, max_draws=500,
                     ga_population=40, ga_generations=100)


def simulate(damper, truth, n_runs, rng):
    """Runs scattered around the model: log-magnitude and phase noise largest at 4-15 Hz."""
    fuu = dynamic_stiffness(damper, F, **truth)[0]
    sm = np.where(F < 15, 0.03, 0.012)
    sp = np.where(F < 15, 0.02, 0.008)
    mag = np.exp(np.log(np.abs(fuu)) + sm * rng.standard_normal((n_runs, F.size)))
    ph = np.degrees(np.angle(fuu) + sp * rng.standard_normal((n_runs, F.size)))
    return mag, ph


def draw_truth(damper, rng):
    return dict(EJ=float(np.exp(rng.uniform(np.log(4), np.log(40)))), beta=float(rng.uniform(0.1, 0.6)),
                a1=damper.a1 * float(rng.uniform(0.96, 1.04)), a2=damper.a2 * float(rng.uniform(0.96, 1.04)))


def run_trials(damper, n_trials, seed, n_fit=10, n_held=4):
    rng = np.random.default_rng(seed)
    prior = load_prior("theta1", damper)
    covered = {n: 0 for n in ("EJ", "beta", "a1", "a2")}
    band_cover = []
    for k in range(n_trials):
        truth = draw_truth(damper, rng)
        mag, ph = simulate(damper, truth, n_fit + n_held, rng)
        fit_m, fit_p, held_m, held_p = mag[:n_fit], ph[:n_fit], mag[n_fit:], ph[n_fit:]
        # noise model from the repeats, as the pipeline does: per-line standard deviation
        like = TestLikelihood(damper, prior, F, fit_m, fit_p, np.log(fit_m).std(axis=0, ddof=1),
                              np.radians(fit_p).std(axis=0, ddof=1))
        res = sample(like, seed=seed * 1000 + k, config=FAST)
        assert res.converged
        for n in covered:
            v = res.x[..., res.names.index(n)].ravel()
            lo, hi = np.quantile(v, [0.05, 0.95])
            covered[n] += lo <= truth[n] <= hi
        pred = like.predictive(res.x.reshape(-1, res.x.shape[-1]), np.random.default_rng(k))
        lo, hi = np.quantile(pred, [0.05, 0.95], axis=1)  # (2, F)
        held = np.stack([np.log(held_m), np.radians(held_p)])  # (2, n_held, F)
        band_cover.append(np.mean((held >= lo[:, None]) & (held <= hi[:, None])))
    return covered, np.array(band_cover)


def min_count(n, p=0.9, alpha=0.005):
    """Smallest count not rejected at lower-tail probability alpha under Binomial(n, p)."""
    return int(binom.ppf(alpha, n, p))


def check(covered, band_cover, n_trials):
    floor = min_count(n_trials)
    for name, c in covered.items():
        assert c >= floor, f"{name}: 90 % interval covered the truth {c}/{n_trials} times (< {floor})"
    # held-out runs: per-trial coverage fractions; their mean must agree with 0.9 within 3 standard errors
    se = band_cover.std(ddof=1) / np.sqrt(len(band_cover))
    assert abs(band_cover.mean() - 0.9) < 3 * se + 0.01, (band_cover.mean(), se)


def test_credible_intervals_and_predictive_bands_cover(other_damper):
    n = 8
    covered, band = run_trials(other_damper, n, seed=41)
    check(covered, band, n)


@pytest.mark.slow
def test_coverage_many_trials(other_damper):
    n = 40
    covered, band = run_trials(other_damper, n, seed=97)
    check(covered, band, n)
