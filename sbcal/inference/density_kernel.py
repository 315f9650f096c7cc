"""The sampled density's per-line arithmetic compiled (numba): the multivariate t of a test's runs
(:meth:`sbcal.inference.likelihood.TestLikelihood.log_likelihood`) summed over lines and quantities, per
parameter set, in one loop.

A sampler's batch is 48 sets x 37 lines x 2 quantities; the numpy expression made ~15 passes over it with
a temporary each (~100 us a call, twice the compiled 6-DOF model); one fused loop costs ~45 us, its two
scalar logarithms per entry (numpy's are vectorised, numba's here are not: no SVML). Compiled on first use and cached on disk (numba's ``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


__all__ = ["mvt_log_likelihood"]

_TWO_PI = 2.0 * math.pi


@njit(cache=True, error_model="numpy")
def mvt_log_likelihood(mu, ybar, ss_sig2, sig2, n, nu, base, s2):
    """``log p(y | theta)`` of each parameter set (module docstring of :mod:`sbcal.inference.likelihood`).

    Parameters
    ----------
    mu : ndarray, shape (2, n_sets, n_freq)
        The model: natural-log magnitude, phase [rad].
    ybar, ss_sig2, sig2 : ndarray, shape (2, n_freq)
        Run mean, the runs' squared deviations over the noise variance ``S / sigma^2``, the noise variance.
    n : ndarray, shape (n_freq,)
        Runs per line.
    nu, base : ndarray, shape (2, n_freq)
        The dof and the theta-free part ``const - (n - 1) log(sigma^2) / 2``.
    s2 : ndarray, shape (2, n_sets)
        The discrepancy variances ``s_q^2`` (zeros: the noise-only likelihood).

    Returns
    -------
    ndarray, shape (n_sets,)
    """
    n_sets, n_freq = mu.shape[1], mu.shape[2]
    out = np.zeros(n_sets)
    for i in range(n_sets):
        acc = 0.0
        for q in range(2):
            s2q = s2[q, i]
            for k in range(n_freq):
                r = ybar[q, k] - mu[q, i, k]
                if q == 1 and not -math.pi <= r < math.pi:  # the phase to [-pi, pi), as wrap_phase
                    r = (r + math.pi) % _TWO_PI - math.pi
                big = sig2[q, k] + n[k] * s2q
                quad = ss_sig2[q, k] + n[k] * r * r / big
                acc += base[q, k] - 0.5 * math.log(big) - 0.5 * (nu[q, k] + n[k]) * math.log(nu[q, k] + quad)
        out[i] = acc
    return out
