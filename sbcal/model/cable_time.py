"""The fast distributed cable in time: a virtual shaker bench, and the reference of the multi-harmonic
solvers (:class:`sbcal.model.cable.CableModel`'s equations integrated in time).

Every (set, line, arm) of :class:`~sbcal.model.cable.CableModel` is integrated at once, in the arm's frame
and the phase time ``theta = omega t`` of its line (every line its own ``omega``, all the same steps
per period). With the loads ``p(theta) = (V L, M_tip)`` [N m] at the mass node, the moment along the arm
is ``p0 eta + p1`` (``eta = 1 - s/L``) and each Gauss section ``q`` of the model's rule has the curvature
``kappa_q`` of its law::

    EJ_q kappa_q + beta EJ_q dkappa_q/dtheta + M_slip,q[kappa_q history] = p0 eta_q + p1

(``EJ_q`` the section's ``EJ_min``, its zone's ratio with a zoned law; the material loss ``EJ_min (1 +
i beta)`` of the first-harmonic model is this viscous term in phase time, exact at the fundamental;
``M_slip`` from :mod:`sbcal.model.laws.steppers`: a Masing law's Jenkins population is built against the
section's ``EJ_min (1 + i beta)``, so that its error stays small against the section's loss too). The node's equation is the frequency-domain residual
``S + N c - N p = 0`` of :class:`~sbcal.model.cable_sections.Arms` in phase time::

    d^2/dtheta^2 [S(theta) + g(theta)] = -N p(theta),   S = sum_q w_q (eta_q, 1) kappa_q,
    g = N c x_b(theta) / x0

with the base motion ``x_b = x0 env(theta) cos(theta)`` (``env`` a C2 quintic ramp from 0 to 1 over
``ramp`` periods; ``x0 = amplitude_mm_pp / 2 * 1e-3`` m); for a sinusoid it is ``S = N p - N c``, the
model's residual, and at harmonic ``h`` ``N / h^2`` (the inertia at ``h omega``). The vertical force on
the base (both arms, the clamp's own inertia) is::

    F = sum_arms [fa p0 + fb p1 - (fc / x0) x_b''] - C x_b'',   C = _clamp_inertia (= -omega^2 mc (1 + ac r))

so that its first harmonic over ``x0`` is the model's ``f_uu`` (``fa, fb, fc`` of :meth:`CableModel._arms`).

Time stepping: Newmark's average acceleration (the trapezoidal rule) on ``Y = S + g`` with ``Y'' = -N p``
and on ``dkappa/dtheta``; unconditionally stable, second order: a linear system's steady response to
``exp(i theta)`` is the exact one at the frequency ``omega (1 + dtheta^2 / 12)``. With ``prewarp`` (the
default) ``N`` is scaled by ``psi^2`` and the viscous term by ``1 / psi``, ``psi = tan(dtheta/2) /
(dtheta/2)``: the discrete first harmonic of a linear cable is then exact (the bilinear transform
pre-warped at the fundamental); a harmonic ``h`` keeps a relative frequency error ``(h^2 - 1)
dtheta^2 / 12``. Each step solves for ``p_n+1`` and the sections' curvatures by Newton (below, in
:func:`_step`), to a relative tolerance ``newton_tol``; a line where a step fails is flagged (NaN), not used.

After the ramp and ``settle`` periods, the force's harmonics are taken over the last ``window`` whole
periods (a rectangular DFT, as a data acquisition system does); a line is settled when its first
harmonic changed by less than ``tol`` (relative) from the window before, and leaves the integration
then (or at ``max_periods``, unsettled). A transient decaying by ``r`` per window leaves an error of
about ``tol / (1 - r)``: ~1e-4 at ``tol = 1e-5`` for a resonance damped at 1 % (4-period windows).
``start="model"`` starts on the first-harmonic model's steady state instead of at rest (the reference
for multi-harmonic solvers: the transient left is only the model's error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .cable import CableModel
from .cable_sections import checked_grid, gauss
from .damper import Damper
from .laws.steppers import law_stepper


__all__ = ["DEFAULT_STEPS_PER_PERIOD", "TimeResponse", "time_response"]

DEFAULT_STEPS_PER_PERIOD = 256
"""Time steps per period of every line: the trapezoidal rule's frequency error ``(2 pi / 256)^2 / 12 =
5e-5`` (removed at the fundamental by ``prewarp``)."""

_TINY = 1e-300


@dataclass(frozen=True, eq=False)
class TimeResponse:
    """The cable's time response per parameter set and line (:func:`time_response`).

    Attributes
    ----------
    f_uu : ndarray of complex, shape (n_sets, n_freq)
        First harmonic of the base force over the base motion's [N/m], last window.
    harmonics : ndarray of complex, shape (n_sets, n_freq, n_harmonics)
        The base force's complex amplitudes [N] at harmonics 1 .. n_harmonics (``F = Re sum F_h
        exp(i h theta)``), last window.
    distortion : ndarray, shape (n_sets, n_freq)
        ``sqrt(sum_{h >= 2} |F_h|^2) / |F_1|`` over the harmonics 2 .. n_harmonics, last window (a sum to the
        Nyquist frequency would also count what is left of a transient's free vibration).
    settled : ndarray of bool, shape (n_sets, n_freq)
        The first harmonic changed by less than ``tol`` from the window before.
    change : ndarray, shape (n_sets, n_freq)
        That relative change.
    converged : ndarray of bool, shape (n_sets, n_freq)
        Every time step met the Newton tolerance (False: the line's results are NaN).
    periods : ndarray of int, shape (n_sets, n_freq)
        Periods integrated.
    iterations : ndarray of int, shape (n_sets, n_freq)
        Most Newton iterations of a time step.
    steps_per_period, window : int
    theta : ndarray, shape (n_samples,), or None
        Phase time [rad] of the samples (``keep_series``): every step, from the first (``dtheta``).
    base : ndarray, shape (n_sets, n_freq, n_samples), or None
        Base motion ``x_b`` [m] (NaN after the line stopped); the time is ``theta / omega``.
    force : ndarray, shape (n_sets, n_freq, n_samples), or None
        Base force ``F`` [N] (NaN after the line stopped).
    """

    f_uu: np.ndarray
    harmonics: np.ndarray
    distortion: np.ndarray
    settled: np.ndarray
    change: np.ndarray
    converged: np.ndarray
    periods: np.ndarray
    iterations: np.ndarray
    steps_per_period: int
    window: int
    theta: np.ndarray | None = None
    base: np.ndarray | None = None
    force: np.ndarray | None = None


@dataclass(frozen=True)
class _Settings:
    steps: int
    ramp: float
    settle: int
    window: int
    tol: float
    max_periods: int
    n_harmonics: int
    newton_tol: float
    max_iter: int
    prewarp: bool
    resolution: float
    keep_series: bool
    start: str

    @property
    def first_window(self) -> int:
        """Periods before the two windows may be compared."""
        return int(math.ceil(self.ramp)) + self.settle + 2 * self.window


def _settings(steps_per_period, ramp, settle, window, tol, max_periods, n_harmonics, newton_tol, max_iter,
              prewarp, resolution, keep_series, start) -> _Settings:
    def integer(name, v, low):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise InputError(f"{name}: expected an integer >= {low}, got {v!r}")
        return int(v)

    def positive(name, v, strict=True):
        ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or (v <= 0 if strict else v < 0):
            raise InputError(f"{name}: expected a finite value {'>' if strict else '>='} 0, got {v!r}")
        return float(v)

    steps = integer("steps_per_period", steps_per_period, 8)
    k = integer("n_harmonics", n_harmonics, 1)
    if 2 * k >= steps:
        raise InputError(f"n_harmonics: expected fewer than steps_per_period / 2 = {steps // 2}, got {k}")
    if start not in ("rest", "model"):
        raise InputError(f"start: expected 'rest' or 'model', got {start!r}")
    s = _Settings(steps=steps, ramp=positive("ramp", ramp, strict=False), settle=integer("settle", settle, 0),
                  window=integer("window", window, 1), tol=positive("tol", tol),
                  max_periods=integer("max_periods", max_periods, 1), n_harmonics=k,
                  newton_tol=positive("newton_tol", newton_tol), max_iter=integer("max_iter", max_iter, 1),
                  prewarp=bool(prewarp), resolution=positive("resolution", resolution),
                  keep_series=bool(keep_series), start=start)
    if s.max_periods < s.first_window:
        raise InputError(f"max_periods: expected >= ramp + settle + 2 window = {s.first_window}, got {max_periods!r}")
    return s


def _envelope(theta, ramp):
    """The ramp ``env`` and its first two derivatives in theta (C2 quintic over ``ramp`` periods)."""
    if ramp == 0:
        return 1.0, 0.0, 0.0
    span = 2 * np.pi * ramp
    s = min(theta / span, 1.0)
    if s >= 1.0:
        return 1.0, 0.0, 0.0
    return (s**3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2 / span,
            60 * s * (1 - s) * (1 - 2 * s) / span**2)


@dataclass(frozen=True, eq=False)
class _Cable:
    """Per-entry and per-section constants of the active lines (entries b = line * 2 + arm; sections
    (Q, b)), and the law's stepper (sections flattened q-major)."""

    eta: np.ndarray  # (Q, b) from the mass node
    w: np.ndarray  # (Q, b) Gauss weights on [0, 1]
    ej: np.ndarray  # (Q, b) EJ_min of the section [N m^2]
    visc: np.ndarray  # (Q, b) beta EJ / psi [N m^2 per unit dkappa/dtheta]
    n: np.ndarray  # (3, b) N (scaled by psi^2 with prewarp)
    nc: np.ndarray  # (2, b) N c
    fab: np.ndarray  # (2, b) (fa, fb) / x0
    inertia: np.ndarray  # (lines,) sum_arms fc / x0 + clamp inertia [N/m]
    x0: np.ndarray  # (lines,) [m]
    stepper: object

    def take(self, lines) -> "_Cable":
        """The constants of the active lines ``lines`` (indices into the current ones)."""
        e = (2 * lines[:, None] + np.arange(2)[None, :]).reshape(-1)
        q, b = self.eta.shape
        flat = (np.arange(q)[:, None] * b + e[None, :]).reshape(-1)
        return _Cable(self.eta[:, e], self.w[:, e], self.ej[:, e], self.visc[:, e], self.n[:, e], self.nc[:, e],
                      self.fab[:, e], self.inertia[lines], self.x0[lines], self.stepper.take(flat))


def _setup(model: CableModel, p, n_sets, f, amp, s: _Settings) -> _Cable:
    """The constants from the model's own helpers (:meth:`CableModel._arms`, ``_zone_rule``, ``_clamp_inertia``)."""
    omega = 2 * np.pi * f
    x0 = amp / 2 * 1e-3
    rule = model._zone_rule(p, n_sets) if model.zoned else None
    arms = model._arms(p, n_sets, omega, x0, rule)
    b = arms.row.size
    row = arms.row
    if rule is None:
        eta, w = gauss(int(model.sections))
        eta, w = np.repeat(eta[:, None], b, axis=1), np.repeat(w[:, None], b, axis=1)
        law = model.law
        lp = {k: np.broadcast_to(p[k], (n_sets,))[row][None, :].repeat(eta.shape[0], axis=0)
              for k in (law.parameter_names if law is not None else ())}
        ratio = np.ones(eta.shape)
    else:
        eta, w = arms.eta, arms.weights[4]  # weights row 4 is w eta^0
        zone = rule[2]
        law = model.law.base
        zones = model.law.zones({k: p[k] for k in model.law.parameter_names})
        lp = {k: np.stack([np.broadcast_to(z[2][k], (n_sets,)) for z in zones])[zone[:, None], row[None, :]]
              for k in law.parameter_names}
        ratios = np.stack([np.broadcast_to(z[3], (n_sets,)) for z in zones]).astype(float)
        ratio = ratios[zone[:, None], row[None, :]]
    q = eta.shape[0]
    dt = 2 * np.pi / s.steps
    psi = math.tan(dt / 2) / (dt / 2) if s.prewarp else 1.0
    ej = np.broadcast_to(p["EJ_min"], (n_sets,))[row][None, :] * ratio
    visc = np.broadcast_to(p["beta_material"], (n_sets,))[row][None, :] * ej / psi
    x0_entry = np.broadcast_to(x0.reshape(-1, f.size)[:, :, None], (n_sets, f.size, 2)).reshape(-1)
    fa, fb, fc = arms.force
    clamp = np.broadcast_to(model._clamp_inertia(p, omega), (n_sets, f.size)).reshape(-1)
    linear = (ej * (1 + 1j * np.broadcast_to(p["beta_material"], (n_sets,))[row][None, :])).reshape(-1)
    stepper = law_stepper(law, {k: v.reshape(-1) for k, v in lp.items()}, size=q * b, resolution=s.resolution,
                          linear=linear)
    return _Cable(eta=np.ascontiguousarray(eta), w=np.ascontiguousarray(w), ej=ej, visc=visc, n=arms.n * psi**2,
                  nc=arms.nc, fab=np.stack([fa, fb]) / x0_entry,
                  inertia=(fc / x0_entry).reshape(-1, 2).sum(axis=1) + clamp, x0=x0_entry[::2].copy(), stepper=stepper)


@dataclass(frozen=True, eq=False)
class _State:
    """The integration's state of the active entries at a step (the two previous steps' ``p`` and
    ``kappa`` for the predictor)."""

    p: np.ndarray  # (2, b)
    p_prev: np.ndarray
    p_prev2: np.ndarray
    kappa: np.ndarray  # (Q, b)
    kappa_prev: np.ndarray
    kappa_prev2: np.ndarray
    kdot: np.ndarray  # (Q, b) dkappa/dtheta
    y: np.ndarray  # (2, b) Y = S + g and its first two derivatives
    yd: np.ndarray
    ydd: np.ndarray
    law: object
    p_max: np.ndarray  # (b,) largest |p| so far: the scale of the relative tolerance
    k_max: np.ndarray  # (b,) largest |kappa| so far

    def take(self, lines, q):
        e = (2 * lines[:, None] + np.arange(2)[None, :]).reshape(-1)
        b = self.p.shape[1]
        flat = (np.arange(q)[:, None] * b + e[None, :]).reshape(-1)
        names = ("p", "p_prev", "p_prev2", "kappa", "kappa_prev", "kappa_prev2", "kdot", "y", "yd", "ydd")
        cols = {k: getattr(self, k)[:, e] for k in names}
        return _State(**cols, law=self.law.take(flat), p_max=self.p_max[e], k_max=self.k_max[e])


def _step(c: _Cable, st: _State, g, dt, tol, max_iter):
    """One time step: ``p_n+1`` and the curvatures by Newton, jointly.

    Joint rather than nested: a section's residual ``EJ kappa + visc kappa' + M_slip(kappa) - (p0 eta +
    p1)`` has the local tangent ``t = EJ (1 + 2 visc' / dtheta) + dM_slip/dkappa``, so a Newton step
    eliminates each ``dkappa_q = (l_q . dp - R_q) / t_q`` (``l = (eta, 1)``) and leaves one 2x2 system
    per entry (the Schur complement ``dtheta^2/4 N + sum w l l^T / t``, symmetric positive definite):
    one law evaluation per iteration (the population sums are the cost), where a nested solve would
    need several per outer iteration. Each section's ``M(kappa)`` is monotone and the steps are small
    (the predictor extrapolates the last two steps), but its tangent jumps where the step reverses
    (at ``kappa_n``: slipping on one side, stuck on the other, up to ~6x stiffer): Newton can cycle
    across that kink. A section whose iterate crosses ``kappa_n`` a second time in a step stops at
    ``kappa_n`` instead (the next iterate starts on the right branch); entries still not converged
    after ``max_iter // 2`` iterations take half steps. An entry that has not met ``tol`` after
    ``max_iter`` iterations is returned as failed.

    The accepted iterate is the last one evaluated (its step below ``tol`` is not taken), so the law's
    committed state is exactly that of the accepted curvatures. Returns (new state, converged per
    entry (b,), iterations).
    """
    a = 0.25 * dt * dt
    n00, n01, n11 = c.n
    y_pred = st.y + dt * st.yd + a * st.ydd
    p = 3.0 * (st.p - st.p_prev) + st.p_prev2  # quadratic extrapolation: ~0.5 iteration fewer than linear
    k = 3.0 * (st.kappa - st.kappa_prev) + st.kappa_prev2
    eta, w = c.eta, c.w
    stiff = c.ej + (2.0 / dt) * c.visc
    lag = (2.0 / dt) * st.kappa + st.kdot  # kappa' = (2 / dt) kappa - lag
    crossed = np.zeros(k.shape, dtype=bool)
    for it in range(1, max_iter + 1):
        trial = c.stepper.trial(st.law, k.reshape(-1))
        m = trial.moment.reshape(k.shape)
        t = stiff + trial.tangent.reshape(k.shape)
        r = c.ej * k + c.visc * ((2.0 / dt) * k - lag) + m - (p[0] * eta + p[1])
        wk = w * k
        s0, s1 = (wk * eta).sum(axis=0), wk.sum(axis=0)
        rn0 = s0 + g[0] - y_pred[0] + a * (n00 * p[0] + n01 * p[1])
        rn1 = s1 + g[1] - y_pred[1] + a * (n01 * p[0] + n11 * p[1])
        wt = w / t
        wte = wt * eta
        k00, k01, k11 = a * n00 + (wte * eta).sum(axis=0), a * n01 + wte.sum(axis=0), a * n11 + wt.sum(axis=0)
        r0, r1 = (wte * r).sum(axis=0) - rn0, (wt * r).sum(axis=0) - rn1
        det = k00 * k11 - k01 * k01
        dp0, dp1 = (k11 * r0 - k01 * r1) / det, (k00 * r1 - k01 * r0) / det
        dk = (eta * dp0 + dp1 - r) / t
        p_scale = np.maximum(np.maximum(st.p_max, np.hypot(p[0], p[1])), _TINY)
        k_scale = np.maximum(np.maximum(st.k_max, np.abs(k).max(axis=0)), _TINY)
        err = np.maximum(np.hypot(dp0, dp1) / p_scale, np.abs(dk).max(axis=0) / k_scale)
        ok = err <= tol
        if ok.all() or it == max_iter:
            break
        if it > max_iter // 2:
            half = np.where(ok, 1.0, 0.5)
            dp0, dp1, dk = dp0 * half, dp1 * half, dk * half
        p = p + np.stack([dp0, dp1])
        side = k - st.kappa
        k = k + dk
        cross = side * (k - st.kappa) < 0.0
        again = cross & crossed
        k = np.where(again, st.kappa, k)
        crossed |= cross
    ydd = -np.stack([n00 * p[0] + n01 * p[1], n01 * p[0] + n11 * p[1]])
    new = _State(p=p, p_prev=st.p, p_prev2=st.p_prev, kappa=k, kappa_prev=st.kappa, kappa_prev2=st.kappa_prev,
                 kdot=(2.0 / dt) * k - lag, y=y_pred + a * ydd, yd=st.yd + 0.5 * dt * (st.ydd + ydd), ydd=ydd,
                 law=c.stepper.commit(trial), p_max=np.maximum(st.p_max, np.hypot(p[0], p[1])),
                 k_max=np.maximum(st.k_max, np.abs(k).max(axis=0)))
    return new, ok, it


def _rest(c: _Cable) -> _State:
    """At rest (the base ramped up from 0)."""
    q, b = c.eta.shape
    z, zq = np.zeros((2, b)), np.zeros((q, b))
    return _State(p=z, p_prev=z, p_prev2=z, kappa=zq, kappa_prev=zq, kappa_prev2=zq, kdot=zq, y=z, yd=z, ydd=z,
                  law=c.stepper.start(), p_max=np.zeros(b), k_max=np.zeros(b))


def _from_model(c: _Cable, load, rigidity, ramped, dt) -> _State:
    """On the first-harmonic model's steady state at theta = 0 (the base at full amplitude).

    ``load`` (2, b) complex ``(V L, M_tip)``, ``rigidity`` (Q, b) the sections' ``EJ*``; the lines
    ``ramped`` (per entry, (b,)) start at rest instead. The law's memory is put on its loop by driving
    each section alone through its sinusoidal curvature (a period's ramp, then two periods: a Masing
    law is on its steady loop after its first full cycle). Values and derivatives are the discrete
    steady state's (``Y' = i psi Y``, ``psi = tan(dtheta/2) / (dtheta/2)``): with ``prewarp`` a linear
    cable starts without any transient.
    """
    load = np.where(ramped[None, :], 0.0, load)
    k = np.where(ramped[None, :], 0.0, (load[0] * c.eta + load[1]) / rigidity)
    k = np.where(np.isfinite(k), k, 0.0)
    steps = int(round(2 * np.pi / dt))
    theta = np.arange(-3 * steps + 1, 1) * dt
    grow = np.clip((theta + 3 * 2 * np.pi) / (2 * np.pi), 0.0, 1.0)
    grow = grow * grow * (3 - 2 * grow)
    law = c.stepper.start()
    for th, gr in zip(theta, grow):
        law = c.stepper.commit(c.stepper.trial(law, (gr * k * np.exp(1j * th)).real.reshape(-1)))
    psi = math.tan(dt / 2) / (dt / 2)
    n00, n01, n11 = c.n
    y = np.stack([(c.w * c.eta * k).sum(axis=0), (c.w * k).sum(axis=0)]) + c.nc * (~ramped)
    p0 = load.real
    back = np.exp(-1j * dt)
    return _State(p=p0, p_prev=(load * back).real, p_prev2=(load * back * back).real, kappa=k.real,
                  kappa_prev=(k * back).real, kappa_prev2=(k * back * back).real, kdot=(1j * psi * k).real,
                  y=y.real, yd=(1j * psi * y).real,
                  ydd=-np.stack([n00 * p0[0] + n01 * p0[1], n01 * p0[0] + n11 * p0[1]]),
                  law=law, p_max=np.abs(load).max(axis=0), k_max=np.abs(k).max(axis=0))


def _start(model: CableModel, damper, p, n_sets, f, amp, c: _Cable, s: _Settings):
    """The initial state and which lines ramp up from rest (lines,): all with ``start="rest"``; with
    ``"model"`` those where the first-harmonic model did not converge."""
    dt = 2 * np.pi / s.steps
    if s.start == "rest":
        env0, _, _ = _envelope(0.0, s.ramp)
        st = _rest(c)
        return _State(**{**st.__dict__, "y": c.nc * env0}), np.ones(c.x0.size, dtype=bool)  # Y = S + g, S = 0
    ms = model.state(damper, f, amp, **p)
    length = np.stack([np.broadcast_to(p["L1"], (n_sets,)), np.broadcast_to(p["L2"], (n_sets,))], axis=1)
    length = np.broadcast_to(length[:, None, :], (n_sets, f.size, 2)).reshape(-1)
    load = np.stack([ms.load[..., 0].reshape(-1) * length, ms.load[..., 1].reshape(-1)])  # (V L, M_tip)
    rigidity = ms.rigidity.reshape(-1, ms.rigidity.shape[-1]).T  # (Q, b)
    good = np.repeat(ms.converged.reshape(-1) & np.isfinite(ms.f_uu.reshape(-1)), 2)
    st = _from_model(c, np.where(good[None, :], load, 0.0), np.where(good[None, :], rigidity, 1.0), ~good, dt)
    return st, ~good[::2]


@dataclass(frozen=True, eq=False)
class _Windows:
    """Per-period sums of the active lines (every active line was active in every period so far):
    ``sum F e^(-i h theta)`` (K + 1, lines) of the force over ``x0`` and ``sum e e^(-i theta)`` (lines,)
    of the base motion over ``x0``; a window is ``window`` consecutive periods."""

    force: list
    base: list

    def last(self, n: int, skip: int = 0):
        """Sums over the ``n`` periods before the last ``skip``."""
        end = len(self.force) - skip
        return sum(self.force[end - n:end]), sum(self.base[end - n:end])

    def take(self, keep) -> "_Windows":
        return _Windows([v[:, keep] for v in self.force], [v[keep] for v in self.base])


def _integrate(model: CableModel, damper, p, n_sets, f, amp, s: _Settings) -> dict:
    """Integrate every line of the valid sets; the fields of :class:`TimeResponse` as arrays (lines,)."""
    c = _setup(model, p, n_sets, f, amp, s)
    lines = c.x0.size
    q = c.eta.shape[0]
    dt = 2 * np.pi / s.steps
    k_h = s.n_harmonics
    st, ramped = _start(model, damper, p, n_sets, f, amp, c, s)
    first = s.first_window if ramped.any() else s.first_window - int(math.ceil(s.ramp))
    phasor = np.exp(-1j * np.outer(np.arange(k_h + 1), np.arange(s.steps) * dt))  # (K + 1, steps)
    out = dict(harmonics=np.full((lines, k_h), np.nan + 0j), f_uu=np.full(lines, np.nan + 0j),
               distortion=np.full(lines, np.nan), settled=np.zeros(lines, dtype=bool), change=np.full(lines, np.nan),
               converged=np.ones(lines, dtype=bool), periods=np.zeros(lines, dtype=int),
               iterations=np.zeros(lines, dtype=int))
    active = np.arange(lines)  # global index of each active line
    win = _Windows([], [])
    series = [] if s.keep_series else None
    period = 0
    while active.size:
        acc = np.zeros((k_h + 1, active.size), dtype=complex)
        acc_base = np.zeros(active.size, dtype=complex)
        block = np.empty((s.steps, 2, active.size)) if series is not None else None
        failed = np.zeros(active.size, dtype=bool)
        iterations = np.zeros(active.size, dtype=int)
        ramp_here = ramped[active]
        for m in range(s.steps):
            theta = (period * s.steps + m + 1) * dt
            env, d_env, dd_env = _envelope(theta, s.ramp)
            cos, sin = math.cos(theta), math.sin(theta)
            # e = x_b / x0 and its second derivative per line (cos theta where not ramped)
            e = np.where(ramp_here, env * cos, cos)
            edd = np.where(ramp_here, dd_env * cos - 2 * d_env * sin - env * cos, -cos)
            st, ok, it = _step(c, st, c.nc * np.repeat(e, 2)[None, :], dt, s.newton_tol, s.max_iter)
            failed |= ~ok.reshape(-1, 2).all(axis=1)
            iterations = np.maximum(iterations, it)
            force = (c.fab[0] * st.p[0] + c.fab[1] * st.p[1]).reshape(-1, 2).sum(axis=1) - c.inertia * edd  # / x0
            j = (m + 1) % s.steps  # this sample's phase within the period
            acc += np.outer(phasor[:, j], force)
            acc_base += e * phasor[1, j]
            if block is not None:
                block[m] = (e * c.x0, force * c.x0)
        period += 1
        win.force.append(acc)
        win.base.append(acc_base)
        out["iterations"][active] = np.maximum(out["iterations"][active], iterations)
        if series is not None:
            series.append((active.copy(), block))
        stop = failed.copy()
        if period >= min(first, s.max_periods):
            n_w = s.window * s.steps
            (last, base), (prev, _) = win.last(s.window), win.last(s.window, skip=s.window)
            f1 = 2 * last[1] / n_w
            change = np.abs(f1 - 2 * prev[1] / n_w) / np.maximum(np.abs(f1), _TINY)
            settled = change < s.tol
            stop |= settled | (period >= s.max_periods)
            idx = active[stop]
            fh = 2 * last[1:, stop] / n_w * c.x0[stop]  # [N]
            out["harmonics"][idx] = fh.T
            out["f_uu"][idx] = fh[0] / (2 * base[stop] / n_w * c.x0[stop])  # over the base motion's first harmonic
            out["distortion"][idx] = np.sqrt((np.abs(fh[1:]) ** 2).sum(axis=0)) / np.abs(fh[0])
            out["settled"][idx] = settled[stop] & ~failed[stop]
            out["change"][idx] = change[stop]
        if stop.any():
            bad = active[failed]
            out["converged"][bad] = False
            for k in ("harmonics", "f_uu", "distortion", "change"):
                out[k][bad] = np.nan
            out["periods"][active[stop]] = period
            keep = np.flatnonzero(~stop)
            active = active[keep]
            if active.size:
                c, st, win = c.take(keep), st.take(keep, q), win.take(keep)
    if series is not None:
        out["series"] = _assemble(series, lines, s.steps, dt)
    return out


def _assemble(series, lines, steps, dt):
    """The samples (theta, x_b, F) of every line after each step, NaN after the line stopped."""
    n = len(series) * steps
    base, force = np.full((lines, n), np.nan), np.full((lines, n), np.nan)
    for j, (idx, block) in enumerate(series):
        base[idx, j * steps:(j + 1) * steps] = block[:, 0].T
        force[idx, j * steps:(j + 1) * steps] = block[:, 1].T
    return np.arange(1, n + 1) * dt, base, force


def time_response(model: CableModel, damper: Damper, freq_hz, amplitude_mm_pp, *,
                  steps_per_period: int = DEFAULT_STEPS_PER_PERIOD, ramp: float = 8.0, settle: int = 8,
                  window: int = 4, tol: float = 1e-5, max_periods: int = 600, n_harmonics: int = 9,
                  newton_tol: float = 1e-10, max_iter: int = 40, prewarp: bool = True, resolution: float = 1.0,
                  start: str = "rest", keep_series: bool = False, **params) -> TimeResponse:
    """The cable's response to a base sine ramped up, settled and measured over whole periods.

    Parameters
    ----------
    model : CableModel
        The fast cable model (its law, sections and zone sections); not ElementCableModel.
    damper : Damper
        Nominal geometry (every geometry parameter not given).
    freq_hz : array_like, shape (n_freq,)
        Frequency lines [Hz]; each integrated on its own (no sweep continuation).
    amplitude_mm_pp : float or array_like, shape (n_freq,) or (n_sets, n_freq)
        Base amplitude per line [mm peak-to-peak].
    steps_per_period : int
        Time steps per period (every line).
    ramp : float
        Periods of the C2 ramp of the base amplitude from 0 (0: a sudden start).
    settle : int
        Periods after the ramp before the first window.
    window : int
        Whole periods of each harmonic analysis.
    tol : float
        Settled when the first harmonic changed by less than this (relative) between the last two windows.
    max_periods : int
        A line stops here, settled or not.
    n_harmonics : int
        Harmonics of the force returned (< steps_per_period / 2).
    newton_tol : float
        Relative tolerance of each step's Newton solve (on the loads and on the curvatures).
    max_iter : int
        Newton iterations per step before the line is flagged as failed.
    prewarp : bool
        Scale the inertia and the material loss so the first harmonic of a linear cable is exact
        (module docstring); False: plain Newmark (frequency error ``(2 pi / steps)^2 / 12``).
    resolution : float
        Cell density of the Jenkins populations of Masing laws (:func:`sbcal.model.laws.steppers.jenkins_population`).
    start : {"rest", "model"}
        ``"rest"``: the bench's way, from rest with the ramp. ``"model"``: on the first-harmonic model's
        steady state (:meth:`CableModel.state`) with the base at full amplitude from ``theta = 0``, the
        law's memory put on its loop by a pre-roll (:func:`_from_model`): the transient left is the
        model's error, not the whole response (lines where the model did not converge start at rest).
        Much faster to settle where the cable is lightly damped (micro-slip); no ``ramp`` then.
    keep_series : bool
        Return the samples (theta, base motion, force) of every line.
    **params : float or array_like, shape (n_sets,)
        As :meth:`CableModel.state`: ``EJ_min``, ``beta_material``, the law's, ``rocking_rad_per_m``,
        geometry overrides.

    Returns
    -------
    TimeResponse
        NaN for sets outside the law's domain (or with ``EJ_min <= 0``).
    """
    if not isinstance(model, CableModel):
        raise InputError(f"model: expected a CableModel, got {type(model).__name__}")
    s = _settings(steps_per_period, ramp, settle, window, tol, max_periods, n_harmonics, newton_tol, max_iter,
                  prewarp, resolution, keep_series, start)
    p, n_sets, in_law = model._parameters(damper, params)
    f, amp, _ = checked_grid(freq_hz, amplitude_mm_pp, None, per_set=True)
    if amp.ndim == 2 and amp.shape[0] > 1:
        if n_sets not in (1, amp.shape[0]):
            raise InputError(f"amplitude_mm_pp: {amp.shape[0]} rows (sets) where the parameters have {n_sets}")
        n_sets = amp.shape[0]
    valid = model._in_domain(p, n_sets, in_law)
    keep, sub = model._valid_subset(p, n_sets, valid)
    nf = f.size
    shape = (n_sets, nf)
    res = dict(f_uu=np.full(shape, np.nan + 0j), harmonics=np.full(shape + (s.n_harmonics,), np.nan + 0j),
               distortion=np.full(shape, np.nan), settled=np.zeros(shape, dtype=bool), change=np.full(shape, np.nan),
               converged=np.zeros(shape, dtype=bool), periods=np.zeros(shape, dtype=int),
               iterations=np.zeros(shape, dtype=int))
    theta = base = force = None
    if keep.size:
        a = amp[keep] if (amp.ndim == 2 and amp.shape[0] == n_sets > 1) else amp
        out = _integrate(model, damper, sub, keep.size, f, a, s)
        for k in res:
            res[k][keep] = out[k].reshape((keep.size, nf) + res[k].shape[2:])
        if s.keep_series:
            theta, b, fo = out["series"]
            base, force = np.full(shape + theta.shape, np.nan), np.full(shape + theta.shape, np.nan)
            base[keep], force[keep] = b.reshape(keep.size, nf, -1), fo.reshape(keep.size, nf, -1)
    return TimeResponse(**res, steps_per_period=s.steps, window=s.window, theta=theta, base=base, force=force)
