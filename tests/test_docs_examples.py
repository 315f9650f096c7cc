"""Every example in README.md and docs/*.md works, so that a broken one cannot be published again.

The fenced blocks are read by their info string:

- ``bash``: every ``sbcal`` command goes through the real parser (an option misspelt, renamed or missing
  fails here, as the README's ``bench --raw`` example once did); ``pip install -e`` names extras that
  ``pyproject.toml`` declares; ``python -m pytest`` and ``dask`` are left to their own tools. Any
  other command fails the test: a doc shows only what the test can check. The short workflows are
  also run as written, in page order in one folder (slow), except the few that take minutes
  (:data:`NOT_RUN`: each is run by another test).
- ``python``: the blocks of one page run in order in one namespace (a later block uses an earlier
  one's names), in a folder holding what the page's text says is there (``bench.csv``, ``new.toml``,
  a cable run in ``runs/damper1/cable-dry``). Pages whose examples read a calibration run after one
  is made with ``sbcal sample`` (slow).
- ``toml``: parsed; a block preceded by ``<!-- schema: KIND -->`` is also read by sbcal's own reader
  of that file kind (the contract's schemas), in the same folder.
- untagged or ``text``: output and synopses, not run.

The regex below is the whole extraction (an info string and a closing fence at the start of a line):
a library (Sybil, pytest-codeblocks) would add a dependency for what the sbcal-specific part, the
parser check and the folder each page needs, does not get from it.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import tomllib
from pathlib import Path

import pytest

from sbcal.cli.app import build_parser, main
from sbcal.core.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
_SCHEMA = re.compile(r"<!-- schema: (\w+) -->\s*$")
# pages whose Python reads a calibration made by ``sbcal sample`` (the slow tier makes it) or makes one
NEEDS_SAMPLES = {"api.md", "calibration.md", "compare.md"}
# documented commands parsed but not run (each is run by the test named)
NOT_RUN = {
    "run": "the whole pipeline: 8 min (.ci/run runs it to its clean stage; tests/test_pipeline.py)",
    "cable": "a cable-law posterior: minutes (tests/test_cable_fit.py)",
    "design": "a design search: minutes (tests/test_design.py)",
    "import": "the lab's raw files (tests/test_import.py reads every format)",
}


def blocks(lang: str | None = None) -> list[tuple[str, int, str, str, str | None]]:
    """(page, line, info string, text, schema) of every fenced block, in page order."""
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in _FENCE.finditer(text):
            if lang is None or m.group(1) == lang:
                before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
                schema = s.group(1) if (s := _SCHEMA.search(before)) else None
                out.append((page.name, text[:m.start()].count("\n") + 1, m.group(1), m.group(2), schema))
    return out


def commands(text: str) -> list[list[str]]:
    """A shell block's commands as argument lists: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", text)
    return [shlex.split(line, comments=True) for line in joined.splitlines() if line.split("#", 1)[0].strip()]


def _ids(items):
    return [f"{p}:{n}" for p, n, *_ in items]


SHELL = blocks("bash")
PYTHON = blocks("python")
TOML = blocks("toml")


def test_the_pages_have_examples_and_every_block_says_its_kind():
    every = blocks()
    assert len(SHELL) >= 15 and len(PYTHON) >= 10 and len(TOML) >= 6
    # ``sh``/``console``/``py`` would escape the checks below: one spelling per kind
    assert {info for _, _, info, _, _ in every} <= {"bash", "python", "toml", "json", "text", ""}


@pytest.mark.parametrize("page,line,info,text,schema", SHELL, ids=_ids(SHELL))
def test_every_shell_example_parses(page, line, info, text, schema, capsys):
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    parser = build_parser()
    for argv in commands(text):
        where = f"{page}:{line}: {' '.join(argv)}"
        if argv[0] == "sbcal":
            try:
                parser.parse_args(argv[1:])
            except (SystemExit, InputError) as exc:  # the CLI's parser raises InputError, argparse SystemExit
                pytest.fail(f"{where}: {exc if isinstance(exc, InputError) else capsys.readouterr().err.strip()}")
        elif argv[:3] == ["pip", "install", "-e"]:
            wanted = re.fullmatch(r"\.(?:\[([\w,]+)\])?", argv[3])
            assert wanted, where
            assert set(filter(None, (wanted.group(1) or "").split(","))) <= set(extras), where
        elif argv[:3] == ["python", "-m", "pytest"] or argv[0] == "dask":
            continue
        else:
            pytest.fail(f"{where}: a command the docs test cannot check")


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """An empty working folder (the examples' relative paths land in it)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _readers():
    from sbcal.data.acquisition.channel_map import load_channel_map
    from sbcal.design.acceptance import read_acceptance
    from sbcal.design.conductor import load_conductor
    from sbcal.design.space import load_space
    from sbcal.model.damper import load_damper, resolve_damper

    return {"channel_map": load_channel_map, "acceptance": read_acceptance, "conductor": load_conductor,
            "damper": load_damper, "space": lambda p: load_space(p, resolve_damper("damper1"))}


@pytest.mark.parametrize("page,line,info,text,schema", TOML, ids=_ids(TOML))
def test_every_toml_example_parses_and_passes_its_schema(page, line, info, text, schema, folder):
    tomllib.loads(text)
    if schema:
        path = folder / f"example-{schema}.toml"
        path.write_text(text, encoding="utf-8")
        _readers()[schema](path)


def test_the_file_kinds_with_a_reader_are_checked_by_it():
    """Each input kind the docs show in full goes through its reader at least once."""
    assert {s for *_, s in TOML if s} == set(_readers())


# --- Python ---------------------------------------------------------------------------------------

def _workspace(root: Path) -> None:
    """What the pages' Python examples say is in the folder: the bundled bench file as ``bench.csv``, a
    new damper ``new.toml`` (docs/predict.md's), a cable-law run of damper1 (``runs/damper1/cable-dry``)."""
    from .test_predict import _store

    _store(root)  # writes its own recordings to bench.csv: the bundled file replaces them
    shutil.copy(ROOT / "sbcal" / "data" / "bench.csv", root / "bench.csv")
    (new,) = [t for p, _, _, t, s in TOML if p == "predict.md" and s == "damper"]
    (root / "new.toml").write_text(new, encoding="utf-8")


def _run_page(page: str, root: Path) -> int:
    import matplotlib

    from sbcal.model.laws import LAWS

    matplotlib.use("Agg")
    namespace: dict = {"__name__": f"docs_{page}"}
    n = 0
    laws = dict(LAWS)  # a page may register a law of its own (docs/cable.md): not beyond the page
    try:
        for p, line, _, text, _ in PYTHON:
            if p == page:
                try:
                    exec(compile(text, f"{page}:{line}", "exec", dont_inherit=True), namespace)
                except Exception as exc:  # the page and line of the example that broke
                    raise AssertionError(f"{page}:{line}: {type(exc).__name__}: {exc}") from exc
                n += 1
    finally:
        LAWS.clear()
        LAWS.update(laws)
    return n


_FAST_PAGES = sorted({p for p, *_ in PYTHON} - NEEDS_SAMPLES)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    root = tmp_path_factory.mktemp("docs")
    _workspace(root)
    return root


@pytest.mark.parametrize("page", _FAST_PAGES)
def test_every_python_example_runs(page, workspace, monkeypatch):
    monkeypatch.chdir(workspace)
    assert _run_page(page, workspace) >= 1


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The workspace after the README's first try and the oiled test's calibration (``sbcal sample``)."""
    root = tmp_path_factory.mktemp("docs-calibrated")
    _workspace(root)
    for name, kind in (("my_line.toml", "conductor"), ("space.toml", "space"), ("channels.toml", "channel_map")):
        (text,) = {t for *_, t, s in TOML if s == kind} if kind != "channel_map" else {
            t for p, _, _, t, s in TOML if s == kind and p == "README.md"}
        (root / name).write_text(text, encoding="utf-8")
    cwd = os.getcwd()
    os.chdir(root)
    try:
        assert main(["sample", "--damper", "damper1", "--tests", "0.5-0.5", "1-1", "1-1-oiled",
                     "--seed", "0", "--quiet"]) == 0
    finally:
        os.chdir(cwd)
    return root


@pytest.mark.long
@pytest.mark.parametrize("page", sorted(NEEDS_SAMPLES))
def test_python_examples_on_a_calibration_run(page, calibrated, monkeypatch):
    monkeypatch.chdir(calibrated)
    assert _run_page(page, calibrated) >= 1


def not_run(argv: list[str]) -> str | None:
    """Why a documented command is parsed but not run by :func:`test_shell_examples_run`, or None."""
    if argv[0] != "sbcal":
        return "not sbcal"
    if any("time:1" in a for a in argv):
        return "the time-domain bench: minutes a test (tests/test_virtual_bench_time.py)"
    if "lot-runs" in argv:
        return "a lot's run store, made by sbcal run (tests/test_batch.py)"
    return NOT_RUN.get(argv[1])


@pytest.mark.long
def test_shell_examples_run(calibrated, monkeypatch, capsys):
    """Every documented sbcal command that takes seconds runs as written, in page order, in one folder."""
    monkeypatch.chdir(calibrated)
    ran = 0
    for page, line, _, text, _ in SHELL:
        for argv in commands(text):
            if not_run(argv) is None:
                assert main(argv[1:]) == 0, f"{page}:{line}: {' '.join(argv)}: {capsys.readouterr().err}"
                ran += 1
    assert ran >= 12
