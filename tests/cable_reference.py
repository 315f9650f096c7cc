"""The fast cable model's numpy formulation: the reference the compiled kernel is tested against.

:class:`NumpyCableModel` is :class:`sbcal.model.cable.CableModel` with its one-compliance start,
Newton and section state done as whole-array numpy passes (the formulation before the compiled
kernel, :mod:`sbcal.model.cable_kernel`): ``tests/test_cable_kernel.py`` holds the two to rounding,
and ``benchmarks/cable.py`` times them side by side.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from sbcal.model.cable import CableModel
from sbcal.model.cable_kernel import _START_RELAX, _START_STEPS, _STEP_CAP
from sbcal.model.cable_sections import TINY, Arms, Compliance


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




def _lookup(table: Compliance, m2, row, out=None, log=True):
    """Section compliance and its slope from the table.

    ``m2 = |M|^2`` [(N m)^2], shape (..., b) (``log=False``: ``ln |M|^2`` already); ``row`` (b,)
    the parameter set (table row) of each entry, or of each section (m2's shape). Returns ``(Kr, Ki, Dr, Di)``, ``D = dK/dy`` (written into
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
    y0, inv_w, offset = table.y0[row], table.inv_w[row], row * table.n_buckets
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
    r = row[at] if row.ndim == y.ndim else row[at[-1]]
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


@dataclass(frozen=True)
class NumpyCableModel(CableModel):
    """:class:`CableModel` on the numpy formulation (same parameters, same numbers to rounding)."""

    def _sections(self, table, arms, p):
        _, _, _, (kr, ki, inv_m2) = self._sums(table, arms, p[0], p[1])
        return kr.copy(), ki.copy(), inv_m2.copy()

    def _lookup_many(self, table, m2, row):
        return _lookup(table, m2, row)

    def _sums(self, table, arms: Arms, p0, p1):
        """Section moments of K, dK/dy and (dK/dy) / |M|^2 against the weights ``w eta^k``.

        Returns (sk, sd, se): complex arrays of shape (3, b), (3, b), (5, b), row k holding the
        weight ``w eta^(2-k)`` (sk, sd) or ``w eta^(4-k)`` (se); and the sections' (Kr, Ki, |M|^-2),
        each (Q, b). All are :class:`_Work` buffers, valid until the next call.
        """
        b = p0.size
        zoned = arms.eta is not None
        eta, wp = (arms.eta, arms.weights) if zoned else self._rule
        q = eta.shape[0]
        # |M|^2 along the arm, a quadratic in eta: |p0|^2 eta^2 + 2 Re(p0 conj p1) eta + |p1|^2
        m2 = _Work.get("m2", (q, b))
        if zoned:
            np.multiply(eta, p0.real**2 + p0.imag**2, out=m2)
        else:
            np.multiply.outer(eta, p0.real**2 + p0.imag**2, out=m2)
        m2 += 2.0 * (p0.real * p1.real + p0.imag * p1.imag)
        m2 *= eta if zoned else eta[:, None]
        m2 += p1.real**2 + p1.imag**2
        kd = _Work.get("kd", (q, 4, b))  # Kr, Ki, Dr, Di: one block for one matrix product
        _lookup(table, m2, arms.zrow if zoned else arms.row, (kd[:, 0], kd[:, 1], kd[:, 2], kd[:, 3]))
        np.maximum(m2, TINY, out=m2)
        np.reciprocal(m2, out=m2)
        e = _Work.get("e", (q, 2, b))
        np.multiply(kd[:, 2], m2, out=e[:, 0])
        np.multiply(kd[:, 3], m2, out=e[:, 1])
        if zoned:  # each entry its own weights: a sum over the sections per entry
            s4 = np.einsum("kqb,qjb->kjb", wp[2:], kd, out=_Work.get("s4", (3, 4, b)))
            s2 = np.einsum("kqb,qjb->kjb", wp, e, out=_Work.get("s2", (5, 2, b)))
        else:
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


    def _start(self, table, arms: Arms):
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
            znew = np.log(np.maximum(m2, TINY) / np.maximum(det.real**2 + det.imag**2, TINY))
            z = znew if z is None else z + _START_RELAX * (znew - z)
            kr, ki, _, _ = _lookup(table, z[None, :], arms.row, log=False)
            k = kr[0] + 1j * ki[0]
        det = d0 + k * (k / 12.0 - d1)
        return np.stack([a, b]) / det


    def _newton(self, table, arms: Arms, p):
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
                           / np.maximum((pa.real**2 + pa.imag**2).sum(axis=0), TINY))
            f = (r.real**2 + r.imag**2).sum(axis=0)
            damping = np.where(f > merit, 0.5 * damping, np.minimum(1.0, 2.0 * damping))
            merit = f
            ok = np.isfinite(size)
            lam = np.where(ok, np.minimum(damping, _STEP_CAP / np.maximum(size, TINY)), 0.0)
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

