"""``sbcal batch``: a lot of units from a run store, end to end through the CLI, and the lot it refuses."""

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from sbcal.cli.app import main


@pytest.fixture(scope="module")
def lot(tmp_path_factory):
    """Four units of damper1 (virtual lot, one test, unit 2 planted at EJ -15 %), calibrated by sbcal run."""
    root = tmp_path_factory.mktemp("lot")
    bench = root / "lot.csv"
    assert main(["bench", "--damper", "damper1", "--units", "4", "--outlier-unit", "2", "--tests", "0.5-0.5",
                 "--runs-per-test", "6", "--seed", "5", "-o", str(bench)]) == 0
    runs = root / "runs"
    assert main(["run", "--bench", str(bench), "--design", "damper1", "--until", "sample", "--runs", str(runs),
                 "--quiet", "--workers", "1"]) == 0
    return runs


def _batch(runs, out, *extra):
    return main(["batch", "--runs", str(runs), "-o", str(out), "--quiet", "--seed", "1", *extra])


@pytest.mark.slow
def test_batch_writes_the_population_and_says_it_first(lot, tmp_path, capsys):
    out = tmp_path / "b"
    assert _batch(lot, out) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("4 units: population EJ ") and "unit scatter" in first
    doc = json.loads((out / "summary.json").read_text())
    assert doc["converged"] and doc["n_units"] == 4 and doc["tests"] == ["0.5-0.5"]
    assert set(doc["versions"]) >= {"numpy", "emcee"} and doc["seed"] == 1
    # the units' own estimates against the virtual lot's truth: EJ = 11.3 N m^2 times the unit factor, the
    # planted unit (u02) at 0.85; the population's median unit between the units' extremes
    own = {u["unit"]: u["values"]["EJ[0.5-0.5]"]["own"][1] for u in doc["per_unit"]}
    assert own["damper1-u02"] == min(own.values())
    pop = doc["population"][0]
    assert pop["parameter"] == "EJ" and min(own.values()) < pop["median_unit"][1] < max(own.values())
    lo, med, hi = pop["next_unit"]
    assert lo < med < hi and hi / lo > 1.02           # the next unit carries the lot's scatter
    units = pd.read_csv(out / "units.csv")
    assert set(units["unit"]) == set(own) and units["outlier_probability"].between(0, 1).all()
    population = pd.read_csv(out / "population.csv")
    assert list(population["parameter"]) == ["EJ", "beta"]
    for u in doc["per_unit"]:
        assert u["ess_median"] > 30 and not u["flagged"]


@pytest.mark.slow
def test_batch_same_seed_same_numbers(lot, tmp_path):
    docs = []
    for name in ("a", "b"):
        assert _batch(lot, tmp_path / name, "--params", "EJ") == 0
        docs.append(json.loads((tmp_path / name / "summary.json").read_text()))
    for key in ("population", "per_unit"):
        assert docs[0][key] == docs[1][key]


def _copy(lot, tmp_path):
    runs = tmp_path / "runs"
    shutil.copytree(lot, runs)
    shutil.rmtree(runs / "batch", ignore_errors=True)
    return runs


@pytest.mark.parametrize("extra, message", [
    (["--dampers", "damper1-u01", "damper1-u02"], "a population needs at least 3"),
    (["--params", "EJ", "mu"], "parameter 'mu' not stored"),
    (["--tests", "2-2"], "test '2-2' not stored for unit 'damper1-u01'"),
    (["--dampers", "damper1-u01", "damper1-u02", "nosuch"], "no finished theta1 posteriors of unit 'nosuch'"),
    (["--seed", "-1"], "argument --seed: expected an integer >= 0, got -1"),
])
def test_batch_refuses_a_bad_lot_in_one_line(lot, tmp_path, capsys, extra, message):
    runs = _copy(lot, tmp_path)
    out = tmp_path / "out"
    assert _batch(runs, out, *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_batch_refuses_units_of_different_designs(lot, tmp_path, capsys):
    runs = _copy(lot, tmp_path)
    summary = runs / "damper1-u03" / "0.5-0.5" / "theta1" / "summary.json"
    doc = json.loads(summary.read_text())
    doc["config"]["damper_values"]["m1"] *= 1.2
    summary.write_text(json.dumps(doc))
    out = tmp_path / "out"
    assert _batch(runs, out) == 2
    err = capsys.readouterr().err.strip()
    assert "damper field 'm1'" in err and "different designs" in err and "\n" not in err
    assert not out.exists()


@pytest.mark.slow
def test_an_unconverged_unit_is_left_out_and_said(lot, tmp_path, capsys):
    runs = _copy(lot, tmp_path)
    summary = runs / "damper1-u04" / "0.5-0.5" / "theta1" / "summary.json"
    doc = json.loads(summary.read_text())
    doc["converged"] = False
    summary.write_text(json.dumps(doc))
    out = tmp_path / "out"
    assert _batch(runs, out) == 0
    captured = capsys.readouterr()
    assert "unit damper1-u04 left out" in captured.err
    assert captured.out.startswith("3 units:") and "left out: damper1-u04" in captured.out.splitlines()[0]
    assert np.isclose(json.loads((out / "summary.json").read_text())["n_units"], 3)


def test_line_departures_name_the_lines_where_a_unit_is_not_like_the_lot():
    """Twelve units' run means with the lot's scatter; unit 5 is 10 scatters high in magnitude at 12-15 Hz:
    exactly that range is named for it; no other line of any unit at a 1e-3 line rate with this seed."""
    from sbcal.inference.batch import line_departures

    rng = np.random.default_rng(8)
    freq = np.arange(4.0, 40.5, 1.0)
    units = [f"u{k}" for k in range(12)]
    curves = {}
    for k, u in enumerate(units):
        logmag = 8.0 + 0.05 * rng.standard_normal(freq.size)
        phase = 0.5 + 0.02 * rng.standard_normal(freq.size)
        if k == 5:
            logmag = logmag + 0.5 * ((freq >= 12) & (freq <= 15))
        curves[u, "1-1"] = (freq, {"logmag": logmag, "phase": phase})
    out = line_departures(curves, units, ["1-1"])
    (span,) = out["u5"]["1-1"]
    assert (span["from_hz"], span["to_hz"], span["quantity"], span["direction"]) == (12.0, 15.0, "magnitude", "above")
    assert all(not out[u]["1-1"] for u in units if u != "u5")


def test_a_stored_summary_without_its_config_is_refused_in_one_line(lot, tmp_path, capsys):
    runs = _copy(lot, tmp_path)
    (runs / "damper1-u02" / "0.5-0.5" / "theta1" / "summary.json").write_text('{"converged": true, "parameters": {}}')
    out = tmp_path / "out"
    assert _batch(runs, out) == 2
    err = capsys.readouterr().err.strip()
    assert "damper1-u02/0.5-0.5/theta1/summary.json: key 'config'" in err and "\n" not in err
    assert not out.exists()


def test_batch_names_a_missing_run_store(tmp_path, capsys):
    from sbcal.cli.app import main as cli

    assert cli(["batch", "--runs", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("no such run store (sbcal run --runs DIR writes one)") and "\n" not in err



def _cable_lot(lot, tmp_path):
    """The lot with a cable fit (state dry) per unit, and a state wet of the first unit alone."""
    from .test_batch_cable import _truths, _unit

    runs = _copy(lot, tmp_path)
    units = ["damper1-u01", "damper1-u02", "damper1-u03", "damper1-u04"]
    source = json.loads((runs / units[0] / "0.5-0.5" / "theta1" / "summary.json").read_text())["config"]["damper_values"]["source"]
    for k, (u, t) in enumerate(zip(units, _truths(4, seed=2))):
        _unit(tmp_path, runs, u, t, seed=50 + k, n_draws=60, source=source)
    shutil.copytree(runs / units[0] / "cable-dry", runs / units[0] / "cable-wet")
    return runs, units


@pytest.mark.slow
def test_batch_refuses_a_cable_state_a_unit_lacks_before_writing(lot, tmp_path, capsys):
    runs, _ = _cable_lot(lot, tmp_path)
    out = tmp_path / "out"
    assert _batch(runs, out, "--cable-states", "wet") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "damper1-u02/cable-wet: no cable fit of state 'wet'" in err[0], err
    assert not out.exists()
    assert _batch(runs, out, "--params", "EJ", "--cable-states", "none") == 0
    assert (out / "summary.json").is_file() and not (out / "cable-dry").exists()


@pytest.mark.long
def test_batch_pools_the_units_cable_law_into_the_designs_cable_run(lot, tmp_path, capsys):
    """Units with a cable fit: their law pooled, the next unit stored as a cable run that predict reads; a
    state one unit lacks is said and skipped."""
    from sbcal.design.cable_run import load_cable_run

    runs, units = _cable_lot(lot, tmp_path)
    out = runs / "batch"                                  # the default, where the report looks
    assert main(["batch", "--runs", str(runs), "--quiet", "--seed", "1", "--params", "EJ"]) == 0
    captured = capsys.readouterr()
    assert "cable state wet not pooled: no cable fit of it for damper1-u02, damper1-u03, damper1-u04" in captured.err
    line = next(x for x in captured.out.splitlines() if x.startswith("cable dry"))
    assert line.startswith("cable dry (iwan5): 4 units: population EJ_min ")
    run = load_cable_run(out / "cable-dry")
    assert run.law == "iwan5" and run.summary["kind"] == "design" and run.summary["units"] == units
    assert run.calibration.name == "damper1-design" and run.n_draws > 1000
    csv = tmp_path / "p.csv"
    assert main(["predict", "--cable", str(out / "cable-dry"), "--damper", "damper1", "--amplitude", "1",
                 "--draws", "50", "-o", str(csv)]) == 0
    assert len(pd.read_csv(csv)) > 0
    # the report reads both stored populations
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "report"), "--quiet"]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    assert "The lot as a population" in page and "The design's cable law: dry (iwan5)" in page
    assert str(out / "cable-dry") in page
