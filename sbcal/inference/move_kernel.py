"""The engine's per-step arithmetic compiled (numba): one half-step's proposals for every ensemble at once.

A step of :class:`sbcal.inference.sampler._Ensembles` moves two halves of each of four ensembles; as numpy,
ensemble by ensemble, it made ~40 small calls a half: ~1.1 ms a step outside the likelihood, more than a test's
likelihood (~400 us a step). The random numbers stay numpy's (each ensemble's from its own generator, drawn in a
few calls); this loop turns them into proposals: differential evolution, or an independence draw from the
ensemble's proposal (:class:`sbcal.inference.proposal.MapProposal`: a multivariate t with its narrow directions'
centres bent along its widest ones) with the Metropolis-Hastings threshold moved by the proposal's density ratio.
``MapProposal.draw`` and ``log_density``, and the numpy formulation ``tests/move_reference.py``, are the test's
references. Compiled on first use and cached on disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["half_step", "stack_proposals"]


def stack_proposals(proposals, ndim: int, t_dof: float):
    """The ensembles' proposals (each a ``MapProposal`` or None) as the arrays :func:`half_step` reads:
    ``(present (G,), mean (G, ndim), chol_t, unwhiten_t, whiten_t, unchol_t (G, ndim, ndim), bent (G,),
    coef (G, n_features, ndim) zero-padded, log_norm (G,), t_dof)``."""
    g = len(proposals)
    present = np.array([p is not None for p in proposals])
    n_feat = max([1] + [p.coef.shape[0] for p in proposals if p is not None])
    mean = np.zeros((g, ndim))
    eye = np.broadcast_to(np.eye(ndim), (g, ndim, ndim))
    chol_t, unwhiten_t, whiten_t, unchol_t = (eye.copy() for _ in range(4))
    bent = np.zeros(g, np.int64)
    coef = np.zeros((g, n_feat, ndim))
    log_norm = np.zeros(g)
    for e, p in enumerate(proposals):
        if p is None:
            continue
        mean[e], chol_t[e], unwhiten_t[e], whiten_t[e], unchol_t[e] = p.mean, p.chol.T, p.unwhiten.T, p.whiten.T, p.chol_inverse.T
        bent[e], log_norm[e] = p.bent, p.log_norm
        coef[e, :p.coef.shape[0], p.bent:] = p.coef
    return present, mean, chol_t, unwhiten_t, whiten_t, unchol_t, bent, coef, log_norm, float(t_dof)


@njit(cache=True, inline="always")
def _bend(v, bent, coef, sign):
    """``v[bent:] += sign f(v[:bent]) @ coef`` in place (``f``: a constant, each wide coordinate, their
    pairwise products ``a <= b`` in row-major order, as ``proposal.bend_features``)."""
    ndim = v.size
    for j in range(bent, ndim):
        acc = coef[0, j]
        k = 1
        for a in range(bent):
            acc += v[a] * coef[k, j]
            k += 1
        for a in range(bent):
            for b in range(a, bent):
                acc += v[a] * v[b] * coef[k, j]
                k += 1
        v[j] += sign * acc


@njit(cache=True)
def _log_density(x, e, mean, whiten_t, unchol_t, bent, coef, log_norm, t_dof, v, y):
    """Ensemble ``e``'s proposal's log-density at ``x (ndim,)`` (``v``, ``y``: work arrays)."""
    ndim = x.size
    for j in range(ndim):
        acc = 0.0
        for i in range(ndim):
            acc += (x[i] - mean[e, i]) * whiten_t[e, i, j]
        v[j] = acc
    _bend(v, bent[e], coef[e], -1.0)
    r2 = 0.0
    for j in range(ndim):
        acc = 0.0
        for i in range(ndim):
            acc += v[i] * unchol_t[e, i, j]
        y[j] = acc
        r2 += acc * acc
    return log_norm[e] - 0.5 * (t_dof + ndim) * math.log1p(r2 / t_dof)


@njit(cache=True)
def half_step(coords, s, c, u, jitter, gamma0, independence, normal, chi2, lower, upper,
              present, mean, chol_t, unwhiten_t, whiten_t, unchol_t, bent, coef, log_norm, t_dof):
    """The proposals ``q (G, H, ndim)`` of the moving halves and their acceptance thresholds ``log_u (G, H)``
    (before any screen).

    Parameters
    ----------
    coords : ndarray, shape (G W, ndim)
        Every walker.
    s, c : ndarray of int, shape (G, H)
        Rows of ``coords``: each ensemble's moving half and the half it moves along.
    u : ndarray, shape (G, >= 5, H)
        Uniforms in [0, 1): walker a, the step to walker b, the jump choice (``gamma = 1`` in a tenth), the
        acceptance and the independence choice (rows beyond the fifth are not read: the engine keeps stage 2's
        threshold there, for a screen).
    jitter : ndarray, shape (G, H)
        Standard normals: ``gamma``'s 1e-5 relative jitter.
    normal : ndarray, shape (G, T, H, ndim); chi2 : ndarray, shape (G, T, H)
        Each walker's ``T`` tries of an independence draw (standard normals, chi-square of ``t_dof``); the
        first inside ``[lower, upper]`` is taken (the last where none is). ``T = 0``: no independence moves.
    present ... t_dof
        The ensembles' proposals, :func:`stack_proposals`.
    """
    n_ens, half = s.shape
    ndim = coords.shape[1]
    tries = normal.shape[1]
    q = np.empty((n_ens, half, ndim))
    log_u = np.empty((n_ens, half))
    v = np.empty(ndim)
    w = np.empty(ndim)
    y = np.empty(ndim)
    for e in range(n_ens):
        for i in range(half):
            x = coords[s[e, i]]
            lu = math.log(u[e, 3, i])
            if tries > 0 and present[e] and u[e, 4, i] < independence:
                for t in range(tries):
                    scale = math.sqrt(t_dof / chi2[e, t, i])
                    for j in range(ndim):
                        acc = 0.0
                        for k in range(ndim):
                            acc += normal[e, t, i, k] * chol_t[e, k, j]
                        v[j] = acc * scale
                    _bend(v, bent[e], coef[e], 1.0)
                    inside = True
                    for j in range(ndim):
                        acc = mean[e, j]
                        for k in range(ndim):
                            acc += v[k] * unwhiten_t[e, k, j]
                        q[e, i, j] = acc
                        inside = inside and lower[j] <= acc <= upper[j]
                    if inside:
                        break
                lu -= (_log_density(x, e, mean, whiten_t, unchol_t, bent, coef, log_norm, t_dof, w, y)
                       - _log_density(q[e, i], e, mean, whiten_t, unchol_t, bent, coef, log_norm, t_dof, w, y))
            else:
                a = int(u[e, 0, i] * half)
                b = (a + 1 + int(u[e, 1, i] * (half - 1))) % half
                gamma = 1.0 if u[e, 2, i] < 0.1 else gamma0 * (1.0 + 1e-5 * jitter[e, i])
                xa, xb = coords[c[e, a]], coords[c[e, b]]
                for j in range(ndim):
                    q[e, i, j] = x[j] + gamma * (xa[j] - xb[j])
            log_u[e, i] = lu
    return q, log_u
