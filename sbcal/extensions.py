"""The catalogue of physics extensions that ``sbcal diagnose`` can add to the forward model.

Each extension is a forward-model variant with a stable id, its own parameters and prior boxes
(``priors/extensions.toml``), and a way to say what its fitted parameters mean on the bench:

============================== ====== ==========================================================
id                             scope  model (``f`` is :func:`sbcal.fem.dynamic_stiffness`)
============================== ====== ==========================================================
strand_slip                    joint  per arm and line, ``EJ_e = EJ_slip + (EJ_stick - EJ_slip) g``,
                                      ``beta_e = beta_material + beta_friction (1 - g)``,
                                      ``g = 1 / (1 + (chi / chi_slip)^k)``, ``chi`` the arm's rms
                                      curvature amplitude (self-consistent); one parameter set for
                                      every amplitude of a cable
fixture_mass                   test   ``f - omega^2 m_f``
sensor_delay                   test   ``f exp(-i omega tau)``
viscous_damping                test   loss factor ``beta + beta_viscous f / 10 Hz``
asymmetric_damping             test   ``beta1 != beta2``
base_rocking                   test   ``H[0,0] + r H[0,1]`` (the clamp rotates by ``r xc``)
frequency_dependent_stiffness  test   ``EJ(f) = EJ (f / 10 Hz)^s``
============================== ====== ==========================================================

The strand-slip law here is a rational (Ramberg-Osgood-like) softening of the arm's rms curvature
with an independent friction loss: deliberately not the virtual bench's tanh law evaluated at Gauss
points along the arm (``docs/virtual_bench.md``), so a detection on the bench's data is not a fit of
the simulator by itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .damper import Damper
from .fem import arm_impedance, arm_kernel, dynamic_stiffness

__all__ = ["Extension", "EXTENSIONS", "SlipModel", "model_for"]

F_REF_HZ = 10.0
"""Reference frequency of ``viscous_damping`` and ``frequency_dependent_stiffness`` [Hz]."""

_SLIP_ITERATIONS = 12  # regula-falsi steps of the strand-slip fixed point (|gap| < 1e-7 on the bundled data)
_GEOMETRY = ("a1", "a2")


@dataclass(frozen=True)
class Extension:
    """One catalogue entry.

    Attributes
    ----------
    id : str
        Stable id (the virtual bench's effect id).
    joint : bool
        True: one parameter set for all tests of a cable (the physics ties amplitudes together).
    signature : str
        The structure statistic of :func:`sbcal.diagnose.locate` that screens it in.
    what : str
        The missing physics in a bench engineer's words.
    """

    id: str
    joint: bool
    signature: str
    what: str


EXTENSIONS = {e.id: e for e in (
    Extension("strand_slip", True, "amplitude_trend",
              "the cable's wires slip at large curvature: EJ falls and friction loss rises with curvature"),
    Extension("fixture_mass", False, "magnitude_omega2",
              "a mass on the table that the empty-table calibration did not cancel"),
    Extension("sensor_delay", False, "phase_linear",
              "a time lag between the force and the displacement channels"),
    Extension("viscous_damping", False, "structured",
              "part of the cable's damping is viscous: the loss factor grows with frequency"),
    Extension("asymmetric_damping", False, "structured",
              "the two arms damp differently"),
    Extension("base_rocking", False, "structured",
              "the table rotates as it moves up and down"),
    Extension("frequency_dependent_stiffness", False, "structured",
              "the cable stiffens (or softens) with frequency: a viscoelastic cable"),
)}
"""The catalogue, by id, in the order of ``shared/notes/model.md``."""


def _base(params: dict) -> dict:
    """The parameters :func:`sbcal.fem.dynamic_stiffness` knows, as (n, 1) columns where per line."""
    return {k: v for k, v in params.items() if k in ("EJ", "beta", "beta1", "beta2") + _GEOMETRY}


def _col(v):
    return np.asarray(v, dtype=float).reshape(-1, 1)


def _fixture_mass(damper: Damper, freq_hz, *, fixture_mass_kg, **params):
    omega = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    return dynamic_stiffness(damper, freq_hz, **_base(params)) - omega**2 * _col(fixture_mass_kg)


def _sensor_delay(damper: Damper, freq_hz, *, delay_s, **params):
    omega = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    return dynamic_stiffness(damper, freq_hz, **_base(params)) * np.exp(-1j * omega * _col(delay_s))


def _per_line(damper: Damper, freq_hz, ej, beta1, beta2, params):
    geometry = {k: params[k] for k in _GEOMETRY if k in params}
    return arm_impedance(damper, freq_hz, ej1=ej, ej2=ej, beta1=beta1, beta2=beta2, **geometry)


def _viscous_damping(damper: Damper, freq_hz, *, beta_viscous, EJ, beta, **params):
    f = np.asarray(freq_hz, dtype=float)
    b = _col(beta) + _col(beta_viscous) * f / F_REF_HZ
    return _per_line(damper, f, _col(EJ), b, b, params)[..., 0, 0]


def _asymmetric_damping(damper: Damper, freq_hz, **params):
    return dynamic_stiffness(damper, freq_hz, **_base(params))


def _base_rocking(damper: Damper, freq_hz, *, rocking_rad_per_m, EJ, beta, **params):
    H = _per_line(damper, freq_hz, _col(EJ), _col(beta), _col(beta), params)
    return H[..., 0, 0] + _col(rocking_rad_per_m) * H[..., 0, 1]


def _frequency_dependent_stiffness(damper: Damper, freq_hz, *, ej_exponent, EJ, beta, **params):
    f = np.asarray(freq_hz, dtype=float)
    ej = _col(EJ) * (f / F_REF_HZ) ** _col(ej_exponent)
    return _per_line(damper, f, ej, _col(beta), _col(beta), params)[..., 0, 0]


@dataclass(frozen=True)
class SlipModel:
    """The strand-slip forward model at given commanded amplitudes (picklable, for the sampler).

    ``SlipModel(amplitude_mm_pp)(damper, freq_hz, **params) -> complex (n, n_freq)``, parameters
    ``EJ_slip, EJ_stick`` [N m^2], ``chi_slip`` [1/m], ``slip_exponent``, ``beta_material``,
    ``beta_friction`` and optionally ``a1, a2`` [m], each scalar or (n,).

    Per arm e and line, with the clamp driven at ``X0 = amplitude / 2`` and the arm's rms curvature
    amplitude over its length ``chi_e`` (the Hermite element's curvature is linear along it)::

        g = 1 / (1 + (chi_e / chi_slip)^k)
        EJ_e = EJ_slip + (EJ_stick - EJ_slip) g,   beta_e = beta_material + beta_friction (1 - g)

    solved self-consistently (the curvature depends on ``EJ_e``) for the stick fraction ``g`` in
    [0, 1] by a bracketing root finder (12 Illinois steps), a fixed number of steps so that the model is a deterministic
    function of its parameters. ``EJ_slip >= EJ_stick`` is outside the model (NaN).

    Attributes
    ----------
    amplitude_mm_pp : ndarray, shape (n_freq,)
        Commanded base amplitude per line [mm peak-to-peak].
    """

    amplitude_mm_pp: np.ndarray

    def state(self, damper: Damper, freq_hz, *, EJ_slip, EJ_stick, chi_slip, slip_exponent, beta_material,
              beta_friction, **params):
        """Per-arm rigidity and loss factor ``(ej, beta)``, each (2 arms, n, n_freq), and the rms curvature."""
        f = np.asarray(freq_hz, dtype=float)
        omega = 2 * np.pi * f[None, :]
        x0 = np.broadcast_to(np.asarray(self.amplitude_mm_pp, dtype=float), f.shape)[None, :] / 2 * 1e-3
        geometry = {k: params[k] for k in _GEOMETRY if k in params}
        kernel = arm_kernel(damper, **geometry)
        lo, hi, c0, k = (_col(v)[None] for v in (EJ_slip, EJ_stick, chi_slip, slip_exponent))
        bm, bf = _col(beta_material)[None], _col(beta_friction)[None]
        n = max(lo.shape[1], hi.shape[1], c0.shape[1], k.shape[1], bm.shape[1], bf.shape[1],
                *(np.size(v) for v in geometry.values()))
        shape = (2, n, f.size)

        def gap(g):
            """``g - G(g)``: the stick fraction in, minus the one the resulting curvature gives."""
            ej, beta = lo + (hi - lo) * g, bm + bf * (1 - g)
            chi = kernel.curvatures(omega, ej * (1 + 1j * beta), x0, 0.0)  # (n, F, arm, end)
            a, b = chi[..., 0], chi[..., 1]
            rms = np.sqrt(np.maximum((np.abs(a)**2 + np.abs(b)**2 + np.real(a * np.conj(b))) / 3, 0.0))
            rms = np.moveaxis(rms, -1, 0)  # (2, n, F)
            return g - 1.0 / (1.0 + (rms / c0) ** k), rms

        # The fixed point is one scalar g in [0, 1] per arm and line, bracketed: gap(0) < 0 <= gap(1).
        # Illinois regula falsi, a fixed number of steps, so the model is a deterministic function of
        # its parameters (plain iteration converges slowly or oscillates near the resonances).
        g0, g1 = np.zeros(shape), np.ones(shape)
        h0, h1 = gap(g0)[0], gap(g1)[0]
        side = np.zeros(shape)
        for _ in range(_SLIP_ITERATIONS):
            denom = h1 - h0
            g = np.where(denom > 0, (g0 * h1 - g1 * h0) / np.where(denom > 0, denom, 1.0), g1)
            h, rms = gap(g)
            left = h < 0
            g0, h0 = np.where(left, g, g0), np.where(left, h, h0)
            g1, h1 = np.where(left, g1, g), np.where(left, h1, h)
            # Illinois: the end kept twice in a row has its value halved (no one-sided stall)
            h1 = np.where(left & (side == 1), 0.5 * h1, h1)
            h0 = np.where(~left & (side == -1), 0.5 * h0, h0)
            side = np.where(left, 1, -1)
        g = np.where(np.abs(h0) < np.abs(h1), g0, g1)
        ln_ej, beta = np.log(lo + (hi - lo) * g), bm + bf * (1 - g)
        return np.exp(ln_ej), beta, rms

    def __call__(self, damper: Damper, freq_hz, **params):
        ej, beta, _ = self.state(damper, freq_hz, **params)
        geometry = {k: params[k] for k in _GEOMETRY if k in params}
        out = arm_impedance(damper, freq_hz, ej1=ej[0], ej2=ej[1], beta1=beta[0], beta2=beta[1], **geometry)[..., 0, 0]
        bad = (_col(params["EJ_slip"]) >= _col(params["EJ_stick"]))
        return np.where(bad, np.nan, out)


_MODELS = {
    "baseline": dynamic_stiffness,
    "fixture_mass": _fixture_mass,
    "sensor_delay": _sensor_delay,
    "viscous_damping": _viscous_damping,
    "asymmetric_damping": _asymmetric_damping,
    "base_rocking": _base_rocking,
    "frequency_dependent_stiffness": _frequency_dependent_stiffness,
}


def model_for(effect: str, amplitude_mm_pp=None):
    """The forward model of ``"baseline"`` or a catalogue id: ``model(damper, freq_hz, **params)``.

    ``amplitude_mm_pp`` (shape (n_freq,)) is needed by ``strand_slip`` only.
    """
    if effect == "strand_slip":
        return SlipModel(np.asarray(amplitude_mm_pp, dtype=float))
    return _MODELS[effect]
