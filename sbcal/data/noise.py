"""The repeatability noise model of a test's cleaned runs, for the likelihood (``docs/data.md``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .bench import TestData, readonly
from .cleaning import (DEFAULT_Z_THRESHOLD, MAX_HALF_WINDOW, NOISE_FLOOR, VALUE_MIN_RUNS, VALUE_Z, check_threshold,
                       outliers, robust_z, score_runs, window_sum)


__all__ = ["SINGLE_RUN_SIGMA", "NoiseModel", "noise_model"]

SINGLE_RUN_SIGMA = 0.05
"""Sigma used where no repeat is available within the pooling window: a 5 % complex relative
error, i.e. 0.05 in log-magnitude and 0.05 rad (2.9 deg) in phase."""

_POOL_DOF = 10        # degrees of freedom pooled per line for the noise sigma (rel. error 1/sqrt(20) = 22 %)


# --- noise model for the likelihood -------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class NoiseModel:
    """Scatter of ONE run about the test's mean curve, per frequency line.

    Attributes
    ----------
    freq_hz : ndarray, shape (n_freq,)
        The test's lines [Hz].
    sigma_logmag : ndarray, shape (n_freq,)
        Standard deviation of ``ln |F/X|`` of one run (dimensionless: a relative error).
    sigma_phase : ndarray, shape (n_freq,)
        Standard deviation of the phase of one run [rad].
    n_runs : ndarray of int, shape (n_freq,)
        Runs of the input test present at each line.
    dof_logmag, dof_phase : ndarray of int, shape (n_freq,)
        Degrees of freedom behind each sigma: ``sum_k (n_k - 1)`` over the lines k pooled into
        it (after the glitch screen, so they may differ between the components); 0 where
        ``single_run_sigma`` was used. The likelihood's Student-t degrees of freedom.
    measured : ndarray of bool, shape (n_freq,)
        Where a measured standard error (the bench file's ``stiffness_se_n_per_m``, ``phase_se_deg``) set a
        sigma (either component): see :func:`noise_model`, step 5.

    Sigmas are finite and >= :data:`NOISE_FLOOR`.
    """

    freq_hz: np.ndarray
    sigma_logmag: np.ndarray
    sigma_phase: np.ndarray
    n_runs: np.ndarray
    dof_logmag: np.ndarray
    dof_phase: np.ndarray
    measured: np.ndarray | None = None


def _with_measured(sigma: np.ndarray, dof: np.ndarray, se: np.ndarray, se_dof: np.ndarray,
                   floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 5 of :func:`noise_model` for one component: the measured standard error where it is larger than the
    repeats' sigma, or where no repeat gave a sigma (``dof == 0``). ``se``, ``se_dof``: (n_runs, n_freq) of the
    kept runs, NaN / 0 where not measured. Returns (sigma, dof, used)."""
    have = np.isfinite(se)
    n = have.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt((np.where(have, se, 0.0) ** 2).sum(axis=0) / n)  # NaN where no run was measured
    used = (n > 0) & ((dof == 0) | (rms > sigma))
    sigma = np.where(used, np.maximum(rms, floor), sigma)
    dof = np.where(used, np.where(have, se_dof, 0).sum(axis=0), dof)
    return sigma, dof.astype(np.int64), used


def _pooled_sigma(x: np.ndarray, floor: float, single_run_sigma: float, group: np.ndarray | None = None,
                  split: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-line sigma and its degrees of freedom of x (n_runs, n_freq): classical pooled variance
    after a robust value screen.

    ``group``/``split`` describe response branches (:func:`_branch_groups`): the screen centres each
    branch on its own median (a branch is not a glitch), a split line keeps the scatter about its
    overall mean (both branches), uses its own lines only and is left out of its neighbours' pools.
    """
    z = robust_z(x, floor, group)
    glitch = (np.abs(z) > VALUE_Z) & (np.sum(~np.isnan(x), axis=0) >= VALUE_MIN_RUNS)  # NaN z: False
    x = np.where(glitch, np.nan, x)
    n = np.sum(~np.isnan(x), axis=0)
    mean = np.where(n > 0, np.nansum(x, axis=0) / np.maximum(n, 1), 0.0)
    ss = np.nansum((x - mean) ** 2, axis=0)
    dof = np.maximum(n - 1, 0).astype(float)
    alone = np.zeros(n.size, bool) if split is None else split
    ss_pool, dof_pool = np.where(alone, 0.0, ss), np.where(alone, 0.0, dof)
    ss_w, dof_w = ss.copy(), dof.copy()
    done = (dof >= _POOL_DOF) | alone
    for h in range(1, MAX_HALF_WINDOW + 1):  # the narrowest window with enough dof, else the widest
        s_h, d_h = window_sum(ss_pool, h), window_sum(dof_pool, h)
        take = ~done & ((d_h >= _POOL_DOF) | (h == MAX_HALF_WINDOW))
        ss_w[take], dof_w[take] = s_h[take], d_h[take]
        done |= take
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.where(dof_w > 0, np.sqrt(ss_w / dof_w), single_run_sigma)
    return np.maximum(sigma, floor), np.rint(dof_w).astype(np.int64)


def noise_model(test: TestData, *, z_threshold: float = DEFAULT_Z_THRESHOLD, floor: float = NOISE_FLOOR,
                single_run_sigma: float = SINGLE_RUN_SIGMA) -> NoiseModel:
    """Repeatability of one run, per line, from the scatter of the repeats.

    Steps, for log-magnitude and phase [rad] separately:

    1. whole outlier runs are set aside as in :func:`remove_outlier_runs` (``z_threshold``);
    2. single values more than 8 robust sigma from their line's median (their branch's median,
       at a line where the runs split into two branches) are dropped, on lines with >= 4 runs;
    3. ``sigma_j^2 = sum_k SS_k / sum_k (n_k - 1)`` over the lines k within +-h of line j, with
       ``SS_k`` the sum of squared deviations from line k's mean and h the smallest half-width
       (0 to 3 lines) that gives >= 10 degrees of freedom -- h = 0 from 11 runs on;
       unbiased for sigma^2 whatever the number of runs. A line where the runs split into two
       branches keeps the scatter of both about their common mean, pools nothing and is pooled
       into no other line;
    4. lines with no degree of freedom within +-3 lines (a single run) get ``single_run_sigma``;
       every sigma is at least ``floor``;
    5. where the bench file gives measured standard errors (``sbcal import``: the first harmonic's
       period-to-period variation within each dwell), their RMS over the kept runs replaces the sigma of
       steps 3-4 where it is larger or where step 4 applied, with their degrees of freedom
       (``sum (se_windows - 1)``). The repeats' scatter holds the within-dwell noise and the run-to-run
       variation, so it can only be smaller than the measured error by chance; a single run's noise is then
       measured instead of assumed. Lines without a measured value keep steps 1-4.

    Parameters
    ----------
    test : TestData
    z_threshold : float
        Run-score threshold of step 1.
    floor : float
        Lower bound, default :data:`NOISE_FLOOR` (0.2 %, 0.002 rad).
    single_run_sigma : float
        Default :data:`SINGLE_RUN_SIGMA` (5 %, 0.05 rad) where no repeat is available.

    Returns
    -------
    NoiseModel
        Shapes (n_freq,) on ``test.freq_hz``; all sigmas finite and > 0; ``dof_*`` the degrees
        of freedom of step 3 (0 where step 4 applied).
    """
    z = check_threshold(z_threshold)
    if not (math.isfinite(floor) and floor > 0 and math.isfinite(single_run_sigma) and single_run_sigma > 0):
        raise InputError("noise_model: floor and single_run_sigma must be finite and > 0")
    scores, branches, group, comps = score_runs(test, floor)
    keep = np.ones(test.runs.size, bool)
    keep[outliers(scores, z)] = False
    logmag, phase = (c[keep] for c in comps)
    group = None if group is None else group[keep]
    split = np.isin(test.freq_hz, branches.freq_hz) if branches.split else None
    sig_m, dof_m = _pooled_sigma(logmag, floor, single_run_sigma, group, split)
    sig_p, dof_p = _pooled_sigma(phase, floor, single_run_sigma, group, split)
    measured = np.zeros(test.freq_hz.size, bool)
    if test.measured_noise:
        sig_m, dof_m, used_m = _with_measured(sig_m, dof_m, test.se_logmag[keep], test.se_dof[keep], floor)
        sig_p, dof_p, used_p = _with_measured(sig_p, dof_p, test.se_phase[keep], test.se_dof[keep], floor)
        measured = used_m | used_p
    return NoiseModel(
        freq_hz=readonly(test.freq_hz, float),
        sigma_logmag=readonly(sig_m, float),
        sigma_phase=readonly(sig_p, float),
        n_runs=readonly(test.present.sum(axis=0), np.int64),
        dof_logmag=readonly(dof_m, np.int64),
        dof_phase=readonly(dof_p, np.int64),
        measured=readonly(measured, bool),
    )
