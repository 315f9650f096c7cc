"""The fit check the report prints beside each posterior (sbcal/inference/fitcheck.py) and the point fit's
bound flag: both statements keep their stated size where the model is right and find a smooth misfit,
and the report warns where a fit fails either."""

import html

import numpy as np
import pytest
from scipy.stats import binom

from sbcal import STANDARD_GRID_HZ as F, dynamic_stiffness, resolve_damper
from sbcal.cli.app import main
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.inference.calibrate import test_likelihood as likelihood_of
from sbcal.inference.fitcheck import check_curve
from sbcal.inference.point_fit import fit_thesis_cost
from tests.benches import noisy_runs

ALPHA = 0.01
REPS = 400
# a failure count that a true rate of ALPHA exceeds with probability < 1e-4 over REPS replicates
MOST = int(binom.isf(1e-4, REPS, ALPHA))


def _runs(rng, misfit, *, n_runs=10, noise=0.02, model_error=0.0):
    """Runs of one quantity about a flat curve (0): a line discrepancy drawn once, noise per run."""
    delta = misfit + model_error * rng.standard_normal(F.size)
    return delta + noise * rng.standard_normal((n_runs, F.size))


@pytest.mark.parametrize("model_error", [0.0, 0.05])
def test_where_the_model_is_right_each_statement_keeps_its_size(model_error):
    """Size: an independent discrepancy (the model's own) and runs of 10: at most ALPHA false alarms for
    the smoothness check, and for the missed lines when the curve is exact (no discrepancy)."""
    rng = np.random.default_rng(5)
    smooth = missed = 0
    for _ in range(REPS):
        c = check_curve("magnitude", F, _runs(rng, 0.0, model_error=model_error), np.zeros(F.size), model_error,
                        alpha=ALPHA)
        smooth += c.fails
        missed += bool(c.missed.any())
    assert smooth <= MOST, smooth
    if model_error == 0.0:
        assert missed <= MOST, missed


def test_a_smooth_misfit_is_found_where_it_is():
    """Power: a resonance-like bump of 10 % at 12-16 Hz under 2 % noise, with a learned model error as
    large as the misfit's spread: the smoothness check fails in >= 95 % of draws and the missed lines are
    the bump's."""
    rng = np.random.default_rng(6)
    bump = 0.10 * np.exp(-0.5 * ((F - 14.0) / 1.5) ** 2)
    fails, inside = 0, []
    for _ in range(100):
        c = check_curve("magnitude", F, _runs(rng, bump), np.zeros(F.size), float(np.std(bump)), alpha=ALPHA)
        fails += c.fails
        inside.append(np.all((F[c.missed] > 10.0) & (F[c.missed] < 18.0)) and c.missed.any())
    assert fails >= 95, fails
    assert np.mean(inside) >= 0.95
    assert "12" in c.bands() and c.words().startswith("magnitude: the median curve misses")


def test_phase_misfit_is_wrapped():
    """A run mean of 179 deg against a curve at -179 deg is 2 deg off, not 358."""
    rng = np.random.default_rng(7)
    runs = np.radians(179.0) + 0.002 * rng.standard_normal((8, F.size))
    c = check_curve("phase", F, runs, np.full(F.size, np.radians(-179.0)), 0.0)
    assert np.allclose(c.misfit, -2.0, atol=0.2)  # the mean of 8 runs of 0.11 deg noise: 5 sd


def _bench(tmp_path, a1_factor, seed=1):
    d = resolve_damper("damper1")
    rng = np.random.default_rng(seed)
    fuu = dynamic_stiffness(d, F, EJ=10.0, beta=0.3, a1=d.a1 * a1_factor)
    noisy = noisy_runs(fuu, 6, rng)
    path = tmp_path / f"bench{a1_factor}.csv"
    write_bench(curves_to_frame("damper1", "0.5-0.5", F, 0.5, noisy), path)
    return path


def test_point_fit_names_the_parameters_its_box_stops():
    """a1 30 % above its nominal, outside the prior's +-5 %: the search stops at the bound and says so;
    with a1 nominal, nothing sits on a bound."""
    import tempfile
    from pathlib import Path

    d = resolve_damper("damper1")
    with tempfile.TemporaryDirectory() as tmp:
        for factor, want in ((1.3, {"a1"}), (1.0, set())):
            data = clean_bench(load_bench(_bench(Path(tmp), factor)))
            fit = fit_thesis_cost(likelihood_of(d, data, "0.5-0.5"), seed=3, population=60, generations=200)
            assert set(fit.on_bound) >= want and ("a1" in fit.on_bound) == bool(want), fit.on_bound
            assert fit.as_dict()["on_bound"] == list(fit.on_bound)


@pytest.mark.slow
def test_the_report_warns_where_a_fit_fails(tmp_path):
    """End to end: a test whose a1 lies outside its prior gets both warnings on its page; a test the model
    can fit gets a passing fit check and none."""
    pages = {}
    for factor in (1.3, 1.0):
        runs = tmp_path / f"runs{factor}"
        assert main(["sample", "--bench", str(_bench(tmp_path, factor)), "--damper", "damper1", "--tests", "0.5-0.5",
                     "--runs", str(runs), "--seed", "0", "--quiet"]) == 0
        assert main(["report", "--runs", str(runs), "-o", str(tmp_path / f"rep{factor}"), "--quiet"]) == 0
        pages[factor] = html.unescape((tmp_path / f"rep{factor}" / "index.html").read_text())
    bad, good = pages[1.3], pages[1.0]
    assert "Warning — the point fit (GA) sits on its prior bound for a1" in bad
    assert "Warning — magnitude: the median curve misses" in bad or "Warning — phase: the median curve misses" in bad
    assert "Warning —" not in good
    assert "Fit check: magnitude: the median curve stays within the runs' noise" in good
