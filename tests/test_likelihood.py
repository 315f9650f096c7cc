import numpy as np
import pytest
from scipy.stats import multivariate_normal

from sbcal import InputError, STANDARD_GRID_HZ, dynamic_stiffness
from sbcal.likelihood import TestLikelihood
from sbcal.priors import load_prior, parameter_sets

F = STANDARD_GRID_HZ


def synthetic(damper, truth, n_runs, rng, sm=0.02, sp=0.01, offset=(0.0, 0.0)):
    fuu = dynamic_stiffness(damper, F, **truth)[0]
    mag = np.exp(np.log(np.abs(fuu)) + offset[0] + sm * rng.standard_normal((n_runs, F.size)))
    ph = np.degrees(np.angle(fuu) + offset[1] + sp * rng.standard_normal((n_runs, F.size)))
    return mag, ph


def test_prior_sets_and_boxes(damper1):
    sets = parameter_sets()
    assert sets["theta1"] == ["beta", "a1", "a2", "EJ"]
    assert set(sets) >= {"theta1", "theta2", "theta3", "poly2", "poly3", "poly4"}
    p = load_prior("theta1", damper1)
    assert p.names == ("beta", "a1", "a2", "EJ", "sigma_mag", "sigma_phase")
    i = p.names.index("a2")
    assert p.lower[i] == pytest.approx(-0.0154 * 1.05) and p.upper[i] == pytest.approx(-0.0154 * 0.95)
    j = p.names.index("EJ")
    assert p.log_scale[j] and p.lower[j] == pytest.approx(1.13) and p.upper[j] == pytest.approx(113)
    x = np.array([[0.3, 0.028, -0.015, 9.0, 0.01, 0.02]])
    np.testing.assert_allclose(p.to_natural(p.to_z(x)), x)
    assert p.log_prob(p.to_z(x))[0] == 0.0
    x[0, j] = 120.0
    assert p.log_prob(p.to_z(x))[0] == -np.inf


def test_prior_errors(tmp_path, damper1):
    with pytest.raises(InputError, match="parameter set 'nope'"):
        load_prior("nope", damper1)
    bad = tmp_path / "p.toml"
    bad.write_text('[parameters.beta]\ndist = "normal"\nlower = 0\nupper = 1\n[sets]\ns = ["beta"]\n')
    with pytest.raises(InputError, match=r"p.toml: key 'parameters.beta.dist'"):
        load_prior("s", damper1, bad)


def test_log_posterior_vectorised_and_peaks_at_truth(damper1, rng):
    truth = dict(EJ=12.0, beta=0.3, a1=0.0280, a2=-0.0155)
    mag, ph = synthetic(damper1, truth, 10, rng)
    prior = load_prior("theta1", damper1)
    like = TestLikelihood(damper1, prior, F, mag, ph, np.full(F.size, 0.02), np.full(F.size, 0.01))
    x0 = np.array([0.3, 0.0280, -0.0155, 12.0, 1e-3, 1e-3])
    z = prior.to_z(np.array([x0, x0 * [1, 1, 1, 1.1, 1, 1], x0 * [1.2, 1, 1, 1, 1, 1], x0 * [1, 1, 1, 2, 1, 1]]))
    lp = like(z)
    np.testing.assert_allclose(lp, [like(zi[None])[0] for zi in z])
    assert lp[0] > lp[1] and lp[0] > lp[2] and lp[0] > lp[3]
    assert np.all(np.isfinite(lp))
    outside = z.copy()
    outside[:, 0] = -1.0
    assert np.all(like(outside) == -np.inf)


def test_pointwise_is_conditional_density_of_a_run(damper1, rng):
    """log p(y_r | y_-r, theta) must equal log p(y) - log p(y_-r) under the shared-discrepancy model."""
    truth = dict(EJ=12.0, beta=0.3)
    n_runs = 4
    f = F[:3]
    mag, ph = synthetic(damper1, truth, n_runs, rng)
    mag, ph = mag[:, :3], ph[:, :3]
    sm, sp = np.array([0.02, 0.03, 0.01]), np.array([0.01, 0.02, 0.015])
    prior = load_prior("theta1", damper1)
    like = TestLikelihood(damper1, prior, f, mag, ph, sm, sp)
    x = np.array([[0.31, 0.0283, -0.0154, 11.5, 0.015, 0.007]])
    mu = like.predict(x)[:, 0]  # (2, 3)
    got = like.pointwise_log_likelihood(x)[0]
    s = x[0, 4:]
    y = like.y  # (2, runs, freq)
    for r in range(n_runs):
        expect = 0.0
        for q, sig in enumerate((sm, sp)):
            for k in range(3):
                def logp(idx):
                    cov = sig[k] ** 2 * np.eye(len(idx)) + s[q] ** 2
                    return multivariate_normal(mean=np.full(len(idx), mu[q, k]), cov=cov).logpdf(y[q, idx, k])
                allr = list(range(n_runs))
                expect += logp(allr) - logp([i for i in allr if i != r])
        assert got[r] == pytest.approx(expect, rel=1e-9)


def test_log_likelihood_is_student_t_of_the_run_means(damper1, rng):
    """Each line and quantity: t with n - 1 dof, centred on the model, scale sqrt(sigma^2/n + s^2)."""
    from scipy.stats import t as student_t

    n_runs = 6
    mag, ph = synthetic(damper1, dict(EJ=12.0, beta=0.3), n_runs, rng)
    f = F[:4]
    mag, ph = mag[:, :4], ph[:, :4]
    sm, sp = np.array([0.02, 0.03, 0.01, 0.02]), np.full(4, 0.01)
    prior = load_prior("theta1", damper1)
    like = TestLikelihood(damper1, prior, f, mag, ph, sm, sp)
    x = np.array([[0.31, 0.0283, -0.0154, 11.5, 0.015, 0.007]])
    mu = like.predict(x)[:, 0]
    ybar = np.stack([np.log(mag).mean(0), np.radians(ph).mean(0)])
    expect = sum(student_t.logpdf(ybar[q], df=n_runs - 1, loc=mu[q], scale=np.sqrt(sig**2 / n_runs + x[0, 4 + q] ** 2)).sum()
                 for q, sig in enumerate((sm, sp)))
    assert like.log_likelihood(x)[0] == pytest.approx(expect, rel=1e-10)


def test_polynomial_support_requires_positive_ej(damper1, rng):
    mag, ph = synthetic(damper1, dict(EJ=12.0, beta=0.3), 4, rng)
    prior = load_prior("poly2", damper1)
    like = TestLikelihood(damper1, prior, F, mag, ph, np.full(F.size, 0.02), np.full(F.size, 0.01))
    ok = np.array([[0.3, 0.0283, -0.0154, 12.0, 0.0, 0.0, 0.01, 0.01]])
    neg = np.array([[0.3, 0.0283, -0.0154, 5.0, -0.1, 0.0, 0.01, 0.01]])  # EJ < 0 above ~8 Hz
    assert np.isfinite(like(prior.to_z(ok))[0])
    assert like(prior.to_z(neg))[0] == -np.inf
