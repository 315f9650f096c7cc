"""The one-way pipeline: stored stages reused only while everything they were made from holds,
the same numbers on a Dask cluster, and docs without dead links."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ as F, dynamic_stiffness
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.readers import load_bench
from sbcal.cli import main
from sbcal.model.damper import resolve_damper
from sbcal.diagnosis.diagnose import DiagnoseConfig
from sbcal.pipeline import Settings, run
from sbcal.inference.sampler import SamplerConfig
from tests.benches import noisy_runs

ROOT = Path(__file__).resolve().parents[1]
FAST = SamplerConfig(nwalkers=16, max_draws=150, de_population=30, de_generations=60)
FAST_DIAG = DiagnoseConfig(draws=150)


@pytest.fixture(scope="module")
def bench_path(tmp_path_factory):
    """damper1 at three amplitudes from the model (EJ falling with amplitude: a well-posed map; each
    test follows its own constant-EJ model, so the diagnosis finds no misfit and stays quick)."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(5)
    frames = []
    for amp, ej in ((0.2, 20.0), (0.5, 12.0), (1.0, 9.0)):
        fuu = dynamic_stiffness(d, F, EJ=ej, beta=0.3)
        noisy = noisy_runs(fuu, 6, rng)
        frames.append(curves_to_frame("damper1", f"{amp:g}-{amp:g}", F, amp, noisy))
    path = tmp_path_factory.mktemp("pipe") / "bench.csv"
    write_bench(pd.concat(frames), path)
    return path


def _run(bench_path, store, settings):
    lines = []
    run(load_bench(bench_path), [resolve_damper("damper1")], store=store, report_dir=store.parent / "report",
        settings=settings, progress=False, say=lines.append)
    return lines


@pytest.mark.slow
def test_changed_prior_file_redoes_what_it_feeds_and_an_unchanged_one_reuses_all(bench_path, tmp_path):
    store = tmp_path / "runs"
    settings = Settings(seed=2, sampler=FAST, diagnose=FAST_DIAG, workers=2)
    first = _run(bench_path, store, settings)
    assert sum("redone (not stored yet)" in line for line in first) == 1 + 3 + 1 + 1  # clean, 3 tests, diagnose, map
    again = _run(bench_path, store, settings)
    assert all(": reused" in line or line.startswith("report:") for line in again), again
    before = json.loads((store / "damper1" / "0.5-0.5" / "theta1" / "summary.json").read_text())

    # the same boxes in another prior file: a changed file, so what it feeds is redone, and says why
    prior = tmp_path / "prior.toml"
    prior.write_text((ROOT / "sbcal" / "priors" / "default.toml").read_text().replace("upper = 2.5", "upper = 2.4"))
    changed = _run(bench_path, store, Settings(seed=2, sampler=FAST, diagnose=FAST_DIAG, workers=2, priors=str(prior)))
    text = "\n".join(changed)
    assert "clean: reused" in text
    for t in ("0.2-0.2", "0.5-0.5", "1-1"):
        assert f"sample {t}: redone (prior file changed)" in text
    assert "diagnose: redone (prior file changed)" in text
    assert "map: redone (per-test posteriors changed)" in text
    after = json.loads((store / "damper1" / "0.5-0.5" / "theta1" / "summary.json").read_text())
    assert after["inputs"]["priors"] != before["inputs"]["priors"]
    assert after["config"]["prior"]["parameters"]["beta"]["upper"] == 2.4

    # a changed seed redoes the posteriors; the cleaning does not depend on it
    seed = "\n".join(_run(bench_path, store, Settings(seed=3, sampler=FAST, diagnose=FAST_DIAG, workers=2,
                                                      priors=str(prior))))
    assert "clean: reused" in seed and "sample 1-1: redone (seed changed)" in seed


def test_run_cli_bad_prior_file_is_one_line(bench_path, tmp_path, capsys):
    rc = main(["run", "--bench", str(bench_path), "--priors", str(tmp_path / "missing.toml"), "--runs",
               str(tmp_path / "r"), "-o", str(tmp_path / "rep"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "missing.toml: no such file" in err and "\n" not in err
    assert not (tmp_path / "r").exists()


def test_run_until_a_stage_stores_it_and_stops(bench_path, tmp_path, capsys):
    """'sbcal run --until clean' (scripts/fresh-check's cut of the main job): the stage stored, nothing after."""
    store, report = tmp_path / "r", tmp_path / "rep"
    rc = main(["run", "--bench", str(bench_path), "--runs", str(store), "-o", str(report), "--until", "clean", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "damper1: clean: redone" in out and "stopped after clean" in out
    assert sorted(p.name for p in (store / "damper1").iterdir()) == ["data.json"] and not report.exists()
    rc = main(["run", "--bench", str(bench_path), "--runs", str(store), "--until", "sample-all", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--until" in err and "\n" not in err


@pytest.mark.slow
def test_dask_cluster_gives_the_same_draws(bench_path, tmp_path):
    """'sample --all --scheduler ADDRESS' on a local Dask cluster stores the very draws of a local run."""
    distributed = pytest.importorskip("distributed")
    import xarray as xr

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        common = ["sample", "--all", "--damper", "damper1", "--bench", str(bench_path), "--seed", "7", "--quiet"]
        assert main(common + ["--runs", str(tmp_path / "cluster"), "--scheduler", cluster.scheduler_address]) == 0
    assert main(common + ["--runs", str(tmp_path / "local"), "--workers", "1"]) == 0
    for t in ("0.2-0.2", "0.5-0.5", "1-1"):
        a, b = (xr.open_dataset(tmp_path / w / "damper1" / t / "theta1" / "posterior.nc", group="posterior")
                for w in ("cluster", "local"))
        for name in a.data_vars:
            np.testing.assert_array_equal(a[name].values, b[name].values)


def test_scheduler_that_does_not_answer_is_one_line(bench_path, tmp_path, capsys):
    pytest.importorskip("distributed")
    rc = main(["sample", "--tests", "0.5-0.5", "--bench", str(bench_path), "--runs", str(tmp_path),
               "--scheduler", "tcp://127.0.0.1:9", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--scheduler tcp://127.0.0.1:9" in err and "\n" not in err


def test_no_dead_relative_links_in_readme_and_docs():
    files = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
    dead = []
    for f in files:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", f.read_text()):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            if not (f.parent / target).exists():
                dead.append(f"{f.relative_to(ROOT)} -> {target}")
        for target in re.findall(r"`(docs/[\w./-]+\.md)`", f.read_text()):  # docs named in backticks
            if not (ROOT / target).exists():
                dead.append(f"{f.relative_to(ROOT)} -> {target}")
    assert not dead, dead
