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
with per-set constants: four complex divisions per frequency line. The constants and the per-line sums
run compiled, one fused loop over sets and lines (:mod:`sbcal.model.fem_kernel`); this module checks and
broadcasts the parameters to it. Results have shape ``(n_sets, n_freq)``.

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

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from . import fem_kernel
from .damper import GEOMETRY, Damper


__all__ = [
    "PARAMETER_NAMES",
    "STANDARD_GRID_HZ",
    "dynamic_stiffness",
    "clamp_impedance",
    "natural_frequencies",
    "arm_impedance",
    "free_response",
    "arm_curvatures",
    "arm_kernel",
    "ArmKernel",
]

_POLY = ("q1", "q2", "q3", "q4", "q5")
PARAMETER_NAMES = ("EJ", "beta", "beta1", "beta2") + _POLY + GEOMETRY
"""The public parameter vocabulary shared by the model, the priors, the CLI and the reports."""

STANDARD_GRID_HZ = np.concatenate(
    [np.arange(4.0, 9.01, 0.5), np.arange(10.0, 30.01, 1.0), np.arange(32.0, 40.01, 2.0)]
)
"""The reference bench's 37 frequency lines [Hz]: 4-9 by 0.5, 10-30 by 1, 32-40 by 2."""


def _resolve(damper: Damper, params: dict) -> tuple[dict, int]:
    """Check names and shapes; return each given parameter as an array of shape (n or 1, 1)."""
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
        if a.ndim > 1 or a.size == 0:
            raise InputError(f"parameter {name!r}: expected a scalar or shape (n_sets,), got shape {a.shape}")
        if a.ndim == 1:
            if n_sets not in (1, a.size) and a.size != 1:
                raise InputError(f"parameter {name!r}: {a.size} sets where others have {n_sets}")
            n_sets = max(n_sets, a.size)
        out[name] = a.reshape(-1, 1)
    return out, n_sets


def _geometry(damper: Damper, p: dict) -> np.ndarray:
    """:data:`GEOMETRY` by row, the damper's nominal values where ``p`` gives none: shape (12, 1 or n_sets)."""
    base = np.array([getattr(damper, name) for name in GEOMETRY])[:, None]
    given = [name for name in GEOMETRY if name in p]
    if not given:
        return base
    g = np.repeat(base, max(p[name].shape[0] for name in given), axis=1)
    for name in given:
        g[GEOMETRY.index(name)] = p[name][:, 0]
    return g


def _rigidity(p: dict, omega: np.ndarray, damper: Damper):
    """EJ of each set: shape (n or 1, 1), or (n or 1, n_freq) for the polynomial."""
    if any(q in p for q in _POLY):
        ej = np.zeros((1, 1))
        for q in reversed(_POLY):  # Horner
            ej = ej * omega + p.get(q, 0.0)
        return ej
    return p.get("EJ", np.full((1, 1), damper.ej_static))


def _condensed(geometry, ej1, ej2, beta1, beta2, omega, n_sets, full):
    """The clamp impedance's entries, complex (3 or 1, n_sets, n_freq): ``H[0, 0]`` (and ``H[0, 1]``,
    ``H[1, 1]`` when ``full``), compiled (:func:`sbcal.model.fem_kernel.impedance`). ``ej1, ej2, beta1,
    beta2`` per arm, shape (n or 1, 1 or n_freq); ``omega`` (1, n_freq)."""
    arms = (np.ascontiguousarray(a, dtype=float) for a in (ej1, ej2, beta1, beta2))
    return fem_kernel.impedance(np.ascontiguousarray(geometry), *arms, np.ascontiguousarray(omega[0]), n_sets, full)


def _prepare(damper, freq_hz, params):
    p, n_sets = _resolve(damper, params)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1:
        raise InputError(f"freq_hz: expected shape (n_freq,), got {f.shape}")
    omega = (2 * np.pi * f)[None, :]
    ej = _rigidity(p, omega, damper)
    beta = p.get("beta", np.zeros((1, 1)))
    return p, n_sets, omega, ej, p.get("beta1", beta), p.get("beta2", beta)


def _matrix(h) -> np.ndarray:
    """(3, n, n_freq) entries to the symmetric (n, n_freq, 2, 2) H."""
    return np.stack([np.stack([h[0], h[1]], -1), np.stack([h[1], h[2]], -1)], -2)


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
    return _condensed(_geometry(damper, p), ej, ej, b1, b2, omega, n_sets, full=False)[0]


def clamp_impedance(damper: Damper, freq_hz, **params) -> np.ndarray:
    """The full clamp impedance matrix ``H = [[f_uu, f_uphi], [f_phiu, f_phiphi]]``.

    Same arguments as :func:`dynamic_stiffness`. Returns complex ``(n_sets, n_freq, 2, 2)``;
    units N/m, N/rad, N m/m, N m/rad. H is symmetric (reciprocity).
    """
    p, n_sets, omega, ej, b1, b2 = _prepare(damper, freq_hz, params)
    return _matrix(_condensed(_geometry(damper, p), ej, ej, b1, b2, omega, n_sets, full=True))


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
    constants = fem_kernel.modal_constants(_geometry(damper, p))  # (n or 1, arm, N_CONSTANTS)
    lam = np.broadcast_to(ej * constants[:, :, :2].reshape(-1, 4), (n_sets, 4))  # lam_j at EJ = 1, times EJ
    return np.sort(np.sqrt(lam) / (2 * np.pi), axis=1)


# --- per-arm, per-line rigidity and loss (the virtual bench's nonlinear physics) ----------------

def _prepare_arms(damper, freq_hz, arms, geometry):
    """Validate per-arm per-line values and geometry overrides.

    ``arms`` maps names to values that are scalars or 2-D arrays broadcastable to
    ``(n_sets, n_freq)``; ``geometry`` holds :data:`GEOMETRY` overrides (scalar or ``(n_sets,)``).
    Returns ``(p, n_sets, omega, values)`` with ``values`` a list of 2-D arrays.
    """
    not_geometry = sorted(set(geometry) - set(GEOMETRY))
    if not_geometry:
        raise InputError(f"unknown geometry parameter {not_geometry[0]!r}; known: {', '.join(GEOMETRY)}")
    p, n_sets = _resolve(damper, geometry)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1:
        raise InputError(f"freq_hz: expected shape (n_freq,), got {f.shape}")
    values = []
    for name, value in arms.items():
        a = np.asarray(value)
        a = a.reshape(1, 1) if a.ndim == 0 else a
        # a 1-D array would be ambiguous (sets or lines?): ask for 2-D
        if (a.ndim != 2 or a.size == 0 or a.shape[1] not in (1, f.size)
                or (a.shape[0] not in (1, n_sets) and n_sets != 1)):
            raise InputError(f"{name}: expected a scalar or shape (n_sets or 1, n_freq or 1), got shape {a.shape}")
        n_sets = max(n_sets, a.shape[0])
        values.append(a)
    return p, n_sets, (2 * np.pi * f)[None, :], values


def arm_impedance(damper: Damper, freq_hz, *, ej1, ej2, beta1=0.0, beta2=0.0, **geometry) -> np.ndarray:
    """Clamp impedance H with each arm's own EJ and loss factor, possibly different per line.

    The same exact condensation as :func:`clamp_impedance`, with ``sigma_e = EJ_e (1 + i beta_e)``
    per arm e; a value that changes from line to line is evaluated pointwise (as the polynomial
    EJ(omega) is).

    Parameters
    ----------
    damper : Damper
    freq_hz : array_like, shape (n_freq,)
        Frequencies [Hz].
    ej1, ej2 : float or array_like, shape (n_sets or 1, n_freq or 1)
        Flexural rigidity of arm 1 (mass 1 - clamp) and arm 2 (clamp - mass 2) [N m^2].
    beta1, beta2 : float or array_like, shape (n_sets or 1, n_freq or 1)
        Hysteretic loss factors of the two arms.
    **geometry : float or array_like, shape (n_sets,)
        Overrides of the geometry (``m1, J1, a1, ..., L1, L2, mu``).

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq, 2, 2)
        ``[[f_uu, f_uphi], [f_phiu, f_phiphi]]`` [N/m, N/rad, N m/m, N m/rad].
    """
    p, n, omega, (e1, e2, b1, b2) = _prepare_arms(
        damper, freq_hz, dict(ej1=ej1, ej2=ej2, beta1=beta1, beta2=beta2), geometry)
    return _matrix(_condensed(_geometry(damper, p), e1, e2, b1, b2, omega, n, full=True))


@dataclass(frozen=True, eq=False)
class ArmKernel:
    """Each arm's clamped-base modes and clamp coupling at unit EJ, for repeated evaluations.

    The constants depend on the geometry only, so a solver that re-evaluates the free-node response
    for many trial rigidities and loss factors (the virtual bench's strand slip) builds them once.
    Made by :func:`arm_kernel`; every array has a leading arm axis of length 2, then the set axis.

    Attributes
    ----------
    lam : tuple of two ndarray, shape (2, n or 1, 1)
        Eigenvalues of the two clamped-base modes at EJ = 1 [1/(m^2 kg) scale: omega^2 / EJ].
    phi : tuple of two pairs of ndarray
        Mass-normalised mode shapes (free displacement, free rotation).
    g, r : tuple of two pairs of ndarray
        ``r_ja = phi_j . M_Fb[:, a]`` and ``g_ja = phi_j . Khat_Fb[:, a] - lam_j r_ja`` for the clamp
        DOFs a = (xc, phic).
    length : ndarray, shape (2, n or 1, 1)
        Arm lengths [m].
    n_sets : int
    """

    lam: tuple
    phi: tuple
    g: tuple
    r: tuple
    length: np.ndarray
    n_sets: int

    def free_response(self, omega, sigma, xc, phic):
        """``X_F`` of each arm: complex (2 arms, n, n_freq, 2 dofs).

        ``omega`` (1, n_freq) [rad/s]; ``sigma = EJ_e (1 + i beta_e)`` (2, n or 1, n_freq or 1);
        ``xc, phic`` clamp motion, broadcastable to (n, n_freq). Per arm::

            X_F = sum_j phi_j [sigma (g_j . X_B) / (omega^2 - sigma lam_j) - r_j . X_B]
        """
        x = omega * omega
        u0 = u1 = 0.0
        for lam_j, (f0, f1), (g0, g1), (r0, r1) in zip(self.lam, self.phi, self.g, self.r):
            q = sigma * (g0 * xc + g1 * phic) / (x - sigma * lam_j) - (r0 * xc + r1 * phic)
            u0 = u0 + f0 * q
            u1 = u1 + f1 * q
        u0, u1 = np.broadcast_arrays(u0, u1)
        return np.stack([u0, u1], -1)

    def curvatures(self, omega, sigma, xc, phic):
        """End curvatures of each arm [1/m]: complex (n, n_freq, 2 arms, 2 ends); see :func:`arm_curvatures`."""
        xf = self.free_response(omega, sigma, xc, phic)
        l = self.length
        xc, phic = np.broadcast_to(xc, xf.shape[1:3]), np.broadcast_to(phic, xf.shape[1:3])
        # node a then node b along y: arm 1 (mass 1, clamp), arm 2 (clamp, mass 2)
        wa, ta = np.stack([xf[0, ..., 0], xc]), np.stack([xf[0, ..., 1], phic])
        wb, tb = np.stack([xc, xf[1, ..., 0]]), np.stack([phic, xf[1, ..., 1]])
        c0 = (-6 * wa - 4 * l * ta + 6 * wb - 2 * l * tb) / l**2
        c1 = (6 * wa + 2 * l * ta - 6 * wb + 4 * l * tb) / l**2
        return np.moveaxis(np.stack([c0, c1], -1), 0, -2)


def _kernel(damper, p, n_sets) -> ArmKernel:
    geometry = _geometry(damper, p)
    c = np.moveaxis(fem_kernel.modal_constants(geometry), 0, -1)[..., None]  # (arm, N_CONSTANTS, n or 1, 1)
    lam = (c[:, 0], c[:, 1])
    phi = ((c[:, 2], c[:, 3]), (c[:, 4], c[:, 5]))
    g = ((c[:, 6], c[:, 7]), (c[:, 8], c[:, 9]))
    r = ((c[:, 10], c[:, 11]), (c[:, 12], c[:, 13]))
    length = geometry[[GEOMETRY.index("L1"), GEOMETRY.index("L2")]][:, :, None]
    return ArmKernel(lam, phi, g, r, length, n_sets)


def arm_kernel(damper: Damper, **geometry) -> ArmKernel:
    """The per-arm modal constants of :class:`ArmKernel` for a damper and geometry overrides.

    ``**geometry``: ``m1, J1, a1, ..., L1, L2, mu``, each a scalar or shape (n_sets,).
    """
    p, n_sets, _, _ = _prepare_arms(damper, [1.0], {}, geometry)
    return _kernel(damper, p, n_sets)


def free_response(damper: Damper, freq_hz, *, ej1, ej2, beta1=0.0, beta2=0.0, xc=1.0, phic=0.0,
                  **geometry) -> np.ndarray:
    """Motion of the two end-mass nodes for a prescribed clamp motion: ``X_F = -Z_FF^-1 Z_FB X_B``.

    Evaluated on each arm's two clamped-base modes (as :func:`arm_impedance`), per arm::

        X_F = sum_j phi_j [sigma (g_j . X_B) / (omega^2 - sigma lam_j) - r_j . X_B]

    Parameters
    ----------
    damper, freq_hz, ej1, ej2, beta1, beta2, **geometry
        As :func:`arm_impedance`.
    xc : complex or array_like, shape (n_sets or 1, n_freq or 1)
        Clamp displacement amplitude [m] (complex phasor, time convention ``exp(+i omega t)``).
    phic : complex or array_like, shape (n_sets or 1, n_freq or 1)
        Clamp rotation amplitude [rad].

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq, 2, 2)
        ``[..., arm, dof]``: arm 0 is the mass-1 node ``(x1, phi1)``, arm 1 the mass-2 node
        ``(x2, phi2)``; displacements [m], rotations ``dx/dy`` [rad].
    """
    p, n, omega, (e1, e2, b1, b2, xb0, xb1) = _prepare_arms(
        damper, freq_hz, dict(ej1=ej1, ej2=ej2, beta1=beta1, beta2=beta2, xc=xc, phic=phic), geometry)
    sigma = np.stack(np.broadcast_arrays(e1 * (1 + 1j * b1), e2 * (1 + 1j * b2)))
    xf = _kernel(damper, p, n).free_response(omega, sigma, xb0, xb1)
    return np.moveaxis(np.broadcast_to(xf, (2, n, omega.shape[1], 2)), 0, -2).copy()


def arm_curvatures(damper: Damper, freq_hz, *, ej1, ej2, beta1=0.0, beta2=0.0, xc=1.0, phic=0.0,
                   **geometry) -> np.ndarray:
    """Curvature amplitudes ``d^2 x / dy^2`` at the two ends of each arm [1/m].

    The Hermite element's curvature is linear along it; at its ends (local ``s = 0`` and ``s = l``,
    nodes a then b along y)::

        chi(0) = (-6 w_a - 4 l t_a + 6 w_b - 2 l t_b) / l^2
        chi(l) = ( 6 w_a + 2 l t_a - 6 w_b + 4 l t_b) / l^2

    Arm 1 runs mass 1 (a) -> clamp (b), arm 2 clamp (a) -> mass 2 (b). Arguments as
    :func:`free_response`; for many evaluations with one geometry, :func:`arm_kernel` skips the
    setup.

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq, 2, 2)
        ``[..., arm, end]``; end 0 is the end at the smaller y (arm 1: mass 1; arm 2: the clamp).
    """
    p, n, omega, (e1, e2, b1, b2, xb0, xb1) = _prepare_arms(
        damper, freq_hz, dict(ej1=ej1, ej2=ej2, beta1=beta1, beta2=beta2, xc=xc, phic=phic), geometry)
    sigma = np.stack(np.broadcast_arrays(e1 * (1 + 1j * b1), e2 * (1 + 1j * b2)))
    chi = _kernel(damper, p, n).curvatures(omega, np.broadcast_to(sigma, (2, n, omega.shape[1])), xb0, xb1)
    return chi.copy()
