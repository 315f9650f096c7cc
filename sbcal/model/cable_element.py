"""The element cable model (the virtual bench's): Euler-Bernoulli elements along each arm, each section's
rigidity from the law at its own curvature, solved by Newton iterations on the curvatures
(``docs/cable.md``, "Two models").

The law may change along the arm: a :class:`sbcal.model.laws.zones.ZonedLaw` (the fitted model's zones, its
parameters given to :meth:`ElementCableModel.state` like every law parameter), or fixed boundary zones
:class:`sbcal.model.cable_zones.CableZone` with a law of their own, of any family (richer than the fitted model: the virtual
bench's). Either way the mesh puts nodes at the zone boundaries and each element takes its zone's law.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import InputError
from .cable import CableBase
from .cable_sections import FD_LOG_STEP, TINY, checked_grid
from .cable_zones import UNIT_CHI, UNIT_EJ, CableZone, zone_spec, zoned_mesh
from .damper import Damper
from .laws.zones import ZonedLaw


__all__ = ["DEFAULT_N_ELEMENTS", "ElementCableState", "ElementCableModel"]

DEFAULT_N_ELEMENTS = 6
"""Elements per arm of :class:`ElementCableModel` (the convergence study of ``docs/cable.md``)."""

_MAX_LOG_STEP = 2.0  # element model: Newton step cap in ln chi (a factor e^2 per iteration)
# --- the element model (the virtual bench) ---------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ElementCableState:
    """The distributed cable's steady state per parameter set and frequency line.

    Attributes
    ----------
    f_uu, fold
        As :class:`sbcal.model.cable.CableState` (the element model always follows the sweep).
    curvature : ndarray, shape (n_sets, n_freq, 2, N)
        Element curvature amplitudes [1/m] (rms over each element), arm 1 (mass 1 - clamp) then
        arm 2 (clamp - mass 2), elements numbered from the clamp outward.
    rigidity : ndarray of complex, shape (n_sets, n_freq, 2, N)
        Element secant rigidity ``EJ*_e`` [N m^2].
    converged : ndarray of bool, shape (n_sets, n_freq)
        The fixed point met the tolerance on both arms.
    residual : ndarray, shape (n_sets, n_freq)
        ``max |ln T(chi) - ln chi|`` over arms and elements at the returned state.
    iterations : int
        Newton iterations, summed over the passes.
    mesh : ndarray, shape (N + 1,)
        Node positions along each arm from the clamp, as fractions of the arm's length (a zoned
        cable's with its zone boundaries among them; N may then exceed ``n_elements``, at least
        :data:`sbcal.model.cable_zones.MIN_ZONE_ELEMENTS` per zone).
    """

    f_uu: np.ndarray
    curvature: np.ndarray
    rigidity: np.ndarray
    converged: np.ndarray
    fold: np.ndarray
    residual: np.ndarray
    iterations: int
    mesh: np.ndarray

    @property
    def curvature_range(self) -> np.ndarray:
        """Smallest and largest element curvature amplitude per line [1/m], shape (n_sets, n_freq, 2)."""
        c = self.curvature.reshape(*self.curvature.shape[:2], -1)
        return np.stack([c.min(axis=-1), c.max(axis=-1)], axis=-1)


# --- 2x2 block algebra on batches (tuples of arrays: (a00, a01, a10, a11); symmetric: (a00, a01, a11))

def _sym_inv(s00, s01, s11):
    d = 1.0 / (s00 * s11 - s01 * s01)
    return s11 * d, -s01 * d, s00 * d


def _mat_vec(m, v0, v1):
    return m[0] * v0 + m[1] * v1, m[2] * v0 + m[3] * v1


def _mat_t_vec(m, v0, v1):
    return m[0] * v0 + m[2] * v1, m[1] * v0 + m[3] * v1


@dataclass(frozen=True, eq=False)
class _Batch:
    """Per-(set, line, arm) constants, flattened on one batch axis b = (set * n_freq + line) * 2 + arm.

    Element quantities have shape (N, B): element-major, so one element's row is contiguous.
    """

    k12: np.ndarray  # 12 / h^3
    k6: np.ndarray  # 6 / h^2
    k4: np.ndarray  # 4 / h
    k2: np.ndarray  # 2 / h
    inv_h: np.ndarray  # 1 / h
    h: np.ndarray
    wm: tuple  # omega^2 x consistent-mass entries: 156 c, 22 c h, 4 c h^2, 54 c, 13 c h, 3 c h^2
    tip: tuple  # omega^2 x end-mass block (00, 01, 11)
    x0: np.ndarray  # clamp displacement amplitude [m], (B,)
    t0: np.ndarray  # clamp rotation along the arm [rad], (B,)
    linear: np.ndarray  # EJ_min (1 + i beta_material), (B,)
    law_params: dict  # each (B, 1)
    zones: tuple = None  # zoned cable: per zone (elements slice, law, params each (B, 1), EJ_min ratio (B,) or float)

    @property
    def n(self) -> int:
        """Elements per arm."""
        return self.h.shape[0]

    def take(self, idx):
        """The constants of the batch entries ``idx``."""
        zones = self.zones
        if zones is not None:
            zones = tuple((sl, law, {k: v[idx] for k, v in lp.items()}, r[idx] if np.ndim(r) else r)
                          for sl, law, lp, r in zones)
        return _Batch(k12=self.k12[:, idx], k6=self.k6[:, idx], k4=self.k4[:, idx], k2=self.k2[:, idx],
                      inv_h=self.inv_h[:, idx], h=self.h[:, idx], wm=tuple(w[:, idx] for w in self.wm),
                      tip=tuple(t[idx] for t in self.tip), x0=self.x0[idx], t0=self.t0[idx],
                      linear=self.linear[idx], law_params={k: v[idx] for k, v in self.law_params.items()},
                      zones=zones)


class _ElementArms:
    """One factorisation of every arm's free-node dynamic stiffness at given element rigidities."""

    def __init__(self, c: _Batch, sigma):
        n = sigma.shape[0]
        self.c, self.n = c, n
        wm156, wm22, wm4, wm54, wm13, wm3 = c.wm
        # element blocks: Zaa (sym), Zbb (sym; shares 00 and 11 with Zaa), Zab (full; Zba = Zab^T)
        self.zaa, self.zab = [], []
        for e in range(n):
            s = sigma[e]
            a00 = s * c.k12[e] - wm156[e]
            a01 = s * c.k6[e] - wm22[e]
            a11 = s * c.k4[e] - wm4[e]
            self.zaa.append((a00, a01, a11))
            self.zab.append((-s * c.k12[e] - wm54[e], s * c.k6[e] + wm13[e], -s * c.k6[e] - wm13[e], s * c.k2[e] + wm3[e]))
        # Schur complements from the end mass inward: S_N = Zbb_{N-1} + tip, S_k = Zbb_{k-1} + Zaa_k - Zab_k S_{k+1}^-1 Zba_k
        # G_k = S_k^-1 Zba_{k-1} (the response propagates X_k = -G_k X_{k-1}); Sinv_k kept for other loads.
        self.g = [None] * (n + 1)
        self.sinv = [None] * (n + 1)
        a00, a01, a11 = self.zaa[n - 1]
        s00, s01, s11 = a00 - c.tip[0], -a01 - c.tip[1], a11 - c.tip[2]
        for k in range(n, 0, -1):
            i00, i01, i11 = _sym_inv(s00, s01, s11)
            z = self.zab[k - 1]  # element k-1 joins nodes k-1 (a) and k (b); Zba = Zab^T
            g = (i00 * z[0] + i01 * z[1], i00 * z[2] + i01 * z[3], i01 * z[0] + i11 * z[1], i01 * z[2] + i11 * z[3])
            self.g[k], self.sinv[k] = g, (i00, i01, i11)
            if k > 1:
                # Zab_{k-1} G_k, symmetric part only
                p00 = z[0] * g[0] + z[1] * g[2]
                p01 = z[0] * g[1] + z[1] * g[3]
                p11 = z[2] * g[1] + z[3] * g[3]
                b00, b01, b11 = self.zaa[k - 2]
                a00, a01, a11 = self.zaa[k - 1]
                s00, s01, s11 = b00 + a00 - p00, -b01 + a01 - p01, b11 + a11 - p11
        # condensed clamp impedance of the arm: Zaa_0 - Zab_0 G_1
        z, g = self.zab[0], self.g[1]
        a00, a01, a11 = self.zaa[0]
        self.h00 = a00 - (z[0] * g[0] + z[1] * g[2])
        self.h01 = a01 - (z[0] * g[1] + z[1] * g[3])

    def response(self):
        """Node motions X_0 .. X_N for the prescribed clamp motion: list of (w, t)."""
        c = self.c
        x = [(c.x0.astype(complex), c.t0.astype(complex))]
        for k in range(1, self.n + 1):
            w, t = _mat_vec(self.g[k], *x[-1])
            x.append((-w, -t))
        return x

    def deformation(self):
        """Node motions less the clamp's rigid motion (``w = x0 + t0 s``, ``t = t0``), nodes 0 .. N
        (node 0 zero): list of (w, t). Solved for the inertial load of the rigid motion (which the
        stiffness does not feel), so the curvatures need not cancel the clamp's motion between
        neighbouring nodes: their rounding is relative to the deformation, not to ``x0``, whose
        cancellation over short elements (~eps x0 / h^2) is the rounding floor of :meth:`response`'s
        (~1e-9 in ln chi at 4 Hz with 12 elements on damper1). Used by zoned cables (shorter elements)."""
        c, n = self.c, self.n
        s = np.concatenate([np.zeros((1, c.h.shape[1])), np.cumsum(c.h, axis=0)])
        t = c.t0
        w = c.x0 + t * s  # (N + 1, B)
        wm156, wm22, wm4, wm54, wm13, wm3 = c.wm
        r = []
        for k in range(1, n + 1):
            e = k - 1  # the element whose mass-side node is k: M_ba X_a + M_bb X_b
            rw = wm54[e] * w[k - 1] + wm13[e] * t + wm156[e] * w[k] - wm22[e] * t
            rt = -wm13[e] * w[k - 1] - wm3[e] * t - wm22[e] * w[k] + wm4[e] * t
            if k < n:  # the element whose clamp-side node is k: M_aa X_a + M_ab X_b
                e = k
                rw = rw + wm156[e] * w[k] + wm22[e] * t + wm54[e] * w[k + 1] - wm13[e] * t
                rt = rt + wm22[e] * w[k] + wm4[e] * t + wm13[e] * w[k + 1] - wm3[e] * t
            else:  # the end mass
                rw = rw + c.tip[0] * w[k] + c.tip[1] * t
                rt = rt + c.tip[1] * w[k] + c.tip[2] * t
            r.append((rw[:, None].astype(complex), rt[:, None].astype(complex)))
        zero = np.zeros(c.x0.shape, dtype=complex)
        return [(zero, zero)] + [(yw[:, 0], yt[:, 0]) for yw, yt in self.solve(r)]

    def clamp_force(self):
        """Vertical force of the arm on the clamp [N] for the prescribed motion."""
        return self.h00 * self.c.x0 + self.h01 * self.c.t0

    def solve(self, r):
        """``Z_FF y = r``: r a list over free nodes 1..N of (r_w, r_t), each (B, m); returns y likewise."""
        n = self.n
        yt = [None] * (n + 1)
        yt[n] = r[n - 1]
        for k in range(n - 1, 0, -1):
            # y~_k = r_k - Zab_k S_{k+1}^-1 y~_{k+1} = r_k - G_{k+1}^T y~_{k+1}
            g = tuple(v[:, None] for v in self.g[k + 1])
            w, t = _mat_t_vec(g, *yt[k + 1])
            yt[k] = (r[k - 1][0] - w, r[k - 1][1] - t)
        y = [None] * (n + 1)
        i00, i01, i11 = (v[:, None] for v in self.sinv[1])
        y[1] = (i00 * yt[1][0] + i01 * yt[1][1], i01 * yt[1][0] + i11 * yt[1][1])
        for k in range(2, n + 1):
            i00, i01, i11 = (v[:, None] for v in self.sinv[k])
            g = tuple(v[:, None] for v in self.g[k])
            gw, gt = _mat_vec(g, *y[k - 1])
            y[k] = (i00 * yt[k][0] + i01 * yt[k][1] - gw, i01 * yt[k][0] + i11 * yt[k][1] - gt)
        return y[1:]


def _curvature_ends(c: _Batch, x, e):
    """Curvatures at the clamp-side and mass-side ends of element e: Hermite second derivatives."""
    (wa, ta), (wb, tb) = x[e], x[e + 1]
    h, ih = c.h[e], c.inv_h[e]
    if wa.ndim == 2:
        h, ih = h[:, None], ih[:, None]
    c0 = (6 * (wb - wa) * ih - 4 * ta - 2 * tb) * ih
    c1 = (6 * (wa - wb) * ih + 2 * ta + 4 * tb) * ih
    return c0, c1


def _rms(c0, c1):
    return np.sqrt(np.maximum((c0.real**2 + c0.imag**2 + c1.real**2 + c1.imag**2
                               + (c0 * np.conj(c1)).real) / 3.0, 0.0))


def _solve_small(a, b):
    """Batched ``a x = b`` for (m, n, n) and (m, n); NaN rows where a matrix is singular."""
    try:
        return np.linalg.solve(a, b[..., None])[..., 0]
    except np.linalg.LinAlgError:  # one singular matrix fails the whole batch: solve one by one
        out = np.full(b.shape, np.nan)
        for i in range(a.shape[0]):
            try:
                out[i] = np.linalg.solve(a[i], b[i])
            except np.linalg.LinAlgError:
                pass
        return out


@dataclass(frozen=True)
class ElementCableModel(CableBase):
    """The distributed strand-slip cable: ``f_uu`` and its steady state for parameter sets.

    Parameters (keyword arguments of :meth:`state`): those of :class:`sbcal.model.cable.CableModel`
    (with a :class:`sbcal.model.laws.zones.ZonedLaw`, its zones' too: ``clamp_zone`` and ``mass_zone`` a
    scalar or equal across the sets, since they place the mesh's nodes).

    A zoned cable (a ``ZonedLaw``, or :attr:`zones`) has nodes at its zone boundaries: each zone gets
    elements in proportion to its length, at least :data:`sbcal.model.cable_zones.MIN_ZONE_ELEMENTS`, ``n_elements`` in all
    (more when ``n_elements`` is below ``MIN_ZONE_ELEMENTS`` per zone); each element's rigidity is its
    zone's ``EJ_min * EJ_min_ratio * (1 + i beta_material) + EJ_slip*(chi_e)`` of its zone's law, and
    the curvatures come from the arm's deformation (:meth:`_ElementArms.deformation`: its shorter
    elements would put the rounding of node motions dominated by the clamp's at the tolerance).

    Attributes
    ----------
    law : HysteresisLaw or None
        The slip part's law (with :attr:`zones`: the middle's); None is the linear cable
        ``EJ_min (1 + i beta_material)``.
    n_elements : int
        Hermite elements per arm (a zoned cable's in all its zones).
    grading : float
        Length of the element at the end mass over that at the clamp (1: uniform; > 1: finer at
        the clamp, where the curvature peaks), geometric progression. Uniform cables only.
    max_iter : int
        Newton iteration budget per pass (a fixed budget: the model is a deterministic function).
    tol : float
        Convergence tolerance on ``max |ln T(chi) - ln chi|`` per arm.
    fold_tol : float
        Two solutions of one line are distinct when their ``ln chi`` differ by more than this.
    zones : tuple of CableZone
        Fixed boundary zones with laws of their own (at most one at the clamp and one at the mass);
        :attr:`law` is the middle's, not a ``ZonedLaw``.
    """

    n_elements: int = DEFAULT_N_ELEMENTS
    grading: float = 1.0
    max_iter: int = 20
    tol: float = 1e-9
    fold_tol: float = 1e-4
    zones: tuple = ()
    _mesh: np.ndarray = field(init=False, repr=False, compare=False)
    _zone_specs: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if int(self.n_elements) != self.n_elements or self.n_elements < 1:
            raise InputError(f"n_elements: expected an integer >= 1, got {self.n_elements!r}")
        if not (np.isfinite(self.grading) and self.grading > 0):
            raise InputError(f"grading: expected a finite value > 0, got {self.grading!r}")
        zones = tuple(self.zones or ())
        if not all(isinstance(z, CableZone) for z in zones):
            raise InputError("zones: expected CableZone values")
        if zones and self.law is None:
            raise InputError("zones: the cable needs a law in its middle (law is None)")
        if zones and isinstance(self.law, ZonedLaw):
            raise InputError(f"zones: the law {self.law.name} has its own zones; give its family "
                             f"({self.law.base.name}) with zones, or the zoned law without")
        where = [z.where for z in zones]
        if len(set(where)) != len(where):
            raise InputError(f"zones: one zone per end, got {', '.join(where)}")
        if (zones or isinstance(self.law, ZonedLaw)) and self.grading != 1.0:
            raise InputError("grading: a zoned cable's elements are uniform within each zone (grading 1)")
        object.__setattr__(self, "zones", zones)
        object.__setattr__(self, "_zone_specs", tuple(zone_spec(z, self.law) for z in zones))
        n = int(self.n_elements)
        if zones:
            lengths = {z.where: z.length for z in zones}
            mesh, _ = zoned_mesh(lengths.get("clamp", 0.0), lengths.get("mass", 0.0), n)
        else:
            ratio = self.grading ** (1.0 / (n - 1)) if n > 1 else 1.0
            lengths = ratio ** np.arange(n)
            mesh = np.concatenate([[0.0], np.cumsum(lengths) / lengths.sum()])
        object.__setattr__(self, "_mesh", mesh)

    @property
    def zoned(self) -> bool:
        """The law changes along the arm (a :class:`sbcal.model.laws.zones.ZonedLaw` or :attr:`zones`)."""
        return bool(self.zones) or isinstance(self.law, ZonedLaw)

    def _zone_laws(self, p: dict, zone_scale):
        """A zoned cable's zones: ``[(zone, law, params, EJ_min ratio)]`` (zone ``"middle"``, ``"clamp"``
        or ``"mass"``; values of shape (n_sets or 1,) or scalars); None for a uniform cable."""
        if isinstance(self.law, ZonedLaw):
            return [(name, self.law.base, lp, ratio) for name, _, lp, ratio in self.law.zones(p)]
        if not self.zones:
            return None
        ej, chi = (1.0, 1.0) if zone_scale is None else zone_scale
        factor = {UNIT_EJ: ej, UNIT_CHI: chi}
        out = [("middle", self.law, {k: p[k] for k in self.law.parameter_names}, 1.0)]
        for z in self._zone_specs:
            lp = {k: v * factor.get(u, 1.0) for k, v, u in z.fixed}
            for k, u in z.derived:
                lp[k] = p[k] * (z.delta_EJ_ratio if u == UNIT_EJ else z.chi_ratio if u == UNIT_CHI else 1.0)
            out.append((z.where, z.law, lp, z.EJ_min_ratio))
        return out

    def _zone_mesh(self, p: dict):
        """A zoned cable's nodes and each zone's elements (:func:`zoned_mesh`)."""
        if isinstance(self.law, ZonedLaw):
            return zoned_mesh(float(p["clamp_zone"][0]), float(p["mass_zone"][0]), int(self.n_elements))
        lengths = {z.where: z.length for z in self.zones}
        return zoned_mesh(lengths.get("clamp", 0.0), lengths.get("mass", 0.0), int(self.n_elements))

    def _check_zone_lengths(self, p: dict):
        """A ZonedLaw's ``clamp_zone`` and ``mass_zone``: one value for all sets (they place the nodes)."""
        if not isinstance(self.law, ZonedLaw):
            return
        for name in ("clamp_zone", "mass_zone"):
            v = p[name]
            if v.size > 1 and not np.all(v == v[0]):
                raise InputError(f"parameter {name!r}: the element model's mesh needs one value for every "
                                 f"parameter set (a scalar), got values from {np.nanmin(v):g} to {np.nanmax(v):g}")

    # --- set-up -------------------------------------------------------------------------------

    def _batch(self, p: dict, n_sets: int, omega, x0, zoned=None) -> _Batch:
        nf = omega.size
        mesh = self._mesh if zoned is None else zoned[0]

        def full(per_set_arm):
            """(n_sets or 1, 2) -> (S, F, 2) broadcast, flattened to (B,)."""
            return np.broadcast_to(per_set_arm[:, None, :], (n_sets, nf, 2)).reshape(-1)

        def arms(a1, a2):
            a1, a2 = np.broadcast_arrays(p[a1], p[a2]) if isinstance(a1, str) else np.broadcast_arrays(a1, a2)
            return np.stack([a1, a2], axis=-1)  # (n_sets or 1, 2)

        length = arms("L1", "L2")
        frac = np.diff(mesh)
        h = np.stack([full(length * f) for f in frac])  # (N, B)
        mu = full(arms(p["mu"], p["mu"]))
        w2 = np.broadcast_to((omega**2)[None, :, None], (n_sets, nf, 2)).reshape(-1)
        c = w2 * mu * h / 420.0
        wm = (156 * c, 22 * c * h, 4 * c * h * h, 54 * c, 13 * c * h, 3 * c * h * h)
        # end masses along the arm (s from the clamp outward): arm 1's offset and rotation change sign
        m, J, a = arms("m1", "m2"), arms("J1", "J2"), arms(-p["a1"], p["a2"])
        m, J, a = full(m), full(J), full(a)
        tip = (w2 * m, w2 * m * a, w2 * (J + m * a * a))
        x0b = np.broadcast_to(x0[None, :, None], (n_sets, nf, 2)).reshape(-1)
        r = full(arms(-p["rocking_rad_per_m"], p["rocking_rad_per_m"]))
        linear = full(arms(p["EJ_min"] * (1 + 1j * p["beta_material"]), p["EJ_min"] * (1 + 1j * p["beta_material"])))
        law_params, zones = {}, None
        if zoned is not None:
            def per_set(v):
                v = np.atleast_1d(np.asarray(v, dtype=float))
                return full(arms(v, v))

            zones = tuple((sl, law, {k: per_set(v)[:, None] for k, v in lp.items()},
                           per_set(ratio) if np.ndim(ratio) else float(ratio))
                          for sl, law, lp, ratio in zoned[1])
        elif self.law is not None:
            law_params = {k: full(arms(p[k], p[k]))[:, None] for k in self.law.parameter_names}
        inv_h = 1.0 / h
        return _Batch(k12=12 * inv_h**3, k6=6 * inv_h**2, k4=4 * inv_h, k2=2 * inv_h, inv_h=inv_h, h=h, wm=wm,
                      tip=tip, x0=x0b, t0=r * x0b, linear=linear, law_params=law_params, zones=zones)

    # --- the fixed point ----------------------------------------------------------------------

    def _sigma(self, c: _Batch, z):
        """Element rigidities (N, B) at curvature amplitudes z (N, B)."""
        if self.law is None:
            return np.broadcast_to(c.linear, z.shape).astype(complex)
        if c.zones is not None:
            sigma = np.empty(z.shape, dtype=complex)
            for sl, law, lp, ratio in c.zones:
                sigma[sl] = c.linear * ratio + law.slip_rigidity(z[sl].T, **lp).T
            return sigma
        slip = self.law.slip_rigidity(z.T, **c.law_params).T
        return c.linear + slip

    def _evaluate(self, c: _Batch, z, jacobian: bool):
        """Map T(z) (N, B), the arm force (B,), and optionally dG/du of G(u) = ln T(e^u) - u (B, N, N)."""
        sigma = self._sigma(c, z)
        arms = _ElementArms(c, sigma)
        x = arms.response() if c.zones is None else arms.deformation()  # the same curvatures
        ends = [_curvature_ends(c, x, e) for e in range(c.n)]
        t = np.stack([_rms(c0, c1) for c0, c1 in ends])
        if not jacobian:
            return t, arms.clamp_force(), sigma, None
        n, b = c.n, z.shape[1]
        # law slope d sigma / d ln z, forward difference (the laws are closed forms or splines)
        if self.law is None:
            slope = np.zeros_like(sigma)
        else:
            slope = (self._sigma(c, z * np.exp(FD_LOG_STEP)) - sigma) / FD_LOG_STEP
        # load of a unit change of sigma_j: -Khat_j X on element j's nodes (node 0 is prescribed)
        zero = np.zeros((b, n), dtype=complex)
        r = [[zero.copy(), zero.copy()] for _ in range(n)]
        for j in range(n):
            (wa, ta), (wb, tb) = x[j], x[j + 1]
            k12, k6, k4, k2 = c.k12[j], c.k6[j], c.k4[j], c.k2[j]
            if j > 0:
                r[j - 1][0][:, j] -= k12 * wa + k6 * ta - k12 * wb + k6 * tb
                r[j - 1][1][:, j] -= k6 * wa + k4 * ta - k6 * wb + k2 * tb
            r[j][0][:, j] -= -k12 * wa - k6 * ta + k12 * wb - k6 * tb
            r[j][1][:, j] -= k6 * wa + k2 * ta - k6 * wb + k4 * tb
        dy = arms.solve([tuple(v) for v in r])  # node k (1..N): (B, n) per unit sigma_j
        dx = [(np.zeros((b, 1)), np.zeros((b, 1)))] + dy
        jac = np.empty((b, n, n))
        for e in range(n):
            c0, c1 = ends[e]
            d0, d1 = _curvature_ends(c, dx, e)  # (B, n): d chi / d sigma_j
            q0 = (2 * np.conj(c0) + np.conj(c1))[:, None]
            q1 = (2 * np.conj(c1) + np.conj(c0))[:, None]
            te = np.maximum(t[e], TINY)[:, None]
            # d ln T_e / d ln z_j = Re[(q0 d0 + q1 d1) slope_j] / (6 T_e^2)
            jac[:, e, :] = ((q0 * d0 + q1 * d1) * slope.T).real / (6 * te * te)
        jac -= np.eye(n)
        return t, arms.clamp_force(), sigma, jac

    def _newton(self, c: _Batch, z, max_iter):
        """Newton on G(u) = ln T(e^u) - u per arm; returns (z, force, sigma, residual, iterations)."""
        b = z.shape[1]
        force = np.zeros(b, dtype=complex)
        sigma = np.zeros(z.shape, dtype=complex)
        resid = np.full(b, np.inf)
        active = np.arange(b)
        it = 0
        z = z.copy()
        while active.size:
            sub = c if active.size == b else c.take(active)
            last = it == max_iter
            t, f, s, jac = self._evaluate(sub, z[:, active], jacobian=not last)
            u = np.log(np.maximum(z[:, active], TINY))
            g = np.log(np.maximum(t, TINY)) - u  # (N, b_active)
            res = np.abs(g).max(axis=0)
            force[active], sigma[:, active], resid[active] = f, s, res
            done = res < self.tol
            if last:
                break
            it += 1
            keep = ~done
            if not keep.any():
                break
            step = _solve_small(jac[keep], -g[:, keep].T).T
            step = np.where(np.isfinite(step), step, g[:, keep])  # singular Jacobian: a plain fixed-point step
            step *= np.minimum(1.0, _MAX_LOG_STEP / np.maximum(np.abs(step).max(axis=0), TINY))
            # converged entries keep their z (their force and sigma were stored above)
            active = active[keep]
            z[:, active] = np.exp(u[:, keep] + step)
        return z, force, sigma, resid, it

    # --- public -------------------------------------------------------------------------------

    def state(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, linear_rigidity=None,
              zone_scale=None, **params) -> ElementCableState:
        """Steady state of the cable at every line, following a stepped-sine sweep up each test.

        Parameters
        ----------
        damper, freq_hz
            As :meth:`sbcal.model.cable.CableModel.state` (the frequencies increasing within each test).
        amplitude_mm_pp : float or array_like, shape (n_freq,)
            Commanded base amplitude per line [mm peak-to-peak].
        segments : array_like of int, shape (n_freq,), optional
            As :meth:`sbcal.model.cable.CableModel.state` (the sweep restarts at each test's first line).
        linear_rigidity : array_like of complex, shape (n_sets or 1, n_freq or 1, 2), optional
            ``EJ_min (1 + i beta_material)`` per set, line and arm [N m^2], replacing ``EJ_min`` and
            ``beta_material`` (the virtual bench's asymmetric, viscous or frequency-dependent cable).
            A zone's ``EJ_min_ratio`` multiplies it.
        zone_scale : (float or array_like, float or array_like), optional
            With :attr:`zones`: factors ``(ej, chi)``, scalars or shape (n_sets,), on the zones' fixed
            parameter values, ``ej`` on those in N m^2, ``chi`` on those in 1/m (the virtual bench's
            re-clamping scatter; the values a zone takes from the middle follow the middle's).
        **params : float or array_like, shape (n_sets,)
            See :class:`sbcal.model.cable.CableModel` (and :class:`sbcal.model.laws.zones.ZonedLaw`: its
            ``clamp_zone`` and ``mass_zone`` one value for all sets).

        Returns
        -------
        ElementCableState
        """
        if linear_rigidity is not None:
            params = dict(params, EJ_min=1.0, beta_material=0.0)  # placeholders, replaced below
        p, n_sets, in_law = self._parameters(damper, params)
        self._check_zone_lengths(p)
        if zone_scale is not None:
            zone_scale, n_sets = self._zone_scale(zone_scale, n_sets)
        zones = self._zone_laws(p, zone_scale)
        if zones is not None:
            for _, law, lp, _ in zones:
                in_law = in_law & law.valid(**lp)
        valid = np.broadcast_to((p["EJ_min"] > 0) & (p["beta_material"] >= 0) & in_law, (n_sets,))
        if linear_rigidity is not None:
            lin = np.asarray(linear_rigidity, dtype=complex)
            if lin.ndim != 3 or lin.shape[2] != 2:
                raise InputError(f"linear_rigidity: expected shape (n_sets, n_freq, 2), got {lin.shape}")
            n_sets = max(n_sets, lin.shape[0])
        if not valid.all():
            if linear_rigidity is not None:
                raise InputError("linear_rigidity: the law's parameters are outside its domain"
                                 + (" (in some zone)" if zones is not None else ""))
            return self._with_invalid(damper, freq_hz, amplitude_mm_pp, segments, p, n_sets, valid, zone_scale)
        f, amp, seg = checked_grid(freq_hz, amplitude_mm_pp, segments)
        omega = 2 * np.pi * f
        x0 = amp / 2 * 1e-3
        mesh = self._mesh
        if zones is None:
            c = self._batch(p, n_sets, omega, x0)
        else:
            mesh, slices = self._zone_mesh(p)
            c = self._batch(p, n_sets, omega, x0, (mesh, [(slices[z], law, lp, r) for z, law, lp, r in zones]))
        if linear_rigidity is not None:
            c = replace(c, linear=np.broadcast_to(lin, (n_sets, f.size, 2)).reshape(-1).copy())
        n, nf = c.n, f.size

        # 1. all lines at once, from the stuck cable's linear response
        # predictor: the stuck cable's curvature overestimates the slipping cable's, the response
        # of a cable slipped to that curvature underestimates it; start between the two (in ln chi)
        z_stuck = self._linear_curvatures(c, self._sigma(c, np.zeros((n, c.x0.size))))
        z_soft = self._linear_curvatures(c, self._sigma(c, z_stuck)) if self.law is not None else z_stuck
        z0 = np.sqrt(z_stuck * z_soft)
        z, force, sigma, resid, iterations = self._newton(c, z0, self.max_iter)
        fold = np.zeros((n_sets, nf), dtype=bool)
        if self.law is not None and nf > 1:
            z, force, sigma, resid, fold, extra = self._continuation(c, z, force, sigma, resid, seg, n_sets, nf)
            iterations += extra

        def per_line(v, tail=()):
            return v.reshape(*tail, n_sets, nf, 2)

        f_uu = per_line(force).sum(axis=-1) / x0[None, :] + self._clamp_inertia(p, omega)
        curv = np.moveaxis(per_line(z, (n,)), 0, -1)
        rig = np.moveaxis(per_line(sigma, (n,)), 0, -1)
        res = per_line(resid).max(axis=-1)
        return ElementCableState(f_uu=np.broadcast_to(f_uu, (n_sets, nf)).copy(), curvature=curv, rigidity=rig,
                          converged=res < self.tol, fold=fold, residual=res, iterations=int(iterations),
                          mesh=mesh.copy())

    def _zone_scale(self, zone_scale, n_sets: int):
        """``zone_scale`` as two 1-D arrays (length n_sets or 1), and n_sets."""
        if not self.zones:
            raise InputError("zone_scale: the cable has no fixed zones (ElementCableModel.zones)")
        try:
            ej, chi = (np.asarray(v, dtype=float).reshape(-1) for v in zone_scale)
        except (TypeError, ValueError):
            raise InputError("zone_scale: expected a pair (ej, chi) of scalars or arrays of shape (n_sets,)") from None
        for name, v in (("ej", ej), ("chi", chi)):
            if v.size not in (1, n_sets) and n_sets != 1:
                raise InputError(f"zone_scale: {name} has {v.size} values for {n_sets} parameter sets")
            if not np.all(np.isfinite(v) & (v > 0)):
                raise InputError(f"zone_scale: {name} must be finite and > 0")
            n_sets = max(n_sets, v.size)
        if ej.size not in (1, n_sets) or chi.size not in (1, n_sets):
            raise InputError(f"zone_scale: ej and chi have {ej.size} and {chi.size} values")
        return (ej, chi), n_sets

    def _with_invalid(self, damper, freq_hz, amplitude_mm_pp, segments, p, n_sets, valid, zone_scale=None):
        """Solve the valid sets only; the others get NaN (outside the law's domain)."""
        keep, sub = self._valid_subset(p, n_sets, valid)
        nf = np.atleast_1d(np.asarray(freq_hz)).size
        mesh = self._mesh
        if keep.size and isinstance(self.law, ZonedLaw):
            mesh = self._zone_mesh(sub)[0]
        shape = (n_sets, nf, 2, mesh.size - 1)
        out = dict(f_uu=np.full((n_sets, nf), np.nan + 0j), curvature=np.full(shape, np.nan),
                   rigidity=np.full(shape, np.nan + 0j), converged=np.zeros((n_sets, nf), dtype=bool),
                   fold=np.zeros((n_sets, nf), dtype=bool), residual=np.full((n_sets, nf), np.inf))
        iterations = 0
        if keep.size:
            if zone_scale is not None:
                zone_scale = tuple(v[keep] if v.size == n_sets and n_sets > 1 else v for v in zone_scale)
                sub = dict(sub, zone_scale=zone_scale)
            iterations = self._scatter(out, keep, self.state(damper, freq_hz, amplitude_mm_pp, segments=segments, **sub))
        return ElementCableState(**out, iterations=iterations, mesh=mesh.copy())

    def _linear_curvatures(self, c, sigma):
        arms = _ElementArms(c, sigma)
        x = arms.response() if c.zones is None else arms.deformation()
        return np.stack([_rms(*_curvature_ends(c, x, e)) for e in range(c.n)])

    def _continuation(self, c, z, force, sigma, resid, seg, n_sets, nf):
        """Check every line against a restart from its predecessor; re-solve the folds in sweep order."""
        n = c.n
        shape = (n, n_sets, nf, 2)
        zl = z.reshape(shape)
        first = np.concatenate([[True], seg[1:] != seg[:-1]])
        # 2. one vectorised pass: every line restarted from its predecessor's solution
        z_prev = np.roll(zl, 1, axis=2)
        z_prev[:, :, first] = zl[:, :, first]
        zc, fc, sc, rc, it = self._newton(c, z_prev.reshape(n, -1), self.max_iter)
        iterations = it

        def differs(za, zb, ra, rb):
            d = np.abs(np.log(np.maximum(za, TINY)) - np.log(np.maximum(zb, TINY))).max(axis=0)
            return (d > self.fold_tol) & (ra < self.tol) & (rb < self.tol)

        diff = differs(z, zc, resid, rc).reshape(n_sets, nf, 2).any(axis=-1)
        diff[:, first] = False
        fold = diff.copy()
        if not diff.any():
            return z, force, sigma, resid, fold, iterations
        # 3. in sweep order from the first line with two states: take the restart's solution, and
        # re-solve a line from its (changed) predecessor until the sweep rejoins the first pass
        force_l = force.reshape(n_sets, nf, 2).copy()
        sigma_l = sigma.reshape(shape).copy()
        resid_l = resid.reshape(n_sets, nf, 2).copy()
        zl = zl.copy()
        zc_l, fc_l, sc_l, rc_l = zc.reshape(shape), fc.reshape(n_sets, nf, 2), sc.reshape(shape), rc.reshape(n_sets, nf, 2)
        changed = np.zeros(n_sets, dtype=bool)
        idx = np.arange(n_sets * nf * 2).reshape(n_sets, nf, 2)
        for k in range(nf):
            if first[k]:
                changed[:] = False
                continue
            take = diff[:, k] & ~changed  # predecessor as in pass 2: its restart result stands
            zl[:, take, k], force_l[take, k], sigma_l[:, take, k], resid_l[take, k] = (
                zc_l[:, take, k], fc_l[take, k], sc_l[:, take, k], rc_l[take, k])
            redo = changed.copy()
            if redo.any():
                sets = np.flatnonzero(redo)
                sub = c.take(idx[sets, k].reshape(-1))
                zs, fs, ss, rs, it = self._newton(sub, zl[:, sets, k - 1].reshape(n, -1), self.max_iter)
                iterations += it
                zs = zs.reshape(n, sets.size, 2)
                new = differs(zs.reshape(n, -1), zl[:, sets, k].reshape(n, -1), rs, resid_l[sets, k].reshape(-1))
                new = new.reshape(sets.size, 2).any(axis=-1)
                fold[sets, k] |= new
                zl[:, sets, k], force_l[sets, k] = zs, fs.reshape(sets.size, 2)
                sigma_l[:, sets, k], resid_l[sets, k] = ss.reshape(n, sets.size, 2), rs.reshape(sets.size, 2)
                changed[sets] = new
            changed |= take
        return (zl.reshape(n, -1), force_l.reshape(-1), sigma_l.reshape(n, -1), resid_l.reshape(-1), fold,
                iterations)

    def dynamic_stiffness(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, **params) -> np.ndarray:
        """``f_uu`` [N/m], complex (n_sets, n_freq): :meth:`state` ``.f_uu`` (NaN outside the laws' domain)."""
        return self.state(damper, freq_hz, amplitude_mm_pp, segments=segments, **params).f_uu
