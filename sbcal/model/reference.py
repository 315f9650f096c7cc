"""A plain transcription of the thesis's Appendix C MATLAB listing (generic 6x6 assembly and a
per-frequency solve), with the seed's typos corrected (``docs/model.md``, "Where it departs from the seed").

It is the yardstick for :mod:`sbcal.model.fem` (tests agree to 1e-10) and the "thesis workflow"
baseline of the benchmarks. It is deliberately slow and simple: do not use it for fitting.
"""

from __future__ import annotations

import numpy as np

from .damper import GEOMETRY, Damper


__all__ = ["dynamic_stiffness_loop"]


def _beam_k(l):
    return np.array([
        [12, 6 * l, -12, 6 * l],
        [6 * l, 4 * l**2, -6 * l, 2 * l**2],
        [-12, -6 * l, 12, -6 * l],
        [6 * l, 2 * l**2, -6 * l, 4 * l**2],
    ]) / l**3


def _beam_m(l):
    return np.array([
        [156, 22 * l, 54, -13 * l],
        [22 * l, 4 * l**2, 13 * l, -3 * l**2],
        [54, 13 * l, 156, -22 * l],
        [-13 * l, -3 * l**2, -22 * l, 4 * l**2],
    ]) * l / 420


def dynamic_stiffness_loop(
    damper: Damper, freq_hz, *, EJ=None, beta1=0.0, beta2=0.0, q=None, full=False, **geometry
):
    """f_uu (or H) for one parameter set, one frequency at a time, as Appendix C does it.

    Parameters
    ----------
    damper : Damper
    freq_hz : array_like, shape (n_freq,)
    EJ : float, optional
        Flexural rigidity [N m^2] (default ``damper.ej_static``).
    beta1, beta2 : float
        Loss factors of arm 1 and arm 2.
    q : sequence of float, optional
        Polynomial ``EJ(omega) = q[0] + q[1] omega + ...`` (chapter 5); overrides EJ.
    full : bool
        Return the 2x2 H per frequency instead of f_uu.
    **geometry : float
        Overrides of the damper's nominal values (m1, J1, a1, ..., L1, L2, mu).

    Returns
    -------
    ndarray, complex, shape (n_freq,) or (n_freq, 2, 2)
    """
    g = {k: getattr(damper, k) for k in GEOMETRY}
    g.update(geometry)
    l1, l2, mu = g["L1"], g["L2"], g["mu"]
    ej0 = damper.ej_static if EJ is None else EJ
    # Consistent mass of both arms and lumped masses (J about the node = J_G + m a^2).
    M = np.zeros((6, 6))
    M[0:4, 0:4] += mu * _beam_m(l1)
    M[2:6, 2:6] += mu * _beam_m(l2)
    for i, (m, J, a) in enumerate(((g["m1"], g["J1"], g["a1"]), (g["mc"], g["Jc"], g["ac"]), (g["m2"], g["J2"], g["a2"]))):
        M[2 * i:2 * i + 2, 2 * i:2 * i + 2] += [[m, m * a], [m * a, J + m * a * a]]
    K1u = np.zeros((6, 6))
    K1u[0:4, 0:4] = _beam_k(l1)
    K2u = np.zeros((6, 6))
    K2u[2:6, 2:6] = _beam_k(l2)
    free = [0, 1, 4, 5]  # x1, phi1, x2, phi2
    bound = [2, 3]  # xc, phic
    out = []
    for f in np.atleast_1d(np.asarray(freq_hz, dtype=float)):
        w = 2 * np.pi * f
        ej = ej0 if q is None else sum(c * w**k for k, c in enumerate(q))
        K1, K2 = ej * K1u, ej * K2u
        K = K1 + K2
        C = beta1 / w * K1 + beta2 / w * K2  # structural damping C = (beta/omega) K
        Z = -w**2 * M + 1j * w * C + K
        A = Z[np.ix_(free, free)]
        B = -Z[np.ix_(free, bound)]
        C1 = Z[np.ix_(bound, free)]
        D = -Z[np.ix_(bound, bound)]
        H = C1 @ np.linalg.solve(A, B) - D
        out.append(H if full else H[0, 0])
    return np.array(out)
