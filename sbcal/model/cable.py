"""The distributed cable: one hysteretic strand-slip law along both arms (``docs/cable.md``).

Each section of the messenger cable has the complex secant rigidity::

    EJ*(chi_a) = EJ_min (1 + i beta_material) + EJ_slip*(chi_a)

with ``EJ_slip*`` the first-harmonic describing function of a law of :mod:`sbcal.model.laws` at the
section's curvature amplitude (equivalent linearisation). The damper is that of :mod:`sbcal.model.fem`:
lumped end masses ``[[m, m a], [m a, J + m a^2]]``, consistent cable mass, the clamp driven at
``X0 = amplitude_mm_pp / 2 * 1e-3`` m (and rotated by ``r X0`` with base rocking), the clamp's own
inertia added; ``f_uu`` is the vertical force on the base per unit vertical base motion, as
:func:`sbcal.model.fem.dynamic_stiffness` defines it. Two models:

:class:`CableModel` (the fit's model: fast)
    Each arm is a statically determinate cantilever from the clamp to its mass node: its bending
    moment is linear, ``M(s) = V (L - s) + M_tip``, set by the generalised load ``P = (V, M_tip)``
    at the node. The node's motion relative to the clamp's rigid motion is the flexibility
    integral ``int l(s) chi(s) ds``, ``l = (L - s, 1)``, evaluated by Gauss-Legendre over
    ``sections`` sections, each section's curvature amplitude solving ``a |EJ*(a)| = |M|``
    (looked up in a per-set table of the compliance ``1 / EJ*`` over ``ln |M|^2``). The cable's
    inertia is the consistent (Hermite) mass of the arm, as in the 6-DOF model, so a linear cable
    is that model exactly. Unknowns: ``P`` per (set, line, arm), solved by Newton with the exact
    widely linear Jacobian (``|M|`` is not analytic in ``P``).

:class:`ElementCableModel` (the virtual bench's: richer)
    Each arm split into ``N`` Hermite elements with distributed consistent mass, one rigidity per
    element at its rms curvature; Newton on the element curvatures.

With the clamp prescribed, every (set, line, arm) is independent. Both models can follow a
stepped-sine sweep up the grid (continuation): a line's answer is the steady state reached from the
previous line's; where a line has two steady states (a fold) it is flagged.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import InputError
from . import cable_kernel
from .cable_sections import (TINY, Arms, Compliance, checked_grid, compliance_table, gauss, linear_compliance,
                             segments_from_frequencies)
from .damper import GEOMETRY, Damper
from .laws import HysteresisLaw
from .laws.zones import ZonedLaw


__all__ = ["DEFAULT_SECTIONS", "CableBase", "CableState", "CableModel", "segments_from_frequencies"]

DEFAULT_SECTIONS = 8
"""Gauss-Legendre sections per arm of :class:`CableModel` (the convergence study of ``docs/cable.md``);
with a zoned law (:class:`sbcal.model.laws.zones.ZonedLaw`), of the arm's middle zone."""

DEFAULT_ZONE_SECTIONS = 3
"""Gauss-Legendre sections of each boundary zone of a zoned law (``docs/cable.md``)."""

_BASE = ("EJ_min", "beta_material", "rocking_rad_per_m")


def _complex(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=complex)


def _real(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float)


def _rows(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.intp)


def _resolve(names: tuple, required: tuple, damper: Damper, params: dict):
    """Check names and shapes; every parameter as a 1-D array (length n_sets or 1), defaults filled."""
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise InputError(f"unknown parameter {unknown[0]!r}; known: {', '.join(names)}")
    for name in required:
        if name not in params:
            raise InputError(f"parameter {name!r} is required")
    n_sets, out = 1, {}
    for name, value in params.items():
        a = np.asarray(value, dtype=float)
        if a.ndim > 1 or (a.ndim == 1 and n_sets not in (1, a.size) and a.size != 1):
            raise InputError(f"parameter {name!r}: expected a scalar or shape (n_sets,), got shape {a.shape}")
        n_sets = max(n_sets, a.size) if a.ndim == 1 else n_sets
        out[name] = a.reshape(-1)
    for name in GEOMETRY:
        out.setdefault(name, np.array([getattr(damper, name)]))
    out.setdefault("rocking_rad_per_m", np.zeros(1))
    return out, n_sets


@dataclass(frozen=True)
class CableBase:
    """What both cable models share: the law, the parameters they accept (the table of
    :class:`CableModel`) and their checks, and the clamp's inertia."""

    law: HysteresisLaw | None = None

    @property
    def parameter_names(self) -> tuple:
        """Every parameter name :meth:`state` accepts."""
        return _BASE[:2] + self._law_names + _BASE[2:] + GEOMETRY

    @property
    def _law_names(self) -> tuple:
        return self.law.parameter_names if self.law is not None else ()

    def _parameters(self, damper: Damper, params: dict):
        """The parameters as :func:`_resolve` returns them, n_sets, and the law's domain per set
        (shape (n_sets or 1,); True for the linear cable)."""
        names = self._law_names
        p, n_sets = _resolve(self.parameter_names, _BASE[:2] + names, damper, params)
        in_law = self.law.valid(**{k: p[k] for k in names}) if self.law is not None else True
        return p, n_sets, in_law

    @staticmethod
    def _in_domain(p: dict, n_sets: int, in_law) -> np.ndarray:
        """Per set (n_sets,): ``EJ_min > 0``, ``beta_material >= 0``, both finite, and the law's domain."""
        valid = np.isfinite(p["EJ_min"]) & (p["EJ_min"] > 0) & np.isfinite(p["beta_material"]) & (p["beta_material"] >= 0)
        return np.broadcast_to(valid & in_law, (n_sets,))

    @staticmethod
    def _valid_subset(p: dict, n_sets: int, valid):
        """Indices of the ``valid`` sets and their parameters (the per-set ones cut to them)."""
        keep = np.flatnonzero(valid)
        return keep, {k: (v[keep] if v.size == n_sets and n_sets > 1 else v) for k, v in p.items()}

    @staticmethod
    def _scatter(out: dict, keep, state) -> int:
        """Rows ``keep`` of the NaN fields ``out`` from ``state``, solved for those sets; its iterations."""
        for k in out:
            out[k][keep] = getattr(state, k)
        return state.iterations

    @staticmethod
    def _clamp_inertia(p: dict, omega) -> np.ndarray:
        """The clamp's own inertia in ``f_uu`` [N/m], shape (n_sets or 1, n_freq) (with its rocking)."""
        r = p["rocking_rad_per_m"][:, None]
        return -(omega**2)[None, :] * p["mc"][:, None] * (1 + p["ac"][:, None] * r)


@dataclass(frozen=True, eq=False)
class CableState:
    """The cable's steady state per parameter set and frequency line (:class:`CableModel`).

    Attributes
    ----------
    f_uu : ndarray of complex, shape (n_sets, n_freq)
        Dynamic stiffness [N/m] (with base rocking: the measured ``f_uu + r f_uphi``).
    load : ndarray of complex, shape (n_sets, n_freq, 2, 2)
        ``(V [N], M_tip [N m])`` at each arm's mass node, arm 1 (mass 1 - clamp) then arm 2, in the
        arm's own frame (s from the clamp to the mass); the moment is ``V (L - s) + M_tip``.
    curvature : ndarray, shape (n_sets, n_freq, 2, sections)
        Section curvature amplitudes [1/m] at :attr:`sections`.
    rigidity : ndarray of complex, shape (n_sets, n_freq, 2, sections)
        Section secant rigidity ``EJ*`` [N m^2].
    curvature_range : ndarray, shape (n_sets, n_freq, 2)
        Smallest and largest curvature amplitude over both arms' full length [1/m] (the largest at
        an arm's end, the smallest where ``|M|`` is least): the range the law was used over.
    converged : ndarray of bool, shape (n_sets, n_freq)
        Newton met the tolerance on both arms.
    fold : ndarray of bool, shape (n_sets, n_freq)
        Two steady states were found at this line (with ``continuation``; the sweep's branch is
        returned). Always False without continuation.
    residual : ndarray, shape (n_sets, n_freq)
        Estimated relative error of the loads ``P`` (max over the arms; see :attr:`CableModel.tol`).
    iterations : int
        Newton iterations (the largest per entry), summed over the passes.
    sections : ndarray, shape (sections,), or (n_sets, sections) with a zoned law
        Section positions from the clamp, as fractions of the arm's length (a zoned law's: each zone's
        Gauss sections, middle, clamp zone, mass zone, per set).
    """

    f_uu: np.ndarray
    load: np.ndarray
    curvature: np.ndarray
    rigidity: np.ndarray
    curvature_range: np.ndarray
    converged: np.ndarray
    fold: np.ndarray
    residual: np.ndarray
    iterations: int
    sections: np.ndarray


@dataclass(frozen=True)
class CableModel(CableBase):
    """The strand-slip cable on statically determinate arms: ``f_uu`` and the steady state, fast.

    Parameters (keyword arguments of :meth:`state`; each a scalar or shape (n_sets,)):

    ===================  ======  =============================================================
    name                 unit    meaning
    ===================  ======  =============================================================
    EJ_min               N m^2   rigidity of the fully slipped strand
    beta_material        1       material loss factor of the strand (on ``EJ_min``)
    the law's            ...     :attr:`law` ``.parameter_names`` (e.g. ``delta_EJ``, ``chi_dahl``)
    rocking_rad_per_m    rad/m   base rocking ``phic = r xc`` (default 0)
    m1 .. mu             SI      geometry overrides as :mod:`sbcal.model.fem` accepts them
    ===================  ======  =============================================================

    The law must make ``a |EJ*(a)|`` increase with the curvature amplitude ``a`` (true for
    ``EJ_min > 0`` and the laws of :mod:`sbcal.model.laws`): a section's moment then fixes its
    curvature. Sets where the table finds otherwise, or outside the law's domain, give NaN.

    Attributes
    ----------
    law : HysteresisLaw or None
        The slip part's law; None is the linear cable ``EJ_min (1 + i beta_material)``.
    sections : int
        Gauss-Legendre sections per arm.
    table_points : int
        Nodes of each set's compliance table (uniform in the curvature's log).
    table_decades : float
        The table spans this many decades of curvature either side of the law's transition.
    max_iter : int
        Newton iteration budget per pass (fixed: the model is a deterministic function).
    tol : float
        Converged when the relative error of ``P`` left after a Newton step, estimated from the
        quadratic convergence of the last two steps, is below ``tol``.
    fold_tol : float
        Two solutions of one line are distinct when their loads differ by more than this (relative).
    """

    sections: int = DEFAULT_SECTIONS
    zone_sections: int = DEFAULT_ZONE_SECTIONS
    table_points: int = 96
    table_decades: float = 3.0
    max_iter: int = 30
    tol: float = 1e-8
    fold_tol: float = 1e-4
    _rule: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if int(self.sections) != self.sections or self.sections < 2:
            raise InputError(f"sections: expected an integer >= 2, got {self.sections!r}")
        if int(self.zone_sections) != self.zone_sections or self.zone_sections < 1:
            raise InputError(f"zone_sections: expected an integer >= 1, got {self.zone_sections!r}")
        if int(self.table_points) != self.table_points or self.table_points < 4:
            raise InputError(f"table_points: expected an integer >= 4, got {self.table_points!r}")
        if not (np.isfinite(self.table_decades) and self.table_decades > 0):
            raise InputError(f"table_decades: expected a finite value > 0, got {self.table_decades!r}")
        eta, w = gauss(int(self.sections))
        powers = eta[None, :] ** np.arange(4, -1, -1)[:, None]  # rows eta^4 .. eta^0
        object.__setattr__(self, "_rule", (eta, np.ascontiguousarray(powers * w[None, :])))

    # --- set-up -------------------------------------------------------------------------------

    @property
    def zoned(self) -> bool:
        """The law changes along the arm (:class:`sbcal.model.laws.zones.ZonedLaw`)."""
        return isinstance(self.law, ZonedLaw)

    def _table(self, p, n_sets) -> Compliance:
        """The sections' compliance table: a row per parameter set; a zoned law's rows are its zones'
        (:data:`sbcal.model.laws.zones.ZONES` order), ``zone * n_sets + set``."""
        lin = np.broadcast_to(p["EJ_min"] * (1 + 1j * p["beta_material"]), (n_sets,)).astype(complex)
        if self.law is None:
            return linear_compliance(lin)
        if not self.zoned:
            lp = {k: np.broadcast_to(p[k], (n_sets,))[:, None] for k in self.law.parameter_names}
            return compliance_table(self.law, lp, lin, int(self.table_points), float(self.table_decades))
        zones = self.law.zones({k: p[k] for k in self.law.parameter_names})
        lp = {k: np.concatenate([np.broadcast_to(z[2][k], (n_sets,)) for z in zones])[:, None]
              for k in self.law.base.parameter_names}
        lins = np.concatenate([lin * np.broadcast_to(z[3], (n_sets,)) for z in zones])
        table = compliance_table(self.law.base, lp, lins, int(self.table_points), float(self.table_decades))
        return replace(table, monotone=table.monotone.reshape(len(zones), n_sets).all(axis=0))

    def _zone_rule(self, p, n_sets):
        """A zoned law's sections per parameter set: eta (Q, n_sets) from the mass node, weights (Q,
        n_sets) and the zone index of each section (Q,), Gauss-Legendre within each zone (the law
        jumps at a zone's edge: one rule across it would not converge)."""
        x, w = gauss(int(self.sections))
        xz, wz = gauss(int(self.zone_sections))
        zc = np.broadcast_to(p["clamp_zone"], (n_sets,))
        zm = np.broadcast_to(p["mass_zone"], (n_sets,))
        eta, wt, zone = [], [], []
        # eta = 1 - s/L: the mass zone is [0, zm], the middle [zm, 1 - zc], the clamp zone [1 - zc, 1]
        for k, (lo, hi, xs, ws) in enumerate(((zm, 1.0 - zc, x, w), (1.0 - zc, np.ones(n_sets), xz, wz),
                                              (np.zeros(n_sets), zm, xz, wz))):
            eta.append(lo[None, :] + (hi - lo)[None, :] * xs[:, None])
            wt.append((hi - lo)[None, :] * ws[:, None])
            zone.append(np.full(xs.size, k))
        return np.concatenate(eta), np.concatenate(wt), np.concatenate(zone)

    @staticmethod
    def _arms(p, n_sets, omega, x0, rule=None) -> Arms:
        """The per-entry constants (see :class:`Arms`) from the damper's consistent mass matrices
        (``rule``: a zoned law's sections per set, :meth:`_zone_rule`)."""
        nf = omega.size

        def full(a1, a2):
            """Per-arm values (each scalar or (n_sets,)) -> flat (n_sets * nf * 2,)."""
            a = np.stack(np.broadcast_arrays(a1, a2), axis=-1).reshape(-1, 1, 2)
            return np.broadcast_to(a, (n_sets, nf, 2)).reshape(-1)

        def per_line(v):  # (nf,) or (n_sets or 1, nf) -> flat
            return np.broadcast_to(v.reshape(-1, nf)[:, :, None], (n_sets, nf, 2)).reshape(-1)

        L = full(p["L1"], p["L2"])
        m, J = full(p["m1"], p["m2"]), full(p["J1"], p["J2"])
        a = full(-p["a1"], p["a2"])  # arm 1 runs from the clamp towards -y: offsets and rotations flip
        r = full(-p["rocking_rad_per_m"], p["rocking_rad_per_m"])
        cm = full(p["mu"], p["mu"]) * L / 420.0
        w2, xb = per_line(omega**2), per_line(x0)
        # the node's mass block (end mass + consistent cable mass) and its coupling to the clamp
        m00, m01, m11 = m + 156 * cm, m * a - 22 * cm * L, J + m * a * a + 4 * cm * L * L
        b00, b01, b10, b11 = 54 * cm, 13 * cm * L, -13 * cm * L, -3 * cm * L * L
        w0, t0 = xb, r * xb
        wr, tr = w0 + L * t0, t0  # the node's rigid motion with the clamp
        c0 = w2 * (m00 * wr + m01 * tr + b00 * w0 + b01 * t0)
        c1 = w2 * (m01 * wr + m11 * tr + b10 * w0 + b11 * t0)
        # N = Mm^-1 and N c (the mass block is positive definite: m, J > 0 or mu > 0)
        det = m00 * m11 - m01 * m01
        idet = 1.0 / (w2 * w2 * L**4 * det)
        nn = np.stack([w2 * L * m11 * idet, -w2 * L**2 * m01 * idet, w2 * L**3 * m00 * idet])
        nc = np.stack([nn[0] * L * c0 + nn[1] * c1, nn[1] * L * c0 + nn[2] * c1])
        # vertical clamp force: -V - omega^2 (M_cc q_clamp + M_cn q)[0] with the node's motion
        # q = M_node^-1 (P / omega^2 - M_nc q_clamp) and M_cn[0] = cm (54, -13 L): linear in P
        u0 = (m11 * 54 * cm + m01 * 13 * cm * L) / det
        u1 = (-m01 * 54 * cm - m00 * 13 * cm * L) / det
        fa, fb = -(1.0 + u0) / L, -u1
        fc = -w2 * cm * (156 * w0 + 22 * L * t0) + w2 * (u0 * (b00 * w0 + b01 * t0) + u1 * (b10 * w0 + b11 * t0))
        row = np.broadcast_to(np.arange(n_sets)[:, None, None], (n_sets, nf, 2)).reshape(-1)
        return Arms(n=nn, nc=nc, force=(fa, fb, fc), row=row, length=L, rule=rule)

    # --- Newton on the node loads (compiled: sbcal.model.cable_kernel) --------------------------

    def _kernel_rule(self, arms: Arms):
        """The sections as the kernel takes them, per parameter set: eta and weights (n_sets or 1, Q), each
        section's zone (Q,) and whether they are per set (a zoned law) or the model's one rule."""
        if arms.zoned:
            eta, w, zone = arms.rule
            return np.ascontiguousarray(eta.T), np.ascontiguousarray(w.T), zone.astype(np.intp), True
        eta, wp = self._rule
        return eta[None, :], wp[4][None, :], np.zeros(eta.size, dtype=np.intp), False

    def _sections(self, table, arms: Arms, p):
        """The sections at the loads ``p`` (2, b): compliance ``Kr``, ``Ki`` and ``|M|^-2``, each (Q, b)."""
        eta, _, zone, zoned = self._kernel_rule(arms)
        return cable_kernel.sections(_complex(p), _rows(arms.row), eta, zone, zoned, *table.args)

    @staticmethod
    def _lookup_many(table, m2, row):
        """``(Kr, Ki, Dr, Di)`` of the table at ``|M|^2`` ``m2`` (..., b), table rows ``row`` (b,) or m2's shape."""
        with np.errstate(divide="ignore", invalid="ignore"):
            y = np.log(m2)
        rows = np.broadcast_to(row, m2.shape)
        out = cable_kernel.lookup(np.ascontiguousarray(y, dtype=float).reshape(-1), _rows(rows.reshape(-1)),
                                  *table.args)
        return tuple(out.reshape((4,) + m2.shape))

    @staticmethod
    def _uniform_start(arms: Arms, k):
        """The loads of a cable with one compliance ``k`` (b,) along each arm (exact, linear)."""
        n00, n01, n11 = arms.n
        x00, x01, x11 = n00 - k / 3.0, n01 - k / 2.0, n11 - k
        c0, c1 = arms.nc
        idet = 1.0 / (x00 * x11 - x01 * x01)
        return np.stack([(x11 * c0 - x01 * c1) * idet, (x00 * c1 - x01 * c0) * idet])

    def _start(self, table, arms: Arms):
        """Start of Newton: the cable with one compliance along each arm, at the arm's rms moment.

        A relaxed fixed point in ``z = ln(mean |M|^2)`` from the fully slipped cable:
        ``z <- (1 - r) z + r ln(mean |M(K(z))|^2)``; a few steps put the loads on the right scale
        (they may be 10x the slipped cable's near a resonance of the partly stuck one). With one
        compliance K the loads are ``(a, b) / det`` with ``a, b, det`` polynomials in K. Returns (2, b).
        """
        return cable_kernel.start(_real(arms.n), _real(arms.nc), _rows(arms.row), *table.args)

    def _newton(self, table, arms: Arms, p):
        """Damped Newton from ``p`` (2, b) for every entry, each to its own convergence.

        A step is at most half of ``|p|`` (far from the solution the widely linear model is poor),
        and an entry whose residual grew halves its later steps until it falls again. An entry
        stops once the error left after its step, estimated from the quadratic convergence of its
        last two full steps (``s_k^3 / s_k-1^2``, relative to ``|p|``), is below ``tol``: the step is
        taken, its residual not evaluated. Returns (p (2, b), error estimate, iterations per entry).
        """
        eta, w, zone, zoned = self._kernel_rule(arms)
        return cable_kernel.newton(_complex(p), _real(arms.n), _real(arms.nc), _rows(arms.row), eta, w,
                                   zone, zoned, float(self.tol), int(self.max_iter), *table.args)

    # --- public -------------------------------------------------------------------------------

    def state(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, continuation=False,
              **params) -> CableState:
        """Steady state of the cable at every line.

        Parameters
        ----------
        damper : Damper
            Nominal geometry (every geometry parameter not given).
        freq_hz : array_like, shape (n_freq,)
            Frequency lines [Hz] (several tests may be concatenated; see ``segments``).
        amplitude_mm_pp : float or array_like, shape (n_freq,) or (n_sets, n_freq)
            Commanded base amplitude per line [mm peak-to-peak]; 2-D: one per parameter set and line
            (e.g. a span's clamp amplitude per posterior draw; the same numbers as set-by-set calls).
        segments : array_like of int, shape (n_freq,), optional
            Test index per line (a sweep restarts at each test's first line); default: a new test
            wherever the frequency does not increase (:func:`segments_from_frequencies`). Used by
            ``continuation`` only.
        continuation : bool
            Follow a stepped-sine sweep up each test: every line is also solved from its
            predecessor's state and from the stuck cable; where these give two steady states the
            line is flagged (:attr:`CableState.fold`) and the sweep's branch is resolved line by
            line. Off (the sampler's path), every line is solved once, from the fully slipped cable.
        **params : float or array_like, shape (n_sets,)
            See the class docstring.

        Returns
        -------
        CableState
        """
        return self._run(damper, freq_hz, amplitude_mm_pp, segments, continuation, params, full=True)

    def dynamic_stiffness(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, continuation=False,
                          start=None, **params) -> np.ndarray:
        """``f_uu`` [N/m], complex (n_sets, n_freq): :meth:`state` ``.f_uu`` (NaN outside the law's domain).

        The sampler's path: the same numbers as :meth:`state`, without the section state. ``start``
        (:meth:`loads` of one nearby parameter set, on the same lines): Newton starts every set from it
        instead of from the fully slipped cable, and an entry it does not bring within ``tol`` is solved
        from the slipped cable as without it. Near a posterior's mode that is 1.4-2.4 evaluations an entry
        instead of 3.3-4.6 and no start (the sets of a fit's posterior: ``docs/cable.md``, "Newton");
        the answer is the same to the solve's tolerance (~1e-6 of ``f_uu``).
        """
        return self._run(damper, freq_hz, amplitude_mm_pp, segments, continuation, params, full=False, start=start)

    def loads(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, **params) -> np.ndarray:
        """Newton's unknowns at one parameter set, complex (2, 2 n_freq) (each line's two arms), from the
        fully slipped cable: a ``start`` for :meth:`dynamic_stiffness` near it. NaN outside the law's domain."""
        out = self._run(damper, freq_hz, amplitude_mm_pp, segments, False, params, full="loads")
        if out.shape[1] != 2 * np.size(freq_hz):
            raise ValueError(f"loads: {out.shape[1] // (2 * np.size(freq_hz))} parameter sets given, expected one")
        return out

    def _solve(self, table, arms: Arms, n_sets: int, start):
        """Newton for every entry, from the slipped cable's :meth:`_start` or from ``start`` (2, b / n_sets)."""
        if start is None:
            return self._newton(table, arms, self._start(table, arms))
        start = np.asarray(start, complex)
        if start.shape != (2, arms.row.size // n_sets):
            raise ValueError(f"start: shape {start.shape}, expected (2, {arms.row.size // n_sets}): one set's loads "
                             "on these lines")
        p, err, it = self._newton(table, arms, np.tile(start, (1, n_sets)))
        lost = np.flatnonzero(~(err < self.tol))
        if lost.size:  # not brought in from the nearby state: those entries from the slipped cable, as without it
            sub = arms.take(lost)
            p[:, lost], err[lost], it[lost] = self._newton(table, sub, self._start(table, sub))
        return p, err, it

    def _run(self, damper, freq_hz, amplitude_mm_pp, segments, continuation, params, full, start=None):
        p, n_sets, in_law = self._parameters(damper, params)
        f, amp, seg = checked_grid(freq_hz, amplitude_mm_pp, segments, per_set=True)
        if amp.ndim == 2 and amp.shape[0] > 1:  # one amplitude per (set, line): the rows are sets
            if n_sets not in (1, amp.shape[0]):
                raise InputError(f"amplitude_mm_pp: {amp.shape[0]} rows (sets) where the parameters have {n_sets}")
            n_sets = amp.shape[0]
        valid = self._in_domain(p, n_sets, in_law)
        if valid.all():
            table = self._table(p, n_sets)
            valid = table.monotone
        if not valid.all():
            return self._subset(damper, f, amp, seg, continuation, p, n_sets, valid, full, start)
        omega = 2 * np.pi * f
        x0 = amp / 2 * 1e-3
        arms = self._arms(p, n_sets, omega, x0, self._zone_rule(p, n_sets) if self.zoned else None)
        sol = self._solve(table, arms, n_sets, start)
        if full == "loads":
            return sol[0]
        iterations = int(sol[2].max())
        fold = np.zeros((n_sets, f.size), dtype=bool)
        if continuation and f.size > 1:
            sol, fold, extra = self._continuation(table, arms, sol, seg, n_sets, f.size)
            iterations += extra
        if not full:
            return self._f_uu(arms, sol[0], p, n_sets, omega, x0)
        return self._assemble(table, arms, sol, fold, iterations, p, n_sets, omega, x0)

    def _f_uu(self, arms, p_load, p, n_sets, omega, x0):
        """``f_uu`` (n_sets, n_freq) from the loads: both arms' vertical clamp forces + the clamp's inertia."""
        fa, fb, fc = arms.force
        force = (fa * p_load[0] + fb * p_load[1] + fc).reshape(n_sets, omega.size, 2).sum(axis=-1)
        return np.broadcast_to(force / x0.reshape(-1, omega.size) + self._clamp_inertia(p, omega),
                               (n_sets, omega.size)).copy()

    def _assemble(self, table, arms, sol, fold, iterations, p, n_sets, omega, x0) -> CableState:
        (p0, p1), step, _ = sol
        kr, ki, inv_m2 = self._sections(table, arms, sol[0])  # the sections at the loads returned
        ksec = kr + 1j * ki
        nf = omega.size
        f_uu = self._f_uu(arms, sol[0], p, n_sets, omega, x0)

        def per_line(v):  # (..., b) -> (n_sets, nf, 2, ...)
            lead = v.ndim - 1
            return np.moveaxis(v.reshape(*v.shape[:-1], n_sets, nf, 2), tuple(range(lead)),
                               tuple(range(-lead, 0)))

        load = per_line(np.stack([p0 / arms.length, p1]))
        curvature = per_line(np.abs(ksec) / np.sqrt(inv_m2))
        # the curvature's range along the whole arm: |M| is largest at an end, least at eta*
        a2 = p0.real**2 + p0.imag**2
        eta = np.clip(-(p0 * np.conj(p1)).real / np.maximum(a2, TINY), 0.0, 1.0)
        m2 = np.abs(np.stack([p1, p0 + p1, p0 * eta + p1])) ** 2
        row = arms.row
        if arms.zoned:  # each end in its zone, eta* in the zone that holds it
            zc, zm = (np.broadcast_to(p[k], (n_sets,))[arms.row] for k in ("clamp_zone", "mass_zone"))
            mid = np.where(eta < zm, 2, np.where(eta > 1.0 - zc, 1, 0))
            row = np.stack([2 * n_sets + arms.row, n_sets + arms.row, mid * n_sets + arms.row])
        kr, ki, _, _ = self._lookup_many(table, m2, row)
        ends = per_line(np.sqrt(m2) * np.hypot(kr, ki)).reshape(n_sets, nf, -1)
        step = step.reshape(n_sets, nf, 2).max(axis=-1)
        if not arms.zoned:
            sections = 1.0 - self._rule[0]
        else:
            sections = 1.0 - arms.eta.reshape(-1, n_sets, nf, 2)[:, :, 0, 0].T
        return CableState(f_uu=f_uu, load=load, curvature=curvature, rigidity=per_line(1.0 / ksec),
                          curvature_range=np.stack([ends.min(axis=-1), ends.max(axis=-1)], axis=-1),
                          converged=step < self.tol, fold=fold, residual=step, iterations=iterations,
                          sections=sections)

    def _subset(self, damper, f, amp, seg, continuation, p, n_sets, valid, full, start=None):
        """Solve the valid sets only; the others get NaN (outside the law's domain)."""
        keep, sub = self._valid_subset(p, n_sets, valid)
        nf, q = f.size, int(self.sections) + (2 * int(self.zone_sections) if self.zoned else 0)
        if amp.ndim == 2 and amp.shape[0] == n_sets > 1:
            amp = amp[keep]
        if full == "loads":  # a set outside the domain: NaN for every set (loads() takes one)
            return np.full((2, 2 * nf * n_sets), np.nan + 0j)
        if not full:
            out = np.full((n_sets, nf), np.nan + 0j)
            if keep.size:
                out[keep] = self._run(damper, f, amp, seg, continuation, sub, full=False, start=start)
            return out
        out = dict(f_uu=np.full((n_sets, nf), np.nan + 0j), load=np.full((n_sets, nf, 2, 2), np.nan + 0j),
                   curvature=np.full((n_sets, nf, 2, q), np.nan), rigidity=np.full((n_sets, nf, 2, q), np.nan + 0j),
                   curvature_range=np.full((n_sets, nf, 2), np.nan), converged=np.zeros((n_sets, nf), dtype=bool),
                   fold=np.zeros((n_sets, nf), dtype=bool), residual=np.full((n_sets, nf), np.inf))
        iterations, sections = 0, 1.0 - self._rule[0]
        if keep.size:
            st = self._run(damper, f, amp, seg, continuation, sub, full=True)
            iterations = self._scatter(out, keep, st)
            if self.zoned:
                sections = np.full((n_sets, q), np.nan)
                sections[keep] = st.sections
        elif self.zoned:
            sections = np.full((n_sets, q), np.nan)
        return CableState(**out, iterations=iterations, sections=sections)

    def _continuation(self, table, arms, sol, seg, n_sets, nf):
        """Follow a sweep up each test: a line's answer is the steady state reached from its
        predecessor's. Every line is re-solved from its predecessor's first-pass state and from the
        stuck cable at once; lines where two converged states differ are flagged; where the sweep's
        state differs from the first pass, the following lines are re-solved in sweep order from
        their predecessors until the sweep rejoins the first pass."""
        shape = (n_sets, nf, 2)
        lines = np.arange(n_sets * nf * 2).reshape(shape)
        first = np.concatenate([[True], seg[1:] != seg[:-1]])
        prev = np.roll(lines, 1, axis=1)
        prev[:, first] = lines[:, first]
        again = self._newton(table, arms, sol[0][:, prev.reshape(-1)])
        stuck = self._newton(table, arms, self._uniform_start(arms, table.refs[arms.row, 0]))
        iterations = int(again[2].max()) + int(stuck[2].max())

        def converged(a, n=n_sets):
            return (a[1] < self.tol).reshape(n, -1, 2).all(axis=-1)

        def differs(a, b, n=n_sets):
            """Per line: converged in both and the loads differ on an arm."""
            gap = np.sqrt((np.abs(a[0] - b[0]) ** 2).sum(axis=0))
            d = (gap > self.fold_tol * np.sqrt((np.abs(a[0]) ** 2).sum(axis=0))).reshape(n, -1, 2).any(axis=-1)
            return d & converged(a, n) & converged(b, n)

        fold = differs(sol, again) | differs(sol, stuck) | differs(again, stuck)
        fold[:, first] &= differs(sol, stuck)[:, first]
        out = [v.copy() for v in sol]

        def put(idx, src, at):
            for dst, v in zip(out, src):
                dst[..., idx] = v[..., at]

        # where the first pass did not converge, the stuck start may have
        rescue = converged(stuck) & ~converged(sol)
        if rescue.any():
            idx = lines[rescue].reshape(-1)
            put(idx, stuck, idx)
        # the sweep takes the restart from its predecessor where that converged to another state
        # (or where the first pass did not converge)
        take = converged(again) & (differs(sol, again) | ~converged(sol))
        take[:, first] = False
        if not take.any():
            return tuple(out), fold, iterations

        changed = np.zeros(n_sets, dtype=bool)  # the sweep's state at the previous line is not the first pass's
        for k in range(nf):
            if first[k]:
                changed[:] = False
                continue
            now = take[:, k] & ~changed  # predecessor as in the restart pass: its result stands
            if now.any():
                idx = lines[now, k].reshape(-1)
                put(idx, again, idx)
            if changed.any():
                sets = np.flatnonzero(changed)
                idx = lines[sets, k].reshape(-1)
                new = self._newton(table, arms.take(idx), out[0][:, lines[sets, k - 1].reshape(-1)])
                iterations += int(new[2].max())
                here = [out[0][:, idx], out[1][idx]]
                moved = differs(new, here, sets.size)[:, 0] | (converged(new, sets.size) & ~converged(here, sets.size))[:, 0]
                fold[sets, k] |= differs(new, here, sets.size)[:, 0]
                use = np.repeat(converged(new, sets.size)[:, 0], 2)
                put(idx[use], new, np.flatnonzero(use))
                now = now.copy()
                now[sets] = moved
            changed = now
        return tuple(out), fold, iterations
