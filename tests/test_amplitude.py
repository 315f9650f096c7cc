import warnings

import numpy as np
import pytest
from scipy.stats import binom

from sbcal import InputError
from sbcal.inference.amplitude import TestPoint, fit_law, points_from_table
from sbcal.cli import main
from sbcal.inference.sampler import SamplerConfig
from tests.benches import noisy_runs

FAST = SamplerConfig(nwalkers=16, max_draws=250, de_population=30, de_generations=60, workers=1)

AMPS = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 1.0, 2.0])


def points(rng, k, n, sd, scatter=0.0):
    """Per-test posteriors of log EJ: centred on the truth plus posterior error, sd ``sd``."""
    true = np.log(k) - n * np.log(AMPS) + scatter * rng.standard_normal(AMPS.size)
    m = true + sd * rng.standard_normal(AMPS.size)
    return [TestPoint("d", f"{a:g}", float(a), float(mi), sd, float(np.exp(mi)), 0.0, 0.0) for a, mi in zip(AMPS, m)]


@pytest.mark.long
def test_recovers_k_and_n_from_per_test_posteriors():
    """90 % intervals of k and n contain the truth at the nominal rate over 120 data sets. Size: a calibrated
    fit fails this with probability 0.38 % a parameter (the 0.5 % lower binomial tail: fewer than 99 hits);
    power: a fit whose intervals cover 75 % fails it with probability 0.967 (40 data sets gave 0.42)."""
    rng = np.random.default_rng(5)
    trials = 120
    hits = {"k": 0, "n": 0}
    for t in range(trials):
        k, n = float(rng.uniform(6, 14)), float(rng.uniform(0.2, 0.7))
        fit = fit_law(points(rng, k, n, sd=0.05, scatter=0.03), "powerlaw", seed=t, config=FAST)
        s = fit.summary()
        hits["k"] += s["k"][1] <= k <= s["k"][2]
        hits["n"] += s["n"][1] <= n <= s["n"][2]
    floor = binom.ppf(0.005, trials, 0.9)  # fail only below a 0.5 % lower tail
    assert hits["k"] >= floor and hits["n"] >= floor, hits


def test_intervals_widen_with_per_test_uncertainty():
    rng = np.random.default_rng(11)
    base = points(rng, 10.0, 0.5, sd=0.0)
    widths = []
    for sd in (0.02, 0.2):
        pts = [TestPoint(p.damper, p.test, p.amplitude, p.mean_log, sd, p.median, 0, 0) for p in base]
        s = fit_law(pts, "powerlaw", seed=3, config=FAST).summary()
        widths.append(s["n"][2] - s["n"][1])
    assert widths[1] > 3 * widths[0]


def test_table_mode_recovers_known_exponent(tmp_path, capsys):
    t = tmp_path / "t.csv"
    ej = 12.5 * AMPS ** -0.37
    t.write_text("amplitude_mm_pp,ej_nm2\n" + "".join(f"{a},{e:.6g}\n" for a, e in zip(AMPS, ej)))
    out = tmp_path / "m.json"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["map", "--table", str(t), "--json", str(out), "--plot", str(tmp_path / "m.png")]) == 0
    # a table has no loss factor: one panel (EJ with the law's band), no empty panel, no legend warning
    assert not [w for w in caught if "No artists" in str(w.message)]
    width = int.from_bytes((tmp_path / "m.png").read_bytes()[16:20], "big")  # the PNG header's IHDR width
    assert width < 800, width  # 6.5 in at 110 dpi; two panels are 11 in
    import json

    d = json.loads(out.read_text())
    assert d["powerlaw"]["n"][1] <= 0.37 <= d["powerlaw"]["n"][2]
    assert abs(d["powerlaw"]["n"][0] - 0.37) < 0.005 and abs(d["powerlaw"]["k"][0] - 12.5) < 0.1
    assert d["powerlaw"]["convergence"]["converged"]
    # exact values leave the saturating law's EJ_inf undetermined (it runs down towards its box's
    # floor, where the law is the power law): its 90 % interval spans decades (measured: 29x), and the
    # power law stays preferred. (The engine once failed to converge on this posterior; it now does,
    # with the quantiles of a differential-evolution-only run of 15000 steps.)
    lo, hi = d["saturating"]["EJ_inf"][1:]
    assert hi / lo > 10 and d["preferred"] == "powerlaw"


def _saturating_points(rng, ej_inf, c, n, sd):
    """Per-test posteriors of log EJ on the saturating law EJ_inf + c A^-n (posterior sd ``sd``)."""
    true = np.log(ej_inf + c * AMPS ** -n)
    m = true + sd * rng.standard_normal(AMPS.size)
    return [TestPoint("d", f"{a:g}", float(a), float(mi), sd, float(np.exp(mi)), 0.0, 0.0) for a, mi in zip(AMPS, m)]


@pytest.mark.slow
def test_saturating_law_is_preferred_on_data_that_saturate_and_not_on_a_power_law():
    """The preference rule on data made for it: tests whose EJ levels off at large amplitude (EJ_inf
    = 6, c = 2, n = 1.2: EJ falls from 37 to 6.9 and flattens) prefer the saturating law; an exact
    power law prefers the power law. Three data sets each (fixed seeds; seed 6's power law is the one a
    1-SE rule got wrong): every one must decide right."""
    from sbcal.inference.amplitude import amplitude_map

    for seed in (1, 2, 6):
        sat, _ = amplitude_map(_saturating_points(np.random.default_rng(seed), 6.0, 2.0, 1.2, 0.02), seed=seed,
                               config=FAST)
        assert sat["preferred"] == "saturating", sat["criterion"]
        assert sat["saturating"]["EJ_inf"][1] < 6.0 < sat["saturating"]["EJ_inf"][2]
        pl, _ = amplitude_map(points(np.random.default_rng(seed), 10.0, 0.45, sd=0.02), seed=seed, config=FAST)
        assert pl["preferred"] == "powerlaw", pl["criterion"]


@pytest.mark.parametrize("text, match", [
    ("amplitude_mm_pp,ej\n0.1,3\n", "column 'ej_nm2': missing"),
    ("amplitude_mm_pp,ej_nm2\n0.1,3\n0.2,abc\n", "line 3, column 'ej_nm2'"),
    ("amplitude_mm_pp,ej_nm2\n-1,3\n", "line 2, column 'amplitude_mm_pp'"),
])
def test_table_errors(tmp_path, text, match):
    p = tmp_path / "t.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        points_from_table(p)


def test_map_needs_runs(tmp_path, capsys):
    assert main(["map", "--runs", str(tmp_path)]) == 2
    assert "no finished theta1 runs" in capsys.readouterr().err


@pytest.mark.slow
def test_joint_model_recovers_known_power_law(tmp_path):
    """One emcee run over three tests whose EJ follows k A^-n exactly: k and n recovered."""
    import pandas as pd

    from sbcal import STANDARD_GRID_HZ as F, dynamic_stiffness
    from sbcal.data.clean_bench import clean_bench
    from sbcal.inference.amplitude import joint_powerlaw
    from sbcal.data.bench import curves_to_frame, write_bench
    from sbcal.data.readers import load_bench
    from sbcal.model.damper import resolve_damper
    d = resolve_damper("damper2")
    rng = np.random.default_rng(2024)
    k, n = 8.5, 0.42
    frames = []
    for amp, beta in ((0.2, 0.3), (0.5, 0.35), (1.5, 0.4)):
        fuu = dynamic_stiffness(d, F, EJ=k * amp**-n, beta=beta)
        noisy = noisy_runs(fuu, 6, rng)
        frames.append(curves_to_frame("damper2", f"{amp:g}-{amp:g}", F, amp, noisy))
    path = tmp_path / "b.csv"
    write_bench(pd.concat(frames), path)
    cfg = SamplerConfig(nwalkers=32, max_steps=20000, max_draws=500)
    out = joint_powerlaw(d, clean_bench(load_bench(path)), ["0.2-0.2", "0.5-0.5", "1.5-1.5"], seed=4, config=cfg)
    # a single trial: the truth must lie within 3.29 posterior sd (the 90 % width), a 0.1 % tail
    for name, truth in (("k", k), ("n", n)):
        med, lo, hi = out[name]
        assert abs(med - truth) < hi - lo, (name, out[name])
    assert out["converged"] and out["r_hat"] <= 1.01, out["convergence"]
    assert out["k"][2] - out["k"][1] < 0.1 * k  # informative, not just a wide box
