"""The virtual bench's time-domain strand slip (``strand_slip=...,time:1``; docs/virtual_bench.md, "Time domain").

The bench integrates the fast cable (CableModel, BENCH_SECTIONS sections per arm) from rest like a shaker
and reads the first harmonic of the force. In micro-slip the motion is nearly sinusoidal, so the
describing-function model with the same sections is exact to first order: they agree within 0.3 %. At
2 mm near the resonances the force is distorted and the two differ by more than 2 %. Effects the fast
cable cannot carry in time are refused in one line; the effect string parses to the library's value;
the runs of a test are one integration's parameter sets.
"""

from dataclasses import replace

import numpy as np
import pytest

import sbcal.simulate.virtual_bench as vb
from sbcal.core.errors import InputError
from sbcal.model.cable import CableModel
from sbcal.model.laws import law_for
from sbcal.simulate.virtual_bench import (BENCH_SECTIONS, BENCH_ZONE_SECTIONS, BenchConfig, CableZone, SlipLaw,
                                          parse_effect, record, response)

# micro-slip at 0.02 mm: the curvature (up to ~0.006 /m at 29 Hz) stays well below chi_macro, so a few
# per cent of the wires slip; beta = 0.3 damps the resonances enough to settle from rest in ~50 periods
IWAN5 = dict(delta_EJ=20.0, chi_micro=1e-5, chi_macro=0.05, density_exponent=-0.5, macro_ratio=0.3)
SWAGED = dict(clamp_zone=0.2, clamp_EJ_min_ratio=2.0, clamp_delta_EJ_ratio=2.5, clamp_moment_ratio=7.5,
              mass_zone=0.1, mass_EJ_min_ratio=1.5, mass_delta_EJ_ratio=1.5, mass_moment_ratio=3.0)
MICRO = {"EJ": 4.4, "beta": 0.3}
RESONANCES = np.array([11.0, 29.0])  # damper1's two peaks of |f_uu| at small amplitude
# the bundled bench's dry cable of damper1 (docs/virtual_bench.md, "The bundled data")
DRY = SlipLaw(law="lognormal_iwan", params=(("delta_EJ", 42.0), ("chi_median", 0.006), ("log_spread", 2.1)),
              time_domain=True)


@pytest.fixture
def spy(monkeypatch):
    """The TimeResponse of every time_response call the bench makes (to read its distortion and sets)."""
    calls, real = [], vb.time_response

    def recorded(*args, **kwargs):
        calls.append(real(*args, **kwargs))
        return calls[-1]

    monkeypatch.setattr(vb, "time_response", recorded)
    return calls


def _fast(law, damper, f, amp, **params):
    model = CableModel(law_for(law), sections=BENCH_SECTIONS, zone_sections=BENCH_ZONE_SECTIONS)
    return model.dynamic_stiffness(damper, f, amp, **params)


def test_micro_slip_is_the_describing_function_model(damper1):
    # two runs with re-clamping scatter (one integration, two parameter sets), base rocking and a fixture
    # mass: the same mapping of the bench's parameters onto the fast model as the frequency-domain bench's
    ej_scale, chi0_scale = np.array([1.0, 1.03]), np.array([1.0, 0.95])
    slip = SlipLaw(law="iwan5", params=tuple(IWAN5.items()), time_domain=True)
    effects = {"strand_slip": slip, "base_rocking": 0.3, "fixture_mass": 0.02}
    got = response(damper1, RESONANCES, 0.02, MICRO, effects, ej_scale=ej_scale, chi0_scale=chi0_scale)
    ref = _fast("iwan5", damper1, RESONANCES, 0.02, EJ_min=4.4 * ej_scale, beta_material=0.3,
                rocking_rad_per_m=0.3, **dict(IWAN5, delta_EJ=20.0 * ej_scale, chi_macro=0.05 * chi0_scale))
    ref = ref - (2 * np.pi * RESONANCES) ** 2 * 0.02
    err = np.abs(got / ref - 1)
    print(f"iwan5, 0.02 mm: |time / describing function - 1| = {err.max():.1e}")
    assert got.shape == (2, RESONANCES.size)
    assert np.all(err < 3e-3)


def test_micro_slip_zoned_law_is_the_describing_function_model(damper1, spy):
    params = dict(IWAN5, **SWAGED)
    slip = SlipLaw(law="iwan5_zoned", params=tuple(params.items()), time_domain=True)
    got = response(damper1, RESONANCES, 0.02, MICRO, {"strand_slip": slip})
    ref = _fast("iwan5_zoned", damper1, RESONANCES, 0.02, EJ_min=4.4, beta_material=0.3, **params)
    err = np.abs(got / ref - 1)
    (r,) = spy
    print(f"iwan5_zoned, 0.02 mm: |time / describing function - 1| = {err.max():.1e}, "
          f"distortion up to {r.distortion.max():.1e}, periods {r.periods.ravel()}")
    assert np.all(r.distortion < 0.02)  # nearly sinusoidal
    assert np.all(err < 3e-3)


def test_two_mm_is_distorted_and_off_the_describing_function(damper1, spy):
    # the bundled dry cable at 2 mm on the lines below the first peak (7.5 Hz) and at it (12 Hz): gross
    # slip, a distorted force, and a first harmonic the describing function misses by a few per cent
    f = np.array([7.5, 12.0])
    got = response(damper1, f, 2.0, {"EJ": 4.4, "beta": 0.11}, {"strand_slip": DRY})
    ref = _fast("lognormal_iwan", damper1, f, 2.0, EJ_min=4.4, beta_material=0.11, **dict(DRY.params))
    err = np.abs(got / ref - 1)
    (r,) = spy
    print(f"bundled dry cable, 2 mm: |time / describing function - 1| = {err.ravel().round(4)}, "
          f"distortion {r.distortion.ravel().round(3)}")
    assert err.max() > 0.02
    assert r.distortion.max() > 0.05


def test_runs_of_a_test_are_one_integration(damper1, spy):
    # record's runs differ by scatter only: one time_response call per test, its runs the parameter sets;
    # the time-domain reading goes into the bench CSV like the frequency-domain one
    cfg = replace(BenchConfig(params={"EJ": 4.4, "beta": 0.3}, effects={"strand_slip": DRY}, runs=3).ideal(),
                  ej_scatter=0.015)
    frame = record(damper1, cfg, ["0.5-0.5"], rng=np.random.default_rng(1), freq_hz=[20.0])
    assert len(spy) == 1 and spy[0].f_uu.shape == (3, 1)
    np.testing.assert_allclose(frame["stiffness_n_per_m"], np.abs(spy[0].f_uu[:, 0]), rtol=1e-12)


@pytest.mark.parametrize("effects, params, match", [
    ({"asymmetric_damping": 0.05}, {}, "effect asymmetric_damping: the time-domain strand slip"),
    ({"viscous_damping": 20.0}, {}, "effect viscous_damping: the time-domain strand slip"),
    ({"frequency_dependent_stiffness": 0.05}, {}, "effect frequency_dependent_stiffness: the time-domain"),
    ({}, {"beta1": 0.2}, "parameter beta1: the time-domain strand slip"),
    ({}, {"beta2": 0.2}, "parameter beta2: the time-domain strand slip"),
])
def test_effects_the_fast_cable_cannot_carry_are_refused(damper1, effects, params, match):
    effects = dict(effects, strand_slip=DRY)
    for call in (lambda: response(damper1, [10.0], 1.0, dict(MICRO, **params), effects),
                 lambda: BenchConfig(params=dict(MICRO, **params), effects=effects)):
        with pytest.raises(InputError, match=match) as info:
            call()
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("make, match", [
    (lambda: SlipLaw(law="iwan5", params=(("chi_macro", 0.02),), time_domain=True,
                     zones=(CableZone("clamp", 0.2, "dahl", (("chi_dahl", 0.03),)),)),
     "does not take clamp/mass zones .*law:iwan5_zoned"),
    (lambda: SlipLaw(params=(("chi_median", 0.01),), time_domain=True, elements=8), "does not take elements"),
    (lambda: SlipLaw(params=(("chi_median", 0.01),), steps_per_period=512), "add time:1"),
    (lambda: SlipLaw(params=(("chi_median", 0.01),), time_domain=True, steps_per_period=16), "integer > 18"),
    (lambda: SlipLaw(params=(("chi_median", 0.01),), time_domain="yes"), "True or False"),
    (lambda: parse_effect("strand_slip=chi_median:0.01,time:2"), "time must be 0 or 1"),
    (lambda: parse_effect("strand_slip=law:iwan5,chi_macro:0.02,mass:0.1/chi_ratio=2,time:1"),
     "does not take clamp/mass zones"),
    (lambda: parse_effect("strand_slip=chi_median:0.01,steps_per_period:x,time:1"), "not a number"),
])
def test_bad_time_domain_slip_is_one_line(make, match):
    with pytest.raises(InputError, match=match) as info:
        make()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("change, match", [
    (dict(max_periods=28, tol=1e-12), "did not settle in 28 periods"),
    (dict(max_iter=1), "a time step's Newton solve failed"),
])
def test_a_line_that_does_not_settle_or_converge_is_named(damper1, monkeypatch, change, match):
    # never silently used: the bench stops with the line's frequency (time_response given a budget the
    # line cannot meet: a tolerance no window meets, or one Newton iteration per step)
    real = vb.time_response
    monkeypatch.setattr(vb, "time_response", lambda *a, **k: real(*a, **dict(k, **change)))
    with pytest.raises(InputError, match=f"time domain.*the line at 12 Hz, parameter set 0: {match}") as info:
        response(damper1, [12.0], 2.0, {"EJ": 4.4, "beta": 0.11}, {"strand_slip": DRY})
    assert "\n" not in str(info.value)


def test_effect_string_round_trips():
    spec = "strand_slip=law:iwan5_zoned,chi_macro:0.05,clamp_zone:0.2,mass_zone:0.1,delta_EJ:20,time:1"
    name, slip = parse_effect(spec)
    assert name == "strand_slip"
    assert slip == SlipLaw(law="iwan5_zoned", params=(("chi_macro", 0.05), ("clamp_zone", 0.2), ("mass_zone", 0.1),
                                                      ("delta_EJ", 20.0)), time_domain=True)
    assert slip.steps_per_period == 256 and slip.time_domain is True
    assert parse_effect(spec.replace("time:1", "time:0")) == (name, replace(slip, time_domain=False))
    assert parse_effect(spec.replace(",time:1", "")) == (name, replace(slip, time_domain=False))
    assert parse_effect(spec + ",steps_per_period:512")[1] == replace(slip, steps_per_period=512)
    # what the bench holds for it: the same value from a config's effects
    assert BenchConfig(effects={"strand_slip": slip}).effects["strand_slip"] == slip
