"""The fast cable in time (sbcal.model.cable_time) and the hysteresis laws' time steppers (sbcal.model.laws.steppers).

Laws: the ODE laws' steppers follow the laws' own steady loops; the Jenkins populations of the Masing
laws follow theirs (at a fine resolution) and their describing functions are within 5e-4 of the laws'.
Cable: the linear cable is the first-harmonic model (exactly with the pre-warped inertia, within the
trapezoidal rule's frequency error without), a hysteretic cable in micro-slip is the describing-function
model within 0.2 %, and at 2 mm near the resonances the distortion and the describing function's error
are measured. Bad input is a one-line InputError.
"""

import math

import numpy as np
import pytest

from sbcal.core.errors import InputError
from sbcal.model.cable import CableModel
from sbcal.model.cable_element import ElementCableModel
from sbcal.model.cable_time import TimeResponse, time_response
from sbcal.model.fem import STANDARD_GRID_HZ
from sbcal.model.laws import LAWS, law_for
from sbcal.model.laws.base import masing_loop
from sbcal.model.laws.steppers import (BoucWenStepper, DahlStepper, JenkinsPopulation, drive, law_stepper,
                                  transition_curvature)

G = STANDARD_GRID_HZ
LINEAR = dict(EJ_min=9.0, beta_material=0.2)
# micro-slip: stiff slip parts (wires slipping as chi^2 and Bouc-Wen n = 2) at a small amplitude
IWAN5_MICRO = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=25.0, chi_micro=1e-6, chi_macro=0.02,
                   density_exponent=1.0, macro_ratio=0.5)
BW_MICRO = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=25.0, chi_slip=0.02, sharpness=2.0)
SWAGED = dict(clamp_zone=0.2, clamp_EJ_min_ratio=2.0, clamp_delta_EJ_ratio=2.5, clamp_moment_ratio=7.5,
              mass_zone=0.1, mass_EJ_min_ratio=1.5, mass_delta_EJ_ratio=1.5, mass_moment_ratio=3.0)
# 2 mm: the thesis's range (priors/cable.toml), slip curvatures well inside the 2 mm sweep's (~0.05-1 /m)
IWAN5_2MM = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=20.0, chi_micro=1e-5, chi_macro=0.05,
                 density_exponent=-0.5, macro_ratio=0.3)
BW_2MM = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=20.0, chi_slip=5e-3, sharpness=1.5)

MASING = {
    "iwan": [dict(delta_EJ=55.0, chi_macro=0.02, micro_exponent=-0.5, macro_ratio=0.1),
             dict(delta_EJ=20.0, chi_macro=0.005, micro_exponent=-0.9, macro_ratio=0.0)],
    "iwan5": [dict(delta_EJ=55.0, chi_micro=1e-6, chi_macro=0.02, density_exponent=-0.5, macro_ratio=0.1),
              dict(delta_EJ=20.0, chi_micro=1e-4, chi_macro=0.01, density_exponent=-2.4, macro_ratio=0.0),
              dict(delta_EJ=20.0, chi_micro=1e-3, chi_macro=0.002, density_exponent=2.0, macro_ratio=5.0)],
    "iwan_tail": [dict(delta_EJ=20.0, chi_micro=1e-5, chi_tail=0.01, density_exponent=-0.5, tail_exponent=-1.5),
                  dict(delta_EJ=20.0, chi_micro=1e-5, chi_tail=0.01, density_exponent=-1.0, tail_exponent=-1.1)],
    "lognormal_iwan": [dict(delta_EJ=55.0, chi_median=4e-3, log_spread=1.5),
                       dict(delta_EJ=55.0, chi_median=4e-3, log_spread=0.3)],
}


def _population(name, params, **kw):
    return JenkinsPopulation.from_law(LAWS[name](), {k: np.array([v]) for k, v in params.items()}, **kw)


# --- the laws in time ---------------------------------------------------------------------------

@pytest.mark.parametrize("name, params", [("dahl", dict(delta_EJ=55.0, chi_dahl=3e-3))]
                         + [("bouc_wen", dict(delta_EJ=30.0, chi_slip=3e-3, sharpness=n)) for n in (0.3, 1.0, 2.5, 5.0)])
def test_ode_law_steppers_follow_the_steady_loop(name, params):
    # started on the law's own loop at theta = 0 (chi = chi_a), one period of 512 steps: exact
    # exponentials (Dahl) and the tabulated profile (Bouc-Wen, ~1e-10) against the loops' DOP853
    law = LAWS[name]()
    chi_s = params.get("chi_dahl", params.get("chi_slip"))
    theta = np.arange(512) * 2 * np.pi / 512
    for a in (0.05, 1.0, 20.0):
        loop = law.steady_loop(a * chi_s, theta, **params)
        st = law_stepper(law, {k: np.array([v]) for k, v in params.items()})
        state = st.state([a * chi_s], [loop[0] / (params["delta_EJ"] * chi_s)])
        out = np.empty(theta.size)
        for i, th in enumerate(np.append(theta[1:], 2 * np.pi)):
            trial = st.trial(state, np.array([a * chi_s * math.cos(th)]))
            out[(i + 1) % theta.size] = trial.moment[0]
            state = st.commit(trial)
        err = np.max(np.abs(out - loop)) / np.max(np.abs(loop))
        assert err < 1e-6, (a, err)


@pytest.mark.parametrize("stepper", [DahlStepper(np.array([55.0, 55.0]), np.array([3e-3, 3e-3])),
                                     BoucWenStepper.from_params(30.0, np.array([3e-3, 1e-2]), np.array([0.3, 2.5]))])
def test_ode_law_tangent_is_the_derivative_of_the_moment(stepper):
    rng = np.random.default_rng(4)
    for _ in range(20):
        state = stepper.state(rng.uniform(-0.01, 0.01, 2), rng.uniform(-0.999, 0.999, 2))
        kappa = state.kappa + rng.uniform(-3e-3, 3e-3, 2)
        h = 1e-7 * np.maximum(np.abs(kappa - state.kappa), 1e-6)
        t = stepper.trial(state, kappa)
        fd = (stepper.trial(state, kappa + h).moment - stepper.trial(state, kappa - h).moment) / (2 * h)
        np.testing.assert_allclose(t.tangent, fd, rtol=2e-5, atol=1e-6)


def _stepped_loop(stepper, chi_a, n=512, periods=1.25):
    """Virgin loading to chi_a (a quarter period), then whole periods: the last period's moments at
    theta = 0 .. 2 pi (chi = chi_a cos theta)."""
    k = int(n * periods)
    th = np.arange(1, k + n + 1) * 2 * np.pi / n - np.pi / 2
    kappa = np.cos(th)[:, None] * np.atleast_1d(chi_a)[None, :]  # from 0 at theta = -pi/2
    m = drive(stepper, kappa)
    return m[-n:][np.argsort(np.mod(th[-n:], 2 * np.pi))]


@pytest.mark.parametrize("name", sorted(MASING))
def test_jenkins_population_follows_the_steady_loop(name):
    # fine populations (resolution 4) follow the law's own Masing loop within 1e-4 of its peak; at the
    # default resolution the stepped loop is exactly the population's own Masing loop (the stepper
    # is exact: the loop's error is the discretisation's, ~5e-4 pointwise)
    law, params = LAWS[name](), MASING[name][0]
    t = transition_curvature(law, **params)
    amps = t * np.array([0.03, 1.0, 30.0])
    theta = np.arange(512) * 2 * np.pi / 512
    fine = law_stepper(law, {k: np.full(3, v) for k, v in params.items()}, resolution=4.0)
    got = _stepped_loop(fine, amps)
    for j, a in enumerate(amps):
        loop = law.steady_loop(a, theta, **params)
        assert np.max(np.abs(got[:, j] - loop)) < 1e-4 * np.max(np.abs(loop))
    pop = _population(name, params)
    got = _stepped_loop(pop, amps)
    ok = pop.stiffness[0] > 0

    def backbone(x):
        x = np.asarray(x, dtype=float)
        return (pop.stiffness[0][ok] * np.minimum(x[..., None], pop.slip[0][ok])).sum(axis=-1) + pop.elastic[0] * x

    for j, a in enumerate(amps):
        own = masing_loop(backbone, a, theta)
        np.testing.assert_allclose(got[:, j], own, rtol=0, atol=1e-12 * np.max(np.abs(own)))


@pytest.mark.parametrize("name", sorted(MASING))
def test_jenkins_population_describing_function_within_5e_4(name):
    # the population's exact describing function (sum of Jenkins elements) against the law's, from
    # 1e-3 to 1e3 times the law's transition; and the stepped loop's first harmonic is that sum
    law = LAWS[name]()
    worst = 0.0
    for params in MASING[name]:
        pop = _population(name, params)
        t = transition_curvature(law, **params)
        chi = t * np.logspace(-3, 3, 1201)
        exact = law.slip_rigidity(chi, **params)
        rel = np.abs(pop.describing_function(chi)[0] - exact) / np.abs(exact)
        worst = max(worst, rel.max())
        print(f"{name} {params}: {int((pop.stiffness > 0).sum())} elements, DF error {rel.max():.2e}")
    assert worst < 5e-4
    amps = t * np.array([0.1, 1.0, 10.0])
    loop = _stepped_loop(pop, amps, n=2048)
    theta = np.arange(2048) * 2 * np.pi / 2048
    df = (loop * np.exp(-1j * theta)[:, None]).sum(axis=0) / 1024 / amps  # first harmonic over chi_a
    np.testing.assert_allclose(df, pop.describing_function(amps)[0], rtol=2e-6)


def test_loss_aware_population_keeps_the_section_loss():
    # with the section's EJ_min (1 + i beta), the population also keeps the error small against the
    # section's loss: in micro-slip the law's loss comes from few elements (~10 % off with the law-only
    # cells, measured here as the largest error of Im over the section's loss)
    lin = 4.0 * (1 + 0.03j)
    for name in ("iwan5", "lognormal_iwan"):
        law, params = LAWS[name](), MASING[name][0]
        t = transition_curvature(law, **params)
        chi = t * np.logspace(-4, 3, 1401)
        exact = law.slip_rigidity(chi, **params)
        loss = (lin + exact).imag
        plain = np.max(np.abs(_population(name, params).describing_function(chi)[0].imag - exact.imag) / loss)
        aware = np.max(np.abs(_population(name, params, linear=lin).describing_function(chi)[0].imag - exact.imag)
                       / loss)
        print(f"{name}: error of the loss over the section's loss: law-only cells {plain:.1e}, loss-aware {aware:.1e}")
        assert aware < 2e-3 < plain


# --- the cable in time ----------------------------------------------------------------------------

def test_linear_cable_is_the_first_harmonic_model(damper1):
    # pre-warped, the discrete first harmonic of a linear cable is the model's exactly: started on its
    # steady state there is no transient; from rest, what is left of the transient after the settling
    # test (relative change < tol between windows) is ~tol / (the decay per window)
    f = G[::6]
    model = CableModel(None)
    ref = model.dynamic_stiffness(damper1, f, 1.0, **LINEAR)
    on = time_response(model, damper1, f, 1.0, start="model", **LINEAR)
    np.testing.assert_allclose(on.f_uu, ref, rtol=1e-12)
    assert np.all(on.distortion < 1e-12) and on.settled.all() and on.converged.all()
    rest = time_response(model, damper1, f, 1.0, **LINEAR)
    assert rest.settled.all() and np.all(rest.periods >= 8 + 8 + 2 * 4)
    np.testing.assert_allclose(rest.f_uu, ref, rtol=1e-4)
    assert np.all(rest.distortion < 1e-4)


def test_plain_newmark_error_is_the_trapezoidal_frequency_error(damper1):
    # without pre-warping, the trapezoidal rule's steady response to exp(i theta) is the exact one at
    # omega (1 + eps), eps = dtheta^2 / 12 (its period error): 2.0e-4 at 128 steps, 5.0e-5 at 256. So the
    # time response's error is second order in the step (a quarter at twice the steps, line by line),
    # and of the size of the model's own change over that shift: measured 0.43-1.017 of it, the same at
    # 128, 256 and 512 steps to 1e-3 (a property of the model, not noise: the force's inertia is taken at
    # omega, not omega (1 + eps), which moves it either way by up to 2 %)
    f = G[::6]
    model = CableModel(None)
    ref = model.dynamic_stiffness(damper1, f, 1.0, **LINEAR)
    err, ratio = {}, {}
    for steps in (128, 256):
        eps = (2 * np.pi / steps) ** 2 / 12
        shift = np.abs(model.dynamic_stiffness(damper1, f * (1 + eps), 1.0, **LINEAR) / ref - 1)
        got = time_response(model, damper1, f, 1.0, steps_per_period=steps, prewarp=False, start="model", **LINEAR)
        err[steps] = np.abs(got.f_uu / ref - 1)
        ratio[steps] = err[steps] / shift
    assert np.allclose(err[256] / err[128], 0.25, rtol=0.02)  # second order in the step
    assert np.allclose(ratio[256], ratio[128], atol=2e-3)
    assert 0.4 < ratio[256].min() and ratio[256].max() < 1.03


@pytest.mark.parametrize("name, params, lines", [
    pytest.param("bouc_wen", BW_MICRO, [9.0, 29.0], marks=pytest.mark.slow),
    ("iwan5", IWAN5_MICRO, [9.0, 19.0, 29.0]),
    ("iwan5_zoned", dict(IWAN5_MICRO, **SWAGED), [9.0, 19.0, 29.0]),
])
def test_micro_slip_is_the_describing_function_model(damper1, name, params, lines):
    # nearly sinusoidal (distortion < 1e-3): the first-harmonic model is then exact to first order,
    # and the time response (started on its steady state: lightly damped, from rest it would take
    # hundreds of periods) agrees within 0.2 %
    model = CableModel(law_for(name))
    f = np.array(lines)
    amp = 0.001
    r = time_response(model, damper1, f, amp, start="model", **params)
    ref = model.dynamic_stiffness(damper1, f, amp, **params)
    err = np.abs(r.f_uu / ref - 1)
    print(f"{name}: distortion {r.distortion.max():.1e}, |f_uu / model - 1| {err.max():.1e}, periods {r.periods}")
    assert r.settled.all() and r.converged.all()
    assert np.all(r.distortion < 1e-3)
    assert np.all(err < 2e-3)


@pytest.mark.parametrize("name, params", [("iwan5", IWAN5_2MM),
                                          pytest.param("bouc_wen", BW_2MM, marks=pytest.mark.slow)])
def test_two_mm_near_the_resonances(damper1, name, params):
    # gross slip near the resonances: the force is distorted and the first-harmonic model is off;
    # measured, not bounded (finite, settled, converged)
    model = CableModel(law_for(name))
    mag = np.abs(model.dynamic_stiffness(damper1, G, 2.0, **params)[0])
    peaks = G[1:-1][(mag[1:-1] > mag[:-2]) & (mag[1:-1] > mag[2:])]  # the lines at the peaks of |f_uu|
    r = time_response(model, damper1, peaks, 2.0, **params)
    ref = model.dynamic_stiffness(damper1, peaks, 2.0, **params)
    err = np.abs(r.f_uu / ref - 1)
    for k, fk in enumerate(peaks):
        print(f"{name} 2 mm {fk:5.1f} Hz: distortion {r.distortion[0, k]:.3f}, |f_uu / model - 1| {err[0, k]:.3f}, "
              f"periods {r.periods[0, k]}")
    assert np.all(np.isfinite(r.f_uu)) and np.all(np.isfinite(r.distortion))
    assert r.settled.all() and r.converged.all()
    assert np.all(r.distortion > 1e-3)  # gross slip: not a sinusoid


@pytest.mark.slow
def test_rest_and_model_starts_reach_one_steady_state(damper1):
    model = CableModel(law_for("iwan5"))
    f = np.array([8.5, 28.0])
    a = time_response(model, damper1, f, 2.0, tol=1e-6, **IWAN5_2MM)
    b = time_response(model, damper1, f, 2.0, tol=1e-6, start="model", **IWAN5_2MM)
    np.testing.assert_allclose(a.f_uu, b.f_uu, rtol=1e-4)
    np.testing.assert_allclose(a.harmonics, b.harmonics, rtol=0, atol=1e-4 * np.abs(a.harmonics[..., :1]).max())


def test_a_coarse_step_still_converges(damper1):
    # 128 steps per period at 2 mm: Newton crosses the reversal kink of Bouc-Wen's tangent (~6x)
    # back and forth unless a second crossing stops at the kink
    model = CableModel(law_for("bouc_wen"))
    r = time_response(model, damper1, np.array([28.0]), 2.0, steps_per_period=128, start="model", tol=1e-4,
                      **dict(BW_2MM, chi_slip=3e-3, delta_EJ=25.0))
    assert r.converged.all() and r.settled.all()


def test_series_sets_and_shapes(damper1):
    model = CableModel(None)
    f = np.array([9.0, 20.0])
    sets = dict(EJ_min=np.array([9.0, -1.0, 5.0]), beta_material=0.2)
    r = time_response(model, damper1, f, 1.0, keep_series=True, n_harmonics=5, **sets)
    assert isinstance(r, TimeResponse)
    assert r.f_uu.shape == (3, 2) and r.harmonics.shape == (3, 2, 5) and r.force.shape == (3, 2, r.theta.size)
    assert np.all(np.isnan(r.f_uu[1])) and not r.settled[1].any() and np.all(np.isnan(r.force[1]))
    np.testing.assert_allclose(r.f_uu[[0, 2]], model.dynamic_stiffness(damper1, f, 1.0, EJ_min=[9.0, 5.0],
                                                                      beta_material=0.2), rtol=1e-4)
    # the recorded samples give back the harmonics: the last window of each line
    n = r.steps_per_period * r.window
    for s in (0, 2):
        for k in range(2):
            end = r.periods[s, k] * r.steps_per_period
            th, x, force = r.theta[end - n:end], r.base[s, k, end - n:end], r.force[s, k, end - n:end]
            np.testing.assert_allclose(x, 0.5e-3 * np.cos(th), atol=1e-15)
            f1 = 2 * np.mean(force * np.exp(-1j * th))
            np.testing.assert_allclose(f1, r.harmonics[s, k, 0], rtol=1e-12)
            np.testing.assert_allclose(f1 / (2 * np.mean(x * np.exp(-1j * th))), r.f_uu[s, k], rtol=1e-12)
            assert np.all(np.isnan(r.force[s, k, end:]))


def test_a_step_that_fails_is_flagged_not_used(damper1):
    # one Newton iteration per step cannot meet 1e-10 on a hysteretic cable: every line is flagged
    model = CableModel(law_for("iwan5"))
    r = time_response(model, damper1, np.array([9.0, 20.0]), 2.0, max_iter=1, **IWAN5_2MM)
    assert not r.converged.any() and not r.settled.any()
    assert np.all(np.isnan(r.f_uu)) and np.all(np.isnan(r.harmonics)) and np.all(r.periods == 1)


@pytest.mark.parametrize("kwargs, match", [
    (dict(steps_per_period=0), "steps_per_period: expected an integer >= 8"),
    (dict(steps_per_period=100.5), "steps_per_period: expected an integer"),
    (dict(window=0), "window: expected an integer >= 1"),
    (dict(tol=0.0), "tol: expected a finite value > 0"),
    (dict(ramp=-1.0), "ramp: expected a finite value >= 0"),
    (dict(n_harmonics=200), "n_harmonics: expected fewer than"),
    (dict(max_periods=5), "max_periods: expected >= ramp"),
    (dict(start="somewhere"), "start: expected 'rest' or 'model'"),
    (dict(resolution=0.0), "resolution: expected a finite value > 0"),
    (dict(newton_tol=float("nan")), "newton_tol: expected a finite value > 0"),
    (dict(EJ_mni=3.0), "unknown parameter 'EJ_mni'"),
])
def test_bad_input_is_one_line(damper1, kwargs, match):
    params = dict(LINEAR)
    params.update(kwargs)
    with pytest.raises(InputError, match=match) as info:
        time_response(CableModel(None), damper1, G[:2], 1.0, **params)
    assert "\n" not in str(info.value)


def test_bad_model_frequency_and_law_input_is_one_line(damper1):
    with pytest.raises(InputError, match="model: expected a CableModel"):
        time_response(ElementCableModel(None), damper1, G[:2], 1.0, **LINEAR)
    with pytest.raises(InputError, match="freq_hz"):
        time_response(CableModel(None), damper1, [-1.0], 1.0, **LINEAR)
    with pytest.raises(InputError, match="iwan5 law: parameters outside the law's domain"):
        law_stepper(LAWS["iwan5"](), dict(MASING["iwan5"][0], chi_micro=0.5))
    with pytest.raises(InputError, match="resolution"):
        law_stepper(LAWS["iwan"](), MASING["iwan"][0], resolution=-1.0)


@pytest.mark.slow
@pytest.mark.parametrize("name, params", [("iwan5", IWAN5_2MM), ("bouc_wen", BW_2MM),
                                          ("iwan5_zoned", dict(IWAN5_2MM, **SWAGED))])
def test_two_mm_sweep_from_rest_settles_at_every_line(damper1, name, params):
    # the virtual bench's sweep: 37 lines, both arms, from rest, in gross slip (distortion up to 18-26 %):
    # every line settles and converges. The first harmonic departs from the describing-function model by
    # up to 11-17 % (measured; near the first resonances, where a line's history matters, not only where the
    # force is most distorted): the 25 % below guards against a stepper that drifts, it is no accuracy claim
    # (the time stepper's accuracy is the micro-slip and Newmark tests')
    model = CableModel(law_for(name))
    r = time_response(model, damper1, G, 2.0, **params)
    ref = model.dynamic_stiffness(damper1, G, 2.0, **params)
    err = np.abs(r.f_uu / ref - 1)
    assert r.settled.all() and r.converged.all() and np.isfinite(r.f_uu).all()
    assert err.max() < 0.25
