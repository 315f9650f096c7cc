"""The fast cable model's compiled kernel against its numpy formulation (``tests/cable_reference.py``).

Both run the same arithmetic in a different order (fused loops against whole-array passes, sums over
the sections by hand against a matrix product), so they agree to rounding: relative differences of
~1e-14 in ``f_uu`` and the loads, measured on the benchmark's random sets; the bound 1e-10 leaves four
orders for the Newton's amplification near resonances. A Newton stop decided differently (an error
estimate within rounding of ``tol``) would show as a ~1e-8 difference: none may.
"""

import numpy as np
import pytest

from sbcal.model.cable import CableModel
from sbcal.model.cable_sections import compliance_table
from sbcal.model.fem import STANDARD_GRID_HZ
from sbcal.model.laws import law_for
from tests.cable_reference import NumpyCableModel, _lookup

G = STANDARD_GRID_HZ
AMPS = np.concatenate([np.full(G.size, a) for a in (0.02, 0.1, 0.5, 2.0, 8.0)])  # tails of the table too
FREQ = np.concatenate([G] * 5)


def _sets(law, n, seed):
    """Random sets in boxes like the priors' (each law's own parameters)."""
    rng = np.random.default_rng(seed)
    u = lambda lo, hi: rng.uniform(lo, hi, n)  # noqa: E731
    logu = lambda lo, hi: np.exp(rng.uniform(np.log(lo), np.log(hi), n))  # noqa: E731
    base = dict(EJ_min=u(3, 7), beta_material=u(0.0, 0.1), delta_EJ=u(30, 60), a1=u(0.03, 0.04))
    own = {
        "dahl": dict(chi_dahl=logu(1e-3, 5e-3)),
        "iwan": dict(chi_macro=logu(5e-3, 5e-2), micro_exponent=u(-0.7, 0.0), macro_ratio=u(0.0, 0.5)),
        "lognormal_iwan": dict(chi_median=logu(1e-3, 5e-3), log_spread=1.5),  # one spread per call
        "bouc_wen": dict(chi_slip=logu(1e-3, 1e-2), sharpness=u(0.5, 3.0)),
        "iwan5_zoned": dict(chi_micro=logu(1e-5, 5e-5), chi_macro=logu(5e-3, 2e-2), density_exponent=u(-0.9, -0.5),
                            macro_ratio=u(0.1, 0.3), clamp_zone=u(0.1, 0.3), clamp_EJ_min_ratio=u(1.5, 2.5),
                            clamp_delta_EJ_ratio=u(2, 3), clamp_moment_ratio=u(5, 10), mass_zone=u(0.05, 0.15),
                            mass_EJ_min_ratio=u(1.2, 1.8), mass_delta_EJ_ratio=u(1.2, 1.8), mass_moment_ratio=u(2, 4)),
    }[law]
    return {**base, **own}


def _rel(a, b):
    return np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300))


@pytest.mark.parametrize("law", ["dahl", "iwan", "lognormal_iwan", "bouc_wen", "iwan5_zoned"])
def test_kernel_is_the_numpy_formulation_to_rounding(damper1, law):
    params = _sets(law, 6, seed=len(law))
    fast, ref = CableModel(law_for(law)), NumpyCableModel(law_for(law))
    got = fast.state(damper1, FREQ, AMPS, **params)
    want = ref.state(damper1, FREQ, AMPS, **params)
    assert want.converged.mean() > 0.99  # the comparison is of solved states
    assert _rel(got.f_uu, want.f_uu) < 1e-10
    assert _rel(got.load, want.load) < 1e-10
    assert _rel(got.rigidity, want.rigidity) < 1e-10
    assert _rel(got.curvature_range, want.curvature_range) < 1e-10
    np.testing.assert_array_equal(got.converged, want.converged)
    np.testing.assert_allclose(got.residual, want.residual, rtol=1e-6, atol=1e-12)  # estimates of ~1e-9


def test_kernel_continuation_and_folds_match(damper1):
    # the continuation re-solves lines from other starts (the predecessor's state, the stuck cable)
    params = _sets("iwan", 4, seed=3)
    got = CableModel(law_for("iwan")).state(damper1, FREQ, AMPS, continuation=True, **params)
    want = NumpyCableModel(law_for("iwan")).state(damper1, FREQ, AMPS, continuation=True, **params)
    assert _rel(got.f_uu, want.f_uu) < 1e-10
    np.testing.assert_array_equal(got.fold, want.fold)
    assert got.iterations == want.iterations


def test_kernel_lookup_is_the_table_everywhere(damper1):
    # inside the nodes (the cubic), beyond them on both sides (the exponential tails), at |M| = 0 and NaN
    law = law_for("iwan")
    p = _sets("iwan", 3, seed=1)
    lp = {k: p[k][:, None] for k in law.parameter_names}
    table = compliance_table(law, lp, p["EJ_min"] * (1 + 1j * p["beta_material"]), 96, 3.0)
    rng = np.random.default_rng(0)
    y = rng.uniform(table.y0.min() - 20, table.y_end.max() + 20, 3000)
    rows = rng.integers(0, 3, y.size)
    m2 = np.exp(y)
    got = CableModel._lookup_many(table, m2, rows)
    want = _lookup(table, m2, rows)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-300)  # the tails: exp, cos, sin against complex exp
    zero = CableModel._lookup_many(table, np.zeros(3), np.arange(3))
    np.testing.assert_allclose(zero[0] + 1j * zero[1], table.refs[:, 0], rtol=1e-15)  # |M| = 0: the stuck cable
    nan = CableModel._lookup_many(table, np.full(3, np.nan), np.arange(3))
    assert np.isnan(np.array(nan)).all()


def test_kernel_gives_nan_outside_the_domain_like_the_model(damper1):
    params = _sets("dahl", 3, seed=2)
    params["EJ_min"][1] = -1.0
    got = CableModel(law_for("dahl")).dynamic_stiffness(damper1, G, 0.5, **params)
    assert np.isnan(got[1]).all() and np.isfinite(got[[0, 2]]).all()


@pytest.mark.parametrize("crowd", [1.0, 1e-3, 1e-6])
def test_buckets_are_those_of_a_search(crowd):
    """The compiled bucket walk (``cable_kernel.buckets``) gives the intervals and comparison count of a binary
    search over the sets' nodes (its numpy formulation, here), with nodes spread evenly or crowded into a
    ``crowd`` of the span (as where the moment saturates), so that the bucket count doubles."""
    from sbcal.model import cable_kernel

    rng = np.random.default_rng(5)
    s, n = 7, 96
    gaps = rng.uniform(0.1, 1.0, (s, n - 1))
    gaps[:, 40:70] *= crowd
    y = np.concatenate([rng.uniform(-30, 0, (s, 1)), gaps], axis=1).cumsum(axis=1)
    y0, span, rows = y[:, 0], y[:, -1] - y[:, 0], np.arange(s)
    for nb in (8 * (n - 1), 64 * n):
        first, steps = cable_kernel.buckets(y, y0, span, nb)
        edges = y0[:, None] + span[:, None] * (np.arange(nb) / nb)[None, :]
        z = (y - y0[:, None]) / span[:, None] + 2.0 * rows[:, None]
        ze = (edges - y0[:, None]) / span[:, None] + 2.0 * rows[:, None]
        pos = np.searchsorted(z.ravel(), ze.ravel(), side="right").reshape(s, nb) - n * rows[:, None]
        np.testing.assert_array_equal(first, np.clip(pos - 1, 0, n - 2))
        assert steps == int(np.max(np.diff(np.concatenate([pos, np.full((s, 1), n)], axis=1), axis=1)))
        if crowd < 1:
            assert steps > 1  # the crowded nodes: more than one comparison even at the most buckets


@pytest.mark.parametrize("law", ["iwan", "bouc_wen", "iwan5_zoned"])
def test_newton_from_a_nearby_state_is_the_same_solve_in_fewer_evaluations(damper1, law):
    # a fit's posterior: sets within a few % of one another; Newton from one's loads instead of the slipped cable
    one = {k: np.atleast_1d(v)[:1] for k, v in _sets(law, 1, seed=7).items()}
    rng = np.random.default_rng(3)
    near = {k: v * np.exp(0.02 * rng.standard_normal(8)) if k != "log_spread" else v for k, v in one.items()}
    model = CableModel(law_for(law))
    start = model.loads(damper1, FREQ, AMPS, **one)
    assert start.shape == (2, 2 * FREQ.size)
    cold = model.dynamic_stiffness(damper1, FREQ, AMPS, **near)
    warm = model.dynamic_stiffness(damper1, FREQ, AMPS, start=start, **near)
    # both stop once the loads' error estimate is below tol = 1e-8; f_uu then agrees with a 1e-12 solve to
    # ~1e-6 (docs/cable.md, "Newton"): two such solves differ by at most twice that
    assert _rel(warm, cold) < 1e-5
    # the evaluations it saves (the sampler's path runs the same _solve)
    p, n_sets, _ = model._parameters(damper1, near)
    table = model._table(p, n_sets)
    x0 = np.broadcast_to(AMPS, FREQ.shape) / 2 * 1e-3
    arms = model._arms(p, n_sets, 2 * np.pi * FREQ, x0, model._zone_rule(p, n_sets) if model.zoned else None)
    assert model._solve(table, arms, n_sets, start)[2].mean() < 0.8 * model._solve(table, arms, n_sets, None)[2].mean()


def test_newton_from_a_start_that_does_not_converge_is_the_slipped_cables_solve(damper1):
    params = _sets("iwan", 4, seed=1)
    model = CableModel(law_for("iwan"))
    cold = model.dynamic_stiffness(damper1, FREQ, AMPS, **params)
    # zero loads cannot move (a step is at most half of |p|): every entry falls back to the slipped cable's start
    zero = np.zeros((2, 2 * FREQ.size), complex)
    np.testing.assert_array_equal(model.dynamic_stiffness(damper1, FREQ, AMPS, start=zero, **params), cold)
    with pytest.raises(ValueError, match=r"start: shape \(2, 10\)"):
        model.dynamic_stiffness(damper1, FREQ, AMPS, start=zero[:, :10], **params)
    with pytest.raises(ValueError, match="4 parameter sets given, expected one"):
        model.loads(damper1, FREQ, AMPS, **params)
    outside = dict(params, delta_EJ=np.array([40.0, -1.0, 40.0, 40.0]))  # one set outside the law's domain
    with pytest.raises(ValueError, match="4 parameter sets given, expected one"):
        model.loads(damper1, FREQ, AMPS, **outside)
    assert np.isnan(model.loads(damper1, FREQ, AMPS, **{k: v[1:2] for k, v in outside.items()})).all()
