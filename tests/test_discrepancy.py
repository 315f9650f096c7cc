"""The true mean curve given the runs (sbcal.inference.discrepancy): the closed-form posterior, the runs'
error covariance with few runs and with re-clamped runs, phases across +-pi."""

import numpy as np
import pytest

from sbcal.inference.discrepancy import _mean_error_cov, true_mean_draws
from sbcal.model.fem import STANDARD_GRID_HZ

F = STANDARD_GRID_HZ.size


def test_independent_noise_gives_the_normal_posterior():
    # delta | y ~ N(w r, w v) per line, w = s^2 / (s^2 + v), v = sigma^2 / n
    rng = np.random.default_rng(3)
    R, S, sig, s = 24, 4000, 0.03, 0.02
    y = 0.05 + sig * rng.standard_normal((R, F))
    draws = true_mean_draws(np.zeros((S, F)), np.full(S, s), y, np.full(F, sig**2), wrap=False, rng=rng)
    ybar, v = y.mean(0), np.maximum(y.var(0, ddof=1), sig**2) / R
    w = s**2 / (s**2 + v)
    # 4000 draws: a line's mean to 1.6 % of its sd, its variance to 2.2 %; the shrunk correlations (lambda
    # near 1 for independent runs, not 1) move each line by a few % more
    assert np.median(np.abs(draws.mean(0) - w * ybar) / np.sqrt(w * v)) < 0.1
    assert np.median(draws.var(0) / (w * v)) == pytest.approx(1.0, abs=0.06)


def test_a_large_discrepancy_follows_the_run_mean_with_its_error():
    # s >> sigma / sqrt(n): the curve is the run mean, whatever the model says, spread as the mean's error
    rng = np.random.default_rng(4)
    R, S, sig = 10, 4000, 0.02
    y = 0.3 + sig * rng.standard_normal((R, F))
    draws = true_mean_draws(np.full((S, F), -0.2), np.full(S, 1.0), y, np.full(F, sig**2), wrap=False, rng=rng)
    v = np.maximum(y.var(0, ddof=1), sig**2) / R
    assert np.max(np.abs(draws.mean(0) - y.mean(0)) / np.sqrt(v)) < 0.15  # 4000 draws: 0.016 sd each, 37 lines
    assert np.median(draws.var(0) / v) == pytest.approx(1.0, abs=0.06)


def test_three_runs_give_a_full_rank_error():
    # 3 runs over 37 lines: the runs' sample covariance has rank 2; drawn with it, every draw's error would
    # be a mix of two shapes. Shrunk, the covariance is full rank and keeps each line's variance.
    rng = np.random.default_rng(7)
    y = 0.01 * rng.standard_normal((3, F))
    C = _mean_error_cov(y, np.full(F, 1e-8), wrap=False)
    assert np.linalg.matrix_rank(C) == F
    assert np.allclose(np.diag(C), y.var(0, ddof=1) / 3)


def test_a_reclamped_run_moves_all_its_lines():
    # Each run shifted as a whole (re-clamping, sd 0.02) plus line noise (0.01): the mean level's error is
    # the shifts' mean, sd 0.02 / sqrt(n), which the runs' covariance carries and the shrinkage keeps.
    rng = np.random.default_rng(11)
    R = 24
    sd_level = []
    for _ in range(20):
        y = 0.02 * rng.standard_normal((R, 1)) + 0.01 * rng.standard_normal((R, F))
        C = _mean_error_cov(y, np.full(F, 0.01**2), wrap=False)
        sd_level.append(np.sqrt(np.mean(C)))  # var of the mean over the lines = mean of C's entries
    expected = np.sqrt(0.02**2 / R + 0.01**2 / R / F)
    # a variance from 24 runs: relative sd of its root ~ sqrt(1 / 46) = 0.15 per set, 0.033 over 20 sets
    assert np.mean(sd_level) / expected == pytest.approx(1.0, abs=0.12)


def test_phase_near_pi_is_wrapped():
    rng = np.random.default_rng(2)
    R, S = 10, 200
    y = np.angle(np.exp(1j * (np.pi - 0.01 + 0.02 * rng.standard_normal((R, F)))))  # some runs read -pi + ...
    mu = np.full((S, F), np.pi - 0.05)
    d = true_mean_draws(mu, np.full(S, 0.05), y, np.full(F, 0.02**2), wrap=True, rng=rng)
    assert np.all(np.abs(np.angle(np.exp(1j * (d - (np.pi - 0.01))))) < 0.05)


def test_magnitude_and_phase_errors_stay_correlated():
    # a re-clamped run moves a line's magnitude and phase together (here phase = 0.5 x magnitude shift):
    # drawn as one vector, the draws' errors keep that correlation (near 1), where drawn apart it would be 0
    rng = np.random.default_rng(13)
    R, S = 24, 2000
    shift = 0.02 * rng.standard_normal((R, 1))
    y = np.concatenate([shift + 0.002 * rng.standard_normal((R, F)), 1.0 + 0.5 * shift + 0.001 * rng.standard_normal((R, F))], axis=1)
    mu = np.concatenate([np.zeros((S, F)), np.ones((S, F))], axis=1)
    d = true_mean_draws(mu, np.full(S, 1.0), y, np.full(2 * F, 1e-8), wrap=np.repeat([False, True], F), rng=rng)
    level = d[:, :F].mean(1), d[:, F:].mean(1)
    assert np.corrcoef(*level)[0, 1] > 0.9
