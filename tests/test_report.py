"""The report renders from a small run store: sections, tables, every referenced image exists."""

import base64
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from sbcal.data.bench import write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.cli import main
from sbcal.model.damper import resolve_damper


class _Refs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.imgs, self.data, self.headings, self.tables = [], [], [], 0
        self._h = None

    def handle_starttag(self, tag, attrs):
        if tag == "img":  # the figure's name (data-src) and the figure itself, inside the page
            self.imgs.append(dict(attrs)["data-src"])
            self.data.append(dict(attrs)["src"])
        if tag == "table":
            self.tables += 1
        if tag in ("h2", "h3"):
            self._h = ""

    def handle_data(self, data):
        if self._h is not None:
            self._h += data

    def handle_endtag(self, tag):
        if tag in ("h2", "h3") and self._h is not None:
            self.headings.append(self._h.strip())
            self._h = None


@pytest.mark.slow
def test_report_structure(run_store, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["report", "--runs", str(run_store), "-o", str(out)]) == 0
    page = (out / "index.html").read_text()
    p = _Refs()
    p.feed(page)
    assert "How to read this page" in p.headings
    assert "damper1" in p.headings and "Provenance" in p.headings
    assert any(h.startswith("Amplitude map") for h in p.headings)
    for t in ("0.2-0.2", "0.5-0.5", "1-1", "2-2"):
        assert f"damper1 — test {t}" in p.headings
    # the unsampled test is shown as missing, not as an error
    assert re.search(r"2-2: not sampled yet", page)
    assert p.tables >= 5  # quality, three parameter tables, map, provenance
    assert len(p.imgs) >= 3 * 4 + 2
    assert len(p.data) == len(p.imgs)
    for name, src in zip(p.imgs, p.data):  # every figure inside the page: it travels alone
        assert src.startswith("data:image/png;base64,"), name
        png = base64.b64decode(src.split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000, name
        assert (out / name).read_bytes() == png, name  # ... and beside it, for slides
    assert "EJ" in page and "R-hat" in page


@pytest.mark.slow
def test_map_on_stored_runs(run_store, tmp_path):
    import json

    out = tmp_path / "m.json"
    assert main(["map", "--runs", str(run_store), "--json", str(out), "--plot", str(tmp_path / "m.png")]) == 0
    d = json.loads(out.read_text())
    # EJ falls with amplitude: a positive exponent, interval away from 0
    assert d["powerlaw"]["n"][1] > 0
    assert {t["test"] for t in d["tests"]} == {"0.2-0.2", "0.5-0.5", "1-1"}
    assert (tmp_path / "m.png").stat().st_size > 1000


@pytest.mark.slow
def test_report_shows_what_the_store_says(run_store, tmp_path):
    """The report renders the stored stages and recomputes nothing: its map numbers are the ones of
    'sbcal map --json' (the stored map.json), its removed runs those of the stored cleaning stage."""
    import json

    out = tmp_path / "m.json"
    assert main(["map", "--runs", str(run_store), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert main(["report", "--runs", str(run_store), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    for name in ("k", "n"):
        v = doc["powerlaw"][name]
        assert f'<td class="{name}">{v[0]:.3g} [{v[1]:.3g}, {v[2]:.3g}]</td>' in page
    data = json.loads((run_store / "damper1" / "data.json").read_text())
    for t, q in data["tests"].items():
        removed = ", ".join(map(str, q["removed_runs"])) or "none"
        assert f"<td>{t}</td><td>{q['runs']}</td><td>{removed}</td>" in page
    # a stored map the report shows is the store's: change it and the page changes with it
    stored = json.loads((run_store / "damper1" / "map.json").read_text())
    assert stored["powerlaw"]["k"] == doc["powerlaw"]["k"]


def test_report_on_missing_store(tmp_path, capsys):
    assert main(["report", "--runs", str(tmp_path / "none"), "-o", str(tmp_path / "r")]) == 2
    assert "no such run store" in capsys.readouterr().err


@pytest.fixture(scope="module")
def diagnosis_doc(tmp_path_factory):
    """A real ``sbcal diagnose`` result (a sensor delay found), computed once for the tests that show it."""
    from sbcal.diagnosis.diagnose import DiagnoseConfig, diagnose
    from sbcal.simulate.virtual_bench import BenchConfig, record

    d = resolve_damper("damper1")
    cfg = BenchConfig(params={"EJ": 9.0, "beta": 0.3}, effects={"sensor_delay": 4e-4}, runs=8)
    path = tmp_path_factory.mktemp("delay") / "delay.csv"
    write_bench(record(d, cfg, ["0.5-0.5", "1-1"], rng=np.random.default_rng(8)), path)
    return diagnose(d, clean_bench(load_bench(path)), seed=2, progress=False, effects=["sensor_delay", "fixture_mass"],
                    config=DiagnoseConfig(draws=150))


@pytest.mark.slow
def test_report_shows_the_diagnosis(run_store, diagnosis_doc, tmp_path, capsys):
    """A stored ``sbcal diagnose`` result gets its section: verdict, ranking, before/after, figure."""
    from sbcal.core._io import write_json

    write_json(run_store / "damper1" / "diagnose.json", diagnosis_doc)
    out = tmp_path / "rep"
    assert main(["report", "--runs", str(run_store), "-o", str(out)]) == 0
    page = (out / "index.html").read_text()
    p = _Refs()
    p.feed(page)
    assert "damper1: missing physics (sbcal diagnose)" in p.headings
    assert "Verdict: sensor_delay" in page and "ms delay" in page
    # what the verdict's model leaves, said before the tables, as the JSON says it
    from markupsafe import escape

    assert diagnosis_doc["qualifier"] in ("complete", "partial")
    q, words = diagnosis_doc["qualifier"], diagnosis_doc["remainder"]["words"]
    size = diagnosis_doc["remainder"].get("materiality")
    shown = size["words"].split(":", 1)[0] if size and not size["material"] else q  # "complete within ..."
    assert words.startswith(f"{q}: ") and f"<b>What is left: {escape(shown)}</b> — " in page
    assert escape(words[len(q) + 2:]) in page
    assert page.index("What is left") < page.index("Rule: ")
    assert "figures/damper1_diagnosis.png" in p.imgs and (out / "figures/damper1_diagnosis.png").is_file()
    # a hand-edited diagnosis with a malformed remainder: one line naming the file and the keys, exit 2
    write_json(run_store / "damper1" / "diagnose.json", dict(diagnosis_doc, qualifier="mostly", remainder="ok"))
    capsys.readouterr()
    assert main(["report", "--runs", str(run_store), "-o", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert "diagnose.json: keys 'qualifier', 'remainder'" in err and "\n" not in err
    assert not (tmp_path / "bad" / "index.html").exists()
    (run_store / "damper1" / "diagnose.json").unlink()  # the other report tests see the store as before


@pytest.mark.slow
def test_the_page_is_the_same_whatever_the_workers(run_store, tmp_path):
    """Figures drawn in worker processes: the same page and the same figure files as drawn here."""
    pages = {}
    for n in (1, 2):
        out = tmp_path / f"w{n}" / "rep"
        assert main(["report", "--runs", str(run_store), "-o", str(out), "--workers", str(n)]) == 0
        page = (out / "index.html").read_text()
        page = page.replace(f"w{n}/rep --workers {n}", "")
        pages[n] = (re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", "", page),
                    sorted(p.name for p in (out / "figures").iterdir()))
    assert pages[1] == pages[2]
    assert main(["report", "--runs", str(run_store), "--workers", "0"]) == 2


# --- the first screen, span studies' life, design searches (fake stored results: nothing is run) --------

def _png(path):
    """A small real PNG (the report copies stored figures, it does not read them)."""
    from sbcal.core.plotting import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(2, 1.5))
    ax.plot([0, 1], [0, 1])
    save_png(fig, path, dpi=50)


def _write(path, doc):
    import json

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))


CONDUCTOR = {"name": "drake", "diameter_m": 0.028143, "tension_n": 28023.8, "tension_pct_rts": 20.0,
             "span_length_m": 400.0, "wind_curve": "cigre", "self_damping": "Kraus & Hagedorn (1991)"}


def _span(runs, label, *, damped=True, life=None, **extra):
    """A span study's stored ``summary.json`` (the keys ``sbcal span`` writes), ``span.png`` and, with a
    life, ``life.png``."""
    d = runs / "span" / label
    doc = {"label": label, "damper": "damper1" if damped else "none", "conductor": CONDUCTOR,
           "cable": str(runs / "damper1" / "cable-dry") if damped else "", "cable_damper": "damper1" if damped else "",
           "state": "dry" if damped else "", "law": "dahl" if damped else "", "positions_m": [0.629] if damped else [],
           "ends": 1, "n_draws": 200 if damped else 0, "limit_mpa": 8.732,
           "margin": ({"median": 0.7402, "q05": 0.7207, "q10": 0.7238, "q95": 0.7603} if damped else
                      {"median": None, "q05": None, "q10": None, "q95": None}),
           "margin_bare": 0.1335, "per_frequency": {"frequency_hz": [10.0, 20.0]},
           "worst_stress_mpa": {"median": 11.80, "q05": 11.48, "q95": 12.12, "bare": 65.39},
           "worst_line": {"frequency_hz": 46.01, "wind_m_s": 7.0,
                          "stress_mpa": {"median": 11.80, "q05": 11.47, "q95": 12.12}, "stress_bare_mpa": 22.86},
           "model_error": ({"amplitude_mm_pp": [0.5, 1.0], "logmag_sd": [0.0133, 0.0105], "phase_sd_deg": [0.84, 0.61]}
                           if damped else None),
           "placement": None, "life": life, "warnings": [], "made_by": "sbcal span ..."}
    doc.update(extra)
    _png(d / "span.png")
    if life is not None:
        _png(d / "life.png")
    _write(d / "summary.json", doc)
    return d


LIFE = {"climate": "weibull:k=2,c=4.5", "across": 0.25, "hours_per_year": 1843.0, "years_bare": 3.217,
        "damage_per_year_bare": 0.3109, "unlimited_bare": False,
        "years": {"median": 187.4, "q05": 96.21, "q95": None}, "damage_per_year": {"median": 0.005336, "q05": 0.0,
                                                                                  "q95": 0.01039},
        "unlimited": False}
LIFE_UNLIMITED = {"climate": "winds.csv", "across": 1.0, "hours_per_year": 8760.0, "years_bare": None,
                  "damage_per_year_bare": 0.0, "unlimited_bare": True, "years": None, "damage_per_year": None,
                  "unlimited": False}


def _design(runs, label, **extra):
    """A design search's stored ``summary.json`` (the keys ``sbcal design`` writes), ``best.toml``,
    ``designs.csv`` and ``design.png``."""
    d = runs / "design" / label
    rec = {"objective": 0.4120, "margin": {"median": 0.4388, "q05": 0.4012, "q95": 0.4771, "q10": 0.4120},
           "position_m": 1.114, "total_mass_kg": 3.41, "extrapolated": False}
    doc = {"conductor": "drake", "cable": str(runs / "damper1" / "cable-dry"), "space": "space.toml",
           "vary": {"mass1_kg": [0.5, 3.0], "arm1_m": [0.1, 0.3]}, "constraints": {"total_mass_kg": 5.0},
           "objective": "margin", "quantile": 0.1, "ends": 1, "climate": None, "across": 1.0,
           "start": dict(rec, fields={"mass1_kg": 1.2, "arm1_m": 0.18}),
           "best": dict(rec, objective=0.8765, margin={"median": 0.9012, "q05": 0.8521, "q95": 0.9433, "q10": 0.8765},
                        position_m=0.7345, total_mass_kg=4.56, fields={"mass1_kg": 2.345, "arm1_m": 0.2468}),
           "best_damper": "damper1-design", "evaluations": 96, "seed": 7,
           "optimiser": {"name": "scipy.optimize.differential_evolution", "popsize": 16, "generations": 6,
                         "search": {"n_draws": 40, "n_freq": 30, "n_positions": 12},
                         "final": {"n_draws": 200, "n_freq": 60}},
           "warnings": ["2 designs bend the arms beyond the calibrated curvature"], "made_by": "sbcal design ..."}
    doc.update(extra)
    _png(d / "design.png")
    (d / "best.toml").write_text('name = "damper1-design"\n')
    (d / "designs.csv").write_text("mass1_kg,arm1_m,objective\n1.2,0.18,0.41\n")
    _write(d / "summary.json", doc)
    return d


def _cable(runs, damper, state):
    """A stored cable law (``dahl``: few parameters) with a small posterior: what the report reads."""
    from sbcal.inference.runs import write_inference_data

    d = runs / damper / f"cable-{state}"
    rng = np.random.default_rng(1)
    post = {"EJ_min": 5 + rng.random((2, 20)), "beta_material": 0.1 + 0.01 * rng.random((2, 20)),
            "delta_EJ": 20 + rng.random((2, 20)), "chi_dahl": 1e-3 * (1 + rng.random((2, 20)))}
    write_inference_data(d / "posterior.nc", {"posterior": post})
    _write(d / "summary.json", {"damper": damper, "state": state, "law": "dahl", "converged": True,
                                "tests_reached": {"0.5-0.5": {"curvature_min": 1e-4, "curvature_max": 1e-2}}})


def _section(page, start_id, end_marker):
    """The page from the element with ``id=start_id`` to ``end_marker``."""
    a = page.index(f'id="{start_id}"')
    return page[a:page.index(end_marker, a)]


@pytest.fixture(scope="module")
def full_store(run_store, diagnosis_doc, tmp_path_factory):
    """A copy of the run store with a diagnosis, a cable law, two span studies (one with a life, one
    bare with an unlimited life) and a design search."""
    import shutil

    from sbcal.core._io import write_json

    runs = tmp_path_factory.mktemp("full") / "runs"
    shutil.copytree(run_store, runs)
    write_json(runs / "damper1" / "diagnose.json", diagnosis_doc)
    _cable(runs, "damper1", "dry")
    _span(runs, "drake-damper1-dry", life=LIFE)
    _span(runs, "drake-bare", damped=False, life=LIFE_UNLIMITED)
    _design(runs, "drake-damper1-damper1-dry")
    return runs


@pytest.fixture(scope="module")
def full_report(full_store, tmp_path_factory):
    """``(report directory, page)`` of the full store, built once."""
    out = tmp_path_factory.mktemp("full_report") / "rep"
    assert main(["report", "--runs", str(full_store), "-o", str(out)]) == 0
    return out, (out / "index.html").read_text()


def test_the_first_screen_is_the_headline(full_report):
    """Before any per-test section: per damper the verdict and the cable law, per span the margins and
    the life with and without dampers, per design search the best design against the start; every row
    links to its section."""
    out, page = full_report
    first = _section(page, "summary", "How to read this page")
    assert page.index('id="summary"') < page.index('id="damper1-0.2-0.2"') < page.index('id="spans"')
    # per damper
    assert '<a href="#damper1">damper1</a>' in first and "3 of 4" in first
    assert '<a href="#damper1-diagnosis">verdict: sensor_delay</a>' in first
    assert "verdict: sensor_delay</a> — <b>complete</b><br><small>what sensor_delay leaves is consistent" in first
    assert "dry: dahl</a> (converged)" in first
    # per span: margins and life, bare and with dampers
    assert '<a href="#span-drake-damper1-dry">' in first and '<a href="#span-drake-bare">' in first
    assert "<td>0.134</td><td>0.74 [0.721, 0.76]</td><td>3.22</td><td>187 [96.2, unlimited]</td>" in first
    assert "<td>unlimited</td><td>—</td>" in first  # the bare span takes no damage
    # per design search: start and best
    assert '<a href="#design-drake-damper1-damper1-dry">' in first
    assert "margin 0.412</td><td>0.439 [0.401, 0.477]</td><td>1.11</td><td>3.41</td>" in first
    assert "margin 0.876</td><td>0.901 [0.852, 0.943]</td><td>0.735</td><td>4.56</td>" in first
    # every link of the first screen has its target, and every image its file
    ids = set(re.findall(r'id="([^"]+)"', page))
    for target in re.findall(r'href="#([^"]+)"', first):
        assert target in ids, target
    p = _Refs()
    p.feed(page)
    for src in p.imgs:
        assert (out / src).is_file(), src
    assert "figures/damper1_law.png" in p.imgs


def test_the_span_section_shows_the_life(full_report):
    out, page = full_report
    damped = _section(page, "span-drake-damper1-dry", "<h2")
    assert "<td>no damper</td><td>3.22</td><td>0.311</td>" in damped
    assert "<td>187 [96.2, unlimited]</td><td>0.00534 [0, 0.0104]</td>" in damped
    assert "weibull:k=2,c=4.5" in damped and "25 % of the time" in damped
    assert ("Worst line with the dampers: 46 Hz (wind 7 m/s), stress 11.8 [11.5, 12.1] MPa; the bare span's there "
            "22.9 MPa (limit 8.73 MPa)") in damped
    assert "hold the calibration&#39;s model error" in damped and "1 mm p-p 1.1 % / 0.6°" in damped
    assert "(10 %: 0.724)" in damped
    assert 'data-src="figures/life_drake-damper1-dry.png"' in damped
    assert (out / "figures" / "life_drake-damper1-dry.png").is_file()
    bare = _section(page, "span-drake-bare", "<h3")
    assert "<td>no damper</td><td>unlimited</td><td>0</td>" in bare and "with dampers" not in bare
    assert "model error" not in bare and "Margin (no damper) 0.134." in bare
    assert "Worst line: 46 Hz (wind 7 m/s), stress 22.9 MPa (limit 8.73 MPa)" in bare


def test_the_design_section(full_report):
    out, page = full_report
    p = _Refs()
    p.feed(page)
    assert "Design searches (sbcal design)" in p.headings
    g = _section(page, "design-drake-damper1-damper1-dry", "</table>")
    assert "<td>mass1_kg</td><td>1.2</td><td>2.35</td>" in g and "<td>arm1_m</td><td>0.18</td><td>0.247</td>" in g
    assert "<td>objective: margin q10</td><td>0.412</td><td>0.876</td>" in g
    assert "<td>0.439 [0.401, 0.477]</td><td>0.901 [0.852, 0.943]</td>" in g
    assert "<td>damper position [m]</td><td>1.11</td><td>0.735</td>" in g
    assert "<td>total mass [kg]</td><td>3.41</td><td>4.56</td>" in g
    assert "scipy.optimize.differential_evolution, population 16, 6 generations; 96 designs evaluated" in g
    assert "2 designs bend the arms beyond the calibrated curvature" in g
    assert "total_mass_kg ≤ 5" in g
    assert (out / "files" / "design_drake-damper1-damper1-dry_best.toml").read_text() == 'name = "damper1-design"\n'
    assert 'data-src="files/design_drake-damper1-damper1-dry_best.toml" download="design_drake-damper1-damper1-dry_best.toml"' in page
    assert "figures/design_drake-damper1-damper1-dry.png" in p.imgs


def test_a_life_design_and_a_malformed_one(tmp_path, capsys):
    """A store of span studies and design searches only still builds; a life objective shows years
    ("unlimited" for a null); a design summary missing 'best' is one line, exit 2, no traceback."""
    runs = tmp_path / "runs"
    _design(runs, "drake-d-d-dry-life", objective="life", climate="weibull:k=2,c=4.5", across=0.25,
            start={"fields": {"mass1_kg": 1.2, "arm1_m": 0.18}, "objective": 51.2, "margin": {"median": 0.5, "q05": 0.4,
                   "q95": 0.6, "q10": 0.42}, "position_m": 1.0, "total_mass_kg": 3.4, "extrapolated": False,
                   "years": {"median": 80.1, "q05": 40.2, "q95": 150.3, "q10": 51.2}},
            best={"fields": {"mass1_kg": 2.0, "arm1_m": 0.2}, "objective": None, "margin": {"median": 1.5, "q05": 1.2,
                  "q95": 1.9, "q10": 1.3}, "position_m": 0.8, "total_mass_kg": 4.4, "extrapolated": True,
                  "years": {"median": None, "q05": 900.0, "q95": None, "q10": None}})
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    g = _section(page, "design-drake-d-d-dry-life", "</table>")
    assert "<td>objective: life q10 [years]</td><td>51.2</td><td>unlimited</td>" in g
    assert "<td>80.1 [40.2, 150]</td><td>unlimited [900, unlimited]</td>" in g
    assert '<td class="bad">yes</td>' in g
    assert "No damper calibrated in this store" in page and 'id="spans"' not in page
    (runs / "design" / "bad").mkdir()
    _write(runs / "design" / "bad" / "summary.json", {"objective": "margin", "start": {}, "optimiser": {},
                                                      "evaluations": 1})
    capsys.readouterr()
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "rep2")]) == 2
    err = capsys.readouterr().err
    assert "bad/summary.json: key 'best': missing" in err and "Traceback" not in err and err.count("\n") == 1
    _write(runs / "design" / "bad" / "summary.json", {"objective": "margin", "start": {}, "best": {}, "optimiser": {},
                                                      "evaluations": 1})
    assert main(["report", "--runs", str(runs), "-o", str(tmp_path / "rep3")]) == 2
    err = capsys.readouterr().err
    assert "bad/summary.json: not a design search written by sbcal design" in err and err.count("\n") == 1


def test_an_empty_store_builds(tmp_path):
    (tmp_path / "runs").mkdir()
    assert main(["report", "--runs", str(tmp_path / "runs"), "-o", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert 'id="summary"' in page and 'id="designs"' not in page and 'id="spans"' not in page
