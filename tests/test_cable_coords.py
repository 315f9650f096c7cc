"""The cable fit's sampled coordinates: ``delta_EJ`` sheared by the share of the drop the bench sees, the same
posterior in other coordinates."""

import pickle

import numpy as np
import pytest

from sbcal.data.clean_bench import clean_bench
from sbcal.data.labels import state_tests
from sbcal.data.readers import default_bench_path, load_bench
from sbcal.inference.cable_coords import (SHARE_FLOOR, SeenRatio, SeenShare, reference_curvature, seen_share_target,
                                         unseen_onsets)
from sbcal.inference.cable_fit import _near, cable_likelihood
from sbcal.inference.priors import Prior, Shear
from sbcal.model.laws import law_for


def _tilt(params):
    """A stand-in offset: a function of the other parameters, NaN outside a domain (b > 0.9)."""
    return np.where(params["b"] > 0.9, np.nan, -3.0 * params["b"] + 0.5 * np.log(params["c"]))


def _prior():
    return Prior.from_boxes("t", {"a": (True, 1e-2, 10.0), "b": (False, 0.0, 1.0), "c": (True, 0.1, 2.0)})


def test_a_shear_is_the_same_box_in_other_coordinates():
    plain = _prior()
    sheared = plain.sheared(Shear(name="a", offset=_tilt, lower=-4.0, upper=0.5))
    rng = np.random.default_rng(3)
    # natural values in and around the box (a beyond both ends, b beyond the offset's domain)
    x = np.column_stack([np.exp(rng.uniform(np.log(1e-3), np.log(30.0), 4000)), rng.uniform(-0.1, 1.1, 4000),
                         np.exp(rng.uniform(np.log(0.1), np.log(2.0), 4000))])
    z = sheared.to_z(x)
    ok = x[:, 1] <= 0.9
    assert np.allclose(sheared.to_natural(z[ok]), x[ok], rtol=1e-13, atol=0)
    off = -3.0 * x[:, 1] + 0.5 * np.log(x[:, 2])
    assert np.allclose(z[ok, 0] - np.log(x[ok, 0]), np.clip(off[ok], -4.0, 0.5), rtol=0, atol=1e-13)
    # inside the sheared prior exactly where x is inside the boxes and the offset is defined
    inside = np.isfinite(plain.log_prob(plain.to_z(x))) & ok
    assert 0.2 < inside.mean() < 0.8
    assert np.array_equal(np.isfinite(sheared.log_prob(z)), inside)
    # the sampled box covers every moved coordinate; draws fall in the box of x
    assert np.all(z[inside] >= sheared.z_lower) and np.all(z[inside] <= sheared.z_upper)
    assert sheared.z_lower[0] == pytest.approx(np.log(1e-2) - 4.0) and sheared.z_upper[0] == pytest.approx(np.log(10.0) + 0.5)
    d = sheared.sample(rng, 500)
    good = np.isfinite(d).all(axis=1)
    assert good.mean() > 0.8 and np.all(np.isfinite(sheared.log_prob(d[good])))
    assert sheared.middle() == pytest.approx(plain.middle()) and plain.middle()["a"] == pytest.approx(np.sqrt(0.1))
    assert [d["parameter"] for d in sheared.as_dict()["sampled_as"]] == ["a"] and "sampled_as" not in plain.as_dict()
    back = pickle.loads(pickle.dumps(sheared))
    assert np.array_equal(back.to_z(x[ok]), z[ok])
    with pytest.raises(ValueError, match="log-uniform"):
        plain.sheared(Shear(name="b", offset=_tilt))
    with pytest.raises(ValueError, match="uniform coordinate"):
        plain.sheared(Shear(name="a", offset=_tilt, kind="scale"))
    with pytest.raises(ValueError, match="at most once"):
        plain.sheared(Shear(name="a", offset=_tilt), Shear(name="a", offset=_tilt))


def _share_of_b(params):
    """A stand-in ratio offset for b: reads c only (clipped to [0, ln 4] by the shear)."""
    return np.log(params["c"]) + 0.8


def test_scale_and_log_shears_chained_carry_their_jacobian():
    plain = _prior()
    # b scaled by e^o(c), then a moved by an offset that reads the natural b: the order the cable fit uses
    sheared = plain.sheared(Shear(name="b", offset=_share_of_b, lower=0.0, upper=np.log(4.0), kind="scale"),
                            Shear(name="a", offset=_tilt, lower=-4.0, upper=0.5))
    rng = np.random.default_rng(11)
    x = np.column_stack([np.exp(rng.uniform(np.log(1e-2), np.log(10.0), 2000)), rng.uniform(0.0, 0.9, 2000),
                         np.exp(rng.uniform(np.log(0.1), np.log(2.0), 2000))])
    z = sheared.to_z(x)
    assert np.allclose(sheared.to_natural(z), x, rtol=1e-13, atol=1e-15)
    assert np.allclose(z[:, 1], x[:, 1] * np.exp(np.clip(np.log(x[:, 2]) + 0.8, 0.0, np.log(4.0))), rtol=1e-14)
    # log_prob is ln |det du/dz| inside the box, u the unmoved coordinates (ln a, b, ln c) in which the box is
    # flat: central differences of to_natural (step 1e-6, error ~1e-10 on O(1) entries)
    def unmoved(zi):
        xi = sheared.to_natural(zi)[0]
        return np.where(plain.log_scale, np.log(xi), xi)

    h = 1e-6
    for zi in z[:20]:
        jac = np.column_stack([(unmoved(zi + h * e) - unmoved(zi - h * e)) / (2 * h) for e in np.eye(3)])
        assert sheared.log_prob(zi)[0] == pytest.approx(np.log(abs(np.linalg.det(jac))), abs=1e-7)
    assert np.ptp(sheared.log_prob(z)) > 0.5  # the Jacobian varies: the check above is not of a constant
    # the scale shear's box is b's [0, 1] times [1, 4]; a draw is inside the prior
    assert sheared.z_lower[1] == 0.0 and sheared.z_upper[1] == pytest.approx(4.0)
    d = sheared.sample(rng, 400)
    assert np.all(np.isfinite(sheared.log_prob(d[np.isfinite(d).all(axis=1)])))
    assert [m["kind"] for m in sheared.as_dict()["sampled_as"]] == ["scale", "log"]
    assert np.array_equal(pickle.loads(pickle.dumps(sheared)).to_z(x), z)


def test_the_seen_ratio_is_the_spread_mass_above_the_reference():
    law = law_for("iwan5")
    p = {"chi_micro": np.array([1e-6, 1e-3, 1e-6, 1e-3]), "chi_macro": np.array([1e-2, 1e-2, 1e-5, 1e-4]),
         "density_exponent": np.array([-0.5, 0.0, 0.0, 0.0])}
    ln_g = law.seen_ratios(1e-4, delta_EJ=1.0, macro_ratio=0.0, **p)["macro_ratio"]
    # int phi^-1/2 from 1e-4 and from 1e-6 to 1e-2: 2 (0.1 - 0.01) over 2 (0.1 - 0.001)
    assert ln_g[0] == pytest.approx(np.log(0.09 / 0.099), rel=1e-12)
    # all above the reference: seen whole; all below: none; outside the domain: NaN
    assert ln_g[1] == 0.0 and ln_g[2] == -np.inf and np.isnan(ln_g[3])
    # the offset of the sampled ratio is -ln g, the zoned law's its middle's; a law without a ratio has none
    got = SeenRatio("iwan5_zoned", 1e-4, "macro_ratio")({k: v[:2] for k, v in p.items()})
    assert got == pytest.approx(-ln_g[:2], rel=1e-12)
    assert law_for("bouc_wen").seen_ratios(1e-4, **{n: 1.0 for n in law_for("bouc_wen").parameter_names}) == {}


def test_the_seen_share_is_the_laws_held_rigidity_at_the_reference():
    law = law_for("iwan5")
    share = SeenShare("iwan5", 1e-4)
    p = {"chi_micro": np.array([1e-3, 2e-5, 1e-6, 1e-8]), "chi_macro": np.array([1e-1, 1e-2, 1e-2, 1e-7]),
         "density_exponent": np.array([-0.5, -0.8, 1.0, -0.5]), "macro_ratio": np.array([0.0, 0.2, 0.0, 0.0])}
    got = np.exp(share(p))
    # every wire sticks below chi_micro: all of the drop is held
    assert got[0] == pytest.approx(1.0, abs=1e-12)
    # the law's own secant rigidity over delta_EJ, whatever delta_EJ (the share does not depend on it)
    for dej in (1.0, 37.0):
        ref = law.slip_rigidity(1e-4, delta_EJ=dej, **{k: v[1:3] for k, v in p.items()}).real / dej
        assert got[1:3] == pytest.approx(ref, rel=1e-12)
    # more of the wires slip late when the density rises with the slip curvature: more of the drop is held
    assert 0 < got[1] < got[2] < 1
    # every wire slipped three decades below the reference: little held (the secant of a slipped Jenkins
    # element falls as phi / chi_a), above the floor
    assert got[3] < 1e-2 and share({k: v[3:] for k, v in p.items()})[0] > SHARE_FLOOR
    # outside the law's domain (chi_micro above chi_macro): NaN, the point is outside the prior
    assert np.isnan(share({**{k: v[:1] for k, v in p.items()}, "chi_micro": np.array([0.5])}))[0]
    assert pickle.loads(pickle.dumps(share)) == share
    # a law of another kind (Bouc-Wen, no backbone): the same rule
    bw = law_for("bouc_wen")
    q = {n: np.array([v]) for n, v in {**bw.typical, bw.scale: 1e-3}.items()}
    ref = bw.slip_rigidity(1e-4, delta_EJ=1.0, **q).real
    assert np.exp(SeenShare("bouc_wen", 1e-4)(q)) == pytest.approx(ref, rel=1e-12) and 0 < ref[0] < 1


def test_the_onsets_that_can_lie_below_the_reference_are_redrawn():
    iwan = {"delta_EJ": 10.0, "chi_micro": 1e-6, "chi_macro": 1e-2, "density_exponent": -1.0, "macro_ratio": 0.1}
    boxes = {"delta_EJ": (True, 1.0, 100.0), "chi_micro": (True, 1e-8, 1e-2), "chi_macro": (True, 1e-4, 1.0),
             "density_exponent": (False, -2.4, 2.0), "macro_ratio": (False, 0.0, 5.0)}
    prior = Prior.from_boxes("iwan5", boxes)
    assert unseen_onsets("iwan5", 1e-4, iwan, prior) == ("chi_micro",)
    # the onset started above the bench's least curvature: its box still reaches below it
    assert unseen_onsets("iwan5", 1e-4, {**iwan, "chi_micro": 1e-3}, prior) == ("chi_micro",)
    assert unseen_onsets("iwan5", 1e-9, iwan, prior) == ()  # every box above the bench's least curvature
    # the law's scale (where the wires slip) only where it starts below
    assert unseen_onsets("iwan5", 2e-4, iwan, prior) == ("chi_micro",)
    assert unseen_onsets("iwan5", 0.1, iwan, prior) == ("chi_micro", "chi_macro")
    zoned = Prior.from_boxes("z", {**boxes, "clamp_zone": (False, 0.0, 0.5)})
    assert unseen_onsets("iwan5_zoned", 1e-4, {**iwan, "clamp_zone": 0.1}, zoned) == ("chi_micro",)
    bw = Prior.from_boxes("bw", {"delta_EJ": (True, 1.0, 100.0), "chi_slip": (True, 1e-6, 1.0),
                                 "sharpness": (False, 0.5, 4.0)})
    assert unseen_onsets("bouc_wen", 1e-4, {"delta_EJ": 1.0, "chi_slip": 1e-3, "sharpness": 1.0}, bw) == ()


@pytest.mark.parametrize("law", ["iwan5", "iwan5_zoned", "bouc_wen"])
def test_the_sheared_cable_posterior_is_the_same_posterior(damper1, law):
    bench = clean_bench(load_bench(default_bench_path()), dampers=["damper1"])
    like = cable_likelihood(damper1, bench, state_tests(bench.tests("damper1"))["dry"][:2], law)
    start = like.prior.middle()
    target = seen_share_target(like, start)
    chi = reference_curvature(like, start)
    assert 1e-6 < chi < 1.0  # [1/m]: the least of the lines' largest curvatures
    assert target.prior.shears[-1].offset == SeenShare(law, chi) and target.model is like.model
    ratios = [s.name for s in target.prior.shears[:-1]]
    assert ratios == (["macro_ratio"] if law.startswith("iwan5") else [])
    assert target.prior.redrawn == unseen_onsets(law, chi, start, like.prior)
    assert target.prior.redrawn == (("chi_micro",) if law.startswith("iwan5") else ())
    rng = np.random.default_rng(5)
    z = like.prior.sample(rng, 48)
    lp = like(z)
    zs = target.prior.to_z(like.prior.to_natural(z))
    lps = target(zs)
    assert np.array_equal(np.isfinite(lp), np.isfinite(lps)) and np.isfinite(lp).sum() >= 12
    f = np.isfinite(lp)
    # the parameters agree to a few ulp; the cable's Newton solve stops at its tolerance, so a ulp moves the
    # log-density by up to ~1e-8 nats here (measured 2e-8 on values of 1e3): far below anything a nat decides
    assert np.allclose(target.prior.to_natural(zs)[f], like.prior.to_natural(z)[f], rtol=1e-14, atol=0)
    # the density in the new coordinates is the same times the map's Jacobian (the seen ratio's g: at most ln 4)
    jac = target.prior.log_prob(zs)[f]
    assert np.all(jac <= 0) and np.all(jac >= -np.log(4.0) - 1e-12)
    assert (jac < -1e-3).any() == law.startswith("iwan5")
    assert np.allclose(lps[f] - jac, lp[f], rtol=1e-10, atol=1e-6)


@pytest.mark.parametrize("law", ["iwan5", "bouc_wen"])
def test_the_fit_solves_every_line_from_its_starts_state_to_the_same_posterior(damper1, law):
    bench = clean_bench(load_bench(default_bench_path()), dampers=["damper1"])
    like = cable_likelihood(damper1, bench, state_tests(bench.tests("damper1"))["dry"][:2], law)
    start = like.prior.middle()
    near = _near(like, start)
    assert near.model.start.shape == (2, 2 * like.freq_hz.size) and like.model.start is None
    # sets about the start, as a posterior lies about its mode
    rng = np.random.default_rng(8)
    pr = like.prior
    z = pr.to_z(np.array([[start[n] for n in pr.names]]))[0] + 0.02 * (pr.z_upper - pr.z_lower) * rng.standard_normal((24, pr.ndim))
    lp, lpn = like(z), near(z)
    f = np.isfinite(lp)
    assert np.array_equal(f, np.isfinite(lpn)) and f.sum() >= 12
    # each solve stops at its tolerance (f_uu to ~1e-6): measured 1e-5 to 3e-5 nats apart on ~1e3
    assert np.allclose(lpn[f], lp[f], rtol=0, atol=1e-3)
