"""The strand-slip hysteresis laws: describing functions against each law's own loop, limits, references."""

import pickle

import numpy as np
import pytest
from scipy import special
from scipy.integrate import quad

from sbcal.model.damper import resolve_damper
from sbcal.core.errors import InputError
from sbcal.model.laws import (
    LAWS, BoucWenLaw, DahlLaw, Iwan5Law, IwanLaw, IwanTailLaw, LognormalIwanLaw, fitted_laws, jenkins_rigidity, law_for,
)
from sbcal.inference.priors import cable_prior

DAHL = dict(delta_EJ=50.0, chi_dahl=2e-3)
IWAN = dict(delta_EJ=50.0, chi_macro=5e-3, micro_exponent=-0.5, macro_ratio=0.3)
LOGN = dict(delta_EJ=50.0, chi_median=3e-3, log_spread=1.5)
BOUC = dict(delta_EJ=50.0, chi_slip=2e-3, sharpness=0.6)
# c = -1: a log-uniform density, where the closed form interpolates across its removable 1/p
IWAN5 = dict(delta_EJ=50.0, chi_micro=2e-5, chi_macro=5e-3, density_exponent=-1.0, macro_ratio=0.3)
TAIL = dict(delta_EJ=50.0, chi_micro=2e-5, chi_tail=5e-3, density_exponent=-1.3, tail_exponent=-1.8)
CASES = [(DahlLaw(), DAHL, 2e-3), (IwanLaw(), IWAN, 5e-3), (LognormalIwanLaw(), LOGN, 3e-3),
         (BoucWenLaw(), BOUC, 2e-3), (Iwan5Law(), IWAN5, 5e-3), (IwanTailLaw(), TAIL, 5e-3)]


def _first_harmonic(law, params, chi_a, n=20000):
    """Fourier coefficients of the law's steady loop (its own operator), trapezoid on a periodic grid."""
    theta = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    m = law.steady_loop(chi_a, theta, **params)
    return 2 * np.mean(m * np.cos(theta)) / chi_a - 2j * np.mean(m * np.sin(theta)) / chi_a


@pytest.mark.parametrize("law, params, scale", CASES, ids=[c[0].name for c in CASES])
@pytest.mark.parametrize("ratio", [0.01, 0.3, 1.0, 1.02, 3.0, 30.0])
def test_describing_function_is_the_loops_first_harmonic(law, params, scale, ratio):
    # Trapezoid on 20000 points: exact for the smooth loops to ~1e-12; the Iwan point mass puts a
    # corner in the loop (error ~1e-8 relative); the lognormal table's spline ~1e-10; the Bouc-Wen
    # table <= 1.2e-7 of delta_EJ (~1e-9 at this sharpness), its loop's |eta|^n corner ~h^(n+2) =
    # 1e-9. 1e-7 covers all.
    chi = ratio * scale
    got = law.slip_rigidity(chi, **params)
    ref = _first_harmonic(law, params, chi)
    assert abs(got - ref) <= 1e-7 * abs(ref)
    assert abs(got.imag - ref.imag) <= 1e-7 * abs(ref) and got.imag > 0  # energy per cycle, dissipative


@pytest.mark.parametrize("law, params, scale", CASES, ids=[c[0].name for c in CASES])
def test_stuck_cable_limit_is_the_full_stick_rigidity(law, params, scale):
    # the Iwan law approaches it as (chi / chi_macro)^(c+1) = chi^0.5 here, Bouc-Wen's loss as
    # (chi / chi_slip)^0.6: a very small amplitude
    for chi in (0.0, 1e-15 * scale):
        s = law.slip_rigidity(chi, **params)
        assert abs(s.real - params["delta_EJ"]) <= 1e-6 * params["delta_EJ"]
        assert 0 <= s.imag <= 1e-6 * params["delta_EJ"]
    # and the slip part softens monotonically with amplitude (once any wire slips)
    chi = scale * np.logspace(-3, 2, 200)
    soft = np.diff(law.slip_rigidity(chi, **params).real)
    assert np.all(soft[chi[1:] > params.get("chi_micro", 0.0)] < 0) and np.all(soft <= 0)


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
    assert set(fitted_laws()) == {"bouc_wen", "iwan5", "iwan_tail"}
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


# --- the fitted families: Bouc-Wen with a free sharpness, Iwan with two cut-offs -------------------

@pytest.mark.parametrize("n", [0.35, 2.5, 4.8])
def test_bouc_wen_loop_across_sharpness(n):
    # near the table's ends in n (its interpolation's worst: <= 1.2e-7 of delta_EJ) and inside;
    # at n = 0.35 the loop's |eta|^n corner costs the trapezoid ~h^(n+2) ~ 1e-8. Hence 2e-7.
    law, p = BoucWenLaw(), dict(BOUC, sharpness=n)
    for ratio in (0.05, 1.0, 8.0):
        chi = ratio * p["chi_slip"]
        assert abs(law.slip_rigidity(chi, **p) - _first_harmonic(law, p, chi)) <= 2e-7 * p["delta_EJ"]


def test_bouc_wen_at_sharpness_one_is_dahl():
    # Dahl's closed forms over 16 decades, inside and beyond the table: measured <= 1.8e-9 of
    # delta_EJ (the interpolation; the quadrature alone ~1e-12)
    chi = 2e-3 * np.logspace(-8, 8, 400)
    got = BoucWenLaw().slip_rigidity(chi, **dict(BOUC, sharpness=1.0))
    assert np.abs(got - DahlLaw().slip_rigidity(chi, **DAHL)).max() <= 5e-9 * DAHL["delta_EJ"]


@pytest.mark.parametrize("n", [0.35, 1.0, 3.0])
def test_bouc_wen_limits(n):
    law, p = BoucWenLaw(), dict(BOUC, sharpness=n)
    dej, chi0 = p["delta_EJ"], p["chi_slip"]
    # micro-slip, beyond the table (it starts at a^n ~ e^-5): a^n = 1e-4, relative corrections
    # ~0.4 a^2n = 4e-9 to Im = 4 a^n / (pi (n + 2)) and to the loss 1 - Re = K_n a^2n
    a = 1e-4 ** (1 / n)
    s = law.slip_rigidity(a * chi0, **p) / dej
    k_n = 2 * n / (np.pi * (n + 1)) * (special.beta(1.5, n / 2) - special.beta(1.5, n + 0.5))
    assert s.imag == pytest.approx(4e-4 / (np.pi * (n + 2)), rel=1e-7)
    assert 1 - s.real == pytest.approx(k_n * 1e-8, rel=1e-5)  # 1 - Re ~ 1e-8: eps / 1e-8 ~ 1e-8 lost
    assert _log_slope(law, p, a * chi0) == pytest.approx(n + 2, abs=1e-6)
    # gross slip, inside (1e3) and beyond (1e6) the table: Coulomb, W = 4 dEJ chi0^2 (a - R_n) with
    # R_n = int_0^1 (1 - z^(n+1)) / (1 - z^2n) dz (from the loop's area), and Re ~ a^-3/2
    r_n = quad(lambda z: (1 - z ** (n + 1)) / (1 - z ** (2 * n)), 0, 1, epsabs=1e-13)[0]
    for a in (1e3, 1e6):
        w = law.energy_per_cycle(a * chi0, **p) / (4 * dej * chi0**2)
        assert a - w == pytest.approx(r_n, abs=1e-5)  # Im's ~1e-9 of its value ~1/a: ~1e-6 in a - w
    h = 1e-3
    s = law.slip_rigidity(1e6 * chi0 * np.exp([0.0, h]), **p).real
    assert np.log(s[1] / s[0]) / h == pytest.approx(-1.5, abs=1e-5)


def test_bouc_wen_is_smooth_across_its_table_ends():
    # the table's ends continue with the limits, matched in value and slope (the sampler's
    # log-density stays smooth): the jump and the kink are at the table's own accuracy
    from sbcal.model.laws.bouc_wen import _BW_XI, _bw_v
    law = BoucWenLaw()
    for n in (0.35, 1.7, 4.8):
        p = dict(BOUC, sharpness=n)
        for xi in _BW_XI:
            v = _bw_v(xi, n) + np.array([-2e-3, -1e-3, -1e-9, 1e-9, 1e-3, 2e-3])
            s = np.log(law.slip_rigidity(p["chi_slip"] * np.exp(v), **p) / p["delta_EJ"])
            for part in (s.real, s.imag):
                assert abs(part[3] - part[2]) <= 1e-8
                left = (3 * part[2] - 4 * part[1] + part[0]) / 2e-3
                right = (-3 * part[3] + 4 * part[4] - part[5]) / 2e-3
                assert abs(left - right) <= 1e-4 * (1 + abs(left))  # one-sided O(h^2) differences: ~1e-6


def test_iwan5_reduces_to_segalmans_iwan4():
    chi = np.logspace(-6, 0, 60)
    for c in (-0.4, 0.5):
        # chi_micro / chi_macro = 1e-20: the cut-off's corrections ~ (1e-20)^(c+1) <= 1e-12
        got = Iwan5Law().slip_rigidity(chi, **dict(IWAN5, chi_micro=1e-20 * IWAN5["chi_macro"], density_exponent=c))
        ref = IwanLaw().slip_rigidity(chi, **dict(IWAN, micro_exponent=c))
        assert np.abs(got - ref).max() <= 1e-10 * IWAN5["delta_EJ"]


def _jenkins_set_harmonic(phi, weight, chi_a, n_theta=8000):
    """First harmonic of parallel Jenkins elements (slip curvatures phi, rigidities weight), time-stepped.

    Each element's elastic curvature is clipped to +-phi on every step (exact for a Jenkins
    element); two periods from the virgin state (steady after the first reversal), the second
    one's Fourier coefficients by the trapezoid rule.
    """
    theta = np.linspace(0.0, 4 * np.pi, 2 * n_theta, endpoint=False)
    z, prev, m = np.zeros(phi.size), 0.0, np.empty(theta.size)
    for k, c in enumerate(chi_a * np.cos(theta)):
        z = np.clip(z + c - prev, -phi, phi)
        prev, m[k] = c, weight @ z
    th, m = theta[n_theta:], m[n_theta:]
    return 2 * np.mean(m * np.cos(th)) / chi_a - 2j * np.mean(m * np.sin(th)) / chi_a


def test_iwan5_matches_time_stepped_jenkins_elements():
    # N elements at the density's midpoint quantiles plus the point mass: the midpoint rule's error
    # falls as N^-2, so |N=1000 - N=2000| bounds N=2000's error (the trapezoid's is ~1e-9)
    p = dict(IWAN5, density_exponent=-0.6)
    q = p["density_exponent"] + 1
    k_cont = p["delta_EJ"] / (1 + p["macro_ratio"])
    for chi in (3e-4, 2e-3, 1.2e-2):
        got = Iwan5Law().slip_rigidity(chi, **p)
        steps = []
        for n in (1000, 2000):
            u = (np.arange(n) + 0.5) / n
            phi = (p["chi_micro"] ** q + u * (p["chi_macro"] ** q - p["chi_micro"] ** q)) ** (1 / q)
            weight = np.append(np.full(n, k_cont / n), p["delta_EJ"] - k_cont)
            steps.append(_jenkins_set_harmonic(np.append(phi, p["chi_macro"]), weight, chi))
        assert abs(got - steps[1]) <= abs(steps[1] - steps[0]) + 1e-8 * p["delta_EJ"]
        assert abs(steps[1] - steps[0]) <= 1e-6 * abs(got)  # and that bound is tight


def test_iwan5_micro_slip_between_its_cut_offs():
    law = Iwan5Law()
    # every wire sticks below chi_micro: the full stick rigidity, no friction
    s = law.slip_rigidity(np.array([0.5, 0.999]) * IWAN5["chi_micro"], **IWAN5)
    assert np.all(s == IWAN5["delta_EJ"])
    # between the cut-offs W ~ chi^(c+3), up to ~(chi_micro / chi)^(c+2) (here <= 1e-6, at c = -1.5)
    for c in (-1.5, -1.0, 0.7):
        p = dict(IWAN5, chi_micro=1e-18, density_exponent=c)
        assert _log_slope(law, p, 1e-6) == pytest.approx(c + 3, abs=1e-5)
    # gross slip: Coulomb at the backbone's saturation moment, as Iwan-4
    m_macro = law.backbone(np.array([2 * IWAN5["chi_macro"]]), **IWAN5)[0]
    chi = 1e3 * IWAN5["chi_macro"]
    assert law.energy_per_cycle(chi, **IWAN5) == pytest.approx(4 * m_macro * chi, rel=2e-3)


def test_iwan5_is_smooth_through_a_log_uniform_density():
    # c = -1 is a removable singularity of the closed form (interpolated over |c + 1| < 1e-6):
    # second differences across it are at rounding level (~1e-10 of the integral), no step
    c = -1.0 + 4e-7 * np.arange(-4, 5)
    chi = np.array([[1e-4], [3e-3], [0.1]])
    s = Iwan5Law().slip_rigidity(chi, **dict(IWAN5, density_exponent=c)) / IWAN5["delta_EJ"]
    assert np.abs(np.diff(s, 2, axis=1)).max() <= 1e-9
    assert np.all(np.abs(np.diff(s, axis=1)) > 0)  # it does depend on c there


def test_fitted_families_domains():
    assert np.isnan(BoucWenLaw().slip_rigidity(1e-3, **dict(BOUC, sharpness=5.5)))
    assert np.isnan(BoucWenLaw().slip_rigidity(1e-3, **dict(BOUC, sharpness=0.2)))
    bad = Iwan5Law().slip_rigidity(1e-3, **dict(IWAN5, chi_micro=np.array([1e-5, 5e-3, 6e-3])))
    assert np.isfinite(bad[0]) and np.isnan(bad[1:]).all()  # chi_micro < chi_macro
    assert np.isnan(Iwan5Law().slip_rigidity(1e-3, **dict(IWAN5, density_exponent=-2.5)))
    # vectorised over parameter sets, sharpness included (the table is 2-D)
    s = BoucWenLaw().slip_rigidity(np.array([[1e-4, 1e-3, 1e-2]]), delta_EJ=50.0, chi_slip=2e-3,
                                   sharpness=np.array([[0.5], [2.0]]))
    assert s.shape == (2, 3) and np.isfinite(s).all()
    np.testing.assert_allclose(s[1], BoucWenLaw().slip_rigidity([1e-4, 1e-3, 1e-2], **dict(BOUC, sharpness=2.0)))


@pytest.mark.parametrize("name", fitted_laws())
def test_prior_boxes_of_the_fitted_families(name):
    law = law_for(name)
    prior = cable_prior(name, resolve_damper("damper1"))
    assert set(prior.names) == {"a1", "a2", "EJ_min", "beta_material", *law.parameter_names}
    # the box's centre (geometric for log scales) lies in the law's domain
    centre = np.where(prior.log_scale, np.sqrt(np.abs(prior.lower * prior.upper)), 0.5 * (prior.lower + prior.upper))
    box = dict(zip(prior.names, centre))
    assert law.valid(**{k: box[k] for k in law.parameter_names})


def test_iwan_tail_is_its_density_summed_over_jenkins_elements():
    """Independent of the closed form and of the loop: the describing function as the density's
    sum of Jenkins elements, a trapezoid in ln(phi) over 26 e-folds (its error ~1e-6 here)."""
    u = np.linspace(np.log(TAIL["chi_micro"]), np.log(TAIL["chi_tail"]) + 26.0, 400001)
    phi = np.exp(u)
    c, ct, hi = TAIL["density_exponent"], TAIL["tail_exponent"], TAIL["chi_tail"]
    w = np.where(phi < hi, phi ** c, hi ** c * (phi / hi) ** ct) * phi  # density per unit ln(phi)
    for chi_a in (1e-4, 5e-3, 2e-2, 1.0):
        quad = TAIL["delta_EJ"] * np.trapezoid(w * jenkins_rigidity(phi / chi_a), u) / np.trapezoid(w, u)
        got = IwanTailLaw().slip_rigidity(chi_a, **TAIL)
        assert abs(got - quad) < 1e-5 * TAIL["delta_EJ"], chi_a


def test_a_steep_tail_is_iwan5_without_its_point_mass():
    chi = np.logspace(-5, 0, 11)
    steep = IwanTailLaw().slip_rigidity(chi, **dict(TAIL, tail_exponent=-2.49))
    sharp = Iwan5Law().slip_rigidity(chi, delta_EJ=50.0, chi_micro=2e-5, chi_macro=5e-3, density_exponent=-1.3,
                                     macro_ratio=0.0)
    below = chi < TAIL["chi_tail"]
    # not equal: the tail holds 1 / 1.49 of ln-decade's worth of wires beyond chi_macro; both stick alike below
    # the micro-slip onset and both lose all but the tail's rigidity far beyond chi_macro
    assert np.all(np.abs(steep - sharp)[below] < 0.2 * TAIL["delta_EJ"])
    assert abs(steep[-1]) < 0.05 * TAIL["delta_EJ"] and abs(sharp[-1]) < 0.05 * TAIL["delta_EJ"]
    assert np.isnan(IwanTailLaw().slip_rigidity(1e-3, **dict(TAIL, tail_exponent=-0.9)))
