"""The clean stage decides the outlier runs once; every later stage fits the stored decision."""

import json

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ as F, InputError, dynamic_stiffness
from sbcal.cli import main
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import CleanBench, clean_bench
from sbcal.data.cleaning import remove_outlier_runs
from sbcal.data.readers import load_bench
from sbcal.inference.calibrate import test_likelihood as likelihood_of
from sbcal.model.damper import resolve_damper
from sbcal.pipeline import Settings, clean


@pytest.fixture(scope="module")
def bench_path(tmp_path_factory):
    """damper1, two tests of 6 runs; run 3 of 0.5-0.5 is 60 % off (an outlier at the default threshold)."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(5)
    fuu = dynamic_stiffness(d, F, EJ=12.0, beta=0.3)
    frames = []
    for t, a in (("0.5-0.5", 0.5), ("1-1", 1.0)):
        runs = fuu * np.exp(0.02 * rng.standard_normal((6, F.size)) + 0.01j * rng.standard_normal((6, F.size)))
        if t == "0.5-0.5":
            runs[2] *= 1.6
        frames.append(curves_to_frame("damper1", t, F, a, runs))
    path = tmp_path_factory.mktemp("clean") / "b.csv"
    write_bench(pd.concat(frames, ignore_index=True), path)
    return path


def test_clean_bench_keeps_what_remove_outlier_runs_keeps(bench_path):
    bench = load_bench(bench_path)
    data = clean_bench(bench)
    for t in ("0.5-0.5", "1-1"):
        own = remove_outlier_runs(bench.test("damper1", t))
        assert data.removed_runs("damper1", t) == own.removed_runs
        np.testing.assert_array_equal(data.kept("damper1", t).runs, own.data.runs)
        np.testing.assert_array_equal(data.kept("damper1", t).magnitude, own.data.magnitude)
    assert data.removed_runs("damper1", "0.5-0.5") == (3,)
    with pytest.raises(TypeError):
        clean_bench(data)


def test_later_stages_fit_the_stored_decision_not_a_new_cleaning(bench_path, tmp_path):
    """The decision in data.json is what a likelihood is made of: edited by hand (its inputs unchanged,
    so the stage is reused), the next stage fits the edited runs. A stage that cleaned again would not."""
    d, bench, settings = resolve_damper("damper1"), load_bench(bench_path), Settings()
    data = clean(bench, [d], store=tmp_path, settings=settings)
    assert likelihood_of(d, data, "0.5-0.5").y.shape[1] == 5
    path = tmp_path / "damper1" / "data.json"
    doc = json.loads(path.read_text())
    doc["tests"]["0.5-0.5"]["removed_runs"] = [1, 3]
    path.write_text(json.dumps(doc))
    lines = []
    again = clean(bench, [d], store=tmp_path, settings=settings, say=lines.append)
    assert lines == ["damper1: clean: reused"]
    assert again.kept("damper1", "0.5-0.5").runs.tolist() == [2, 4, 5, 6]
    assert likelihood_of(d, again, "0.5-0.5").y.shape[1] == 4
    # another threshold is another input: the stage is redone and the decision made afresh
    lines = []
    redone = clean(bench, [d], store=tmp_path, settings=Settings(z_threshold=1e9), say=lines.append)
    assert lines == ["damper1: clean: redone (settings changed)"]
    assert redone.removed_runs("damper1", "0.5-0.5") == ()


@pytest.mark.parametrize("value, match", [
    ("3", "key 'tests.0.5-0.5.removed_runs': expected a list of run ids"),
    ([99], "key 'tests.0.5-0.5.removed_runs': run 99 is not a run of damper1 0.5-0.5"),
])
def test_a_bad_stored_decision_is_one_clear_line(bench_path, tmp_path, capsys, value, match):
    d, bench = resolve_damper("damper1"), load_bench(bench_path)
    clean(bench, [d], store=tmp_path, settings=Settings())
    path = tmp_path / "damper1" / "data.json"
    doc = json.loads(path.read_text())
    doc["tests"]["0.5-0.5"]["removed_runs"] = value
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=match.replace(".", r"\.")):
        CleanBench.from_stored(bench, {"damper1": doc["tests"]}, z_threshold=3.0, source=str(path))
    # through the command line: exit 2, one line naming the file and the key, nothing sampled
    rc = main(["sample", "--tests", "1-1", "--bench", str(bench_path), "--runs", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and str(path) in err and "removed_runs" in err and err.count("\n") == 1
    assert not (tmp_path / "damper1" / "1-1").exists()
