import dataclasses
import json
from importlib.resources import files

import numpy as np
import pytest

from sbcal import InputError
from sbcal.design.conductor import load_conductor, resolve_conductor
from sbcal.design.life import (
    HOURS_PER_YEAR,
    Climate,
    allowed_cycles,
    parse_climate,
    plot_life,
    service_life,
)
from sbcal.design.span import FemImpedance, energy_balance
from sbcal.design.vibration import safe_border_line

WEIBULL = "weibull:k=2.0,c=4.5"

# ---------------------------------------------------------------------------------------------
# The bare span's yearly damage against pallas-dohl
#
# Inputs: the bundled Drake (and the same at 15 % RTS), bare span, 13 Strouhal lines 1-7 m/s
# (S = 0.185, D = 0.028143 m), stresses from energy_balance (STRESS_MPA below), Weibull k = 2,
# c = 4.5 m/s, across = 1. Reference: pallas-dohl (github.com/rte-france/pallas-dohl, commit
# 45b6cb9) installed in a throwaway venv (/tmp/dohl_ref, numpy 2.4.6, scipy 1.17.1), outside sbcal:
# dohl.lifespan.damage_year(v_i, ..., multilayer=True, strouhal=0.185) with dohl.ebp.ymax and
# dohl.damage.fictive_stress stubbed to return these stresses [Pa], so that its own S-N inversion
# (damage.inv_safe_border_line on 1e-6 sigma, multi-layer Orange Book line) and yearly formula
# (365.25 * 24 * 3600 * f / N: the damage if the wind blew at v_i all year, f = v S / D) act on
# them; times the line's share of the year, the integral over [lo_i, hi_i] (midpoints to the
# neighbouring lines, clipped to 1-7 m/s) of the Weibull pdf exactly as damage_year_weibull writes
# it, scipy.stats.exponweib.pdf(u, 1., k, 0., c) (trapezoid, 200001 points per interval).
# Conventions checked equal: stress amplitude (both the Poffenberger-Swart sigma_a), 3600 f cycles
# per hour, 8766 h per year, Weibull shape k / scale c. The 15 % case crosses both branches of the
# line and its step at N0 = 1.56e7 (16.27 MPa lies between 15.74 and 16.39 MPa: N = N0 there).
# dohl's damage_year_weibull on the same piecewise-constant stresses (grid refined to 1.5e6
# points) lets the frequency vary within each line's interval: totals 15720.5 and 1409.33,
# 0.04 % and 0.3 % above the sums of the per-line values below.
STRESS_MPA = {
    20.0: [33.422554992, 47.442823692, 57.945253320, 63.995971585, 65.303569976, 62.360083982, 56.353340396,
           48.838482858, 41.284949314, 34.702916181, 29.509859361, 25.654446318, 22.864217514],
    15.0: [32.048821769, 42.487913894, 46.592783632, 44.423208524, 38.025152105, 30.387841902, 23.848742862,
           19.239509864, 16.274985877, 14.387568045, 13.147269147, 12.296535933, 11.688743543],
}
DOHL_DAMAGE = {
    20.0: [12.2257052597, 267.8901844809, 1187.4533324147, 2728.6935162452, 3796.485441236, 3495.9557758796,
           2287.468768553, 1147.9207420025, 484.0750689734, 189.760455983, 75.6351884382, 32.39362113,
           8.0916574932],
    15.0: [9.9114233875, 154.32319135, 399.13564074, 439.78578587, 254.12764986, 96.057607253, 31.051623136,
           10.891083843, 4.7741043546, 2.6247935255, 1.3845306021, 0.80567888637, 0.26562672424],
}
DOHL_HOURS = [228.5779951597, 579.3908412459, 708.6894314431, 792.8851722036, 830.8729037671, 825.8918095718,
              784.6131644113, 715.891652028, 629.4230793087, 534.5297725061, 439.2337210747, 349.6967870231,
              144.2502141962]


def drake(pct=20.0):
    c = resolve_conductor("drake")
    return dataclasses.replace(c, tension_n=pct / 100 * c.rts_n)


@pytest.fixture(scope="module")
def imp(damper1):
    """A linear damper from the 6-DOF model: 20 posterior-like draws of EJ and beta (fixed seed)."""
    z = np.random.default_rng(7).standard_normal((2, 20))
    return FemImpedance(damper1, dict(EJ=20.0 * np.exp(0.2 * z[0]), beta=0.15 * np.exp(0.2 * z[1])))


@pytest.fixture(scope="module")
def damped(imp):
    return energy_balance(resolve_conductor("drake"), imp, 1.1, n_freq=13)


@pytest.mark.parametrize("pct", [20.0, 15.0])
def test_bare_damage_per_line_reproduces_pallas_dohl(pct):
    r = energy_balance(drake(pct), None, None, n_freq=13)
    np.testing.assert_allclose(r.stress_bare_pa * 1e-6, STRESS_MPA[pct], rtol=1e-7)  # the inputs fed to dohl
    life = service_life(r, WEIBULL)
    np.testing.assert_allclose(life.hours_per_year, DOHL_HOURS, rtol=1e-6)
    # the reference values are printed to 10-11 significant digits: agreement to 1e-9 (measured 4e-12-2e-11)
    np.testing.assert_allclose(life.damage_bare, DOHL_DAMAGE[pct], rtol=1e-9)
    assert life.damage_total_bare == pytest.approx(sum(DOHL_DAMAGE[pct]), rel=1e-9)
    assert life.years_bare == pytest.approx(1 / sum(DOHL_DAMAGE[pct]), rel=1e-9)
    np.testing.assert_allclose(life.wind_lo_mps, np.r_[1.0, np.arange(1.25, 7.0, 0.5)])
    np.testing.assert_allclose(life.wind_hi_mps, np.r_[np.arange(1.25, 7.0, 0.5), 7.0])


def test_safe_border_line_inverted_on_both_branches_and_its_step():
    c = resolve_conductor("drake")  # multi-layer: N0 = 1.56e7
    n = np.array([1e4, 1e6, 1.56e7, 1e8, 1e10])
    np.testing.assert_allclose(allowed_cycles(safe_border_line(n, "multi"), c), n, rtol=1e-12)
    between = 0.5 * (safe_border_line(1.56e7, "multi") + 263e6 * 1.56e7**-0.17)
    assert allowed_cycles(between, c) == 1.56e7
    single = dataclasses.replace(c, fatigue_layers="single")
    np.testing.assert_allclose(allowed_cycles(safe_border_line(n, "single"), single), n, rtol=1e-12)
    assert np.isnan(allowed_cycles(np.nan, c)) and allowed_cycles(0.0, c) == np.inf


def test_the_files_endurance_limit_stops_damage():
    c = dataclasses.replace(resolve_conductor("drake"), endurance_limit_pa=8.5e6)
    assert np.all(np.isinf(allowed_cycles([1e6, 8.5e6], c)))
    assert np.isfinite(allowed_cycles(8.6e6, c))
    assert np.isfinite(allowed_cycles(1e6, resolve_conductor("drake")))  # the safe border line goes on


# ---------------------------------------------------------------------------------------------
# Across share, dampers, unlimited life


def test_life_halves_when_across_doubles(damped):
    half, full = service_life(damped, WEIBULL, across=0.5), service_life(damped, WEIBULL, across=1.0)
    assert half.years_bare == pytest.approx(2 * full.years_bare, rel=1e-12)
    np.testing.assert_allclose(half.years_q, 2 * full.years_q, rtol=1e-12)
    np.testing.assert_allclose(half.damage_draws, 0.5 * full.damage_draws, rtol=1e-12)


def test_dampers_lengthen_the_life(damped):
    life = service_life(damped, WEIBULL)
    assert life.years_q[1] > 10 * life.years_bare
    assert np.all(1 / life.damage_draws > life.years_bare)
    assert life.to_dict()["years"]["q05"] == pytest.approx(life.years_q[0])
    assert life.words()[-1].startswith("with dampers: ")


def test_a_failed_balance_counts_as_infinite_damage(damped):
    s = damped.stress_pa.copy()
    s[3, 5] = np.nan
    life = service_life(dataclasses.replace(damped, stress_pa=s), WEIBULL)
    assert life.damage_draws[3] == np.inf and np.isfinite(np.delete(life.damage_draws, 3)).all()
    assert life.unsolved_draws == 1 and any("failed balance" in w for w in life.words())
    json.dumps(life.to_dict(), allow_nan=False)


def _with_sn(tmp_path, extra: str):
    text = files("sbcal").joinpath("conductors/drake.toml").read_text()
    assert text.rstrip().splitlines()[-1].startswith("design_cycles")  # [fatigue] is the last table
    path = tmp_path / "c.toml"
    path.write_text(text + extra)
    return load_conductor(path)


SN = "sn_curve = [[1e5, 60e6], [1e7, 25e6], [1e8, 18e6]]\n"


def test_sn_curve_from_the_file(tmp_path):
    c = _with_sn(tmp_path, SN)
    assert c.sn_curve == ((1e5, 60e6), (1e7, 25e6), (1e8, 18e6)) and c.sn_endurance_limit_pa is None
    np.testing.assert_allclose(allowed_cycles([60e6, 25e6, 18e6], c), [1e5, 1e7, 1e8], rtol=1e-12)
    mid = np.exp(0.5 * (np.log(60e6) + np.log(25e6)))  # log-log: halfway in log stress, halfway in log N
    assert allowed_cycles(mid, c) == pytest.approx(1e6, rel=1e-12)
    slope = np.log(1e8 / 1e7) / np.log(18 / 25)  # extrapolated by the end slope
    assert allowed_cycles(9e6, c) == pytest.approx(1e8 * (9 / 18) ** slope, rel=1e-12)
    assert allowed_cycles(120e6, c) == pytest.approx(1e5 * 2 ** (np.log(100) / np.log(25 / 60)), rel=1e-12)
    assert resolve_conductor("drake").sn_curve == ()


def test_no_stress_above_the_endurance_limit_is_unlimited(tmp_path, imp):
    c = _with_sn(tmp_path, SN + "sn_endurance_limit_pa = 70e6\n")
    for r in (energy_balance(c, None, None, n_freq=13), energy_balance(c, imp, 1.1, n_freq=13)):
        life = service_life(r, WEIBULL)
        d = life.to_dict()
        assert life.damage_total_bare == 0 and d["unlimited_bare"] and d["years_bare"] is None
        assert d["damage_per_year_bare"] == 0.0
        assert "no damper: unlimited (no damage)" in life.words()
        if r.positions_m:
            assert d["unlimited"] and d["years"] == {"median": None, "q05": None, "q95": None}
            assert "with dampers: unlimited" in life.words()[-1]
        json.dumps(d, allow_nan=False)


@pytest.mark.parametrize("extra, key", [
    ("sn_curve = [[1e5, 60e6]]\n", "fatigue.sn_curve"),
    ("sn_curve = [[1e7, 60e6], [1e5, 25e6]]\n", "fatigue.sn_curve[1]"),
    ("sn_curve = [[1e5, 20e6], [1e7, 25e6]]\n", "fatigue.sn_curve[1]"),
    ("sn_curve = [[1e5, -6e6], [1e7, -8e6]]\n", "fatigue.sn_curve[0][1]"),
    ("sn_curve = [[1e5, 60e6, 1], [1e7, 25e6]]\n", "fatigue.sn_curve[0]"),
    ("sn_curve = [[1e5, 'a'], [1e7, 25e6]]\n", "fatigue.sn_curve[0][1]"),
    ("sn_endurance_limit_pa = 0\n", "fatigue.sn_endurance_limit_pa"),
])
def test_bad_sn_curve_is_one_line_naming_file_and_key(tmp_path, extra, key):
    with pytest.raises(InputError) as e:
        _with_sn(tmp_path, extra)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(tmp_path / "c.toml")) and f"key '{key}'" in msg


# ---------------------------------------------------------------------------------------------
# Climates


def test_weibull_hours_add_up_to_a_year():
    w = parse_climate("weibull:k=2.0,c=4.5")
    assert w.hours_between(0.0, np.inf) == pytest.approx(HOURS_PER_YEAR, rel=1e-15)
    assert w.describe() == "weibull:k=2,c=4.5" and w.total_hours == HOURS_PER_YEAR
    edges = np.linspace(0, 40, 401)
    assert w.hours_between(edges[:-1], edges[1:]).sum() == pytest.approx(HOURS_PER_YEAR, rel=1e-12)
    assert w.hours_between(3.0, 3.0) == 0.0 and w.hours_between(4.0, 3.0) == 0.0


def test_histogram_integrates_a_piecewise_constant_density(tmp_path):
    p = tmp_path / "wind.csv"
    p.write_text("wind_m_s,hours_per_year,turbulence_intensity\n1,100,0.1\n2,200,0.12\n\n4,300,0.15\n")
    h = parse_climate(str(p))
    np.testing.assert_allclose(h.edges_mps, [0.5, 1.5, 3.0, 5.0])
    assert h.hours_between(0.0, np.inf) == pytest.approx(600.0)
    assert h.hours_between(1.0, 2.0) == pytest.approx(100 * 0.5 + 200 * 0.5 / 1.5)
    assert h.hours_between(4.5, 9.0) == pytest.approx(300 * 0.5 / 2)
    np.testing.assert_allclose(h.hours_between([0.0, 1.5], [1.5, 5.0]), [100.0, 500.0])
    np.testing.assert_allclose(h.turbulence_intensity, [0.1, 0.12, 0.15])
    assert h.describe() == str(p) and parse_climate(h) is h
    life = service_life(energy_balance(resolve_conductor("drake"), None, None, n_freq=13), p)
    assert life.hours_per_year.sum() == pytest.approx(h.hours_between(1.0, 7.0))
    assert any("reported only" in w for w in life.words())


def test_a_speed_of_zero_bounds_the_first_bin_at_zero(tmp_path):
    p = tmp_path / "wind.csv"
    p.write_text("hours_per_year,wind_m_s\n50,0\n100,1\n")
    h = parse_climate(p)
    np.testing.assert_allclose(h.edges_mps, [0.0, 0.5, 1.5])
    assert h.hours_between(0.0, 0.25) == pytest.approx(25.0) and h.turbulence_intensity is None


BAD_CSV = {
    "negative speed": ("wind_m_s,hours_per_year\n-1,10\n2,20\n", "line 2, column 'wind_m_s'"),
    "negative hours": ("wind_m_s,hours_per_year\n1,10\n2,-20\n", "line 3, column 'hours_per_year'"),
    "hours over a year": ("wind_m_s,hours_per_year\n1,5000\n2,3900\n", "hours that do not add up"),
    "unsorted speeds": ("wind_m_s,hours_per_year\n1,10\n3,20\n2,20\n", "line 4, column 'wind_m_s'"),
    "missing column": ("wind_m_s,hours\n1,10\n2,20\n", "column 'hours_per_year': missing"),
    "not a number": ("wind_m_s,hours_per_year\n1,ten\n2,20\n", "line 2, column 'hours_per_year'"),
    "bad turbulence": ("wind_m_s,hours_per_year,turbulence_intensity\n1,10,1.5\n2,20,0.1\n",
                       "column 'turbulence_intensity'"),
    "one row": ("wind_m_s,hours_per_year\n1,10\n", "at least two rows"),
}


@pytest.mark.parametrize("case", list(BAD_CSV))
def test_bad_climate_file_is_one_line(tmp_path, case):
    text, part = BAD_CSV[case]
    p = tmp_path / "wind.csv"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        parse_climate(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)) and part in msg


def test_hours_just_over_a_year_are_rounding(tmp_path):
    p = tmp_path / "wind.csv"
    p.write_text("wind_m_s,hours_per_year\n1,4400\n2,4400\n")  # 8800 h: 0.4 % over
    assert parse_climate(p).total_hours == 8800.0


@pytest.mark.parametrize("spec", ["weibull:k=0,c=4.5", "weibull:k=-1,c=4.5", "weibull:k=2,c=0", "weibull:k=2",
                                  "weibull:k=2,c=inf", "weibull:k=2,c=x", "weibull:k=2,c=4,z=1", "gumbel:1,2",
                                  "", "no/such/file.csv"])
def test_bad_climate_spec_names_the_option(spec):
    with pytest.raises(InputError) as e:
        parse_climate(spec)
    assert str(e.value).startswith("--climate: ") and "\n" not in str(e.value)


@pytest.mark.parametrize("across", [0, -0.5, 1.5, float("nan"), "1", True])
def test_bad_across_names_the_option(across):
    r = energy_balance(resolve_conductor("drake"), None, None, n_freq=5)
    with pytest.raises(InputError, match="^--across: "):
        service_life(r, WEIBULL, across=across)


# ---------------------------------------------------------------------------------------------
# Outputs

COLUMNS = ["wind_m_s", "wind_lo_m_s", "wind_hi_m_s", "frequency_hz", "hours_per_year", "cycles_per_year",
           "stress_bare_mpa", "allowed_cycles_bare", "damage_per_year_bare", "stress_median_mpa",
           "allowed_cycles_median", "damage_per_year_median", "damage_per_year_q05", "damage_per_year_q95"]
KEYS = {"climate", "across", "hours_per_year", "years_bare", "damage_per_year_bare", "years", "damage_per_year",
        "unlimited_bare", "unlimited"}


def test_frame_dict_words_and_plot(damped, tmp_path):
    bare = service_life(energy_balance(resolve_conductor("drake"), None, None, n_freq=13), WEIBULL, across=0.3)
    life = service_life(damped, WEIBULL, across=0.3)
    for lf in (bare, life):
        f = lf.to_frame()
        assert list(f.columns) == COLUMNS and len(f) == 13
        np.testing.assert_allclose(f.cycles_per_year, 3600 * f.hours_per_year * f.frequency_hz)
        np.testing.assert_allclose(f.damage_per_year_bare, f.cycles_per_year / f.allowed_cycles_bare)
        d = json.loads(json.dumps(lf.to_dict(), allow_nan=False))
        assert set(d) == KEYS and d["climate"] == "weibull:k=2,c=4.5" and d["across"] == 0.3
        assert d["hours_per_year"] == pytest.approx(0.3 * parse_climate(WEIBULL).hours_between(1, 7))
        assert d["years_bare"] == pytest.approx(1 / d["damage_per_year_bare"])
        assert all(isinstance(w, str) and "\n" not in w for w in lf.words())
    assert bare.to_frame()[COLUMNS[9:]].isna().all().all()
    assert bare.to_dict()["years"] is None and bare.to_dict()["damage_per_year"] is None
    assert not life.to_frame()[COLUMNS[9:]].isna().any().any()
    y = life.to_dict()["years"]
    assert y["q05"] < y["median"] < y["q95"]
    assert y["q05"] == pytest.approx(1 / np.quantile(life.damage_draws, 0.95), rel=0.05)
    for lf, name in ((bare, "bare.png"), (life, "life.png")):
        plot_life(lf, tmp_path / name)
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare.png", "life.png"]  # no temporary left


def test_climate_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        parse_climate(WEIBULL).k = 3.0
    assert isinstance(parse_climate(WEIBULL), Climate)
