"""The strand-slip hysteresis laws: describing functions against each law's own loop, limits, references."""

import pickle

import numpy as np
import pytest

from sbcal.errors import InputError
from sbcal.hysteresis import (
    FITTED_LAWS, LAWS, DahlLaw, IwanLaw, LognormalIwanLaw, jenkins_rigidity, law_for,
)

DAHL = dict(delta_EJ=50.0, chi_dahl=2e-3)
IWAN = dict(delta_EJ=50.0, chi_macro=5e-3, micro_exponent=-0.5, macro_ratio=0.3)
LOGN = dict(delta_EJ=50.0, chi_median=3e-3, log_spread=1.5)
CASES = [(DahlLaw(), DAHL, 2e-3), (IwanLaw(), IWAN, 5e-3), (LognormalIwanLaw(), LOGN, 3e-3)]


def _first_harmonic(law, params, chi_a, n=20000):
    """Fourier coefficients of the law's steady loop (its own operator), trapezoid on a periodic grid."""
    theta = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    m = law.steady_loop(chi_a, theta, **params)
    return 2 * np.mean(m * np.cos(theta)) / chi_a - 2j * np.mean(m * np.sin(theta)) / chi_a


@pytest.mark.parametrize("law, params, scale", CASES, ids=[c[0].name for c in CASES])
@pytest.mark.parametrize("ratio", [0.01, 0.3, 1.0, 1.02, 3.0, 30.0])
def test_describing_function_is_the_loops_first_harmonic(law, params, scale, ratio):
    # Trapezoid on 20000 points: exact for the smooth loops to ~1e-12; the Iwan point mass puts a
    # corner in the loop (error ~1e-8 relative); the lognormal table's spline ~1e-10. 1e-7 covers all.
    chi = ratio * scale
    got = law.slip_rigidity(chi, **params)
    ref = _first_harmonic(law, params, chi)
    assert abs(got - ref) <= 1e-7 * abs(ref)
    assert abs(got.imag - ref.imag) <= 1e-7 * abs(ref) and got.imag > 0  # energy per cycle, dissipative


@pytest.mark.parametrize("law, params, scale", CASES, ids=[c[0].name for c in CASES])
def test_stuck_cable_limit_is_the_full_stick_rigidity(law, params, scale):
    # the Iwan law approaches it as (chi / chi_macro)^(c+1) = chi^0.5 here: a very small amplitude
    for chi in (0.0, 1e-15 * scale):
        s = law.slip_rigidity(chi, **params)
        assert abs(s.real - params["delta_EJ"]) <= 1e-6 * params["delta_EJ"]
        assert 0 <= s.imag <= 1e-6 * params["delta_EJ"]
    # and the slip part softens monotonically with amplitude
    chi = scale * np.logspace(-3, 2, 200)
    assert np.all(np.diff(law.slip_rigidity(chi, **params).real) < 0)


def _log_slope(law, params, chi, h=1e-3):
    w = law.energy_per_cycle(np.array([chi, chi * np.exp(h)]), **params)
    return np.log(w[1] / w[0]) / h


def test_micro_slip_exponents():
    # Dahl: W = 4 dEJ chi0^2 (a - tanh a) ~ a^3 (1 - 2 a^2 / 5): slope 3 - 4 a^2 / 5 at small a
    assert _log_slope(DahlLaw(), DAHL, 1e-4 * 2e-3) == pytest.approx(3.0, abs=1e-6)
    # Iwan: exactly chi^(c+3) below chi_macro (closed form), for any c
    for c in (-0.7, -0.2, 0.5):
        p = dict(IWAN, micro_exponent=c)
        assert _log_slope(IwanLaw(), p, 1e-3) == pytest.approx(c + 3, abs=1e-9)
    # lognormal: no fixed exponent, the slope steepens as the amplitude falls
    slopes = [_log_slope(LognormalIwanLaw(), LOGN, chi) for chi in (3e-4, 3e-5, 3e-6)]
    assert 3.0 < slopes[0] < slopes[1] < slopes[2]  # steeper than Dahl's 3


def test_dahl_closed_forms():
    law, chi0, dej = DahlLaw(), 2e-3, 50.0
    a = np.array([1e-3, 0.1, 1.0, 4.0, 40.0])
    w = law.energy_per_cycle(a * chi0, delta_EJ=dej, chi_dahl=chi0)
    # the direct a - tanh(a) loses ~eps / a^2 = 2e-10 at a = 1e-3 (the law uses its series there)
    np.testing.assert_allclose(w, 4 * dej * chi0**2 * (a - np.tanh(a)), rtol=1e-9)


def test_iwan_matches_tmdsimpy_iwan4_harmonic_balance():
    """Reference: tmdsimpy (github.com/tmd-lab/tmdsimpy, commit 17d5fc3), VectorIwan4.aft with
    kt = 50, Fs = 0.15, chi = -0.5, beta = 0.3, Nt = 2^13, displacement A cos(t), Nsliders = 4000
    (midpoint sliders); first-harmonic coefficients divided by A (Re = cos part, Im = -sin part).
    Run outside the project in a throwaway venv. Its sliders discretise the phi^c density, so it
    differs from the continuum by its own discretisation error: tolerance = |N=1000 - N=4000|
    (the midpoint rule's error falls as N^-(c+1) = N^-0.5, so that difference bounds N=4000's error).
    """
    kt, fs, c, beta = 50.0, 0.15, -0.5, 0.3
    phimax = fs * (1 + beta) / kt / (beta + (c + 1) / (c + 2))  # Segalman 2005, as tmdsimpy computes it
    amps = [2e-4, 1e-3, 3e-3, 6e-3, 2e-2]
    n4000 = [45.29312089 + 1.176914381j, 39.47506767 + 2.631268536j, 31.77028038 + 4.557442077j,
             24.21928301 + 6.445185239j, 5.627242041 + 7.22810518j]
    n1000 = [45.29335797 + 1.177857799j, 39.47508742 + 2.631509919j, 31.7702844 + 4.55752853j,
             24.21928469 + 6.445227086j, 5.62724208 + 7.228117873j]
    got = IwanLaw().slip_rigidity(np.array(amps), delta_EJ=kt, chi_macro=phimax, micro_exponent=c, macro_ratio=beta)
    for g, a, b in zip(got, n4000, n1000):
        tol = abs(a - b) + 1e-8 * abs(a)  # + print precision
        assert abs(g.real - a.real) <= tol and abs(g.imag - a.imag) <= tol


def test_iwan_macro_slip_is_coulomb():
    p = IWAN
    c, k = p["micro_exponent"], p["delta_EJ"] / (1 + p["macro_ratio"])
    m_macro = p["chi_macro"] * (k * (c + 1) / (c + 2) + p["delta_EJ"] - k)
    chi = 1e3 * p["chi_macro"]
    w = IwanLaw().energy_per_cycle(chi, **p)
    assert w == pytest.approx(4 * m_macro * chi, rel=2e-3)  # minus the O(chi_macro / chi) elastic part
    assert IwanLaw().backbone(np.array([2 * p["chi_macro"]]), **p)[0] == pytest.approx(m_macro)


def test_jenkins_element():
    np.testing.assert_allclose(jenkins_rigidity([1.0, 2.0]), [1.0, 1.0])
    assert jenkins_rigidity(0.0) == 0
    x = 0.25  # theta = arccos(0.5) = pi/3
    th = np.pi / 3
    assert jenkins_rigidity(x) == pytest.approx((th - np.sin(th) * np.cos(th)) / np.pi + 1j * 4 * x * (1 - x) / np.pi)


def test_outside_the_domain_is_nan_and_names_are_checked():
    s = IwanLaw().slip_rigidity(np.array([1e-3, 1e-3]), delta_EJ=50.0, chi_macro=5e-3,
                                micro_exponent=np.array([-1.5, -0.5]), macro_ratio=0.0)
    assert np.isnan(s[0]) and np.isfinite(s[1])
    assert np.isnan(DahlLaw().slip_rigidity(1e-3, delta_EJ=-1.0, chi_dahl=1e-3))
    with pytest.raises(InputError, match="missing 'chi_dahl'"):
        DahlLaw().slip_rigidity(1e-3, delta_EJ=1.0)
    with pytest.raises(InputError, match="unknown 'beta'"):
        DahlLaw().slip_rigidity(1e-3, delta_EJ=1.0, chi_dahl=1e-3, beta=0.1)
    with pytest.raises(InputError, match="unknown hysteresis law"):
        law_for("bouc")


def test_laws_are_picklable_and_describe_their_parameters():
    for name in LAWS:
        law = law_for(name)
        assert pickle.loads(pickle.dumps(law)) == law
        assert law.parameter_names[0] == "delta_EJ"
        assert all(p.unit and p.meaning for p in law.parameters)
    assert set(FITTED_LAWS) == {"dahl", "iwan"}
    # no parameter name means two things across the laws
    meaning = {}
    for cls in LAWS.values():
        for p in cls.parameters:
            assert meaning.setdefault(p.name, p.meaning) == p.meaning


def test_vectorised_over_parameter_sets():
    chi = np.array([[1e-4, 1e-3, 1e-2]])
    ej = np.array([[10.0], [50.0]])
    s = DahlLaw().slip_rigidity(chi, delta_EJ=ej, chi_dahl=2e-3)
    assert s.shape == (2, 3)
    np.testing.assert_allclose(s[1], 5 * s[0])
