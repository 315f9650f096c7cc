"""Below both cable models: the frequency grid they are solved on; and the fast model's sections
(:class:`sbcal.model.cable.CableModel`): each law's section compliance tabulated over curvature and looked
up, and the statically determinate arms' Gauss sections."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..core.errors import InputError
from . import cable_kernel
from .laws import HysteresisLaw


__all__ = ["FD_LOG_STEP", "TINY", "checked_grid", "Compliance", "linear_compliance", "compliance_table", "Arms",
           "gauss"]

FD_LOG_STEP = 1e-6  # forward-difference step of the law's slope in ln chi
TINY = 1e-300
# curvatures [1/m] scanned for the law's transition (where the slip part has lost half its stuck
# value); the compliance table spans ``table_decades`` either side of it
_SCAN = 10.0 ** np.arange(-9.0, 3.01, 1.0 / 3.0)

# --- both models: the frequency grid ---------------------------------------------------------------

def segments_from_frequencies(freq_hz) -> np.ndarray:
    """Test index per line, a new test starting wherever the frequency does not increase.

    Returns
    -------
    ndarray of int, shape (n_freq,)
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    return np.concatenate([[0], np.cumsum(np.diff(f) <= 0)]).astype(int)


def checked_grid(freq_hz, amplitude_mm_pp, segments, per_set=False):
    """Validated frequencies [Hz], amplitudes [mm p-p] and test segments, each shape (n_freq,)
    (``per_set``: amplitudes may also be (n_sets or 1, n_freq), returned 2-D then)."""
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or not np.all(np.isfinite(f) & (f > 0)):
        raise InputError("freq_hz: expected finite frequencies > 0 [Hz], shape (n_freq,)")
    amp = np.asarray(amplitude_mm_pp, dtype=float)
    if per_set and amp.ndim == 2 and amp.shape[1] == f.size:
        pass  # one amplitude per (set, line)
    elif amp.ndim > 1 or amp.size not in (1, f.size):
        shapes = f"({f.size},)" + (f" or (n_sets, {f.size})" if per_set else "")
        raise InputError(f"amplitude_mm_pp: expected a scalar or shape {shapes}, got shape {amp.shape}")
    else:
        amp = np.broadcast_to(amp.reshape(-1), f.shape)
    if not np.all(np.isfinite(amp) & (amp > 0)):
        raise InputError("amplitude_mm_pp: expected finite amplitudes > 0 [mm p-p]")
    seg = segments_from_frequencies(f) if segments is None else np.asarray(segments)
    if seg.shape != f.shape:
        raise InputError(f"segments: expected shape {f.shape}, got {seg.shape}")
    return f, amp, seg


# --- the fast model: statically determinate arms ---------------------------------------------------

@dataclass(frozen=True, eq=False)
class Compliance:
    """Section compliance ``K = 1 / EJ*(a)`` per parameter set as a function of ``y = ln m^2``,
    ``m = a |EJ*(a)| = |M|`` [N m] the section's moment amplitude.

    Nodes uniform in the curvature ``u = ln a`` (j = 0 .. n - 1), so they crowd where the moment
    saturates while the curvature runs on (a uniform grid in ``y`` would step over that knee); on
    each interval ``[y_j, y_j+1]`` ``K`` is the cubic Hermite interpolant of the nodes' ``K`` and
    ``dK/dy``, stored as power coefficients in ``y - y_j``. A section finds its interval through a
    uniform grid of buckets in ``y`` (the first interval of each bucket, then ``steps`` comparisons
    with the next node): gathers, no search. Beyond the nodes, ``K -> k_ref + (K_end - k_ref) exp(p (y - y_end))`` with ``k_ref`` the stuck (below) or
    fully slipped (above) compliance and ``p`` matching the end node's slope.

    Attributes
    ----------
    coef : ndarray, shape (9, n_sets * (n - 1))
        Per interval ``Re c0..c3, Im c0..c3`` of ``K = c0 + c1 v + c2 v^2 + c3 v^3``, ``v = y - y_j``,
        then ``y_j``.
    upper : ndarray, shape (n_sets * (n - 1),)
        ``y_j+1`` of each interval (+inf for each set's last).
    first : ndarray of intp, shape (n_sets * n_buckets,)
        Global index of the interval holding each bucket's lower edge.
    y0, inv_w : ndarray, shape (n_sets,)
        First node's ``y`` and the inverse bucket width; ``y_end`` the last node's ``y``.
    n, n_buckets, steps : int
    ends : ndarray of complex, shape (n_sets, 2)
        ``K`` at the first and last node.
    refs : ndarray of complex, shape (n_sets, 2)
        Stuck and fully slipped compliance.
    rates : ndarray of complex, shape (n_sets, 2)
        Tail exponents ``p`` [per unit y] below and above.
    monotone : ndarray of bool, shape (n_sets,)
        ``a |EJ*(a)|`` increases over the table (a section's moment fixes its curvature).
    """

    coef: np.ndarray
    upper: np.ndarray
    first: np.ndarray
    y0: np.ndarray
    y_end: np.ndarray
    inv_w: np.ndarray
    n: int
    n_buckets: int
    steps: int
    ends: np.ndarray
    refs: np.ndarray
    rates: np.ndarray
    monotone: np.ndarray

    @property
    def args(self) -> tuple:
        """The table as the compiled kernel's trailing arguments (:mod:`sbcal.model.cable_kernel`)."""
        cache = self.__dict__.get("_args")
        if cache is None:
            c = np.ascontiguousarray
            cache = (c(self.coef, dtype=float), c(self.upper, dtype=float), c(self.first, dtype=np.intp),
                     c(self.y0, dtype=float), c(self.y_end, dtype=float), c(self.inv_w, dtype=float),
                     int(self.n_buckets), int(self.steps), c(self.ends, dtype=complex), c(self.refs, dtype=complex),
                     c(self.rates, dtype=complex))
            object.__setattr__(self, "_args", cache)
        return cache


def _hermite_table(y, k, dk, refs, n_buckets_per_node=8, max_steps=1) -> Compliance:
    """Pack nodes ``y`` (n_sets, n) increasing, ``K`` and ``dK/dy`` there into a :class:`Compliance`."""
    s, n = y.shape
    rows = np.arange(s)
    h = np.diff(y, axis=1)
    h = np.where(h > 0, h, 1.0)
    ka, kb, da, db = k[:, :-1], k[:, 1:], h * dk[:, :-1], h * dk[:, 1:]
    c = np.stack([ka, da / h, (3 * (kb - ka) - 2 * da - db) / h**2, (2 * (ka - kb) + da + db) / h**3])
    coef = np.concatenate([c.real, c.imag, y[None, :, :-1]]).reshape(9, -1)
    upper = y[:, 1:].copy()
    upper[:, -1] = np.inf
    y0, y_end = y[:, 0], y[:, -1]
    span = np.maximum(y_end - y0, TINY)
    nb = n_buckets_per_node * (n - 1)
    while True:  # double the buckets until a lookup needs at most max_steps comparisons
        first, steps = cable_kernel.buckets(np.ascontiguousarray(y, dtype=float), y0, span, nb)
        if steps <= max_steps or nb >= 64 * n:
            break
        nb *= 2
    first = (first + (n - 1) * rows[:, None]).reshape(-1).astype(np.intp)
    ends = k[:, [0, -1]]
    with np.errstate(divide="ignore", invalid="ignore"):
        rates = dk[:, [0, -1]] / (ends - refs)
    # a tail must decay towards its limit; otherwise hold the end value
    ok = np.isfinite(rates) & (np.array([1.0, -1.0]) * rates.real > 0)
    rates = np.where(ok, rates, 0.0)
    return Compliance(coef=np.ascontiguousarray(coef), upper=upper.reshape(-1), first=first, y0=y0, y_end=y_end,
                      inv_w=nb / span, n=n, n_buckets=nb, steps=max(steps, 1), ends=ends, refs=refs,
                      rates=rates, monotone=np.ones(s, dtype=bool))


def linear_compliance(lin) -> Compliance:
    """The table of a linear cable: ``K = 1 / lin`` for every moment."""
    k = np.repeat((1.0 / lin)[:, None], 2, axis=1)
    # one interval over every representable |M|^2 (ln of a double lies within +-745)
    y = np.repeat(np.array([[-2000.0, 2000.0]]), lin.size, axis=0)
    return _hermite_table(y, k, np.zeros_like(k), k.copy())


def compliance_table(law: HysteresisLaw, lp: dict, lin, n: int, decades: float) -> Compliance:
    """Tabulate ``K(y)`` for each parameter set.

    ``lp``: the law's parameters, each (n_sets, 1); ``lin = EJ_min (1 + i beta_material)`` (n_sets,).
    A coarse scan finds the law's transition (the curvature where the slip part has lost half its
    stuck value); ``n`` nodes uniform in ``ln a`` span ``decades`` either side of it. Two law
    evaluations of ``n`` curvatures per set (``EJ*`` and a forward difference for its slope): the
    nodes' moments ``m = a |EJ*(a)|`` need no inversion.
    """
    s = lin.size
    rows = np.arange(s)
    stuck = law.slip_rigidity(np.zeros((s, 1)), **lp)[:, 0]
    ratio = np.abs(law.slip_rigidity(_SCAN[None, :], **lp)) / np.maximum(np.abs(stuck), TINY)[:, None]
    below = ratio < 0.5
    k = np.where(below.any(axis=1), below.argmax(axis=1), _SCAN.size // 2).clip(1, _SCAN.size - 1)
    r0, r1 = ratio[rows, k - 1], ratio[rows, k]
    frac = np.clip((r0 - 0.5) / np.maximum(r0 - r1, TINY), 0.0, 1.0)
    u_mid = np.log(_SCAN[k - 1]) + frac * np.log(_SCAN[1] / _SCAN[0])

    span = decades * np.log(10.0)
    u = u_mid[:, None] + np.linspace(-span, span, n)[None, :]
    e = lin[:, None] + law.slip_rigidity(np.exp(u), **lp)
    de = (lin[:, None] + law.slip_rigidity(np.exp(u + FD_LOG_STEP), **lp) - e) / FD_LOG_STEP
    y = 2.0 * (u + np.log(np.abs(e)))
    dy_du = 2.0 * (1.0 + (de / e).real)
    kk = 1.0 / e
    dk = -de / (e * e) / np.where(dy_du > 0, dy_du, 1.0)
    refs = np.stack([1.0 / (lin + stuck), 1.0 / lin], axis=1)
    table = _hermite_table(y, kk, dk, refs)
    monotone = (np.all(dy_du > 0, axis=1) & np.all(np.diff(y, axis=1) > 0, axis=1)
                & np.all(np.isfinite(table.coef.reshape(9, s, -1)), axis=(0, 2)))
    return replace(table, monotone=monotone)


@dataclass(frozen=True, eq=False)
class Arms:
    """Per-(set, line, arm) constants of the statically determinate arms, flattened on one batch axis
    b = (set * n_freq + line) * 2 + arm; arm-local frame (s from the clamp to the mass node).

    In the scaled unknowns ``p = (V L, M_tip)`` [N m] (the moment ``M = p0 eta + p1``, ``eta = 1 - s/L``)
    the node's equation (its inertia balancing the load) is ``p = Mm . S(p) + c``, with
    ``S(p) = sum_q w_q (eta_q, 1) K_q M_q`` the flexibility integral (per unit length: the node's
    motion relative to the clamp's rigid motion is ``diag(L^2, L) S``). It is solved in the form
    ``N p - S(p) - N c = 0``, ``N = Mm^-1``; the vertical clamp force is ``fa p0 + fb p1 + fc``.
    """

    n: np.ndarray  # (3, b): N = Mm^-1 as (n00, n01, n11), Mm = omega^2 L diag(L, 1) M_node diag(L, 1)
    nc: np.ndarray  # (2, b): N c, c = omega^2 diag(L, 1) (M_node q_rigid + M_node,clamp q_clamp)
    force: tuple  # (fa, fb, fc) real
    row: np.ndarray  # table row (parameter set) of each entry, intp
    length: np.ndarray  # arm length [m]
    # a zoned cable (sbcal.model.laws.zones): the sections per parameter set, eta (Q, n_sets) from the mass node,
    # weights w (Q, n_sets) and each section's zone (Q,) (CableModel._zone_rule); None: the model's one rule
    rule: tuple | None = None

    @property
    def zoned(self) -> bool:
        return self.rule is not None

    @cached_property
    def eta(self) -> np.ndarray | None:
        """A zoned cable's section positions per entry (Q, b) (None: the model's one rule)."""
        return None if self.rule is None else np.ascontiguousarray(self.rule[0][:, self.row])

    @cached_property
    def weights(self) -> np.ndarray | None:
        """A zoned cable's weights per entry, ``w eta^(4 - k)`` (5, Q, b)."""
        if self.rule is None:
            return None
        return np.ascontiguousarray(self.eta[None] ** np.arange(4, -1, -1)[:, None, None] * self.rule[1][:, self.row][None])

    @cached_property
    def zrow(self) -> np.ndarray | None:
        """A zoned cable's table row per section and entry (Q, b): ``zone * n_sets + set``."""
        if self.rule is None:
            return None
        return (self.rule[2][:, None] * self.rule[0].shape[1] + self.row[None, :]).astype(np.intp)

    def take(self, idx):
        """The constants of the entries ``idx``."""
        return Arms(n=self.n[:, idx], nc=self.nc[:, idx], force=tuple(v[idx] for v in self.force),
                    row=self.row[idx], length=self.length[idx], rule=self.rule)


def gauss(q: int):
    """Gauss-Legendre on [0, 1]: eta nodes (from the mass node, eta = 1 - s/L) and weights."""
    x, w = np.polynomial.legendre.leggauss(q)
    return 0.5 * (1.0 - x), 0.5 * w
