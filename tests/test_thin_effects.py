"""A thin effect under heavy noise (docs/diagnose.md, "Verdict"): the misfit an extension must remove is
measured where the misfit is. A 100 g fixture mass on noisy runs fails the global check and leaves no band
but isolated off lines of noise-like size; the mass must be judged by the misfit it removes over all lines,
not in those lines alone. The same bench without the mass stays ``none``."""

from __future__ import annotations

import numpy as np
import pytest

from sbcal.data.bench import write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.diagnosis.diagnose import DiagnoseConfig, _explained, _misfit, diagnose
from sbcal.inference.checks import Check
from sbcal.model.damper import resolve_damper
from sbcal.simulate.virtual_bench import BenchConfig, record

N_FREQ, THR = 37, 4.5  # lines per test and quantity; the per-line alarm's |z|


def _check(z, dof_taken=0):
    """A model's check as :func:`sbcal.diagnosis.diagnose._check_model` returns it, with z as its own
    normal scores (the t of infinite dof) and the per-line alarm at THR."""
    u = np.concatenate([a.ravel() for a in z])
    dof = u.size - dof_taken
    chi2 = float(np.sum(u ** 2))
    from scipy import stats

    glob = {"chi2": chi2, "dof": dof, "p_value": float(stats.chi2.sf(chi2, dof)), "excess": chi2 - dof}
    thr = [np.full(a.shape, THR) for a in z]
    c = Check(z=z, thresholds=thr, coverage_90=0.9, global_=glob, scores=z)
    return z, thr, 0.9, np.zeros(1), glob, c


def _band(test, q, lines):
    return {"test": test, "quantity": ("magnitude", "phase")[q], "lines": list(lines)}


def test_lone_lines_count_beyond_chance_and_the_global_excess_where_it_is():
    """The issue's shape: a thin misfit on every line (|z| 1.5: the global check fails, no line is off)
    and three isolated lines at |z| 5 that the extension leaves. Squared z in those lines alone, the
    extension removes nothing; where the misfit is, it removes the thin part, and the lone lines count only
    by how far they pass the alarm (5^2 - 4.5^2 each)."""
    tests = ["a", "b"]
    rng = np.random.default_rng(0)
    signs = [np.where(rng.random((2, N_FREQ)) < 0.5, -1.0, 1.0) for _ in tests]
    thin = [1.5 * s for s in signs]
    fixed = [0.8 * s for s in signs]  # the extension's residuals: below chance (it took a parameter)
    lone = [("a", 1, 30), ("b", 0, 3), ("b", 1, 20)]
    for z in (thin, fixed):
        for t, q, i in lone:
            z[tests.index(t)][q, i] = 5.0
    bands = [_band(t, q, [i]) for t, q, i in lone]
    ref, new = _check(thin), _check(fixed, dof_taken=2)
    assert ref[4]["p_value"] < 0.01 and new[4]["p_value"] > 0.01
    lone_excess = 3 * (5.0 ** 2 - THR ** 2)
    n_out = 4 * N_FREQ - 3
    assert _misfit(bands, tests, new, global_part=True) == pytest.approx(lone_excess)
    assert _misfit(bands, tests, ref, global_part=True) == pytest.approx(lone_excess + 1.5 ** 2 * n_out - n_out)
    share = _explained(bands, tests, ref_check=ref, new_check=new, global_alpha=0.01)
    assert share == pytest.approx(1 - lone_excess / (lone_excess + 1.25 * n_out)) and share > 0.9
    # a global check that passes does not count: then only the lone lines' excess is the misfit
    assert _misfit(bands, tests, ref, global_part=False) == pytest.approx(lone_excess)
    assert _explained(bands, tests, ref_check=ref, new_check=new, global_alpha=1e-300) == 0.0
    # without bands the measure is the global excess over chance, as before
    assert _misfit([], tests, ref, global_part=True) == pytest.approx(ref[4]["excess"])


def test_a_band_of_lines_counts_its_squared_z_over_chance():
    """A band of several lines is structure: its squared z less 1 a line (not the alarm's square), floored
    at 0 per band, so that a model cannot earn in one band by fitting another's lines below chance."""
    tests = ["a"]
    z = [np.zeros((2, N_FREQ))]
    z[0][0, 10:13] = [6.0, 3.0, 7.0]  # off, on (a gap of one line), off: one band of three lines
    band = [_band("a", 0, range(10, 13))]
    assert _misfit(band, tests, _check(z), global_part=False) == pytest.approx(36 + 9 + 49 - 3)
    z[0][0, 10:13] = 0.1
    assert _misfit(band, tests, _check(z), global_part=False) == 0.0


def _bench(tmp_path, mass_kg, seed):
    """Damper1 at 0.2 and 2 mm, 6 runs a test, the bench's measurement noise tripled."""
    d = resolve_damper("damper1")
    cfg = BenchConfig(effects={"fixture_mass": mass_kg} if mass_kg else {}, runs=6, logmag_noise=(0.09, 0.024),
                      phase_noise_deg=(4.5, 1.2))
    path = tmp_path / f"thin_{mass_kg}_{seed}.csv"
    write_bench(record(d, cfg, ["0.2-0.2", "2-2"], rng=np.random.default_rng(seed)), path)
    return d, clean_bench(load_bench(path))


# seed 9114 of the sweep 9100-9119 (docs/diagnose.md, "Verdict"): thin mass 19 of 20 right (16 before the
# measure changed), clean 19 of 20 none (the 20th has an off line no extension removes: unexplained)
@pytest.mark.parametrize("seed", [9114])
def test_a_thin_fixture_mass_under_heavy_noise_is_named_and_its_absence_is_none(tmp_path, seed):
    d, data = _bench(tmp_path, 0.1, seed)
    r = diagnose(d, data, seed=seed, progress=False, effects=["fixture_mass", "sensor_delay"],
                 config=DiagnoseConfig(draws=150))
    # the misfit is thin: the global check fails, the only off lines are isolated ones of noise-like size
    assert r["global"]["p_value"] < 1e-6
    assert r["bands"] and all(b["f_lo"] == b["f_hi"] and b["max_abs_z"] < 6 for b in r["bands"])
    best = r["ranking"][0]
    assert r["verdict"] == "fixture_mass", r["ranking"]
    assert best["effect"] == "fixture_mass" and best["delta_elpd"] > 4 * best["se"] and best["explained"] >= 0.8
    # measured in those lines alone the mass would remove less than the rule's 80 % (the failure)
    res = r["residuals"]
    off = [(b["test"], ("magnitude", "phase").index(b["quantity"]), res[b["test"]]["freq_hz"].index(b["f_lo"]))
           for b in r["bands"]]
    before = sum(res[t]["z_before"][q][i] ** 2 for t, q, i in off)
    after = sum(res[t]["z_after"][q][i] ** 2 for t, q, i in off)
    assert 1 - after / before < 0.8
    v = r["parameters"]["values"]["fixture_mass_kg"]
    assert v["q05"] < 0.1 < v["q95"] or abs(v["median"] - 0.1) < 0.02
    # the same bench (the same noise) without the mass: nothing to find
    d, data = _bench(tmp_path, 0.0, seed)
    r = diagnose(d, data, seed=seed, progress=False, effects=["fixture_mass", "sensor_delay"],
                 config=DiagnoseConfig(draws=150))
    assert r["verdict"] == "none" and r["bands"] == [] and r["global"]["p_value"] >= 0.01, r["ranking"]
