"""The laws in time: each law's steady-loop branch (:meth:`HysteresisLaw.loop_branch`) and its periodic
operator for any periodic curvature (:meth:`HysteresisLaw.periodic_moment`), held to the law's own
``steady_loop`` and, with inner loops, to a plain time-stepping of the law."""

import numpy as np
import pytest

from sbcal.model.laws import law_for

LAWS = {
    "bouc_wen": dict(delta_EJ=20.0, chi_slip=0.01, sharpness=2.5),
    "bouc_wen_soft": dict(delta_EJ=20.0, chi_slip=0.01, sharpness=0.4),
    "dahl": dict(delta_EJ=20.0, chi_dahl=0.01),
    "iwan": dict(delta_EJ=55.0, chi_macro=0.02, micro_exponent=-0.5, macro_ratio=0.1),
    "iwan5": dict(delta_EJ=20.0, chi_micro=1e-3, chi_macro=0.05, density_exponent=-0.5, macro_ratio=0.2),
    "iwan_tail": dict(delta_EJ=20.0, chi_micro=1e-3, chi_tail=0.03, density_exponent=-0.5, tail_exponent=-1.8),
    "lognormal_iwan": dict(delta_EJ=20.0, chi_median=4e-3, log_spread=1.2),
}


def _law(key):
    return law_for(key.replace("_soft", "")), LAWS[key]


@pytest.mark.parametrize("key", sorted(LAWS))
@pytest.mark.parametrize("scale", [1e-3, 0.3, 3.0, 100.0])
def test_branch_is_the_steady_loop(key, scale):
    law, p = _law(key)
    a = scale * 0.01
    theta = np.linspace(0.0, np.pi, 17)
    ref = law.steady_loop(a, theta, **p)
    m, dm, dma = law.loop_branch(a * np.cos(theta), a, **p)
    # closed forms, Bouc-Wen's arc inverted by a Hermite table (<= 1.3e-9 in eta): 1e-8 of the loop
    assert np.max(np.abs(m - ref)) <= 1e-8 * np.max(np.abs(ref))
    # the slopes against differences of the branch itself
    chi = a * np.cos(theta[1:-1])
    h = 1e-6 * a
    up = law.loop_branch(chi + h, a, **p)[0]
    down = law.loop_branch(chi - h, a, **p)[0]
    np.testing.assert_allclose(dm[1:-1], (up - down) / (2 * h), rtol=2e-3, atol=1e-6 * p["delta_EJ"])
    turn = (law.loop_branch(chi, a + h, **p)[0] - law.loop_branch(chi, a - h, **p)[0]) / (2 * h)
    np.testing.assert_allclose(dma[1:-1], turn, rtol=2e-3, atol=1e-6 * p["delta_EJ"])


@pytest.mark.parametrize("key", ["bouc_wen", "dahl", "iwan", "iwan5", "lognormal_iwan"])
def test_periodic_operator_on_a_sine_is_the_steady_loop(key):
    law, p = _law(key)
    nt = 128
    theta = 2 * np.pi * np.arange(nt) / nt
    amps = np.array([3e-4, 3e-3, 3e-2, 0.3])
    chi = amps[:, None] * np.cos(theta)[None, :]  # samples include the turning points
    m = law.periodic_moment(chi, **{k: np.full((amps.size, 1), v) for k, v in p.items()})
    for i, a in enumerate(amps):
        ref = law.steady_loop(a, theta, **p)
        assert np.max(np.abs(m[i] - ref)) <= 1e-8 * np.max(np.abs(ref))


def _stepped(law_key, p, chi, periods=40, sub=400):
    """A plain reference: the law stepped in small increments over many periods (Euler for Bouc-Wen,
    a dense Jenkins population for Masing laws)."""
    law = law_for(law_key)
    if law_key in ("bouc_wen", "dahl"):
        n = p.get("sharpness", 1.0)
        ks = p.get("chi_slip", p.get("chi_dahl"))
        eta, prev, out = 0.0, chi[0], []
        for _ in range(periods):
            for c in chi:
                d = (c - prev) / sub
                for _ in range(sub):
                    eta += d / ks * (1 - np.sign(d) * abs(eta) ** (n - 1) * eta)
                prev = c
                out.append(eta)
        return p["delta_EJ"] * ks * np.array(out[-chi.size:])
    phi = np.geomspace(1e-7, 10.0, 40001)
    slope = np.gradient(law.backbone(phi, **p), phi)
    k, ph = -np.diff(slope), 0.5 * (phi[1:] + phi[:-1])
    z, prev, out = np.zeros_like(ph), 0.0, []
    for _ in range(3):
        for c in chi:
            z = np.clip(z + (c - prev), -ph, ph)
            prev = c
            out.append((k * z).sum() + slope[-1] * c)
    return np.array(out[-chi.size:])


@pytest.mark.parametrize("key", ["dahl", "bouc_wen", "iwan5"])
def test_periodic_operator_with_inner_loops(key):
    law, p = _law(key)
    nt = 64
    theta = 2 * np.pi * np.arange(nt) / nt
    chi = 0.02 * (np.cos(theta) + 0.5 * np.cos(3 * theta + 0.4))  # three maxima per period
    assert (np.diff(np.sign(np.diff(chi))) != 0).sum() > 2
    m = law.periodic_moment(chi[None, :], **{k: np.array([[v]]) for k, v in p.items()})
    ref = _stepped(key, p, chi, periods=30 if key != "iwan5" else 3, sub=100)
    # the references' own errors: Euler with 100 sub-steps ~1e-3 of the loop; the population's ~5e-4
    assert np.max(np.abs(m[0] - ref)) <= 2e-3 * np.max(np.abs(ref))


@pytest.mark.parametrize("key", ["dahl", "bouc_wen", "bouc_wen_soft", "iwan5", "lognormal_iwan"])
def test_periodic_derivatives_along_the_path(key):
    """The forward-mode derivatives (reversal points and the periodic state moving with the path)
    against central differences of the operator itself."""
    law, p = _law(key)
    nt = 96
    theta = 2 * np.pi * np.arange(nt) / nt
    chi = 0.02 * (np.cos(theta) + 0.5 * np.cos(3 * theta + 0.4))
    chi[np.argmax(chi)] *= 1.0  # the samples carry the turning points approximately; fine for a derivative check
    dirs = np.stack([np.cos(3 * theta), np.sin(theta), np.cos(5 * theta + 1.0)], axis=-1)  # smooth directions
    kw = {k: np.array([[v]]) for k, v in p.items()}
    m, dm = law.periodic_moment(chi[None], dirs[None], **kw)
    h = 1e-7
    for j in range(dirs.shape[1]):
        up = law.periodic_moment((chi + h * dirs[:, j])[None], **kw)
        down = law.periodic_moment((chi - h * dirs[:, j])[None], **kw)
        fd = (up - down)[0] / (2 * h)
        # tabulated Bouc-Wen arc: ~1e-9 noise over h = 1e-7 -> 1e-2 of delta_EJ chi_slip per unit
        assert np.max(np.abs(dm[0, :, j] - fd)) <= 2e-3 * np.max(np.abs(fd)) + 1e-2 * p["delta_EJ"] * 0.01


# tmdsimpy (github.com/tmd-lab/tmdsimpy at 17d5fc3), Iwan4Force.aft: Segalman's four-parameter Iwan element with
# kt = 2, Fs = 1e-3, chi = -0.5, beta = 0.1, 1e5 sliders, Nt = 4096, run outside the project; force
# harmonics (cos, sin) at 1, 3, 5 for u = A cos t (a) and u = A cos t + 0.2 A cos(3 t + 0.7) (b), A in
# units of its macro-slip displacement phi_max = Fs (1 + beta) / (kt (beta + (chi + 1) / (chi + 2))).
# Its sliders converge to the continuous law as N^-1.5 (to 8e-6, 2.5e-7, 8e-9 of |F1| at 1e3, 1e4, 1e5);
# both evaluate the same samples (turning points between samples cost both alike, 1e-6 at Nt = 4096).
_TMDSIMPY = {
    ("a", 0.2): (3.675298376332367e-04, -3.50406203638829e-05, 2.2248011418386898e-06, 6.1182021128675635e-06,
                 2.3337077484304113e-07, 1.1318475564404616e-06),
    ("a", 1.0): (9.713974834177223e-04, -3.917660165995533e-04, 2.4874032632158446e-05, 6.840358876152223e-05,
                 2.6091642727629822e-06, 1.2654446099950251e-05),
    ("a", 5.0): (5.842690491298535e-04, -1.096944795277674e-03, 3.373997789051777e-04, -3.4525137941280366e-05,
                 8.315026347568843e-05, 1.0045987965203228e-04),
    ("b", 0.2): (3.4824792077628485e-04, -5.3539580931039103e-05, 5.477199450007393e-05, -4.558398286030617e-05,
                 3.3097048348760974e-06, 1.8719801761679833e-06),
    ("b", 1.0): (7.401466300756363e-04, -6.238151548148955e-04, 1.2296360525062378e-04, -1.0440900222368659e-04,
                 3.526515507894099e-05, 2.5861523629468106e-05),
    ("b", 5.0): (2.0388804325373994e-04, -1.2428785479329922e-03, 1.796864692332425e-04, -3.3983998127468763e-04,
                 1.3840730315145048e-04, -1.3303385404806324e-04),
}


@pytest.mark.parametrize("case, ratio", sorted(_TMDSIMPY))
def test_iwan_harmonics_against_tmdsimpy(case, ratio):
    """The same element in sbcal's words (delta_EJ = kt, chi_macro = phi_max, micro_exponent = chi,
    macro_ratio = beta; the Jenkins elements' slip curvature for its slip displacement): the periodic
    operator's harmonics equal tmdsimpy's harmonic balance to its sliders' error (within 5e-8 of |F1|)."""
    kt, fs, chi, beta = 2.0, 1e-3, -0.5, 0.1
    phi_max = fs * (1 + beta) / (kt * (beta + (chi + 1) / (chi + 2)))
    params = dict(delta_EJ=kt, chi_macro=phi_max, micro_exponent=chi, macro_ratio=beta)
    nt = 4096
    t = 2 * np.pi * np.arange(nt) / nt
    a = ratio * phi_max
    u = a * np.cos(t) + (0.2 * a * np.cos(3 * t + 0.7) if case == "b" else 0.0)
    m = law_for("iwan").periodic_moment(u[None], **{k: np.array([[v]]) for k, v in params.items()})[0]
    ours = [2 / nt * np.sum(m * f(h * t)) for h in (1, 3, 5) for f in (np.cos, np.sin)]
    ref = np.array(_TMDSIMPY[(case, ratio)])
    assert np.max(np.abs(np.array(ours) - ref)) <= 5e-8 * np.hypot(ref[0], ref[1])
