"""Reading bench recordings: one entry point (:func:`load_bench`) and one set of checks for CSV,
Excel and Parquet (``docs/data.md``); every problem is one line naming the file, the line or cell,
and what is wrong.
"""

from __future__ import annotations

import csv
import datetime as _dt
import gzip
import io
import math
import re
import warnings
from collections import defaultdict
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from ..core.errors import InputError
from .bench import BENCH_COLUMNS, MEASURED_COLUMNS, BenchData


__all__ = ["load_bench", "default_bench_path"]

_MAX_RUN_ID = 2.0 ** 53  # run ids must be exact in float64


# --- reading: one entry point, one set of checks -------------------------------------------------

def default_bench_path() -> Path:
    """The bundled bench recordings, ``sbcal/data/bench.csv`` (or ``bench.csv.gz``).

    Returns the ``.csv`` path when neither exists; :func:`load_bench` then reports it missing.
    """
    root = resources.files("sbcal") / "data"
    for name in ("bench.csv", "bench.csv.gz"):
        p = root / name
        if p.is_file():
            return Path(str(p))
    return Path(str(root / "bench.csv"))


_LABELS = ("damper", "test")
_NUMERIC = BENCH_COLUMNS[2:]
_POSITIVE = ("frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m", "amplitude_achieved_mm_pp")
_SE_PAIR = ("stiffness_se_n_per_m", "phase_se_deg")


def _columns(names) -> list[str]:
    """The contract's columns and the optional measured ones among ``names``, in that order."""
    return list(BENCH_COLUMNS) + [c for c in MEASURED_COLUMNS if c in names]


def _measured_rule(col: str) -> str:
    """What a measured column's value must be (blank: not measured)."""
    if col == "se_windows":
        return "an integer >= 2"
    return "> 0" if col in _POSITIVE else ">= 0"

# where(rows) -> one place name per row ("line 5", "sheet 'A', row 5", "row index 4");
# explain(column, row) -> what is wrong with that value. Only called to report an error.
_Where = Callable[[list], list]
_Explain = Callable[[str, int], str]


def _clean_labels(df: pd.DataFrame) -> None:
    """Strip blanks around damper and test labels (in place); few unique labels make it cheap."""
    for col in _LABELS:
        uniq = pd.unique(df[col].dropna())
        if any(isinstance(u, str) and u != u.strip() for u in uniq):
            df[col] = df[col].str.strip()


def _bad_masks(df: pd.DataFrame) -> list:
    """[(column, bad-row mask)] of the failing checks, in column order (vectorised)."""
    checks = []
    for col in _LABELS:
        s = df[col]
        empty = [u for u in pd.unique(s) if not isinstance(u, str) or not u]  # NaN, None or ""
        checks.append((col, s.isin(empty).to_numpy() | s.isna().to_numpy()))
    run = df["run"].to_numpy(dtype=float)
    checks.append(("run", ~np.isfinite(run) | (run != np.round(run)) | (np.abs(run) > _MAX_RUN_ID)))
    for col in _NUMERIC[1:]:
        x = df[col].to_numpy(dtype=float)
        bad = ~np.isfinite(x)
        if col in _POSITIVE:
            bad |= x <= 0  # NaN compares False: already flagged
        checks.append((col, bad))
    for col in MEASURED_COLUMNS:  # blank (NaN) is "not measured"; +inf also marks text that is not a number
        if col not in df:
            continue
        x = df[col].to_numpy(dtype=float)
        with np.errstate(invalid="ignore"):
            bad = np.isinf(x) | (x <= 0 if col in _POSITIVE else x < 0)
            if col == "se_windows":
                bad |= (x != np.round(x)) & ~np.isnan(x) | (x < 2)
        if col in _SE_PAIR and all(c in df for c in _SE_PAIR):
            other = df[_SE_PAIR[1 - _SE_PAIR.index(col)]].to_numpy(dtype=float)
            bad |= np.isnan(x) & ~np.isnan(other)  # one standard error without the other
        checks.append((col, bad))
    return [c for c in checks if c[1].any()]


def _raise_first(source, found: list, where: _Where, explain: _Explain) -> None:
    """InputError for the earliest bad row of ``found`` (ties: column order)."""
    row, k = min((int(np.argmax(mask)), k) for k, (_, mask) in enumerate(found))
    col = found[k][0]
    n_bad = int(np.logical_or.reduce([m for _, m in found]).sum())
    more = f" (first of {n_bad} bad rows)" if n_bad > 1 else ""
    raise InputError(f"{source}: {where([row])[0]}: column '{col}': {explain(col, row)}{more}")


def _finish(source, df: pd.DataFrame, where: _Where) -> pd.DataFrame:
    """The checked rows typed as in :attr:`BenchData.frame`; duplicate keys rejected."""
    df = df[_columns(df.columns)].reset_index(drop=True)
    for col in _LABELS:  # the text dtype pandas gives CSV labels, whatever the format
        df[col] = df[col].astype(str)
    df["run"] = df["run"].to_numpy(dtype=float).astype(np.int64)
    for col in _columns(df.columns)[3:]:
        df[col] = df[col].to_numpy(dtype=float)
    key = ["damper", "test", "run", "frequency_hz"]
    dup = df.duplicated(subset=key, keep="first").to_numpy()
    if dup.any():
        b = int(np.argmax(dup))
        row = df.iloc[b]
        same = np.ones(len(df), bool)
        for c in key:
            same &= (df[c] == row[c]).to_numpy()
        a = int(np.argmax(same))
        at_b, at_a = where([b, a])
        raise InputError(
            f"{source}: {at_b}: columns 'damper','test','run','frequency_hz': duplicate of {at_a} "
            f"({row['damper']} {row['test']} run {row['run']} at {row['frequency_hz']:g} Hz)")
    _check_units(source, df, where)
    return df


# Unit slips the contract's units make visible, per test (docs/data.md): an amplitude in metres reads as a few
# micrometres, a phase in radians never leaves +-2 pi, a stiffness in kN/m or N/mm weighs a few grams.
_LEAST_AMPLITUDE_MM_PP = 0.002  # a shaker test's least, about ten times a laser vibrometer's noise floor
_LARGEST_AMPLITUDE_MM_PP = 200.0
_LEAST_APPARENT_MASS_KG = 0.02  # median |K| / omega^2 over the test's rows: a damper's moving mass is kilograms


def _check_units(source, df: pd.DataFrame, where: _Where) -> None:
    """One line for the first test (file order) whose values say the file's units are not the contract's."""
    omega2 = (2 * np.pi * df["frequency_hz"].to_numpy()) ** 2
    code = df.groupby(["damper", "test"], sort=False).ngroup().to_numpy()
    _, first = np.unique(code, return_index=True)  # each test's first row, in file order
    frame = pd.DataFrame({"amp": df["amplitude_mm_pp"].to_numpy(), "phase": np.abs(df["phase_deg"].to_numpy()),
                          "mass": df["stiffness_n_per_m"].to_numpy() / omega2})
    g = frame.groupby(code, sort=True)
    stats = pd.DataFrame({"first": first, "amp": g["amp"].median().to_numpy(), "phase": g["phase"].max().to_numpy(),
                          "mass": g["mass"].median().to_numpy()})
    bad = ((stats["amp"] < _LEAST_AMPLITUDE_MM_PP) | (stats["amp"] > _LARGEST_AMPLITUDE_MM_PP)
           | ((stats["phase"] > 0.5) & (stats["phase"] < 2 * np.pi + 0.1)) | (stats["mass"] < _LEAST_APPARENT_MASS_KG))
    if not bad.any():
        return
    row = stats[bad].sort_values("first").iloc[0]  # the first bad test in file order
    at = f"{source}: {where([int(row['first'])])[0]}"  # only on error: a CSV's line numbers cost a re-read
    first = df.iloc[int(row["first"])]
    test = f"{first['damper']} {first['test']}"
    if row["amp"] < _LEAST_AMPLITUDE_MM_PP:
        raise InputError(f"{at}: column 'amplitude_mm_pp': {test} is tested at {row['amp']:.3g} mm peak-to-peak, "
                         f"below any shaker test's {_LEAST_AMPLITUDE_MM_PP:g} mm: metres typed as millimetres?")
    if row["amp"] > _LARGEST_AMPLITUDE_MM_PP:
        raise InputError(f"{at}: column 'amplitude_mm_pp': {test} is tested at {row['amp']:.3g} mm peak-to-peak, "
                         f"above {_LARGEST_AMPLITUDE_MM_PP:g} mm: micrometres typed as millimetres?")
    if 0.5 < row["phase"] < 2 * np.pi + 0.1:  # a damper's phase reaches 180 deg below its first resonance
        raise InputError(f"{at}: column 'phase_deg': every phase of {test} lies within +-2 pi (largest "
                         f"{row['phase']:.3g}): radians? sbcal reads degrees")
    if row["mass"] < _LEAST_APPARENT_MASS_KG:
        raise InputError(f"{at}: column 'stiffness_n_per_m': {test}'s stiffness over omega^2 is {1e3 * row['mass']:.3g} g "
                         f"(median over its rows), a damper's moving mass is kilograms: kN/m or N/mm typed as N/m?")


def _validated(source, df: pd.DataFrame, where: _Where, explain: _Explain) -> pd.DataFrame:
    """The checks every format shares: labels, numbers, run ids, duplicates (docs/data.md 1).

    ``df`` holds the seven contract columns: labels as text (NaN or None where missing), the
    rest as numbers (NaN where a cell is not a number); and the measured columns the file has, as numbers (NaN
    where blank, +inf where a cell is not a number).
    """
    _clean_labels(df)
    found = _bad_masks(df)
    if found:
        _raise_first(source, found, where, explain)
    return _finish(source, df, where)


def _check_header(source, names: list, at: str) -> None:
    """Every contract column exactly once among ``names`` (stripped header cells), a measured column at most
    once, and the two standard errors together."""
    for col in BENCH_COLUMNS + MEASURED_COLUMNS:
        count = names.count(col)
        if count == 0 and col in BENCH_COLUMNS:
            raise InputError(f"{source}: {at}: missing column '{col}' (required: {','.join(BENCH_COLUMNS)})")
        if count > 1:
            raise InputError(f"{source}: {at}: column '{col}' appears {count} times")
    have = [c in names for c in _SE_PAIR]
    if any(have) and not all(have):
        missing = _SE_PAIR[have.index(False)]
        raise InputError(f"{source}: {at}: column '{_SE_PAIR[have.index(True)]}' without '{missing}' "
                         "(the two standard errors come together)")


def load_bench(path, sheet: str | None = None) -> BenchData:
    """Read and validate bench recordings (the long-format contract, ``formats.md`` section 2).

    Parameters
    ----------
    path : str or path-like
        The format follows the name's ending: ``.xlsx`` (or ``.xlsm``) an Excel workbook,
        ``.parquet`` (or ``.pq``) a Parquet file, anything else CSV (``.csv``; ``.gz``: gzip).
        CSV: UTF-8 (a byte-order mark is allowed), header required, separated by commas, or by
        semicolons or tabs when the header line says so (then decimal commas are read too).
        Excel: every sheet holds the long layout (header row first), concatenated in workbook
        order. Columns may come in any order; extra columns are ignored. Several dampers and
        tests may share one file; any frequency grid is accepted, runs of one test need not
        share it, and the amplitude may vary with frequency.
    sheet : str, optional
        Read only this sheet of a workbook (an error for other formats).

    Returns
    -------
    BenchData

    Raises
    ------
    InputError
        One line naming the file, the place (CSV: the 1-based file line, header = line 1;
        Excel: the sheet and the row as Excel numbers it; Parquet: the 0-based row index) and
        the column, for the earliest bad row: a missing column; an empty, non-numeric, NaN or
        infinite value (in a workbook also a text cell in a number column); ``frequency_hz``,
        ``amplitude_mm_pp`` or ``stiffness_n_per_m`` <= 0; a ``run`` that is not an integer
        (``3.0`` is read as 3; ``1.5`` is rejected); an empty damper or test label; a CSV row
        with more fields than the header; two rows with the same (damper, test, run,
        frequency_hz) (both named); an empty file, sheet or header without rows; a missing
        sheet; a missing or unreadable file; a test whose values show a unit slip (amplitudes in metres,
        phases in radians, stiffness in kN/m: :func:`_check_units`).

    Notes
    -----
    Every format goes through the same checks on a DataFrame (:func:`_validated`); the readers
    only differ in how they turn cells into values and name a row. A plain CSV's happy path is one
    typed ``pandas.read_csv`` and vectorised checks; only when a check fails is the file re-read
    as text to say exactly what is wrong, and where.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a bench file (.csv, .csv.gz, .xlsx, .parquet)")
    name = p.name.lower()
    if name.endswith((".xlsx", ".xlsm")):
        return BenchData(source=str(p), frame=_load_xlsx(p, sheet))
    if sheet is not None:
        raise InputError(f"{p}: sheet {sheet!r} named, but only .xlsx workbooks have sheets")
    if name.endswith(".xls"):
        raise InputError(f"{p}: old Excel .xls workbooks are not read; save it as .xlsx")
    if name.endswith((".parquet", ".pq")):
        return BenchData(source=str(p), frame=_load_parquet(p))
    return BenchData(source=str(p), frame=_load_csv(p))


# --- CSV ------------------------------------------------------------------------------------------

_DELIMITERS = (",", ";", "\t")
_DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab"}


def _open_text(path: Path):
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="")
    return open(path, encoding="utf-8-sig", newline="")


def _blank(record: list) -> bool:
    # what pandas' skip_blank_lines skips: an empty or all-whitespace line (no delimiter)
    return len(record) == 0 or (len(record) == 1 and not record[0].strip())


def _first_record(path: Path, delimiter: str) -> tuple[int, list[str]] | None:
    """(line number, fields) of the first non-blank record, or None for a file of blank lines."""
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end = 0
        for rec in reader:
            start, end = end + 1, reader.line_num
            if not _blank(rec):
                return start, rec
    return None


def _read_header(path: Path) -> tuple[int, list[str], str]:
    """(line number, field names, delimiter) of the first non-blank line; errors as one line.

    The delimiter is the one of ``, ; tab`` that splits the header into the most contract
    columns (ties: the comma): European spreadsheets write ``;`` with decimal commas.
    """
    best = None
    for d in _DELIMITERS:
        first = _first_record(path, d)
        if first is None:
            raise InputError(f"{path}: empty file, expected the header line {','.join(BENCH_COLUMNS)}")
        n = len(set(BENCH_COLUMNS) & {h.strip() for h in first[1]})
        if best is None or n > best[0]:
            best = (n, first[0], first[1], d)
        if n == len(BENCH_COLUMNS):
            break
    return best[1], best[2], best[3]


def _record_lines(path: Path, rows, delimiter: str = ",") -> dict[int, int]:
    """First physical line (1-based) of data records ``rows`` (0-based, pandas' row order).

    Only called to report an error, so a plain Python pass over the file is fine; it follows
    quoted fields that span lines, which pandas' row index cannot.
    """
    wanted, out = set(int(r) for r in rows), {}
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end, k = 0, -2  # -2: the header is still to come
        for rec in reader:
            start, end = end + 1, reader.line_num
            if _blank(rec):
                continue
            k += 1
            if k in wanted:
                out[k] = start
                if len(out) == len(wanted):
                    break
    return out


def _too_many_fields(path: Path, n_fields: int, delimiter: str) -> InputError | None:
    """The first record with more fields than the header (error path only)."""
    with _open_text(path) as fh:
        reader = csv.reader(fh, delimiter=delimiter)
        end, header = 0, True
        for rec in reader:
            start, end = end + 1, reader.line_num
            if _blank(rec):
                continue
            if header:
                header = False
            elif len(rec) > n_fields:
                return InputError(f"{path}: line {start}: expected {n_fields} fields (as in the header), saw {len(rec)}")
    return None


def _read_frame(path: Path, header: list[str], dtypes: dict, delimiter: str) -> pd.DataFrame:
    """The file's contract columns, renamed to :data:`BENCH_COLUMNS`; other columns read as text.

    ``dtypes`` maps contract names to str or float. A row with more fields than the header is an
    error (pandas would silently shift or drop them); only a trailing empty field on every row
    (a trailing comma) passes, as pandas drops it without loss.
    """
    names = {h: h.strip() for h in header}
    dtype = defaultdict(lambda: str, {h: dtypes[c] for h, c in names.items() if c in dtypes})
    kw = dict(sep=delimiter, index_col=False, dtype=dtype, skip_blank_lines=True, encoding="utf-8-sig",
              compression="gzip" if path.suffix == ".gz" else None)
    if dtypes["run"] is str:
        kw.update(keep_default_na=False)
    try:
        with warnings.catch_warnings():
            # "Length of header or names does not match length of data": fields would be lost
            warnings.simplefilter("error", pd.errors.ParserWarning)
            df = pd.read_csv(path, **kw)
    except (pd.errors.ParserError, pd.errors.ParserWarning) as e:
        raise (_too_many_fields(path, len(header), delimiter) or InputError(
            f"{path}: malformed CSV: {str(e).strip().splitlines()[-1]}")) from None
    except UnicodeDecodeError:
        raise _not_utf8(path) from None
    except (OSError, EOFError) as e:
        raise InputError(f"{path}: cannot read: {e}") from None
    df = df.rename(columns={h: c for h, c in names.items() if c in dtypes})
    return df[_columns(df.columns)]


def _not_utf8(path: Path) -> InputError:
    """Name the line of the first byte that is not UTF-8 (error path only)."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rb") as fh:
        data = fh.read()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        return InputError(f"{path}: line {line}: not UTF-8 text (byte 0x{data[e.start]:02x})")
    return InputError(f"{path}: not UTF-8 text")


# 4.573,2: a dot between groups of three digits before a decimal comma (thousands separator)
_GROUPED = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+,\d*([eE][+-]?\d+)?$")


def _decimal_comma_numbers(s: pd.Series) -> np.ndarray:
    """Text with a decimal comma to float64; NaN where it is not such a number.

    A dot is accepted only as a thousands separator before a decimal comma (``4.573,2``);
    anywhere else it is ambiguous (``1.234``: 1.234 or 1234?) and the value is refused.
    """
    t = s.str.strip()
    grouped = t.str.match(_GROUPED).to_numpy(dtype=bool)
    dotted = t.str.contains(".", regex=False).to_numpy(dtype=bool)
    t = t.where(~grouped, t.str.replace(".", "", regex=False)).str.replace(",", ".", regex=False)
    x = pd.to_numeric(t, errors="coerce").to_numpy(dtype=float)
    return np.where(dotted & ~grouped, np.nan, x)


def _explain_csv(text: pd.DataFrame, df: pd.DataFrame, decimal_comma: bool) -> _Explain:
    def explain(col: str, i: int) -> str:
        s = str(text[col].iloc[i]).strip()
        if col in MEASURED_COLUMNS:
            x = float(df[col].iloc[i])
            return _explain_measured(col, repr(s) if np.isinf(x) else s, x)
        if s == "" or col in _LABELS:
            return "empty value"
        if col == "run":
            return f"expected an integer run id, got {s!r}"
        x = float(df[col].iloc[i])
        if np.isfinite(x):
            return f"must be > 0, got {s}"
        if np.isinf(x) or s.lower().lstrip("+-") == "nan":
            return f"value {s!r} is not finite"
        if decimal_comma and "." in s:
            return f"expected a number with a decimal comma, got {s!r} (a dot is read only between thousands)"
        return f"expected a number, got {s!r}"
    return explain


def _explain_measured(col: str, shown: str, x: float) -> str:
    """Why a measured column's value was refused (``x``: as read; +inf for a cell that is not a number)."""
    if np.isnan(x):
        return f"blank, while '{_SE_PAIR[1 - _SE_PAIR.index(col)]}' is given (the two standard errors come together)"
    if np.isinf(x):
        return f"expected a number or a blank (not measured), got {shown}"
    return f"must be {_measured_rule(col)} or blank (not measured), got {shown}"


def _text_numbers(s: pd.Series, parse) -> np.ndarray:
    """A measured column's text to numbers: blank -> NaN (not measured), text that is no number -> +inf."""
    x = parse(s)
    junk = np.isnan(x) & (s.fillna("").str.strip() != "").to_numpy(dtype=bool) & \
        ~s.fillna("").str.strip().str.lower().isin(["nan", "na", "n/a"]).to_numpy(dtype=bool)
    return np.where(junk, np.inf, x)


def _load_csv(p: Path) -> pd.DataFrame:
    try:
        header_line, header, delim = _read_header(p)
    except UnicodeDecodeError:
        raise _not_utf8(p) from None
    except (OSError, EOFError) as e:
        raise InputError(f"{p}: cannot read: {e}") from None
    except csv.Error as e:
        raise InputError(f"{p}: malformed CSV: {e}") from None
    _check_header(p, [h.strip() for h in header], f"line {header_line}")

    def where(rows):
        lines = _record_lines(p, rows, delim)
        return [f"line {lines.get(r, r + 2)}" for r in rows]

    columns = _columns([h.strip() for h in header])
    if delim == ",":
        fast = {c: (str if c in _LABELS else float) for c in columns}
        try:
            df = _read_frame(p, header, fast, delim)
            _clean_labels(df)
            clean = not _bad_masks(df)
        except InputError:
            raise
        except ValueError:
            clean = False  # a non-numeric value: the text pass says which
        if clean:
            if len(df) == 0:
                raise InputError(f"{p}: line {header_line}: header only, no data rows")
            return _finish(p, df, where)
    # the text pass: labels such as "NA" are text (NaN to the typed reader), and a semicolon or
    # tab file may write decimal commas
    text = _read_frame(p, header, dict.fromkeys(columns, str), delim)
    if len(text) == 0:
        raise InputError(f"{p}: line {header_line}: header only, no data rows")
    decimal_comma = delim != "," and any(text[c].str.contains(",", regex=False).any() for c in columns[2:])
    parse = _decimal_comma_numbers if decimal_comma else (
        lambda s: pd.to_numeric(s, errors="coerce").to_numpy(dtype=float))
    df = pd.DataFrame({c: (text[c] if c in _LABELS else _text_numbers(text[c], parse) if c in MEASURED_COLUMNS
                           else parse(text[c])) for c in columns})
    return _validated(p, df, where, _explain_csv(text, df, decimal_comma))


# --- Excel ----------------------------------------------------------------------------------------

def _is_blank_cell(v) -> bool:
    return v is None or (isinstance(v, str) and not v.strip())


def _cell_label(v):
    """A label cell as text; None for a cell that cannot be a label (empty, date, TRUE/FALSE)."""
    if isinstance(v, str):
        return v  # stripped later, with the other formats' labels
    if type(v) is int:
        return str(v)
    if type(v) is float:
        return str(int(v)) if v.is_integer() else repr(v)
    return None


def _cell_number(v) -> float:
    # only number cells are numbers: a text cell is refused, never parsed (bool is not a number)
    return float(v) if type(v) in (int, float) else np.nan


def _measured_cell(v) -> float:
    """A measured column's cell: blank -> NaN (not measured), a cell that is no number -> +inf (refused)."""
    return np.nan if _is_blank_cell(v) else (float(v) if type(v) in (int, float) else np.inf)


def _describe_cell(v) -> str:
    if isinstance(v, bool):
        return str(v).upper()
    if isinstance(v, (_dt.date, _dt.time, _dt.timedelta)):
        return f"a date/time cell ({v})"
    if isinstance(v, str):
        return f"text {v.strip()!r}"
    return repr(v)


def _explain_cell(raw: dict) -> _Explain:
    def explain(col: str, i: int) -> str:
        v = raw[col][i]
        if col in MEASURED_COLUMNS:
            x = _measured_cell(v)
            return _explain_measured(col, _describe_cell(v) if np.isinf(x) else f"{x:g}", x)
        if _is_blank_cell(v):
            return "empty value"
        if col in _LABELS:
            hint = ("; Excel turns labels such as 2-1 into dates: format the column as Text"
                    if isinstance(v, (_dt.date, _dt.time, _dt.timedelta)) else "")
            return f"expected a text label, got {_describe_cell(v)}{hint}"
        if type(v) not in (int, float):
            return f"expected a number, got {_describe_cell(v)}"
        if col == "run":
            return f"expected an integer run id, got {v!r}"
        if not math.isfinite(v):
            return f"value {v!r} is not finite"
        return f"must be > 0, got {v:g}"
    return explain


def _read_sheet(path: Path, ws, name: str):
    """The contract columns of one sheet: (raw cells per column, Excel row numbers)."""
    if hasattr(ws, "reset_dimensions"):
        ws.reset_dimensions()  # a writer's stale dimension tag must not cut rows off
    rows = ws.iter_rows(values_only=True)
    header_row = header = None
    data, numbers = [], []
    for r, row in enumerate(rows, start=1):
        if all(_is_blank_cell(v) for v in row):
            continue
        if header is None:
            header_row, header = r, row
        else:
            data.append(row)
            numbers.append(r)
    at = f"sheet {name!r}"
    if header is None:
        raise InputError(f"{path}: {at}: empty sheet, expected a header row {','.join(BENCH_COLUMNS)}")
    names = ["" if v is None else str(v).strip() for v in header]
    _check_header(path, names, f"{at}, row {header_row}")
    if not data:
        raise InputError(f"{path}: {at}, row {header_row}: header only, no data rows")
    raw = {}
    for col in _columns(names):
        i = names.index(col)
        raw[col] = [row[i] if i < len(row) else None for row in data]
    return raw, numbers


def _load_xlsx(p: Path, sheet: str | None) -> pd.DataFrame:
    import zipfile

    import openpyxl
    from openpyxl.utils.exceptions import InvalidFileException

    try:
        wb = openpyxl.load_workbook(p, read_only=True, data_only=True)
    except (zipfile.BadZipFile, InvalidFileException, KeyError, OSError, ValueError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"{p}: cannot read as an Excel workbook: {msg}") from None
    try:
        # chart sheets hold no cells: not part of the data
        names = [n for n in wb.sheetnames if hasattr(wb[n], "iter_rows")]
        if sheet is not None:
            if sheet not in names:
                raise InputError(f"{p}: no sheet {sheet!r}; sheets: {', '.join(names) or '(none)'}")
            names = [sheet]
        if not names:
            raise InputError(f"{p}: no worksheet")
        parts = [(n, *_read_sheet(p, wb[n], n)) for n in names]
    finally:
        wb.close()
    columns = _columns(set.intersection(*(set(cols) for _, cols, _ in parts)))
    for name, cols, _ in parts:
        extra = [c for c in cols if c not in columns]
        if extra:  # a measured column on one sheet only would leave the others' rows half described
            raise InputError(f"{p}: sheet {name!r}: column '{extra[0]}' that other sheets lack (give it on every "
                             "sheet, blank where not measured)")
    raw = {c: [v for _, cols, _ in parts for v in cols[c]] for c in columns}
    sheet_of = np.concatenate([np.full(len(rows), k) for k, (_, _, rows) in enumerate(parts)])
    row_of = np.concatenate([rows for _, _, rows in parts])

    def where(rows):
        return [f"sheet {parts[sheet_of[r]][0]!r}, row {row_of[r]}" for r in rows]

    df = pd.DataFrame({c: (pd.Series([_cell_label(v) for v in raw[c]], dtype=object) if c in _LABELS
                           else np.array([_measured_cell(v) for v in raw[c]], dtype=float) if c in MEASURED_COLUMNS
                           else np.array([_cell_number(v) for v in raw[c]], dtype=float))
                       for c in columns})
    return _validated(p, df, where, _explain_cell(raw))


# --- Parquet --------------------------------------------------------------------------------------

def _load_parquet(p: Path) -> pd.DataFrame:
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    try:
        meta = pq.read_metadata(p)
        schema = meta.schema.to_arrow_schema()
    except (pa.ArrowException, OSError) as e:
        raise InputError(f"{p}: cannot read as Parquet: {str(e).strip().splitlines()[0]}") from None
    _check_header(p, [n.strip() for n in schema.names], "schema")
    if meta.num_rows == 0:  # before the types: a writer may type an empty column as null
        raise InputError(f"{p}: no data rows")
    text_types = (pa.types.is_string, pa.types.is_large_string, getattr(pa.types, "is_string_view", lambda t: False))
    columns = _columns(schema.names)
    for col in columns:
        t = schema.field(schema.names.index(col)).type
        base = t.value_type if pa.types.is_dictionary(t) else t
        if col in _LABELS:
            ok = any(is_text(base) for is_text in text_types) or pa.types.is_integer(base)
            want = "text"
        else:
            ok = pa.types.is_integer(base) or pa.types.is_floating(base) or pa.types.is_decimal(base)
            want = "a number (integer or floating point)"
        if not ok:
            raise InputError(f"{p}: column '{col}': Parquet type {t}, expected {want}")
    try:
        table = pq.read_table(p, columns=columns)
    except (pa.ArrowException, OSError) as e:
        raise InputError(f"{p}: cannot read as Parquet: {str(e).strip().splitlines()[0]}") from None
    if table.num_rows == 0:
        raise InputError(f"{p}: no data rows")
    null = {c: table.column(c).is_null().to_numpy(zero_copy_only=False) for c in columns}
    df = pd.DataFrame({c: (pc.cast(table.column(c), pa.string()).to_pandas() if c in _LABELS
                           else pc.cast(table.column(c), pa.float64()).to_numpy(zero_copy_only=False))
                       for c in columns})

    def where(rows):
        return [f"row index {r}" for r in rows]

    def explain(col, i):
        if col in MEASURED_COLUMNS:
            x = float(df[col].iloc[i])
            return _explain_measured(col, f"{x:g}", x)
        if null[col][i] or col in _LABELS:
            return "empty value" + (" (null)" if null[col][i] else "")
        x = float(df[col].iloc[i])
        if col == "run":
            return f"expected an integer run id, got {x:g}"
        if not math.isfinite(x):
            return f"value {x} is not finite"
        return f"must be > 0, got {x:g}"

    return _validated(p, df, where, explain)
