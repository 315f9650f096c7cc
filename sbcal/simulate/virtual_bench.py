"""The virtual shaker bench: recordings from physics richer than the calibration model.

A real bench measures a real damper; to prove the tool on data whose physics is known but hidden
from the fit, this module plays the bench (``docs/virtual_bench.md``). The damper is the 6-DOF model
of :mod:`sbcal.model.fem` with each arm's rigidity and loss factor free to depend on the line (per-arm,
per-line values through :func:`sbcal.model.fem.arm_impedance`), plus switchable effects the calibration
model leaves out (``docs/virtual_bench.md``, "Effects"; the catalogue of ``docs/diagnose.md``):

==============================  =============================  ==========================================
id                              VALUE                          equation
==============================  =============================  ==========================================
``strand_slip``                 ``chi_median`` [1/m] or        the distributed cable with a hysteresis law
                                ``key:value,...`` (SlipLaw)    (below)
``fixture_mass``                ``m_f`` [kg]                   ``f_meas = f - omega^2 m_f``
``sensor_delay``                ``tau`` [s]                    ``f_meas = f exp(-i omega tau)``
``viscous_damping``             ``f_ref`` [Hz]                 ``beta_e(omega) = beta_e f / f_ref``
``asymmetric_damping``          ``d`` [1]                      ``beta1 = beta + d/2, beta2 = beta - d/2``
``base_rocking``                ``r`` [rad/m]                  ``phic = r xc``: ``f = H00 + r H01``
``frequency_dependent_stiffness`` ``k`` [1]                    ``EJ(omega) = EJ (1 + k ln(f / 10 Hz))``
==============================  =============================  ==========================================

and, outside the catalogue (for an "unexplained misfit" check), ``fixture_resonance``
(:class:`FixtureResonance`); their descriptions and parsing are :mod:`sbcal.simulate.effects`'s.
Bench artefacts on top: run-to-run scatter of the damper (re-clamping),
measurement noise largest at 4-15 Hz, occasional outlier runs, and the thesis's test plan with test
``2-1``'s amplitude step at 10 Hz. Every random draw comes from the caller's
:class:`numpy.random.Generator`: the same seed gives the same frame, byte for byte once written.

Strand slip (:class:`SlipLaw`): the cable is the distributed model of :mod:`sbcal.model.cable` (each arm
split into Hermite elements, each with ``EJ*_e = EJ_min (1 + i beta_material) + EJ_slip*(chi_e)``
from a hysteresis law of :mod:`sbcal.model.laws`: by default the bench's own lognormal Iwan law,
outside both fitted families), driven at ``X0 = amplitude_mm_pp / 2 * 1e-3`` m and followed up the
frequency grid as a stepped-sine controller does (``docs/virtual_bench.md``, ``docs/cable.md``).
With ``time_domain`` (``strand_slip=...,time:1``) the cable is instead the fast model
(:class:`sbcal.model.cable.CableModel`, :data:`BENCH_SECTIONS` sections per arm) integrated in time from
rest, and the reading is the first harmonic of its distorted force over whole periods once settled, as
a shaker's acquisition measures it (:func:`sbcal.model.cable_time.time_response`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from ..core.errors import InputError
from ..data.bench import BENCH_COLUMNS, curves_to_frame
from ..data.labels import parse_label
from ..model.cable import CableModel
from ..model.cable_element import ElementCableModel
from ..model.cable_time import time_response
from ..model.cable_zones import CableZone
from ..model.damper import Damper
from ..model.fem import STANDARD_GRID_HZ, arm_impedance
from ..model.laws import law_for
from .effects import (BENCH_ELEMENTS, BENCH_HARMONICS, BENCH_SECTIONS, BENCH_ZONE_SECTIONS, EFFECTS, EXTRA_EFFECTS,
                      TIME_REFUSED, FixtureResonance, SlipLaw, check_effects, check_params, parse_effect)


__all__ = [
    "EFFECTS",
    "EXTRA_EFFECTS",
    "DEFAULT_TESTS",
    "BENCH_ELEMENTS",
    "BENCH_SECTIONS",
    "BENCH_ZONE_SECTIONS",
    "RAMP_PERIODS",
    "SlipLaw",
    "CableZone",
    "FixtureResonance",
    "BenchConfig",
    "parse_effect",
    "test_amplitude",
    "response",
    "slip_law_params",
    "integrate_slip",
    "record",
    "reclamping",
    "table_and_channels",
    "with_defaults",
]

DEFAULT_TESTS = ("0.1-0.1", "0.2-0.2", "0.3-0.3", "0.4-0.4", "0.5-0.5", "1-1", "2-2", "2-1")
"""The thesis's test plan (Table 2.1) on a dry cable; ``1-1-oiled`` is another cable state (another config)."""

STEP_HZ = 10.0
"""A two-amplitude test ``A-B`` runs at A mm p-p up to and including this line, at B above it."""

_F_REF_STIFFNESS_HZ = 10.0  # frequency_dependent_stiffness: EJ(10 Hz) = EJ

RAMP_PERIODS = 8.0
"""Periods over which the time-domain bench ramps the base amplitude up from rest at every line (its C2 quintic:
:func:`sbcal.model.cable_time.time_response`'s ``ramp``)."""



# --- configuration -----------------------------------------------------------------------------

@dataclass(frozen=True)
class BenchConfig:
    """What the virtual bench runs: the damper's concealed physics and the bench's artefacts.

    Attributes
    ----------
    params : dict
        Model parameters of :data:`sbcal.model.fem.PARAMETER_NAMES` (not ``q1..q5``: a frequency-dependent
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
        slip law's curvature scale. Drawn once per run, so correlated across all its lines.
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
        Convergence tolerance of the strand-slip fixed point (``max |ln T(chi) - ln chi|`` over the
        elements, :class:`sbcal.model.cable_element.ElementCableModel`); not used in the time domain
        (:attr:`SlipLaw.time_domain`: :func:`sbcal.model.cable_time.time_response`'s settling test).
    slip_max_iter : int
        Newton budget per pass of the fixed point (InputError if a line does not converge); the same.
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
    slip_tol: float = 1e-9
    slip_max_iter: int = 30

    def __post_init__(self):
        object.__setattr__(self, "params", check_params(self.params))
        object.__setattr__(self, "effects", check_effects(dict(self.effects)))
        _check_time_domain(self.params, self.effects)
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

def test_amplitude(label: str, freq_hz) -> np.ndarray:
    """Commanded amplitude per line of a test [mm p-p].

    ``"A-B"`` (optionally with a suffix, ``"1-1-oiled"``) runs at A mm p-p for ``f <= 10 Hz``
    (:data:`STEP_HZ`) and B above: ``"0.5-0.5"`` is constant, ``"2-1"`` steps from 2 to 1 mm.

    Returns
    -------
    ndarray, shape (n_freq,)
    """
    p = parse_label(label)
    if not p or p.below_mm_pp <= 0 or p.above_mm_pp <= 0:
        raise InputError(f"test {label!r}: expected A-B[-suffix] with amplitudes A, B > 0 in mm p-p (e.g. 0.5-0.5, 2-1)")
    f = np.asarray(freq_hz, dtype=float)
    return np.where(f <= STEP_HZ, p.below_mm_pp, p.above_mm_pp)
test_amplitude.__test__ = False  # not a pytest test


# --- the noise-free physics --------------------------------------------------------------------

def with_defaults(damper: Damper, params: dict) -> dict:
    """The bench's model parameters with their defaults: ``EJ`` = 0.1 ``ej_static``, ``beta`` = 0.3."""
    p = dict(params)
    p.setdefault("EJ", 0.1 * damper.ej_static)
    p.setdefault("beta", 0.3)
    return p


def response(damper: Damper, freq_hz, amplitude_mm_pp, params: dict, effects: dict, *, ej_scale=1.0,
             chi0_scale=1.0, tol: float = 1e-9, max_iter: int = 30) -> np.ndarray:
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
        Per-set factors on the cable's rigidity (``EJ``, and ``delta_EJ`` with strand slip) and on
        the slip law's curvature scale: the run-to-run scatter. A zoned cable's zones get the same:
        their rigidities follow the scaled ``EJ`` and ``delta_EJ`` through their ratios, and their own
        (fixed) values in N m^2 are times ``ej_scale``, in 1/m times ``chi0_scale``.
    tol, max_iter : float, int
        The strand-slip fixed point's tolerance (on ``ln chi``) and Newton budget per pass
        (:class:`sbcal.model.cable_element.ElementCableModel`); a line that does not converge is an InputError.
        Not used by the time-domain strand slip (:func:`integrate_slip`: a line that does not settle or
        whose time steps fail is an InputError).

    Returns
    -------
    ndarray of complex, shape (n_sets, n_freq)
        ``f_meas`` [N/m].
    """
    effects = check_effects(dict(effects))
    p = with_defaults(damper, check_params(params))
    _check_time_domain(p, effects)
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
        slip = effects["strand_slip"]
        law = law_for(slip.law)
        scale = ej_scale[:, 0]
        lp = slip_law_params(slip, damper, col["EJ"][:, 0], scale, chi0_scale)
        if slip.time_domain:  # no frequency factor or per-arm loss here: _check_time_domain refused them
            r = integrate_slip(damper, f, amplitude_mm_pp, slip, lp, ej_min=(col["EJ"] * ej_scale)[:, 0],
                               beta=col["beta"][:, 0], rocking=rocking, geometry=geometry)
            return table_and_channels(r.f_uu, omega, effects)
        ej = col["EJ"] * ej_scale * factor
        linear = np.stack(np.broadcast_arrays(ej * (1 + 1j * b1), ej * (1 + 1j * b2)), axis=-1)
        model = ElementCableModel(law, n_elements=int(slip.elements), tol=tol, max_iter=max_iter, zones=slip.zones)
        lp = {k: (np.asarray(v, dtype=float) if np.ndim(v) == 0 else np.asarray(v, dtype=float).reshape(-1))
              for k, v in lp.items()}
        if slip.zones:  # the same scatter on the zones' own values (those taken from the middle follow it)
            lp["zone_scale"] = (scale, np.asarray(chi0_scale, dtype=float).reshape(-1))
        state = model.state(damper, f, amplitude_mm_pp, linear_rigidity=linear, rocking_rad_per_m=rocking,
                            **lp, **geometry)
        if not state.converged.all():
            i, k = np.argwhere(~state.converged)[0]
            raise InputError(f"strand_slip: no convergence in {max_iter} iterations at {f[k]:g} Hz "
                             f"(residual {state.residual[i, k]:.2g})")
        fm = state.f_uu
    else:
        e1 = e2 = col["EJ"] * ej_scale * factor
        H = arm_impedance(damper, f, ej1=e1, ej2=e2, beta1=b1, beta2=b2, **geometry)
        fm = H[..., 0, 0] + rocking * H[..., 0, 1] if rocking else H[..., 0, 0]
    return table_and_channels(fm, omega, effects)


def table_and_channels(fm, omega, effects: dict) -> np.ndarray:
    """The damper's ``f`` (n_sets, n_freq) [N/m] as read through the table and the channels: fixture
    mass, fixture resonance, sensor delay (``omega`` [rad/s], shape (1, n_freq))."""
    if "fixture_mass" in effects:
        fm = fm - omega**2 * effects["fixture_mass"]
    if "fixture_resonance" in effects:
        fr = effects["fixture_resonance"]
        wr2 = (2 * np.pi * fr.freq_hz) ** 2
        fm = fm - fr.mass_kg * omega**4 / (wr2 * (1 + 1j * fr.eta) - omega**2)
    if "sensor_delay" in effects:
        fm = fm * np.exp(-1j * omega * effects["sensor_delay"])
    return fm


def _check_time_domain(params: dict, effects: dict):
    """Refuse what the time-domain strand slip cannot carry (:data:`TIME_REFUSED`): one line naming it."""
    slip = effects.get("strand_slip")
    if slip is None or not slip.time_domain:
        return
    for name, what in TIME_REFUSED.items():
        if name in effects or name in params:
            kind = "effect" if name in effects else "parameter"
            raise InputError(f"{kind} {name}: the time-domain strand slip (time:1) does not take it "
                             f"(its cable has one constant loss factor and EJ for both arms, not {what})")


def slip_law_params(slip: SlipLaw, damper: Damper, ej, ej_scale, chi0_scale) -> dict:
    """The strand slip law's parameters for parameter sets: the law's own (:meth:`SlipLaw.law_params`) with the
    re-clamping scatter, which scales the cable's rigidity as a whole (``EJ_min`` and ``delta_EJ`` together) and
    the law's curvature scale.

    Parameters
    ----------
    slip : SlipLaw
    damper : Damper
    ej : ndarray, shape (n_sets,)
        The full-slip rigidity ``EJ`` [N m^2] before the scatter.
    ej_scale, chi0_scale : float or ndarray, shape (n_sets,)
        Scatter factors (:func:`response`).

    Raises
    ------
    InputError
        ``EJ`` at or above ``ej_static`` without a ``delta_EJ``.
    """
    lp = slip.law_params(ej, damper.ej_static)
    if np.any(np.asarray(lp["delta_EJ"]) <= 0):
        raise InputError(f"strand_slip: EJ (the full-slip rigidity) must be below ej_static = {damper.ej_static:g} N m^2 "
                         "(or give delta_EJ)")
    lp["delta_EJ"] = np.asarray(lp["delta_EJ"], dtype=float) * np.asarray(ej_scale, dtype=float).reshape(-1)
    lp[slip.scale_name] = lp[slip.scale_name] * np.asarray(chi0_scale, dtype=float).reshape(-1)
    return lp


def integrate_slip(damper: Damper, freq_hz, amplitude_mm_pp, slip: SlipLaw, law_params: dict, *, ej_min, beta,
                   rocking, geometry: dict, keep_series: bool = False, label: str | None = None):
    """The time-domain strand slip: the fast cable integrated from rest, as a shaker records it.

    Every parameter set and line is one integration of :func:`sbcal.model.cable_time.time_response` (all
    in one call: the runs of a test are its parameter sets) on :class:`sbcal.model.cable.CableModel` with
    :data:`BENCH_SECTIONS` sections per arm (:data:`BENCH_ZONE_SECTIONS` per zone of a zoned law). The CSV
    bench takes its first harmonics (:func:`response`), the raw bench its samples
    (:mod:`sbcal.simulate.raw_bench`).

    Parameters
    ----------
    damper : Damper
    freq_hz : ndarray, shape (n_freq,)
        Lines [Hz].
    amplitude_mm_pp : float or array_like, shape (n_freq,)
        Base amplitude per line [mm p-p].
    slip : SlipLaw
        The law (its ``steps_per_period``).
    law_params : dict
        The law's parameters with the re-clamping scatter applied (:func:`slip_law_params`), scalars or shape
        (n_sets,).
    ej_min, beta : ndarray, shape (n_sets,) or (1,)
        Full-slip rigidity [N m^2] (scatter applied) and material loss factor [1].
    rocking : float
        Base rocking [rad/m].
    geometry : dict
        Geometry overrides of :data:`sbcal.model.damper.GEOMETRY`, scalars or shape (n_sets,).
    keep_series : bool
        Keep the samples (``time_response``'s ``keep_series``).
    label : str, optional
        What a parameter set is, for messages (default ``"parameter set i"``).

    Returns
    -------
    TimeResponse
        ``f_uu`` (n_sets, n_freq): the first harmonic of the base force over the base motion [N/m], last window.

    Raises
    ------
    InputError
        ``EJ <= 0`` or ``beta < 0``; a line that did not settle in the periods allowed or whose time steps
        failed (named: never used).
    """
    if np.any(np.asarray(ej_min) <= 0) or np.any(np.asarray(beta) < 0):
        raise InputError("strand_slip (time domain): EJ (the full-slip rigidity) must be > 0 and beta >= 0")
    model = CableModel(law_for(slip.law), sections=BENCH_SECTIONS, zone_sections=BENCH_ZONE_SECTIONS)
    r = time_response(model, damper, freq_hz, amplitude_mm_pp, steps_per_period=slip.steps_per_period,
                      ramp=RAMP_PERIODS, n_harmonics=BENCH_HARMONICS, EJ_min=ej_min, beta_material=beta, rocking_rad_per_m=rocking,
                      keep_series=keep_series, **law_params, **geometry)
    bad = ~(r.converged & r.settled)
    if bad.any():
        i, k = np.argwhere(bad)[0]
        why = ("a time step's Newton solve failed" if not r.converged[i, k] else
               f"did not settle in {r.periods[i, k]} periods (first harmonic still changing by {r.change[i, k]:.2g} "
               "per window)")
        raise InputError(f"strand_slip (time domain): the line at {freq_hz[k]:g} Hz, "
                         f"{label or f'parameter set {i}'}: {why}")
    return r


# --- the bench ---------------------------------------------------------------------------------

def _noise_profile(freq_hz, levels, corner_hz, width_hz):
    """``hi + (lo - hi) / (1 + exp((f - corner) / width))``: lo below the corner, hi above."""
    lo, hi = levels
    return hi + (lo - hi) / (1.0 + np.exp((np.asarray(freq_hz) - corner_hz) / width_hz))


def _factor(rng, rel_sd, n):
    """Lognormal factors with median 1 and log standard deviation ``rel_sd``, shape (n,)."""
    return np.exp(rel_sd * rng.standard_normal(n))


def reclamping(damper: Damper, config: BenchConfig, params: dict, rng: np.random.Generator):
    """The re-clamping scatter of ``config.runs`` runs, drawn from ``rng`` (step 1 of :func:`record`).

    Parameters
    ----------
    damper : Damper
        Supplies ``a1``, ``a2`` when ``params`` has none.
    config : BenchConfig
    params : dict
        The model parameters with their defaults (``with_defaults(damper, config.params)``).
    rng : numpy.random.Generator

    Returns
    -------
    runs : dict
        ``params`` with ``a1``, ``a2`` and the loss factors scattered, shape (runs,) each of those.
    ej_scale, chi0_scale : ndarray, shape (runs,)
        Factors on the cable's rigidity and on the slip law's curvature scale (:func:`response`).
    """
    n = int(config.runs)
    ej_scale = _factor(rng, config.ej_scatter, n)
    beta_scale = _factor(rng, config.beta_scatter, n)
    chi0_scale = _factor(rng, config.chi0_scatter, n)
    a1 = np.asarray(params.get("a1", damper.a1), dtype=float) * (1 + config.offset_scatter * rng.standard_normal(n))
    a2 = np.asarray(params.get("a2", damper.a2), dtype=float) * (1 + config.offset_scatter * rng.standard_normal(n))
    runs = dict(params, a1=a1, a2=a2)
    for name in ("beta", "beta1", "beta2"):
        if name in runs:
            runs[name] = np.asarray(runs[name], dtype=float) * beta_scale
    return runs, ej_scale, chi0_scale


def record(damper: Damper, config: BenchConfig, tests=DEFAULT_TESTS, *, rng: np.random.Generator,
           freq_hz=None) -> pd.DataFrame:
    """Run the virtual bench: ``config.runs`` runs of each test, as bench CSV rows.

    Per test, in this order (all draws from ``rng``, so a seed fixes the frame):

    1. re-clamping scatter, one draw per run (hence correlated over its lines): lognormal factors
       on EJ (and ``delta_EJ``), on the loss factors and on the slip law's curvature scale; normal factors
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
        Frequency lines [Hz] (default :data:`sbcal.model.fem.STANDARD_GRID_HZ`).

    Returns
    -------
    DataFrame
        :data:`sbcal.data.bench.BENCH_COLUMNS`, ``config.runs * n_freq`` rows per test, runs numbered
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
    p = with_defaults(damper, config.params)
    sig_mag = _noise_profile(f, config.logmag_noise, config.noise_corner_hz, config.noise_width_hz)
    sig_ph = _noise_profile(f, config.phase_noise_deg, config.noise_corner_hz, config.noise_width_hz)
    ramp = (f - f.min()) / max(f.max() - f.min(), 1e-300) - 0.5  # -0.5 .. 0.5 over the sweep
    frames = []
    for label, amp in zip(tests, amplitudes):
        runs, ej_scale, chi0_scale = reclamping(damper, config, p, rng)
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
