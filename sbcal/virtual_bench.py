"""The virtual shaker bench: recordings from physics richer than the calibration model.

A real bench measures a real damper; to prove the tool on data whose physics is known but hidden
from the fit, this module plays the bench (``docs/virtual_bench.md``). The damper is the 6-DOF model
of :mod:`sbcal.fem` with each arm's rigidity and loss factor free to depend on the line (per-arm,
per-line values through :func:`sbcal.fem.arm_impedance`), plus switchable effects the calibration
model leaves out (``shared/notes/model.md``, "Physics the linear model leaves out"):

==============================  =============================  ==========================================
id                              VALUE                          equation
==============================  =============================  ==========================================
``strand_slip``                 ``CHI0`` [1/m] or              per arm, per line: ``EJ_e, beta_e`` from the
                                ``key:value,...`` (SlipLaw)    curvature amplitude (fixed point, below)
``fixture_mass``                ``m_f`` [kg]                   ``f_meas = f - omega^2 m_f``
``sensor_delay``                ``tau`` [s]                    ``f_meas = f exp(-i omega tau)``
``viscous_damping``             ``f_ref`` [Hz]                 ``beta_e(omega) = beta_e f / f_ref``
``asymmetric_damping``          ``d`` [1]                      ``beta1 = beta + d/2, beta2 = beta - d/2``
``base_rocking``                ``r`` [rad/m]                  ``phic = r xc``: ``f = H00 + r H01``
``frequency_dependent_stiffness`` ``k`` [1]                    ``EJ(omega) = EJ (1 + k ln(f / 10 Hz))``
==============================  =============================  ==========================================

and, outside the catalogue (for an "unexplained misfit" check), ``fixture_resonance``
(:class:`FixtureResonance`). Bench artefacts on top: run-to-run scatter of the damper (re-clamping),
measurement noise largest at 4-15 Hz, occasional outlier runs, and the thesis's test plan with test
``2-1``'s amplitude step at 10 Hz. Every random draw comes from the caller's
:class:`numpy.random.Generator`: the same seed gives the same frame, byte for byte once written.

Strand slip (:class:`SlipLaw`): at curvature amplitude ``chi_a``, ``u = chi_a / chi0``, a length
of cable has the secant rigidity and the friction energy per cycle and unit length::

    EJ(u) = EJ_min + (EJ_max - EJ_min) S(u),      S(u) = (tanh(u^n) / u^n)^(p / n)
    D(u)  = 4 eta (EJ_max - EJ_min) chi0^2 (u - u S(u)) u^m

``n = p = eta = 1, m = 0`` is the steady-cycle Bouc-Wen/Masing equivalent linearisation of the
notes; the sharpness ``n``, decay ``p``, loss amplitude ``eta`` and loss exponent ``m`` give the
bench a law of its own. Each arm is one element, so it gets one rigidity per line: the
strain-energy-weighted secant over the element's (linear) curvature distribution, and the loss
factor dissipated energy / (2 pi peak strain energy), both by 5-point Gauss-Legendre quadrature
along the arm::

    EJ_e   = sum_k w_k EJ(u_k) chi_k^2 / sum_k w_k chi_k^2
    beta_e = beta_material + sum_k w_k D(u_k) / (pi EJ_e sum_k w_k chi_k^2)

The curvatures come from the arm's response to the clamp motion ``X_B = X0 (1, r)``,
``X0 = amplitude_mm_pp / 2 * 1e-3`` m, ``X_F = -Z_FF^-1 Z_FB X_B`` (:class:`sbcal.fem.ArmKernel`),
and depend on ``EJ_e, beta_e``: a fixed point per arm and line, solved by damped Newton along an
amplitude ramp with a bracketing fallback (:func:`solve_strand_slip`), vectorised over runs, lines
and arms.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .bench import BENCH_COLUMNS, curves_to_frame
from .damper import Damper
from .errors import InputError
from .fem import PARAMETER_NAMES, STANDARD_GRID_HZ, arm_impedance, arm_kernel

__all__ = [
    "EFFECTS",
    "EXTRA_EFFECTS",
    "DEFAULT_TESTS",
    "SlipLaw",
    "FixtureResonance",
    "BenchConfig",
    "SlipState",
    "parse_effect",
    "test_amplitude",
    "solve_strand_slip",
    "response",
    "record",
]

EFFECTS = (
    "strand_slip",
    "fixture_mass",
    "sensor_delay",
    "viscous_damping",
    "asymmetric_damping",
    "base_rocking",
    "frequency_dependent_stiffness",
)
"""Catalogue effect ids (the discrepancy catalogue of ``shared/notes/model.md``)."""

EXTRA_EFFECTS = ("fixture_resonance",)
"""Selectable effects outside the catalogue (physics no catalogue entry explains)."""

DEFAULT_TESTS = ("0.1-0.1", "0.2-0.2", "0.3-0.3", "0.4-0.4", "0.5-0.5", "1-1", "2-2", "2-1")
"""The thesis's test plan (Table 2.1) on a dry cable; ``1-1-oiled`` is another cable state (another config)."""

STEP_HZ = 10.0
"""A two-amplitude test ``A-B`` runs at A mm p-p up to and including this line, at B above it."""

_F_REF_STIFFNESS_HZ = 10.0  # frequency_dependent_stiffness: EJ(10 Hz) = EJ
_RAMP = tuple(2.0 ** np.arange(-6, 1))  # amplitude continuation of the slip solver: 1/64 .. 1
_RAMP_TOL = 1e-6  # its intermediate stages need not be tight
_FD_STEP = 1e-7  # forward-difference step of the slip solver's Jacobian (ln EJ and beta are O(1))
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(5)
_GAUSS_X = 0.5 * (_GAUSS_X + 1.0)  # on [0, 1] along the element
_GAUSS_W = 0.5 * _GAUSS_W


# --- effect descriptions -----------------------------------------------------------------------

@dataclass(frozen=True)
class SlipLaw:
    """Curvature-dependent rigidity and friction loss of the messenger cable (strand slip).

    With ``u = chi_a / chi0`` and ``Delta = EJ_max - EJ_min``, a length of cable at curvature
    amplitude ``chi_a`` has the secant rigidity and the friction energy per cycle and unit length::

        EJ(u) = EJ_min + Delta S(u),      S(u) = (tanh(u^n) / u^n)^(p / n)
        D(u)  = 4 eta Delta chi0^2 (u - u S(u)) u^m

    ``n = p = eta = 1, m = 0`` is the notes' steady-cycle Bouc-Wen/Masing law
    (``S = tanh(u) / u``, ``D = 4 Delta chi0^2 (u - tanh u)``). ``EJ_min`` is the bench's ``EJ``
    parameter (full slip); the material loss factor is its ``beta``.

    Attributes
    ----------
    chi0 : float
        Transition curvature [1/m]: the wires start to slip around ``chi_a ~ chi0``.
    ej_max : float or None
        Full-stick rigidity [N m^2] (``u -> 0``); None means the damper's ``ej_static``.
    sharpness : float
        ``n`` >= 0.5: the knee of the stick-slip transition; larger is sharper (``n -> inf``: a
        corner at ``u = 1``), smaller broader.
    decay : float
        ``p`` in (0, 1]: at large ``u``, ``EJ - EJ_min ~ Delta u^-p``. 1 is a friction plateau (the
        slipping moment saturates, Coulomb-like); below 1 a broad power-law softening (wires with
        a wide spread of slip thresholds).
    loss : float
        ``eta`` >= 0: friction loss amplitude, independent of the stiffness drop (1 ties the two
        as the Bouc-Wen law does; 0 is slip without friction loss).
    loss_exponent : float
        ``m`` in [0, 1]: in gross slip ``D ~ u^(1 + m)``; 0 is Coulomb friction (the loss factor
        falls as ``1/u``), 1 a loss proportional to the strain energy (a loss factor that levels off).
    """

    chi0: float
    ej_max: float | None = None
    sharpness: float = 1.0
    decay: float = 1.0
    loss: float = 1.0
    loss_exponent: float = 0.0

    def __post_init__(self):
        checks = (("chi0", lambda v: v > 0, "> 0"), ("sharpness", lambda v: v >= 0.5, ">= 0.5"),
                  ("decay", lambda v: 0 < v <= 1, "in (0, 1]"), ("loss", lambda v: v >= 0, ">= 0"),
                  ("loss_exponent", lambda v: 0 <= v <= 1, "in [0, 1]"))
        for name, ok, text in checks:
            v = getattr(self, name)
            if not (math.isfinite(v) and ok(v)):
                raise InputError(f"strand_slip: {name} must be finite and {text}, got {v!r}")
        if self.ej_max is not None and not (math.isfinite(self.ej_max) and self.ej_max > 0):
            raise InputError(f"strand_slip: ej_max must be finite and > 0, got {self.ej_max!r}")

    def evaluate(self, chi_amp, ej_min, ej_max, chi0=None):
        """Secant rigidity and energy loss per cycle at curvature amplitude ``chi_amp``.

        Parameters
        ----------
        chi_amp : ndarray
            Curvature amplitude ``|chi|`` [1/m].
        ej_min, ej_max : float or ndarray
            Full-slip and full-stick rigidity [N m^2] (broadcast against ``chi_amp``).
        chi0 : float or ndarray, optional
            Transition curvature overriding :attr:`chi0` (per-run scatter).

        Returns
        -------
        ej : ndarray
            ``EJ(u)`` [N m^2].
        energy : ndarray
            ``D(u)``, energy dissipated per cycle and unit length [J/m].
        """
        chi0 = self.chi0 if chi0 is None else chi0
        n, p = self.sharpness, self.decay
        u = np.asarray(chi_amp) / chi0
        un = u**n
        tiny = un < 1e-12  # S(u) -> 1: the stuck cable
        ratio = np.where(tiny, 1.0, np.tanh(un) / np.where(tiny, 1.0, un)) ** (p / n)  # S(u)
        s = u * ratio
        delta = ej_max - ej_min
        ej = ej_min + delta * ratio
        energy = 4.0 * self.loss * delta * chi0**2 * np.maximum(u - s, 0.0) * u**self.loss_exponent
        return ej, energy


@dataclass(frozen=True)
class FixtureResonance:
    """A fixture mode on the table (not in the catalogue): a mass on a spring, rigid part calibrated out.

    A modal mass ``m_r`` on a spring ``k_r = m_r omega_r^2 (1 + i eta)`` riding on the table adds
    ``-omega^2 m_r k_r / (k_r - omega^2 m_r)``; the empty-table calibration removes its rigid-body
    part ``-omega^2 m_r``, leaving a narrow, passive resonance::

        f_meas = f - m_r omega^4 / (omega_r^2 (1 + i eta) - omega^2)

    Attributes
    ----------
    freq_hz : float
        Fixture natural frequency ``omega_r / 2 pi`` [Hz].
    mass_kg : float
        Modal mass ``m_r`` [kg].
    eta : float
        The fixture's loss factor (narrow resonance: small).
    """

    freq_hz: float
    mass_kg: float = 0.05
    eta: float = 0.05

    def __post_init__(self):
        for name in ("freq_hz", "mass_kg", "eta"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"fixture_resonance: {name} must be finite and > 0, got {v!r}")


_KEYED = {
    "strand_slip": (SlipLaw, "chi0", {"chi0": "chi0", "ej_max": "ej_max", "sharpness": "sharpness", "n": "sharpness",
                                      "decay": "decay", "p": "decay",
                                      "loss": "loss", "eta": "loss", "m": "loss_exponent",
                                      "loss_exponent": "loss_exponent"}),
    "fixture_resonance": (FixtureResonance, "freq_hz", {"f": "freq_hz", "freq_hz": "freq_hz", "m": "mass_kg",
                                                        "mass_kg": "mass_kg", "eta": "eta"}),
}


def _number(spec: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise InputError(f"effect {spec!r}: {text!r} is not a number") from None
    if not math.isfinite(x):
        raise InputError(f"effect {spec!r}: value is not finite")
    return x


def parse_effect(spec: str):
    """``"NAME=VALUE"`` to ``(name, value)``, checked.

    Numeric effects take a number (units: see the module table). ``strand_slip`` and
    ``fixture_resonance`` take a number (``chi0`` [1/m], resp. ``freq_hz``) or ``key:value`` pairs
    separated by commas: ``strand_slip=chi0:0.004,ej_max:60,sharpness:2,loss:0.5``,
    ``fixture_resonance=f:23,m:0.05,eta:0.03``; they return a :class:`SlipLaw` /
    :class:`FixtureResonance`.

    Raises
    ------
    InputError
        One line: unknown effect, malformed spec, non-numeric or out-of-range value.
    """
    name, sep, value = str(spec).partition("=")
    name, value = name.strip(), value.strip()
    known = EFFECTS + EXTRA_EFFECTS
    if not sep or not value:
        raise InputError(f"effect {spec!r}: expected NAME=VALUE")
    if name not in known:
        raise InputError(f"effect {spec!r}: unknown effect {name!r}; known: {', '.join(known)}")
    if name in _KEYED:
        cls, first, keys = _KEYED[name]
        kwargs = {}
        if ":" not in value:
            kwargs[first] = _number(spec, value)
        else:
            for item in value.split(","):
                key, colon, text = item.partition(":")
                key = key.strip()
                if not colon or key not in keys:
                    raise InputError(f"effect {spec!r}: expected key:value pairs with keys {', '.join(keys)}")
                kwargs[keys[key]] = _number(spec, text)
            if first not in kwargs:
                raise InputError(f"effect {spec!r}: {first} is required")
        try:
            return name, cls(**kwargs)
        except InputError as e:
            raise InputError(f"effect {spec!r}: {str(e).removeprefix(name + ': ')}") from None
    x = _number(spec, value)
    if name in ("fixture_mass", "sensor_delay") and x < 0:
        raise InputError(f"effect {spec!r}: must be >= 0")
    if name == "viscous_damping" and x <= 0:
        raise InputError(f"effect {spec!r}: the reference frequency must be > 0 Hz")
    return name, x


def _check_params(params: dict) -> dict:
    out = dict(params)
    for name, value in out.items():
        if name not in PARAMETER_NAMES:
            raise InputError(f"unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}")
        if name.startswith("q"):
            raise InputError(f"parameter {name!r}: the bench's EJ(omega) is the frequency_dependent_stiffness effect")
        if not np.all(np.isfinite(np.asarray(value, dtype=float))):
            raise InputError(f"parameter {name!r}: value is not finite")
    return out


def _check_effects(effects: dict) -> dict:
    out = {}
    for name, value in effects.items():
        if name not in EFFECTS + EXTRA_EFFECTS:
            raise InputError(f"unknown effect {name!r}; known: {', '.join(EFFECTS + EXTRA_EFFECTS)}")
        if name in _KEYED:
            cls, first, _ = _KEYED[name]
            if not isinstance(value, cls):
                value = cls(**{first: float(value)})
        else:
            _, value = parse_effect(f"{name}={float(value)!r}")
        out[name] = value
    return out


# --- configuration -----------------------------------------------------------------------------

@dataclass(frozen=True)
class BenchConfig:
    """What the virtual bench runs: the damper's concealed physics and the bench's artefacts.

    Attributes
    ----------
    params : dict
        Model parameters of :data:`sbcal.fem.PARAMETER_NAMES` (not ``q1..q5``: a frequency-dependent
        EJ is the ``frequency_dependent_stiffness`` effect). Defaults: ``EJ = 0.1 ej_static``,
        ``beta = 0.3``; geometry from the damper. With ``strand_slip`` on, ``EJ`` is the full-slip
        ``EJ_min`` and ``beta`` the material loss factor.
    effects : dict
        Effect id -> value (see :func:`parse_effect`); read-only by convention.
    runs : int
        Runs per test.
    ej_scatter, beta_scatter, offset_scatter, chi0_scatter : float
        Re-clamping scatter of one run: relative standard deviations of a lognormal factor on EJ
        (and ``EJ_max``), on the loss factors, on ``a1`` and ``a2`` (independently), and on the
        slip curvature ``chi0``. Drawn once per run, so correlated across all its lines.
    logmag_noise : tuple of float
        Standard deviation of the measurement noise on ``ln |f|`` at low and at high frequency.
    phase_noise_deg : tuple of float
        The same for the phase [deg].
    noise_corner_hz, noise_width_hz : float
        The noise falls from its low- to its high-frequency level around ``noise_corner_hz``:
        ``sigma(f) = hi + (lo - hi) / (1 + exp((f - corner) / width))``.
    outlier_probability : float
        Chance that a run is an outlier (a bad clamping or a drifting channel).
    outlier_logmag, outlier_phase_deg : float
        Scale of an outlier's distortion: a whole-run offset of ``+-U(1, 2) * scale`` on ``ln |f|``
        and on the phase, tilted linearly over the sweep by up to the same amount.
    slip_tol : float
        Convergence tolerance of the strand-slip fixed point (max over lines of the change of
        ``ln EJ_e`` plus that of ``beta_e``).
    slip_max_iter : int
        Iteration cap of the fixed point (InputError if it is reached without convergence).
    """

    params: dict = field(default_factory=dict, hash=False)
    effects: dict = field(default_factory=dict, hash=False)
    runs: int = 24
    ej_scatter: float = 0.015
    beta_scatter: float = 0.04
    offset_scatter: float = 0.01
    chi0_scatter: float = 0.02
    logmag_noise: tuple = (0.03, 0.008)
    phase_noise_deg: tuple = (1.5, 0.4)
    noise_corner_hz: float = 15.0
    noise_width_hz: float = 2.0
    outlier_probability: float = 0.03
    outlier_logmag: float = 0.15
    outlier_phase_deg: float = 5.0
    slip_tol: float = 1e-10
    slip_max_iter: int = 15

    def __post_init__(self):
        object.__setattr__(self, "params", _check_params(self.params))
        object.__setattr__(self, "effects", _check_effects(dict(self.effects)))
        if int(self.runs) != self.runs or self.runs < 1:
            raise InputError(f"runs: expected an integer >= 1, got {self.runs!r}")
        if not 0 <= self.outlier_probability <= 1:
            raise InputError(f"outlier_probability: expected 0..1, got {self.outlier_probability!r}")
        for name in ("ej_scatter", "beta_scatter", "offset_scatter", "chi0_scatter", "outlier_logmag",
                     "outlier_phase_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name}: expected a finite value >= 0, got {v!r}")

    def ideal(self) -> "BenchConfig":
        """The same damper and effects with no scatter, no noise and no outliers."""
        return replace(self, ej_scatter=0.0, beta_scatter=0.0, offset_scatter=0.0, chi0_scatter=0.0,
                       logmag_noise=(0.0, 0.0), phase_noise_deg=(0.0, 0.0), outlier_probability=0.0)


# --- tests and amplitudes ----------------------------------------------------------------------

_LABEL = re.compile(r"^(\d+(?:\.\d+)?)-(\d+(?:\.\d+)?)(?:-[A-Za-z0-9_]+)?$")


def test_amplitude(label: str, freq_hz) -> np.ndarray:
    """Commanded amplitude per line of a test [mm p-p].

    ``"A-B"`` (optionally with a suffix, ``"1-1-oiled"``) runs at A mm p-p for ``f <= 10 Hz``
    (:data:`STEP_HZ`) and B above: ``"0.5-0.5"`` is constant, ``"2-1"`` steps from 2 to 1 mm.

    Returns
    -------
    ndarray, shape (n_freq,)
    """
    m = _LABEL.match(str(label))
    if not m or float(m.group(1)) <= 0 or float(m.group(2)) <= 0:
        raise InputError(f"test {label!r}: expected A-B[-suffix] with amplitudes A, B > 0 in mm p-p (e.g. 0.5-0.5, 2-1)")
    f = np.asarray(freq_hz, dtype=float)
    return np.where(f <= STEP_HZ, float(m.group(1)), float(m.group(2)))
test_amplitude.__test__ = False  # not a pytest test


# --- the strand-slip fixed point ---------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SlipState:
    """Converged strand-slip state, per set and line (arrays of shape (n_sets, n_freq)).

    Attributes
    ----------
    ej1, ej2 : ndarray
        Equivalent rigidity of arm 1 and arm 2 [N m^2].
    beta1, beta2 : ndarray
        Total loss factor of each arm (material + friction).
    curvature : ndarray of complex, shape (n_sets, n_freq, 2, 2)
        End curvatures ``[..., arm, end]`` at the solution [1/m] (:func:`sbcal.fem.arm_curvatures`).
    residual : ndarray
        Fixed-point residual at the returned state: ``max over arms |ln EJ_e - ln T(EJ)_e| +
        |beta_e - T(beta)_e|`` with T one more evaluation of the law.
    iterations : int
        Newton iterations, summed over the ramp's stages and the fallbacks.
    """

    ej1: np.ndarray
    ej2: np.ndarray
    beta1: np.ndarray
    beta2: np.ndarray
    curvature: np.ndarray
    residual: np.ndarray
    iterations: int

    @property
    def max_residual(self) -> float:
        """Largest residual over all sets and lines."""
        return float(np.max(self.residual))


def _slip_map(kernel, omega, law, ej, beta, ej_min, ej_max, beta_material, chi0, xc, phic):
    """One application of the law: (EJ_e, beta_e) -> curvatures -> new (EJ_e, beta_e), each (2, n, F).

    Also returns the end curvatures (n, F, 2 arms, 2 ends).
    """
    chi = kernel.curvatures(omega, ej * (1 + 1j * beta), xc, phic)
    c0, c1 = chi[..., 0], chi[..., 1]  # (n, F, 2)
    amp = np.abs(c0[..., None] + (c1 - c0)[..., None] * _GAUSS_X)  # (n, F, 2, k): linear along the element
    w = _GAUSS_W * amp**2
    ej_pt, d_pt = law.evaluate(amp, ej_min[..., None, None], ej_max[..., None, None], chi0[..., None, None])
    wsum = w.sum(-1)
    safe = wsum > 0
    denom = np.where(safe, wsum, 1.0)
    ej_new = np.where(safe, (w * ej_pt).sum(-1) / denom, ej_pt.mean(-1))  # no motion: the stuck value
    loss = np.where(safe, (_GAUSS_W * d_pt).sum(-1) / (np.pi * ej_new * denom), 0.0)
    return np.moveaxis(ej_new, -1, 0), np.moveaxis(loss, -1, 0) + beta_material, chi


def solve_strand_slip(damper: Damper, freq_hz, amplitude_mm_pp, law: SlipLaw, *, ej_min, beta1, beta2,
                      ej_max=None, chi0=None, rocking=0.0, tol: float = 1e-10, max_iter: int = 15,
                      **geometry) -> SlipState:
    """Per-arm equivalent rigidity and loss factor under strand slip: the fixed point ``z = T(z)``.

    ``T`` maps ``z = (ln EJ_e, beta_e)`` of each arm and line to the curvatures (clamp motion
    ``X0 (1, r)``) and back through the law (module docstring). The arms respond independently to
    the prescribed clamp motion and the lines are independent, so every (set, line, arm) is a
    2-unknown problem, all solved together (no loop over frequencies):

    1. an amplitude ramp from the stuck cable (``EJ_e = EJ_max``), stages 1/64, 1/32, ..., 1, each
       started from the previous stage's solution;
    2. damped Newton per stage (:func:`_newton`);
    3. where Newton stalls (the branch grown from the stuck cable folded: a softening arm jumps),
       the stiffest root of the arm's bracketed 1-D reduction (:func:`_stiffest_root`), then Newton;
    4. the residual ``|ln T_EJ - ln EJ_e| + |T_beta - beta_e|``, max over arms, at the returned
       state is below ``tol`` on every line, or an InputError names the line.

    Parameters
    ----------
    damper : Damper
    freq_hz : array_like, shape (n_freq,)
    amplitude_mm_pp : float or array_like, shape (n_freq,)
        Commanded base displacement [mm p-p]; the peak is ``X0 = amplitude / 2 * 1e-3`` m.
    law : SlipLaw
    ej_min : float or array_like, shape (n_sets or 1, n_freq or 1)
        Full-slip rigidity [N m^2].
    beta1, beta2 : float or array_like, shape (n_sets or 1, n_freq or 1)
        Material loss factor of each arm.
    ej_max : float or array_like, optional
        Full-stick rigidity (default ``law.ej_max`` or ``damper.ej_static``), same shapes.
    chi0 : float or array_like, shape (n_sets or 1, 1), optional
        Transition curvature overriding ``law.chi0`` [1/m].
    rocking : float
        Base rocking ``r`` [rad/m]: the clamp rotates by ``r xc``.
    tol, max_iter : float, int
        Convergence tolerance on the residual; Newton iteration cap per attempt.
    **geometry : float or array_like, shape (n_sets,)
        Geometry overrides (``a1``, ``a2``, ...).

    Returns
    -------
    SlipState

    Raises
    ------
    InputError
        When some line does not converge below ``tol``.
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    x0 = (np.broadcast_to(np.asarray(amplitude_mm_pp, dtype=float), f.shape) / 2 * 1e-3)[None, :]
    ej_max = (law.ej_max if law.ej_max is not None else damper.ej_static) if ej_max is None else ej_max
    chi0 = law.chi0 if chi0 is None else chi0
    n = max(np.shape(v)[0] if np.ndim(v) == 2 else 1 for v in (ej_min, ej_max, beta1, beta2, chi0))
    n = max([n] + [np.size(v) for v in geometry.values()])
    shape = (2, n, f.size)
    beta_material = np.stack(np.broadcast_arrays(*(np.broadcast_to(b, (n, f.size)) for b in (beta1, beta2))))
    ej_min, ej_max = (np.broadcast_to(np.asarray(v, dtype=float), (n, f.size)) for v in (ej_min, ej_max))
    chi0 = np.broadcast_to(np.asarray(chi0, dtype=float).reshape(-1, 1), (n, 1))

    kernel = arm_kernel(damper, **geometry)
    omega = 2 * np.pi * f[None, :]

    def residual_on(cols):
        """R = T(z) - z on the lines ``cols``, z = (ln EJ_e, beta_e) of shape (2, 2 arms, n, len(cols))."""
        fixed = (ej_min[:, cols], ej_max[:, cols], beta_material[..., cols], chi0)

        def residual(z, scale):
            ej_new, beta_new, chi = _slip_map(kernel, omega[:, cols], law, np.exp(z[0]), z[1], *fixed,
                                              scale * x0[:, cols], scale * rocking * x0[:, cols])
            return np.stack([np.log(ej_new) - z[0], beta_new - z[1]]), chi
        return residual

    residual = residual_on(slice(None))
    # Amplitude continuation from the stuck cable: each stage starts from the previous stage's
    # solution, so Newton follows the branch that grows out of the stuck state.
    z = np.stack([np.log(np.broadcast_to(ej_max, shape)), beta_material])
    iterations = 0
    for scale in _RAMP:
        stage_tol = tol if scale == 1.0 else _RAMP_TOL
        z, r, it = _newton(residual, z, scale, stage_tol, max_iter)
        iterations += it
        lost = _size(r) >= stage_tol  # (2 arms, n, F)
        if lost.any():
            # Newton stalled: that branch folded (a jump: softening with little damping) or a dip
            # of |R| trapped it. Bracket instead: the stiffest root of the arm's 1-D reduction
            # (the highest state an amplitude ramp jumping down from a fold lands on), then polish.
            # Only the lost (arm, set, line) move; converged ones keep their branch.
            cols = np.flatnonzero(lost.any(axis=(0, 1)))
            sub = residual_on(cols)
            z_sub = _stiffest_root(sub, scale, np.log(ej_min[:, cols]), np.log(ej_max[:, cols]),
                                   beta_material[..., cols])
            z_sub, _, it = _newton(sub, np.where(lost[..., cols], z_sub, z[..., cols]), scale, stage_tol, max_iter)
            iterations += it
            z[..., cols] = z_sub
            r, _ = residual(z, scale)
        norm = _size(r)
        if np.any(norm >= stage_tol):
            arm, i, k = np.unravel_index(np.argmax(norm), norm.shape)
            raise InputError(f"strand_slip: no convergence in {max_iter} iterations at {scale:g} x the amplitude "
                             f"(residual {norm.max():.2g}, arm {arm + 1}, {f[k]:g} Hz)")
    r, chi = residual(z, 1.0)  # the reported state and residual: one more application of the law
    return SlipState(ej1=np.exp(z[0, 0]), ej2=np.exp(z[0, 1]), beta1=z[1, 0], beta2=z[1, 1], curvature=chi,
                     residual=_size(r).max(axis=0), iterations=iterations)


def _illinois(fun, lo, hi, flo, fhi, ftol, max_iter=200):
    """Elementwise root of ``fun`` in ``[lo, hi]`` with ``flo >= 0 >= fhi``: the Illinois regula falsi.

    Returns the root estimate (the bracket's secant point; the midpoint where the bracket is flat).
    """
    side = np.zeros(lo.shape, dtype=int)
    x = lo.copy()
    for _ in range(max_iter):
        flat = fhi == flo
        x = np.where(flat, 0.5 * (lo + hi), (lo * fhi - hi * flo) / np.where(flat, 1.0, fhi - flo))
        fx = fun(x)
        if np.all((np.abs(fx) < ftol) | (hi - lo <= 1e-14 * (1 + np.abs(hi)))):
            break
        left = fx > 0  # root lies above x
        # Illinois: when the same end moves twice running, halve the other end's value
        flo, fhi = np.where(~left & (side == -1), 0.5 * flo, flo), np.where(left & (side == 1), 0.5 * fhi, fhi)
        lo, flo = np.where(left, x, lo), np.where(left, fx, flo)
        hi, fhi = np.where(left, hi, x), np.where(left, fhi, fx)
        side = np.where(left, 1, -1)
    return x


def _stiffest_root(residual, scale, ln_lo, ln_hi, beta_material, tol=1e-7, n_grid=16):
    """The stiffest fixed point of each arm and line, by bracketing its 1-D reduction.

    For a given ``ln EJ_e`` the loss factor solves ``h(beta) = T_beta - beta = 0`` (h >= 0 at the
    material loss, < 0 far above it: bracketed). What remains is ``g(ln EJ) = ln T_EJ - ln EJ`` with
    ``g >= 0`` at ``EJ_min`` and ``g <= 0`` at ``EJ_max`` (the law's secant lies between them): a
    grid finds its highest sign change, Illinois refines it (to ``tol``: Newton polishes it after).
    Returns z of shape (2, 2, n, F).
    """
    def beta_star(ln_ej):
        def h(b):
            return residual(np.stack([ln_ej, b]), scale)[0][1]
        lo, flo = beta_material, h(beta_material)
        hi = lo + 1.0
        fhi = h(hi)
        for _ in range(30):  # T_beta is bounded: doubling the bracket ends
            if np.all(fhi <= 0):
                break
            hi = np.where(fhi > 0, lo + 2 * (hi - lo), hi)
            fhi = h(hi)
        return np.where(flo <= 0, lo, _illinois(h, lo, hi, np.maximum(flo, 0.0), np.minimum(fhi, 0.0), tol / 8))

    def g(ln_ej):
        b = beta_star(ln_ej)
        return residual(np.stack([ln_ej, b]), scale)[0][0]

    ln_lo, ln_hi = np.broadcast_to(ln_lo, beta_material.shape), np.broadcast_to(ln_hi, beta_material.shape)
    grid = [ln_lo + (ln_hi - ln_lo) * k / (n_grid - 1) for k in range(n_grid)]
    values = [np.maximum(g(grid[0]), 0.0)] + [g(x) for x in grid[1:-1]] + [np.minimum(g(grid[-1]), 0.0)]
    lo, hi, flo, fhi = grid[0], grid[1], values[0], values[1]
    for k in range(n_grid - 1):  # keep the highest cell with g(lo) > 0 >= g(hi)
        cell = (values[k] > 0) & (values[k + 1] <= 0)
        lo, hi = np.where(cell, grid[k], lo), np.where(cell, grid[k + 1], hi)
        flo, fhi = np.where(cell, values[k], flo), np.where(cell, values[k + 1], fhi)
    ln_ej = _illinois(g, lo, hi, flo, fhi, tol / 8)
    return np.stack([ln_ej, beta_star(ln_ej)])


def _size(r):
    """Fixed-point residual per arm and line: ``|R_lnEJ| + |R_beta|``, shape (2 arms, n, F)."""
    return np.abs(r[0]) + np.abs(r[1])


def _newton(residual, z, scale, tol, max_iter):
    """Damped Newton on ``residual(z, scale) = 0`` for every arm and line at once; returns (z, r, iterations).

    The arms respond independently to the prescribed clamp motion and the lines are independent,
    so each (arm, line) is a 2x2 problem in ``(ln EJ_e, beta_e)``; its Jacobian is by forward
    differences (one perturbation per component serves all of them: 2 extra evaluations per step).
    A step is at most 0.5 in either component and halves (up to 8 times) where the 2-norm of R does
    not fall; an (arm, line) where no halving helps is left as it is (the caller brackets it).
    """
    r, _ = residual(z, scale)
    failed = np.zeros(r.shape[1:], dtype=bool)
    for it in range(max_iter + 1):
        active = (_size(r) >= tol) & ~failed
        if not active.any() or it == max_iter:
            break
        cols = []
        for j in range(2):
            zp = z.copy()
            zp[j] += _FD_STEP
            cols.append((residual(zp, scale)[0] - r) / _FD_STEP)
        (a, c), (b, d) = cols  # J = [[a, b], [c, d]]
        det = a * d - b * c
        singular = np.abs(det) <= 1e-12
        det = np.where(singular, 1.0, det)
        dz = np.stack([-(d * r[0] - b * r[1]) / det, -(a * r[1] - c * r[0]) / det])
        dz = np.where(singular, r, dz)  # a plain fixed-point step where the Jacobian is singular
        dz *= np.minimum(1.0, 0.5 / np.maximum(np.abs(dz).max(axis=0), 1e-300))
        merit = r[0] ** 2 + r[1] ** 2
        lam = np.ones(merit.shape)
        done = ~active
        z_next, r_next = z.copy(), r.copy()
        for _ in range(8):
            zt = z + lam * dz
            zt[1] = np.maximum(zt[1], 0.0)
            rt, _ = residual(zt, scale)
            ok = ~done & (rt[0] ** 2 + rt[1] ** 2 < (1 - 1e-4 * lam) * merit)
            z_next[:, ok], r_next[:, ok] = zt[:, ok], rt[:, ok]
            done |= ok
            if done.all():
                break
            lam = np.where(done, lam, 0.5 * lam)
        failed |= ~done
        z, r = z_next, r_next
    return z, r, it


# --- the noise-free physics --------------------------------------------------------------------

def _defaults(damper: Damper, params: dict) -> dict:
    p = dict(params)
    p.setdefault("EJ", 0.1 * damper.ej_static)
    p.setdefault("beta", 0.3)
    return p


def response(damper: Damper, freq_hz, amplitude_mm_pp, params: dict, effects: dict, *, ej_scale=1.0,
             chi0_scale=1.0, tol: float = 1e-10, max_iter: int = 15) -> np.ndarray:
    """The bench's noise-free reading ``f_meas`` for parameter sets and effects.

    Parameters
    ----------
    damper : Damper
    freq_hz : array_like, shape (n_freq,)
    amplitude_mm_pp : float or array_like, shape (n_freq,)
        Commanded amplitude per line [mm p-p] (matters only with ``strand_slip``).
    params : dict
        Model parameters (see :class:`BenchConfig`), scalars or arrays of shape (n_sets,).
    effects : dict
        Effect id -> value (as :func:`parse_effect` returns).
    ej_scale, chi0_scale : float or array_like, shape (n_sets,)
        Per-set factors on the cable's rigidity (``EJ``, and ``EJ_max`` with strand slip) and on
        the slip law's ``chi0``: the run-to-run scatter.
    tol, max_iter : float, int
        The strand-slip fixed point's tolerance and cap (:func:`solve_strand_slip`).

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq)
        ``f_meas`` [N/m].
    """
    effects = _check_effects(dict(effects))
    p = _defaults(damper, _check_params(params))
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    col = {k: np.asarray(v, dtype=float).reshape(-1, 1) for k, v in p.items()}  # (n or 1, 1)
    geometry = {k: np.asarray(v, dtype=float) for k, v in p.items() if k not in ("EJ", "beta", "beta1", "beta2")}
    omega = 2 * np.pi * f[None, :]

    # loss factors of the cable material, per arm and line
    b1, b2 = col.get("beta1", col["beta"]), col.get("beta2", col["beta"])
    if "asymmetric_damping" in effects:
        d = effects["asymmetric_damping"]
        b1, b2 = b1 + d / 2, b2 - d / 2
        if np.any(b1 < 0) or np.any(b2 < 0):
            raise InputError(f"asymmetric_damping={d:g}: makes a loss factor negative (|d|/2 > beta)")
    if "viscous_damping" in effects:
        b1, b2 = b1 * f / effects["viscous_damping"], b2 * f / effects["viscous_damping"]
    b1, b2 = (np.broadcast_to(b, np.broadcast_shapes(b.shape, (1, f.size))) for b in (b1, b2))

    # rigidity: frequency factor on the cable's moduli
    factor = np.ones((1, f.size))
    if "frequency_dependent_stiffness" in effects:
        factor = 1 + effects["frequency_dependent_stiffness"] * np.log(f / _F_REF_STIFFNESS_HZ)[None, :]
        if np.any(factor <= 0):
            raise InputError("frequency_dependent_stiffness: EJ(omega) <= 0 on this grid")
    rocking = effects.get("base_rocking", 0.0)

    ej_scale = np.asarray(ej_scale, dtype=float).reshape(-1, 1)
    if "strand_slip" in effects:
        law = effects["strand_slip"]
        ej_max = law.ej_max if law.ej_max is not None else damper.ej_static
        if np.any(col["EJ"] >= ej_max):
            raise InputError(f"strand_slip: EJ (the full-slip rigidity) must be below ej_max = {ej_max:g} N m^2")
        # re-clamping scatter scales the cable's rigidity as a whole: EJ_min and EJ_max together
        state = solve_strand_slip(damper, f, amplitude_mm_pp, law, ej_min=col["EJ"] * ej_scale * factor,
                                  ej_max=ej_max * ej_scale * factor, beta1=b1, beta2=b2,
                                  chi0=law.chi0 * np.asarray(chi0_scale, dtype=float).reshape(-1, 1),
                                  rocking=rocking, tol=tol, max_iter=max_iter, **geometry)
        e1, e2, b1, b2 = state.ej1, state.ej2, state.beta1, state.beta2
    else:
        e1 = e2 = col["EJ"] * ej_scale * factor

    H = arm_impedance(damper, f, ej1=e1, ej2=e2, beta1=b1, beta2=b2, **geometry)
    fm = H[..., 0, 0] + rocking * H[..., 0, 1] if rocking else H[..., 0, 0]
    if "fixture_mass" in effects:
        fm = fm - omega**2 * effects["fixture_mass"]
    if "fixture_resonance" in effects:
        fr = effects["fixture_resonance"]
        wr2 = (2 * np.pi * fr.freq_hz) ** 2
        fm = fm - fr.mass_kg * omega**4 / (wr2 * (1 + 1j * fr.eta) - omega**2)
    if "sensor_delay" in effects:
        fm = fm * np.exp(-1j * omega * effects["sensor_delay"])
    return fm


# --- the bench ---------------------------------------------------------------------------------

def _noise_profile(freq_hz, levels, corner_hz, width_hz):
    """``hi + (lo - hi) / (1 + exp((f - corner) / width))``: lo below the corner, hi above."""
    lo, hi = levels
    return hi + (lo - hi) / (1.0 + np.exp((np.asarray(freq_hz) - corner_hz) / width_hz))


def _factor(rng, rel_sd, n):
    """Lognormal factors with median 1 and log standard deviation ``rel_sd``, shape (n,)."""
    return np.exp(rel_sd * rng.standard_normal(n))


def record(damper: Damper, config: BenchConfig, tests=DEFAULT_TESTS, *, rng: np.random.Generator,
           freq_hz=None) -> pd.DataFrame:
    """Run the virtual bench: ``config.runs`` runs of each test, as bench CSV rows.

    Per test, in this order (all draws from ``rng``, so a seed fixes the frame):

    1. re-clamping scatter, one draw per run (hence correlated over its lines): lognormal factors
       on EJ (and ``EJ_max``), on the loss factors and on ``chi0``; normal factors
       ``1 + N(0, offset_scatter)`` on ``a1`` and on ``a2``;
    2. the noise-free reading of every run (:func:`response`) at the test's amplitude per line;
    3. measurement noise, independent per line: ``N(0, sigma(f))`` on ``ln |f|`` and on the phase,
       ``sigma`` falling from its 4-15 Hz level to its high-frequency level (:class:`BenchConfig`);
    4. outliers: each run with probability ``outlier_probability`` gets an offset of
       ``+-U(1, 2) * outlier_logmag`` on ``ln |f|`` and ``+-U(1, 2) * outlier_phase_deg`` on the phase,
       plus a linear tilt over the sweep of up to ``+-outlier_logmag`` / ``+-outlier_phase_deg``.

    The phase is written unwrapped (noise may push it just past 180 deg, as the CSV contract allows).

    Parameters
    ----------
    damper : Damper
        Supplies the geometry; its ``name`` fills the ``damper`` column.
    config : BenchConfig
    tests : sequence of str
        Test labels (:func:`test_amplitude`); default the thesis's plan :data:`DEFAULT_TESTS`.
    rng : numpy.random.Generator
    freq_hz : array_like, shape (n_freq,), optional
        Frequency lines [Hz] (default :data:`sbcal.fem.STANDARD_GRID_HZ`).

    Returns
    -------
    DataFrame
        :data:`sbcal.bench.BENCH_COLUMNS`, ``config.runs * n_freq`` rows per test, runs numbered
        from 1 within each test.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng: expected a numpy.random.Generator (np.random.default_rng(seed))")
    f = STANDARD_GRID_HZ.copy() if freq_hz is None else np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f) & (f > 0)):
        raise InputError("freq_hz: expected finite frequencies > 0 [Hz], shape (n_freq,)")
    tests = [tests] if isinstance(tests, str) else list(tests)
    if not tests:
        raise InputError("tests: at least one test label is needed")
    amplitudes = [test_amplitude(label, f) for label in tests]  # check every label before any work
    n = int(config.runs)
    p = _defaults(damper, config.params)
    sig_mag = _noise_profile(f, config.logmag_noise, config.noise_corner_hz, config.noise_width_hz)
    sig_ph = _noise_profile(f, config.phase_noise_deg, config.noise_corner_hz, config.noise_width_hz)
    ramp = (f - f.min()) / max(f.max() - f.min(), 1e-300) - 0.5  # -0.5 .. 0.5 over the sweep
    frames = []
    for label, amp in zip(tests, amplitudes):
        ej_scale = _factor(rng, config.ej_scatter, n)
        beta_scale = _factor(rng, config.beta_scatter, n)
        chi0_scale = _factor(rng, config.chi0_scatter, n)
        a1 = np.asarray(p.get("a1", damper.a1), dtype=float) * (1 + config.offset_scatter * rng.standard_normal(n))
        a2 = np.asarray(p.get("a2", damper.a2), dtype=float) * (1 + config.offset_scatter * rng.standard_normal(n))
        runs = dict(p, a1=a1, a2=a2)
        for name in ("beta", "beta1", "beta2"):
            if name in runs:
                runs[name] = np.asarray(runs[name], dtype=float) * beta_scale
        fm = response(damper, f, amp, runs, config.effects, ej_scale=ej_scale, chi0_scale=chi0_scale,
                      tol=config.slip_tol, max_iter=config.slip_max_iter)
        dmag = sig_mag * rng.standard_normal(fm.shape)  # on ln |f|
        dphase = sig_ph * rng.standard_normal(fm.shape)  # [deg]
        bad = rng.random(n) < config.outlier_probability
        sign = np.where(rng.random((2, n)) < 0.5, -1.0, 1.0)
        size = rng.uniform(1.0, 2.0, (2, n))
        tilt = rng.uniform(-1.0, 1.0, (2, n))
        for k, (delta, scale) in enumerate(((dmag, config.outlier_logmag), (dphase, config.outlier_phase_deg))):
            delta[bad] += scale * ((sign[k] * size[k])[bad, None] + tilt[k][bad, None] * ramp)
        phase = np.degrees(np.unwrap(np.angle(fm), axis=1))
        phase = np.where(phase[:, :1] <= -90.0, phase + 360.0, phase)  # the contract's (-90, 270] at the first line
        frame = curves_to_frame(damper.name, label, f, amp, fm)
        frame["stiffness_n_per_m"] = (np.abs(fm) * np.exp(dmag)).ravel()  # exp(0) = 1: no noise, exact values
        frame["phase_deg"] = (phase + dphase).ravel()
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)[list(BENCH_COLUMNS)]
