"""The harmonic refit (:mod:`sbcal.inference.harmonic_refit`) on recordings made by the multi-harmonic solve.

The data: damper1's cable under ``bouc_wen`` solved with five odd harmonics (the bench records the base force's
first harmonic of a distorted force), at 0.2, 0.5, 1 and 2 mm (the first-harmonic model misses by up to ~11 %
at 1-2 mm), 8 runs with 0.5 % / 0.3 deg noise. On such data the first-harmonic model's mode is biased (its law bends to
absorb what the harmonics do); the corrected model's fixed point is the multi-harmonic model's own mode, so
it recovers the truth to the noise's resolution.
"""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.inference.cable_fit import cable_likelihood, polish_mode
from sbcal.inference.harmonic_refit import RESOLVE, correction_at, harmonic_fixed_point
from sbcal.inference.likelihood import JointLikelihood
from sbcal.model.cable import CableModel
from sbcal.model.cable_harmonics import HarmonicBalance
from sbcal.model.fem import STANDARD_GRID_HZ
from sbcal.model.laws import law_for

LAW = "bouc_wen"  # its posterior converges on these lines (iwan5's micro-slip onset would not be pinned)
TRUTH = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0, chi_slip=3e-3, sharpness=2.0)
LINES = STANDARD_GRID_HZ[::3]  # 13 lines over 4-40 Hz: the resonances and between
AMPS = (0.2, 0.5, 1.0, 2.0)  # [mm p-p]: micro-slip pinned by the small ones, the distortion at the large ones


@pytest.fixture(scope="module")
def distorted(damper1, tmp_path_factory):
    """A bench file of the multi-harmonic cable (first harmonic of the force), its likelihood and the truth."""
    rng = np.random.default_rng(7)
    hb = HarmonicBalance(CableModel(law_for(LAW)), harmonics=5)
    frames, gaps = [], []
    for amp in AMPS:
        st = hb.state(damper1, LINES, amp, **TRUTH)
        gaps.append(np.abs(st.f_uu[0] / st.first_harmonic[0] - 1))
        noise = np.exp(0.005 * rng.standard_normal((8, LINES.size)) + 1j * np.radians(0.3) * rng.standard_normal((8, LINES.size)))
        frames.append(curves_to_frame(damper1.name, f"{amp:g}-{amp:g}", LINES, amp, st.f_uu[0][None, :] * noise))
    path = tmp_path_factory.mktemp("hb") / "bench.csv"
    write_bench(pd.concat(frames, ignore_index=True), path)
    data = clean_bench(load_bench(path))
    like = cable_likelihood(damper1, data, data.tests(damper1.name), LAW)
    truth = dict(TRUTH, a1=damper1.a1, a2=damper1.a2)
    return like, truth, np.concatenate(gaps), path


@pytest.mark.slow
def test_the_correction_makes_the_first_harmonic_model_the_multi_harmonic_one(distorted, damper1):
    like, truth, gaps, _ = distorted
    assert gaps.max() > 0.05  # the first-harmonic model misses by more than the noise here
    lines = np.ones(like.freq_hz.size, bool)
    c, solved = correction_at(like, truth, lines)
    assert solved.all()
    np.testing.assert_allclose(np.abs(c - 1), gaps, rtol=1e-6, atol=1e-12)
    hb = np.concatenate([HarmonicBalance(CableModel(law_for(LAW)), harmonics=5)
                         .state(damper1, LINES, a, **TRUTH).f_uu[0] for a in AMPS])
    corrected = replace(like.model, correction=c)
    got = corrected(damper1, like.freq_hz, **like.model_params(truth))[0]
    np.testing.assert_allclose(got, hb, rtol=1e-9)
    none = correction_at(like, truth, np.zeros_like(lines))[0]
    assert np.all(none == 1)


@pytest.mark.slow
def test_the_fixed_point_recovers_what_the_first_harmonic_model_bends(distorted):
    like, truth, _, _ = distorted
    prior = like.prior
    names = prior.names
    z_true = prior.z_of(truth)[0]
    # the plain model's mode, polished from the truth itself: biased
    z_plain, lp_plain = polish_mode(like, z_true)
    lines = np.ones(like.freq_hz.size, bool)
    z, c, changes = harmonic_fixed_point(like, dict(zip(names, prior.to_natural(z_plain[None])[0])), lines)
    assert changes[-1] < RESOLVE, changes
    corrected = JointLikelihood(like.likes, prior, replace(like.model, correction=c))
    noise_free = like.model(like.damper, like.freq_hz, **like.model_params(truth))[0] * correction_at(like, truth, lines)[0]

    def error(model, zz):  # against the noise-free recordings: largest |ln| ratio| [1] and phase [deg]
        f = model(like.damper, like.freq_hz, **like.model_params(dict(zip(names, prior.to_natural(zz[None])[0]))))[0]
        r = f / noise_free
        lm, ph = np.log(np.abs(r)), np.degrees(np.angle(r))
        return np.max(np.abs(lm)), np.max(np.abs(ph)), np.sqrt(np.mean(lm**2)), np.sqrt(np.mean(ph**2))

    plain, fixed = error(like.model, z_plain), error(corrected.model, z)
    # measured (rms over the 52 lines, magnitude / phase): the plain mode 3.6 % / 2.7 deg off the noise-free
    # recordings (worst line 11 % / 8.2 deg); the fixed point (3 rounds) 0.084 % / 0.038 deg (worst 0.47 % /
    # 0.15 deg): the noise's reach (0.5 % over 8 runs). Bounds: the plain error is real (> 2 % / 1 deg), the
    # fixed point removes >= 9/10 of it (measured 98 %)
    assert plain[2] > 0.02 and plain[3] > 1.0, plain
    assert fixed[2] < 0.1 * plain[2] and fixed[3] < 0.1 * plain[3], (plain, fixed)
    assert corrected(z[None])[0] > lp_plain + 10  # the corrected model explains the runs far better


@pytest.mark.long
def test_sbcal_cable_refits_with_the_harmonics_and_stores_the_record(distorted, tmp_path, capsys):
    """End to end: the plain fit's posterior, the refit's (PSIS-LOO decides: the bench file has no measured
    distortion), the one kept stored with its record, and printed."""
    from sbcal.cli import main
    from sbcal.inference.cable_fit import read_cable

    like, truth, _, path = distorted
    assert main(["cable", "--damper", "damper1", "--bench", str(path), "--law", LAW, "--runs", str(tmp_path / "runs"),
                 "--seed", "3", "--quiet"]) == 0
    out = capsys.readouterr().out
    s, draws = read_cable(tmp_path / "runs" / "damper1" / "cable-dry")
    r = s["harmonic_refit"]
    print(r)
    assert r["basis"] == "PSIS-LOO" and r["fixed_point"] and r["lines"] >= 10, r
    assert r["c_spread"] < 1.0, r  # the correction is constant across the posterior within the noise
    assert r["used"] and r["delta_elpd"] > 2 * r["se"] and r["converged"], r
    assert s["converged"] and "harmonic refit on" in out and ": used" in out
    # the stored posterior's median curves against the noise-free recordings: within the noise's reach
    from sbcal.inference.harmonic_refit import correction_at
    med = {k: float(np.median(v)) for k, v in draws.items()}
    lines = np.ones(like.freq_hz.size, bool)
    truth_f = like.model(like.damper, like.freq_hz, **like.model_params(truth))[0] * correction_at(like, truth, lines)[0]
    got = like.model(like.damper, like.freq_hz, **like.model_params(med))[0] * correction_at(like, med, lines)[0]
    rms = np.sqrt(np.mean(np.log(np.abs(got / truth_f)) ** 2))
    assert rms < 0.005, rms  # the fixed-point mode's 0.08 %, the plain one's 3.6 % (the fast test above)
    # the stored correction (the one the draws were fitted with) gives the same curves to the refit's resolution
    from sbcal.inference.cable_fit import stored_correction
    c = stored_correction(tmp_path / "runs" / "damper1" / "cable-dry")
    assert c is not None and c.shape == like.freq_hz.shape
    stored = like.model(like.damper, like.freq_hz, **like.model_params(med))[0] * c
    assert np.sqrt(np.mean(np.log(np.abs(stored / truth_f)) ** 2)) < 0.005
