"""The 6-DOF model's compiled kernel (numba): each arm's clamped-base modes and the condensed clamp
impedance, per parameter set and frequency line, in one fused loop.

The arithmetic is :mod:`sbcal.model.fem`'s (``docs/model.md``): per arm, the unit-EJ Hermite blocks, the
two mass-normalised modes of the free node's 2x2 pencil and the partial-fraction constants of the
Schur complement; per line, four complex divisions. At a sampler's batch (16-64 sets x 37 lines) the numpy
formulation spent ~230 us a 32-set call, most of it on ~200 small-array operations; compiled, the call takes
46 us, ~30 of them this loop and the rest the argument checks (``benchmarks/forward.py``).
The numpy formulation is kept as the tests' reference (``tests/fem_reference.py``); both agree to
rounding (5e-14 relative on ``f_uu``, 5e-12 on ``H[0, 1]``, whose sum cancels to ~1e-3 of its terms).

Compiled on first use and cached on disk (numba's ``cache=True``), as :mod:`sbcal.model.cable_kernel`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .cable_kernel import _inv  # 1 / z without numba's branching complex division


__all__ = ["N_CONSTANTS", "modal_constants", "impedance"]

N_CONSTANTS = 20
"""Per arm: ``lam_j`` (2), ``phi_j`` (2 x 2: free displacement, rotation), ``g_ja`` (2 x 2), ``r_ja``
(2 x 2) for the modes j and clamp DOFs a = (xc, phic), then ``Kbb`` and ``Mbb`` (00, 01, 11 each)."""

# the rows of the geometry array: sbcal.model.damper.GEOMETRY's order
_M1, _J1, _A1, _M2, _J2, _A2, _MC, _JC, _AC, _L1, _L2, _MU = range(12)


@njit(cache=True, error_model="numpy")
def _arm(l, m, J, a, mu, t, out):
    """One arm's :data:`N_CONSTANTS` into ``out``; ``t`` = +1 (arm 1, mass 1 -> clamp) or -1 (arm 2): the
    sign of the odd Hermite terms."""
    k = 1.0 / (l * l * l)
    c = mu * l / 420.0
    ma = m * a
    lk, l2k, lc, l2c = l * k, l * l * k, l * c, l * l * c
    k00, k01, k11 = 12.0 * k, t * 6.0 * lk, 4.0 * l2k  # Kff
    m00, m01, m11 = 156.0 * c + m, t * 22.0 * lc + ma, 4.0 * l2c + J + ma * a  # Mff (with the end mass)
    kfb = ((-12.0 * k, t * 6.0 * lk), (-t * 6.0 * lk, 2.0 * l2k))
    mfb = ((54.0 * c, -t * 13.0 * lc), (t * 13.0 * lc, -3.0 * l2c))
    aa = m00 * m11 - m01 * m01
    bb = k00 * m11 + k11 * m00 - 2.0 * k01 * m01
    cc = k00 * k11 - k01 * k01
    q = 0.5 * (bb + math.sqrt(max(bb * bb - 4.0 * aa * cc, 0.0)))  # no cancellation in either root
    for j in range(2):
        lam = cc / q if j == 0 else q / aa
        # null vector of K - lam M from whichever row is better conditioned
        r00, r01, r11 = k00 - lam * m00, k01 - lam * m01, k11 - lam * m11
        if abs(r00) >= abs(r11):
            v0, v1 = -r01, r00
        else:
            v0, v1 = r11, -r01
        norm = math.sqrt(v0 * v0 * m00 + 2.0 * v0 * v1 * m01 + v1 * v1 * m11)
        f0, f1 = v0 / norm, v1 / norm
        out[j] = lam
        out[2 + 2 * j], out[3 + 2 * j] = f0, f1
        for b in range(2):
            r = f0 * mfb[0][b] + f1 * mfb[1][b]
            out[10 + 2 * j + b] = r
            out[6 + 2 * j + b] = f0 * kfb[0][b] + f1 * kfb[1][b] - lam * r
    out[14], out[15], out[16] = 12.0 * k, -t * 6.0 * lk, 4.0 * l2k  # Kbb
    out[17], out[18], out[19] = 156.0 * c, -t * 22.0 * lc, 4.0 * l2c  # Mbb


@njit(cache=True, error_model="numpy")
def modal_constants(geometry):
    """Both arms' :data:`N_CONSTANTS` at unit EJ for each geometry set.

    Parameters
    ----------
    geometry : ndarray, shape (12, n_geometry)
        :data:`sbcal.model.damper.GEOMETRY` by row (SI units).

    Returns
    -------
    ndarray, shape (n_geometry, 2, N_CONSTANTS)
        Arm 1 (mass 1 -> clamp), then arm 2 (clamp -> mass 2).
    """
    g = geometry
    out = np.empty((g.shape[1], 2, N_CONSTANTS))
    for s in range(g.shape[1]):
        _arm(g[_L1, s], g[_M1, s], g[_J1, s], g[_A1, s], g[_MU, s], 1.0, out[s, 0])
        _arm(g[_L2, s], g[_M2, s], g[_J2, s], g[_A2, s], g[_MU, s], -1.0, out[s, 1])
    return out


@njit(cache=True, error_model="numpy")
def _fractions(c, n_keys, out):
    """One arm's partial-fraction constants per entry (00, 01, 11) of H: ``(alpha, gamma, G_0, G_1)`` into
    ``out[key]``, from its :data:`N_CONSTANTS` ``c``."""
    for key in range(n_keys):
        a, b = (0, 0) if key == 0 else ((0, 1) if key == 1 else (1, 1))
        alpha, gamma = c[14 + key], -c[17 + key]
        for j in range(2):
            ga, gb, ra, rb = c[6 + 2 * j + a], c[6 + 2 * j + b], c[10 + 2 * j + a], c[10 + 2 * j + b]
            alpha -= ga * rb + gb * ra + ra * rb * c[j]
            gamma += ra * rb
            out[key, 2 + j] = ga * gb
        out[key, 0], out[key, 1] = alpha, gamma


@njit(cache=True, error_model="numpy")
def impedance(geometry, ej1, ej2, beta1, beta2, omega, n_sets, full):
    """Entries of the clamp impedance ``H`` (condensed on the clamp DOFs xc, phic).

    Per arm e, with ``sigma = EJ_e (1 + i beta_e)`` and ``x = omega^2``, the arm adds to ``H[a, b]``::

        sigma alpha + x gamma + sigma^2 sum_j G_j / (x - sigma lam_j)

    exactly (the Schur complement expanded on the arm's two clamped-base modes); the clamp's own inertia
    takes ``x (mc, mc ac, Jc + mc ac^2)``.

    Parameters
    ----------
    geometry : ndarray, shape (12, 1 or n_sets)
        As :func:`modal_constants`.
    ej1, ej2, beta1, beta2 : ndarray, shape (1 or n_sets, 1 or n_freq)
        Each arm's rigidity [N m^2] and loss factor (a length-1 axis broadcasts).
    omega : ndarray, shape (n_freq,)
        [rad/s].
    n_sets : int
    full : bool
        All three entries, or ``f_uu = H[0, 0]`` only.

    Returns
    -------
    ndarray of complex, shape (3 or 1, n_sets, n_freq)
        ``H[0, 0], H[0, 1], H[1, 1]`` [N/m, N/rad, N m/rad], or ``H[0, 0]``.
    """
    n_keys = 3 if full else 1
    n_freq = omega.shape[0]
    constants = modal_constants(geometry)
    fractions = np.empty((constants.shape[0], 2, 3, 4))
    for s in range(constants.shape[0]):
        for e in range(2):
            _fractions(constants[s, e], n_keys, fractions[s, e])
    x = omega * omega
    out = np.empty((n_keys, n_sets, n_freq), dtype=np.complex128)
    for i in range(n_sets):
        s = i if geometry.shape[1] > 1 else 0
        mc, ac = geometry[_MC, s], geometry[_AC, s]
        clamp = (mc, mc * ac, geometry[_JC, s] + mc * ac * ac)  # the clamp's own inertia
        for key in range(n_keys):
            for k in range(n_freq):
                out[key, i, k] = -x[k] * clamp[key]
        for e in range(2):
            ee, bb = (ej1, beta1) if e == 0 else (ej2, beta2)
            ie, ib = (i if ee.shape[0] > 1 else 0), (i if bb.shape[0] > 1 else 0)
            pe, pb = ee.shape[1] > 1, bb.shape[1] > 1
            lam0, lam1 = constants[s, e, 0], constants[s, e, 1]
            f = fractions[s, e]
            for k in range(n_freq):
                sr = ee[ie, k if pe else 0]
                sigma = complex(sr, sr * bb[ib, k if pb else 0])
                s2 = sigma * sigma
                d0 = s2 * _inv(x[k] - sigma * lam0)
                d1 = s2 * _inv(x[k] - sigma * lam1)
                for key in range(n_keys):
                    out[key, i, k] += sigma * f[key, 0] + x[k] * f[key, 1] + d0 * f[key, 2] + d1 * f[key, 3]
    return out
