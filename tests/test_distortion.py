"""The force distortion a fitted cable law predicts (issue 21): computed once per fit at its posterior median,
stored with it, carried by the diagnosis's JSON and CSV, printed by ``sbcal cable`` and drawn by the report.

The fits are the fast ones of the predict tests (draws scattered about a known iwan5 cable, packed by the real
writer), so what is tested is the numbers' plumbing and their physics, not the sampler.
"""

import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ
from sbcal.cli import main
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.diagnosis.diagnose import (DiagnoseConfig, _cable_fits, _curves, _refit_harmonics, _store_cables, curves_frame,
                                    diagnose)
from sbcal.diagnosis.fits import FitJob, _posterior
from sbcal.inference.cable_fit import cable_likelihood, read_cable
from sbcal.inference.distortion import HARMONICS, predicted_distortion
from sbcal.model.cable import CableModel
from sbcal.model.damper import resolve_damper
from sbcal.model.laws import law_for
from sbcal.simulate.virtual_bench import BenchConfig, record

from .test_predict import LAW, TRUTH, _fit

AMPLITUDES = ("0.1-0.1", "0.5-0.5", "2-2")


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return tmp_path_factory.mktemp("fit")


@pytest.fixture(scope="module")
def fit(root):
    """A cable fit of damper1's dry cable at 0.2 and 1 mm (``tests.test_predict._fit``; its bench in ``root``)."""
    return _fit(root)


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """A real diagnosis of damper1 with nothing missing (verdict none: the per-test model's curves only)."""
    d = resolve_damper("damper1")
    path = tmp_path_factory.mktemp("plain") / "b.csv"
    write_bench(record(d, BenchConfig(params={"EJ": 9.0, "beta": 0.25}, runs=6), ["1-1"], rng=np.random.default_rng(2)),
                path)
    return diagnose(d, clean_bench(load_bench(path)), seed=0, progress=False, config=DiagnoseConfig(draws=100))


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The likelihood of an iwan5 cable's own curves at three amplitudes (1 % noise, 4 runs)."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(3)
    model = CableModel(law_for(LAW))
    frames = []
    for t in AMPLITUDES:
        a = float(t.split("-")[0])
        fuu = model.dynamic_stiffness(d, STANDARD_GRID_HZ, a, **TRUTH)[0]
        noise = 0.01 * (rng.standard_normal((4, fuu.size)) + 1j * rng.standard_normal((4, fuu.size)))
        frames.append(curves_to_frame(d.name, t, STANDARD_GRID_HZ, a, fuu[None] * np.exp(noise)))
    path = tmp_path_factory.mktemp("sweep") / "bench.csv"
    write_bench(pd.concat(frames, ignore_index=True), path)
    return cable_likelihood(d, clean_bench(load_bench(path)), list(AMPLITUDES), LAW)


def _point(like, **values):
    """Natural values of every parameter of ``like``: TRUTH, the damper's geometry, ``values`` on top."""
    return {n: float(values.get(n, TRUTH.get(n, getattr(like.damper, n, np.nan)))) for n in like.prior.names}


def _lines(harmonics, key, tests):
    """A per-test quantity of :func:`predicted_distortion` on the concatenated lines (None -> NaN)."""
    return np.concatenate([np.array(harmonics[key][t], dtype=float) for t in tests])


def test_a_stuck_cable_is_not_distorted_and_a_slipping_one_more_with_amplitude(sweep):
    # slip starting beyond every curvature the bench reaches: the cable stays linear, the force a sine
    stuck = predicted_distortion(sweep, _point(sweep, chi_micro=50.0, chi_macro=100.0), AMPLITUDES)
    assert stuck["orders"] == [1, 3, 5, 7, 9] and len(stuck["orders"]) == HARMONICS
    for t in AMPLITUDES:
        assert all(stuck["converged"][t])
        assert max(stuck["distortion"][t]) < 1e-9 and max(stuck["gap"][t]) < 1e-9
    slip = predicted_distortion(sweep, _point(sweep), AMPLITUDES)
    typical = [np.median(np.array(slip["distortion"][t], float)) for t in AMPLITUDES]
    assert 0.005 < typical[0] < typical[1] < typical[2] < 0.5, typical  # the median line grows with the amplitude
    big = slip["largest"]["distortion"]
    assert big["value"] == max(max(v) for v in slip["distortion"].values())
    assert big["amplitude_mm_pp"] == float(big["test"].split("-")[0])
    assert slip["largest"]["gap"]["value"] > 0 and slip["n_not_converged"] == 0


def test_a_fixture_mass_reaches_the_distortion_as_the_bench_measures_it(fit, root):
    """A fixture mass adds a sine to the measured force: its first harmonic moves, the higher ones do not."""
    like = cable_likelihood(fit.like.damper, clean_bench(load_bench(root / "bench.csv")), fit.tests, LAW,
                            effects=("fixture_mass",))
    mass = 0.5
    base = predicted_distortion(fit.like, fit.median(), fit.tests)
    heavy = predicted_distortion(like, dict(fit.median(), fixture_mass_kg=mass), fit.tests)
    _, f_uu, first = fit.like.model.harmonic_state(fit.like.damper, fit.like.freq_hz, harmonics=HARMONICS,
                                                   **fit.like.model_params(fit.median()))
    inertia = (2 * np.pi * fit.like.freq_hz) ** 2 * mass
    np.testing.assert_allclose(_lines(heavy, "distortion", fit.tests),
                               _lines(base, "distortion", fit.tests) * np.abs(f_uu[0]) / np.abs(f_uu[0] - inertia),
                               rtol=1e-9)
    np.testing.assert_allclose(_lines(heavy, "gap", fit.tests), np.abs((f_uu[0] - inertia) / (first[0] - inertia) - 1),
                               rtol=1e-9)


@pytest.fixture(scope="module")
def shown(fit):
    """The diagnosis's view of the fit: the strand-slip model's fits by ``(model, state)``, as it keeps them."""
    post = _posterior(FitJob(("strand_slip", "dry", LAW), fit.like, None, DiagnoseConfig(), fit.tests), fit.result)
    return {("strand_slip", "dry"): dict(post, law=LAW)}


def test_the_diagnosis_carries_the_distortion_per_line(fit, shown, tmp_path):
    d = resolve_damper("damper1")
    cables = _cable_fits(d, shown)
    case = SimpleNamespace(tests=fit.tests, likes=fit.like.likes)
    baseline = {("baseline", "all"): shown[("strand_slip", "dry")]}  # any curves will do for the per-test model
    curves = _curves(case, {**shown, **baseline}, [("baseline", "all")], "strand_slip", shown,
                     harmonics=[c.harmonics for c in cables.values()])
    h = cables[("strand_slip", "dry")].harmonics
    for t, lk in zip(fit.tests, fit.like.likes):
        c = curves["strand_slip"][t]
        assert len(c["distortion"]) == len(c["harmonics_gap"]) == len(c["harmonics_converged"]) == lk.freq_hz.size
        assert c["distortion"] == h["distortion"][t] and all(c["harmonics_converged"])
        assert "distortion" not in curves["baseline"][t]
    frame = curves_frame(json.loads(json.dumps({"damper": d.name, "curves": curves})))  # as stored
    assert "distortion" in frame.columns and len(frame) == 2 * sum(lk.freq_hz.size for lk in fit.like.likes)
    assert frame.loc[frame.model == "baseline", "distortion"].isna().all()
    law_rows = frame[frame.model == "strand_slip"]
    np.testing.assert_allclose(law_rows["distortion"], _lines(h, "distortion", fit.tests))
    # the store gets the very numbers the curves carry (made once, not solved again)
    _store_cables(d, cables, shown, store=tmp_path, seed=0, comparison=None)
    stored, _ = read_cable(tmp_path / "damper1" / "cable-dry")
    assert stored["harmonics"] == json.loads(json.dumps(h))
    assert set(stored["harmonics"]) >= {"orders", "distortion", "gap", "converged", "largest"}


def test_a_diagnosis_without_a_cable_law_has_no_distortion(plain):
    """The per-test models have no distortion: the CSV column is there, empty."""
    assert plain["verdict"] == "none" and all("distortion" not in c for c in plain["curves"]["baseline"].values())
    assert curves_frame(plain)["distortion"].isna().all()


def test_sbcal_cable_prints_the_largest_distortion(tmp_path, monkeypatch, capsys):
    from sbcal.inference import cable_fit

    root = tmp_path
    fresh = _fit(root)  # its bench written to root/bench.csv, which the command reads
    monkeypatch.setattr(cable_fit, "fit_damper_cable",
                        lambda *a, **k: ({LAW: {"dry": fresh}}, {"best": LAW, "families": {}, "screened": {}}))
    from sbcal.inference import harmonic_refit  # the refit is tested in test_harmonic_refit.py: not here
    monkeypatch.setattr(harmonic_refit, "refit_harmonics", lambda fit, **k: None)
    assert main(["cable", "--damper", "damper1", "--bench", str(root / "bench.csv"), "--runs", str(root / "runs"),
                 "--quiet"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if "predicted force distortion" in x)
    s, _ = read_cable(root / "runs" / "damper1" / "cable-dry")
    big, gap = s["harmonics"]["largest"]["distortion"], s["harmonics"]["largest"]["gap"]
    assert f"largest {100 * big['value']:.1f} % at {big['test']} {big['freq_hz']:g} Hz" in line
    assert f"by up to {100 * gap['value']:.1f} %" in line and "harmonics 1-9" in line



def test_sbcal_cable_names_a_zoned_law_that_only_patches(tmp_path, monkeypatch, capsys):
    """A zoned family above the winner whose zones patch a mismatched law (``zone_patch``) is named with its reason."""
    from sbcal.inference import cable_fit, harmonic_refit

    fresh = _fit(tmp_path)
    why = "clamp_zone on its bound in the dry state: median 0.399 in its box [0.05, 0.4] (within 5% of its width from an end)"
    row = {"delta_elpd": 0.0, "se_delta": 0.0, "converged": True, "patch": None}
    comparison = {"best": LAW, "converged": True, "settled": True, "higher_not_converged": [], "outscored_by": [],
                  "patched": ["iwan5_zoned"], "screened": {},
                  "families": {LAW: row, "iwan5_zoned": dict(row, delta_elpd=700.0, se_delta=55.0, patch=why)}}
    monkeypatch.setattr(cable_fit, "fit_damper_cable",
                        lambda *a, **k: ({LAW: {"dry": fresh}, "iwan5_zoned": {"dry": fresh}}, comparison))
    monkeypatch.setattr(harmonic_refit, "refit_harmonics", lambda fit, **k: None)
    assert main(["cable", "--damper", "damper1", "--bench", str(tmp_path / "bench.csv"), "--runs", str(tmp_path / "runs"),
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"not a law along the arm: iwan5_zoned scored higher, but its zones patch a mismatched law ({why})" in out
    assert "iwan5_zoned 700.0 +- 55.0" in out and f"(best: {LAW})" in out

def test_the_report_draws_the_stored_distortion(fit, plain, tmp_path, monkeypatch, capsys):
    """The report draws each cable state's stored distortion and says its largest (it solves nothing)."""
    from sbcal.core._io import write_json
    from sbcal.inference.cable_fit import store_cable
    from sbcal.model.cable_harmonics import HarmonicBalance
    from sbcal.report.build import build_report

    runs = tmp_path / "runs"
    write_json(runs / "damper1" / "diagnose.json", plain)
    s = store_cable(fit, runs / "damper1" / "cable-dry", meta={"seed": 0})

    def solve(*args, **kwargs):
        raise AssertionError("the report solved the harmonic balance again")

    monkeypatch.setattr(HarmonicBalance, "state", solve)
    page = build_report(runs, tmp_path / "rep").read_text()
    assert "Harmonic distortion the cable law predicts" in page
    assert 'data-src="figures/damper1_distortion.png"' in page
    assert (tmp_path / "rep" / "figures" / "damper1_distortion.png").is_file()
    big = s["harmonics"]["largest"]["distortion"]
    assert f"dry cable: largest {100 * big['value']:.1f} % at {big['test']} {big['freq_hz']:g} Hz" in page
    # a hand-edited distortion: one line naming the file and the key, exit 2
    summary = runs / "damper1" / "cable-dry" / "summary.json"
    write_json(summary, dict(s, harmonics=dict(s["harmonics"], distortion={"1-1": [0.1]})))
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{summary}: key 'harmonics'" in err and "\n" not in err


def test_measured_distortion_is_set_beside_the_prediction_and_switches(sweep, tmp_path):
    """A bench file with its own distortion (``sbcal import``'s column): the law's prediction confirmed at 2 mm,
    contradicted at 0.5 mm (undistorted recordings), not measured at 0.1 mm."""
    slip = predicted_distortion(sweep, _point(sweep), AMPLITUDES)
    frame = pd.concat([curves_to_frame(sweep.damper.name, t, lk.freq_hz, lk.amplitude_mm_pp,
                                       np.exp(lk.y[0] + 1j * lk.y[1]))
                       for t, lk in zip(AMPLITUDES, sweep.likes)], ignore_index=True)
    measured = {"0.1-0.1": np.nan, "0.5-0.5": 0.0}
    frame["distortion"] = np.concatenate([
        np.tile(1.1 * np.array(slip["distortion"][t], float), lk.y.shape[1]) if t == "2-2"
        else np.full(lk.y.shape[1] * lk.freq_hz.size, measured[t]) for t, lk in zip(AMPLITUDES, sweep.likes)])
    sweep_path = tmp_path / "m.csv"
    frame.to_csv(sweep_path, index=False)
    like = cable_likelihood(sweep.damper, clean_bench(load_bench(sweep_path)), list(AMPLITUDES), LAW)
    h = predicted_distortion(like, _point(like), AMPLITUDES)
    np.testing.assert_allclose(np.array(h["measured"]["2-2"], float), 1.1 * np.array(slip["distortion"]["2-2"], float))
    assert all(v is None for v in h["measured"]["0.1-0.1"]) and not any(h["agrees"]["0.1-0.1"])
    assert not any(h["agrees"]["0.5-0.5"]) and not any(h["switch"]["0.5-0.5"])  # predicted, not recorded: no switch
    on = np.array(h["switch"]["2-2"])
    gap = np.array(h["gap"]["2-2"], float)
    lk = like.likes[2]
    np.testing.assert_array_equal(on, gap > 2 * lk.sigma[0] / np.sqrt(lk.n))  # all agree at 2 mm: the gap decides
    assert on.any() and h["comparison"]["n_switch"] == on.sum()
    assert h["comparison"]["n_measured"] == 2 * STANDARD_GRID_HZ.size
    p, m = _lines(h, "distortion", AMPLITUDES), _lines(h, "measured", AMPLITUDES)
    big = np.isfinite(m) & (p > 0.01)
    assert h["comparison"]["median_ratio"] == pytest.approx(np.median(m[big] / p[big]))


def test_the_cable_states_are_refitted_side_by_side_with_the_numbers_of_one_process(fit, shown, monkeypatch):
    """Each cable state's screen is a job of its own (``workers`` processes), and the refits past their screens
    are sampled side by side with the ``workers`` shared among them (one refit to sample: both workers): every
    state gets its own record back, in order, as in one process, and the predicted distortion of the fit that
    stands is carried to the curves and the store (given to the fit, not solved again). The refit itself is
    ``test_harmonic_refit.py``'s: here one whose oiled state passes its screen (the real one samples a cable
    posterior on this fit)."""
    from dataclasses import replace

    from sbcal.inference import harmonic_refit
    from sbcal.inference.harmonic_refit import RefitPlan

    def plan(fit, **k):
        if fit.state == "dry":
            return replace(fit, refit={"state": "dry", "used": False})
        return RefitPlan(z=np.zeros(1), c=np.ones(1, complex), lines=np.ones(1, bool), record={"state": "oiled"})

    monkeypatch.setattr(harmonic_refit, "plan_refit", plan)
    monkeypatch.setattr(harmonic_refit, "sample_refit",
                        lambda fit, plan, **k: replace(fit, refit=dict(plan.record, used=False, workers=k["workers"])))
    d = resolve_damper("damper1")
    fits = {("strand_slip", state): f for state in ("dry", "oiled") for f in shown.values()}  # a damper's two states
    one, rec_one = _refit_harmonics(d, fits, seed=0, workers=1)
    two, rec_two = _refit_harmonics(d, fits, seed=0, workers=2)
    assert {s: r["state"] for s, r in rec_two.items()} == {"dry": "dry", "oiled": "oiled"}
    assert rec_one["oiled"]["workers"] == 1 and rec_two["oiled"]["workers"] == 2  # the one refit sampled gets both
    assert "workers" not in rec_two["dry"]  # screened out: not sampled

    def solved(h):  # the distortion without the solve's wall time
        return {k: v for k, v in h.items() if k != "wall_s"}

    expected = solved(json.loads(json.dumps(fit.harmonics)))
    for key in fits:
        assert solved(one[key]["harmonics"]) == solved(two[key]["harmonics"]) == expected  # not used: the fit's own
        assert two[key]["refit"]["state"] == key[1]
        carried = _cable_fits(d, two)[key]
        assert carried.distortion is two[key]["harmonics"] and carried.harmonics is carried.distortion  # not solved again
