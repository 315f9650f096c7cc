"""sbcal compare: the acceptance file, the change as a posterior, the CLI and its refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.stats import norm

from sbcal.cli.app import main
from sbcal.core.errors import InputError
from sbcal.design.acceptance import Acceptance, read_acceptance
from sbcal.design.characteristic import Characteristic
from sbcal.design.compare import compare_characteristics, lab_gap
from sbcal.design.resonance import resonance_draws

SPEC = """
[excitation]
amplitude_mm_pp = 1.0
frequency_hz = [5.0, 30.0]
[tolerance]
resonance_frequency_pct = 5.0
resonance_power_pct = 20.0
impedance_pct = 20.0
"""


# --- the acceptance file -----------------------------------------------------------------------------

def test_acceptance_reads_a_good_file(tmp_path):
    p = tmp_path / "a.toml"
    p.write_text("same_design = true\n" + SPEC)
    a = read_acceptance(p)
    assert (a.mode, a.level, a.freq_range_hz, a.same_design) == ("amplitude", 1.0, (5.0, 30.0), True)
    assert a.tolerances == {"resonance_frequency_pct": 5.0, "resonance_power_pct": 20.0, "impedance_pct": 20.0}


@pytest.mark.parametrize("edit, key", [
    (lambda s: s.replace("impedance_pct = 20.0", "impedance_pct = 0"), "tolerance.impedance_pct"),
    (lambda s: s.replace("impedance_pct = 20.0", "impedance_pct = -3"), "tolerance.impedance_pct"),
    (lambda s: s.replace("impedance_pct", "impedence_pct"), "tolerance.impedence_pct"),
    (lambda s: s.replace("[5.0, 30.0]", "[30.0, 5.0]"), "excitation.frequency_hz"),
    (lambda s: s.replace("[5.0, 30.0]", "[5.0]"), "excitation.frequency_hz"),
    (lambda s: s.replace("amplitude_mm_pp = 1.0", "amplitude_mm_pp = 1.0\nvelocity_m_s = 0.1"), "[excitation]"),
    (lambda s: s.replace("amplitude_mm_pp = 1.0", "amplitude_mm_pp = 'one'"), "excitation.amplitude_mm_pp"),
    (lambda s: s + "\ncolour = 'red'\n", "colour"),
    (lambda s: s.split("[tolerance]")[0], "[tolerance]"),
])
def test_acceptance_refuses_bad_files_naming_the_key(tmp_path, edit, key):
    p = tmp_path / "bad.toml"
    p.write_text(edit(SPEC))
    with pytest.raises(InputError) as e:
        read_acceptance(p)
    msg = str(e.value)
    assert str(p) in msg and key in msg and "\n" not in msg


# --- the change as a posterior, on characteristics whose answer is known --------------------------------

def _base_excited(freq_hz, f0, zeta=0.08, m=1.0):
    """Force on the base of a mass on a spring and dashpot per unit base motion: one resonance at ~f0."""
    w = 2 * np.pi * np.asarray(freq_hz)
    w0 = 2 * np.pi * np.asarray(f0)[..., None]
    k, c = m * w0 ** 2, 2 * zeta * m * w0
    return -(w ** 2) * m * (k + 1j * c * w) / (k + 1j * c * w - m * w ** 2)


def _char(f, fuu, label):
    x0 = np.full(f.shape, 0.5e-3)
    return Characteristic(damper="unit", state="dry", source=label, run=label, mode="amplitude", level=1.0,
                          freq_hz=f, x0=x0, fuu=fuu, resonances=tuple(resonance_draws(f, fuu, x0)),
                          extrapolated=np.zeros(f.size, bool), discrepancy="none", n_runs=24, damper_values={})


def test_impedance_change_probability_matches_the_lognormal_it_was_drawn_from():
    # after = before * g per draw, ln g ~ N(ln 0.9, 0.06^2): P(|g - 1| <= 15 %) is known in closed form
    rng = np.random.default_rng(1)
    f = np.geomspace(5, 30, 60)
    n = 4000
    before = _base_excited(f, np.full(n, 12.0))
    g = np.exp(np.log(0.9) + 0.06 * rng.standard_normal(n))
    acc = Acceptance(mode="amplitude", level=1.0, freq_range_hz=(5, 30), tolerances={"impedance_pct": 15.0})
    out = compare_characteristics(_char(f, before, "b"), _char(f, before * g[:, None], "a"), acc,
                                  rng=np.random.default_rng(2))
    exact = norm.cdf((np.log(1.15) - np.log(0.9)) / 0.06) - norm.cdf((np.log(0.85) - np.log(0.9)) / 0.06)
    (imp,) = [c for c in out.criteria if c.key == "impedance_pct"]
    # the before draws are all equal, so the pairing does not matter: binomial error sd <= 0.008 at n = 4000
    assert imp.p_within == pytest.approx(exact, abs=0.03)
    assert imp.change[1] == pytest.approx(-10.0, abs=0.6)  # the median of g - 1, in %
    assert out.verdict == ("pass" if exact >= 0.95 else "fail" if exact <= 0.05 else "inconclusive")


def test_resonance_shift_is_recovered_and_judged():
    # the resonance moves by -8 % +- 1 % (sd) against +-5 %: fail, and the change's median within a grid step
    rng = np.random.default_rng(3)
    f = np.geomspace(5, 30, 400)  # 0.45 % steps
    n = 1000
    fb = 12.0 * np.exp(0.003 * rng.standard_normal(n))
    fa = 12.0 * 0.92 * np.exp(0.01 * rng.standard_normal(n))
    acc = Acceptance(mode="amplitude", level=1.0, freq_range_hz=(5, 30), tolerances={"resonance_frequency_pct": 5.0})
    out = compare_characteristics(_char(f, _base_excited(f, fb), "b"), _char(f, _base_excited(f, fa), "a"), acc,
                                  rng=np.random.default_rng(4))
    (c,) = [c for c in out.criteria if c.key == "resonance_frequency_pct"]
    assert c.change[1] == pytest.approx(-8.0, abs=0.5)
    assert c.verdict == "fail" and out.verdict == "fail"
    assert c.p_within < 0.05


def test_inconclusive_says_how_many_runs_would_decide():
    # the change sits 1 sd inside the tolerance: inconclusive; the runs that put it 1.645 sd away
    rng = np.random.default_rng(5)
    f = np.geomspace(5, 30, 60)
    n = 4000
    before = _base_excited(f, np.full(n, 12.0))
    g = np.exp(-0.15 + 0.05 * rng.standard_normal(n))  # |Z| down ~14 % +- 4.3 %, tolerance 20 %
    acc = Acceptance(mode="amplitude", level=1.0, freq_range_hz=(5, 30), tolerances={"impedance_pct": 17.0})
    out = compare_characteristics(_char(f, before, "b"), _char(f, before * g[:, None], "a"), acc,
                                  rng=np.random.default_rng(6))
    (c,) = out.criteria[-1:]
    assert c.verdict == "inconclusive" and out.verdict == "inconclusive"
    sd, gap = np.std(100 * (g - 1)), 17.0 - abs(np.median(100 * (g - 1)))
    assert c.runs_needed == pytest.approx(24 * (1.6449 * sd / gap) ** 2, rel=0.1)


def test_lab_gap_reads_the_largest_point_gap():
    f = np.geomspace(5, 30, 40)
    b = _base_excited(f, 12.0)[0]
    a = b * np.where(f > 20, 1.25, 1.0)  # +25 % above 20 Hz only
    acc = Acceptance(mode="amplitude", level=1.0, freq_range_hz=(5, 30), tolerances={"impedance_pct": 20.0})
    out = lab_gap(b, a, f, np.full(f.size, 5e-4), acc)
    assert out["gaps"]["impedance_pct"] == pytest.approx(25.0, rel=1e-9)
    assert out["verdict"] == "fail"


# --- the command, on the virtual bench --------------------------------------------------------------

@pytest.fixture(scope="module")
def benches(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare")
    for name, ej, seed in (("before", "11.3", 1), ("after", "7.9", 2)):  # a 30 % stiffness loss
        assert main(["bench", "--damper", "damper1", "--set", f"EJ={ej}", "--tests", "1-1", "--runs-per-test", "12",
                     "--seed", str(seed), "-o", str(d / f"{name}.csv")]) == 0
    (d / "spec.toml").write_text(SPEC)
    return d


def test_compare_bench_files_fails_a_stiffness_loss_and_writes_every_file(benches, capsys):
    d = benches
    out = d / "out"
    assert main(["compare", "--before", str(d / "before.csv"), "--after", str(d / "after.csv"), "--spec",
                 str(d / "spec.toml"), "--runs", str(d / "runs"), "-o", str(out), "--seed", "3", "--quiet"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert ": fail — " in first and "P(beyond)" in first
    doc = json.loads((out / "summary.json").read_text())
    assert doc["verdict"] == "fail" and doc["seed"] == 3 and "numpy" in doc["versions"]
    (c,) = doc["comparisons"]
    freq = [k for k in c["criteria"] if k["key"] == "resonance_frequency_pct" and k["change"][1] is not None]
    # EJ down 30 % in the linear model the bench ran: every mode moves by sqrt(0.7) - 1 = -16.3 %
    assert len(freq) >= 3
    assert all(k["change"][1] == pytest.approx(-16.3, abs=1.0) for k in freq)
    for name in ("criteria.csv", "curves.csv", "compare.png"):
        assert (out / name).stat().st_size > 0
    # the bench files were calibrated into their own stores, and a second run reuses them (same numbers)
    assert len(list((d / "runs" / "compare" / "calibrations").iterdir())) == 2
    out2 = d / "out2"
    assert main(["compare", "--before", str(d / "before.csv"), "--after", str(d / "after.csv"), "--spec",
                 str(d / "spec.toml"), "--runs", str(d / "runs"), "-o", str(out2), "--seed", "3", "--quiet"]) == 0
    assert json.loads((out2 / "summary.json").read_text())["comparisons"] == doc["comparisons"]



def _calibrations(d):
    """The stores the test above calibrated the bench files into (none when it did not run: the tests below skip)."""
    where = d / "runs" / "compare" / "calibrations"
    return sorted(where.iterdir()) if where.is_dir() else []

def test_compare_a_run_with_itself_passes_and_without_spec_decides_nothing(benches, capsys):
    d = benches
    stores = _calibrations(d)
    if not stores:
        pytest.skip("needs the calibrations of the test above")
    run = str(next(s for s in stores if s.name.startswith("before")) / "damper1")
    assert main(["compare", "--before", run, "--after", run, "--spec", str(d / "spec.toml"), "-o",
                 str(d / "self"), "--quiet"]) == 0
    assert json.loads((d / "self" / "summary.json").read_text())["verdict"] == "pass"
    assert main(["compare", "--before", run, "--after", run, "-o", str(d / "nospec"), "--quiet"]) == 0
    doc = json.loads((d / "nospec" / "summary.json").read_text())
    assert doc["verdict"] == "no spec" and all(k["p_within"] is None for k in doc["comparisons"][0]["criteria"])
    assert "no acceptance file: no decision" in capsys.readouterr().out


@pytest.mark.parametrize("case", ["missing", "range", "velocity", "tolerance", "same_design"])
def test_compare_refuses_bad_input_in_one_line(benches, tmp_path, capsys, case):
    d = benches
    stores = _calibrations(d)
    if not stores:
        pytest.skip("needs the calibrations of the test above")
    run = str(stores[0] / "damper1")
    spec = tmp_path / "s.toml"
    text = SPEC
    before, after = run, run
    if case == "missing":
        after = str(tmp_path / "nowhere" / "damper1")
    elif case == "range":
        text = SPEC.replace("[5.0, 30.0]", "[50.0, 80.0]")
    elif case == "velocity":
        text = SPEC.replace("amplitude_mm_pp = 1.0", "velocity_m_s = 0.1")
    elif case == "tolerance":
        text = SPEC.replace("impedance_pct = 20.0", "impedance_pct = 0.0")
    elif case == "same_design":
        text = "same_design = true\n" + SPEC
        other = tmp_path / "other"
        import shutil

        shutil.copytree(stores[0], other)
        s = other / "damper1" / "1-1" / "theta1" / "summary.json"
        doc = json.loads(s.read_text())
        doc["config"]["damper_values"]["L1"] *= 1.1
        s.write_text(json.dumps(doc))
        after = str(other / "damper1")
    spec.write_text(text)
    out = tmp_path / "out"
    assert main(["compare", "--before", before, "--after", after, "--spec", str(spec), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sbcal: error:") and "\n" not in err
    assert not out.exists()
    want = {"missing": "no such run", "range": "line(s)", "velocity": "no cable-law fit",
            "tolerance": "tolerance.impedance_pct", "same_design": "L1"}[case]
    assert want in err


def test_pairing_is_reproducible_and_draws_are_independent():
    f = np.geomspace(5, 30, 30)
    rng = np.random.default_rng(7)
    b = _base_excited(f, 12 * np.exp(0.02 * rng.standard_normal(500)))
    a = _base_excited(f, 12 * np.exp(0.02 * rng.standard_normal(500)))
    acc = Acceptance(mode="amplitude", level=1.0, freq_range_hz=(5, 30), tolerances={"resonance_frequency_pct": 3.0})
    one = compare_characteristics(_char(f, b, "b"), _char(f, a, "a"), acc, rng=np.random.default_rng(8))
    two = compare_characteristics(_char(f, b, "b"), _char(f, a, "a"), acc, rng=np.random.default_rng(8))
    assert one.criteria == two.criteria
    # independent 2 % sds: the change's sd is about 2 sqrt(2) = 2.8 % (grid steps of 6 % blur it a little)
    (c,) = [c for c in one.criteria if c.key == "resonance_frequency_pct"]
    assert (c.change[2] - c.change[0]) / (2 * 1.645) == pytest.approx(2.83, rel=0.35)
    assert math.isfinite(c.p_within)


def test_default_output_is_in_the_run_store_and_the_report_shows_it(benches, tmp_path):
    from sbcal.report.compare import compare_section

    d = benches
    stores = _calibrations(d)
    if not stores:
        pytest.skip("needs the calibrations of the test above")
    runs = tmp_path / "runs"
    before = str(next(s for s in stores if s.name.startswith("before")) / "damper1")
    after = str(next(s for s in stores if s.name.startswith("after")) / "damper1")
    assert main(["compare", "--before", before, "--after", after, "--spec", "example", "--runs", str(runs),
                 "--quiet"]) == 0
    (entry,) = compare_section(runs, tmp_path)
    assert entry["name"] == "damper1-vs-damper1" and entry["verdict"] == "fail"
    assert (tmp_path / entry["figure"]).is_file()
    assert entry["acceptance"]["source"] == "example" and entry["acceptance"]["same_design"] is True
