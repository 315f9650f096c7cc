"""The distributed cable: the fast model (statically determinate arms) and the element model.

Fast model: the linear limit is the 6-DOF model exactly, the returned loads satisfy the arm equations
(checked by a plain evaluation with the law itself), batching and determinism, folds with
continuation. Element model: equivalence with the 6-DOF model, the fixed point, continuation.
"""

import math
import pickle
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest
from scipy.optimize import brentq

from sbcal.model.cable import DEFAULT_SECTIONS, CableModel, segments_from_frequencies
from sbcal.model.cable_element import DEFAULT_N_ELEMENTS, ElementCableModel
from sbcal.core.errors import InputError
from sbcal.model.fem import STANDARD_GRID_HZ, clamp_impedance, dynamic_stiffness
from sbcal.model.laws import DahlLaw, HysteresisLaw, IwanLaw, LawParameter, LognormalIwanLaw

G = STANDARD_GRID_HZ
DAHL = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_dahl=3e-3)
IWAN = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_macro=0.02, micro_exponent=-0.5, macro_ratio=0.1)
LOGNORMAL = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_median=4e-3, log_spread=1.5)


@dataclass(frozen=True)
class _SofteningLaw(HysteresisLaw):
    """Test-only: a strongly softening slip part with almost no friction (a Duffing-like cable).

    Not a Masing law (those dissipate as they soften, which keeps their folds rare): it makes two
    steady states near a resonance at low damping, as a softening oscillator has.
    """

    name: ClassVar[str] = "softening"
    parameters: ClassVar[tuple] = (LawParameter("delta_EJ", "N m^2", "stick rigidity"),
                                   LawParameter("chi_soft", "1/m", "softening curvature"))

    def _rigidity(self, chi, *, delta_EJ, chi_soft):
        return delta_EJ / (1 + (chi / chi_soft) ** 2) + 0j


# --- the fast model --------------------------------------------------------------------------------

@pytest.mark.parametrize("sections", [2, 5, DEFAULT_SECTIONS])
@pytest.mark.parametrize("geometry", ["damper1", "other_damper"])
def test_linear_cable_is_the_six_dof_model_exactly(request, geometry, sections):
    # a linear arm's flexibility integral is the inverse of the Hermite element's stiffness (any
    # Gauss rule with >= 2 points integrates it exactly) and the cable's inertia is the same
    # consistent mass: fem's f_uu to rounding, cable mass, rocking, clamp offset and per-set values
    d = request.getfixturevalue(geometry)
    sets = dict(EJ_min=np.array([9.0, 5.0, 30.0]), beta_material=np.array([0.2, 0.0, 0.05]),
                a1=np.array([0.02, 0.03, -0.01]), L2=np.array([0.15, 0.12, 0.18]))
    m = CableModel(None, sections=sections)
    for r in (0.0, 3.0):
        got = m.dynamic_stiffness(d, G, 0.5, rocking_rad_per_m=r, **sets)
        H = clamp_impedance(d, G, EJ=sets["EJ_min"], beta=sets["beta_material"], a1=sets["a1"], L2=sets["L2"])
        np.testing.assert_allclose(got, H[..., 0, 0] + r * H[..., 0, 1], rtol=1e-10)


def test_tiny_amplitude_is_the_stuck_cable(damper1):
    # at 1e-10 mm every section is below the table: the stuck tail, EJ* -> EJ_min (1 + i beta) +
    # delta_EJ. Dahl's friction loss grows like the curvature (Im EJ_slip* = 4 delta_EJ a / (3 pi
    # chi_dahl)): at these 1e-10 /m it is 3e-7 of the stuck loss, which moves f_uu by 2.5e-7 at most
    ej = DAHL["EJ_min"] + DAHL["delta_EJ"]
    beta = DAHL["EJ_min"] * 0.5 / ej
    got = CableModel(DahlLaw()).dynamic_stiffness(damper1, G, 1e-10, **dict(DAHL, beta_material=0.5))
    np.testing.assert_allclose(got, dynamic_stiffness(damper1, G, EJ=ej, beta=beta), rtol=1e-6)


def _node_masses(damper):
    """Per arm (from the clamp): its length, ``mu L / 420``, the mass node's block (end mass + consistent
    cable mass) and its coupling to the clamp node."""
    out = []
    for L, m, J, a in ((damper.L1, damper.m1, damper.J1, -damper.a1), (damper.L2, damper.m2, damper.J2, damper.a2)):
        c = damper.mu * L / 420
        m_node = np.array([[m + 156 * c, m * a - 22 * c * L], [m * a - 22 * c * L, J + m * a * a + 4 * c * L * L]])
        out.append((L, c, m_node, c * np.array([[54, 13 * L], [-13 * L, -3 * L * L]])))
    return out


def _plain_arm_check(damper, law, params, freq_hz, amp_mm, state):
    """An independent evaluation of the arm equations at the returned loads.

    Per arm and line, from the clamp (s = 0) to the mass node (s = L): the moment ``V (L - s) + M``,
    each Gauss section's curvature amplitude from ``a |EJ*(a)| = |M|`` by bracketing on the law
    itself, the node's motion ``q = q_rigid + int (L - s, 1) chi ds`` and its inertia
    ``omega^2 (M_node q + M_node,clamp q_clamp)`` (end mass + consistent cable mass). Returns the
    relative load mismatch (n_freq, 2), the section curvatures (n_freq, 2, Q) and f_uu (n_freq,).
    """
    lp = {k: params[k] for k in law.parameter_names}
    lin = params["EJ_min"] * (1 + 1j * params["beta_material"])
    xi, w = np.polynomial.legendre.leggauss(state.sections.size)
    s_frac, w = 0.5 * (xi + 1), 0.5 * w
    np.testing.assert_allclose(np.sort(s_frac), np.sort(state.sections), rtol=1e-14)
    x0 = amp_mm / 2 * 1e-3
    mismatch, curv = np.zeros((freq_hz.size, 2)), np.zeros((freq_hz.size, 2, s_frac.size))
    f_uu = -(2 * np.pi * freq_hz) ** 2 * damper.mc + 0j
    for arm, (L, c, m_node, m_cross) in enumerate(_node_masses(damper)):
        for k, f in enumerate(freq_hz):
            w2 = (2 * np.pi * f) ** 2
            V, M_tip = state.load[0, k, arm]
            s = s_frac * L
            chi = np.zeros(s.size, dtype=complex)
            for q, sq in enumerate(s):
                M = V * (L - sq) + M_tip
                g = lambda u: u + math.log(abs(lin + law.slip_rigidity(math.exp(u), **lp))) - math.log(abs(M))
                u = brentq(g, -40.0, 20.0, xtol=1e-14)
                curv[k, arm, q] = math.exp(u)
                chi[q] = M / (lin + law.slip_rigidity(math.exp(u), **lp))
            q_clamp = np.array([x0, 0.0])
            q = q_clamp + L * np.array([np.sum(w * (L - s) * chi), np.sum(w * chi)])
            load = w2 * (m_node @ q + m_cross @ q_clamp)
            mismatch[k, arm] = np.max(np.abs(load - [V, M_tip])) / np.max(np.abs([V, M_tip]))
            # the arm's vertical force on the clamp: -V - omega^2 (M_clamp q_clamp + M_clamp,node q)[0]
            f_uu[k] += (-V - w2 * c * (156 * x0 + 54 * q[0] - 13 * L * q[1])) / x0
    return mismatch, curv, f_uu


@pytest.mark.parametrize("law, params", [(DahlLaw(), DAHL), (LognormalIwanLaw(), LOGNORMAL)],
                         ids=["dahl", "lognormal"])
def test_state_satisfies_the_arm_equations(damper1, law, params):
    f = G[::2]
    st = CableModel(law).state(damper1, f, 0.5, **params)
    assert st.converged.all() and st.residual.max() < 1e-8
    mismatch, curv, f_uu = _plain_arm_check(damper1, law, params, f, 0.5, st)
    # the table interpolates the compliance to 3e-5 (Dahl) and 1e-6 (lognormal) at its worst
    # (docs/cable.md): the equations and the section curvatures hold to that (measured: 5e-5 and
    # 6e-6 at 0.1-2 mm); f_uu, an average over the arm, to 1e-7
    assert mismatch.max() < 1e-4
    np.testing.assert_allclose(st.curvature[0], curv, rtol=1e-4)
    np.testing.assert_allclose(st.f_uu[0], f_uu, rtol=1e-6)
    lp = {k: params[k] for k in law.parameter_names}
    lin = params["EJ_min"] * (1 + 1j * params["beta_material"])
    np.testing.assert_allclose(st.rigidity[0], lin + law.slip_rigidity(curv, **lp), rtol=1e-4)
    assert np.all(st.f_uu.imag > 0)  # passive
    lo, hi = st.curvature_range[..., 0], st.curvature_range[..., 1]
    flat = st.curvature.reshape(*st.curvature.shape[:2], -1)
    assert np.all(lo <= flat.min(axis=-1) * (1 + 1e-9)) and np.all(hi >= flat.max(axis=-1) * (1 - 1e-9))


def test_batching_and_determinism(damper1):
    # one Newton per (set, line, arm): any grouping of sets and lines gives the same numbers (to
    # the rounding of the reductions' blocking), and the same call the same bits
    m = CableModel(IwanLaw())
    sets = dict(IWAN, EJ_min=np.array([3.0, 5.0, 4.0]), chi_macro=np.array([0.01, 0.03, 0.02]))
    amp = np.concatenate([np.full(G.size, 0.2), np.where(G <= 10, 2.0, 1.0)])  # "0.2-0.2" then "2-1"
    f = np.concatenate([G, G])
    both = m.state(damper1, f, amp, **sets)
    assert both.converged.all()
    np.testing.assert_array_equal(both.f_uu, m.dynamic_stiffness(damper1, f, amp, **sets))
    for i in range(3):
        one = {k: (v[i] if np.ndim(v) else v) for k, v in sets.items()}
        for sl in (slice(0, G.size), slice(G.size, None), slice(5, 50)):
            alone = m.dynamic_stiffness(damper1, f[sl], amp[sl], **one)[0]
            np.testing.assert_allclose(both.f_uu[i, sl], alone, rtol=1e-12)
    again = pickle.loads(pickle.dumps(m)).state(damper1, f, amp, **sets)
    for name in ("f_uu", "load", "curvature", "rigidity", "curvature_range"):
        np.testing.assert_array_equal(getattr(again, name), getattr(both, name))


def test_a_fold_is_detected_with_continuation(damper1):
    f = np.arange(4.0, 40.0, 0.25)
    m = CableModel(_SofteningLaw())
    p = dict(EJ_min=4.0, beta_material=0.02, delta_EJ=20.0, chi_soft=3e-3)
    up = m.state(damper1, f, 0.1, continuation=True, **p)
    assert up.fold.any() and up.converged[up.fold].all()  # two steady states on those lines
    assert not m.state(damper1, f, 0.1, **p).fold.any()  # no continuation, no check
    # the response is hysteretic there: a sweep down the grid (one test) lands elsewhere
    down = m.state(damper1, f[::-1], 0.1, segments=np.zeros(f.size, dtype=int), continuation=True, **p)
    both = up.converged[0] & down.converged[0, ::-1]
    assert np.any(np.abs(down.f_uu[0, ::-1][both] / up.f_uu[0, both] - 1) > 1e-3)
    # a Masing law dissipates as it softens: no fold on the same cable
    assert not CableModel(DahlLaw()).state(damper1, f, 0.1, continuation=True, **DAHL).fold.any()


def test_outside_the_domain_is_nan_and_bad_input_is_one_line(damper1):
    m = CableModel(IwanLaw())
    st = m.state(damper1, G, 0.5, **dict(IWAN, micro_exponent=np.array([-0.5, -1.5])))
    assert np.all(np.isfinite(st.f_uu[0])) and np.all(np.isnan(st.f_uu[1])) and not st.converged[1].any()
    fast = m.dynamic_stiffness(damper1, G, 0.5, **dict(IWAN, micro_exponent=np.array([-0.5, -1.5])))
    np.testing.assert_array_equal(fast, st.f_uu)
    # a|EJ*(a)| falling somewhere (EJ_min 2, a softening of 20): a moment does not fix the curvature
    soft = CableModel(_SofteningLaw()).dynamic_stiffness(damper1, G, 0.5, EJ_min=np.array([2.0, 4.0]),
                                                         beta_material=0.02, delta_EJ=20.0, chi_soft=3e-3)
    assert np.all(np.isnan(soft[0])) and np.all(np.isfinite(soft[1]))
    with pytest.raises(InputError, match="unknown parameter 'EJ'"):
        m.state(damper1, G, 0.5, EJ=3.0, **IWAN)
    with pytest.raises(InputError, match="'chi_macro' is required"):
        m.state(damper1, G, 0.5, **{k: v for k, v in IWAN.items() if k != "chi_macro"})
    with pytest.raises(InputError, match="amplitude_mm_pp"):
        m.state(damper1, G, -1.0, **IWAN)
    with pytest.raises(InputError, match="sections"):
        CableModel(IwanLaw(), sections=1)


def test_fast_model_names_its_parameters():
    m = CableModel(LognormalIwanLaw(), sections=6)
    assert pickle.loads(pickle.dumps(m)).sections == 6
    assert m.parameter_names[:5] == ("EJ_min", "beta_material", "delta_EJ", "chi_median", "log_spread")
    assert "a1" in m.parameter_names and "rocking_rad_per_m" in m.parameter_names


# --- the element model ------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 3, 7])
def test_element_linear_massless_cable_is_the_six_dof_model_exactly(damper1, n):
    # static condensation of a uniform beam's interior nodes is exact: any N, any grading
    for grading in (1.0, 3.0):
        m = ElementCableModel(None, n_elements=n, grading=grading)
        got = m.dynamic_stiffness(damper1, G, 0.5, EJ_min=9.0, beta_material=0.2, mu=0.0)
        ref = dynamic_stiffness(damper1, G, EJ=9.0, beta=0.2, mu=0.0)
        np.testing.assert_allclose(got, ref, rtol=1e-10)


def test_element_linear_cable_with_mass_converges_to_the_beam(damper1):
    ref = dynamic_stiffness(damper1, G, EJ=9.0, beta=0.2)
    one = ElementCableModel(None, n_elements=1).dynamic_stiffness(damper1, G, 0.5, EJ_min=9.0, beta_material=0.2)
    np.testing.assert_allclose(one, ref, rtol=1e-12)  # one element is the 6-DOF model itself
    errors = [np.max(np.abs(ElementCableModel(None, n_elements=n).dynamic_stiffness(
        damper1, G, 0.5, EJ_min=9.0, beta_material=0.2) / ref - 1)) for n in (2, 4, 8, 16)]
    # consistent mass: the 1-element model is already within 6e-4 of the converged one; the
    # differences between successive meshes fall (the mesh converges)
    assert errors[-1] < 1e-3
    steps = np.abs(np.diff(errors))
    assert np.all(steps[1:] < steps[:-1])


def test_element_slip_part_vanishes_with_mu_zero_for_any_n(damper1):
    # delta_EJ -> 0: the law's slip part is gone, the cable is linear (massless: exact for any N)
    for n in (2, 5):
        got = ElementCableModel(DahlLaw(), n_elements=n).dynamic_stiffness(
            damper1, G, 1.0, EJ_min=9.0, beta_material=0.2, delta_EJ=1e-12, chi_dahl=1e-3, mu=0.0)
        np.testing.assert_allclose(got, dynamic_stiffness(damper1, G, EJ=9.0, beta=0.2, mu=0.0), rtol=1e-10)


def test_element_tiny_amplitude_is_the_stuck_cable(damper1):
    # at 1e-10 mm the wires stick: EJ* = EJ_min (1 + i beta) + delta_EJ, a linear cable (Dahl's
    # friction loss grows like the amplitude: at 1e-6 mm it still moves the resonance peak by 1e-3)
    ej = DAHL["EJ_min"] + DAHL["delta_EJ"]
    beta = DAHL["EJ_min"] * 0.5 / ej
    got = ElementCableModel(DahlLaw(), n_elements=4).dynamic_stiffness(damper1, G, 1e-10, mu=0.0, **dict(DAHL, beta_material=0.5))
    np.testing.assert_allclose(got, dynamic_stiffness(damper1, G, EJ=ej, beta=beta, mu=0.0), rtol=1e-6)


def test_element_base_rocking_is_f_uu_plus_r_f_uphi(damper1):
    got = ElementCableModel(None, n_elements=3).dynamic_stiffness(damper1, G, 0.5, EJ_min=9.0, beta_material=0.2,
                                                          mu=0.0, rocking_rad_per_m=3.0, ac=0.004)
    H = clamp_impedance(damper1, G, EJ=9.0, beta=0.2, mu=0.0, ac=0.004)
    np.testing.assert_allclose(got, H[..., 0, 0] + 3.0 * H[..., 0, 1], rtol=1e-10)


def _dense_arm(damper, freq_hz, amp_mm, rigidity, arm, mesh):
    """Plain assembly of one arm on a mesh (node positions as fractions of the arm, clamp node 0 .. end
    mass; the zoned cables' meshes are not uniform) and a dense solve: each element's rms curvature."""
    L, m, J, a = ((damper.L1, damper.m1, damper.J1, -damper.a1) if arm == 0 else
                  (damper.L2, damper.m2, damper.J2, damper.a2))
    n = mesh.size - 1
    out = []
    for k, f in enumerate(freq_hz):
        w2 = (2 * np.pi * f) ** 2
        Z = np.zeros((2 * n + 2, 2 * n + 2), dtype=complex)
        for e in range(n):
            h = L * (mesh[e + 1] - mesh[e])
            K = np.array([[12, 6 * h, -12, 6 * h], [6 * h, 4 * h * h, -6 * h, 2 * h * h],
                          [-12, -6 * h, 12, -6 * h], [6 * h, 2 * h * h, -6 * h, 4 * h * h]]) / h**3
            M = damper.mu * h / 420 * np.array([[156, 22 * h, 54, -13 * h], [22 * h, 4 * h * h, 13 * h, -3 * h * h],
                                                [54, 13 * h, 156, -22 * h], [-13 * h, -3 * h * h, -22 * h, 4 * h * h]])
            Z[2 * e:2 * e + 4, 2 * e:2 * e + 4] += rigidity[k, e] * K - w2 * M
        Z[-2:, -2:] -= w2 * np.array([[m, m * a], [m * a, J + m * a * a]])
        xb = np.array([amp_mm / 2 * 1e-3, 0.0])
        x = np.concatenate([xb, np.linalg.solve(Z[2:, 2:], -Z[2:, :2] @ xb)])
        rms = []
        for e in range(n):
            h = L * (mesh[e + 1] - mesh[e])
            wa, ta, wb, tb = x[2 * e:2 * e + 4]
            c0 = (-6 * wa - 4 * h * ta + 6 * wb - 2 * h * tb) / h**2
            c1 = (6 * wa + 2 * h * ta - 6 * wb + 4 * h * tb) / h**2
            rms.append(np.sqrt((abs(c0) ** 2 + abs(c1) ** 2 + (c0 * np.conj(c1)).real) / 3))
        out.append(rms)
    return np.array(out)


@pytest.mark.parametrize("law, params", [(DahlLaw(), DAHL), (IwanLaw(), IWAN)], ids=["dahl", "iwan"])
def test_element_state_is_a_fixed_point_of_the_plain_assembly(damper1, law, params):
    n = 4
    st = ElementCableModel(law, n_elements=n).state(damper1, G, 0.5, **params)
    assert st.converged.all() and st.residual.max() < 1e-9
    for arm in (0, 1):
        # the returned rigidities are the law at the returned curvatures ...
        lp = {k: params[k] for k in law.parameter_names}
        expect = params["EJ_min"] * (1 + 1j * params["beta_material"]) + law.slip_rigidity(st.curvature[0, :, arm], **lp)
        np.testing.assert_allclose(st.rigidity[0, :, arm], expect, rtol=1e-12)
        # ... and a dense solve with those rigidities gives back the curvatures (to the tolerance)
        dense = _dense_arm(damper1, G, 0.5, st.rigidity[0, :, arm], arm, np.linspace(0.0, 1.0, n + 1))
        np.testing.assert_allclose(st.curvature[0, :, arm], dense, rtol=1e-8)
    assert np.all(st.f_uu.imag > 0)  # passive
    assert st.curvature.shape == (1, G.size, 2, n) and st.mesh.shape == (n + 1,)
    lo, hi = st.curvature_range[..., 0], st.curvature_range[..., 1]
    assert np.all(lo <= hi) and np.all(lo > 0)


def test_element_vectorised_over_sets_and_tests(damper1):
    m = ElementCableModel(IwanLaw(), n_elements=3)
    sets = dict(IWAN, EJ_min=np.array([3.0, 5.0]), chi_macro=np.array([0.01, 0.03]))
    amp = np.concatenate([np.full(G.size, 0.2), np.where(G <= 10, 2.0, 1.0)])  # "0.2-0.2" then "2-1"
    f = np.concatenate([G, G])
    both = m.state(damper1, f, amp, **sets)
    assert both.f_uu.shape == (2, 2 * G.size)
    for i in range(2):
        one = {k: (v[i] if np.ndim(v) else v) for k, v in sets.items()}
        for t, sl in enumerate((slice(0, G.size), slice(G.size, None))):
            alone = m.dynamic_stiffness(damper1, G, amp[sl], **one)[0]
            np.testing.assert_allclose(both.f_uu[i, sl], alone, rtol=1e-7)
    np.testing.assert_array_equal(segments_from_frequencies(f), np.repeat([0, 1], G.size))


def test_element_deterministic(damper1):
    m = ElementCableModel(DahlLaw())
    a = m.dynamic_stiffness(damper1, G, 2.0, **DAHL)
    b = m.dynamic_stiffness(damper1, G, 2.0, **DAHL)
    np.testing.assert_array_equal(a, b)
    assert DEFAULT_N_ELEMENTS == m.n_elements


def test_element_fold_is_detected_and_flagged(damper1):
    f = np.arange(4.0, 40.0, 0.25)
    m = ElementCableModel(_SofteningLaw(), n_elements=2)
    p = dict(EJ_min=2.0, beta_material=0.02, delta_EJ=20.0, chi_soft=3e-3)
    st = m.state(damper1, f, 0.1, **p)
    assert st.fold.any() and st.converged[st.fold].any()  # two steady states on those lines
    # the frequency response is hysteretic there: a sweep down the grid (another test) lands elsewhere
    down = m.state(damper1, f[::-1], 0.1, segments=np.zeros(f.size, dtype=int), **p).f_uu[0, ::-1]
    both = st.converged[0] & m.state(damper1, f[::-1], 0.1, segments=np.zeros(f.size, dtype=int), **p).converged[0, ::-1]
    assert np.any(np.abs(down[both] / st.f_uu[0, both] - 1) > 1e-3)
    # a Masing law dissipates as it softens: no fold on the same cable
    assert not ElementCableModel(DahlLaw(), n_elements=2).state(damper1, f, 0.1, **DAHL).fold.any()


def test_element_outside_the_domain_is_nan_and_bad_input_is_one_line(damper1):
    m = ElementCableModel(IwanLaw(), n_elements=2)
    st = m.state(damper1, G, 0.5, **dict(IWAN, micro_exponent=np.array([-0.5, -1.5])))
    assert np.all(np.isfinite(st.f_uu[0])) and np.all(np.isnan(st.f_uu[1])) and not st.converged[1].any()
    with pytest.raises(InputError, match="unknown parameter 'EJ'"):
        m.state(damper1, G, 0.5, EJ=3.0, **IWAN)
    with pytest.raises(InputError, match="'chi_macro' is required"):
        m.state(damper1, G, 0.5, **{k: v for k, v in IWAN.items() if k != "chi_macro"})
    with pytest.raises(InputError, match="amplitude_mm_pp"):
        m.state(damper1, G, -1.0, **IWAN)
    with pytest.raises(InputError, match="n_elements"):
        ElementCableModel(IwanLaw(), n_elements=0)


def test_element_model_is_picklable_and_names_its_parameters():
    m = ElementCableModel(LognormalIwanLaw(), n_elements=5, grading=2.0)
    assert pickle.loads(pickle.dumps(m)).n_elements == 5
    assert m.parameter_names[:5] == ("EJ_min", "beta_material", "delta_EJ", "chi_median", "log_spread")
    assert "a1" in m.parameter_names and "rocking_rad_per_m" in m.parameter_names
