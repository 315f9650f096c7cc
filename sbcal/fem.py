"""The forward model: the 6-DOF planar finite-element model of a Stockbridge damper, condensed
on the clamp (``docs/model.md``).

DOFs ``X = {x1, phi1, xc, phic, x2, phi2}``; element 1 joins mass 1 to the clamp (length L1),
element 2 the clamp to mass 2 (length L2); Euler-Bernoulli Hermite elements with consistent mass,
lumped rigid masses at the three nodes, hysteretic damping ``K_e (1 + i beta_e)``, time convention
``exp(+i omega t)``. With the clamp DOFs B = {xc, phic} prescribed, the force on the base per
unit clamp motion is the Schur complement ``H = Z_BB - Z_BF Z_FF^-1 Z_FB``; the bench measures
``f_uu = H[0, 0]``.

Z_FF is block-diagonal (the free DOFs of the two arms do not couple), so H is a sum of two 2x2
closed forms plus the clamp's own inertia. Each arm's stiffness scales as ``sigma = EJ (1 + i beta)``,
so expanding its 2x2 free block on its two clamped-base modes (frequency-independent) gives the
exact partial-fraction form ``sigma alpha + omega^2 gamma + sum_j sigma^2 G_j / (omega^2 - sigma lam_j)``
with per-set constants: four complex divisions per frequency line. Everything broadcasts on arrays
of shape ``(n_sets, n_freq)``: no Python loop over frequencies or parameter sets.

Parameters (keyword arguments; each a scalar or an array of shape ``(n_sets,)``):

=========  =========  =====================================================================
name       unit       meaning (default: the damper's nominal value)
=========  =========  =====================================================================
EJ         N m^2      flexural rigidity of both arms (default ``ej_static``)
beta       1          hysteretic loss factor of both arms (default 0)
beta1/2    1          loss factor of arm 1 / arm 2 (override ``beta``)
a1, a2     m          signed centre-of-mass offsets of the end masses
mu         kg/m       cable mass per metre
q1..q5     N m^2 s^k  ``EJ(omega) = q1 + q2 omega + ... + q5 omega^4`` (omega in rad/s);
                      when any q is given EJ is this polynomial (missing q's are 0)
m1, m2, mc kg         end and clamp masses
J1, J2, Jc kg m^2     inertias about the own centre of mass
ac         m          clamp offset
L1, L2     m          arm lengths
=========  =========  =====================================================================
"""

from __future__ import annotations

import numpy as np

from .damper import Damper
from .errors import InputError

__all__ = [
    "PARAMETER_NAMES",
    "STANDARD_GRID_HZ",
    "dynamic_stiffness",
    "clamp_impedance",
    "natural_frequencies",
]

_GEOMETRY = ("m1", "J1", "a1", "m2", "J2", "a2", "mc", "Jc", "ac", "L1", "L2", "mu")
_POLY = ("q1", "q2", "q3", "q4", "q5")
PARAMETER_NAMES = ("EJ", "beta", "beta1", "beta2") + _POLY + _GEOMETRY
"""The public parameter vocabulary shared by the model, the priors, the CLI and the reports."""

STANDARD_GRID_HZ = np.concatenate(
    [np.arange(4.0, 9.01, 0.5), np.arange(10.0, 30.01, 1.0), np.arange(32.0, 40.01, 2.0)]
)
"""The reference bench's 37 frequency lines [Hz]: 4-9 by 0.5, 10-30 by 1, 32-40 by 2."""


def _resolve(damper: Damper, params: dict) -> tuple[dict, int]:
    """Check names and shapes; return every parameter as an array of shape (n or 1, 1)."""
    unknown = sorted(set(params) - set(PARAMETER_NAMES))
    if unknown:
        raise InputError(
            f"unknown parameter {unknown[0]!r}; known: {', '.join(PARAMETER_NAMES)}"
        )
    if "EJ" in params and any(q in params for q in _POLY):
        raise InputError("give either EJ or the polynomial coefficients q1..q5, not both")
    n_sets = 1
    out = {}
    for name, value in params.items():
        a = np.asarray(value, dtype=float)
        if a.ndim > 1:
            raise InputError(f"parameter {name!r}: expected a scalar or shape (n_sets,), got shape {a.shape}")
        if a.ndim == 1:
            if n_sets not in (1, a.size) and a.size != 1:
                raise InputError(f"parameter {name!r}: {a.size} sets where others have {n_sets}")
            n_sets = max(n_sets, a.size)
        out[name] = a.reshape(-1, 1)
    for name in _GEOMETRY:
        out.setdefault(name, np.full((1, 1), getattr(damper, name)))
    return out, n_sets


def _rigidity(p: dict, omega: np.ndarray, damper: Damper):
    """EJ of each set: shape (n or 1, 1), or (n or 1, n_freq) for the polynomial."""
    if any(q in p for q in _POLY):
        ej = np.zeros((1, 1))
        for q in reversed(_POLY):  # Horner
            ej = ej * omega + p.get(q, 0.0)
        return ej
    return p.get("EJ", np.full((1, 1), damper.ej_static))


def _arm_matrices(p, arm):
    """Unit-EJ blocks of one arm, free node (F) and clamp (B), each as nested 2x2 lists.

    Returns (Kff, Mff, Kfb, Mfb, Kbb, Mbb) with K at EJ = 1 (scale by ``EJ (1 + i beta)``); Mff
    includes the lumped end mass. Arm 1 runs mass 1 -> clamp, arm 2 clamp -> mass 2, which flips
    the sign of the odd Hermite terms between them.
    """
    if arm == 1:
        l, m, J, a, t = p["L1"], p["m1"], p["J1"], p["a1"], 1.0
    else:
        l, m, J, a, t = p["L2"], p["m2"], p["J2"], p["a2"], -1.0
    k = 1.0 / l**3
    c = p["mu"] * l / 420.0
    ma = m * a
    Kff = [[12 * k, t * 6 * l * k], [t * 6 * l * k, 4 * l * l * k]]
    Mff = [[156 * c + m, t * 22 * l * c + ma], [t * 22 * l * c + ma, 4 * l * l * c + J + ma * a]]
    Kfb = [[-12 * k, t * 6 * l * k], [-t * 6 * l * k, 2 * l * l * k]]
    Mfb = [[54 * c, -t * 13 * l * c], [t * 13 * l * c, -3 * l * l * c]]
    Kbb = [[12 * k, -t * 6 * l * k], [-t * 6 * l * k, 4 * l * l * k]]
    Mbb = [[156 * c, -t * 22 * l * c], [-t * 22 * l * c, 4 * l * l * c]]
    return Kff, Mff, Kfb, Mfb, Kbb, Mbb


def _modes(K, M):
    """Mass-normalised modes of the symmetric 2x2 pencil (K, M), elementwise over sets.

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
        use0 = np.abs(r00) + np.abs(r01) >= np.abs(r11) + np.abs(r01)
        v0 = np.where(use0, -r01, r11)
        v1 = np.where(use0, r00, -r01)
        norm = np.sqrt(v0 * v0 * M[0][0] + 2 * v0 * v1 * M[0][1] + v1 * v1 * M[1][1])
        out.append((lam, (v0 / norm, v1 / norm)))
    return out


def _modal_arm(p, arm, cols):
    """Partial-fraction constants of one arm's condensed impedance at unit EJ.

    With ``sigma = EJ (1 + i beta)`` and ``x = omega^2`` the arm adds to ``H[a, b]``::

        sigma * alpha[a,b] + x * gamma[a,b] + sigma^2 * sum_j G_j[a,b] / (x - sigma * lam_j)

    exactly (the Schur complement expanded on the arm's two clamped-base modes). ``cols`` lists
    the clamp DOFs wanted (0 = xc, 1 = phic). Returns (lam, G, alpha, gamma): lam a list of two
    arrays, G/alpha/gamma dicts keyed by (a, b).
    """
    Kff, Mff, Kfb, Mfb, Kbb, Mbb = _arm_matrices(p, arm)
    modes = _modes(Kff, Mff)
    lam, g, r = [], [], []
    for lam_j, (f0, f1) in modes:
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


def _condensed(p, ej, beta1, beta2, omega, full):
    """Entries (h00, h01, h11) of the clamp impedance H; each broadcasts to (n, n_freq).

    ``H[a,b] = const + x * lin + sum over the four modes of R / (x - pole)``, ``x = omega^2``:
    the per-set constants are cheap, and only four complex divisions per line remain.
    """
    x = omega * omega
    keys = ((0, 0), (0, 1), (1, 1)) if full else ((0, 0),)
    mc, ac = p["mc"], p["ac"]
    const = dict.fromkeys(keys, 0.0)
    lin = {(0, 0): -mc, (0, 1): -mc * ac, (1, 1): -(p["Jc"] + mc * ac * ac)}  # clamp inertia
    fractions = {key: [] for key in keys}
    for arm, beta in ((1, beta1), (2, beta2)):
        sigma = ej * (1 + 1j * beta)
        lam, G, alpha, gamma = _modal_arm(p, arm, (0, 1) if full else (0,))
        poles = [sigma * lam_j for lam_j in lam]
        s2 = sigma * sigma
        for key in keys:
            const[key] = const[key] + sigma * alpha[key]
            lin[key] = lin[key] + gamma[key]
            fractions[key] += [(s2 * G[key][j], poles[j]) for j in (0, 1)]
    h = []
    for key in keys:
        acc = const[key] + x * lin[key]
        for R, pole in fractions[key]:
            acc = acc + R / (x - pole)
        h.append(acc)
    return (h[0], None, None) if not full else tuple(h)


def _prepare(damper, freq_hz, params):
    p, n_sets = _resolve(damper, params)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1:
        raise InputError(f"freq_hz: expected shape (n_freq,), got {f.shape}")
    omega = (2 * np.pi * f)[None, :]
    ej = _rigidity(p, omega, damper)
    beta = p.get("beta", np.zeros((1, 1)))
    return p, n_sets, omega, ej, p.get("beta1", beta), p.get("beta2", beta)


def dynamic_stiffness(damper: Damper, freq_hz, **params) -> np.ndarray:
    """Dynamic stiffness ``f_uu(omega)``: force on the base per unit vertical base motion.

    Parameters
    ----------
    damper : Damper
        Nominal description; supplies every parameter not given.
    freq_hz : array_like, shape (n_freq,)
        Frequencies [Hz].
    **params : float or array_like of shape (n_sets,)
        Any of :data:`PARAMETER_NAMES` (see the module docstring); broadcast against each other.

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq)
        ``f_uu`` [N/m]; magnitude is the bench's "dynamic stiffness", angle its phase
        (in (0, pi) for a passive damper with ``beta > 0``).
    """
    p, n_sets, omega, ej, b1, b2 = _prepare(damper, freq_hz, params)
    h00, _, _ = _condensed(p, ej, b1, b2, omega, full=False)
    return np.broadcast_to(h00, (n_sets, omega.shape[1])).copy() if h00.shape[0] != n_sets else h00


def clamp_impedance(damper: Damper, freq_hz, **params) -> np.ndarray:
    """The full clamp impedance matrix ``H = [[f_uu, f_uphi], [f_phiu, f_phiphi]]``.

    Same arguments as :func:`dynamic_stiffness`. Returns complex ``(n_sets, n_freq, 2, 2)``;
    units N/m, N/rad, N m/m, N m/rad. H is symmetric (reciprocity).
    """
    p, n_sets, omega, ej, b1, b2 = _prepare(damper, freq_hz, params)
    h00, h01, h11 = (np.broadcast_to(h, (n_sets, omega.shape[1]))
                     for h in _condensed(p, ej, b1, b2, omega, full=True))
    return np.stack([np.stack([h00, h01], -1), np.stack([h01, h11], -1)], -2)


def natural_frequencies(damper: Damper, **params) -> np.ndarray:
    """Undamped natural frequencies of the damper with its clamp held fixed [Hz].

    These are the poles of ``f_uu``: the roots of ``det(K_FF - lambda M_FF) = 0``, two per arm.
    Accepts the parameters of :func:`dynamic_stiffness` except the polynomial q1..q5
    (a frequency-dependent EJ has no fixed eigenproblem); damping is ignored.

    Returns
    -------
    ndarray, shape (n_sets, 4)
        Ascending frequencies [Hz].
    """
    if any(q in params for q in _POLY):
        raise InputError("natural_frequencies: EJ(omega) as a polynomial has no fixed eigenproblem")
    p, n_sets, _, ej, _, _ = _prepare(damper, [1.0], params)
    lam = [ej * lam_j for arm in (1, 2) for lam_j, _ in _modes(*_arm_matrices(p, arm)[:2])]
    lam = np.concatenate([np.broadcast_to(v, (n_sets, 1)) for v in lam], axis=1)
    return np.sort(np.sqrt(lam) / (2 * np.pi), axis=1)
