"""The report renders from a small run store: sections, tables, every referenced image exists."""

import re
from html.parser import HTMLParser

import numpy as np
import pytest

from sbcal import STANDARD_GRID_HZ as F, dynamic_stiffness
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.pipeline import Settings, clean, map_damper, sample_tests
from sbcal.cli import main
from sbcal.model.damper import resolve_damper
from sbcal.inference.sampler import SamplerConfig

FAST = SamplerConfig(nwalkers=16, max_draws=150, de_population=30, de_generations=60)


class _Refs(HTMLParser):
    def __init__(self):
        super().__init__()
        self.imgs, self.headings, self.tables = [], [], 0
        self._h = None

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.imgs.append(dict(attrs)["src"])
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


@pytest.fixture(scope="module")
def run_store(tmp_path_factory):
    """damper1 at three amplitudes (EJ falling with amplitude), sampled fast; one test left unsampled."""
    tmp = tmp_path_factory.mktemp("store")
    d = resolve_damper("damper1")
    rng = np.random.default_rng(77)
    frames = []
    for amp, ej, beta in ((0.2, 20.0, 0.25), (0.5, 12.0, 0.3), (1.0, 9.0, 0.33), (2.0, 7.0, 0.35)):
        fuu = dynamic_stiffness(d, F, EJ=ej, beta=beta)
        noisy = fuu * np.exp(0.02 * rng.standard_normal((6, F.size)) + 0.01j * rng.standard_normal((6, F.size)))
        frames.append(curves_to_frame("damper1", f"{amp:g}-{amp:g}", F, amp, noisy))
    import pandas as pd

    path = tmp / "bench.csv"
    write_bench(pd.concat(frames), path)
    bench = load_bench(path)
    runs = tmp / "runs"
    settings = Settings(seed=3, sampler=FAST, workers=2)
    data = clean(bench, [d], store=runs, settings=settings)
    sample_tests(data, [(d, t) for t in ("0.2-0.2", "0.5-0.5", "1-1")], store=runs, settings=settings, progress=False)
    map_damper(runs, "damper1", settings=settings)
    return runs


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
    for src in p.imgs:
        assert not src.startswith(("http:", "https:", "/")), src  # self-contained, relative
        assert (out / src).is_file() and (out / src).stat().st_size > 1000, src
    assert "EJ" in page and "R-hat" in page


def test_map_on_stored_runs(run_store, tmp_path):
    import json

    out = tmp_path / "m.json"
    assert main(["map", "--runs", str(run_store), "--json", str(out), "--plot", str(tmp_path / "m.png")]) == 0
    d = json.loads(out.read_text())
    # EJ falls with amplitude: a positive exponent, interval away from 0
    assert d["powerlaw"]["n"][1] > 0
    assert {t["test"] for t in d["tests"]} == {"0.2-0.2", "0.5-0.5", "1-1"}
    assert (tmp_path / "m.png").stat().st_size > 1000


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


def test_report_shows_the_diagnosis(run_store, tmp_path):
    """A stored ``sbcal diagnose`` result gets its section: verdict, ranking, before/after, figure."""
    from sbcal.diagnosis.diagnose import DiagnoseConfig
    from sbcal.simulate.virtual_bench import BenchConfig, record

    from sbcal.core._io import write_json
    from sbcal.diagnosis.diagnose import diagnose

    d = resolve_damper("damper1")
    cfg = BenchConfig(params={"EJ": 9.0, "beta": 0.3}, effects={"sensor_delay": 4e-4}, runs=8)
    path = tmp_path / "delay.csv"
    write_bench(record(d, cfg, ["0.5-0.5", "1-1"], rng=np.random.default_rng(8)), path)
    doc = diagnose(d, clean_bench(load_bench(path)), seed=2, progress=False, effects=["sensor_delay", "fixture_mass"],
                   config=DiagnoseConfig(draws=150))
    write_json(run_store / "damper1" / "diagnose.json", doc)
    out = tmp_path / "rep"
    assert main(["report", "--runs", str(run_store), "-o", str(out)]) == 0
    page = (out / "index.html").read_text()
    p = _Refs()
    p.feed(page)
    assert "damper1: missing physics (sbcal diagnose)" in p.headings
    assert "Verdict: sensor_delay" in page and "ms delay" in page
    assert "figures/damper1_diagnosis.png" in p.imgs and (out / "figures/damper1_diagnosis.png").is_file()
    (run_store / "damper1" / "diagnose.json").unlink()  # the other report tests see the store as before


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
