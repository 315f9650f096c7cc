"""The 6-DOF model's numpy formulation before :mod:`sbcal.model.fem_kernel`: the tests' reference for the
compiled kernel (``tests/test_fem.py``) and the baseline of ``benchmarks/forward.py``. The same exact
condensation (``docs/model.md``), as ~200 operations on small arrays."""

from __future__ import annotations

import numpy as np

from sbcal.model.damper import GEOMETRY
from sbcal.model.fem import _prepare_arms, _resolve, _rigidity


__all__ = ["impedance_numpy", "arm_impedance_numpy"]


def _arm_matrices(p):
    """Unit-EJ blocks of both arms, free node (F) and clamp (B), as nested 2x2 lists.

    Every entry is an array with a leading axis of length 2 (arm 1, arm 2), then the set axis.
    Returns (Kff, Mff, Kfb, Mfb, Kbb, Mbb) with K at EJ = 1 (scale by ``EJ (1 + i beta)``); Mff
    includes the lumped end mass. Arm 1 runs mass 1 -> clamp, arm 2 clamp -> mass 2, which flips
    the sign ``t`` of the odd Hermite terms between them.
    """
    def pair(a, b):
        return np.stack(np.broadcast_arrays(p[a], p[b]))

    l, m, J, a = pair("L1", "L2"), pair("m1", "m2"), pair("J1", "J2"), pair("a1", "a2")
    t = _ARM_SIGN
    k = 1.0 / l**3
    c = p["mu"] * l / 420.0
    ma = m * a
    lk, l2k, lc, l2c = l * k, l * l * k, l * c, l * l * c
    Kff = [[12 * k, t * 6 * lk], [t * 6 * lk, 4 * l2k]]
    Mff = [[156 * c + m, t * 22 * lc + ma], [t * 22 * lc + ma, 4 * l2c + J + ma * a]]
    Kfb = [[-12 * k, t * 6 * lk], [-t * 6 * lk, 2 * l2k]]
    Mfb = [[54 * c, -t * 13 * lc], [t * 13 * lc, -3 * l2c]]
    Kbb = [[12 * k, -t * 6 * lk], [-t * 6 * lk, 4 * l2k]]
    Mbb = [[156 * c, -t * 22 * lc], [-t * 22 * lc, 4 * l2c]]
    return Kff, Mff, Kfb, Mfb, Kbb, Mbb


_ARM_SIGN = np.array([1.0, -1.0]).reshape(2, 1, 1)


def _modes(K, M):
    """Mass-normalised modes of the symmetric 2x2 pencil (K, M), elementwise over arms and sets.

    Returns ``[(lam, (phi0, phi1)), ...]`` for the two eigenvalues, with ``phi^T M phi = 1``.
    """
    a = M[0][0] * M[1][1] - M[0][1] ** 2
    b = K[0][0] * M[1][1] + K[1][1] * M[0][0] - 2 * K[0][1] * M[0][1]
    c = K[0][0] * K[1][1] - K[0][1] ** 2
    q = 0.5 * (b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0)))  # no cancellation in either root
    out = []
    for lam in (c / q, q / a):
        # null vector of K - lam M from whichever row is better conditioned
        r00, r01, r11 = K[0][0] - lam * M[0][0], K[0][1] - lam * M[0][1], K[1][1] - lam * M[1][1]
        use0 = np.abs(r00) >= np.abs(r11)
        v0 = np.where(use0, -r01, r11)
        v1 = np.where(use0, r00, -r01)
        norm = np.sqrt(v0 * v0 * M[0][0] + 2 * v0 * v1 * M[0][1] + v1 * v1 * M[1][1])
        out.append((lam, (v0 / norm, v1 / norm)))
    return out


def _modal(p, cols):
    """Partial-fraction constants of both arms' condensed impedance at unit EJ.

    With ``sigma = EJ (1 + i beta)`` and ``x = omega^2`` an arm adds to ``H[a, b]``::

        sigma * alpha[a,b] + x * gamma[a,b] + sigma^2 * sum_j G_j[a,b] / (x - sigma * lam_j)

    exactly (the Schur complement expanded on the arm's two clamped-base modes). ``cols`` lists
    the clamp DOFs wanted (0 = xc, 1 = phic). Returns (lam, G, alpha, gamma): lam a list of two
    arrays (arm axis first), G/alpha/gamma dicts keyed by (a, b).
    """
    Kff, Mff, Kfb, Mfb, Kbb, Mbb = _arm_matrices(p)
    lam, g, r = [], [], []
    for lam_j, (f0, f1) in _modes(Kff, Mff):
        lam.append(lam_j)
        rj = {a: f0 * Mfb[0][a] + f1 * Mfb[1][a] for a in cols}
        g.append({a: f0 * Kfb[0][a] + f1 * Kfb[1][a] - lam_j * rj[a] for a in cols})
        r.append(rj)
    G, alpha, gamma = {}, {}, {}
    for a in cols:
        for b in cols:
            if b < a:
                continue
            G[a, b] = [g[j][a] * g[j][b] for j in (0, 1)]
            alpha[a, b] = Kbb[a][b] - sum(g[j][a] * r[j][b] + g[j][b] * r[j][a] + r[j][a] * r[j][b] * lam[j]
                                         for j in (0, 1))
            gamma[a, b] = sum(r[j][a] * r[j][b] for j in (0, 1)) - Mbb[a][b]
    return lam, G, alpha, gamma


def _condensed(p, ej1, ej2, beta1, beta2, omega, full):
    """Entries (h00, h01, h11) of the clamp impedance H; each broadcasts to (n, n_freq).

    ``ej1, ej2`` and ``beta1, beta2`` are per arm, shape (n or 1, 1 or n_freq).

    ``H[a,b] = const + x * lin + sum over the four modes of R / (x - pole)``, ``x = omega^2``:
    the per-set constants are cheap, and only four complex divisions per line remain.
    """
    x = omega * omega
    keys = ((0, 0), (0, 1), (1, 1)) if full else ((0, 0),)
    mc, ac = p["mc"], p["ac"]
    clamp = {(0, 0): mc, (0, 1): mc * ac, (1, 1): p["Jc"] + mc * ac * ac}  # the clamp's own inertia
    # sigma = EJ (1 + i beta) per arm, stacked on a leading arm axis: (2, n, 1 or n_freq)
    sigma = np.stack(np.broadcast_arrays(ej1 * (1 + 1j * beta1), ej2 * (1 + 1j * beta2)))
    lam, G, alpha, gamma = _modal(p, (0, 1) if full else (0,))
    poles = [sigma * lam_j for lam_j in lam]
    s2 = sigma * sigma
    h = []
    for key in keys:
        acc = sigma * alpha[key] + x * gamma[key]
        for j in (0, 1):
            acc = acc + s2 * G[key][j] / (x - poles[j])
        h.append(acc[0] + acc[1] - x * clamp[key])
    return (h[0], None, None) if not full else tuple(h)


def impedance_numpy(damper, freq_hz, full=False, **params):
    """``f_uu`` (n_sets, n_freq), or with ``full`` H (n_sets, n_freq, 2, 2), as
    :func:`sbcal.model.fem.dynamic_stiffness` / :func:`~sbcal.model.fem.clamp_impedance` compute them."""
    p, n_sets = _resolve(damper, params)
    for name in GEOMETRY:
        p.setdefault(name, np.full((1, 1), getattr(damper, name)))
    omega = 2 * np.pi * np.atleast_1d(np.asarray(freq_hz, float))[None, :]
    ej = _rigidity(p, omega, damper)
    beta = p.get("beta", np.zeros((1, 1)))
    h = _condensed(p, ej, ej, p.get("beta1", beta), p.get("beta2", beta), omega, full)
    h00, h01, h11 = (np.broadcast_to(x, (n_sets, omega.shape[1])) if x is not None else None for x in h)
    if not full:
        return h00.copy()
    return np.stack([np.stack([h00, h01], -1), np.stack([h01, h11], -1)], -2)


def arm_impedance_numpy(damper, freq_hz, *, ej1, ej2, beta1=0.0, beta2=0.0, **geometry):
    """H (n_sets, n_freq, 2, 2) with per-arm, per-line values, as :func:`sbcal.model.fem.arm_impedance`."""
    p, n, omega, (e1, e2, b1, b2) = _prepare_arms(
        damper, freq_hz, dict(ej1=ej1, ej2=ej2, beta1=beta1, beta2=beta2), geometry)
    for name in GEOMETRY:
        p.setdefault(name, np.full((1, 1), getattr(damper, name)))
    h00, h01, h11 = (np.broadcast_to(h, (n, omega.shape[1])) for h in _condensed(p, e1, e2, b1, b2, omega, True))
    return np.stack([np.stack([h00, h01], -1), np.stack([h01, h11], -1)], -2)
