"""The population fit by reweighting stored posteriors (sbcal.inference.population).

Checked against a public reference (posteriordb's eight schools), against a joint fit of population and
units together, and on lots whose outlier is plain.
"""

import math

import numpy as np
import pytest

from sbcal.inference.population import (HyperPrior, PopulationModel, PopulationTarget, UnitDraws,
                                        from_population_coordinates, outlier_probabilities, predictive_draws,
                                        to_population_coordinates, unit_ess)
from sbcal.inference.sampler import SamplerConfig, sample

ENGINE = SamplerConfig(workers=1)

# posteriordb, eight_schools-eight_schools_noncentered: reference draws (Stan, 10 chains x 1000 draws, ESS
# ~1e4): mean and sd of mu and tau, and the reference's Monte Carlo standard errors of the means.
ES_Y = np.array([28, 8, -3, 7, -1, 1, 18, 12.0])
ES_SIGMA = np.array([15, 10, 16, 11, 9, 11, 10, 18.0])
ES_REF = {"mu": (4.4105, 3.3091, 0.0330), "tau": (3.6021, 3.1983, 0.0319)}


def _engine_mcse(result, name):
    """Monte Carlo standard errors of a posterior's mean and sd from the engine's bulk ESS."""
    d = result.flat()[name]
    ess = result.ess_bulk[name]
    sd = d.std()
    kurt = np.mean((d - d.mean()) ** 4) / sd ** 4
    return sd / math.sqrt(ess), sd * math.sqrt((kurt - 1) / (4 * ess))


@pytest.mark.long
def test_eight_schools_matches_posteriordb_reference():
    """Eight schools, non-centred, by reweighting each school's draws under a flat prior (its estimate
    N(y_j, sigma_j)): the hyper-posterior of mu ~ N(0, 5), tau ~ half-Cauchy(0, 5) must match the
    reference's mean and sd of mu and tau within 3.5 combined Monte Carlo standard errors (engine's
    ESS-based, and the reference's; the reweighting's own error, 8 000 draws per school, is below them)."""
    rng = np.random.default_rng(20261127)
    S = 8000
    units = [UnitDraws(f"school{j + 1}", (ES_Y[j] + ES_SIGMA[j] * rng.standard_normal(S))[:, None], np.zeros(S))
             for j in range(8)]
    model = PopulationModel(blocks=(("theta", ("",)),), outliers=False,
                            hyper=HyperPrior(mean_box=((-60.0, 60.0),), mean_normal=((0.0, 5.0),), scatter_scale=5.0,
                                             scatter_box=(1e-3, 500.0)))
    result = sample(PopulationTarget(model, units, chunk=16), seed=7, config=ENGINE,
                    start={"theta.mean": 4.0, "theta.scatter": 3.0})
    assert result.converged, result.reason
    for name, ref in (("theta.mean", ES_REF["mu"]), ("theta.scatter", ES_REF["tau"])):
        d = result.flat()[name]
        se_mean, se_sd = _engine_mcse(result, name)
        tol_mean = 3.5 * math.hypot(se_mean, ref[2])
        tol_sd = 3.5 * math.hypot(se_sd, ref[2])   # the reference's sd error is of the order of its mean's
        assert abs(d.mean() - ref[0]) < tol_mean, (name, d.mean(), ref[0], tol_mean)
        assert abs(d.std() - ref[1]) < tol_sd, (name, d.std(), ref[1], tol_sd)


def _rejection(rng, m, s, box, n):
    """Draws of a unit's posterior N(x; m, s) pi(x) in population coordinates under the prior box (pi: the
    box's density in x), by rejection from N(m, s)."""
    out = []
    while sum(len(o) for o in out) < n:
        x = m + s * rng.standard_normal(4 * n)
        _, logp = to_population_coordinates(from_population_coordinates(x, box), box)
        keep = np.log(rng.random(x.size)) < logp - logp.max()
        out.append(x[keep])
    return np.concatenate(out)[:n]


@pytest.mark.long
def test_reweighting_matches_a_joint_fit_of_population_and_units():
    """Four units with Gaussian likelihoods in EJ (log coordinate, log-uniform box) and beta (logit of a
    uniform box): the hyper-posterior from reweighting each unit's posterior draws (sampled under its box
    prior, whose density the reweighting divides out) against emcee on population and units together, and
    both against the exact marginal (quadrature: a Gaussian likelihood makes it closed-form)."""
    rng = np.random.default_rng(4)
    boxes = {"EJ": (True, 1.13, 113.0), "beta": (False, 0.0, 2.5)}
    centres = {"EJ": np.log([10.5, 11.3, 12.4, 11.0]), "beta": to_population_coordinates(
        np.array([0.28, 0.33, 0.30, 0.36]), boxes["beta"])[0]}
    widths = {"EJ": 0.04, "beta": 0.08}       # unit posteriors as wide as the lot's scatter: reweighting matters
    hyper = HyperPrior(mean_box=((0.0, 5.0), (-5.0, 2.0)), scatter_scale=0.25, scatter_box=(1e-3, 5.0))
    model = PopulationModel(blocks=(("EJ", ("1",)), ("beta", ("1",))), hyper=hyper, outliers=False)
    S = 8000
    units = []
    for u in range(4):
        cols = [_rejection(rng, centres[p][u], widths[p], boxes[p], S) for p in ("EJ", "beta")]
        logp = sum(to_population_coordinates(from_population_coordinates(c, boxes[p]), boxes[p])[1]
                   for c, p in zip(cols, ("EJ", "beta")))
        units.append(UnitDraws(f"u{u}", np.stack(cols, axis=1), logp))
    start = {"EJ[1].mean": 2.43, "beta[1].mean": -2.0, "EJ[1].scatter": 0.07, "beta[1].scatter": 0.1}
    reweighted = sample(PopulationTarget(model, units), seed=11, config=ENGINE, start=start)

    class Joint:
        """Population and the four units sampled together (the units' likelihoods exact), non-centred
        (``x_u = mean + scatter z_u``, ``z_u ~ N(0, 1)``: the centred form is a funnel)."""

        def __init__(self):
            from sbcal.inference.priors import Prior

            self.pop = PopulationTarget(model, units[:1])   # for its hyper prior only
            boxes_z = {**{n: (b[0], b[1], b[2]) for n, b in zip(self.pop.prior.names, zip(
                self.pop.prior.log_scale, self.pop.prior.lower, self.pop.prior.upper))},
                **{f"z{u}_{p}": (False, -10.0, 10.0) for u in range(4) for p in ("EJ", "beta")}}
            self.prior = Prior.from_boxes("joint", boxes_z)

        def __call__(self, z):
            z = np.atleast_2d(z)
            params = self.prior.params(z)
            hz = self.pop.prior.z_of(params)
            lp = self.prior.log_prob(z) + self.pop.log_hyper_prior({n: params[n] for n in self.pop.prior.names}, hz)
            mean, scatter, _, _ = model.unpack(params)
            for u in range(4):
                for i, p in enumerate(("EJ", "beta")):
                    z_u = params[f"z{u}_{p}"]
                    x = mean[:, i] + scatter[:, i] * z_u
                    lp = lp - 0.5 * ((x - centres[p][u]) / widths[p]) ** 2 - 0.5 * z_u ** 2
            return np.where(np.isfinite(lp), lp, -np.inf)

    jstart = {**start, **{f"z{u}_{p}": 0.0 for u in range(4) for p in ("EJ", "beta")}}
    joint = sample(Joint(), seed=12, config=ENGINE, start=jstart)
    assert reweighted.converged and joint.converged, (reweighted.reason, joint.reason)
    for i, p in enumerate(("EJ", "beta")):
        exact = _exact_marginal(centres[p], widths[p], hyper.mean_box[i], hyper)
        for what in ("mean", "scatter"):
            name = f"{p}[1].{what}"
            a, b = reweighted.flat()[name], joint.flat()[name]
            (ma, sa), (mb, _) = _engine_mcse(reweighted, name), _engine_mcse(joint, name)
            # the reweighting: the exact marginal's mean and sd within 3.5 Monte Carlo standard errors
            assert abs(a.mean() - exact[what][0]) < 3.5 * ma, (name, a.mean(), exact[what])
            assert abs(a.std() - exact[what][1]) < 3.5 * sa, (name, a.std(), exact[what])
            # the joint fit: the same means; its sds are off by up to 30 % (emcee in 12 dimensions samples
            # the half-Cauchy's tail poorly: sd of EJ's scatter 0.059 against the exact 0.074, of beta's
            # 0.131 against 0.108; the reweighting is the better of the two)
            assert abs(b.mean() - exact[what][0]) < 3.5 * mb + 0.1 * exact[what][1], (name, b.mean(), exact[what])
            assert 0.7 < b.std() / exact[what][1] < 1.3, (name, b.std(), exact[what])


def _exact_marginal(centres, width, mean_box, hyper):
    """The hyper-posterior of Gaussian unit likelihoods by quadrature: ``prod_u N(c_u; mean, sqrt(w^2 +
    scatter^2))`` times the half-Cauchy and flat priors; ``{"mean": (mean, sd), "scatter": (mean, sd)}``."""
    mu = np.linspace(*mean_box, 1501)
    lt = np.linspace(*np.log(hyper.scatter_box), 1501)
    M, L = np.meshgrid(mu, lt, indexing="ij")
    T = np.exp(L)
    s = np.sqrt(width ** 2 + T ** 2)
    lp = sum(-0.5 * ((c - M) / s) ** 2 - np.log(s) for c in centres) - np.log1p((T / hyper.scatter_scale) ** 2) + L
    w = np.exp(lp - lp.max())
    w /= w.sum()
    out = {}
    for what, v in (("mean", M), ("scatter", T)):
        m = float((w * v).sum())
        out[what] = (m, float(np.sqrt((w * (v - m) ** 2).sum())))
    return out


def _lot(rng, offsets, scatter=0.05, width=0.005, S=500):
    """Units' log-EJ posteriors at two amplitudes: a shared unit deviation (correlation 1 between tests)."""
    box = (True, 1.13, 113.0)
    units = []
    for k, off in enumerate(offsets):
        dev = off if off else scatter * rng.standard_normal()    # a planted unit sits exactly there
        x = np.log(11.3) + dev + np.array([0.0, -0.3]) + width * rng.standard_normal((S, 2))
        units.append(UnitDraws(f"u{k + 1:02d}", x, to_population_coordinates(np.exp(x[:, 0]), box)[1] * 2))
    return units


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_a_plain_outlier_is_named_and_the_others_are_not(seed):
    """Twelve units with EJ scatter 5 % shared by both amplitudes; unit 7 planted at -30 % (7 scatters):
    its outlier probability >= 0.95, every other unit's < 0.5; the unit ESS of tight posteriors is high."""
    rng = np.random.default_rng(seed)
    offsets = [0.0] * 12
    offsets[6] = math.log(0.7)
    units = _lot(rng, offsets)
    med = np.stack([np.median(u.x, axis=0) for u in units])
    model = PopulationModel(blocks=(("EJ", ("a", "b")),),
                            hyper=HyperPrior(mean_box=tuple((float(m - 2), float(m + 2)) for m in np.median(med, axis=0))))
    target = PopulationTarget(model, units)
    start = {"EJ[a].mean": float(np.median(med[:, 0])), "EJ[b].mean": float(np.median(med[:, 1])),
             "EJ[a].scatter": 0.06, "EJ[b].scatter": 0.06, "EJ.correlation": 0.5, "outlier_fraction": 0.05}
    result = sample(target, seed=seed, config=ENGINE, start=start)
    assert result.converged, result.reason
    flat = result.flat()
    p, per_block = outlier_probabilities(target, {k: v[::4] for k, v in flat.items()})
    assert p[6] >= 0.95 and np.all(np.delete(p, 6) < 0.5), p
    np.testing.assert_allclose(per_block.sum(axis=0), p)
    ess = unit_ess(target, {k: v[::40] for k, v in flat.items()})
    assert np.median(ess) > 100
    # the scatter is the members', not inflated by the outlier: its 90 % interval holds 5 %
    q = np.quantile(flat["EJ[a].scatter"], (0.05, 0.95))
    assert q[0] < 0.05 < q[1] * 1.5, q
    # the next unit: centred on the members' median, as wide as the scatter
    nxt = predictive_draws(model, {k: v[::4] for k, v in flat.items()}, np.random.default_rng(0))
    assert abs(np.median(nxt[:, 0]) - np.log(11.3)) < 0.05
    assert 0.03 < nxt[:, 0].std() < 0.09


def test_population_coordinates_roundtrip_and_density():
    rng = np.random.default_rng(0)
    for box in ((True, 1.13, 113.0), (False, 0.0, 2.5)):
        v = (np.exp(rng.uniform(np.log(box[1]), np.log(box[2]), 20000)) if box[0]
             else rng.uniform(box[1], box[2], 20000))
        x, logp = to_population_coordinates(v, box)
        np.testing.assert_allclose(from_population_coordinates(x, box), v, rtol=1e-10)
        # the density of x under the box's prior: a histogram of x agrees with exp(logp)
        hist, edges = np.histogram(x, bins=20, range=np.quantile(x, (0.05, 0.95)))
        centre = 0.5 * (edges[1:] + edges[:-1])
        dens = hist / (x.size * np.diff(edges))
        _, logp_c = to_population_coordinates(from_population_coordinates(centre, box), box)
        np.testing.assert_allclose(dens, np.exp(logp_c), rtol=0.15)
