import numpy as np
import pytest
from scipy.stats import multivariate_t
from scipy.stats import t as student_t

from sbcal import InputError, STANDARD_GRID_HZ, dynamic_stiffness
from sbcal.inference.likelihood import NU_MIN, TestLikelihood
from sbcal.inference.priors import Prior, canonical_order, load_prior, parameter_sets

F = STANDARD_GRID_HZ


def synthetic(damper, truth, n_runs, rng, sm=0.02, sp=0.01, f=F):
    fuu = dynamic_stiffness(damper, f, **truth)[0]
    mag = np.exp(np.log(np.abs(fuu)) + sm * rng.standard_normal((n_runs, f.size)))
    ph = np.degrees(np.angle(fuu) + sp * rng.standard_normal((n_runs, f.size)))
    return mag, ph


def params(**kw):
    return {k: np.atleast_1d(np.asarray(v, float)) for k, v in kw.items()}


P0 = dict(beta=0.31, a1=0.0283, a2=-0.0154, EJ=11.5, sigma_mag=0.015, sigma_phase=0.007)


def test_prior_sets_and_boxes(damper1):
    sets = parameter_sets()
    assert sets["theta1"] == ["beta", "a1", "a2", "EJ"]
    assert set(sets) >= {"theta1", "theta2", "theta3", "poly2", "poly3", "poly4"}
    p = load_prior("theta1", damper1)
    # canonical order, whatever the file's: the model vocabulary's order, then the error scales
    assert p.names == ("EJ", "beta", "a1", "a2", "sigma_mag", "sigma_phase")
    assert p.box("a2")[1:] == pytest.approx((-0.0154 * 1.05, -0.0154 * 0.95))
    assert p.box("EJ") == (True, pytest.approx(1.13), pytest.approx(113))
    x = {"beta": 0.3, "a1": 0.028, "a2": -0.015, "EJ": 9.0, "sigma_mag": 0.01, "sigma_phase": 0.02}
    z = p.z_of(x)
    back = p.params(z)
    assert {k: float(v[0]) for k, v in back.items()} == pytest.approx(x)
    assert p.log_prob(z)[0] == 0.0
    assert p.log_prob(p.z_of(dict(x, EJ=120.0)))[0] == -np.inf
    with pytest.raises(KeyError, match="EJ"):
        p.z_of({k: v for k, v in x.items() if k != "EJ"})
    assert canonical_order(["zeta", "sigma_phase", "a2", "EJ", "sigma_mag", "alpha"]) == (
        "EJ", "a2", "alpha", "zeta", "sigma_mag", "sigma_phase")
    with pytest.raises(ValueError, match="canonical"):
        Prior("x", ("a1", "EJ"), np.zeros(2, bool), np.zeros(2), np.ones(2))


def test_prior_errors(tmp_path, damper1):
    with pytest.raises(InputError, match="parameter set 'nope'"):
        load_prior("nope", damper1)
    bad = tmp_path / "p.toml"
    bad.write_text('[parameters.beta]\ndist = "normal"\nlower = 0\nupper = 1\n[sets]\ns = ["beta"]\n')
    with pytest.raises(InputError, match=r"p.toml: key 'parameters.beta.dist'"):
        load_prior("s", damper1, bad)
    twice = tmp_path / "q.toml"
    twice.write_text('[parameters.beta]\ndist = "uniform"\nlower = 0\nupper = 1\n[sets]\ns = ["beta", "beta"]\n')
    with pytest.raises(InputError, match="listed twice"):
        load_prior("s", damper1, twice)


def test_log_posterior_vectorised_and_peaks_at_truth(damper1, rng):
    truth = dict(EJ=12.0, beta=0.3, a1=0.0280, a2=-0.0155)
    mag, ph = synthetic(damper1, truth, 10, rng)
    prior = load_prior("theta1", damper1)
    like = TestLikelihood(damper1, prior, F, mag, ph, np.full(F.size, 0.02), np.full(F.size, 0.01))
    base = dict(truth, sigma_mag=1e-3, sigma_phase=1e-3)
    rows = [base, dict(base, EJ=13.2), dict(base, beta=0.36), dict(base, EJ=24.0)]
    z = np.vstack([prior.z_of(r) for r in rows])
    lp = like(z)
    np.testing.assert_allclose(lp, [like(zi[None])[0] for zi in z])
    assert lp[0] > lp[1] and lp[0] > lp[2] and lp[0] > lp[3]
    assert np.all(np.isfinite(lp))
    outside = z.copy()
    outside[:, prior.names.index("beta")] = -1.0
    assert np.all(like(outside) == -np.inf)


def _three_lines(damper1, rng, n_runs):
    f = F[:3]
    mag, ph = synthetic(damper1, dict(EJ=12.0, beta=0.3), n_runs, rng, f=f)
    sm, sp = np.array([0.02, 0.03, 0.01]), np.array([0.01, 0.02, 0.015])
    return f, mag, ph, sm, sp


def test_loo_identity_pointwise_is_the_sampled_density_of_all_runs_minus_the_others(damper1, rng):
    """The identity behind PSIS-LOO: log p(y_r | y_-r) = log p(y) - log p(y_-r), with log p the very
    log-likelihood the sampler samples (a multivariate t per line), for every run and parameter set."""
    n_runs = 5
    f, mag, ph, sm, sp = _three_lines(damper1, rng, n_runs)
    mag[3, 1] = ph[3, 1] = np.nan  # a run without one line
    prior = load_prior("theta1", damper1)
    dof = np.array([[9.0, 14.0, 30.0], [4.0, 6.0, 12.0]])
    like = TestLikelihood(damper1, prior, f, mag, ph, sm, sp, noise_dof=dof)
    p = params(**{k: [v, v * 1.3] for k, v in P0.items()})
    got = like.pointwise_log_likelihood(p)
    full = like.log_likelihood(p)
    for r in range(n_runs):
        keep = np.arange(n_runs) != r
        # the same line noise model (nu) without run r: its own dof falls by one where it was present
        reduced = TestLikelihood(damper1, prior, f, mag[keep], ph[keep], sm, sp,
                                 noise_dof=dof - np.isfinite(mag[r]))
        np.testing.assert_allclose(got[:, r], full - reduced.log_likelihood(p), rtol=1e-10)


def test_sampled_density_is_the_multivariate_t_and_its_run_mean_the_t(damper1, rng):
    n_runs = 4
    f, mag, ph, sm, sp = _three_lines(damper1, rng, n_runs)
    prior = load_prior("theta1", damper1)
    dof = np.full((2, 3), 9.0)
    like = TestLikelihood(damper1, prior, f, mag, ph, sm, sp, noise_dof=dof)
    nu = dof - (n_runs - 1)
    np.testing.assert_array_equal(like.nu, nu)
    p = params(**P0)
    mu = like.predict(p)[:, 0]
    y = like.y
    s = (P0["sigma_mag"], P0["sigma_phase"])
    expect = 0.0
    for q, sig in enumerate((sm, sp)):
        for k in range(3):
            cov = sig[k] ** 2 * np.eye(n_runs) + s[q] ** 2
            expect += multivariate_t(loc=np.full(n_runs, mu[q, k]), shape=cov, df=nu[q, k]).logpdf(y[q, :, k])
    assert like.log_likelihood(p)[0] == pytest.approx(expect, rel=1e-10)
    # one run: the run mean's marginal t_nu(mu, sigma^2 + s^2)
    one = TestLikelihood(damper1, prior, f, mag[:1], ph[:1], sm, sp, noise_dof=np.full((2, 3), 5.0))
    assert one.nu.min() == 5.0
    r = one.residual(one.predict(p))[:, 0]
    expect = sum(student_t.logpdf(r[q], 5.0, scale=np.sqrt(sig ** 2 + s[q] ** 2)).sum() for q, sig in enumerate((sm, sp)))
    assert one.log_likelihood(p)[0] == pytest.approx(expect, rel=1e-10)


def test_normal_limit_runs_are_independent(damper1, rng):
    """A known sigma (infinite dof) and no discrepancy: the runs are independent normals, and the
    conditional density of a run given the others is its own normal density."""
    n_runs = 4
    f, mag, ph, sm, sp = _three_lines(damper1, rng, n_runs)
    prior = load_prior("theta1", damper1)
    known = TestLikelihood(damper1, prior, f, mag, ph, sm, sp, noise_dof=np.inf)
    p = params(**dict(P0, sigma_mag=1e-9, sigma_phase=1e-9))
    dev = known.y - known.predict(p)[:, 0][:, None, :]
    sig = np.stack([sm, sp])[:, None, :]
    expect = (-0.5 * (dev / sig) ** 2 - np.log(sig * np.sqrt(2 * np.pi))).sum(axis=(0, 2))
    # "infinite" dof is 1e6: the t differs from the normal by O(Q^2 / nu), Q <= ~20 here
    np.testing.assert_allclose(known.pointwise_log_likelihood(p)[0], expect, atol=2e-3)
    assert known.log_likelihood(p)[0] == pytest.approx(expect.sum(), abs=5e-3)


def test_default_noise_dof_is_the_lines_own_runs(damper1, rng):
    mag, ph = synthetic(damper1, dict(EJ=12.0, beta=0.3), 6, rng)
    like = TestLikelihood(damper1, load_prior("theta1", damper1), F, mag, ph, np.full(F.size, 0.02),
                          np.full(F.size, 0.01))
    assert np.all(like.nu == NU_MIN)


def test_polynomial_support_requires_positive_ej(damper1, rng):
    mag, ph = synthetic(damper1, dict(EJ=12.0, beta=0.3), 4, rng)
    prior = load_prior("poly2", damper1)
    like = TestLikelihood(damper1, prior, F, mag, ph, np.full(F.size, 0.02), np.full(F.size, 0.01))
    base = dict(beta=0.3, a1=0.0283, a2=-0.0154, q2=0.0, q3=0.0, sigma_mag=0.01, sigma_phase=0.01)
    assert np.isfinite(like(prior.z_of(dict(base, q1=12.0)))[0])
    assert like(prior.z_of(dict(base, q1=5.0, q2=-0.1)))[0] == -np.inf  # EJ < 0 above ~8 Hz


def test_compiled_density_is_the_numpy_expression(damper1, rng):
    """The compiled density (sbcal.inference.density_kernel) against the numpy expression it replaced, with
    the discrepancy (``theta1``) and without it (the noise-only likelihood of ``sbcal diagnose``), and with
    model phases 2 pi away, which the wrap must take back. The two sum the same ~150 terms of |.| < 1e3 in
    another order: 1e-11 relative is a thousand roundings."""
    from sbcal.inference.likelihood import wrap_phase
    from sbcal.inference.priors import composed_prior

    truth = dict(EJ=12.0, beta=0.3, a1=0.0280, a2=-0.0155)
    mag, ph = synthetic(damper1, truth, 6, rng)

    def numpy_density(like, params, mu):
        s2 = like.discrepancy_variance(params, mu.shape[1])
        sig2 = like.sigma[:, None, :] ** 2
        r = like.ybar[:, None, :] - mu
        r[1] = wrap_phase(r[1])
        big = sig2 + like.n * s2
        q = like.ss[:, None, :] / sig2 + like.n * r * r / big
        nu = like.nu[:, None, :]
        return np.sum(like._const[:, None, :] - 0.5 * ((like.n - 1) * np.log(sig2) + np.log(big))
                      - 0.5 * (nu + like.n) * np.log(nu + q), axis=(0, 2))

    for prior in (load_prior("theta1", damper1), composed_prior("baseline", (), damper1)):
        like = TestLikelihood(damper1, prior, F, mag, ph, np.full(F.size, 0.02), np.full(F.size, 0.01),
                              noise_dof=np.full((2, F.size), 30.0))
        centre = prior.z_of({k: v for k, v in dict(truth, sigma_mag=0.01, sigma_phase=0.005).items()
                             if k in prior.names})
        params = prior.params(centre + 0.05 * rng.standard_normal((16, prior.ndim)))
        mu = like.predict(params)
        want = numpy_density(like, params, mu)
        np.testing.assert_allclose(like.log_likelihood(params), want, rtol=1e-11)
        turned = mu.copy()
        turned[1] += 2 * np.pi * rng.integers(-2, 3, size=turned[1].shape)
        np.testing.assert_allclose(like.log_likelihood(params, turned), want, rtol=1e-11)
