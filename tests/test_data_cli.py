"""``sbcal data``: the per-test report and its JSON contract, run in-process."""

import json

import numpy as np
import pandas as pd
import pytest

import sbcal
from sbcal.data import bench, readers
from sbcal.cli import main
from tests.benches import noisy_runs

GRID = sbcal.STANDARD_GRID_HZ


@pytest.fixture
def bench_file(tmp_path, damper1):
    """Two dampers; damperA 1-1 has a planted outlier run (id 4), 2-1 steps 2 -> 1 mm at 10 Hz."""
    rng = np.random.default_rng(31)
    fuu = sbcal.dynamic_stiffness(damper1, GRID, EJ=9.0, beta=0.3)[0]

    def runs(n):
        return noisy_runs(fuu, n, rng, 0.03, 0.02)

    c11 = runs(10)
    c11[3] *= np.exp(0.25)
    amp21 = np.where(GRID <= 10, 2.0, 1.0)
    df = pd.concat([
        bench.curves_to_frame("damperA", "1-1", GRID, 1.0, c11),
        bench.curves_to_frame("damperA", "2-1", GRID, amp21, runs(6), runs=[2, 3, 5, 7, 11, 13]),
        bench.curves_to_frame("damperB", "0.5-0.5", GRID[::2], 0.5, runs(4)[:, ::2]),
    ], ignore_index=True)
    p = tmp_path / "bench.csv"
    bench.write_bench(df, p)
    return p


def test_report_and_json(bench_file, tmp_path, capsys):
    out = tmp_path / "out" / "data.json"
    assert main(["data", "--bench", str(bench_file), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert list(doc) == ["damperA", "damperB"]
    assert list(doc["damperA"]) == ["1-1", "2-1"] and list(doc["damperB"]) == ["0.5-0.5"]
    a11, a21, b = doc["damperA"]["1-1"], doc["damperA"]["2-1"], doc["damperB"]["0.5-0.5"]
    assert (a11["runs"], a11["removed_runs"], a11["amplitude_mm_pp"], a11["n_frequencies"]) == (10, [4], [1.0], 37)
    assert (a21["runs"], a21["removed_runs"], a21["amplitude_mm_pp"], a21["n_frequencies"]) == (6, [], [1.0, 2.0], 37)
    assert (b["runs"], b["removed_runs"], b["amplitude_mm_pp"], b["n_frequencies"]) == (4, [], [0.5], 19)
    assert a21["run_ids"] == [2, 3, 5, 7, 11, 13] and len(a21["run_scores"]) == 6
    cv = a11["cv_median_pct"]
    assert cv["clean"]["magnitude"]["f<=15Hz"] < cv["raw"]["magnitude"]["f<=15Hz"]  # the outlier widened it
    text = capsys.readouterr().out
    assert "damperA" in text and "damperB" in text and "2-1" in text and "wrote" in text
    line11 = next(line for line in text.splitlines() if line.strip().startswith("1-1"))
    assert line11.split()[1:4] == ["10", "4", "37"]            # runs, removed, lines
    line21 = next(line for line in text.splitlines() if line.strip().startswith("2-1"))
    assert "1,2" in line21.split()                            # both amplitudes


def test_z_threshold_option(bench_file, tmp_path):
    out = tmp_path / "d.json"
    assert main(["data", "--bench", str(bench_file), "--json", str(out), "--z-threshold", "100"]) == 0
    assert json.loads(out.read_text())["damperA"]["1-1"]["removed_runs"] == []
    assert json.loads(out.read_text())["damperA"]["1-1"]["z_threshold"] == 100


@pytest.mark.parametrize("argv, match", [
    (["--z-threshold", "0"], "must be a finite number > 0"),
    (["--z-threshold", "nan"], "must be a finite number > 0"),
    (["--z-threshold", "x"], "invalid float value"),
])
def test_bad_threshold(bench_file, tmp_path, capsys, argv, match):
    out = tmp_path / "d.json"
    assert main(["data", "--bench", str(bench_file), "--json", str(out)] + argv) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1 and not out.exists()


def test_bad_file_one_line_exit_2_no_output(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text(",".join(bench.BENCH_COLUMNS) + "\nd,1-1,1,4,1,1000,170\nd,1-1,1,4.5,1,oops,170\n")
    out = tmp_path / "d.json"
    assert main(["data", "--bench", str(bad), "--json", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"sbcal: error: {bad}: line 3: column 'stiffness_n_per_m': expected a number, got 'oops'\n"
    assert captured.out == "" and not out.exists()
    assert main(["data", "--bench", str(tmp_path / "nope.csv")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_default_bench_is_the_bundled_file(bench_file, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(readers, "default_bench_path", lambda: bench_file)
    assert main(["data"]) == 0
    assert str(bench_file) in capsys.readouterr().out
    monkeypatch.setattr(readers, "default_bench_path", lambda: tmp_path / "sbcal" / "data" / "bench.csv")
    assert main(["data"]) == 2
    err = capsys.readouterr().err
    assert "no bundled bench data" in err and "--bench" in err and err.count("\n") == 1
