"""sbcal.design.predict: a new damper from a stored cable-law posterior (docs/predict.md).

The stored posterior is made here in seconds: draws scattered about a known iwan5 cable (the law's
own curves as the bench recordings), packed by the real writer :func:`sbcal.inference.cable_fit.store_cable`.
What is tested is the prediction's plumbing and its numbers, not the sampler.
"""

import json
import pickle
import shutil
from dataclasses import asdict, replace

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ, InputError, load_damper
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.model.cable import CableModel
from sbcal.inference.cable_fit import CableFit, CableForward, cable_config, cable_likelihood, store_cable
from sbcal.cli import main
from sbcal.model.damper import Damper, FILE_KEYS, resolve_damper, with_value
from sbcal.model.fem import dynamic_stiffness, natural_frequencies
from sbcal.model.laws import law_for
from sbcal.design.cable_run import RANGE_STATUS, load_cable_run
from sbcal.design.impedance import impedance_from_cable
from sbcal.design.predict import EXTRAPOLATION_MARGIN, level_resonances, model_error_of, predict
from sbcal.design.predict_store import read_prediction, read_sweep, store_prediction, store_sweep
from sbcal.design.sweep import sweep
from sbcal.inference.sampler import SampleResult
from sbcal.inference.stats import loo, read_netcdf

from .test_damper import GOOD as BASE  # the damper file of the damper tests

LAW = "iwan5"
TRUTH = dict(EJ_min=4.4, beta_material=0.11, delta_EJ=42.0, chi_micro=3e-4, chi_macro=0.03, density_exponent=-1.0,
             macro_ratio=0.05)
TESTS = ("0.2-0.2", "1-1")
CHAINS, DRAWS = 2, 12
# a clearly different geometry: lighter masses, longer arms
NEW = Damper(name="newdamper", m1=2.2, J1=0.0095, a1=0.022, m2=1.5, J2=0.004, a2=-0.012, mc=1.05, Jc=0.0015,
             ac=0.0, L1=0.26, L2=0.17, mu=0.53, ej_static=113.0)


OFFSET = (0.04, 0.02)  # what the law leaves at 1 mm in the default store: ln|f| [1], phase [rad]


def _store(root, *, converged=True, seed=0, spread=0.02, offset=OFFSET):
    """A cable-law run of damper1 in ``root/runs/damper1/cable-dry``; returns its directory. The draws
    scatter about TRUTH by ``spread`` in log (1.5 ``spread`` on the density exponent). The recordings are
    the law's own curves with 1 % noise, and at 1 mm ``offset`` on top (ln|f|, phase [rad]): physics the
    law does not have, which the store's remainder must call ``partial`` and its discrepancy carry."""
    out = root / "runs" / "damper1" / "cable-dry"
    store_cable(_fit(root, converged=converged, seed=seed, spread=spread, offset=offset), out,
                meta={"seed": seed, "made_by": "test", "damper_values": asdict(resolve_damper("damper1"))})
    return out


def _fit(root, *, converged=True, seed=0, spread=0.02, offset=OFFSET):
    """The :class:`CableFit` that :func:`_store` stores (its recordings written to ``root/bench.csv``)."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(seed)
    model = CableModel(law_for(LAW))
    frames = []
    for t in TESTS:
        a = float(t.split("-")[0])
        fuu = model.dynamic_stiffness(d, STANDARD_GRID_HZ, a, **TRUTH)[0]
        noise = 0.01 * (rng.standard_normal((6, fuu.size)) + 1j * rng.standard_normal((6, fuu.size)))
        if a == 1.0:
            noise = noise + offset[0] + 1j * offset[1]
        frames.append(curves_to_frame(d.name, t, STANDARD_GRID_HZ, a, fuu[None] * np.exp(noise)))
    write_bench(pd.concat(frames, ignore_index=True), root / "bench.csv")
    like = cable_likelihood(d, clean_bench(load_bench(root / "bench.csv")), list(TESTS), LAW)
    draws = {}
    for n in like.prior.names:
        base = TRUTH.get(n, getattr(d, n, None))
        z = rng.standard_normal((CHAINS, DRAWS))
        draws[n] = base + 1.5 * spread * z if n == "density_exponent" else base * np.exp(spread * z)
    ll = like.pointwise_log_likelihood({n: v.ravel() for n, v in draws.items()}).reshape(CHAINS, DRAWS, -1)
    one = {n: 1.0 for n in like.prior.names}
    many = {n: 1e3 for n in like.prior.names}
    res = SampleResult(names=tuple(like.prior.names), draws=draws, log_prob=np.zeros((CHAINS, DRAWS)), log_likelihood=ll,
                       tau=one, acceptance=np.full(CHAINS, 0.3), r_hat=dict(one, chi_macro=1.2 if not converged else 1.0),
                       ess_bulk=many, ess_tail=many, n_steps=100, burn=20, thin=1, converged=converged,
                       reason="" if converged else "R-hat above 1.01", start={}, wall_s=0.0,
                       config=cable_config(len(like.prior.names)))
    return CableFit(damper=d.name, state="dry", law=LAW, tests=TESTS, effects=(), result=res, like=like, loo=loo(ll))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return _store(tmp_path_factory.mktemp("cable"))


def _reference(run, damper, freq, amp, **overrides):
    """Quantiles of |f|, phase and power from the calibration's own forward model on every stored draw."""
    c = load_cable_run(run)
    params = dict(c.draws, **overrides)
    _, fm = CableForward(LAW, np.broadcast_to(amp, freq.shape), np.zeros(freq.size, int)).state(damper, freq, **params)
    x0 = np.broadcast_to(amp, freq.shape) / 2e3
    power = 0.5 * 2 * np.pi * freq * fm.imag * x0**2
    q = (0.05, 0.5, 0.95)
    return (np.quantile(np.abs(fm), q, axis=0), np.quantile(np.degrees(np.angle(fm)), q, axis=0),
            np.quantile(power, q, axis=0))


def test_a_harmonic_refits_run_predicts_with_its_correction(tmp_path):
    """A used harmonic refit's run (its draws fitted with the multi-harmonic solve's correction): every draw's curves
    are the first-harmonic model's times that correction at the draws' median, solved here independently; a
    first-harmonic run's are not. At 2 mm the correction moves |f| by several per cent, so a prediction that
    dropped it could not pass."""
    from sbcal.model.cable_harmonics import DEFAULT_HARMONICS, HarmonicBalance

    d = resolve_damper("damper1")
    fit = _fit(tmp_path)
    for name, refit in (("plain", None), ("refit", {"used": True})):
        store_cable(replace(fit, refit=refit), tmp_path / name / "damper1" / "cable-dry",
                    meta={"seed": 0, "damper_values": asdict(d)})
    amps = [0.2, 2.0]
    plain, refit = (predict(tmp_path / name / "damper1" / "cable-dry", d, amplitude_mm_pp=amps, model_error=False, seed=1)
                    for name in ("plain", "refit"))
    assert refit.summary()["harmonic_correction"] and not plain.summary()["harmonic_correction"]
    hb = HarmonicBalance(CableModel(law_for(LAW)), harmonics=DEFAULT_HARMONICS)
    median = {k: np.atleast_1d(np.median(v)) for k, v in fit.result.draws.items()}
    for i, a in enumerate(amps):
        st = hb.state(d, STANDARD_GRID_HZ, a, **median)
        c = np.abs(st.f_uu[0] / st.first_harmonic[0])
        ratio = refit.stiffness_n_per_m[i, 1] / plain.stiffness_n_per_m[i, 1]  # the same draws: c exactly
        np.testing.assert_allclose(ratio, c, rtol=1e-9)
    assert np.abs(c - 1).max() > 0.03  # 2 mm: 9.5 % when written



def test_a_harmonic_refits_correction_reaches_compare_sweep_and_span(tmp_path):
    """Every other use of a used refit's draws carries the correction too (sbcal.design.harmonics): compare's
    characteristic and a design sweep solve it at their lines, span's impedance tabulates it over lines and
    clamp amplitudes; the same draws as a first-harmonic run's, times the correction solved here independently."""
    from sbcal.design.characteristic import from_cable
    from sbcal.design.harmonics import TABLE_AMPLITUDES_MM
    from sbcal.design.impedance import impedance_from_cable
    from sbcal.design.sweep import sweep
    from sbcal.model.cable_harmonics import DEFAULT_HARMONICS, HarmonicBalance

    d = resolve_damper("damper1")
    fit = _fit(tmp_path)
    runs = {}
    for name, refit in (("plain", None), ("refit", {"used": True})):
        runs[name] = tmp_path / name / "damper1" / "cable-dry"
        store_cable(replace(fit, refit=refit), runs[name], meta={"seed": 0, "damper_values": asdict(d)})
    hb = HarmonicBalance(CableModel(law_for(LAW)), harmonics=DEFAULT_HARMONICS)

    def c_at(params, f, a_mm):
        median = {k: np.atleast_1d(np.median(v)) for k, v in params.items()}
        st = hb.state(d, f, np.full(np.size(f), a_mm), **median)
        return st.f_uu[0] / st.first_harmonic[0]

    # compare's characteristic at 2 mm p-p: every draw (and the same model error draws), times c at their median
    f = STANDARD_GRID_HZ[(STANDARD_GRID_HZ >= 5) & (STANDARD_GRID_HZ <= 30)]
    plain, refit = (from_cable(runs[n], mode="amplitude", level=2.0, freq_hz=f, n_draws=CHAINS * DRAWS, rng=np.random.default_rng(3))
                    for n in ("plain", "refit"))
    c = c_at({k: v.ravel() for k, v in fit.result.draws.items()}, f, 2.0)
    assert np.abs(c - 1).max() > 0.03
    np.testing.assert_allclose(refit.fuu / plain.fuu, np.broadcast_to(c, plain.fuu.shape), rtol=1e-9)

    # span's impedance: on the table's own lines and amplitudes the correction exactly; between two amplitudes of
    # the table (a factor 1.8 apart) within 0.5 % of the solve there (linear in ln a: measured 0.1 % when written)
    imps = {n: impedance_from_cable(runs[n], d, n_draws=8, seed=2, model_error=False) for n in runs}
    assert imps["refit"].harmonic and not imps["plain"].harmonic
    lines = np.geomspace(5.0, 30.0, 37)  # 5 % steps: the table's own grid over this band
    for a_mm in (TABLE_AMPLITUDES_MM[11], np.sqrt(TABLE_AMPLITUDES_MM[11] * TABLE_AMPLITUDES_MM[12])):
        x = np.full((1, lines.size), a_mm / 2e3)
        ratio = imps["refit"](lines, x) / imps["plain"](lines, x)
        exact = c_at(imps["refit"].params, lines, a_mm)
        assert np.abs(exact - 1).max() > 0.02
        tol = 1e-9 if a_mm == TABLE_AMPLITUDES_MM[11] else 5e-3
        np.testing.assert_allclose(ratio, np.broadcast_to(exact, ratio.shape), rtol=tol)
        stacked = imps["refit"].stacked(lines, x[None]) / imps["plain"].stacked(lines, x[None])
        np.testing.assert_allclose(stacked[0], ratio, rtol=1e-12)
    assert len(imps["refit"].tables) == 1  # made once for the band
    # a design sweep at 2 mm: the same draws, so without the correction the peak power would be the plain run's to the
    # last digit; with it, moved by the correction near the peak (0.31 % when written; c up to ~5 % over the band)
    sw = {n: sweep(runs[n], d, "mass1.mass_kg", [d.m1], amplitude_mm_pp=2.0, freq_hz=[5.0, 30.0], n_draws=8, seed=2)
          for n in runs}
    moved = sw["refit"].peak_power_w[0, 0, 1] / sw["plain"].peak_power_w[0, 0, 1] - 1
    assert 1e-3 < abs(moved) < np.abs(c - 1).max() + 0.01, moved


# --- the damper file's tolerances -----------------------------------------------------------------

def test_tolerance_table_is_optional_and_checked(tmp_path):
    p = tmp_path / "d.toml"
    p.write_text(BASE)
    plain = load_damper(p)
    assert plain.tolerance == () and plain.tolerances() == {"a1": 5.0, "a2": 5.0, "ac": 5.0}  # the thesis's 5 %
    p.write_text(BASE + '[tolerance]\n"mass1.mass_kg" = 2\n"mass1.offset_m" = 0\n[tolerance.cable]\nlength1_m = 1.5\n')
    d = load_damper(p)
    assert replace(d, tolerance=()) == plain  # the model's values are unchanged
    assert d.tolerance == (("L1", 1.5), ("a1", 0.0), ("m1", 2.0))
    assert d.tolerances() == {"L1": 1.5, "a2": 5.0, "ac": 5.0, "m1": 2.0}  # 0 switches a default off
    for bad, match in (('"mass1.colour" = 3', r"key 'tolerance.mass1.colour': unknown key; known: clamp.mass_kg"),
                       ('"cable.ej_static_nm2" = 3', r"tolerance.cable.ej_static_nm2': the cable's rigidity comes from"),
                       ('"mass2.mass_kg" = 100', r"below 100, got 100"),
                       ('"mass2.mass_kg" = -1', r"must be >= 0"),
                       ('"mass2.mass_kg" = "a lot"', r"expected a number")):
        p.write_text(BASE + "[tolerance]\n" + bad + "\n")
        with pytest.raises(InputError, match=match) as e:
            load_damper(p)
        assert "\n" not in str(e.value) and str(p) in str(e.value)


def test_tolerances_leave_the_calibration_inputs_unchanged():
    """The run store's digest of a damper is the one before tolerances existed: stored runs stay valid."""
    from sbcal.pipeline import _damper_digest, inputs_digest

    d = resolve_damper("damper1")
    before = inputs_digest({k: v for k, v in asdict(d).items() if k not in ("source", "tolerance")})
    assert _damper_digest(d) == _damper_digest(replace(d, tolerance=(("m1", 2.0),))) == before


def test_with_value_checks_like_the_reader():
    d = resolve_damper("damper1")
    assert with_value(d, "cable.length1_m", np.float64(0.3)).L1 == 0.3
    assert with_value(d, "m2", 2).m2 == 2.0
    with pytest.raises(InputError, match=r"key 'cable.length1_m': must be > 0, got -0.1"):
        with_value(d, "cable.length1_m", -0.1)
    with pytest.raises(InputError, match="unknown damper field"):
        with_value(d, "cable.colour", 1.0)
    assert set(FILE_KEYS.values()) == {"mc", "Jc", "ac", "m1", "J1", "a1", "m2", "J2", "a2", "L1", "L2", "mu", "ej_static"}


# --- the cable model with one amplitude per (set, line) --------------------------------------------

def test_cable_model_amplitude_per_set_and_line_equals_set_by_set(damper1):
    rng = np.random.default_rng(5)
    model = CableModel(law_for(LAW))
    f = np.linspace(4.0, 40.0, 25)
    ej = TRUTH["EJ_min"] * np.exp(0.1 * rng.standard_normal(4))
    amp = np.exp(rng.uniform(np.log(0.05), np.log(3.0), (4, f.size)))
    for continuation in (False, True):
        st = model.state(damper1, f, amp, continuation=continuation, **dict(TRUTH, EJ_min=ej))
        for i in range(4):
            one = model.state(damper1, f, amp[i], continuation=continuation, **dict(TRUTH, EJ_min=ej[i]))
            # sets are independent: the grouping changes nothing but the rounding
            np.testing.assert_allclose(st.f_uu[i], one.f_uu[0], rtol=1e-12)
            np.testing.assert_allclose(st.curvature_range[i], one.curvature_range[0], rtol=1e-12)
    # one row broadcasts over the sets; scalar parameters take the sets from the amplitudes
    np.testing.assert_allclose(model.dynamic_stiffness(damper1, f, amp[:1], **dict(TRUTH, EJ_min=ej))[2],
                               model.dynamic_stiffness(damper1, f, amp[0], **dict(TRUTH, EJ_min=ej[2]))[0], rtol=1e-12)
    assert model.dynamic_stiffness(damper1, f, amp, **TRUTH).shape == (4, f.size)
    with pytest.raises(InputError, match="3 rows"):
        model.dynamic_stiffness(damper1, f, amp[:3], **dict(TRUTH, EJ_min=ej))


# --- predictions ----------------------------------------------------------------------------------

def test_own_geometry_reproduces_the_calibration_posterior_predictive(run, damper1):
    """The calibration damper at its own tests: the calibration's forward model on every stored
    draw (its lines and amplitudes from posterior.nc), the same numbers."""
    p = predict(run, damper1, n_draws=1000, seed=3, model_error=False)  # the calibration's amplitudes
    assert p.own_offsets and p.n_draws == CHAINS * DRAWS and list(p.levels) == [0.2, 1.0]
    const = read_netcdf(run / "posterior.nc").constant_data
    f_all, amp_all = np.asarray(const["freq_hz"]), np.asarray(const["amplitude_mm_pp"])
    test = np.asarray(const["line_test"]).astype(str)
    for i, t in enumerate(TESTS):
        sel = test == t
        ref = _reference(run, damper1, f_all[sel], amp_all[sel])
        np.testing.assert_allclose(p.freq_hz, f_all[sel])
        for got, want in zip((p.stiffness_n_per_m[i], p.phase_deg[i], p.power_w[i]), ref):
            np.testing.assert_allclose(got, want, rtol=1e-9)
        assert not p.extrapolated[i].any() and p.fold_share[i].max() == 0 and p.converged_share[i].min() == 1
    # the same seed gives the same numbers; a subset is drawn by the seed
    a, b = (predict(run, damper1, amplitude_mm_pp=1.0, n_draws=10, seed=7) for _ in range(2))
    c = predict(run, damper1, amplitude_mm_pp=1.0, n_draws=10, seed=8)
    assert np.array_equal(a.stiffness_n_per_m, b.stiffness_n_per_m) and a.resonances == b.resonances
    assert not np.array_equal(a.stiffness_n_per_m, c.stiffness_n_per_m)


@pytest.fixture(scope="module")
def complete_run(tmp_path_factory):
    return _store(tmp_path_factory.mktemp("complete"), offset=(0.0, 0.0))


def test_model_error_is_the_calibration_discrepancy(run, tmp_path, damper1):
    """The model error, stored with the cable run by its writer, is the discrepancy of what the fit leaves:
    the store's law misses the 1 mm recordings by OFFSET, so its remainder is ``partial`` and, for a
    posterior as narrow as a real one (0.2 % spread), the discrepancy at 1 mm is the offset (the run
    means' noise, 0.01 / sqrt(6) = 0.004, taken out: within 10 %), at 0.2 mm, where the law is the
    recordings' own, at most that noise; the posterior's own spread is not counted twice (the default
    store's 2 % spread takes its share off). The bands with it are those of the draws times independent
    normal errors of that scale."""
    tight = model_error_of(_store(tmp_path, spread=0.002))
    np.testing.assert_array_equal(tight.amplitude_mm_pp, [0.2, 1.0])
    assert tight.logmag_sd[1] == pytest.approx(OFFSET[0], rel=0.1)
    assert tight.phase_sd_deg[1] == pytest.approx(np.degrees(OFFSET[1]), rel=0.1)
    assert tight.logmag_sd[0] < 0.004 and tight.phase_sd_deg[0] < np.degrees(0.004)
    s = load_cable_run(run).summary
    err = model_error_of(run)
    assert s["remainder"]["qualifier"] == "partial" and s["discrepancy"]["partial"]
    assert s["remainder"]["lines_off"] > 0 and s["remainder"]["n_lines"] == 2 * 2 * STANDARD_GRID_HZ.size
    assert {k: s["discrepancy"][k] for k in ("amplitude_mm_pp", "logmag_sd", "phase_sd_deg")} == err.as_dict()
    assert 0.5 * OFFSET[0] < err.logmag_sd[1] < tight.logmag_sd[1]
    sd_m, sd_p = err.at(np.array([0.1, 0.2, 0.447, 1.0, 3.0]))
    np.testing.assert_allclose(sd_m[[0, 1, 3, 4]], err.logmag_sd[[0, 0, 1, 1]])  # held beyond the ends
    assert sd_m[2] == pytest.approx(np.mean(err.logmag_sd), rel=1e-2)  # 0.447 ~ the log-midpoint of 0.2 and 1
    # the bands widen by the error: at lines where the draws barely spread, the 90 % band of ln|f|
    # tends to +-1.645 sd (4000 samples: +-3 %)
    p = predict(run, NEW, amplitude_mm_pp=1.0, n_draws=1000)
    q = predict(run, NEW, amplitude_mm_pp=1.0, n_draws=1000, model_error=False)
    assert p.model_error == err.as_dict() and q.model_error is None
    wide = np.log(p.stiffness_n_per_m[0, 2] / p.stiffness_n_per_m[0, 0])
    narrow = np.log(q.stiffness_n_per_m[0, 2] / q.stiffness_n_per_m[0, 0])
    assert np.all(wide > narrow)
    # independent errors add in quadrature: the added width is the 90 % band of the discrepancy alone
    assert np.median(np.sqrt(wide ** 2 - narrow ** 2)) == pytest.approx(2 * 1.645 * err.logmag_sd[1], rel=0.25)
    # a symmetric error leaves the median where the draws' band is symmetric; where it is skewed (the
    # tolerances), convolving it with an error of sd 0.03 moves the median by a fraction of that sd
    np.testing.assert_allclose(p.stiffness_n_per_m[0, 1], q.stiffness_n_per_m[0, 1], rtol=0.5 * err.logmag_sd[1])


def test_a_complete_fit_adds_no_model_error(complete_run):
    """A law that leaves nothing but noise: the store's remainder is ``complete``, its discrepancy zero,
    and predict's bands with the model error are those without it, number for number (the same draws)."""
    s = load_cable_run(complete_run).summary
    assert s["remainder"]["qualifier"] == "complete" and s["remainder"]["lines_off"] == 0
    assert s["remainder"]["global"]["p_value"] >= 0.01
    assert not s["discrepancy"]["partial"] and not any(s["discrepancy"]["logmag_sd"] + s["discrepancy"]["phase_sd_deg"])
    p = predict(complete_run, NEW, amplitude_mm_pp=[0.2, 1.0], n_draws=200, seed=4)
    q = predict(complete_run, NEW, amplitude_mm_pp=[0.2, 1.0], n_draws=200, seed=4, model_error=False)
    np.testing.assert_allclose(p.stiffness_n_per_m, q.stiffness_n_per_m, rtol=1e-12)
    np.testing.assert_allclose(p.phase_deg, q.phase_deg, atol=1e-9)


def _edited_store(run, tmp_path, edit):
    """A copy of the stored cable run with its summary.json edited by ``edit(summary)``."""
    out = tmp_path / "runs" / "damper1" / "cable-dry"
    shutil.copytree(run, out)
    s = json.loads((out / "summary.json").read_text())
    edit(s)
    (out / "summary.json").write_text(json.dumps(s))
    return out


def test_a_store_without_the_discrepancy_says_so(run, tmp_path):
    """A cable run stored before the discrepancy was: the prediction goes on without model error and
    says why in one line; a malformed one is bad input naming the file and the key."""
    old = _edited_store(run, tmp_path / "old", lambda s: s.pop("discrepancy"))
    p = predict(old, NEW, amplitude_mm_pp=1.0, n_draws=4)
    assert p.model_error is None
    note = [w for w in p.warnings if "model error" in w]
    assert len(note) == 1 and "\n" not in note[0] and "summary.json: key 'discrepancy': missing" in note[0]
    bad = _edited_store(run, tmp_path / "bad", lambda s: s["discrepancy"].update(logmag_sd=[0.01]))
    with pytest.raises(InputError, match=r"cable-dry/summary.json: key 'discrepancy': expected lists of one length"):
        model_error_of(bad)


def test_one_extrapolation_rule(run):
    """predict and span judge a state by the same rule: the median over draws of its largest arm
    curvature against the calibrated range, with the margin on both sides; no stored range, no flags."""
    c = load_cable_run(run)
    lo, hi = c.curvature_range
    m = 1 + EXTRAPOLATION_MARGIN
    top = np.array([lo / m * 0.99, lo / m * 1.01, hi, hi * m * 0.99, hi * m * 1.01, np.nan])
    assert [RANGE_STATUS[k] for k in c.range_status(top)] == ["below_range", "ok", "ok", "ok", "extrapolated", "ok"]
    assert c.range_warning() == ""
    none = replace(c, curvature_range=(np.nan, np.nan))
    assert not none.range_status(top).any() and "key 'tests_reached': missing" in none.range_warning()


def test_new_damper_takes_its_own_offsets_and_tolerances(run, damper1):
    """Another damper never gets the calibration damper's posterior offsets: with the tolerances off
    a renamed copy of damper1 is the calibration's model at the file's nominal a1, a2."""
    twin = replace(damper1, name="twin", tolerance=(("a1", 0.0), ("a2", 0.0)))
    p = predict(run, twin, amplitude_mm_pp=1.0, n_draws=1000, model_error=False)
    assert not p.own_offsets and p.tolerance_pct == {}
    n = CHAINS * DRAWS
    ref = _reference(run, twin, STANDARD_GRID_HZ, 1.0, a1=np.full(n, damper1.a1), a2=np.full(n, damper1.a2))
    np.testing.assert_allclose(p.stiffness_n_per_m[0], ref[0], rtol=1e-9)
    # tolerances widen the band: +-5 % on the offsets and +-3 % on the arm lengths
    wide = predict(run, replace(twin, tolerance=(("L1", 3.0), ("L2", 3.0))), amplitude_mm_pp=1.0, n_draws=1000,
                   model_error=False)
    assert wide.tolerance_pct == {"L1": 3.0, "L2": 3.0, "a1": 5.0, "a2": 5.0}
    # (median 90 % width of ln|f| over the lines: 0.131 against 0.094 with these 24 draws; the
    # posterior's own 2 % scatter is already in both)
    width = np.log(wide.stiffness_n_per_m[0, 2] / wide.stiffness_n_per_m[0, 0])
    assert np.median(width) > 1.2 * np.median(np.log(p.stiffness_n_per_m[0, 2] / p.stiffness_n_per_m[0, 0]))


def test_velocity_mode(run):
    v = 0.1
    p = predict(run, NEW, velocity_m_s=v, n_draws=1000, model_error=False)
    f = p.freq_hz
    np.testing.assert_allclose(p.amplitude_mm_pp[0], 2e3 * v / (2 * np.pi * f))
    c = load_cable_run(run)
    n = CHAINS * DRAWS
    zero = {k: np.zeros(n) for k in ("a1", "a2")}
    # the reference: the same unit draws of the offsets, from the same seed, through the model
    from sbcal.design.cable_run import drawn_geometry, drawn_tolerances, streams, unit_draws
    _, geo = streams(0)
    tol = drawn_tolerances([NEW], False)
    overrides = dict(zero, **drawn_geometry(NEW, tol, unit_draws(tol, n, geo)))
    ref = _reference(run, NEW, f, 2e3 * v / (2 * np.pi * f), **overrides)
    np.testing.assert_allclose(p.power_w[0], ref[2], rtol=1e-9)
    # under constant velocity the power is 0.5 R v^2, so a resonance is the power's peak: on a dense grid
    # about the first one the median power peaks there (a median of peaks against the peak of the
    # medians: they differ by 0.4 % in frequency and 0.3 % in power here)
    r = p.resonances[0]
    dense = predict(run, NEW, velocity_m_s=v, n_draws=1000, freq_hz=np.geomspace(0.9, 1.1, 161) * r.freq_hz[1],
                    model_error=False)
    top = np.argmax(dense.power_w[0, 1])
    assert dense.freq_hz[top] == pytest.approx(r.freq_hz[1], rel=0.01)
    assert dense.power_w[0, 1, top] == pytest.approx(r.power_w[1], rel=0.02)
    assert p.labels() == ["v0.1"] and c.law == LAW


def test_extrapolation_marks_where_the_arms_bend_beyond_the_calibration(run):
    """The calibration reached 0.2 and 1 mm on damper1: NEW at 0.5 mm stays inside, at 4 mm it bends the
    arms beyond, and under 0.1 m/s at its first resonance (X0 = v / omega = 2.3 mm there)."""
    c = load_cable_run(run)
    hi = c.curvature_range[1]
    p = predict(run, NEW, amplitude_mm_pp=[0.5, 4.0], n_draws=12)
    assert not p.extrapolated[0].any()
    assert p.extrapolated[1].sum() >= 5
    np.testing.assert_array_equal(p.extrapolated, p.curvature_max > hi * (1 + EXTRAPOLATION_MARGIN))
    np.testing.assert_array_equal(p.extrapolated, c.range_status(p.curvature_max) != 0)
    frame = p.to_frame()
    assert frame.loc[frame.test == "4-4", "extrapolated"].sum() == p.extrapolated[1].sum()
    v = predict(run, NEW, velocity_m_s=0.1, n_draws=12)
    first = v.resonances[0].freq_hz[1]
    assert v.extrapolated[0, np.argmin(np.abs(v.freq_hz - first))] and not v.extrapolated[0, v.freq_hz > 30].any()


def test_resonances_are_the_peaks_of_the_resistance():
    """Light damping: the resistance Im f / omega peaks at the clamped-base natural frequencies (the
    shift is O(beta^2) ~ 1e-4 here; the fine grid's parabola adds < 0.1 %)."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(2)
    ej = 9.0 * np.exp(0.03 * rng.standard_normal(40))
    f = np.geomspace(3.0, 60.0, 601)
    fuu = dynamic_stiffness(d, f, EJ=ej, beta=0.01)
    res = level_resonances(f, fuu, np.full(f.size, 1e-3), 1.0)
    fn = natural_frequencies(d, EJ=ej)
    assert len(res) == 4 and all(r.share == 1.0 for r in res)
    for k, r in enumerate(res):
        assert r.freq_hz[1] == pytest.approx(np.median(fn[:, k]), rel=2e-3)
        assert r.freq_hz[0] == pytest.approx(np.quantile(fn[:, k], 0.05), rel=3e-3)
    # one draw at loss factor 0.05: the power at each resonance is 0.5 R (omega X0)^2 at its frequency
    # (X0 = 1 mm), against a 40x denser grid: the grid's parabola errs by <= 3.3e-4 in power and 5e-5
    # in frequency here (at loss factor 0.01 the peaks are ~2 steps wide and the power falls short by
    # up to 9 %: docs/predict.md)
    fuu = dynamic_stiffness(d, f, EJ=9.0, beta=0.05)
    dense = np.geomspace(3.0, 60.0, 24001)
    fd = dynamic_stiffness(d, dense, EJ=9.0, beta=0.05)[0]
    p_dense = 0.5 * 2 * np.pi * dense * fd.imag * 1e-6
    peaks = dense[1:-1][(fd.imag[1:-1] / dense[1:-1] > fd.imag[:-2] / dense[:-2])
                        & (fd.imag[1:-1] / dense[1:-1] > fd.imag[2:] / dense[2:])]
    one = level_resonances(f, fuu, np.full(f.size, 1e-3), 1.0)
    assert len(one) == peaks.size == 4
    for r, fp in zip(one, peaks):
        assert r.freq_hz[1] == pytest.approx(fp, rel=2e-4)
        assert r.power_w[1] == pytest.approx(np.interp(r.freq_hz[1], dense, p_dense), rel=1e-3)


def test_a_rising_edge_at_the_band_end_is_no_resonance():
    """A window reaching the band's end may hold a larger value than its peak (a resistance rising to a
    mode just beyond the band): each draw's resonance is its local maximum nearest the median's peak."""
    f = np.geomspace(4.0, 40.0, 462)
    lorentz = lambda f0, w: 1.0 / (1.0 + ((f - f0) / w) ** 2)  # noqa: E731
    scale = np.array([1.0, 1.02, 0.98])[:, None]
    r = 1.0 + 3.0 * lorentz(9.0 * scale, 0.8) + 2.0 * lorentz(20.0 * scale, 1.5) + 8.0 * lorentz(39.8, 1.5)
    fuu = 2 * np.pi * f * r * 1j + 1.0  # Im f = omega R
    res = level_resonances(f, fuu, np.full(f.size, 1e-3), 1.0)
    assert [round(x.freq_hz[1], 1) for x in res] == [9.0, 20.0] and all(x.share == 1.0 for x in res)


def test_sweep_equals_single_predictions_and_moves_the_resonance(run):
    values = np.array([0.20, 0.24, 0.28])
    s = sweep(run, NEW, "cable.length1_m", values, amplitude_mm_pp=[1.0], n_draws=8, seed=4)
    assert s.resonance_hz.shape[:2] == (3, 1) and s.peak_power_w.shape == (3, 1, 3)
    for v, x in enumerate(values):
        p = predict(run, with_value(NEW, "cable.length1_m", x), amplitude_mm_pp=1.0, n_draws=8, seed=4)
        got = s.resonance_hz[v, 0][np.isfinite(s.resonance_hz[v, 0, :, 1])]
        np.testing.assert_allclose(sorted(map(tuple, got)), [r.freq_hz for r in p.resonances], rtol=1e-9)
    first = s.resonance_hz[:, 0, 0, 1]
    assert np.all(np.diff(first) < 0)  # a longer arm lowers the first resonance (one track throughout)
    frame = s.to_frame()
    assert list(frame["value"]) == list(values) and {"resonance1_hz", "peak_power_q95", "extrapolated"} <= set(frame)


def test_resonance_tracks_follow_a_peak_across_design_values():
    from sbcal.design.predict import Resonance
    from sbcal.design.sweep import _tracks

    def r(f):
        return Resonance(level=1.0, index=0, freq_hz=(f, f, f), power_w=(1.0, 1.0, 1.0), share=1.0)

    # a low mode falling with the value, a middle one vanishing at the third value, a high one steady
    per_value = [[r(9.0), r(24.0), r(38.0)], [r(8.0), r(23.5), r(38.1)], [r(7.3), r(38.2)], [r(6.6), r(38.2)]]
    tracks = _tracks(per_value)
    freqs = [[round(x.freq_hz[1], 1) for _, x in t] for t in tracks]
    assert freqs == [[9.0, 8.0, 7.3, 6.6], [24.0, 23.5], [38.0, 38.1, 38.2, 38.2]]
    assert [v for v, _ in tracks[1]] == [0, 1]


def test_store_read_and_csv(run, tmp_path):
    p = predict(run, NEW, amplitude_mm_pp=[0.5, 4.0], n_draws=12)
    d = store_prediction(p, tmp_path / "pred")
    assert {x.name for x in d.iterdir()} == {"prediction.csv", "prediction.png", "summary.json"}
    q = read_prediction(d)
    for name in ("stiffness_n_per_m", "phase_deg", "power_w", "amplitude_mm_pp", "extrapolated", "fold_share"):
        np.testing.assert_allclose(getattr(q, name), getattr(p, name), rtol=1e-9)
    assert q.resonances == p.resonances and q.warnings == p.warnings
    text = (d / "prediction.csv").read_text().splitlines()
    assert text[0] == ("damper,test,run,frequency_hz,amplitude_mm_pp,stiffness_n_per_m,phase_deg,stiffness_q05,"
                       "stiffness_q95,phase_q05,phase_q95,power_w,power_q05,power_q95,extrapolated")
    assert text[1].startswith("newdamper,0.5-0.5,0,4,0.5,") and text[1].endswith(",false")
    assert any(line.endswith(",true") for line in text)
    # the rows are bench rows: the bench reader takes them (run 0 is the median)
    assert load_bench(d / "prediction.csv").tests("newdamper") == ["0.5-0.5", "4-4"]
    s = sweep(run, NEW, "mass2.mass_kg", [1.2, 1.8], amplitude_mm_pp=[1.0], n_draws=4)
    sd = store_sweep(s, tmp_path / "sweep")
    t = read_sweep(sd)
    np.testing.assert_allclose(t.resonance_hz, s.resonance_hz, equal_nan=True)
    np.testing.assert_allclose(t.peak_power_w, s.peak_power_w)


def test_impedance_for_the_span(run):
    from sbcal.design.conductor import resolve_conductor
    from sbcal.design.span import energy_balance

    imp = impedance_from_cable(run, NEW, n_draws=6, seed=1, model_error=False)
    f = np.array([8.0, 15.0, 30.0])
    amp = np.array([[1e-4, 5e-4, 2e-3]] * imp.n_draws) * np.arange(1, imp.n_draws + 1)[:, None]
    k = imp(f, amp)
    assert k.shape == (imp.n_draws, 3) and np.all(k.imag > 0)
    model = CableModel(law_for(LAW))
    for i in range(imp.n_draws):  # each (draw, line) its own steady state at its own amplitude
        one = model.dynamic_stiffness(NEW, f, 2e3 * amp[i], **{n: v[i] for n, v in imp.params.items()})
        np.testing.assert_allclose(k[i], one[0], rtol=1e-12)
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(imp))(f, amp), k)
    np.testing.assert_array_equal(imp(f, amp[:1]), imp(f, np.repeat(amp[:1], imp.n_draws, axis=0)))
    # K trial amplitudes in one solve: the same as K calls
    trials = np.stack([amp, 0.5 * amp, amp[:1].repeat(imp.n_draws, axis=0)])
    np.testing.assert_array_equal(imp.stacked(f, trials), np.array([imp(f, a) for a in trials]))
    r = energy_balance(resolve_conductor("drake"), imp, 1.0, n_freq=4)
    assert r.ymax_m.shape == (imp.n_draws, 4) and np.isfinite(r.ymax_m).any()


def test_span_impedance_band_is_predicts_band(run):
    """The span's impedance holds what predict's band holds (posterior, tolerances, model error): at
    one line and amplitude, its stiffness and power quantiles over (draw, error) samples equal
    predict's. The span draws one error pair per (draw, line), so the line is repeated 200 times
    (24 draws x 200 = 4 800 samples against predict's 4 000): the quantiles' Monte Carlo standard
    error is about 2.1 sigma / sqrt(n) at 5 % and 95 %, 0.047 sigma for the two samples together, or
    1.4 % of the 90 % band's width (3.29 sigma); they must agree to 6 % of it (4 standard errors)."""
    f0, amp = 15.0, 1.0
    p = predict(run, NEW, amplitude_mm_pp=amp, freq_hz=[f0], n_draws=300, seed=3)
    imp = impedance_from_cable(run, NEW, n_draws=300, seed=3)
    assert imp.model_error is not None and imp.model_error.as_dict() == p.model_error
    f = np.full(200, f0)
    k = imp(f, np.full((1, f.size), amp / 2e3)).ravel()
    power = 0.5 * 2 * np.pi * f0 * k.imag * (amp / 2e3) ** 2
    for mine, theirs in ((np.abs(k), p.stiffness_n_per_m[0, :, 0]), (power, p.power_w[0, :, 0])):
        q = np.quantile(mine, (0.05, 0.5, 0.95))
        width = theirs[2] - theirs[0]
        np.testing.assert_allclose(q, theirs, atol=0.06 * width)
    # without the model error the band is the posterior's and the tolerances' alone: narrower
    bare = np.abs(impedance_from_cable(run, NEW, n_draws=300, seed=3, model_error=False)(f, np.full((1, f.size), amp / 2e3)))
    assert np.ptp(np.quantile(bare, (0.05, 0.95))) < 0.9 * np.ptp(np.quantile(np.abs(k), (0.05, 0.95)))
    # the same seed gives the same errors at every call (common random numbers across positions)
    np.testing.assert_array_equal(imp(f, np.full((1, f.size), amp / 2e3)).ravel(), k)


# --- the command line and the report --------------------------------------------------------------

def test_cli_predict_and_report(run, tmp_path, capsys):
    import shutil

    runs = tmp_path / "runs"
    shutil.copytree(run.parent.parent, runs)
    cable = runs / "damper1" / "cable-dry"
    toml = tmp_path / "new.toml"
    toml.write_text(BASE.replace('name = "x"', 'name = "newdamper"') + '[tolerance]\n"cable.length1_m" = 2\n')
    out = tmp_path / "p.csv"
    rc = main(["predict", "--cable", str(cable), "--damper", str(toml), "--amplitude", "0.5", "1", "--draws", "6",
               "-o", str(out), "--plot", str(tmp_path / "p.png")])
    text = capsys.readouterr().out
    assert rc == 0 and "resonances" in text and out.is_file() and (tmp_path / "p.png").is_file()
    stored = runs / "damper1" / "predict-newdamper-dry"
    assert (stored / "prediction.csv").read_bytes() == out.read_bytes()
    rc = main(["predict", "--cable", str(cable), "--damper", str(toml), "--velocity", "0.1", "--draws", "4",
               "--sweep", "cable.length1_m=0.16:0.2:2"])
    assert rc == 0 and (stored / "sweep-cable.length1_m" / "sweep.csv").is_file()
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "newdamper: predicted from the damper1 dry cable" in page and "Design sweep: cable.length1_m" in page
    for name in ("damper1_predict-newdamper-dry.png", "damper1_predict-newdamper-dry_sweep0.png"):
        assert (tmp_path / "rep" / "figures" / name).is_file()


def test_cli_predict_bad_input_is_one_line(run, tmp_path, capsys):
    incomplete = tmp_path / "inc.toml"
    incomplete.write_text(BASE.replace("length2_m = 0.14\n", ""))
    cases = [
        (["--cable", str(tmp_path / "nope"), "--damper", "damper1"], "no such cable run"),
        (["--cable", str(run.parent), "--damper", "damper1"], "no cable-law run here"),
        (["--cable", str(run), "--damper", str(tmp_path / "missing.toml")], "no such file"),
        (["--cable", str(run), "--damper", str(incomplete)], "key 'cable.length2_m': missing"),
        (["--cable", str(run), "--damper", "damper1", "--amplitude", "0"], "--amplitude 0: must be > 0"),
        (["--cable", str(run), "--damper", "damper1", "--velocity", "-0.1"], "--velocity -0.1: must be > 0"),
        (["--cable", str(run), "--damper", "damper1", "--sweep", "cable.length1_m=0.1:0.2"], "expected NAME=START:STOP:N"),
        (["--cable", str(run), "--damper", "damper1", "--sweep", "cable.ej_static_nm2=50:90:3"],
         "does not change a prediction"),
    ]
    for argv, match in cases:
        assert main(["predict"] + argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert match in err and "\n" not in err, (argv, err)


def test_cli_warns_on_a_non_converged_posterior(tmp_path, capsys):
    cable = _store(tmp_path, converged=False)
    assert main(["predict", "--cable", str(cable), "--damper", "damper1", "--amplitude", "1", "--draws", "3"]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "did not converge" in err and "for chi_macro" in err
    assert read_prediction(cable.parent / "predict-damper1-dry").warnings[0].endswith("misplaced")


def test_a_law_outscored_by_an_unconverged_family_is_not_settled(tmp_path, capsys):
    """A converged law that a family which did not converge beats clearly (compare_families: 'outscored_by')
    is not a result: predict warns, and the characteristic compare draws from it refuses it."""
    from sbcal.design.characteristic import from_cable

    out = tmp_path / "runs" / "damper1" / "cable-dry"
    families = {LAW: {"elpd": -100.0, "se": 5.0, "delta_elpd": 0.0, "se_delta": 0.0, "converged": True},
                "iwan5": {"elpd": 552.0, "se": 9.0, "delta_elpd": 652.0, "se_delta": 52.0, "converged": False}}
    comparison = {"best": LAW, "converged": True, "settled": False, "higher_not_converged": ["iwan5"],
                  "outscored_by": ["iwan5"], "families": families, "screened": {}}
    store_cable(_fit(tmp_path), out, meta={"seed": 0, "made_by": "test",
                                           "damper_values": asdict(resolve_damper("damper1"))}, comparison=comparison)
    warning = load_cable_run(out).convergence_warning()
    assert f"the {LAW} law is not settled: iwan5 (652 +- 52 nats)" in warning and "\n" not in warning
    assert main(["predict", "--cable", str(out), "--damper", "damper1", "--amplitude", "1", "--draws", "3"]) == 0
    assert "not settled" in capsys.readouterr().err
    with pytest.raises(InputError, match="not settled.*its draws are not a result"):
        from_cable(out, mode="amplitude", level=1.0, freq_hz=[10.0, 20.0], n_draws=3, rng=np.random.default_rng(0))
    # a hand-edited comparison that names a family it does not hold still gives one line, no traceback
    summary = json.loads((out / "summary.json").read_text())
    summary["comparison"]["outscored_by"] = ["dahl"]
    (out / "summary.json").write_text(json.dumps(summary))
    assert f"the {LAW} law is not settled: dahl scored" in load_cable_run(out).convergence_warning()
    # within noise of the winner the law stands: no warning
    settled = dict(comparison, settled=True, outscored_by=[])
    store_cable(_fit(tmp_path), out, meta={"seed": 0, "made_by": "test",
                                           "damper_values": asdict(resolve_damper("damper1"))}, comparison=settled)
    assert load_cable_run(out).convergence_warning() == ""
