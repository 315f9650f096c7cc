"""``sbcal design`` and :func:`sbcal.design.search.design`: the damper design that maximises a span's margin.

The stored cable posterior is the fast one of :func:`tests.test_predict._store` (draws about a known iwan5
cable), its calibrated curvature range widened so that no design here is an extrapolation (its two
tests reach only 1 mm p-p; the span bends the arms further). No cable fit runs here.
"""

import json
import tomllib

import numpy as np
import pytest

from sbcal.cli import main
from sbcal.design.conductor import resolve_conductor
from sbcal.design.search import Search, design, evaluate_design
from sbcal.design.space import parse_space
from sbcal.model.damper import parse_damper, resolve_damper, with_value

from .test_predict import _store

GRID = Search(n_draws=6, n_freq=10, n_positions=6)  # about a second per design
WIND = (1.0, 4.0)  # a band where the arm length has an interior optimum (about 0.35 m)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = _store(tmp_path_factory.mktemp("cable"))
    s = json.loads((out / "summary.json").read_text())
    for t in s["tests_reached"].values():
        t["curvature_min"], t["curvature_max"] = 1e-6, 1e3
    (out / "summary.json").write_text(json.dumps(s))
    return out


@pytest.mark.slow
def test_design_finds_the_optimum_of_a_sweep(run):
    """One free field (the clamp-to-mass-1 arm): the search lands within the sweep's resolution of the
    sweep's best value, with an objective at least the sweep's best less its variation over one step."""
    c, d = resolve_conductor("drake"), resolve_damper("damper1")
    values = np.linspace(0.10, 0.40, 7)  # resolution 0.05 m
    # the seed fixes the draws and the model errors: the sweep's and the search's objective are one function
    sweep = np.array([evaluate_design(c, run, with_value(d, "cable.length1_m", v), wind=WIND, n_draws=GRID.n_draws,
                                      n_freq=GRID.n_freq, n_positions=GRID.n_positions, seed=1)["objective"]
                      for v in values])
    k = int(np.argmax(sweep))
    assert 0 < k < values.size - 1  # an interior optimum: the test is not about a bound
    space = parse_space({"vary": {"cable.length1_m": [0.10, 0.40]}}, d, "space.toml")
    res = design(c, run, d, space, budget=16, seed=1, wind=WIND, n_freq=8, n_draws=4, search=GRID)
    best = max(res.records, key=lambda r: r["objective"])
    assert abs(best["fields"]["cable.length1_m"] - values[k]) <= 0.05
    step = max(abs(sweep[k] - sweep[k - 1]), abs(sweep[k] - sweep[k + 1]))
    assert best["objective"] >= sweep[k] - step
    assert len(res.records) == 16 and res.optimiser["generations"] == 2
    # the starting damper is one of the designs and the reported best is at least the start
    assert any(r["fields"]["cable.length1_m"] == d.L1 for r in res.records)
    assert res.best["objective"] >= res.start["objective"]


@pytest.mark.slow
def test_cli_design_writes_a_damper_that_span_reproduces(run, tmp_path, capsys):
    space = tmp_path / "space.toml"
    space.write_text('[vary]\n"cable.length1_m" = [0.10, 0.40]\n[constraints]\narm_length_sum_m_max = 0.6\n')
    out = tmp_path / "design"
    argv = ["design", "--conductor", "drake", "--cable", str(run), "--damper", "damper1", "--space", str(space),
            "--budget", "8", "--search-grid", "4,8,4", "--wind", "1:4", "--lines", "8", "--draws", "4",
            "--workers", "1", "-o", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    # the same seed, the same designs and numbers (with two processes: a generation's jobs in any order)
    assert main(argv[:-1] + [str(tmp_path / "again"), "--workers", "2"]) == 0
    capsys.readouterr()
    assert (tmp_path / "again" / "designs.csv").read_text() == (out / "designs.csv").read_text()
    assert "start:" in text and "best :" in text and "reproduces the best" in text
    doc = json.loads((out / "summary.json").read_text())
    for key in ("start", "best", "optimiser", "evaluations", "seed"):
        assert key in doc
    for rec in (doc["start"], doc["best"]):
        assert set(rec) >= {"fields", "objective", "margin", "position_m", "total_mass_kg", "extrapolated"}
        assert set(rec["margin"]) == {"median", "q05", "q95", "q10"}
    assert doc["evaluations"] == 8 and doc["best"]["objective"] >= doc["start"]["objective"]
    best = parse_damper(tomllib.loads((out / "best.toml").read_text()))
    assert best.L1 + best.L2 <= 0.6 and best.L1 == pytest.approx(doc["best"]["fields"]["cable.length1_m"], rel=1e-12)
    assert (out / "designs.csv").read_text().count("\n") == 9 and (out / "design.png").stat().st_size > 1000
    # sbcal span on the written file, with the same settings, gives the same objective
    js = tmp_path / "span.json"
    assert main(["span", "--conductor", "drake", "--damper", str(out / "best.toml"), "--cable", str(run), "--optimise",
                 "--wind", "1:4", "--lines", "8", "--draws", "4", "--quiet", "-o", str(tmp_path / "span"),
                 "--json", str(js)]) == 0
    assert json.loads(js.read_text())["margin"]["q10"] == pytest.approx(doc["best"]["objective"], rel=1e-9)


@pytest.mark.parametrize("space, message", [
    ('[vary]\n"mass1.colour" = [1, 2]\n', r"space.toml: key 'vary.mass1.colour': unknown damper field"),
    ('[vary]\n"mass1.mass_kg" = [3.0, 1.0]\n', r"key 'vary.mass1.mass_kg': empty or inverted bounds \[3, 1\]"),
    ('[vary]\n"mass1.mass_kg" = [2.0, 2.0]\n', r"empty or inverted bounds"),
    ('[vary]\n"mass1.mass_kg" = [-1.0, 2.0]\n', r"key 'mass1.mass_kg': must be > 0"),
    ('[vary]\n"cable.ej_static_nm2" = [50, 150]\n', r"not a design field \(the cable's rigidity"),
    ('[vary]\n', r"table '\[vary\]': missing or empty"),
    ('[vary]\n"mass1.mass_kg" = [1.0, 3.0]\n[constraints]\ntotal_mass_kg_max = 2.0\n',
     r"key 'constraints.total_mass_kg_max': no design in the box meets it \(least total mass 4\.712"),
    ('[vary]\n"mass1.mass_kg" = [1.0, 3.0]\n[constraints]\nlightest = 2.0\n', r"'constraints.lightest': unknown constraint"),
])
def test_cli_design_bad_space_is_one_line(run, tmp_path, capsys, space, message):
    p = tmp_path / "space.toml"
    p.write_text(space)
    out = tmp_path / "design"
    code = main(["design", "--conductor", "drake", "--cable", str(run), "--damper", "damper1", "--space", str(p),
                 "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("sbcal: error: ")
    assert __import__("re").search(message, err), err
    assert not out.exists()


def test_cli_design_bad_options(run, tmp_path, capsys):
    p = tmp_path / "space.toml"
    p.write_text('[vary]\n"mass1.mass_kg" = [1.0, 3.0]\n')
    base = ["design", "--conductor", "drake", "--cable", str(run), "--damper", "damper1", "--space", str(p),
            "-o", str(tmp_path / "d")]
    for extra, message in ((["--budget", "3"], "--budget: expected an integer >= 8"),
                           (["--objective", "life"], "--objective life: give the wind climate"),
                           (["--search-grid", "6,10"], "--search-grid '6,10': expected three integers")):
        assert main(base + extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_life_objective_is_the_life_q10_at_the_best_position(run):
    """With the life objective the score is the 10 % quantile of the service life [years] where the
    margin is best, and the reported life equals sbcal span's life for the same damper there."""
    from sbcal.design.life import parse_climate
    from sbcal.design.span_study import span_study

    c, d = resolve_conductor("drake"), resolve_damper("damper1")
    climate = parse_climate("weibull:k=2.0,c=3.0")
    space = parse_space({"vary": {"cable.length1_m": [0.10, 0.40]}}, d, "space.toml")
    res = design(c, run, d, space, objective="life", climate=climate, across=0.5, budget=8, seed=0, wind=WIND,
                 n_freq=8, n_draws=4, search=Search(n_draws=4, n_freq=8, n_positions=4))
    for rec in res.records:
        assert rec["objective"] == rec["years"]["q10"] and rec["years"]["q10"] > 0
    assert res.best["objective"] >= res.start["objective"] and res.summary()["objective"] == "life"
    study = span_study(c, res.best_damper, cable=run, optimise=True, wind=WIND, n_freq=8, n_draws=4, climate=climate,
                       across=0.5)
    years = np.quantile(1.0 / study.life.damage_draws, [0.1, 0.5])
    assert res.best["years"]["q10"] == pytest.approx(years[0], rel=1e-9)
    assert res.best["years"]["median"] == pytest.approx(years[1], rel=1e-9)


def test_unlimited_lives_are_the_best_objective_not_a_nan():
    """A design under which no draw takes damage has an infinite life: its quantiles stay inf (no
    inf - inf interpolation), the optimiser ranks it first, and the summary stores null."""
    from sbcal.design.search import _minimised, _quantiles
    from sbcal.core._io import json_ready

    q = _quantiles(np.r_[np.full(5, 30.0), np.full(5, np.inf)])
    assert q["q10"] == 30.0 and q["q95"] == np.inf and np.isfinite(q["q05"])
    all_inf = _quantiles(np.full(8, np.inf))
    assert all(v == np.inf for v in all_inf.values())
    assert _minimised({"objective": np.inf, "extrapolated": False}) < _minimised({"objective": 1e3, "extrapolated": False})
    assert _minimised({"objective": np.nan, "extrapolated": False}) > _minimised({"objective": 0.0, "extrapolated": False})
    assert json_ready({"years": all_inf})["years"]["q10"] is None


@pytest.mark.long
def test_on_the_bundled_cable_the_search_beats_the_start_and_a_random_search(tmp_path):
    """The issue's claim on real data: damper1's dry cable fitted on the bundled recordings, Drake,
    four free fields under two constraints (the box of benchmarks/design.py). The chosen design's
    margin q10 is at least the starting damper's, and on the search grid the search's best is at least
    the best of 100 designs drawn uniformly in the same box with the same seed (measured: 0.711 -> 0.906;
    search 0.908 against random 0.870)."""
    import pandas as pd

    from sbcal.core.workers import run_jobs
    from sbcal.data.readers import default_bench_path
    from sbcal.design.search import _Evaluate

    bench = pd.read_csv(default_bench_path())
    dry = bench[(bench["damper"] == "damper1") & ~bench["test"].str.contains("oiled")]
    dry.to_csv(tmp_path / "dry.csv", index=False)
    runs = tmp_path / "runs"
    assert main(["cable", "--damper", "damper1", "--bench", str(tmp_path / "dry.csv"), "--law", "iwan5",
                 "--runs", str(runs), "--quiet"]) == 0
    run = runs / "damper1" / "cable-dry"
    c, d = resolve_conductor("drake"), resolve_damper("damper1")
    space = parse_space({"vary": {"mass1.mass_kg": [1.5, 4.5], "mass2.mass_kg": [1.0, 4.0],
                                  "cable.length1_m": [0.12, 0.30], "cable.length2_m": [0.10, 0.25]},
                         "constraints": {"total_mass_kg_max": 9.0, "arm_length_sum_m_max": 0.5}}, d, "space.toml")
    res = design(c, run, d, space, budget=120, seed=0, workers=2, progress=False)
    assert not res.best["extrapolated"] and res.best["objective"] >= res.start["objective"]
    search_best = max(r["objective"] for r in res.records if not r["extrapolated"])
    rng = np.random.default_rng(0)
    lo, hi = np.array(space.lower), np.array(space.upper)
    xs = [x for x in lo + (hi - lo) * rng.random((100, lo.size)) if space.feasible(space.damper(d, x))]
    evaluate = _Evaluate(conductor=c, cable=str(run), start=d, space=space, objective="margin", ends=1,
                         wind=(1.0, 7.0), search=Search(), seed=0, model_error=True)
    random = [r["objective"] for r in run_jobs(evaluate, xs, workers=2) if not r["extrapolated"]]
    assert len(random) >= 50 and search_best >= max(random)
