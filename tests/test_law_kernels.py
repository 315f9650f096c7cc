"""The laws' compiled periodic operators (:mod:`sbcal.model.laws.kernels`) against their numpy formulation
(``tests/law_reference.py``): the moments and their derivatives along the path to 1e-10, with inner
loops (several maxima per period), flat steps, micro-slip and saturation; Bouc-Wen's turning state;
and the harmonic balance on either."""

import subprocess
import sys

import numpy as np
import pytest

from sbcal.model.laws.bouc_wen import _bw_turning
from sbcal.model.cable import CableModel
from sbcal.model.cable_harmonics import HarmonicBalance
from sbcal.model.fem import STANDARD_GRID_HZ as G
from sbcal.model.laws import law_for

from .law_reference import bw_turning_reference, iwan5_rigidity_reference, reference_law
from .test_law_periodic import LAWS, _law

NT = 96


def _paths():
    """Curvature paths over one period (rows): a sine, and sines with third and fifth harmonics strong
    enough for two and three maxima per period, from micro-slip to saturation; one with flat steps."""
    rng = np.random.default_rng(7)
    theta = 2 * np.pi * np.arange(NT) / NT
    rows = [0.01 * np.cos(theta)]
    for scale in (1e-4, 3e-3, 0.02, 0.3):
        for ratio in (0.3, 0.6, 1.5):
            rows.append(scale * (np.cos(theta + rng.uniform(0, 6)) + ratio * np.cos(3 * theta + rng.uniform(0, 6))
                                 + 0.4 * ratio * np.cos(5 * theta + rng.uniform(0, 6))))
    flat = 0.02 * np.cos(theta)
    flat[10:14] = flat[10]  # a step with no change (the direction is kept)
    rows.append(flat)
    chi = np.array(rows)
    dirs = np.stack([np.cos(theta), np.sin(3 * theta), np.cos(5 * theta + 1.0), np.ones(NT)], axis=-1)
    return chi, np.broadcast_to(dirs, chi.shape + dirs.shape[1:]).copy()


def _maxima(chi):
    return (np.diff(np.sign(np.diff(chi, append=chi[:, :1], axis=1)), append=0, axis=1) < 0).sum(axis=1)


def _per_row_reference(law, chi, dirs, params):
    """The numpy operator row by row: its period-map Newton stops when every row of a call has converged
    (a row's last digits hang on its neighbours'); the compiled one stops per row."""
    ref = reference_law(law)
    out = [ref.periodic_moment(chi[i:i + 1], dirs[i:i + 1], **{k: v[i:i + 1] for k, v in params.items()})
           for i in range(chi.shape[0])]
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


@pytest.mark.parametrize("key", sorted(LAWS))
def test_compiled_periodic_operator_is_the_numpy_one(key):
    law, p = _law(key)
    chi, dirs = _paths()
    assert _maxima(chi).max() >= 3 and (_maxima(chi) == 1).any()
    params = {k: np.full((chi.shape[0], 1), v) for k, v in p.items()}
    m, dm = law.periodic_moment(chi, dirs, **params)
    m_ref, dm_ref = _per_row_reference(law, chi, dirs, params)
    scale = np.max(np.abs(m_ref), axis=1, keepdims=True)
    assert np.max(np.abs(m - m_ref) / scale) <= 1e-10
    assert np.max(np.abs(dm - dm_ref) / np.max(np.abs(dm_ref), axis=(1, 2), keepdims=True)) <= 1e-10


@pytest.mark.parametrize("exponents", [2, 70])
def test_bouc_wen_with_many_exponents(exponents):
    """Rows of several exponents: one inverse-arc table each (up to 64), else Newton on the arc. The
    reference then needs all rows in one call, and its Newton on the period map runs until every row's
    map is within 1e-13: in micro-slip, where the map contracts slowly (``1 - d eta_end / d eta0 ~
    1e-4``), a state that close is still ~1e-9 from its fixed point, so the rows' last steps differ
    by that much; those rows (curvatures below a tenth of ``chi_slip``) are left out here."""
    law = law_for("bouc_wen")
    chi, dirs = _paths()
    keep = np.abs(chi).max(axis=1) > 1e-3
    chi, dirs = chi[keep], dirs[keep]
    rows = np.arange(max(exponents, chi.shape[0])) % chi.shape[0]
    chi, dirs = chi[rows], dirs[rows]
    n = np.linspace(0.4, 4.0, exponents)[np.arange(rows.size) % exponents]
    params = dict(delta_EJ=np.full((n.size, 1), 20.0), chi_slip=np.full((n.size, 1), 0.01), sharpness=n[:, None])
    m, dm = law.periodic_moment(chi, dirs, **params)
    if exponents < 64:
        m_ref, dm_ref = _per_row_reference(law, chi, dirs, params)
    else:
        m_ref, dm_ref = reference_law(law).periodic_moment(chi, dirs, **params)
    assert np.max(np.abs(m - m_ref)) <= 1e-10 * np.max(np.abs(m_ref))
    assert np.max(np.abs(dm - dm_ref)) <= 1e-10 * np.max(np.abs(dm_ref))


def test_bouc_wen_turning_state():
    """Newton in ``-ln(1 - eta_a)`` (compiled) against the numpy Newton in ``eta_a``: to a few ulps, and to
    the double below 1 in saturation."""
    a = np.concatenate([[0.0], np.geomspace(1e-9, 1e4, 300)])
    for n in (0.3, 1.0, 2.0, 5.0):
        ours, ref = _bw_turning(a, n), bw_turning_reference(a, n)
        assert np.all(np.abs(ours - ref) <= 4 * np.spacing(ref))


@pytest.mark.parametrize("name, params, harmonics", [
    pytest.param("bouc_wen", dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_slip=3e-3, sharpness=2.0), 5,
                 marks=pytest.mark.slow),
    ("iwan5", dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_micro=1e-3, chi_macro=0.02,
                   density_exponent=-0.5, macro_ratio=0.1), 5)])
def test_harmonic_balance_on_the_compiled_operators(damper1, name, params, harmonics):
    """Near the first resonance at 2 mm (inner loops at every line), the harmonic balance on the compiled
    operators equals the one on the numpy reference to 1e-10 (f_uu and the distortion)."""
    lines = G[[5, 8, 12]]
    law = law_for(name)
    st = HarmonicBalance(CableModel(law=law), harmonics=harmonics).state(damper1, lines, 2.0, **params)
    ref = HarmonicBalance(CableModel(law=reference_law(law)), harmonics=harmonics).state(damper1, lines, 2.0, **params)
    assert st.converged.all() and not st.single_loop.any()
    assert np.max(np.abs(st.f_uu / ref.f_uu - 1)) <= 1e-10
    assert np.max(np.abs(st.distortion / ref.distortion - 1)) <= 1e-10


def test_iwan5_describing_function_is_the_numpy_one():
    """The compiled five-parameter Iwan law (:mod:`sbcal.model.laws.iwan_kernel`) against its numpy formulation
    over the whole domain: stuck, micro- and macro-slip, both ends of the incomplete beta's series switch,
    ``c`` over its box, one cut-off a hair above the other, and ``p = c + 1`` within the interpolation band
    around 0. Measured against ``delta_EJ`` (the law's scale: the real part alone cancels to ~1e-10 of it
    deep in macro-slip): 1e-12 of it apart from rounding (measured 1.1e-12 on 2e5 points); near p = 0 the
    formulation's own 1/p cancellation amplifies rounding by ~1/_P_ZERO = 1e6 (measured 1.2e-9)."""
    rng = np.random.default_rng(11)
    n = 20000
    p = dict(delta_EJ=rng.uniform(1, 60, n), chi_micro=10 ** rng.uniform(-7, -1, n),
             density_exponent=rng.uniform(-2.4, 2, n), macro_ratio=rng.uniform(0, 5, n))
    p["chi_macro"] = p["chi_micro"] * 10 ** rng.uniform(1e-4, 6, n)
    chi = 10 ** rng.uniform(-8, 1, n)
    chi[:500] = p["chi_micro"][:500] * rng.uniform(0.5, 1.0, 500)  # stuck, and right at the lower cut-off
    chi[500:1000] = p["chi_macro"][500:1000] / rng.choice([0.3, 0.2999, 0.3001, 1.0, 0.9999], 500)
    near = np.zeros(n, dtype=bool)
    near[1000:1500] = True
    p["density_exponent"][near] = -1.0 + rng.uniform(-2e-6, 2e-6, 500)
    compiled = law_for("iwan5").slip_rigidity(chi, **p)
    reference = iwan5_rigidity_reference(chi, **p)
    gap = np.abs(compiled - reference) / p["delta_EJ"]
    assert np.all(np.isfinite(compiled))
    assert gap[~near].max() < 1e-11
    assert gap[near].max() < 1e-8
    # on a parameter grid broadcast against the curvatures, as the compliance table calls it
    grid = {k: v[:40, None] for k, v in p.items()}
    chis = 10 ** np.linspace(-8, 1, 96)[None, :]
    np.testing.assert_allclose(law_for("iwan5").slip_rigidity(chis, **grid),
                               iwan5_rigidity_reference(chis, **grid), rtol=0, atol=1e-11 * 60)
    # broadcast views reach the kernel without a warning: numba reads its arguments' flags when it types a
    # call, and a broadcast view's warns (a fresh process: typing happens on its first call)
    calls = ("import numpy as np; from sbcal.model.laws import law_for; "
             "law_for('iwan5').slip_rigidity(np.array([1e-3]), delta_EJ=40., chi_micro=1e-5, chi_macro=1e-2, "
             "density_exponent=-0.5, macro_ratio=0.1); "
             "law_for('iwan_tail').slip_rigidity(np.array([1e-3]), delta_EJ=40., chi_micro=1e-5, chi_tail=1e-2, "
             "density_exponent=-0.5, tail_exponent=-1.5)")
    done = subprocess.run([sys.executable, "-W", "error", "-c", calls], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-400:]


def test_tail_law_on_the_compiled_slip_integral_is_the_numpy_one():
    """The Iwan law with a power-law tail uses the compiled slip integral at both of its segments: against
    the numpy integral (``tests/law_reference.py``) to 1e-11 of ``delta_EJ`` over its domain, both sides of
    ``chi_tail`` and within the p = 0 band (1e-8 there, as for ``iwan5``)."""
    rng = np.random.default_rng(12)
    n = 20000
    p = dict(delta_EJ=rng.uniform(1, 60, n), chi_micro=10 ** rng.uniform(-7, -1, n),
             density_exponent=rng.uniform(-2.4, 2, n), tail_exponent=rng.uniform(-2.45, -1.05, n))
    p["chi_tail"] = p["chi_micro"] * 10 ** rng.uniform(1e-4, 6, n)
    chi = 10 ** rng.uniform(-8, 1, n)
    near = np.zeros(n, dtype=bool)
    near[:500] = True
    p["density_exponent"][near] = -1.0 + rng.uniform(-2e-6, 2e-6, 500)
    law = law_for("iwan_tail")
    gap = np.abs(law.slip_rigidity(chi, **p) - reference_law(law).slip_rigidity(chi, **p)) / p["delta_EJ"]
    assert np.all(np.isfinite(gap))
    assert gap[~near].max() < 1e-11
    assert gap[near].max() < 1e-8
