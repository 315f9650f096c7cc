"""The fast cable model's compiled kernel (numba): per (set, line, arm) entry, the one-compliance
start and the damped Newton on the node loads, each a fused loop over the arm's sections.

The arithmetic is :class:`sbcal.model.cable.CableModel`'s (``docs/cable.md``, "Newton"): a section's
compliance from the per-set table (:class:`sbcal.model.cable_sections.Compliance`: bucket, first
interval, comparisons, cubic Hermite; exponential tails beyond the nodes), the section moments of
``K``, ``dK/dy`` and ``(dK/dy) / |M|^2``, the widely linear 2x2 solve and the step control. Every
entry is independent, so one entry runs its whole Newton in registers: no pass over memory per
operation (the numpy formulation made ~45 passes over ~76 000 sections per evaluation). The gain is ~2x
(``benchmarks/cable.py``): the work is arithmetic, not memory traffic (``docs/cable.md``, "Speed").
The numpy formulation is kept as the tests' reference (``tests/cable_reference.py``); both agree to
rounding (1e-10 on ``f_uu``).

Compiled on first use and cached on disk (numba's ``cache=True``: ``__pycache__`` beside this file,
or numba's user cache directory where that is not writable), so a machine pays the compile once.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


__all__ = []

_TINY = 1e-300
_STEP_CAP = 0.5  # a Newton step is at most this fraction of |P|
_START_STEPS = 6  # relaxed steps of the one-compliance start
_START_RELAX = 0.3


@njit(cache=True, error_model="numpy", inline="always")
def _abs2(a, b):
    """``|a|^2 + |b|^2`` of two complex numbers (no ``**``: numba's integer power is a loop)."""
    return a.real * a.real + a.imag * a.imag + b.real * b.real + b.imag * b.imag


@njit(cache=True, error_model="numpy", inline="always")
def _inv(z):
    """``1 / z`` as ``conj(z) / |z|^2`` (numba's complex division branches: the Newton's algebra took 15 % longer
    with it, measured)."""
    d = 1.0 / (z.real * z.real + z.imag * z.imag)
    return complex(z.real * d, -z.imag * d)


@njit(cache=True, error_model="numpy", inline="always")
def _k_at(y, r, coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates):
    """``(Kr, Ki, Dr, Di)``: the compliance and its slope in ``y = ln |M|^2`` of table row ``r``.

    """
    x = (y - y0[r]) * inv_w[r]
    xc = x if x > 0.0 else 0.0  # (a NaN moment: 0, then the tail below gives NaN)
    if xc > nb - 1:
        xc = nb - 1.0
    j = first[int(xc) + r * nb]
    for _ in range(steps):
        if y >= upper[j]:
            j += 1
    v = y - coef[8, j]
    h1 = coef[3, j] * v + coef[2, j]
    h2 = h1 * v + coef[1, j]
    kr = h2 * v + coef[0, j]
    dr = h2 + v * (2.0 * h1 - coef[2, j])
    h1 = coef[7, j] * v + coef[6, j]
    h2 = h1 * v + coef[5, j]
    ki = h2 * v + coef[4, j]
    di = h2 + v * (2.0 * h1 - coef[6, j])
    # Beyond the nodes: K = ref + (K_end - ref) exp(rate (y - edge)). A loop of 0 or 1 trips, not an
    # `if`: LLVM speculates exp/cos/sin out of an `if` into every lookup (8x slower, measured).
    for _ in range(0 if (x >= 0.0 and x <= nb) else 1):
        side = 1 if x > 0.0 else 0
        ref, rate = refs[r, side], rates[r, side]
        gr, gi = ends[r, side].real - ref.real, ends[r, side].imag - ref.imag
        t = y - (y_end[r] if side == 1 else y0[r])
        mag = math.exp(rate.real * t)
        cr, ci = mag * math.cos(rate.imag * t), mag * math.sin(rate.imag * t)
        er, ei = gr * cr - gi * ci, gr * ci + gi * cr
        if not (math.isfinite(er) and math.isfinite(ei)):  # the limit itself
            er, ei = 0.0, 0.0
        kr, ki = ref.real + er, ref.imag + ei
        dr, di = rate.real * er - rate.imag * ei, rate.real * ei + rate.imag * er
        if y != y:
            kr, ki, dr, di = y, y, y, y
    return kr, ki, dr, di


@njit(cache=True, error_model="numpy")
def lookup(y, rows, coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates):
    """The compliance table at ``y = ln |M|^2`` (n,) of table rows ``rows`` (n,): (4, n) Kr, Ki, Dr, Di."""
    n = y.size
    out = np.empty((4, n))
    for i in range(n):
        kr, ki, dr, di = _k_at(y[i], rows[i], coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates)
        out[0, i], out[1, i], out[2, i], out[3, i] = kr, ki, dr, di
    return out


@njit(cache=True, error_model="numpy")
def start(n, nc, rows, coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates):
    """The one-compliance start (``CableModel._start``): loads (2, b) complex.

    ``n`` (3, b) and ``nc`` (2, b) the arms' ``N`` and ``N c``; ``rows`` (b,) each entry's table row.
    Steps outside, entries inside: one entry's steps are a chain of dependent operations (log,
    lookup, division), the entries are independent, so the processor overlaps them (1.8x faster than one
    entry's steps in a row, measured).
    """
    b = rows.size
    z = np.zeros(b)
    k = np.empty(b, dtype=np.complex128)
    for e in range(b):
        k[e] = refs[rows[e], 1]
    out = np.empty((2, b), dtype=np.complex128)
    for it in range(_START_STEPS + 1):
        for e in range(b):
            n00, n01, n11 = n[0, e], n[1, e], n[2, e]
            c0, c1 = nc[0, e], nc[1, e]
            # (N - K U) p = N c, U = [[1/3, 1/2], [1/2, 1]]: det = d0 - d1 K + K^2 / 12,
            # p0 det = e0 - e1 K, p1 det = f0 - f1 K
            ke = k[e]
            a = (n11 * c0 - n01 * c1) - (c0 - c1 / 2.0) * ke
            bb = (n00 * c1 - n01 * c0) - (c1 / 3.0 - c0 / 2.0) * ke
            det = (n00 * n11 - n01 * n01) + ke * (ke / 12.0 - (n00 + n11 / 3.0 - n01))
            if it == _START_STEPS:
                out[0, e], out[1, e] = a / det, bb / det
                continue
            # mean of |p0 eta + p1|^2 over eta in [0, 1]
            m2 = (a.real * a.real + a.imag * a.imag) / 3.0 + (a.real * bb.real + a.imag * bb.imag) \
                + bb.real * bb.real + bb.imag * bb.imag
            dd = det.real * det.real + det.imag * det.imag
            znew = math.log(max(m2, _TINY) / max(dd, _TINY))
            ze = znew if it == 0 else z[e] + _START_RELAX * (znew - z[e])
            z[e] = ze
            kr, ki, _, _ = _k_at(ze, rows[e], coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates)
            k[e] = complex(kr, ki)
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _moments(p0, p1, row, eta, w, zone, zoned, coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates,
             sec, mom):
    """The section moments of an entry of table row ``row`` at loads ``(p0, p1)`` into ``mom`` (22,): Re and
    Im of ``sk`` (3: weights w eta^2, eta, 1), ``sd`` (3, the same) and ``se`` (5: w eta^4 .. w eta^0 on
    ``(dK/dy) / |M|^2``). ``sec`` (6, Q) scratch: every section's lookup first (independent: they
    overlap), then the moments, the weights ``w eta^k`` made on the way."""
    a2 = p0.real * p0.real + p0.imag * p0.imag
    c = 2.0 * (p0.real * p1.real + p0.imag * p1.imag)
    b2 = p1.real * p1.real + p1.imag * p1.imag
    q_n = eta.shape[1]
    sr = row if zoned else 0
    n_sets = eta.shape[0]
    for q in range(q_n):
        et = eta[sr, q]
        m2 = (et * a2 + c) * et + b2  # |M|^2 = |p0 eta + p1|^2
        kr, ki, dr, di = _k_at(math.log(m2) if m2 > 0.0 else -np.inf, zone[q] * n_sets + row if zoned else row,
                               coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates)
        inv = 1.0 / max(m2, _TINY)
        sec[0, q], sec[1, q], sec[2, q], sec[3, q], sec[4, q], sec[5, q] = kr, ki, dr, di, dr * inv, di * inv
    for k in range(22):
        mom[k] = 0.0
    for q in range(q_n):
        et = eta[sr, q]
        w0 = w[sr, q]
        w1 = w0 * et
        w2 = w1 * et
        w3 = w2 * et
        w4 = w3 * et
        kr, ki, dr, di, er, ei = sec[0, q], sec[1, q], sec[2, q], sec[3, q], sec[4, q], sec[5, q]
        mom[0] += w2 * kr
        mom[1] += w2 * ki
        mom[2] += w1 * kr
        mom[3] += w1 * ki
        mom[4] += w0 * kr
        mom[5] += w0 * ki
        mom[6] += w2 * dr
        mom[7] += w2 * di
        mom[8] += w1 * dr
        mom[9] += w1 * di
        mom[10] += w0 * dr
        mom[11] += w0 * di
        mom[12] += w4 * er
        mom[13] += w4 * ei
        mom[14] += w3 * er
        mom[15] += w3 * ei
        mom[16] += w2 * er
        mom[17] += w2 * ei
        mom[18] += w1 * er
        mom[19] += w1 * ei
        mom[20] += w0 * er
        mom[21] += w0 * ei


@njit(cache=True, error_model="numpy")
def newton(p_start, n, nc, rows, eta, w, zone, zoned, tol, max_iter, coef, upper, first, y0, y_end, inv_w, nb,
           steps, ends, refs, rates):
    """Damped Newton on the node loads from ``p_start`` (2, b) (``CableModel._newton``).

    ``n`` (3, b) and ``nc`` (2, b) real; ``rows`` (b,) each entry's parameter set; the sections: ``eta``
    (from the mass node) and Gauss weights ``w``, (n_sets, Q) for a zoned law (``zoned``: section q of
    set s is in table row ``zone[q] * n_sets + s``), else (1, Q) for every entry (table row: the set).
    Returns (loads (2, b) complex, error estimate (b,), iterations per entry (b,)).

    Iterations outside, the entries still active inside: one entry's iteration is a chain of
    dependent operations and the entries are independent (the same speed as one entry's iterations in a row,
    measured; the start gains from this order); a converged entry leaves the active list.
    """
    b = rows.size
    p = p_start.copy()
    error = np.full(b, np.inf)
    its = np.zeros(b, dtype=np.int64)
    damping, merit, last = np.ones(b), np.full(b, np.inf), np.full(b, np.inf)
    active = np.arange(b)
    n_active = b
    sec = np.empty((6, eta.shape[1]))
    mom = np.empty(22)
    out = np.empty(6)
    for it in range(max_iter):
        kept = 0
        for i in range(n_active):
            e = active[i]
            p0, p1 = p[0, e], p[1, e]
            _moments(p0, p1, rows[e], eta, w, zone, zoned, coef, upper, first, y0, y_end, inv_w, nb, steps,
                     ends, refs, rates, sec, mom)
            _step(p0, p1, mom, n[0, e], n[1, e], n[2, e], nc[0, e], nc[1, e], out)
            size, f = out[4], out[5]
            damping[e] = 0.5 * damping[e] if f > merit[e] else min(1.0, 2.0 * damping[e])
            merit[e] = f
            lam = 0.0
            if math.isfinite(size):
                lam = min(damping[e], _STEP_CAP / max(size, _TINY))
                p[0, e] = p0 + lam * complex(out[0], out[1])
                p[1, e] = p1 + lam * complex(out[2], out[3])
            # the error left after this step: quadratic convergence from the last full step, else the step
            full = lam == 1.0
            err = size
            if not full:
                err = np.inf
            elif size < 1e-3 and size < last[e]:
                err = size * (size / last[e]) * (size / last[e])
            last[e] = size if full else np.inf
            if err < tol or it == max_iter - 1:
                error[e], its[e] = err, it + 1
            else:
                active[kept] = e
                kept += 1
        n_active = kept
        if n_active == 0:
            break
    return p, error, its


@njit(cache=True, error_model="numpy", inline="always")
def _step(p0, p1, mom, n00, n01, n11, nc0, nc1, out):
    """The Newton step at loads ``(p0, p1)`` from the section moments ``mom`` (:func:`_moments`):
    ``X d + Y conj(d) = r`` solved by 2x2 complex eliminations (``docs/cable.md``, Newton); ``out``
    (6,) = Re d0, Im d0, Re d1, Im d1, ``|d| / |p|``, ``|r|^2``."""
    # R = N c - (N - SK) p; dR = -(X dp + Y conj(dp)), X = N - SK - SD, Y = -(p p^T weighted se)
    x00 = n00 - complex(mom[0], mom[1])
    x01 = n01 - complex(mom[2], mom[3])
    x11 = n11 - complex(mom[4], mom[5])
    r0 = nc0 - (x00 * p0 + x01 * p1)
    r1 = nc1 - (x01 * p0 + x11 * p1)
    x00 -= complex(mom[6], mom[7])
    x01 -= complex(mom[8], mom[9])
    x11 -= complex(mom[10], mom[11])
    se0, se1, se2 = complex(mom[12], mom[13]), complex(mom[14], mom[15]), complex(mom[16], mom[17])
    se3, se4 = complex(mom[18], mom[19]), complex(mom[20], mom[21])
    pp, pq, qq = p0 * p0, 2.0 * p0 * p1, p1 * p1
    y00 = -(pp * se0 + pq * se1 + qq * se2)
    y01 = -(pp * se1 + pq * se2 + qq * se3)
    y11 = -(pp * se2 + pq * se3 + qq * se4)
    # X d + Y conj(d) = r: (X - W conj(Y)) d = r - W conj(r), W = Y conj(X^-1)
    idet = _inv(x00 * x11 - x01 * x01).conjugate()
    i00, i01, i11 = x11.conjugate() * idet, -x01.conjugate() * idet, x00.conjugate() * idet
    w00, w01 = y00 * i00 + y01 * i01, y00 * i01 + y01 * i11
    w10, w11 = y01 * i00 + y11 * i01, y01 * i01 + y11 * i11
    c00, c01, c11 = y00.conjugate(), y01.conjugate(), y11.conjugate()
    s00, s01 = x00 - (w00 * c00 + w01 * c01), x01 - (w00 * c01 + w01 * c11)
    s10, s11 = x01 - (w10 * c00 + w11 * c01), x11 - (w10 * c01 + w11 * c11)
    rc0, rc1 = r0.conjugate(), r1.conjugate()
    v0, v1 = r0 - (w00 * rc0 + w01 * rc1), r1 - (w10 * rc0 + w11 * rc1)
    idet = _inv(s00 * s11 - s01 * s10)
    d0, d1 = (s11 * v0 - s01 * v1) * idet, (s00 * v1 - s10 * v0) * idet
    out[0], out[1], out[2], out[3] = d0.real, d0.imag, d1.real, d1.imag
    out[4] = math.sqrt(_abs2(d0, d1) / max(_abs2(p0, p1), _TINY))
    out[5] = _abs2(r0, r1)


@njit(cache=True, error_model="numpy")
def sections(p, rows, eta, zone, zoned, coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates):
    """The sections at loads ``p`` (2, b) (``eta``, ``zone``, ``zoned`` as :func:`newton`'s): compliance
    ``Kr``, ``Ki`` and ``|M|^-2``, each (Q, b)."""
    b = rows.size
    q_n = eta.shape[1]
    n_sets = eta.shape[0]
    kr_o, ki_o, inv_o = np.empty((q_n, b)), np.empty((q_n, b)), np.empty((q_n, b))
    for e in range(b):
        p0, p1 = p[0, e], p[1, e]
        a2 = p0.real * p0.real + p0.imag * p0.imag
        c = 2.0 * (p0.real * p1.real + p0.imag * p1.imag)
        b2 = p1.real * p1.real + p1.imag * p1.imag
        row = rows[e]
        sr = row if zoned else 0
        for q in range(q_n):
            et = eta[sr, q]
            m2 = (et * a2 + c) * et + b2
            kr, ki, _, _ = _k_at(math.log(m2) if m2 > 0.0 else -np.inf, zone[q] * n_sets + row if zoned else row,
                                 coef, upper, first, y0, y_end, inv_w, nb, steps, ends, refs, rates)
            kr_o[q, e], ki_o[q, e], inv_o[q, e] = kr, ki, 1.0 / max(m2, _TINY)
    return kr_o, ki_o, inv_o


@njit(cache=True, error_model="numpy")
def buckets(y, y0, span, nb):
    """A compliance table's buckets (:func:`sbcal.model.cable_sections._hermite_table`): per set (row of the
    nodes ``y`` (s, n), increasing) the interval holding each of ``nb`` uniform buckets' lower edge (s, nb),
    and the most nodes between two edges (the comparisons a lookup needs). One walk along the nodes per set,
    in the arithmetic of a search over the sets' nodes mapped onto ``[2 r, 2 r + 1]`` (set ``r``), so the
    intervals are those of that search; a row whose nodes do not increase gets some interval (its table
    is not monotone: never used)."""
    s, n = y.shape
    first = np.empty((s, nb), dtype=np.intp)
    steps = 0
    for r in range(s):
        j, prev = 0, 0
        for k in range(nb):
            edge = (y0[r] + span[r] * (k / nb) - y0[r]) / span[r] + 2.0 * r
            while j < n and (y[r, j] - y0[r]) / span[r] + 2.0 * r <= edge:
                j += 1
            first[r, k] = min(max(j - 1, 0), n - 2)
            if k > 0:
                steps = max(steps, j - prev)
            prev = j
        steps = max(steps, n - prev)
    return first, steps
