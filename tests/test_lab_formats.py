"""Lab file formats (Excel workbooks, Parquet, European CSV) and run-to-run frequency jitter."""

import datetime
import json
import re

import numpy as np
import openpyxl
import pandas as pd
import pytest

import sbcal
from sbcal import InputError
from sbcal.data import bench, readers
from sbcal.data.bench import BENCH_COLUMNS
from sbcal.data.readers import load_bench
from sbcal.data.summary import bench_summary
from sbcal.cli import main

GRID = sbcal.STANDARD_GRID_HZ


@pytest.fixture(scope="module")
def bundled() -> pd.DataFrame:
    return load_bench(readers.default_bench_path()).frame


def small(bundled):
    """Three bundled tests (2664 rows): one with planted outlier runs, one that steps its
    amplitude. The workbook test uses this subset: writing all 15 984 rows with openpyxl takes ~2 s."""
    keep = (bundled.test == "0.1-0.1") | ((bundled.damper == "damper1") & (bundled.test == "2-1"))
    return bundled[keep].reset_index(drop=True)


def write_xlsx(frame, path, by="damper"):
    with pd.ExcelWriter(path, engine="openpyxl") as w:
        for name, part in frame.groupby(by, sort=True):
            part.to_excel(w, sheet_name=name, index=False)


def data_json(tmp_path, bench_path, *extra):
    out = tmp_path / f"{bench_path.name}.json"
    assert main(["data", "--bench", str(bench_path), "--json", str(out), *extra]) == 0
    return json.loads(out.read_text())


# --- the same content in every format gives the same answer ---------------------------------------

def test_xlsx_and_parquet_give_the_csv_answer(tmp_path, bundled, capsys):
    sub = small(bundled)
    csv_path, xlsx, pq = tmp_path / "b.csv", tmp_path / "b.xlsx", tmp_path / "b.parquet"
    bench.write_bench(sub, csv_path)
    write_xlsx(sub, xlsx)                      # one sheet per damper: concatenated on reading
    sub.to_parquet(pq)
    ref = data_json(tmp_path, csv_path)
    assert data_json(tmp_path, xlsx) == ref
    assert data_json(tmp_path, pq) == ref
    # the subset exercises the cleaning keys: planted outlier runs removed, the branch check run
    assert ref["damper1"]["0.1-0.1"]["removed_runs"] and "split" in ref["damper1"]["0.1-0.1"]["branches"]
    pd.testing.assert_frame_equal(load_bench(xlsx).frame, load_bench(csv_path).frame)
    pd.testing.assert_frame_equal(load_bench(pq).frame, load_bench(csv_path).frame)
    capsys.readouterr()


def test_parquet_of_all_bundled_data(tmp_path, bundled):
    pq = tmp_path / "all.parquet"
    bundled.to_parquet(pq)
    assert bench_summary(load_bench(pq)) == bench_summary(load_bench(readers.default_bench_path()))


def test_sheet_option_reads_one_sheet(tmp_path, bundled, capsys):
    sub = small(bundled)
    xlsx = tmp_path / "b.xlsx"
    write_xlsx(sub, xlsx)
    doc = data_json(tmp_path, xlsx, "--sheet", "damper2")
    assert list(doc) == ["damper2"] and list(doc["damper2"]) == ["0.1-0.1"]
    assert main(["data", "--bench", str(xlsx), "--sheet", "damper3"]) == 2
    err = capsys.readouterr().err
    assert err == f"sbcal: error: {xlsx}: no sheet 'damper3'; sheets: damper1, damper2\n"
    csv_path = tmp_path / "b.csv"
    bench.write_bench(sub, csv_path)
    assert main(["data", "--bench", str(csv_path), "--sheet", "damper1"]) == 2
    assert "only .xlsx workbooks have sheets" in capsys.readouterr().err


def test_workbook_layout_freedoms(tmp_path):
    """Header below blank rows, columns in any order, extra and unnamed columns, blank rows,
    numbers in a label column, integral float run ids."""
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = "run log"
    ws.append([])
    ws.append(["note", "phase_deg", "run", "test", "damper", "stiffness_n_per_m", "amplitude_mm_pp",
               "frequency_hz", None, "temp_c"])
    ws.append(["a", 170.5, 1, "1-1", "d1", 1000, 1, 4, "x", 21.5])
    ws.append([])
    ws.append(["b", -0.5, 2.0, "1-1", " d1 ", 1100, 1, 4, None, "hot"])
    ws.append([None, 180.4, 2, "1-1", 7, 1200.5, 1, 4.5])
    p = tmp_path / "lab.xlsx"
    wb.save(p)
    b = load_bench(p)
    assert b.dampers() == ["7", "d1"]
    t = b.test("d1", "1-1")
    np.testing.assert_array_equal(t.runs, [1, 2])
    np.testing.assert_allclose(t.phase_deg, [[170.5], [-0.5]])
    assert b.frame["run"].dtype == np.int64


def workbook(tmp_path, rows, name="bad.xlsx", extra_sheets=()):
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = "tests"
    for r in rows:
        ws.append(r)
    for s in extra_sheets:
        wb.create_sheet(s)
    p = tmp_path / name
    wb.save(p)
    return p


GOOD = [["d1", "1-1", 1, 4.0, 1.0, 1000.0, 170.0], ["d1", "1-1", 1, 4.5, 1.0, 1100.0, 169.0]]


def with_cell(row, col, value):
    rows = [list(r) for r in GOOD]
    rows[row][BENCH_COLUMNS.index(col)] = value
    return [list(BENCH_COLUMNS)] + rows


@pytest.mark.parametrize("rows, extra, sheet, message", [
    (with_cell(1, "frequency_hz", "4.5"), (), None,
     "sheet 'tests', row 3: column 'frequency_hz': expected a number, got text '4.5'"),
    (with_cell(0, "stiffness_n_per_m", "abc"), (), None,
     "sheet 'tests', row 2: column 'stiffness_n_per_m': expected a number, got text 'abc'"),
    (with_cell(1, "phase_deg", None), (), None, "sheet 'tests', row 3: column 'phase_deg': empty value"),
    (with_cell(1, "amplitude_mm_pp", True), (), None,
     "sheet 'tests', row 3: column 'amplitude_mm_pp': expected a number, got TRUE"),
    (with_cell(0, "amplitude_mm_pp", 0), (), None,
     "sheet 'tests', row 2: column 'amplitude_mm_pp': must be > 0, got 0"),
    (with_cell(0, "run", 1.5), (), None, "sheet 'tests', row 2: column 'run': expected an integer run id, got 1.5"),
    (with_cell(0, "test", datetime.datetime(2024, 2, 1)), (), None,
     "sheet 'tests', row 2: column 'test': expected a text label, got a date/time cell (2024-02-01 00:00:00); "
     "Excel turns labels such as 2-1 into dates: format the column as Text"),
    ([list(BENCH_COLUMNS)] + GOOD, ("notes",), None,
     "sheet 'notes': empty sheet, expected a header row " + ",".join(BENCH_COLUMNS)),
    ([list(BENCH_COLUMNS)], (), None, "sheet 'tests', row 1: header only, no data rows"),
    ([list(BENCH_COLUMNS[:-1])] + GOOD, (), None,
     "sheet 'tests', row 1: missing column 'phase_deg' (required: " + ",".join(BENCH_COLUMNS) + ")"),
    ([list(BENCH_COLUMNS)] + GOOD + [GOOD[1]], (), None,
     "sheet 'tests', row 4: columns 'damper','test','run','frequency_hz': duplicate of sheet 'tests', row 3 "
     "(d1 1-1 run 1 at 4.5 Hz)"),
    ([list(BENCH_COLUMNS)] + GOOD, (), "Sheet9", "no sheet 'Sheet9'; sheets: tests"),
])
def test_bad_workbooks_one_line_naming_sheet_row_and_column(tmp_path, capsys, rows, extra, sheet, message):
    p = workbook(tmp_path, rows, extra_sheets=extra)
    with pytest.raises(InputError) as e:
        load_bench(p, sheet=sheet)
    assert str(e.value) == f"{p}: {message}"
    out = tmp_path / "d.json"
    argv = ["data", "--bench", str(p), "--json", str(out)] + (["--sheet", sheet] if sheet else [])
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.err == f"sbcal: error: {p}: {message}\n" and captured.out == "" and not out.exists()


def test_first_bad_cell_across_sheets_and_counts(tmp_path):
    wb = openpyxl.Workbook()
    a = wb.active
    a.title = "A"
    for r in [list(BENCH_COLUMNS)] + GOOD:
        a.append(r)
    b = wb.create_sheet("B")
    b.append(list(BENCH_COLUMNS))
    b.append(["d1", "2-2", 1, 4.0, 2.0, "n/a", 170.0])
    b.append(["d1", "2-2", 1, 5.0, 2.0, -3.0, 170.0])
    p = tmp_path / "two.xlsx"
    wb.save(p)
    with pytest.raises(InputError, match=r"^.*two\.xlsx: sheet 'B', row 2: column 'stiffness_n_per_m': "
                                         r"expected a number, got text 'n/a' \(first of 2 bad rows\)$"):
        load_bench(p)


def test_not_a_workbook(tmp_path):
    p = tmp_path / "fake.xlsx"
    p.write_text("damper,test\n")
    with pytest.raises(InputError, match=r"fake\.xlsx: cannot read as an Excel workbook"):
        load_bench(p)
    old = tmp_path / "old.xls"
    old.write_bytes(b"\xd0\xcf\x11\xe0")
    with pytest.raises(InputError, match=r"old\.xls: old Excel \.xls workbooks are not read; save it as \.xlsx"):
        load_bench(old)


def parquet(tmp_path, frame, name="bad.parquet"):
    p = tmp_path / name
    frame.to_parquet(p)
    return p


def good_frame():
    return pd.DataFrame([r for r in GOOD], columns=list(BENCH_COLUMNS))


@pytest.mark.parametrize("change, message", [
    (lambda f: f.assign(stiffness_n_per_m=[1000.0, None]),
     "row index 1: column 'stiffness_n_per_m': empty value (null)"),
    (lambda f: f.assign(frequency_hz=["4", "4.5"]),
     # pandas 3 writes text as large_string, pandas 2 as string
     re.compile(r"column 'frequency_hz': Parquet type (large_)?string, expected a number \(integer or floating point\)")),
    (lambda f: f.drop(columns="damper"), "schema: missing column 'damper'"),
    (lambda f: f.assign(run=[1.0, 2.5]), "row index 1: column 'run': expected an integer run id, got 2.5"),
    (lambda f: f.assign(phase_deg=[np.inf, 1.0]), "row index 0: column 'phase_deg': value inf is not finite"),
    (lambda f: f.assign(amplitude_mm_pp=[1.0, -2.0]), "row index 1: column 'amplitude_mm_pp': must be > 0, got -2"),
    (lambda f: f.assign(test=["1-1", None]), "row index 1: column 'test': empty value (null)"),
    (lambda f: f.iloc[:0], "no data rows"),
])
def test_bad_parquet_names_file_column_and_row_index(tmp_path, change, message):
    p = parquet(tmp_path, change(good_frame()))
    with pytest.raises(InputError) as e:
        load_bench(p)
    pattern = message.pattern if isinstance(message, re.Pattern) else re.escape(message)
    assert re.match(re.escape(f"{p}: ") + pattern, str(e.value)) and "\n" not in str(e.value), str(e.value)


def test_parquet_types_readers_meet(tmp_path):
    """Categorical labels (dictionary-encoded), integer numbers and a nullable integer run read."""
    f = good_frame().assign(damper=lambda d: d.damper.astype("category"), stiffness_n_per_m=[1000, 1100],
                            run=pd.array([1, 1], dtype="Int64"))
    b = load_bench(parquet(tmp_path, f, "ok.parquet"))
    assert b.dampers() == ["d1"] and b.frame["stiffness_n_per_m"].dtype == np.float64
    with pytest.raises(InputError, match=r"junk\.parquet: cannot read as Parquet"):
        load_bench(write_text(tmp_path / "junk.parquet", "not parquet"))


def write_text(path, text, encoding="utf-8"):
    path.write_text(text, encoding=encoding)
    return path


# --- European CSV -----------------------------------------------------------------------------------

def test_semicolon_decimal_comma_with_bom_reads_like_the_plain_csv(tmp_path, bundled):
    sub = small(bundled)
    plain = tmp_path / "plain.csv"
    bench.write_bench(sub, plain)
    eu = tmp_path / "eu.csv"
    eu.write_text(sub.to_csv(sep=";", decimal=",", index=False, float_format="%.10g"), encoding="utf-8-sig")
    assert eu.read_bytes().startswith(b"\xef\xbb\xbf") and b";0,1;" in eu.read_bytes()
    pd.testing.assert_frame_equal(load_bench(eu).frame, load_bench(plain).frame)
    assert data_json(tmp_path, eu) == data_json(tmp_path, plain)


HEADER_EU = ";".join(BENCH_COLUMNS)


@pytest.mark.parametrize("rows, expected", [
    (["d;1-1;1;4;1;4.573,25;170,5"], [4573.25]),                 # thousands dot before a decimal comma
    (["d;1-1;1;4,5;0,1;1,5E+03;-0,5"], [1500.0]),                # scientific notation
    (["d;1-1;1;4.5;1;4573.5;170.5"], [4573.5]),                  # semicolons, decimal points: also fine
])
def test_semicolon_numbers(tmp_path, rows, expected):
    b = load_bench(write_text(tmp_path / "eu.csv", HEADER_EU + "\n" + "\n".join(rows) + "\n"))
    np.testing.assert_allclose(b.frame["stiffness_n_per_m"], expected)


def test_tab_separated_with_decimal_commas(tmp_path):
    text = "\t".join(BENCH_COLUMNS) + "\nd\t1-1\t3\t4,5\t1\t4573,2\t170\n"
    b = load_bench(write_text(tmp_path / "t.csv", text))
    assert b.frame.loc[0, "frequency_hz"] == 4.5 and b.frame.loc[0, "run"] == 3


@pytest.mark.parametrize("text, message", [
    (HEADER_EU + "\nd;1-1;1;4;1;4573,2;170\nd;1-1;1;4.5;1;4573,2;170\n",
     "line 3: column 'frequency_hz': expected a number with a decimal comma, got '4.5'"),
    (HEADER_EU + "\nd;1-1;1;4;1;1.234;170,5\n",             # 1.234 or 1234? refused, never guessed
     "line 2: column 'stiffness_n_per_m': expected a number with a decimal comma, got '1.234'"),
    (HEADER_EU.replace(";phase_deg", "") + "\nd;1-1;1;4;1;4573\n", "line 1: missing column 'phase_deg'"),
    (HEADER_EU + "\nd;1-1;1;4;1;-4,5;170\n", "line 2: column 'stiffness_n_per_m': must be > 0, got -4,5"),
    (HEADER_EU + '\n"a;b";1-1;1;4;1;4573,2;170\n\nd;1-1;2;4;1;0;170\n',
     "line 4: column 'stiffness_n_per_m': must be > 0, got 0"),
])
def test_semicolon_rejections_name_the_line(tmp_path, text, message):
    p = write_text(tmp_path / "eu.csv", text)
    with pytest.raises(InputError) as e:
        load_bench(p)
    assert str(e.value).startswith(f"{p}: {message}"), str(e.value)


# --- frequency jitter ------------------------------------------------------------------------------

def jitter_bench(freqs_per_run, seed=0) -> bench.BenchData:
    from sbcal.model.damper import resolve_damper

    rng = np.random.default_rng(seed)
    d = resolve_damper("damper1")
    parts = []
    for r, f in freqs_per_run.items():
        f = np.asarray(f, float)
        c = sbcal.dynamic_stiffness(d, f, EJ=9.0, beta=0.3)[0] * np.exp(0.02 * rng.standard_normal(f.size))
        parts.append(bench.curves_to_frame("d", "t", f, 1.0, c[None], runs=[r]))
    return bench.BenchData("mem", pd.concat(parts, ignore_index=True))


def test_jittered_runs_stay_on_the_grid():
    """Today's failure: one run 0.01 Hz off doubled the lines and left none with repeats."""
    rng = np.random.default_rng(4)
    runs = {1: GRID, 2: GRID + 0.01, 3: GRID - 0.01, 4: GRID * (1 + 0.004 * rng.uniform(-1, 1, GRID.size))}
    t = jitter_bench(runs).test("d", "t")
    assert t.freq_hz.size == GRID.size and t.present.all() and t.unmatched == ()
    # the line is the median of its runs' values: 0.01 either side of the grid cancels
    np.testing.assert_allclose(t.freq_hz, np.median(np.stack(list(runs.values())), axis=0))


def test_a_missed_line_is_reported_not_made_a_line(tmp_path):
    f3 = GRID.copy()
    f3[GRID == 10] = 10.07                         # 0.7 %: beyond the 0.5 % tolerance, within 2 %
    b = jitter_bench({1: GRID, 2: GRID, 3: f3, 4: GRID})
    t = b.test("d", "t")
    assert t.freq_hz.size == GRID.size and t.unmatched == ((3, 10.07, 10.0),)
    assert t.present.sum(axis=0)[GRID == 10] == 3 and t.present[2].sum() == GRID.size - 1
    assert t.select_runs([3, 4]).unmatched == ((3, 10.07, 10.0),) and t.select_runs([1]).unmatched == ()
    entry = bench_summary(b)["d"]["t"]
    assert entry["n_frequencies"] == GRID.size
    assert entry["unmatched"] == [{"run": 3, "frequency_hz": 10.07, "nearest_line_hz": 10.0}]
    p = tmp_path / "j.csv"
    bench.write_bench(b.frame, p)
    assert main(["data", "--bench", str(p)]) == 0


def test_cli_prints_unmatched(tmp_path, capsys):
    f3 = GRID.copy()
    f3[GRID == 10] = 10.07
    p = tmp_path / "j.csv"
    bench.write_bench(jitter_bench({1: GRID, 2: GRID, 3: f3, 4: GRID}).frame, p)
    assert main(["data", "--bench", str(p)]) == 0
    assert "^ unmatched frequencies, left out: run 3 at 10.07 Hz (line 10)" in capsys.readouterr().out


def test_runs_on_different_grids_keep_their_lines():
    """The contract: runs need not share a grid. Lines 2-6 % away from the others' are lines."""
    other = np.array([4.25, 6.0, 10.0, 12.0, 41.0])
    t = jitter_bench({1: GRID, 2: GRID, 7: other}).test("d", "t")
    np.testing.assert_array_equal(t.freq_hz, np.union1d(GRID, other))
    assert t.unmatched == ()
    t = jitter_bench({1: GRID, 2: GRID, 3: GRID + 0.25, 4: GRID + 0.25}).test("d", "t")
    assert t.freq_hz.size == 2 * GRID.size and t.unmatched == ()


def test_a_runs_fine_steps_are_never_merged():
    """A run stepping 0.02 Hz (0.2 %) near 10 Hz: its own step caps the tolerance at 0.005 Hz."""
    fine = np.sort(np.r_[GRID, 10.02, 10.04])
    t = jitter_bench({1: GRID, 2: GRID, 3: fine}).test("d", "t")
    np.testing.assert_array_equal(t.freq_hz, fine)
    assert t.unmatched == ()


def test_a_chain_of_values_never_holds_one_run_twice():
    """10.00 ... 10.05 in 0.01 steps from five runs; run 1 has both ends: they stay two lines."""
    runs = {1: [10.0, 10.05, 12.0], 2: [10.01, 12.0], 3: [10.02, 12.0], 4: [10.03, 12.0], 5: [10.04, 12.0]}
    t = jitter_bench(runs).test("d", "t")
    assert t.freq_hz.size == 3 and t.present.sum() == 11 and t.unmatched == ()
    assert (t.present.sum(axis=1) == [3, 2, 2, 2, 2]).all()
