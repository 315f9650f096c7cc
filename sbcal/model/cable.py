"""The distributed cable: one hysteretic strand-slip law along both arms (``docs/cable.md``).

Each section of the messenger cable has the complex secant rigidity::

    EJ*(chi_a) = EJ_min (1 + i beta_material) + EJ_slip*(chi_a)

with ``EJ_slip*`` the first-harmonic describing function of a law of :mod:`sbcal.model.hysteresis` at the
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

import math
import threading
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import InputError
from .damper import GEOMETRY, Damper
from .hysteresis import HysteresisLaw


__all__ = [
    "DEFAULT_SECTIONS",
    "DEFAULT_N_ELEMENTS",
    "CableState",
    "CableModel",
    "ElementCableState",
    "ElementCableModel",
    "segments_from_frequencies",
]

DEFAULT_SECTIONS = 8
"""Gauss-Legendre sections per arm of :class:`CableModel` (the convergence study of ``docs/cable.md``)."""

DEFAULT_N_ELEMENTS = 6
"""Elements per arm of :class:`ElementCableModel` (the convergence study of ``docs/cable.md``)."""

_BASE = ("EJ_min", "beta_material", "rocking_rad_per_m")
_FD_LOG_STEP = 1e-6  # forward-difference step of the law's slope in ln chi
_MAX_LOG_STEP = 2.0  # element model: Newton step cap in ln chi (a factor e^2 per iteration)
_TINY = 1e-300
_STEP_CAP = 0.5  # fast model: a Newton step is at most this fraction of |P|
_START_STEPS = 6  # fast model: relaxed steps of the one-compliance start
_START_RELAX = 0.3
# curvatures [1/m] scanned for the law's transition (where the slip part has lost half its stuck
# value); the compliance table spans ``table_decades`` either side of it
_SCAN = 10.0 ** np.arange(-9.0, 3.01, 1.0 / 3.0)


def segments_from_frequencies(freq_hz) -> np.ndarray:
    """Test index per line, a new test starting wherever the frequency does not increase.

    Returns
    -------
    ndarray of int, shape (n_freq,)
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    return np.concatenate([[0], np.cumsum(np.diff(f) <= 0)]).astype(int)


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


def _grid(freq_hz, amplitude_mm_pp, segments, per_set=False):
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
class _Compliance:
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

    def per_entry(self, row):
        """``(y0, inv_w, bucket offset)`` of the parameter sets ``row`` (cached for the last ``row``)."""
        cache = self.__dict__.get("_per_entry")
        if cache is None or cache[0] is not row:
            cache = (row, self.y0[row], self.inv_w[row], row * self.n_buckets)
            object.__setattr__(self, "_per_entry", cache)
        return cache[1:]


def _hermite_table(y, k, dk, refs, n_buckets_per_node=8, max_steps=1) -> _Compliance:
    """Pack nodes ``y`` (n_sets, n) increasing, ``K`` and ``dK/dy`` there into a :class:`_Compliance`."""
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
    span = np.maximum(y_end - y0, _TINY)
    nb = n_buckets_per_node * (n - 1)
    while True:
        # first interval of each bucket; the most nodes inside one bucket is the comparisons needed
        edges = y0[:, None] + span[:, None] * (np.arange(nb) / nb)[None, :]
        z = (y - y0[:, None]) / span[:, None] + 2.0 * rows[:, None]
        ze = (edges - y0[:, None]) / span[:, None] + 2.0 * rows[:, None]
        pos = np.searchsorted(z.ravel(), ze.ravel(), side="right").reshape(s, nb) - n * rows[:, None]
        first = np.clip(pos - 1, 0, n - 2)
        steps = int(np.max(np.diff(np.concatenate([pos, np.full((s, 1), n)], axis=1), axis=1), initial=0))
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
    return _Compliance(coef=np.ascontiguousarray(coef), upper=upper.reshape(-1), first=first, y0=y0, y_end=y_end,
                       inv_w=nb / span, n=n, n_buckets=nb, steps=max(steps, 1), ends=ends, refs=refs,
                       rates=rates, monotone=np.ones(s, dtype=bool))


def _linear_compliance(lin) -> _Compliance:
    """The table of a linear cable: ``K = 1 / lin`` for every moment."""
    k = np.repeat((1.0 / lin)[:, None], 2, axis=1)
    # one interval over every representable |M|^2 (ln of a double lies within +-745)
    y = np.repeat(np.array([[-2000.0, 2000.0]]), lin.size, axis=0)
    return _hermite_table(y, k, np.zeros_like(k), k.copy())


def _compliance_table(law: HysteresisLaw, lp: dict, lin, n: int, decades: float) -> _Compliance:
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
    ratio = np.abs(law.slip_rigidity(_SCAN[None, :], **lp)) / np.maximum(np.abs(stuck), _TINY)[:, None]
    below = ratio < 0.5
    k = np.where(below.any(axis=1), below.argmax(axis=1), _SCAN.size // 2).clip(1, _SCAN.size - 1)
    r0, r1 = ratio[rows, k - 1], ratio[rows, k]
    frac = np.clip((r0 - 0.5) / np.maximum(r0 - r1, _TINY), 0.0, 1.0)
    u_mid = np.log(_SCAN[k - 1]) + frac * np.log(_SCAN[1] / _SCAN[0])

    span = decades * np.log(10.0)
    u = u_mid[:, None] + np.linspace(-span, span, n)[None, :]
    e = lin[:, None] + law.slip_rigidity(np.exp(u), **lp)
    de = (lin[:, None] + law.slip_rigidity(np.exp(u + _FD_LOG_STEP), **lp) - e) / _FD_LOG_STEP
    y = 2.0 * (u + np.log(np.abs(e)))
    dy_du = 2.0 * (1.0 + (de / e).real)
    kk = 1.0 / e
    dk = -de / (e * e) / np.where(dy_du > 0, dy_du, 1.0)
    refs = np.stack([1.0 / (lin + stuck), 1.0 / lin], axis=1)
    table = _hermite_table(y, kk, dk, refs)
    monotone = (np.all(dy_du > 0, axis=1) & np.all(np.diff(y, axis=1) > 0, axis=1)
                & np.all(np.isfinite(table.coef.reshape(9, s, -1)), axis=(0, 2)))
    return replace(table, monotone=monotone)


class _Work:
    """Scratch arrays of the section arithmetic, kept per thread across calls.

    ``get(name, shape)`` is a contiguous view of the first ``prod(shape)`` elements of the buffer
    ``name`` (grown when too small, never shrunk). The hot loop writes into memory it already
    owns: a fresh ~1 MB array costs its page faults, more than the arithmetic done on it, and a
    sampler calls the model ~10^4 times with the same shapes. Every element read in a call is
    written earlier in that call, so the results do not depend on the buffers' history.
    """

    _local = threading.local()

    @classmethod
    def get(cls, name, shape, dtype=float):
        buffers = cls._local.__dict__.setdefault("buffers", {})
        n = math.prod(shape)
        buf = buffers.get((name, np.dtype(dtype)))
        if buf is None or buf.size < n:
            buf = buffers[(name, np.dtype(dtype))] = np.empty(n, dtype=dtype)
        return buf[:n].reshape(shape)


def _lookup(table: _Compliance, m2, row, out=None, log=True):
    """Section compliance and its slope from the table.

    ``m2 = |M|^2`` [(N m)^2], shape (..., b) (``log=False``: ``ln |M|^2`` already); ``row`` (b,)
    the parameter set of each entry. Returns ``(Kr, Ki, Dr, Di)``, ``D = dK/dy`` (written into
    ``out``, four arrays of m2's shape, when given). Scratch from :class:`_Work`.
    """
    shape = m2.shape
    y, x = _Work.get("y", shape), _Work.get("x", shape)
    if log:
        with np.errstate(divide="ignore"):
            np.log(m2, out=y)
    else:
        y[...] = m2
    # bucket, its first interval, then the comparisons with the next node
    y0, inv_w, offset = table.per_entry(row)
    np.subtract(y, y0, out=x)
    x *= inv_w
    outside = x.min() < 0.0 or x.max() > table.n_buckets
    if outside:
        flat = x.reshape(-1)
        where = np.flatnonzero((flat < 0.0) | (flat > table.n_buckets))
        side = flat[where] > 0.0
    np.clip(x, 0.0, table.n_buckets - 1, out=x)
    j = _Work.get("j", shape, np.intp)
    np.copyto(j, x, casting="unsafe")
    j += offset
    np.take(table.first, j, out=j)
    for _ in range(table.steps):
        np.take(table.upper, j, out=x)
        j += y >= x
    cf = _Work.get("cf", (9,) + shape)
    np.take(table.coef, j, axis=1, out=cf)  # one contiguous array per coefficient
    v = cf[8]
    np.subtract(y, v, out=v)
    out = tuple(np.empty(shape) for _ in range(4)) if out is None else out
    tmp = x
    for c0, c1, c2, c3, k, d in ((cf[0], cf[1], cf[2], cf[3], out[0], out[2]),
                                 (cf[4], cf[5], cf[6], cf[7], out[1], out[3])):
        # Horner in place: h1 = c3 v + c2, h2 = h1 v + c1, K = h2 v + c0; dK/dy = h2 + v (2 h1 - c2)
        c3 *= v
        c3 += c2
        np.multiply(c3, v, out=tmp)
        c1 += tmp
        np.multiply(c1, v, out=k)
        k += c0
        c3 *= 2.0
        c3 -= c2
        c3 *= v
        np.add(c3, c1, out=d)
    if outside:
        _tails(table, y, row, out, where, side)
    return out


def _tails(table, y, row, out, where, side):
    """Beyond the nodes, in place: ``K = k_ref + (K_end - k_ref) exp(p (y - y_end))``.

    ``y`` (..., b) the sections' ``ln |M|^2``; ``out`` the four (Kr, Ki, Dr, Di) arrays; ``where``
    the flat indices of the sections beyond the nodes, ``side`` True above the last one.
    """
    at = np.unravel_index(where, y.shape)
    r = row[at[-1]]
    side = side.astype(np.intp)
    ref = table.refs[r, side]
    gap = table.ends[r, side] - ref
    rate = table.rates[r, side]
    edge = np.where(side == 1, table.y_end[r], table.y0[r])
    with np.errstate(over="ignore", invalid="ignore"):
        e = gap * np.exp(rate * (y[at] - edge))
    e = np.where(np.isfinite(e), e, 0.0)
    k = ref + e
    d = rate * e
    for dst, src in zip(out, (k.real, k.imag, d.real, d.imag)):
        dst[at] = src


def _widely_solve(x, y, r):
    """Solve ``X d + Y conj(d) = r`` for d (2 complex per entry) by 2x2 complex eliminations.

    ``x, y``: symmetric 2x2 complex matrices as arrays (3, b) of (a00, a01, a11); ``r`` (2, b).
    Conjugating gives ``conj(d) = conj(X)^-1 (conj(r) - conj(Y) d)``, hence
    ``(X - W conj(Y)) d = r - W conj(r)`` with ``W = Y conj(X^-1)``. Returns d, (2, b).
    """
    x00, x01, x11 = x
    y00, y01, y11 = y
    idet = np.conj(1.0 / (x00 * x11 - x01 * x01))
    i00, i01, i11 = np.conj(x11) * idet, -np.conj(x01) * idet, np.conj(x00) * idet  # conj(X^-1)
    w00, w01 = y00 * i00 + y01 * i01, y00 * i01 + y01 * i11
    w10, w11 = y01 * i00 + y11 * i01, y01 * i01 + y11 * i11
    c00, c01, c11 = np.conj(y)
    s00, s01 = x00 - (w00 * c00 + w01 * c01), x01 - (w00 * c01 + w01 * c11)
    s10, s11 = x01 - (w10 * c00 + w11 * c01), x11 - (w10 * c01 + w11 * c11)
    r0, r1 = r
    c0, c1 = np.conj(r0), np.conj(r1)
    v0, v1 = r0 - (w00 * c0 + w01 * c1), r1 - (w10 * c0 + w11 * c1)
    idet = 1.0 / (s00 * s11 - s01 * s10)
    return np.stack([(s11 * v0 - s01 * v1) * idet, (s00 * v1 - s10 * v0) * idet])


@dataclass(frozen=True, eq=False)
class _Arms:
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

    def take(self, idx):
        """The constants of the entries ``idx``."""
        return _Arms(n=self.n[:, idx], nc=self.nc[:, idx], force=tuple(v[idx] for v in self.force),
                     row=self.row[idx], length=self.length[idx])


def _gauss(q: int):
    """Gauss-Legendre on [0, 1]: eta nodes (from the mass node, eta = 1 - s/L) and weights."""
    x, w = np.polynomial.legendre.leggauss(q)
    return 0.5 * (1.0 - x), 0.5 * w


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
    sections : ndarray, shape (sections,)
        Section positions from the clamp, as fractions of the arm's length.
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
class CableModel:
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
    ``EJ_min > 0`` and the laws of :mod:`sbcal.model.hysteresis`): a section's moment then fixes its
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

    law: HysteresisLaw | None = None
    sections: int = DEFAULT_SECTIONS
    table_points: int = 96
    table_decades: float = 3.0
    max_iter: int = 30
    tol: float = 1e-8
    fold_tol: float = 1e-4
    _rule: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if int(self.sections) != self.sections or self.sections < 2:
            raise InputError(f"sections: expected an integer >= 2, got {self.sections!r}")
        if int(self.table_points) != self.table_points or self.table_points < 4:
            raise InputError(f"table_points: expected an integer >= 4, got {self.table_points!r}")
        if not (np.isfinite(self.table_decades) and self.table_decades > 0):
            raise InputError(f"table_decades: expected a finite value > 0, got {self.table_decades!r}")
        eta, w = _gauss(int(self.sections))
        powers = eta[None, :] ** np.arange(4, -1, -1)[:, None]  # rows eta^4 .. eta^0
        object.__setattr__(self, "_rule", (eta, np.ascontiguousarray(powers * w[None, :])))

    @property
    def parameter_names(self) -> tuple:
        """Every parameter name :meth:`state` accepts."""
        law = self.law.parameter_names if self.law is not None else ()
        return _BASE[:2] + law + _BASE[2:] + GEOMETRY

    # --- set-up -------------------------------------------------------------------------------

    def _table(self, p, n_sets) -> _Compliance:
        lin = np.broadcast_to(p["EJ_min"] * (1 + 1j * p["beta_material"]), (n_sets,)).astype(complex)
        if self.law is None:
            return _linear_compliance(lin)
        lp = {k: np.broadcast_to(p[k], (n_sets,))[:, None] for k in self.law.parameter_names}
        return _compliance_table(self.law, lp, lin, int(self.table_points), float(self.table_decades))

    @staticmethod
    def _arms(p, n_sets, omega, x0) -> _Arms:
        """The per-entry constants (see :class:`_Arms`) from the damper's consistent mass matrices."""
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
        return _Arms(n=nn, nc=nc, force=(fa, fb, fc), row=row, length=L)

    # --- Newton on the node loads ---------------------------------------------------------------

    def _sums(self, table, arms: _Arms, p0, p1):
        """Section moments of K, dK/dy and (dK/dy) / |M|^2 against the weights ``w eta^k``.

        Returns (sk, sd, se): complex arrays of shape (3, b), (3, b), (5, b), row k holding the
        weight ``w eta^(2-k)`` (sk, sd) or ``w eta^(4-k)`` (se); and the sections' (Kr, Ki, |M|^-2),
        each (Q, b). All are :class:`_Work` buffers, valid until the next call.
        """
        eta, wp = self._rule
        q, b = eta.size, p0.size
        # |M|^2 along the arm, a quadratic in eta: |p0|^2 eta^2 + 2 Re(p0 conj p1) eta + |p1|^2
        m2 = _Work.get("m2", (q, b))
        np.multiply.outer(eta, p0.real**2 + p0.imag**2, out=m2)
        m2 += 2.0 * (p0.real * p1.real + p0.imag * p1.imag)
        m2 *= eta[:, None]
        m2 += p1.real**2 + p1.imag**2
        kd = _Work.get("kd", (q, 4, b))  # Kr, Ki, Dr, Di: one block for one matrix product
        _lookup(table, m2, arms.row, (kd[:, 0], kd[:, 1], kd[:, 2], kd[:, 3]))
        np.maximum(m2, _TINY, out=m2)
        np.reciprocal(m2, out=m2)
        e = _Work.get("e", (q, 2, b))
        np.multiply(kd[:, 2], m2, out=e[:, 0])
        np.multiply(kd[:, 3], m2, out=e[:, 1])
        s4 = np.matmul(wp[2:], kd.reshape(q, 4 * b), out=_Work.get("s4", (3, 4 * b))).reshape(3, 4, b)
        s2 = np.matmul(wp, e.reshape(q, 2 * b), out=_Work.get("s2", (5, 2 * b))).reshape(5, 2, b)
        out = []
        for name, src, i in (("sk", s4, 0), ("sd", s4, 2), ("se", s2, 0)):
            z = _Work.get(name, (src.shape[0], b), complex)
            z.real, z.imag = src[:, i], src[:, i + 1]
            out.append(z)
        return (*out, (kd[:, 0], kd[:, 1], m2))

    def _residual(self, table, arms, p):
        """Residual ``R(p) = S(p) + N c - N p`` (2, b), the Newton matrices X, Y (``dR = -(X dp +
        Y conj(dp))``, symmetric, (3, b) each) and the sections' (Kr, Ki, |M|^-2)."""
        p0, p1 = p
        sk, sd, se, sec = self._sums(table, arms, p0, p1)
        # S(p) = SK p with SK = (sk[eta^2], sk[eta], sk[1]) symmetric, so R = N c - (N - SK) p
        x = np.subtract(arms.n, sk, out=sk)
        r = _Work.get("r", (2, p0.size), complex)
        np.multiply(x[0], p0, out=r[0])
        r[0] += x[1] * p1
        np.multiply(x[1], p0, out=r[1])
        r[1] += x[2] * p1
        np.subtract(arms.nc, r, out=r)
        # dS = A dp + B conj(dp): A = sum w l l^T (K + dK/dy), B = sum w l l^T (M^2/|M|^2) dK/dy
        x -= sd
        y = np.multiply(p0 * p0, se[:3], out=sd)
        y += (2.0 * p0 * p1) * se[1:4]
        y += (p1 * p1) * se[2:]
        np.negative(y, out=y)
        return r, x, y, sec

    @staticmethod
    def _uniform_start(arms: _Arms, k):
        """The loads of a cable with one compliance ``k`` (b,) along each arm (exact, linear)."""
        n00, n01, n11 = arms.n
        x00, x01, x11 = n00 - k / 3.0, n01 - k / 2.0, n11 - k
        c0, c1 = arms.nc
        idet = 1.0 / (x00 * x11 - x01 * x01)
        return np.stack([(x11 * c0 - x01 * c1) * idet, (x00 * c1 - x01 * c0) * idet])

    def _start(self, table, arms: _Arms):
        """Start of Newton: the cable with one compliance along each arm, at the arm's rms moment.

        A relaxed fixed point in ``z = ln(mean |M|^2)`` from the fully slipped cable:
        ``z <- (1 - r) z + r ln(mean |M(K(z))|^2)``; a few steps put the loads on the right scale
        (they may be 10x the slipped cable's near a resonance of the partly stuck one). With one
        compliance K the loads are ``(a, b) / det`` with ``a, b, det`` polynomials in K (below).
        """
        n00, n01, n11 = arms.n
        c0, c1 = arms.nc
        # (N - K U) p = N c, U = [[1/3, 1/2], [1/2, 1]]: det = d0 - d1 K + K^2 / 12,
        # p0 det = e0 - e1 K, p1 det = f0 - f1 K
        d0, d1 = n00 * n11 - n01 * n01, n00 + n11 / 3.0 - n01
        e0, e1 = n11 * c0 - n01 * c1, c0 - c1 / 2.0
        f0, f1 = n00 * c1 - n01 * c0, c1 / 3.0 - c0 / 2.0
        k = table.refs[arms.row, 1]
        z = None
        for it in range(_START_STEPS + 1):
            a, b = e0 - e1 * k, f0 - f1 * k
            if it == _START_STEPS:
                break
            det = d0 + k * (k / 12.0 - d1)
            # mean of |p0 eta + p1|^2 over eta in [0, 1]
            m2 = ((a.real**2 + a.imag**2) / 3.0 + (a.real * b.real + a.imag * b.imag) + b.real**2 + b.imag**2)
            znew = np.log(np.maximum(m2, _TINY) / np.maximum(det.real**2 + det.imag**2, _TINY))
            z = znew if z is None else z + _START_RELAX * (znew - z)
            kr, ki, _, _ = _lookup(table, z[None, :], arms.row, log=False)
            k = kr[0] + 1j * ki[0]
        det = d0 + k * (k / 12.0 - d1)
        return np.stack([a, b]) / det

    def _newton(self, table, arms: _Arms, p):
        """Damped Newton from ``p`` (2, b) for every entry; converged entries leave the batch.

        A step is at most half of ``|p|`` (far from the solution the widely linear model is poor),
        and an entry whose residual grew halves its later steps until it falls again. An entry
        leaves once the error left after its step, estimated from the quadratic convergence of its
        last two full steps (``s_k^3 / s_k-1^2``, relative to ``|p|``), is below ``tol``: the step is
        taken, its residual not evaluated. Returns (p (2, b), error estimate, iterations per entry).
        """
        b = p.shape[1]
        p = p.astype(complex)
        error = np.full(b, np.inf)
        its = np.zeros(b, dtype=int)
        # the active entries, compacted: global index, loads, step factor, merit, last full step
        idx, pa = np.arange(b), p.copy()
        damping, merit, last = np.ones(b), np.full(b, np.inf), np.full(b, np.inf)
        sub = arms
        for it in range(self.max_iter):
            r, x, y, _ = self._residual(table, sub, pa)
            d = _widely_solve(x, y, r)
            size = np.sqrt((d.real**2 + d.imag**2).sum(axis=0)
                           / np.maximum((pa.real**2 + pa.imag**2).sum(axis=0), _TINY))
            f = (r.real**2 + r.imag**2).sum(axis=0)
            damping = np.where(f > merit, 0.5 * damping, np.minimum(1.0, 2.0 * damping))
            merit = f
            ok = np.isfinite(size)
            lam = np.where(ok, np.minimum(damping, _STEP_CAP / np.maximum(size, _TINY)), 0.0)
            d *= lam
            d[:, ~ok] = 0.0
            pa += d
            # error left after this step: quadratic convergence from the last full step, else the step
            full = lam == 1.0
            quadratic = full & (size < 1e-3) & (size < last)
            err = np.where(quadratic, size * (size / np.where(quadratic, last, 1.0)) ** 2, size)
            err[~full] = np.inf
            last = np.where(full, size, np.inf)
            done = err < self.tol if it < self.max_iter - 1 else np.ones(err.shape, dtype=bool)
            if not done.any():
                continue
            gone = idx[done]
            p[:, gone], error[gone], its[gone] = pa[:, done], err[done], it + 1
            keep = ~done
            if not keep.any():
                break
            idx, pa, damping, merit, last = idx[keep], pa[:, keep], damping[keep], merit[keep], last[keep]
            sub = arms.take(idx)
        return p, error, its

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
                          **params) -> np.ndarray:
        """``f_uu`` [N/m], complex (n_sets, n_freq): :meth:`state` ``.f_uu`` (NaN outside the law's domain).

        The sampler's path: the same numbers as :meth:`state`, without the section state.
        """
        return self._run(damper, freq_hz, amplitude_mm_pp, segments, continuation, params, full=False)

    def _run(self, damper, freq_hz, amplitude_mm_pp, segments, continuation, params, full):
        law_names = self.law.parameter_names if self.law is not None else ()
        p, n_sets = _resolve(self.parameter_names, _BASE[:2] + law_names, damper, params)
        f, amp, seg = _grid(freq_hz, amplitude_mm_pp, segments, per_set=True)
        if amp.ndim == 2 and amp.shape[0] > 1:  # one amplitude per (set, line): the rows are sets
            if n_sets not in (1, amp.shape[0]):
                raise InputError(f"amplitude_mm_pp: {amp.shape[0]} rows (sets) where the parameters have {n_sets}")
            n_sets = amp.shape[0]
        valid = np.isfinite(p["EJ_min"]) & (p["EJ_min"] > 0) & np.isfinite(p["beta_material"]) & (p["beta_material"] >= 0)
        if self.law is not None:
            valid = valid & self.law.valid(**{k: p[k] for k in law_names})
        valid = np.broadcast_to(valid, (n_sets,))
        if valid.all():
            table = self._table(p, n_sets)
            valid = table.monotone
        if not valid.all():
            return self._subset(damper, f, amp, seg, continuation, p, n_sets, valid, full)
        omega = 2 * np.pi * f
        x0 = amp / 2 * 1e-3
        arms = self._arms(p, n_sets, omega, x0)
        sol = self._newton(table, arms, self._start(table, arms))
        iterations = int(sol[2].max())
        fold = np.zeros((n_sets, f.size), dtype=bool)
        if continuation and f.size > 1:
            sol, fold, extra = self._continuation(table, arms, sol, seg, n_sets, f.size)
            iterations += extra
        if not full:
            return self._f_uu(arms, sol[0], p, n_sets, omega, x0)
        return self._assemble(table, arms, sol, fold, iterations, p, n_sets, omega, x0)

    @staticmethod
    def _f_uu(arms, p_load, p, n_sets, omega, x0):
        """``f_uu`` (n_sets, n_freq) from the loads: both arms' vertical clamp forces + the clamp's inertia."""
        fa, fb, fc = arms.force
        force = (fa * p_load[0] + fb * p_load[1] + fc).reshape(n_sets, omega.size, 2).sum(axis=-1)
        r = p["rocking_rad_per_m"][:, None]
        body = -(omega**2)[None, :] * p["mc"][:, None] * (1 + p["ac"][:, None] * r)
        return np.broadcast_to(force / x0.reshape(-1, omega.size) + body, (n_sets, omega.size)).copy()

    def _assemble(self, table, arms, sol, fold, iterations, p, n_sets, omega, x0) -> CableState:
        (p0, p1), step, _ = sol
        _, _, _, (kr, ki, inv_m2) = self._sums(table, arms, p0, p1)  # the sections at the loads returned
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
        eta = np.clip(-(p0 * np.conj(p1)).real / np.maximum(a2, _TINY), 0.0, 1.0)
        m2 = np.abs(np.stack([p1, p0 + p1, p0 * eta + p1])) ** 2
        kr, ki, _, _ = _lookup(table, m2, arms.row)
        ends = per_line(np.sqrt(m2) * np.hypot(kr, ki)).reshape(n_sets, nf, -1)
        step = step.reshape(n_sets, nf, 2).max(axis=-1)
        return CableState(f_uu=f_uu, load=load, curvature=curvature, rigidity=per_line(1.0 / ksec),
                          curvature_range=np.stack([ends.min(axis=-1), ends.max(axis=-1)], axis=-1),
                          converged=step < self.tol, fold=fold, residual=step, iterations=iterations,
                          sections=1.0 - self._rule[0])

    def _subset(self, damper, f, amp, seg, continuation, p, n_sets, valid, full):
        """Solve the valid sets only; the others get NaN (outside the law's domain)."""
        keep = np.flatnonzero(valid)
        nf, q = f.size, int(self.sections)
        sub = {k: (v[keep] if v.size == n_sets and n_sets > 1 else v) for k, v in p.items()}
        if amp.ndim == 2 and amp.shape[0] == n_sets > 1:
            amp = amp[keep]
        if not full:
            out = np.full((n_sets, nf), np.nan + 0j)
            if keep.size:
                out[keep] = self._run(damper, f, amp, seg, continuation, sub, full=False)
            return out
        out = dict(f_uu=np.full((n_sets, nf), np.nan + 0j), load=np.full((n_sets, nf, 2, 2), np.nan + 0j),
                   curvature=np.full((n_sets, nf, 2, q), np.nan), rigidity=np.full((n_sets, nf, 2, q), np.nan + 0j),
                   curvature_range=np.full((n_sets, nf, 2), np.nan), converged=np.zeros((n_sets, nf), dtype=bool),
                   fold=np.zeros((n_sets, nf), dtype=bool), residual=np.full((n_sets, nf), np.inf))
        iterations = 0
        if keep.size:
            st = self._run(damper, f, amp, seg, continuation, sub, full=True)
            for k in out:
                out[k][keep] = getattr(st, k)
            iterations = st.iterations
        return CableState(**out, iterations=iterations, sections=1.0 - self._rule[0])

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


# --- the element model (the virtual bench) ---------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ElementCableState:
    """The distributed cable's steady state per parameter set and frequency line.

    Attributes
    ----------
    f_uu : ndarray of complex, shape (n_sets, n_freq)
        Dynamic stiffness [N/m] (with base rocking: the measured ``f_uu + r f_uphi``).
    curvature : ndarray, shape (n_sets, n_freq, 2, N)
        Element curvature amplitudes [1/m] (rms over each element), arm 1 (mass 1 - clamp) then
        arm 2 (clamp - mass 2), elements numbered from the clamp outward.
    rigidity : ndarray of complex, shape (n_sets, n_freq, 2, N)
        Element secant rigidity ``EJ*_e`` [N m^2].
    converged : ndarray of bool, shape (n_sets, n_freq)
        The fixed point met the tolerance on both arms.
    fold : ndarray of bool, shape (n_sets, n_freq)
        Two steady states were found at this line (the sweep's branch is the one returned).
    residual : ndarray, shape (n_sets, n_freq)
        ``max |ln T(chi) - ln chi|`` over arms and elements at the returned state.
    iterations : int
        Newton iterations, summed over the passes.
    mesh : ndarray, shape (N + 1,)
        Node positions along each arm from the clamp, as fractions of the arm's length.
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

    def take(self, idx):
        """The constants of the batch entries ``idx``."""
        return _Batch(k12=self.k12[:, idx], k6=self.k6[:, idx], k4=self.k4[:, idx], k2=self.k2[:, idx],
                      inv_h=self.inv_h[:, idx], h=self.h[:, idx], wm=tuple(w[:, idx] for w in self.wm),
                      tip=tuple(t[idx] for t in self.tip), x0=self.x0[idx], t0=self.t0[idx],
                      linear=self.linear[idx], law_params={k: v[idx] for k, v in self.law_params.items()})


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
class ElementCableModel:
    """The distributed strand-slip cable: ``f_uu`` and its steady state for parameter sets.

    Parameters (keyword arguments of :meth:`state`; each a scalar or shape (n_sets,)):

    ===================  ======  =============================================================
    name                 unit    meaning
    ===================  ======  =============================================================
    EJ_min               N m^2   rigidity of the fully slipped strand
    beta_material        1       material loss factor of the strand (on ``EJ_min``)
    the law's            ...     :attr:`law` ``.parameters`` (e.g. ``delta_EJ``, ``chi_dahl``)
    rocking_rad_per_m    rad/m   base rocking ``phic = r xc`` (default 0)
    m1 .. mu             SI      geometry overrides as :mod:`sbcal.model.fem` accepts them
    ===================  ======  =============================================================

    Attributes
    ----------
    law : HysteresisLaw or None
        The slip part's law; None is the linear cable ``EJ_min (1 + i beta_material)``.
    n_elements : int
        Hermite elements per arm.
    grading : float
        Length of the element at the end mass over that at the clamp (1: uniform; > 1: finer at
        the clamp, where the curvature peaks), geometric progression.
    max_iter : int
        Newton iteration budget per pass (a fixed budget: the model is a deterministic function).
    tol : float
        Convergence tolerance on ``max |ln T(chi) - ln chi|`` per arm.
    fold_tol : float
        Two solutions of one line are distinct when their ``ln chi`` differ by more than this.
    """

    law: HysteresisLaw | None = None
    n_elements: int = DEFAULT_N_ELEMENTS
    grading: float = 1.0
    max_iter: int = 20
    tol: float = 1e-9
    fold_tol: float = 1e-4
    _mesh: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if int(self.n_elements) != self.n_elements or self.n_elements < 1:
            raise InputError(f"n_elements: expected an integer >= 1, got {self.n_elements!r}")
        if not (np.isfinite(self.grading) and self.grading > 0):
            raise InputError(f"grading: expected a finite value > 0, got {self.grading!r}")
        n = int(self.n_elements)
        ratio = self.grading ** (1.0 / (n - 1)) if n > 1 else 1.0
        lengths = ratio ** np.arange(n)
        object.__setattr__(self, "_mesh", np.concatenate([[0.0], np.cumsum(lengths) / lengths.sum()]))

    @property
    def parameter_names(self) -> tuple:
        """Every parameter name :meth:`state` accepts."""
        law = self.law.parameter_names if self.law is not None else ()
        return _BASE[:2] + law + _BASE[2:] + GEOMETRY

    # --- set-up -------------------------------------------------------------------------------

    def _batch(self, p: dict, n_sets: int, omega, x0) -> _Batch:
        nf = omega.size

        def full(per_set_arm):
            """(n_sets or 1, 2) -> (S, F, 2) broadcast, flattened to (B,)."""
            return np.broadcast_to(per_set_arm[:, None, :], (n_sets, nf, 2)).reshape(-1)

        def arms(a1, a2):
            a1, a2 = np.broadcast_arrays(p[a1], p[a2]) if isinstance(a1, str) else np.broadcast_arrays(a1, a2)
            return np.stack([a1, a2], axis=-1)  # (n_sets or 1, 2)

        length = arms("L1", "L2")
        frac = np.diff(self._mesh)
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
        law_params = {}
        if self.law is not None:
            law_params = {k: full(arms(p[k], p[k]))[:, None] for k in self.law.parameter_names}
        inv_h = 1.0 / h
        return _Batch(k12=12 * inv_h**3, k6=6 * inv_h**2, k4=4 * inv_h, k2=2 * inv_h, inv_h=inv_h, h=h, wm=wm,
                      tip=tip, x0=x0b, t0=r * x0b, linear=linear, law_params=law_params)

    # --- the fixed point ----------------------------------------------------------------------

    def _sigma(self, c: _Batch, z):
        """Element rigidities (N, B) at curvature amplitudes z (N, B)."""
        if self.law is None:
            return np.broadcast_to(c.linear, z.shape).astype(complex)
        slip = self.law.slip_rigidity(z.T, **c.law_params).T
        return c.linear + slip

    def _evaluate(self, c: _Batch, z, jacobian: bool):
        """Map T(z) (N, B), the arm force (B,), and optionally dG/du of G(u) = ln T(e^u) - u (B, N, N)."""
        sigma = self._sigma(c, z)
        arms = _ElementArms(c, sigma)
        x = arms.response()
        ends = [_curvature_ends(c, x, e) for e in range(self.n_elements)]
        t = np.stack([_rms(c0, c1) for c0, c1 in ends])
        if not jacobian:
            return t, arms.clamp_force(), sigma, None
        n, b = self.n_elements, z.shape[1]
        # law slope d sigma / d ln z, forward difference (the laws are closed forms or splines)
        if self.law is None:
            slope = np.zeros_like(sigma)
        else:
            slope = (self._sigma(c, z * np.exp(_FD_LOG_STEP)) - sigma) / _FD_LOG_STEP
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
            te = np.maximum(t[e], _TINY)[:, None]
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
            u = np.log(np.maximum(z[:, active], _TINY))
            g = np.log(np.maximum(t, _TINY)) - u  # (N, b_active)
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
            step *= np.minimum(1.0, _MAX_LOG_STEP / np.maximum(np.abs(step).max(axis=0), _TINY))
            # converged entries keep their z (their force and sigma were stored above)
            active = active[keep]
            z[:, active] = np.exp(u[:, keep] + step)
        return z, force, sigma, resid, it

    # --- public -------------------------------------------------------------------------------

    def state(self, damper: Damper, freq_hz, amplitude_mm_pp, *, segments=None, linear_rigidity=None,
              **params) -> ElementCableState:
        """Steady state of the cable at every line, following a stepped-sine sweep up each test.

        Parameters
        ----------
        damper : Damper
            Nominal geometry (every geometry parameter not given).
        freq_hz : array_like, shape (n_freq,)
            Frequency lines [Hz], increasing within each test.
        amplitude_mm_pp : float or array_like, shape (n_freq,)
            Commanded base amplitude per line [mm peak-to-peak].
        segments : array_like of int, shape (n_freq,), optional
            Test index per line (the sweep restarts at each test's first line); default: a new test
            wherever the frequency does not increase (:func:`segments_from_frequencies`).
        linear_rigidity : array_like of complex, shape (n_sets or 1, n_freq or 1, 2), optional
            ``EJ_min (1 + i beta_material)`` per set, line and arm [N m^2], replacing ``EJ_min`` and
            ``beta_material`` (the virtual bench's asymmetric, viscous or frequency-dependent cable).
        **params : float or array_like, shape (n_sets,)
            See the class docstring.

        Returns
        -------
        ElementCableState
        """
        if linear_rigidity is not None:
            params = dict(params, EJ_min=1.0, beta_material=0.0)  # placeholders, replaced below
        law_names = self.law.parameter_names if self.law is not None else ()
        p, n_sets = _resolve(self.parameter_names, _BASE[:2] + law_names, damper, params)
        valid = np.broadcast_to((p["EJ_min"] > 0) & (p["beta_material"] >= 0), (n_sets,))
        if self.law is not None:
            valid = valid & np.broadcast_to(self.law.valid(**{k: p[k] for k in self.law.parameter_names}), (n_sets,))
        if linear_rigidity is not None:
            lin = np.asarray(linear_rigidity, dtype=complex)
            if lin.ndim != 3 or lin.shape[2] != 2:
                raise InputError(f"linear_rigidity: expected shape (n_sets, n_freq, 2), got {lin.shape}")
            n_sets = max(n_sets, lin.shape[0])
        if not valid.all():
            if linear_rigidity is not None:
                raise InputError("linear_rigidity: the law's parameters are outside its domain")
            return self._with_invalid(damper, freq_hz, amplitude_mm_pp, segments, p, n_sets, valid)
        f, amp, seg = _grid(freq_hz, amplitude_mm_pp, segments)
        omega = 2 * np.pi * f
        x0 = amp / 2 * 1e-3
        c = self._batch(p, n_sets, omega, x0)
        if linear_rigidity is not None:
            c = replace(c, linear=np.broadcast_to(lin, (n_sets, f.size, 2)).reshape(-1).copy())
        n, nf = int(self.n_elements), f.size

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

        fx = per_line(force).sum(axis=-1)
        r = p["rocking_rad_per_m"][:, None]
        body = -(omega**2)[None, :] * p["mc"][:, None] * (1 + p["ac"][:, None] * r)
        f_uu = fx / x0[None, :] + body
        curv = np.moveaxis(per_line(z, (n,)), 0, -1)
        rig = np.moveaxis(per_line(sigma, (n,)), 0, -1)
        res = per_line(resid).max(axis=-1)
        return ElementCableState(f_uu=np.broadcast_to(f_uu, (n_sets, nf)).copy(), curvature=curv, rigidity=rig,
                          converged=res < self.tol, fold=fold, residual=res, iterations=int(iterations),
                          mesh=self._mesh.copy())

    def _with_invalid(self, damper, freq_hz, amplitude_mm_pp, segments, p, n_sets, valid):
        """Solve the valid sets only; the others get NaN (outside the law's domain)."""
        keep = np.flatnonzero(valid)
        nf = np.atleast_1d(np.asarray(freq_hz)).size
        shape = (n_sets, nf, 2, int(self.n_elements))
        out = dict(f_uu=np.full((n_sets, nf), np.nan + 0j), curvature=np.full(shape, np.nan),
                   rigidity=np.full(shape, np.nan + 0j), converged=np.zeros((n_sets, nf), dtype=bool),
                   fold=np.zeros((n_sets, nf), dtype=bool), residual=np.full((n_sets, nf), np.inf))
        iterations = 0
        if keep.size:
            sub = {k: (v[keep] if v.size == n_sets and n_sets > 1 else v) for k, v in p.items()}
            st = self.state(damper, freq_hz, amplitude_mm_pp, segments=segments, **sub)
            for k in out:
                out[k][keep] = getattr(st, k)
            iterations = st.iterations
        return ElementCableState(**out, iterations=iterations, mesh=self._mesh.copy())

    def _linear_curvatures(self, c, sigma):
        arms = _ElementArms(c, sigma)
        x = arms.response()
        return np.stack([_rms(*_curvature_ends(c, x, e)) for e in range(self.n_elements)])

    def _continuation(self, c, z, force, sigma, resid, seg, n_sets, nf):
        """Check every line against a restart from its predecessor; re-solve the folds in sweep order."""
        n = int(self.n_elements)
        shape = (n, n_sets, nf, 2)
        zl = z.reshape(shape)
        first = np.concatenate([[True], seg[1:] != seg[:-1]])
        # 2. one vectorised pass: every line restarted from its predecessor's solution
        z_prev = np.roll(zl, 1, axis=2)
        z_prev[:, :, first] = zl[:, :, first]
        zc, fc, sc, rc, it = self._newton(c, z_prev.reshape(n, -1), self.max_iter)
        iterations = it

        def differs(za, zb, ra, rb):
            d = np.abs(np.log(np.maximum(za, _TINY)) - np.log(np.maximum(zb, _TINY))).max(axis=0)
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
