"""The catalogue of physics extensions that ``sbcal diagnose`` can add to the forward model.

Each extension is a forward-model variant with a stable id, its own parameters and prior boxes
(``priors/extensions.toml``), and a way to say what its fitted parameters mean on the bench:

============================== ====== ==========================================================
id                             scope  model (``f`` is :func:`sbcal.model.fem.dynamic_stiffness`)
============================== ====== ==========================================================
strand_slip                    joint  the distributed cable of :mod:`sbcal.model.cable`: every section of
                                      the arms follows one hysteresis law (:mod:`sbcal.model.laws`),
                                      one parameter set for every amplitude of a cable state
                                      (:mod:`sbcal.inference.cable_fit`)
fixture_mass                   test   ``f - omega^2 m_f``
sensor_delay                   test   ``f exp(-i omega tau)``
viscous_damping                test   loss factor ``beta + beta_viscous f / 10 Hz``
asymmetric_damping             test   ``beta1 != beta2``
base_rocking                   test   ``H[0,0] + r H[0,1]`` (the clamp rotates by ``r xc``)
frequency_dependent_stiffness  test   ``EJ(f) = EJ (f / 10 Hz)^s``
============================== ====== ==========================================================

Measurement-chain effects compose (:func:`model_for` with ``secondary``): ``fixture_mass`` and
``sensor_delay`` act on the measured signal and ride on any model; ``base_rocking`` adds ``r H[0,1]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .damper import Damper
from .fem import arm_impedance, dynamic_stiffness


__all__ = ["Extension", "EXTENSIONS", "CHAIN", "Composed", "model_for"]

F_REF_HZ = 10.0
"""Reference frequency of ``viscous_damping`` and ``frequency_dependent_stiffness`` [Hz]."""

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
        The structure statistic of :func:`sbcal.diagnosis.diagnose.locate` that screens it in.
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
    # per-test model changes with no signature of their own: a structured (correlated) misfit screens them in
    *(Extension(id_, False, "structured", what) for id_, what in (
        ("viscous_damping", "part of the cable's damping is viscous: the loss factor grows with frequency"),
        ("asymmetric_damping", "the two arms damp differently"),
        ("base_rocking", "the table rotates as it moves up and down"),
        ("frequency_dependent_stiffness", "the cable stiffens (or softens) with frequency: a viscoelastic cable"),
    )),
)}
"""The catalogue, by id, in the order of ``docs/diagnose.md`` ("The catalogue")."""


def _base(params: dict) -> dict:
    """The parameters :func:`sbcal.model.fem.dynamic_stiffness` knows, as (n, 1) columns where per line."""
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


_MODELS = {
    "baseline": dynamic_stiffness,
    "fixture_mass": _fixture_mass,
    "sensor_delay": _sensor_delay,
    "viscous_damping": _viscous_damping,
    "asymmetric_damping": _asymmetric_damping,
    "base_rocking": _base_rocking,
    "frequency_dependent_stiffness": _frequency_dependent_stiffness,
}


CHAIN = ("fixture_mass", "sensor_delay")
"""Effects on the measured signal: they compose with any model (in this order: mass, then delay)."""


@dataclass(frozen=True)
class Composed:
    """A per-test model with measurement-chain effects on top (picklable).

    ``Composed(base, chain)(damper, freq_hz, **params)``: the ``base`` catalogue model (or
    ``"baseline"``) with its own parameters, then ``f - omega^2 m_f`` and ``f exp(-i omega tau)`` for
    the effects of ``chain`` (their parameters ``fixture_mass_kg``, ``delay_s``).
    """

    base: str
    chain: tuple

    def __call__(self, damper: Damper, freq_hz, **params):
        own = {"fixture_mass": "fixture_mass_kg", "sensor_delay": "delay_s"}
        chain = {own[e]: params.pop(own[e]) for e in self.chain}
        f = _MODELS[self.base](damper, freq_hz, **params)
        omega = 2 * np.pi * np.asarray(freq_hz, dtype=float)
        if "fixture_mass_kg" in chain:
            f = f - omega**2 * _col(chain["fixture_mass_kg"])
        if "delay_s" in chain:
            f = f * np.exp(-1j * omega * _col(chain["delay_s"]))
        return f


def model_for(effect: str, secondary=()):
    """The per-test forward model of ``"baseline"`` or a catalogue id, with measurement-chain effects
    ``secondary`` (:data:`CHAIN`) on top: ``model(damper, freq_hz, **params)``.

    ``strand_slip`` is a joint model (:class:`sbcal.inference.cable_fit.CableForward`), not made here.
    """
    if effect == "strand_slip":
        raise ValueError("strand_slip is the cable model of sbcal.inference.cable_fit")
    secondary = tuple(secondary)
    bad = [e for e in secondary if e not in CHAIN]
    if bad:
        raise ValueError(f"{bad[0]} does not compose with a per-test model (composable: {', '.join(CHAIN)})")
    if not secondary:
        return _MODELS[effect]
    chain = set(secondary) | ({effect} if effect in CHAIN else set())
    return Composed("baseline" if effect in CHAIN else effect, tuple(e for e in CHAIN if e in chain))
