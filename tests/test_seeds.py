"""Every job's stream is keyed by what the job is: a test's draws do not depend on which other tests run,
two tests' streams differ, and ``sbcal cable`` / ``sbcal diagnose`` make the same cable fit."""

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ, dynamic_stiffness
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.model.cable import CableModel
from sbcal.inference.cable_fit import cable_seed, read_cable
from sbcal.cli import main
from sbcal.model.damper import resolve_damper
from sbcal.diagnosis.diagnose import DiagnoseConfig
from sbcal.diagnosis.fits import _fit, fit_jobs
from sbcal.model.laws import law_for
from sbcal.pipeline import Settings, sample_tests
from sbcal.inference.sampler import SamplerConfig
from sbcal.core.seeds import job_seed, seed_key
from sbcal.inference.stats import read_netcdf
from tests.benches import noisy_runs

FAST = SamplerConfig(nwalkers=16, max_draws=150, de_population=30, de_generations=60, workers=1)


def test_a_job_seed_is_its_name_under_the_seed():
    a = job_seed(0, "sample", "damper1", "0.5-0.5")
    assert a.generate_state(4).tolist() == job_seed(0, "sample", "damper1", "0.5-0.5").generate_state(4).tolist()
    # keys compose: a stream keyed further is the stream of the longer key
    assert (job_seed(job_seed(0, "sample", "damper1"), "0.5-0.5").generate_state(4).tolist()
            == a.generate_state(4).tolist())
    others = [job_seed(1, "sample", "damper1", "0.5-0.5"), job_seed(0, "sample", "damper1", "1-1"),
              job_seed(0, "sample", "damper2", "0.5-0.5"), job_seed(0, "diagnose", "damper1", "0.5-0.5"),
              job_seed(0, "sample", "damper1")]
    states = {tuple(s.generate_state(4).tolist()) for s in others + [a]}
    assert len(states) == len(others) + 1
    # and a child of numpy's own spawn is another stream again (the key is a name, not a place)
    assert a.spawn(1)[0].generate_state(4).tolist() != a.generate_state(4).tolist()
    assert seed_key("cable", "damper1", "dry", "iwan5") == "cable/damper1/dry/iwan5"


@pytest.fixture(scope="module")
def twin_bench(tmp_path_factory):
    """Two tests of damper1 with the very same recordings under two labels."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(321)
    fuu = dynamic_stiffness(d, STANDARD_GRID_HZ, EJ=12.0, beta=0.3)
    noisy = noisy_runs(fuu, 4, rng)
    frames = [curves_to_frame("damper1", t, STANDARD_GRID_HZ, 0.5, noisy) for t in ("0.5-0.5", "0.5-0.5-again")]
    path = tmp_path_factory.mktemp("twin") / "bench.csv"
    write_bench(pd.concat(frames, ignore_index=True), path)
    return clean_bench(load_bench(path))


def _draws(store, test):
    post = read_netcdf(store / "damper1" / test / "theta1" / "posterior.nc").posterior
    return np.asarray(post["EJ"])


@pytest.mark.slow
def test_a_tests_draws_do_not_depend_on_the_other_tests(twin_bench, tmp_path):
    d = resolve_damper("damper1")
    settings = Settings(seed=4, sampler=FAST, workers=1)
    both = sample_tests(twin_bench, [(d, "0.5-0.5-again"), (d, "0.5-0.5")], store=tmp_path / "both", settings=settings,
                        progress=False)
    alone = sample_tests(twin_bench, [(d, "0.5-0.5")], store=tmp_path / "alone", settings=settings, progress=False)
    np.testing.assert_array_equal(_draws(tmp_path / "both", "0.5-0.5"), _draws(tmp_path / "alone", "0.5-0.5"))
    assert both["damper1", "0.5-0.5"][0]["parameters"] == alone["damper1", "0.5-0.5"][0]["parameters"]
    s = json.loads((tmp_path / "alone" / "damper1" / "0.5-0.5" / "theta1" / "summary.json").read_text())
    assert s["seed"] == 4 and s["seed_key"] == "sample/damper1/0.5-0.5"
    # the same recordings under another label are another job: another stream, other draws (one seed
    # for every job, as before this change, gave both tests the very same draws)
    a, b = _draws(tmp_path / "both", "0.5-0.5"), _draws(tmp_path / "both", "0.5-0.5-again")
    assert a.shape == b.shape and not np.array_equal(a, b)
    # ... which agree as posteriors of the same data do: within Monte Carlo error of the median
    ma, mb = np.median(a), np.median(b)
    se = 1.2533 * np.std(a) / np.sqrt(min(both["damper1", t][0]["ess_bulk_min"] for t in ("0.5-0.5", "0.5-0.5-again")))
    assert abs(ma - mb) < 6 * np.sqrt(2) * se


# --- one cable-law fit: sbcal cable and sbcal diagnose ------------------------------------------

LAW = "bouc_wen"
TRUTH = dict(EJ_min=5.0, beta_material=0.1, delta_EJ=35.0, chi_slip=0.01, sharpness=1.0)
LINES = STANDARD_GRID_HZ[::3]


@pytest.fixture(scope="module")
def cable_bench(tmp_path_factory):
    """Damper1 with a Bouc-Wen cable at two amplitudes, a third of the lines, 5 runs: a quick cable fit."""
    d = resolve_damper("damper1")
    rng = np.random.default_rng(11)
    model = CableModel(law_for(LAW))
    frames = []
    for t, a in (("0.2-0.2", 0.2), ("1-1", 1.0)):
        fuu = model.dynamic_stiffness(d, LINES, a, **TRUTH)[0]
        noise = 0.01 * (rng.standard_normal((5, fuu.size)) + 1j * rng.standard_normal((5, fuu.size)))
        frames.append(curves_to_frame(d.name, t, LINES, a, fuu[None] * np.exp(noise)))
    path = tmp_path_factory.mktemp("cable") / "bench.csv"
    write_bench(pd.concat(frames, ignore_index=True), path)
    return path


@pytest.mark.slow
def test_sbcal_cable_end_to_end_and_diagnose_makes_the_same_fit(cable_bench, tmp_path, capsys):
    runs = tmp_path / "runs"
    argv = ["cable", "--damper", "damper1", "--bench", str(cable_bench), "--law", LAW, "--seed", "3",
            "--runs", str(runs), "--workers", "1", "--quiet"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "damper1 cable dry (bouc_wen, 2 tests)" in out and f"stored in {runs / 'damper1' / 'cable-dry'}/" in out
    summary, draws = read_cable(runs / "damper1" / "cable-dry")
    on_disk = json.loads((runs / "damper1" / "cable-dry" / "summary.json").read_text())
    assert on_disk == summary
    assert summary["law"] == LAW and summary["tests"] == ["0.2-0.2", "1-1"] and summary["state"] == "dry"
    assert summary["seed"] == 3 and summary["seed_key"] == "cable/damper1/dry/bouc_wen"
    assert set(summary["parameters"]) == {"a1", "a2", *TRUTH}
    assert {"converged", "r_hat_max", "ess_bulk_min", "elpd_loo", "tests_reached", "versions"} <= set(summary)
    # the coordinates the chains ran in are stored with them (delta_EJ sheared by the share the bench sees)
    (moved,) = summary["sampled_as"]  # Bouc-Wen has no seen ratio: delta_EJ alone
    assert moved["parameter"] == "delta_EJ" and moved["kind"] == "log" and "SeenShare(law='bouc_wen'" in moved["offset"]
    # the truth is found: the stuck and slipped rigidities within 10 % (noise 1 %, 10 lines x 2 tests)
    for n in ("EJ_min", "delta_EJ"):
        assert summary["parameters"][n]["median"] == pytest.approx(TRUTH[n], rel=0.1)
    # diagnose's strand-slip job for the same state and law: the same stream, start and engine settings,
    # so the very same draws as sbcal cable's stored ones
    d = resolve_damper("damper1")
    data = clean_bench(load_bench(cable_bench))
    jobs = fit_jobs("strand_slip", (), damper=d, data=data, tests=["0.2-0.2", "1-1"], seed=3,
                    config=replace(DiagnoseConfig(), laws=(LAW,)), prior_path=None)
    assert len(jobs) == 1 and jobs[0].key == ("strand_slip", "dry", LAW)
    assert jobs[0].stream.generate_state(4).tolist() == cable_seed(3, "damper1", "dry", LAW).generate_state(4).tolist()
    res = _fit(jobs[0])
    for n, v in res.draws.items():
        np.testing.assert_array_equal(np.asarray(v).ravel(), draws[n])


@pytest.mark.parametrize("argv, match", [
    (["--law", "tail"], "invalid choice: 'tail'"),
    (["--workers", "0"], "--workers 0: must be >= 1"),
    (["--damper", "damper9"], "damper9"),
    (["--bench", "missing.csv"], "missing.csv"),
])
def test_sbcal_cable_bad_input_is_one_line(cable_bench, tmp_path, capsys, argv, match):
    options = {"--damper": "damper1", "--bench": str(cable_bench), "--runs": str(tmp_path / "runs")}
    options.update(zip(argv[::2], argv[1::2]))
    rc = main(["cable", "--quiet"] + [x for kv in options.items() for x in kv])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "runs").exists()  # nothing written
