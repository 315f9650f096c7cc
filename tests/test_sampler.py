"""The sampling engine: a known posterior, the convergence policy, reproducibility, one emcee user."""

from pathlib import Path

import numpy as np
import pytest

from sbcal.inference.priors import Prior
from sbcal.inference.sampler import POLICY, SamplerConfig, _laplace, sample

MEAN = np.array([1.0, -2.0, 0.5])
COV = np.array([[1.0, 0.8, 0.0], [0.8, 1.0, -0.3], [0.0, -0.3, 0.5]])


class Gaussian:
    """A correlated 3-D normal (wide box prior), with a pointwise 'likelihood' of 2 points."""

    def __init__(self):
        self.prior = Prior.from_boxes("gauss", {n: (False, -20.0, 20.0) for n in ("a", "b", "c")})
        self.prec = np.linalg.inv(COV)

    def pointwise_log_likelihood(self, params):
        x = np.column_stack([params[n] for n in ("a", "b", "c")]) - MEAN
        q = np.einsum("ni,ij,nj->n", x, self.prec, x)
        return np.column_stack([-0.25 * q, -0.25 * q])

    def __call__(self, z):
        z = np.atleast_2d(z)
        out = self.prior.log_prob(z)
        ok = np.isfinite(out)
        out[ok] = self.pointwise_log_likelihood(self.prior.params(z[ok])).sum(axis=1)
        return out


FAST = SamplerConfig(nwalkers=16, max_draws=500, de_population=30, de_generations=60, workers=1)


def test_known_gaussian_moments_and_diagnostics():
    res = sample(Gaussian(), seed=11, config=FAST)
    assert res.converged and res.reason == ""
    assert res.n_chains == 4 and res.log_likelihood.shape[:2] == res.log_prob.shape
    x = np.column_stack([res.draws[n].ravel() for n in ("a", "b", "c")])
    # the mean's error is sd / sqrt(ESS); 5 of those is a ~1e-6 two-sided tail
    for i, n in enumerate(("a", "b", "c")):
        assert abs(x[:, i].mean() - MEAN[i]) < 5 * np.sqrt(COV[i, i] / res.ess_bulk[n])
    # the covariance: relative error of a variance ~ sqrt(2 / ESS) (< 0.05 here); allow 0.15 absolute
    np.testing.assert_allclose(np.cov(x.T), COV, atol=0.15)
    for n in res.names:
        assert res.r_hat[n] <= POLICY["rhat_max"] and min(res.ess_bulk[n], res.ess_tail[n]) >= POLICY["ess_min"]
        assert res.n_steps - res.burn >= POLICY["tau_factor"] * res.tau[n]


def test_same_seed_same_draws_whatever_the_workers():
    a = sample(Gaussian(), seed=5, config=FAST)
    b = sample(Gaussian(), seed=5, config=SamplerConfig(**{**FAST.__dict__, "workers": 2}))
    c = sample(Gaussian(), seed=6, config=FAST)
    for n in a.names:
        np.testing.assert_array_equal(a.draws[n], b.draws[n])
    assert not np.array_equal(a.draws["a"], c.draws["a"])


def test_step_cap_marks_not_converged_with_the_reason():
    res = sample(Gaussian(), seed=1, config=SamplerConfig(nwalkers=16, first_steps=60, max_steps=60, workers=1))
    assert not res.converged
    assert res.reason.startswith("stopped at the 60-step cap") and "tau" in res.reason
    d = res.convergence_dict()
    assert d["converged"] is False and d["reason"] == res.reason and "R-hat <= 1.01" in d["policy"]


def test_policy_is_enforced_by_the_configuration():
    with pytest.raises(ValueError, match="n_ensembles 2"):
        SamplerConfig(n_ensembles=2)
    with pytest.raises(ValueError, match="tau_reason"):
        SamplerConfig(tau_factor=20)
    loose = SamplerConfig(tau_factor=30, tau_reason="a test of the wording")
    assert "30 tau because a test of the wording" in loose.policy()


def test_emcee_has_one_user():
    root = Path(__file__).resolve().parents[1] / "sbcal"
    users = sorted(p.name for p in root.rglob("*.py") if "import emcee" in p.read_text())
    assert users == ["sampler.py"]


class SkewedGamma:
    """x ~ Gamma(2, 1) (mean 2, variance 2, skewness sqrt(2)) and y | x ~ N(x, 1): a posterior that the
    independence proposal's symmetric t does not match, so its Hastings ratio must be right."""

    def __init__(self):
        self.prior = Prior.from_boxes("skew", {"x": (False, 0.0, 40.0), "y": (False, -20.0, 60.0)})

    def __call__(self, z):
        z = np.atleast_2d(z)
        out = self.prior.log_prob(z)
        ok = np.isfinite(out)
        x, y = z[ok, 0], z[ok, 1]
        with np.errstate(divide="ignore"):
            out[ok] = np.log(x) - x - 0.5 * (y - x) ** 2
        return out


def test_independence_moves_keep_a_skewed_posterior():
    # mostly independence moves, so a wrong Hastings ratio would show: without it the chain samples
    # closer to the proposal (measured, seed 3: mean of x 2.00, variance 2.02, skewness 1.49; with the
    # ratio dropped 1.28, 0.50 and 0.93)
    res = sample(SkewedGamma(), seed=3, config=SamplerConfig(nwalkers=16, max_draws=1000, de_population=20,
                                                             de_generations=40, workers=1, independence=0.9))
    assert res.converged
    x = res.draws["x"].ravel()
    # mean: error sd / sqrt(ESS), 5 of those; variance: relative sd sqrt((kurtosis - 1) / ESS) ~ 0.1 at
    # ESS ~ 400 (Gamma(2): excess kurtosis 3), 4 of those
    assert abs(x.mean() - 2.0) < 5 * np.sqrt(2.0 / res.ess_bulk["x"])
    assert abs(x.var() / 2.0 - 1) < 4 * np.sqrt(5.0 / res.ess_bulk["x"])
    skew = np.mean((x - x.mean()) ** 3) / x.std() ** 3
    assert 1.0 < skew < 1.9  # sqrt(2) = 1.41; Gamma's third moment converges slowly


def test_independence_moves_shorten_the_autocorrelation_of_a_gaussian():
    # a correlated 3-D normal: differential evolution alone needs tau ~ 4 ndim steps, the fitted t
    # decorrelates a walker in a few (measured, seed 2: tau 3.0 against 12.5; 9-D: 4.4 against 35)
    de = sample(Gaussian(), seed=2, config=SamplerConfig(**{**FAST.__dict__, "independence": 0.0}))
    mixed = sample(Gaussian(), seed=2, config=FAST)
    assert de.converged and mixed.converged
    assert max(mixed.tau.values()) < 0.6 * max(de.tau.values())


class Saddle:
    """log p = -(x^2 + y^2) / 2 + 2 x y: each parameter curves down, but (1, 1) is a direction of ascent."""

    prior = Prior.from_boxes("saddle", {"x": (False, -1.0, 1.0), "y": (False, -1.0, 1.0)})

    def __call__(self, z):
        z = np.atleast_2d(z)
        return -0.5 * (z[:, 0] ** 2 + z[:, 1] ** 2) + 2 * z[:, 0] * z[:, 1]


def test_laplace_falls_back_to_each_parameters_own_curvature():
    cov, full = _laplace(Saddle(), np.zeros(2))
    assert not full
    np.testing.assert_allclose(cov, np.eye(2), rtol=1e-6)
    cov, full = _laplace(Gaussian(), MEAN)
    assert full
    np.testing.assert_allclose(cov, COV, rtol=1e-4, atol=1e-8)
