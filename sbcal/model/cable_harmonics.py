"""Beyond the first harmonic: the fast cable model's steady periodic response by harmonic balance.

:class:`sbcal.model.cable.CableModel` evaluates each section at the first harmonic of its own curvature
(a describing function), as if the motion stayed sinusoidal. At large amplitude a slipping cable's
moment is far from a sine, and the first harmonic of the base force (what the bench measures) moves
with it. :class:`HarmonicBalance` solves the same statically determinate arms with the odd harmonics
``1, 3, .., 2 H - 1`` of the loads ``p = (V L, M_tip)`` and of every section's curvature:

- each section: ``EJ_min (1 + i beta_material) chi_h + M_slip[chi]_h = p0_h eta + p1_h`` per harmonic,
  the slip moment evaluated over one period in time (alternating frequency-time): a rate-independent
  law under an odd periodic curvature with one maximum ``chi_a`` per period runs its steady loop's
  branches (:meth:`sbcal.model.laws.base.HysteresisLaw.loop_branch`), so every law is exact in time;
- each arm: ``S_h + N_h c_h - N_h p_h = 0`` with ``N_h`` the node's inertia at ``h omega`` and the
  clamp's motion only in the first harmonic (``c_h = 0`` beyond it), as the first-harmonic model has.

Newton on all unknowns at once, the sections eliminated per entry (each section's Jacobian is local:
a ``2H x 2H`` block, with the turning point's own term), from the first-harmonic model's solution. The
measured quantity is the first harmonic of the base force over the base motion (``f_uu``, as
:meth:`CableModel.dynamic_stiffness`); the force's harmonic distortion comes with it. The material
loss stays hysteretic (``i beta_material`` at every harmonic).

A section whose curvature has more than one maximum per period (inner loops: near the arm's point of
zero moment, where the higher harmonics dominate) is evaluated by the law's periodic operator instead
(:meth:`sbcal.model.laws.base.HysteresisLaw.periodic_moment`: Masing's rule with Madelung's memory,
or the Bouc-Wen state stepped exactly), its Jacobian without the reversal points' motion.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import InputError
from .cable import CableModel
from .cable_sections import checked_grid
from .damper import Damper


__all__ = ["DEFAULT_HARMONICS", "DEFAULT_SAMPLES", "HarmonicState", "HarmonicBalance"]

DEFAULT_HARMONICS = 5
"""Odd harmonics solved (1, 3, .., 9): within 0.2 % of a time integration at 2 mm (docs/cable.md)."""

DEFAULT_SAMPLES = 128
"""Time samples per period of the alternating frequency-time evaluation."""

_STEP_CAP = 0.5  # a Newton step moves the loads by at most this fraction of |p| (as the first-harmonic model)


@dataclass(frozen=True, eq=False)
class HarmonicState:
    """The multi-harmonic steady state per parameter set and line (:class:`HarmonicBalance`).

    Attributes
    ----------
    f_uu : ndarray of complex, shape (n_sets, n_freq)
        First harmonic of the base force over the base motion [N/m] (the bench's dynamic stiffness).
    force : ndarray of complex, shape (n_sets, n_freq, H)
        The base force's complex amplitudes [N] at :attr:`orders` (time convention ``exp(+i h omega t)``).
    distortion : ndarray, shape (n_sets, n_freq)
        ``sqrt(sum_{h > 1} |F_h|^2) / |F_1|``: the force's harmonic distortion.
    first_harmonic : ndarray of complex, shape (n_sets, n_freq)
        The describing-function model's ``f_uu`` (the start), for comparison.
    converged : ndarray of bool, shape (n_sets, n_freq)
    single_loop : ndarray of bool, shape (n_sets, n_freq)
        Every section's curvature has one maximum per period (else some sections ran inner loops,
        evaluated by :meth:`sbcal.model.laws.base.HysteresisLaw.periodic_moment`).
    residual : ndarray, shape (n_sets, n_freq)
        Relative size of the last Newton step.
    orders : tuple of int
    iterations : int
    """

    f_uu: np.ndarray
    force: np.ndarray
    distortion: np.ndarray
    first_harmonic: np.ndarray
    converged: np.ndarray
    single_loop: np.ndarray
    residual: np.ndarray
    orders: tuple
    iterations: int


def _complex_block(z):
    """Real 2x2 blocks ``[[Re, -Im], [Im, Re]]`` of complex ``z`` (...,) -> (..., 2, 2)."""
    return np.stack([np.stack([z.real, -z.imag], -1), np.stack([z.imag, z.real], -1)], -2)


@dataclass(frozen=True)
class HarmonicBalance:
    """The cable model solved with several odd harmonics (module docstring).

    Attributes
    ----------
    model : CableModel
        The model (its law, sections and zone rule).
    harmonics : int
        Odd harmonics ``1, 3, .., 2 harmonics - 1``; 1 is the describing function evaluated in time.
    samples : int
        Time samples per period (must resolve the highest harmonic several times over).
    max_iter : int
    tol : float
        Converged when the Newton step is below ``tol`` relative to the unknowns.
    material_loss : {"hysteretic", "viscous"}
        ``beta_material`` at harmonic ``h``: ``i beta`` (the frequency-domain models' structural loss,
        default) or ``i beta h`` (a viscous loss equal at the first harmonic: a time integration's).
    """

    model: CableModel
    harmonics: int = DEFAULT_HARMONICS
    samples: int = DEFAULT_SAMPLES
    max_iter: int = 40
    tol: float = 1e-9
    material_loss: str = "hysteretic"

    def __post_init__(self):
        if self.material_loss not in ("hysteretic", "viscous"):
            raise InputError(f"material_loss: expected 'hysteretic' or 'viscous', got {self.material_loss!r}")
        if int(self.harmonics) != self.harmonics or self.harmonics < 1:
            raise InputError(f"harmonics: expected an integer >= 1, got {self.harmonics!r}")
        if int(self.samples) != self.samples or self.samples < 8 * (2 * self.harmonics - 1):
            raise InputError(f"samples: expected an integer >= {8 * (2 * self.harmonics - 1)} "
                             f"(8 per period of the highest harmonic), got {self.samples!r}")

    @property
    def orders(self) -> tuple:
        """The harmonic orders solved."""
        return tuple(range(1, 2 * int(self.harmonics), 2))

    def state(self, damper: Damper, freq_hz, amplitude_mm_pp, **params) -> HarmonicState:
        """Multi-harmonic steady state at every line (parameters as :meth:`CableModel.state`).

        Parameters
        ----------
        damper : Damper
        freq_hz : array_like, shape (n_freq,)
        amplitude_mm_pp : float or array_like, shape (n_freq,)
            Base amplitude [mm peak-to-peak].
        **params : float or array_like, shape (n_sets,)

        Returns
        -------
        HarmonicState
            NaN for sets outside the law's domain.
        """
        model = self.model
        p, n_sets, in_law = model._parameters(damper, params)
        f, amp, _ = checked_grid(freq_hz, amplitude_mm_pp, None)
        valid = model._in_domain(p, n_sets, in_law)
        table = model._table(p, n_sets) if valid.all() else None
        if table is not None:
            valid = table.monotone
        if not valid.all():
            return self._subset(damper, f, amp, p, n_sets, valid)
        return self._solve(table, p, n_sets, f, amp)

    def _subset(self, damper, f, amp, p, n_sets, valid):
        keep, sub = CableModel._valid_subset(p, n_sets, valid)
        h, nf = len(self.orders), f.size
        out = dict(f_uu=np.full((n_sets, nf), np.nan + 0j), force=np.full((n_sets, nf, h), np.nan + 0j),
                   distortion=np.full((n_sets, nf), np.nan), first_harmonic=np.full((n_sets, nf), np.nan + 0j),
                   converged=np.zeros((n_sets, nf), dtype=bool), single_loop=np.zeros((n_sets, nf), dtype=bool),
                   residual=np.full((n_sets, nf), np.inf))
        iterations = 0
        if keep.size:
            st = self.state(damper, f, amp, **sub)
            for k in out:
                out[k][keep] = getattr(st, k)
            iterations = st.iterations
        return HarmonicState(**out, orders=self.orders, iterations=iterations)

    # --- the sections ------------------------------------------------------------------------------

    def _sections(self, p, n_sets, arms):
        """Per (section, entry): eta, weight, the law's parameters and the linear rigidity, each (Q, b)."""
        model, law, row = self.model, self.model.law, arms.row
        lin = (np.broadcast_to(p["EJ_min"], (n_sets,)) * (1 + 1j * np.broadcast_to(p["beta_material"], (n_sets,))))
        if arms.eta is None:
            eta, wp = model._rule
            q = eta.size
            eta = np.broadcast_to(eta[:, None], (q, row.size))
            w = np.broadcast_to(wp[4][:, None], (q, row.size))
            lp = {} if law is None else {k: np.broadcast_to(np.broadcast_to(p[k], (n_sets,))[row][None, :], (q, row.size))
                                         for k in law.parameter_names}
            return eta, w, lp, np.broadcast_to(lin[row][None, :], (q, row.size)), law
        eta, w = arms.eta, arms.weights[4]
        zone = model._zone_rule(p, n_sets)[2]
        zones = law.zones({k: p[k] for k in law.parameter_names})
        lp = {}
        for k in law.base.parameter_names:
            per_zone = np.stack([np.broadcast_to(z[2][k], (n_sets,)) for z in zones])  # (3, n_sets)
            lp[k] = per_zone[zone[:, None], row[None, :]]
        ratio = np.stack([np.broadcast_to(z[3], (n_sets,)) for z in zones])
        return eta, w, lp, lin[row][None, :] * ratio[zone[:, None], row[None, :]], law.base

    def _context(self, table, p, n_sets, f, amp):
        """What Newton needs at these lines (a tuple, :meth:`_newton`), the arms per harmonic, the
        first-harmonic model's solution and the start made from it (loads, curvatures)."""
        model, orders = self.model, self.orders
        h_n, nt = len(orders), int(self.samples)
        omega, x0 = 2 * np.pi * f, amp / 2 * 1e-3
        rule = model._zone_rule(p, n_sets) if model.zoned else None
        arms = [model._arms(p, n_sets, h * omega, x0 if h == 1 else 0.0 * x0, rule) for h in orders]
        eta, w, lp, lin, law = self._sections(p, n_sets, arms[0])
        first, start = self._first_start(table, arms[0], eta)
        # time basis: a signal is E x, its harmonics (2 / nt) E^T s
        theta = 2 * np.pi * np.arange(nt) / nt
        hs = np.repeat(np.asarray(orders, dtype=float), 2)
        basis, slope = _basis(theta, hs, 0), _basis(theta, hs, 1)  # (nt, 2H); d/dtheta
        project = 2.0 / nt * basis.T  # (2H, nt)
        nmat = np.stack([np.stack([a.n[[0, 1]], a.n[[1, 2]]]) for a in arms])  # (H, 2, 2, b)
        nc = np.stack([a.nc for a in arms])  # (H, 2, b) complex
        # the material loss per harmonic: hysteretic (i beta at every harmonic) or viscous (i beta h)
        loss = np.asarray(orders, dtype=float) if self.material_loss == "viscous" else np.ones(h_n)
        lin_h = lin.real[..., None] + 1j * lin.imag[..., None] * loss
        ctx = (eta, w, lp, _complex_block(lin_h), law, basis, slope, project, hs, nmat, nc)
        return ctx, arms, first, start

    def _first_start(self, table, arms, eta):
        """The first-harmonic model's solution at ``arms`` and Newton's start made from it (loads,
        curvatures; :func:`_start_arrays`)."""
        first = self.model._newton(table, arms, self.model._start(table, arms))
        p0, p1 = first[0]
        kr, ki, _ = self.model._sections(table, arms, first[0])
        return first, _start_arrays(p0, p1, kr + 1j * ki, eta, len(self.orders))

    def _solve(self, table, p, n_sets, f, amp):
        model, h_n = self.model, len(self.orders)
        omega, x0 = 2 * np.pi * f, amp / 2 * 1e-3
        ctx, arms, first, (load, chi) = self._context(table, p, n_sets, f, amp)
        b = load.shape[0]
        load, chi, done, step, single, its = self._newton(ctx, load, chi, 1.0)
        if not done.all():
            its += self._ramp(ctx, table, arms[0], load, chi, done, step, single)
        if not done.all():
            its += self._rescue(p, n_sets, f, amp, load, chi, done, step, single)
        lh = load.reshape(b, 2, h_n, 2)
        pc = lh[..., 0] + 1j * lh[..., 1]  # (b, 2, H)
        nf = f.size
        fa, fb, fc = (np.stack([a.force[i] for a in arms], -1) for i in range(3))  # (b, H)
        force = (fa * pc[:, 0] + fb * pc[:, 1] + fc).reshape(n_sets, nf, 2, h_n).sum(axis=2)
        force[:, :, 0] += (model._clamp_inertia(p, omega) * x0[None, :]).reshape(-1, nf)
        f_uu = force[:, :, 0] / x0[None, :]
        distortion = np.sqrt((np.abs(force[:, :, 1:]) ** 2).sum(axis=-1)) / np.abs(force[:, :, 0])
        per_line = lambda v, fn: fn(v.reshape(n_sets, nf, 2), axis=-1)  # noqa: E731
        return HarmonicState(
            f_uu=f_uu, force=force, distortion=distortion,
            first_harmonic=model._f_uu(arms[0], first[0], p, n_sets, omega, x0),
            converged=per_line(done, np.all), single_loop=per_line(single, np.all),
            residual=per_line(step, np.max), orders=self.orders, iterations=its)

    def _ramp(self, ctx, table, arms, load, chi, done, step, single, scales=(0.3, 0.45, 0.6, 0.72, 0.84, 0.92, 1.0)):
        """Amplitude continuation for the entries whose Newton did not converge from the first-harmonic
        start (the higher harmonics grow with the amplitude, out of the start's reach): from the
        first-harmonic model at ``scales[0]`` of the amplitude, each step solved from the last. In place."""
        idx = np.flatnonzero(~done)
        sub = _take(ctx, idx)
        _, (cl, cc) = self._first_start(table, replace(arms.take(idx), nc=arms.nc[:, idx] * scales[0]), sub[0])
        its = 0
        for scale in scales:
            cl, cc, cd, cs, csg, ci = self._newton(sub, cl, cc, scale)
            its += ci
        ok = idx[cd]
        load[ok], chi[:, ok], step[ok], single[ok] = cl[cd], cc[:, cd], cs[cd], csg[cd]
        done[ok] = True
        return its

    def _rescue(self, p, n_sets, f, amp, load, chi, done, step, single, substeps=8):
        """Frequency continuation for the lines whose Newton did not converge from the first-harmonic
        start (near a resonance, where a higher harmonic meets one of the arm's): from the nearest
        converged line of the same set, in ``substeps`` frequency steps, each solved from the last.
        Updates the arrays in place (both arms of a line); returns the iterations."""
        nf = f.size
        ok = done.reshape(n_sets, nf, 2).all(axis=-1)
        its = 0
        for s_, k in zip(*np.nonzero(~ok)):
            good = np.flatnonzero(ok[s_])
            if good.size == 0:
                continue
            j = good[np.argmin(np.abs(f[good] - f[k]))]
            ps = {key: (v[s_:s_ + 1] if v.size == n_sets and n_sets > 1 else v) for key, v in p.items()}
            table = self.model._table(ps, 1)
            src = (s_ * nf + j) * 2 + np.arange(2)
            dst = (s_ * nf + k) * 2 + np.arange(2)
            cl, cc = load[src], chi[:, src]
            for fk in np.linspace(f[j], f[k], substeps + 1)[1:]:
                ctx = self._context(table, ps, 1, np.array([fk]), np.array([amp[k]]))[0]
                cl, cc, cd, cs, csg, ci = self._newton(ctx, cl, cc, 1.0)
                its += ci
                if not cd.all():
                    break
            if cd.all():
                load[dst], chi[:, dst] = cl, cc
                done[dst], step[dst], single[dst] = True, cs, csg
        return its

    def _newton(self, ctx, load, chi, scale):
        """Damped Newton on the loads and curvatures from ``(load, chi)``, the base motion scaled by
        ``scale``; returns them with per-entry done, last step, single-loop flags and iterations."""
        eta, w, lp, lin_block, law, basis, slope, project, hs, nmat, nc = ctx
        load, chi = load.copy(), chi.copy()
        q, b, k2 = chi.shape
        h_n = k2 // 2
        nc = nc * scale
        done = np.zeros(b, dtype=bool)
        single = np.ones(b, dtype=bool)
        step, last, damping = np.full(b, np.inf), np.full(b, np.inf), np.ones(b)
        its = 0
        for its in range(1, self.max_iter + 1):
            r_sec, jac, single_now = self._section_terms(chi, load, eta, lp, lin_block, law, basis, slope, project, hs)
            single &= single_now
            # arm residual per harmonic: sum_q w (eta, 1) chi_h + nc_h - N_h p_h
            s0 = np.einsum("qb,qbk->bk", w * eta, chi)
            s1 = np.einsum("qb,qbk->bk", w, chi)
            res_arm = np.stack([s0, s1], 1)  # (b, 2, 2H)
            ncr = np.stack([nc.real, nc.imag], -1).transpose(2, 1, 0, 3).reshape(b, 2, 2 * h_n)
            res_arm += ncr
            lh = load.reshape(b, 2, h_n, 2)
            res_arm -= np.einsum("hacb,bchx->bahx", nmat, lh).reshape(b, 2, 2 * h_n)
            cinv = np.linalg.inv(jac)  # (Q, b, 2H, 2H)
            wk = [np.einsum("qb,qbij->bij", w * eta**k, cinv) for k in (2, 1, 0)]
            big = np.empty((b, 2, 2 * h_n, 2, 2 * h_n))
            big[:, 0, :, 0], big[:, 0, :, 1], big[:, 1, :, 0], big[:, 1, :, 1] = wk[0], wk[1], wk[1], wk[2]
            nblock = np.zeros((b, 2, h_n, 2, 2, h_n, 2))  # N acts per harmonic, alike on Re and Im
            for k in range(h_n):
                for x in range(2):
                    nblock[:, :, k, x, :, k, x] = nmat[k].transpose(2, 0, 1)
            big -= nblock.reshape(b, 2, 2 * h_n, 2, 2 * h_n)
            cr = np.einsum("qbij,qbj->qbi", cinv, r_sec)
            rhs = -res_arm + np.stack([np.einsum("qb,qbi->bi", w * eta, cr), np.einsum("qb,qbi->bi", w, cr)], 1)
            dp = np.linalg.solve(big.reshape(b, 4 * h_n, 4 * h_n), rhs.reshape(b, 4 * h_n)[..., None])[..., 0]
            dp = dp.reshape(b, 2, 2 * h_n)
            dm = eta[:, :, None] * dp[None, :, 0] + dp[None, :, 1]
            dchi = np.einsum("qbij,qbj->qbi", cinv, dm - r_sec)
            size = np.sqrt((dp**2).sum(axis=(1, 2)) / np.maximum((load**2).sum(axis=(1, 2)), 1e-300))
            # an entry whose step grew halves its later steps until they shrink again (as the first-harmonic model)
            damping = np.where(size > last, 0.5 * damping, np.minimum(1.0, 2.0 * damping))
            last = size
            lam = np.where(np.isfinite(size), np.minimum(damping, _STEP_CAP / np.maximum(size, 1e-300)), 0.0)
            lam[done] = 0.0
            load += lam[:, None, None] * np.nan_to_num(dp)
            chi += lam[None, :, None] * np.nan_to_num(dchi)
            step = np.where(done, step, size)
            done |= (size < self.tol) & (lam == 1.0)
            if done.all():
                break
        return load, chi, done, step, single, its

    @staticmethod
    def _section_terms(chi, load, eta, lp, lin_block, law, basis, slope, project, hs):
        """Section residuals ``EJ_lin chi + M_slip[chi] - M`` (Q, b, 2H), their Jacobians (Q, b, 2H, 2H)
        and whether each entry's sections all have one maximum per period (b,)."""
        q, b, k2 = chi.shape
        h_n = k2 // 2
        # linear part and the moment the loads set: M = p0 eta + p1
        cz = chi.reshape(q, b, h_n, 2)
        lin_part = np.einsum("qbhij,qbhj->qbhi", lin_block, cz).reshape(q, b, k2)
        moment = eta[:, :, None] * load[None, :, 0] + load[None, :, 1]
        jac = np.zeros((q, b, k2, k2))
        for k in range(h_n):
            jac[:, :, 2 * k:2 * k + 2, 2 * k:2 * k + 2] = lin_block[:, :, k]
        single = np.ones(b, dtype=bool)
        if law is None:
            return lin_part - moment, jac, single
        kt = chi @ basis.T  # (Q, b, nt)
        kd = chi @ slope.T
        nt = basis.shape[0]
        # the turning point: the largest sample, refined by Newton on d chi / d theta = 0
        i0 = np.argmax(kt, axis=-1)
        th = 2 * np.pi * i0 / nt
        for _ in range(4):
            d1 = (chi * _basis(th, hs, 1)).sum(-1)
            d2 = (chi * _basis(th, hs, 2)).sum(-1)
            th = th - np.where(d2 < 0, d1 / np.where(d2 < 0, d2, 1.0), 0.0)
        star = _basis(th, hs, 0)  # (Q, b, 2H)
        chi_a = np.maximum((chi * star).sum(-1), kt.max(axis=-1))
        # one maximum per period (the slope changes sign twice): the steady loop's branches, with the
        # turning point's own term in the Jacobian; inner loops: the law's periodic evaluation
        s = np.sign(kd)
        inner = (s != np.roll(s, 1, axis=-1)).sum(axis=-1) > 2
        single = ~inner.any(axis=0)
        theta = 2 * np.pi * np.arange(nt) / nt
        falling = np.mod(theta - th[..., None], 2 * np.pi) < np.pi
        x = np.clip(np.where(falling, kt, -kt), -chi_a[..., None], chi_a[..., None])
        m, dm, dma = law.loop_branch(x, chi_a[..., None], **{k: v[..., None] for k, v in lp.items()})
        slip = np.where(falling, m, -m)
        g = np.where(falling, dma, -dma)
        inner_jac = None
        if inner.any():
            # the moment hangs on every reversal point and on the periodic state: derivatives along the path
            path, dirs = _with_reversals(chi[inner], hs, nt)
            m_in, dm_in = law.periodic_moment(path, dirs, **{k: v[inner][:, None] for k, v in lp.items()})
            slip[inner], dm[inner], g[inner] = m_in[:, ::2], 0.0, 0.0
            inner_jac = np.einsum("it,ntj->nij", project, dm_in[:, ::2])
        jac += np.einsum("it,qbt,tj->qbij", project, dm, basis, optimize=True)
        jac += (g @ project.T)[..., :, None] * star[..., None, :]
        if inner_jac is not None:
            jac[inner] += inner_jac
        return lin_part + slip @ project.T - moment, jac, single


def _with_reversals(chi, hs, nt):
    """Curvature at twice the samples, every reversal exact: between samples ``j`` and ``j + 1`` the
    half-way value, or the extremum there when the slope changes sign (Newton on the harmonic series).

    The law's periodic operator then sees the true turning points, so the moment at the samples moves
    smoothly with the harmonics (reversals at the samples would make it jump as they cross one).

    Parameters
    ----------
    chi : ndarray, shape (n, 2H)
        Curvature harmonics ``[Re, Im]`` per harmonic of ``hs`` (each twice).
    hs : ndarray, shape (2H,)
    nt : int
        Samples per period.

    Returns
    -------
    path : ndarray, shape (n, 2 nt)
        Samples ``0, 1/2, 1, ..`` of the period; the original samples at the even indices.
    dirs : ndarray, shape (n, 2 nt, 2H)
        Their derivatives with the harmonic coefficients.
    """
    theta = np.pi * np.arange(2 * nt) / nt
    b0 = _basis(theta, hs, 0)
    out = chi @ b0.T
    dirs = np.broadcast_to(b0[None], (chi.shape[0],) + b0.shape).copy()
    d = chi @ _basis(theta[::2], hs, 1).T  # slope at the samples
    rows, cols = np.nonzero(np.sign(d) != np.sign(np.roll(d, -1, axis=1)))
    if rows.size:
        c = chi[rows]
        lo = theta[2 * cols]
        t = lo + np.pi / nt
        for _ in range(5):
            d1 = (c * _basis(t, hs, 1)).sum(-1)
            d2 = (c * _basis(t, hs, 2)).sum(-1)
            t = np.clip(t - d1 / np.where(d2 != 0, d2, 1.0), lo, lo + 2 * np.pi / nt)
        at = _basis(t, hs, 0)
        out[rows, 2 * cols + 1] = (c * at).sum(-1)
        dirs[rows, 2 * cols + 1] = at  # at an extremum d chi / d theta = 0: only the coefficients move it
    return out, dirs


def _basis(theta, hs, order):
    """The real harmonic basis at phases ``theta`` (...,) and its ``order``-th derivative in theta (0-2):
    columns ``cos(h theta), -sin(h theta)`` per harmonic of ``hs`` (each twice), so that a signal is
    ``basis @ [Re, Im, ..]``. Shape (..., 2H)."""
    h = hs[::2]  # each order once: one cosine and one sine per order
    ph = h * np.asarray(theta, dtype=float)[..., None]
    c, s = np.cos(ph), np.sin(ph)
    out = np.empty(ph.shape[:-1] + (hs.size,))
    if order == 0:
        out[..., 0::2], out[..., 1::2] = c, -s
    elif order == 1:
        out[..., 0::2], out[..., 1::2] = -s * h, -c * h
    else:
        out[..., 0::2], out[..., 1::2] = -c * h**2, s * h**2
    return out


def _start_arrays(p0, p1, compliance, eta, h_n):
    """Newton's unknowns from a first-harmonic solution: loads (b, 2, 2H) and curvatures (Q, b, 2H),
    ``[Re, Im]`` per harmonic, the higher harmonics 0."""
    load = np.zeros((p0.size, 2, 2 * h_n))
    load[:, 0, :2] = np.stack([p0.real, p0.imag], -1)
    load[:, 1, :2] = np.stack([p1.real, p1.imag], -1)
    chi = np.zeros((eta.shape[0], p0.size, 2 * h_n))
    c1 = compliance * (p0[None, :] * eta + p1[None, :])
    chi[:, :, 0], chi[:, :, 1] = c1.real, c1.imag
    return load, chi


def _take(ctx, idx):
    """Newton's context (:meth:`HarmonicBalance._context`) for the entries ``idx``."""
    eta, w, lp, lin_block, law, basis, slope, project, hs, nmat, nc = ctx
    return (eta[:, idx], w[:, idx], {k: v[:, idx] for k, v in lp.items()}, lin_block[:, idx], law, basis, slope,
            project, hs, nmat[..., idx], nc[..., idx])
