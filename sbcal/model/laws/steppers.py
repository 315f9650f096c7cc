"""The hysteresis laws in time: steppers of the slip moment for the cable's time integration
(:mod:`sbcal.model.cable_time`).

A stepper advances the slip moment ``M_slip`` [N m] of many sections at once, each section with its
own law parameters (arrays). From the state committed at step ``n`` (curvature ``kappa_n`` and the
law's memory) and a trial curvature ``kappa_n+1``, :meth:`trial` gives the slip moment and its exact
tangent ``dM_slip / dkappa_n+1`` [N m^2] (what a Newton solver needs); :meth:`commit` keeps the state
of the trial the solver accepted. Within a step the curvature is taken to move monotonically from
``kappa_n`` to ``kappa_n+1`` (linear in time), so every law below is advanced exactly along that path
(rate independent: only the path matters):

:class:`JenkinsPopulation` (the Masing laws: ``iwan``, ``iwan5``, ``iwan_tail``, ``lognormal_iwan``)
    Parallel Jenkins elements (unit springs in series with sliders): an Iwan model, exact under any
    history (virgin loading, inner loops). The population is discretised from the law's backbone
    ``B`` (:func:`jenkins_population`): the elements slipping between ``phi_a`` and ``phi_b`` have the
    stiffness ``B'(phi_a) - B'(phi_b)`` and sit at their centroid, so the discrete backbone equals
    ``B`` at every cell edge; a point mass of the slip-curvature density (a jump of ``B'``) is an
    element of its own; what is still stuck beyond the last cell stays elastic.
:class:`DahlStepper` (``dahl``)
    ``chi_dahl d(eta) = d(kappa) (1 - sign(d kappa) eta)``, ``M_slip = delta_EJ chi_dahl eta``: on a
    monotone step, exact exponentials.
:class:`BoucWenStepper` (``bouc_wen``)
    ``chi_slip d(eta) = d(kappa) (1 - sign(d kappa) |eta|^(n-1) eta)``. On a monotone step the
    oriented state ``zeta = sign(d kappa) eta`` follows the one profile ``d(zeta)/dx = 1 - |zeta|^(n-1)
    zeta`` (``x = |d kappa| / chi_slip``): with ``Phi(zeta) = int_0^zeta dz / (1 - |z|^(n-1) z)`` a step is
    ``zeta_n+1 = Phi^-1(Phi(zeta_n) + x)``. ``Phi`` is tabulated once per exponent (cubic Hermite with
    exact slopes, ~1e-10) and the state carries ``Phi`` for both directions, so a step is one table
    lookup, whatever its length (an ODE integrator would need many sub-steps in gross slip).

:func:`law_stepper` picks the stepper of a law; :func:`drive` runs one along a curvature history.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from .base import HysteresisLaw, jenkins_rigidity


__all__ = ["LawState", "Trial", "NoSlip", "JenkinsPopulation", "DahlStepper", "BoucWenStepper",
           "jenkins_population", "law_stepper", "drive", "transition_curvature"]

# --- the Jenkins population's discretisation (measured in tests/test_cable_time.py) ------------------
_DECADES = (-6.0, 4.0)  # cells span these decades around the law's transition (beyond: one lump / elastic)
_SCAN_PER_LN = 24  # scan points per unit of ln(phi) for the cell placement
_TAIL_WIDTH = 0.5  # largest cell width in ln(phi) where the density is thin
_LOSS = 0.1  # as _BULK, against the section's whole rigidity's real and imaginary parts (``linear``)
_BULK = 0.055  # cells per unit ln(phi) grow as sqrt(dF/d ln phi) / _BULK (F: fraction of the stuck rigidity)
_FD = 1e-5  # relative step of the backbone's one-sided second-order differences
_ROUNDING = 1e-9  # a slipping share this close to 0 or 1 is the backbone's differences' rounding
_NEAR_BREAK = 1e-3  # a cell edge this close (relative) to a breakpoint is dropped: the breakpoint is the edge
_THIN = 1e-9  # dF/d ln(phi) below this (relative) is no density: no cells there (outside a compact support)


@dataclass(frozen=True, eq=False)
class LawState:
    """A stepper's committed state.

    Attributes
    ----------
    kappa : ndarray, shape (n_sections,)
        Curvature at the step [1/m].
    memory : tuple of ndarray
        The law's memory, each with the sections on its first axis.
    """

    kappa: np.ndarray
    memory: tuple = ()

    def take(self, idx) -> "LawState":
        """The state of the sections ``idx``."""
        return LawState(self.kappa[idx], tuple(m[idx] for m in self.memory))


@dataclass(frozen=True, eq=False)
class Trial:
    """The slip moment at a trial curvature.

    Attributes
    ----------
    moment : ndarray, shape (n_sections,)
        ``M_slip`` [N m].
    tangent : ndarray, shape (n_sections,)
        ``dM_slip / dkappa`` at the trial curvature [N m^2] (>= 0).
    kappa : ndarray, shape (n_sections,)
        The trial curvature [1/m].
    memory : tuple of ndarray
        The law's memory after the step (completed by the stepper's ``commit``).
    """

    moment: np.ndarray
    tangent: np.ndarray
    kappa: np.ndarray
    memory: tuple = ()


def _sections(*arrays):
    """The arrays as float arrays of one shape (n_sections,)."""
    out = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in arrays))
    return tuple(np.ascontiguousarray(a.reshape(-1)) for a in out)


@dataclass(frozen=True, eq=False)
class NoSlip:
    """No slip part (the linear cable): ``M_slip = 0``.

    Attributes
    ----------
    size : int
        Number of sections.
    """

    size: int

    def start(self) -> LawState:
        """The virgin state."""
        return LawState(np.zeros(self.size))

    def trial(self, state: LawState, kappa) -> Trial:
        """``M_slip = 0`` and its tangent 0 at ``kappa`` (n_sections,)."""
        z = np.zeros(self.size)
        return Trial(z, z, kappa)

    def commit(self, trial: Trial) -> LawState:
        """The state at the accepted trial."""
        return LawState(trial.kappa)

    def take(self, idx) -> "NoSlip":
        """The stepper of the sections ``idx``."""
        return NoSlip(int(np.arange(self.size)[idx].size))


# --- Masing laws: a population of Jenkins elements ------------------------------------------------

def transition_curvature(law: HysteresisLaw, **params) -> float:
    """Curvature [1/m] where the slip part has lost half its stuck rigidity: ``|EJ_slip*(chi)| =
    delta_EJ / 2`` (scalar parameters; a scan in decades, then bisection in ``ln chi``)."""
    stuck = abs(complex(law.slip_rigidity(0.0, **params)))
    scan = 10.0 ** np.arange(-12.0, 6.01, 0.25)
    ratio = np.abs(law.slip_rigidity(scan, **params)) / stuck
    below = np.flatnonzero(ratio < 0.5)
    if not np.isfinite(stuck) or stuck <= 0 or below.size == 0 or below[0] == 0:
        raise InputError(f"{law.name} law: no stick-slip transition between 1e-12 and 1e6 1/m for these parameters")
    lo, hi = math.log(scan[below[0] - 1]), math.log(scan[below[0]])
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if abs(complex(law.slip_rigidity(math.exp(mid), **params))) / stuck < 0.5:
            hi = mid
        else:
            lo = mid
    return math.exp(0.5 * (lo + hi))


def _slopes(backbone, phi):
    """One-sided slopes ``B'(phi-)``, ``B'(phi+)`` of the backbone (second-order differences, step
    ``_FD phi`` on one side only: neither straddles a breakpoint at ``phi``)."""
    h = _FD * phi
    b0 = backbone(phi)
    up = (-3.0 * b0 + 4.0 * backbone(phi + h) - backbone(phi + 2 * h)) / (2 * h)
    down = (3.0 * b0 - 4.0 * backbone(phi - h) + backbone(phi - 2 * h)) / (2 * h)
    return b0, down, up


def jenkins_population(law: HysteresisLaw, *, resolution: float = 1.0, linear: complex | None = None, **params):
    """Jenkins elements equivalent to a Masing law (scalar parameters).

    Cells in ``ln phi`` over ``_DECADES`` around the law's transition (:func:`transition_curvature`),
    only where the slip-curvature density is not zero. Their density per unit ``ln phi``::

        (1 / _TAIL_WIDTH + sqrt(f / s) / _BULK) * resolution,   f = dF / d ln phi,   s = |EJ_slip*(phi)| / delta_EJ

    (``F`` the fraction of the stuck rigidity slipping below ``phi``): the describing function at an
    amplitude ``~phi`` errs by about ``f h^2`` (``h`` the cells' width there; mostly a ripple from the
    element that starts slipping), so the cells keep that below ``~_BULK^2 s``: within 5e-4 of
    ``EJ_slip*`` from 1e-3 to 1e3 times the transition (``tests/test_cable_time.py``). The first term
    keeps thin tails resolved. Every curvature parameter of the law (unit 1/m: cut-offs, point masses)
    is an edge (the density may jump or end there); a jump of ``B'`` (a point mass) becomes an element
    exactly there.

    ``linear`` (a section's ``EJ_min (1 + i beta)`` [N m^2]): the density is also at least
    ``sqrt(f / s') / _LOSS`` with ``s'`` the smaller of the section's whole rigidity's real part and
    loss (``Im(linear + EJ_slip*)``, at least ``1e-3 |linear|``) over ``delta_EJ``. Near a lightly
    damped resonance what counts is the loss: in micro-slip the law's ``Im EJ_slip*`` is a small part
    of ``|EJ_slip*|`` but may be most of the section's loss, and it comes from the few wires slipping
    just below the amplitude (one element per 0.5 in ``ln phi`` errs by ~10 % there).

    Returns
    -------
    slip : ndarray, shape (n_elements,)
        Slip curvatures [1/m].
    stiffness : ndarray, shape (n_elements,)
        Element rigidities [N m^2] (they sum to the stuck rigidity less ``elastic``).
    elastic : float
        Rigidity [N m^2] of what is still stuck beyond the last cell (a spring without slider).
    """
    backbone = functools.partial(law.backbone, **params)
    stuck = float(np.real(law.slip_rigidity(0.0, **params)))
    t = transition_curvature(law, **params)
    units = {p.name: p.unit for p in law.parameters}
    lo, hi = t * 10.0 ** _DECADES[0], t * 10.0 ** _DECADES[1]
    breaks = np.array(sorted({float(params[k]) for k in params if units.get(k) == "1/m"
                              and lo < float(params[k]) < hi}))
    # scan: where the density lives and how much of it
    n_scan = int(math.ceil(_SCAN_PER_LN * math.log(hi / lo)))
    grid = np.unique(np.concatenate([np.geomspace(lo, hi, n_scan + 1), breaks]))
    _, down, up = _slopes(backbone, grid)
    frac = np.clip((stuck - np.where(np.isin(grid, breaks), up, 0.5 * (up + down))) / stuck, 0.0, 1.0)
    gain = np.maximum((up[:-1] - down[1:]) / stuck, 0.0)  # continuous share slipping in each scan interval
    width = np.diff(np.log(grid))
    density = gain / width
    # the describing function at amplitude ~phi comes from the cells near phi, each erring by ~ its
    # share times its width squared: the cells' density goes as sqrt(dF / d ln phi / |EJ_slip*(phi)|)
    mid = np.sqrt(grid[:-1] * grid[1:])
    slip_part = law.slip_rigidity(mid, **params)
    share = np.abs(slip_part) / stuck
    per_ln = (density > _THIN) / _TAIL_WIDTH + np.sqrt(density / np.maximum(share, 1e-12)) / _BULK
    if linear is not None:
        total = linear + slip_part
        loss = np.maximum(total.imag, 1e-3 * abs(linear)) / stuck
        per_ln = np.maximum(per_ln, np.sqrt(density / np.minimum(np.abs(total.real) / stuck, loss)) / _LOSS)
    per_ln = per_ln * resolution
    count = np.concatenate([[0.0], np.cumsum(per_ln * width)])
    n_cells = max(int(math.ceil(count[-1])), 1)
    edges = np.exp(np.interp(np.linspace(0.0, count[-1], n_cells + 1), count, np.log(grid)))
    if breaks.size:
        near = np.min(np.abs(np.log(edges[:, None] / breaks[None, :])), axis=1) < _NEAR_BREAK
        edges = np.union1d(edges[~near | (edges == lo) | (edges == hi)], breaks)
    # trim the ends where nothing slips (below a lower cut-off, above a compact support); the backbone's
    # differences leave ~1e-11 of rounding where the share is 0 or 1 (a law that is one point mass)
    live = np.flatnonzero((frac > _ROUNDING) & (frac < 1.0 - _ROUNDING))
    if live.size:
        first, last = grid[max(live[0] - 1, 0)], grid[min(live[-1] + 1, grid.size - 1)]
        edges = np.union1d(edges[(edges >= first) & (edges <= last)], [first, last])
    b, down, up = _slopes(backbone, edges)
    g_down, g_up = b - edges * down, b - edges * up  # G = B - phi B' = int_0^phi rho(s) s ds
    # cells: the lump below the first edge, then each cell, then the jumps at the breakpoints
    k = np.concatenate([[stuck - down[0]], up[:-1] - down[1:]])
    moment = np.concatenate([[g_down[0]], g_down[1:] - g_up[:-1]])
    left, right = np.concatenate([[0.0], edges[:-1]]), edges
    with np.errstate(divide="ignore", invalid="ignore"):
        centroid = np.clip(moment / k, left, right)
    at_break = np.isin(edges, breaks)
    jump = np.where(at_break, down - up, 0.0)
    slip = np.concatenate([centroid, edges[at_break]])
    stiffness = np.concatenate([k, jump[at_break]])
    keep = stiffness > 1e-14 * stuck
    return slip[keep], stiffness[keep], max(float(up[-1]), 0.0)


@dataclass(frozen=True, eq=False)
class JenkinsPopulation:
    """Parallel Jenkins elements per section: an Iwan model, stepped exactly.

    Element ``e`` of a section has rigidity ``k_e`` [N m^2] and slips at the elastic curvature
    ``phi_e`` [1/m]: its elastic curvature ``u_e`` follows ``kappa`` while ``|u_e| < phi_e`` and stays
    at ``+-phi_e`` while it slips. On a monotone step ``u_e -> clip(u_e + d kappa, -phi_e, phi_e)``
    (exact), ``M_slip = sum_e k_e u_e + k_el kappa``, tangent ``sum_e k_e [|u_e + d kappa| < phi_e] +
    k_el``.

    Attributes
    ----------
    slip : ndarray, shape (n_sections, n_elements)
        ``phi_e`` [1/m] (inf for padding).
    stiffness : ndarray, shape (n_sections, n_elements)
        ``k_e`` [N m^2] (0 for padding).
    elastic : ndarray, shape (n_sections,)
        ``k_el`` [N m^2]: the part still stuck beyond the population (never slips).
    """

    slip: np.ndarray
    stiffness: np.ndarray
    elastic: np.ndarray

    @classmethod
    def from_law(cls, law: HysteresisLaw, params: dict, *, resolution: float = 1.0,
                 linear=None) -> "JenkinsPopulation":
        """The population of a Masing law (one with ``backbone``) per section: ``params`` the law's
        parameters, each a scalar or shape (n_sections,); ``linear`` (complex, scalar or
        (n_sections,)) as :func:`jenkins_population`'s; one discretisation per distinct set."""
        names = law.parameter_names
        cols = [params[k] for k in names]
        if linear is not None:
            lin = np.asarray(linear, dtype=complex)
            cols += [lin.real, lin.imag]
        table = np.stack(_sections(*cols), axis=1)
        rows, inverse = np.unique(table, axis=0, return_inverse=True)
        pops = []
        for row in rows:
            lp = dict(zip(names, (float(v) for v in row)))
            lin = complex(row[-2], row[-1]) if linear is not None else None
            pops.append(jenkins_population(law, resolution=resolution, linear=lin, **lp))
        width = max(p[0].size for p in pops)
        slip = np.full((rows.shape[0], width), np.inf)
        stiffness = np.zeros((rows.shape[0], width))
        for r, (phi, k, _) in enumerate(pops):
            slip[r, :phi.size], stiffness[r, :k.size] = phi, k
        elastic = np.array([p[2] for p in pops])
        inverse = inverse.reshape(-1)
        return cls(slip[inverse], stiffness[inverse], elastic[inverse])

    @property
    def size(self) -> int:
        return self.elastic.size

    def start(self) -> LawState:
        """The virgin state: every element unstrained."""
        return LawState(np.zeros(self.size), (np.zeros(self.slip.shape),))

    def trial(self, state: LawState, kappa) -> Trial:
        """Slip moment and tangent at the curvature ``kappa`` (n_sections,) from ``state``."""
        u = state.memory[0] + (kappa - state.kappa)[:, None]
        stuck = np.abs(u) < self.slip
        np.clip(u, -self.slip, self.slip, out=u)
        moment = np.einsum("se,se->s", self.stiffness, u) + self.elastic * kappa
        tangent = np.einsum("se,se->s", self.stiffness, stuck) + self.elastic
        return Trial(moment, tangent, kappa, (u,))

    def commit(self, trial: Trial) -> LawState:
        """The state at the accepted trial."""
        return LawState(trial.kappa, trial.memory)

    def take(self, idx) -> "JenkinsPopulation":
        """The population of the sections ``idx``."""
        return JenkinsPopulation(self.slip[idx], self.stiffness[idx], self.elastic[idx])

    def describing_function(self, chi_a) -> np.ndarray:
        """The population's exact first harmonic ``sum_e k_e J(phi_e / chi_a) + k_el`` [N m^2] on its
        steady loop (:func:`sbcal.model.laws.base.jenkins_rigidity`), shape (n_sections, n_amplitudes)."""
        chi = np.atleast_1d(np.asarray(chi_a, dtype=float))
        x = self.slip[:, :, None] / chi[None, None, :]
        return np.einsum("se,sea->sa", self.stiffness, jenkins_rigidity(np.where(np.isfinite(x), x, 2.0))) \
            + self.elastic[:, None]


# --- Dahl: exact exponentials ----------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class DahlStepper:
    """Dahl's law per section, exact on a monotone step.

    With ``x = |d kappa| / chi_dahl`` and ``s = sign(d kappa)``: ``eta -> s (1 - (1 - s eta) exp(-x))``,
    ``M_slip = delta_EJ chi_dahl eta``, tangent ``delta_EJ (1 - s eta_n+1)`` (the law's right-hand side
    at the end of the step). Memory: ``eta``.

    Attributes
    ----------
    delta_EJ, chi : ndarray, shape (n_sections,)
        ``delta_EJ`` [N m^2] and ``chi_dahl`` [1/m].
    """

    delta_EJ: np.ndarray
    chi: np.ndarray

    @property
    def size(self) -> int:
        return self.chi.size

    def start(self) -> LawState:
        return LawState(np.zeros(self.size), (np.zeros(self.size),))

    def trial(self, state: LawState, kappa) -> Trial:
        step = kappa - state.kappa
        s = np.where(step >= 0.0, 1.0, -1.0)
        decay = np.exp(-np.abs(step) / self.chi)
        gap = (1.0 - s * state.memory[0]) * decay  # 1 - zeta_n+1
        eta = state.memory[0] * decay - s * np.expm1(-np.abs(step) / self.chi)  # s (1 - gap), no cancellation
        return Trial(self.delta_EJ * self.chi * eta, self.delta_EJ * gap, kappa, (eta,))

    def commit(self, trial: Trial) -> LawState:
        return LawState(trial.kappa, trial.memory)

    def state(self, kappa, eta) -> LawState:
        """The state at curvature ``kappa`` [1/m] with the internal variable ``eta`` (|eta| <= 1),
        each (n_sections,) (e.g. a point of a steady loop)."""
        kappa, eta = _sections(kappa, eta)
        return LawState(kappa, (eta,))

    def take(self, idx) -> "DahlStepper":
        return DahlStepper(self.delta_EJ[idx], self.chi[idx])


# --- Bouc-Wen: the tabulated profile ---------------------------------------------------------------

_G_FAR = -40.0  # the profile table ends at 1 - zeta = exp(-40) (beyond: linear in ln(1 - zeta))
_KNEE = 0.9  # below: nodes graded towards zeta = 0; above: uniform in ln(1 - zeta)
_NODES_NEAR, _NODES_FAR = 400, 600
_GL = np.polynomial.legendre.leggauss(8)


def _rate(g, n):
    """``r = 1 - |zeta|^(n-1) zeta`` at ``zeta = 1 - exp(g)``, without cancellation near ``zeta = 1``."""
    g = np.asarray(g, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = -np.expm1(n * np.log1p(-np.exp(np.minimum(g, 0.0))))  # 1 - zeta^n, zeta >= 0
        neg = 1.0 + np.expm1(np.maximum(g, 0.0)) ** n  # 1 + |zeta|^n, zeta <= 0
    return np.where(g < 0.0, pos, np.where(g > 0.0, neg, 1.0))


@functools.lru_cache(maxsize=64)
def _profile(n: float):
    """Nodes of ``Phi`` against ``g = ln(1 - zeta)``: (u, g, dg/du), u increasing (g decreasing).

    ``dPhi/dg = -exp(g) / r``: smooth and bounded on each side of ``zeta = 0`` (where ``|zeta|^n`` is
    not smooth: nodes graded geometrically towards it), linear in ``g`` as ``zeta -> 1``. ``Phi`` by
    8-point Gauss-Legendre per interval, summed from ``zeta = 0``.
    """
    # |zeta| = t^q, t uniform: the singular term |zeta|^(n+1) is t^(q (n+1)), smooth enough for q (n + 1) >= 4
    q = max(1.0, 4.0 / (n + 1.0))
    t = np.linspace(0.0, 1.0, _NODES_NEAR + 1)[1:]
    neg = np.log1p(t**q)  # zeta = -t^q in [-1, 0)
    pos = np.log1p(-_KNEE * t**q)  # zeta in (0, _KNEE]
    far = np.linspace(math.log1p(-_KNEE), _G_FAR, _NODES_FAR + 1)[1:]  # then uniform in ln(1 - zeta)
    g = np.concatenate([neg[::-1], [0.0], pos, far])  # decreasing g: zeta from -1 to 1
    x, w = _GL
    a, b = g[:-1, None], g[1:, None]
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    nodes = mid + half * x[None, :]
    pieces = (half[:, 0] * (w[None, :] * (-np.exp(nodes) / _rate(nodes, n))).sum(axis=1))
    zero = int(np.flatnonzero(g == 0.0)[0])
    u = np.zeros(g.size)
    u[zero + 1:] = np.cumsum(pieces[zero:])
    u[:zero] = -np.cumsum(pieces[:zero][::-1])[::-1]
    slope = -_rate(g, n) / np.exp(g)  # dg/du
    return u, g, slope


@dataclass(frozen=True, eq=False)
class _Profiles:
    """The profile tables of several exponents, concatenated: table ``j`` holds nodes
    ``start[j] .. start[j+1] - 1``; ``ukey``, ``gkey`` search keys increasing across all tables
    (``u`` and ``-g`` shifted by the table's index times a span larger than either's range)."""

    u: np.ndarray
    g: np.ndarray
    dgdu: np.ndarray
    start: np.ndarray
    ukey: np.ndarray
    gkey: np.ndarray

    _USPAN = 1e4  # |u| < ~200 (n >= 0.3: Phi(1 - e^-40) ~ 40 / n)
    _GSPAN = 1e3  # -g in [-ln 2, 40]

    @classmethod
    def of(cls, exponents) -> "_Profiles":
        tabs = [_profile(float(n)) for n in exponents]
        start = np.concatenate([[0], np.cumsum([t[0].size for t in tabs])])
        u, g, d = (np.concatenate([t[i] for t in tabs]) for i in range(3))
        which = np.repeat(np.arange(len(tabs)), np.diff(start))
        return cls(u, g, d, start, u + cls._USPAN * which, -g + cls._GSPAN * which)

    @staticmethod
    def _interval(keys, offset, first, last):
        """Index of the node interval (within the table's nodes ``first .. last``) holding ``offset``."""
        return np.clip(np.searchsorted(keys, offset, side="right") - 1, first, last - 1)

    def forward(self, table, u):
        """``g = ln(1 - zeta)`` and ``dg/du`` at ``u = Phi(zeta)`` (per section: its table)."""
        first, last = self.start[table], self.start[table + 1] - 1
        i = self._interval(self.ukey, self._USPAN * table + np.clip(u, self.u[first], self.u[last]), first, last)
        return _cubic(u, self.u[i], self.u[i + 1], self.g[i], self.g[i + 1], self.dgdu[i], self.dgdu[i + 1],
                      beyond=u > self.u[last], x_end=self.u[last], y_end=self.g[last], d_end=self.dgdu[last])

    def inverse(self, table, g):
        """``u = Phi(zeta)`` at ``g = ln(1 - zeta)``."""
        first, last = self.start[table], self.start[table + 1] - 1
        i = self._interval(self.gkey, self._GSPAN * table + np.clip(-g, -self.g[first], -self.g[last]), first, last)
        value, _ = _cubic(g, self.g[i], self.g[i + 1], self.u[i], self.u[i + 1], 1.0 / self.dgdu[i],
                          1.0 / self.dgdu[i + 1], beyond=g < self.g[last], x_end=self.g[last],
                          y_end=self.u[last], d_end=1.0 / self.dgdu[last])
        return value


def _cubic(x, x0, x1, y0, y1, d0, d1, *, beyond, x_end, y_end, d_end):
    """Cubic Hermite on ``[x0, x1]`` (either order): value and derivative at ``x``; the line through
    the end node where ``beyond``."""
    h = x1 - x0
    t = (x - x0) / h
    dy = y1 - y0
    # y = y0 + t (h d0) + t^2 (3 dy - 2 h d0 - h d1) + t^3 (h d0 + h d1 - 2 dy)
    c2 = 3.0 * dy - h * (2.0 * d0 + d1)
    c3 = h * (d0 + d1) - 2.0 * dy
    y = y0 + t * (h * d0 + t * (c2 + t * c3))
    dydx = d0 + t * (2.0 * c2 + 3.0 * t * c3) / h
    y = np.where(beyond, y_end + d_end * (x - x_end), y)
    dydx = np.where(beyond, d_end, dydx)
    return y, dydx


@dataclass(frozen=True, eq=False)
class BoucWenStepper:
    """The Bouc-Wen law per section, stepped along its tabulated profile.

    Memory: ``eta`` and ``Phi(eta)``, ``Phi(-eta)`` (the profile coordinate of the state for a step
    up and for a step down). A step of ``d kappa`` (sign ``s``, ``x = |d kappa| / chi_slip``) moves
    ``u = Phi(s eta)`` to ``u + x`` and ``eta = s Phi^-1(u + x)``; ``M_slip = delta_EJ chi_slip eta``,
    tangent ``delta_EJ dzeta/du`` (the derivative of the interpolant: consistent with the moment).

    Attributes
    ----------
    delta_EJ, chi : ndarray, shape (n_sections,)
        ``delta_EJ`` [N m^2] and ``chi_slip`` [1/m].
    table : ndarray of int, shape (n_sections,)
        Each section's profile (its exponent) in ``profiles``.
    profiles : _Profiles
    """

    delta_EJ: np.ndarray
    chi: np.ndarray
    table: np.ndarray
    profiles: _Profiles

    @classmethod
    def from_params(cls, delta_EJ, chi_slip, sharpness) -> "BoucWenStepper":
        d, c, n = _sections(delta_EJ, chi_slip, sharpness)
        exps, table = np.unique(n, return_inverse=True)
        return cls(d, c, table.reshape(-1).astype(np.intp), _Profiles.of(exps))

    @property
    def size(self) -> int:
        return self.chi.size

    def start(self) -> LawState:
        z = np.zeros(self.size)
        return LawState(z, (z, z, z))

    def trial(self, state: LawState, kappa) -> Trial:
        eta, up, down = state.memory
        step = kappa - state.kappa
        rising = step >= 0.0
        s = np.where(rising, 1.0, -1.0)
        u = np.where(rising, up, down) + np.abs(step) / self.chi
        g, dgdu = self.profiles.forward(self.table, u)
        e = np.exp(g)
        zeta = -np.expm1(g)  # relative precision at small zeta (the first steps from rest)
        eta_new = s * zeta
        # no step: the state as it is (the table's round trip is ~1e-10, not exact)
        eta_new = np.where(step == 0.0, eta, eta_new)
        tangent = self.delta_EJ * np.maximum(-e * dgdu, 0.0)
        return Trial(self.delta_EJ * self.chi * eta_new, tangent, kappa, (eta_new, u, s))

    def commit(self, trial: Trial) -> LawState:
        eta, u, s = trial.memory
        # Phi of the state seen from the other direction: zeta' = -s eta, g = ln(1 - zeta') = log1p(s eta)
        other = self.profiles.inverse(self.table, np.log1p(np.maximum(s * eta, -1.0 + 1e-300)))
        rising = s > 0
        return LawState(trial.kappa, (eta, np.where(rising, u, other), np.where(rising, other, u)))

    def state(self, kappa, eta) -> LawState:
        """The state at curvature ``kappa`` [1/m] with the internal variable ``eta`` (|eta| <= 1),
        each (n_sections,) (e.g. a point of a steady loop)."""
        kappa, eta = _sections(kappa, eta)
        up = self.profiles.inverse(self.table, np.log1p(-np.minimum(eta, 1.0 - 1e-16)))
        down = self.profiles.inverse(self.table, np.log1p(np.maximum(eta, -1.0 + 1e-16)))
        return LawState(kappa, (eta, up, down))

    def take(self, idx) -> "BoucWenStepper":
        return BoucWenStepper(self.delta_EJ[idx], self.chi[idx], self.table[idx], self.profiles)


# --- dispatch and driving ---------------------------------------------------------------------------

def law_stepper(law: HysteresisLaw | None, params: dict, *, size: int | None = None, resolution: float = 1.0,
                linear=None):
    """The time stepper of ``law`` for sections with the parameters ``params``.

    Parameters
    ----------
    law : HysteresisLaw or None
        A law of :mod:`sbcal.model.laws` (not zoned: a zoned law's sections carry their zone's
        parameters of its ``base``); None: no slip part.
    params : dict
        The law's parameters, each a scalar or shape (n_sections,).
    size : int, optional
        Number of sections (default: the parameters' size).
    resolution : float
        Jenkins populations only: cell density multiplier (1: the describing function within 5e-4,
        ``tests/test_cable_time.py``).
    linear : complex or array_like of complex, shape (n_sections,), optional
        Jenkins populations only: the sections' ``EJ_min (1 + i beta)`` [N m^2] (:func:`jenkins_population`).

    Returns
    -------
    NoSlip, JenkinsPopulation, DahlStepper or BoucWenStepper
    """
    if law is None:
        return NoSlip(int(size if size is not None else 1))
    if not (resolution > 0 and math.isfinite(resolution)):
        raise InputError(f"resolution: expected a finite value > 0, got {resolution!r}")
    names = law.parameter_names
    missing = [k for k in names if k not in params]
    if missing:
        raise InputError(f"{law.name} law: parameter {missing[0]!r} is required")
    n = size if size is not None else max(np.size(params[k]) for k in names)
    p = {}
    for k in names:
        v = np.asarray(params[k], dtype=float).reshape(-1)
        if v.size not in (1, n):
            raise InputError(f"{law.name} law: parameter {k!r} has {v.size} values for {n} sections")
        p[k] = np.ascontiguousarray(np.broadcast_to(v, (n,)))
    if not np.all(law.valid(**p)):
        raise InputError(f"{law.name} law: parameters outside the law's domain")
    own = law.time_stepper(p, resolution=resolution, linear=linear)
    if own is not None:
        return own
    if hasattr(law, "backbone"):
        return JenkinsPopulation.from_law(law, p, resolution=resolution, linear=linear)
    raise InputError(f"{law.name} law: no time stepper (a Masing law with a backbone, or its own time_stepper)")


def drive(stepper, kappa) -> np.ndarray:
    """Run ``stepper`` from its virgin state along the curvature history ``kappa`` [1/m], shape
    (n_steps, n_sections) (each step a monotone path from the previous value; the history starts
    from 0); the slip moment [N m] after each step, shape (n_steps, n_sections)."""
    kappa = np.asarray(kappa, dtype=float)
    state = stepper.start()
    out = np.empty(kappa.shape)
    for i, k in enumerate(kappa):
        trial = stepper.trial(state, k)
        out[i] = trial.moment
        state = stepper.commit(trial)
    return out
