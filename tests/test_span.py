import dataclasses
import json
import os

import numpy as np
import pytest

from sbcal import InputError
from sbcal.design.conductor import (
    SELF_DAMPING_PRESETS,
    WIND_CURVES,
    Conductor,
    bundled_conductors,
    lilien_k,
    load_conductor,
    resolve_conductor,
)
from sbcal.design.placement import optimise_position
from sbcal.design.span import STATUS, FemImpedance, energy_balance
from sbcal.design.span_study import plot_span
from sbcal.design.vibration import bending_amplitude, fatigue_limit, poffenberger_swart, safe_border_line, strouhal_band, wind_power_curve

# Drake exactly as fed to pallas-dohl for the reference numbers below: D = 1.108 in, m = 1.094 lb/ft,
# RTS = 31,500 lbf, converted with 0.0254 m/in, 0.45359237 kg/lb, 0.3048 m/ft, 4.4482216152605 N/lbf.
D = 1.108 * 0.0254
M = 1.094 * 0.45359237 / 0.3048
RTS = 31500 * 4.4482216152605
F_REF = np.array([6.0, 10.0, 15.0, 20.0, 30.0, 40.0, 46.0])


def drake(**over) -> Conductor:
    kw = dict(name="drake-ref", diameter_m=D, mass_kg_per_m=M, rts_n=RTS, tension_n=0.20 * RTS,
              ej_min_nm2=43.9, wire_diameter_m=0.004442, wire_modulus_pa=68e9, span_length_m=400.0,
              self_damping_k=lilien_k(D, M, RTS))
    kw.update(over)
    return Conductor(**kw)


@pytest.fixture(scope="module")
def imp(damper1):
    """A linear damper from the 6-DOF model: 20 posterior-like draws of EJ and beta (fixed seed)."""
    z = np.random.default_rng(7).standard_normal((2, 20))
    return FemImpedance(damper1, dict(EJ=20.0 * np.exp(0.2 * z[0]), beta=0.15 * np.exp(0.2 * z[1])))


# ---------------------------------------------------------------------------------------------
# The bare span against an independent implementation


@pytest.mark.parametrize("over, ref", [
    # pallas-dohl (github.com/rte-france/pallas-dohl, commit 45b6cb9), installed in a throwaway venv:
    # dohl.ebp.ymax(F_REF, 0.20 * RTS, D, wind_method='cigre', damping_method='kraus', mu=M, rts=RTS)
    # (CIGRE cubic, Kraus & Hagedorn exponents, k = D[mm]/sqrt(m RTS[kN]); its bisection tol 1e-6 m).
    ({}, [0.0280083, 0.02625193, 0.02260123, 0.01784796, 0.00873651, 0.00394191, 0.00272716]),
    # the same with wind_method='foti', iv=0.15 (turbulence factor (1 + (0.15/0.09)^2)^-1/2)
    ({"turbulence_intensity": 0.15},
     [0.02729652, 0.02406505, 0.01801705, 0.01160457, 0.00403638, 0.00199712, 0.00153763]),
    # wind_method='cigre', damping_method='noiseux1991', tension 0.15 * RTS
    ({"tension_n": 0.15 * RTS, "self_damping_l": 2.44, "self_damping_m": 5.63, "self_damping_n": 2.76},
     [0.02551385, 0.01806858, 0.00785081, 0.00314102, 0.00125796, 0.00081189, 0.0006734]),
])
def test_bare_span_reproduces_pallas_dohl(over, ref):
    r = energy_balance(drake(**over), freq_hz=F_REF)
    np.testing.assert_allclose(r.ymax_bare_m, ref, rtol=0.02)
    np.testing.assert_array_equal(r.ymax_m[0], r.ymax_bare_m)
    assert r.flags == ["ok"] * F_REF.size and r.n_dampers == 0


def test_balance_holds_at_the_solution(imp):
    """Wind input equals self-damping plus damper power at every returned Y_max."""
    r = energy_balance(drake(), imp, 1.1, n_freq=25)
    np.testing.assert_allclose(r.p_wind_w, r.p_self_w + r.p_damper_w, rtol=1e-8)
    # the bare span's own balance: P_w(Y) = L k Y^l f^m / T^n
    c = drake()
    pc = c.span_length_m * c.self_damping_k * r.ymax_bare_m**2.47 * r.freq_hz**5.38 / (c.tension_n / 1e3) ** 2.80
    np.testing.assert_allclose(r.p_wind_bare_w, pc, rtol=1e-8)


# ---------------------------------------------------------------------------------------------
# Damper, node and bands


def test_damper_reduces_ymax_except_at_a_node(imp):
    c = drake()
    x_d = 1.2
    f_node = c.wave_speed_m_s / (2 * x_d)     # lambda = 2 x_d: the damper sits on a node
    freq = np.sort(np.append(np.linspace(8.0, 45.0, 30), f_node))
    r = energy_balance(c, imp, x_d, freq_hz=freq)
    node = np.flatnonzero(freq == f_node)[0]
    sines = np.abs(np.sin(2 * np.pi * x_d / r.wavelength_m))
    moving = sines > 0.05
    assert moving.sum() >= 28
    assert np.all(r.ymax_m[:, moving] < 0.9 * r.ymax_bare_m[moving])
    np.testing.assert_allclose(r.ymax_m[:, node], r.ymax_bare_m[node], rtol=1e-9)
    assert np.all(r.p_damper_w[:, node] < 1e-20)
    # dampers at both ends take out more than at one
    r2 = energy_balance(c, imp, x_d, ends=2, freq_hz=freq)
    assert r2.n_dampers == 2
    assert np.all(r2.ymax_m[:, moving] < r.ymax_m[:, moving])


def test_bands_widen_with_the_posterior_spread(damper1):
    c = drake()
    z = np.random.default_rng(1).standard_normal((2, 200))

    def log_width(sigma):
        imp = FemImpedance(damper1, dict(EJ=20.0 * np.exp(sigma * z[0]), beta=0.15 * np.exp(sigma * z[1])))
        lo, hi = np.quantile(np.log(energy_balance(c, imp, 1.0, n_freq=30).ymax_m), [0.05, 0.95], axis=0)
        return hi - lo

    # Same standard-normal draws, log-spread 0.05 vs 0.3: on this seed the 90 % band of log Y_max is
    # 2.4-12x wider at every frequency; 1.5x leaves room for quantile noise of 200 draws.
    assert np.all(log_width(0.3) > 1.5 * log_width(0.05))


def test_amplitude_dependent_damper_is_balanced(damper1):
    """A nonlinear damper (EJ falling with amplitude, like the amplitude map's power law): the
    balance holds with K* taken at the amplitudes each damper really has."""
    betas = np.array([0.1, 0.15, 0.2])                       # three draws of the loss factor

    def impedance(freq_hz, amplitude_m):
        ej = 9.5 * (2e3 * np.broadcast_to(amplitude_m, (3, freq_hz.size))) ** -0.35  # k A^-n, A in mm p-p
        return np.concatenate([FemImpedance(damper1, dict(EJ=ej[:, j], beta=betas))(freq_hz[j:j + 1], None)
                               for j in range(freq_hz.size)], axis=1)   # EJ varies per line: one line at a time

    c = drake()
    freq = np.linspace(8, 40, 6)
    for wave in ("travelling", "standing"):
        r = energy_balance(c, impedance, [0.8, 1.5], freq_hz=freq, wave=wave)
        assert r.ymax_m.shape == (3, 6) and r.flags == ["ok"] * 6
        pd = sum(0.5 * 2 * np.pi * freq * impedance(freq, x).imag * x**2 for x in r.damper_amplitude_m)
        np.testing.assert_allclose(r.p_damper_w, pd, rtol=1e-9)
        np.testing.assert_allclose(r.p_wind_w, r.p_self_w + r.p_damper_w, rtol=1e-7)


def test_travelling_wave_equals_standing_wave_for_a_light_damper(damper1):
    """Scaled down 1000x the damper barely disturbs the mode: both formulations agree; at full
    size (loading above 1 on Drake) they part, and the standing-wave result carries a warning."""
    c = drake()
    light = FemImpedance(damper1, dict(EJ=20.0, beta=0.15))
    scaled = lambda f, x: 1e-3 * light(f, x)
    kw = dict(n_freq=30, freq_hz=None)
    t, s = (energy_balance(c, scaled, 1.1, wave=w, **kw) for w in ("travelling", "standing"))
    assert np.max(t.damper_loading) < 0.01
    np.testing.assert_allclose(t.p_damper_w, s.p_damper_w, rtol=0.02)
    np.testing.assert_allclose(t.ymax_m, s.ymax_m, rtol=1e-3)
    np.testing.assert_allclose(t.damper_amplitude_m[0], s.damper_amplitude_m[0], rtol=0.02)
    t, s = (energy_balance(c, light, 1.1, wave=w, **kw) for w in ("travelling", "standing"))
    assert np.max(t.damper_loading) > 1
    assert any("use wave='travelling'" in w for w in s.warnings) and not t.warnings
    assert np.max(np.abs(np.log(t.ymax_m / s.ymax_m))) > np.log(2)
    # the travelling wave never takes out more than a perfect absorber: 0.5 sqrt(T m) omega^2 Y^2
    cap = 0.5 * np.sqrt(c.tension_n * c.mass_kg_per_m) * (2 * np.pi * t.freq_hz) ** 2 * t.ymax_m**2
    assert np.all(t.p_damper_w <= cap) and np.any(s.p_damper_w > cap)
    with pytest.raises(InputError, match="wave"):
        energy_balance(c, light, 1.1, wave="breaking")


# ---------------------------------------------------------------------------------------------
# Bending, stress, fatigue


def test_poffenberger_swart_matches_the_f_ymax_formula():
    """Y_b from the clamp's boundary-layer mode shape, through K, gives the Orange Book's
    sigma = pi d E_a sqrt(m / EJ) f Y_max (eq. 3.2-14, pallas-dohl damage.fictive_stress_fymax):
    both are E_a d/2 times the curvature at the clamp; they differ by terms of order (b x_b)^2."""
    c = drake()
    f = np.linspace(5, 60, 12)
    sigma = poffenberger_swart(c) * bending_amplitude(c, f, np.full(f.size, 0.01))
    fymax = np.pi * c.wire_diameter_m * c.wire_modulus_pa * np.sqrt(c.mass_kg_per_m / c.ej_min_nm2) * f * 0.01
    np.testing.assert_allclose(sigma, fymax, rtol=0.01)


def test_safe_border_line_values():
    # 730 N^-0.2 MPa to 2e7 cycles and 430 N^-0.17 beyond (single layer); 450 / 263 (multi layer)
    np.testing.assert_allclose(safe_border_line([1e6, 1e8], "single"), [730e6 * 1e6**-0.2, 430e6 * 1e8**-0.17])
    np.testing.assert_allclose(safe_border_line(5e8, "multi"), 263e6 * 5e8**-0.17)
    assert fatigue_limit(drake(endurance_limit_pa=8.5e6)) == 8.5e6
    with pytest.raises(InputError, match="layers"):
        safe_border_line(1e7, "triple")


# ---------------------------------------------------------------------------------------------
# Flags, warnings and errors


def test_status_flags():
    # a curve measured only over Y/D = 0.03-0.10 and still rising steeply there: the bare Drake
    # balance lies inside it at high frequency, beyond it (extrapolated) lower down, and at the
    # lowest frequencies the extrapolated input outgrows self-damping up to 2 D
    r = energy_balance(drake(wind_curve="carroll1936"), freq_hz=F_REF)
    assert r.flags == ["no_solution"] * 2 + ["extrapolated"] * 3 + ["ok"] * 2
    assert any("extrapolated" in w for w in r.warnings) and any("no balance" in w for w in r.warnings)
    assert np.all(np.isnan(r.ymax_bare_m[:2])) and np.all(np.isfinite(r.ymax_bare_m[2:]))
    # almost no self-damping with a curve that keeps rising: no balance up to 2 D
    r = energy_balance(drake(wind_curve="rawlins1983", self_damping_k=1e-12), freq_hz=F_REF[:2])
    assert r.flags == ["no_solution"] * 2 and np.all(np.isnan(r.ymax_m))
    assert r.margin_bare == 0.0 and np.all(r.margin == 0.0)
    # in the standing-wave formula a damper so lossy that it out-dissipates the wind at Y = 1e-4 D:
    # Y_max is that bound (the travelling wave would see it as a second clamp)
    r = energy_balance(drake(), lambda f, x: np.full((1, f.size), 1e12j), 1.0, freq_hz=[20.0], wave="standing")
    assert r.flags == ["below_range"] and r.ymax_m[0, 0] == pytest.approx(1e-4 * D)
    assert list(STATUS) == ["ok", "extrapolated", "below_range", "no_solution"]


def test_wind_and_position_errors(imp):
    c = drake()
    for wind in [(0.0, 7.0), (1.0, 20.0), (5.0, 2.0), "fast"]:
        with pytest.raises(InputError, match="wind"):
            energy_balance(c, wind=wind)
    r = energy_balance(c, wind=(0.5, 9.0), n_freq=5)
    assert any("outside 1-7 m/s" in w for w in r.warnings)
    assert not energy_balance(c, n_freq=5).warnings
    for pos, ends, match in [(450.0, 1, "outside the span"), (250.0, 2, "half the span"), (-1.0, 1, "outside"),
                             (1.0, 3, "ends")]:
        with pytest.raises(InputError, match=match):
            energy_balance(c, imp, pos, ends=ends, n_freq=5)
    with pytest.raises(InputError, match="position_m"):
        energy_balance(c, imp, n_freq=5)
    with pytest.raises(InputError, match="not passive"):
        energy_balance(c, lambda f, x: np.full((2, f.size), 1e3 - 10j), 1.0, n_freq=5)
    with pytest.raises(InputError, match="returned shape"):
        energy_balance(c, lambda f, x: np.ones((2, 3), complex), 1.0, n_freq=5)


def test_strouhal_band():
    c = drake(strouhal=0.2)
    f, v = strouhal_band(c, (1.0, 7.0), 7)
    np.testing.assert_allclose(v, np.arange(1.0, 8.0))
    np.testing.assert_allclose(f, 0.2 * v / D)


def test_wind_curves_are_the_conductor_vocabulary():
    assert WIND_CURVES[0] == "cigre"
    y = np.array([0.05, 0.2, 0.5])
    for name in WIND_CURVES:
        p = wind_power_curve(y, name)
        assert np.all(np.isfinite(p) & (p > 0)), name
    # the tabulated points are reproduced (Diana & Falco 1971 at Y/D = 0.3: 9.0)
    assert wind_power_curve(0.3, "diana1971") == pytest.approx(9.0)


# ---------------------------------------------------------------------------------------------
# Placement and outputs


def test_placement_maximises_the_worst_case_margin(imp):
    c = drake()
    pos = np.linspace(0.3, 2.5, 12)
    p = optimise_position(c, imp, pos, n_freq=20, quantile=0.1)
    assert p.best_position_m in pos
    assert np.all(p.best_margin >= p.margin)
    assert p.margin.shape == (12,) and np.unique(p.margin).size > 6   # the curve is not flat
    assert p.best_margin == pytest.approx(np.quantile(energy_balance(c, imp, p.best_position_m, n_freq=20).margin, 0.1))
    assert p.suffices == (p.best_margin >= 1)
    assert p.best.margin_bare < p.best_margin                         # the damper helps
    with pytest.raises(InputError, match="quantile"):
        optimise_position(c, imp, pos, quantile=1.5)


def test_outputs_frame_json_plot(imp, tmp_path):
    r = energy_balance(drake(), imp, [0.9, 1.6], n_freq=12)
    frame = r.to_frame()
    assert len(frame) == 12 and {"ymax_median_m", "stress_q95_mpa", "flag", "damper2_amplitude_median_m"} <= set(frame)
    assert np.all(frame["ymax_q05_m"] <= frame["ymax_median_m"]) and np.all(frame["ymax_median_m"] <= frame["ymax_q95_m"])
    doc = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert doc["n_dampers"] == 2 and doc["n_draws"] == 20 and len(doc["per_frequency"]["frequency_hz"]) == 12
    p = optimise_position(drake(), imp, [0.8, 1.2], n_freq=8)
    json.dumps(p.to_dict(), allow_nan=False)
    out = tmp_path / "sub" / "span.png"
    plot_span(r, out, placement=p)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [f.name for f in out.parent.iterdir()] == ["span.png"]     # no temporary left behind


# ---------------------------------------------------------------------------------------------
# Conductor files

GOOD = """
name = "c"
diameter_m = 0.028
mass_kg_per_m = 1.6
rts_n = 140000.0
tension_pct_rts = 20.0
ej_min_nm2 = 44.0
span_length_m = 400.0
[outer_wire]
diameter_m = 0.0044
modulus_pa = 68e9
"""


def write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_minimal_file_takes_the_cited_defaults(tmp_path):
    c = load_conductor(write(tmp_path, GOOD))
    assert c.tension_n == pytest.approx(28000.0) and c.tension_pct_rts == pytest.approx(20.0)
    assert (c.self_damping_l, c.self_damping_m, c.self_damping_n) == SELF_DAMPING_PRESETS["kraus"][:3]
    assert c.self_damping_k == pytest.approx(28.0 / np.sqrt(1.6 * 140.0))
    assert (c.wind_curve, c.turbulence_intensity, c.strouhal, c.fatigue_layers) == ("cigre", 0.0, 0.185, "multi")
    c = load_conductor(write(tmp_path, GOOD.replace("tension_pct_rts = 20.0", "tension_n = 30000")
                             + "[self_damping]\npreset = 'noiseux1991'\nk = 2.5\nn = 2.5\n"))
    assert c.tension_n == 30000 and c.self_damping_k == 2.5
    assert (c.self_damping_l, c.self_damping_n) == (2.44, 2.5)


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("ej_min_nm2 = 44.0\n", ""), r"key 'ej_min_nm2': missing"),
    (lambda t: t.replace('name = "c"\n', ""), r"key 'name': missing"),
    (lambda t: t.replace("modulus_pa = 68e9\n", ""), r"key 'outer_wire.modulus_pa': missing"),
    (lambda t: t.replace("mass_kg_per_m = 1.6", 'mass_kg_per_m = "heavy"'), r"key 'mass_kg_per_m': expected a number"),
    (lambda t: t.replace("diameter_m = 0.028", "diameter_m = -0.028"), r"key 'diameter_m': must be > 0"),
    (lambda t: t.replace("span_length_m = 400.0", "span_length_m = nan"), r"key 'span_length_m': value nan is not finite"),
    (lambda t: t.replace("tension_pct_rts = 20.0", "tension_pct_rts = 20.0\ntension_n = 1000.0"),
     r"key 'tension_n': give exactly one.*both"),
    (lambda t: t.replace("tension_pct_rts = 20.0\n", ""), r"key 'tension_n': give exactly one.*neither"),
    (lambda t: t.replace("tension_pct_rts = 20.0", "tension_pct_rts = 120.0"), r"key 'tension_pct_rts': must be < 100"),
    (lambda t: t.replace("tension_pct_rts = 20.0", "tension_n = 2e5"), r"key 'tension_n': .* not below rts_n"),
    (lambda t: t + "[self_damping]\nk = -1.0\n", r"key 'self_damping.k': must be > 0"),
    (lambda t: t + "[self_damping]\npreset = 'nobody'\n", r"key 'self_damping.preset': expected one of"),
    (lambda t: t + "[wind]\ncurve = 'gale'\n", r"key 'wind.curve': expected one of cigre"),
    (lambda t: t + "[wind]\nstrouhal = 2.0\n", r"key 'wind.strouhal'"),
    (lambda t: t + "[wind]\nturbulence_intensity = -0.1\n", r"key 'wind.turbulence_intensity': must be >= 0"),
    (lambda t: t + "[fatigue]\nlayers = 'three'\n", r"key 'fatigue.layers'"),
    (lambda t: t.replace("[outer_wire]", "outer_wire = 3\n[x]"), r"key 'outer_wire': expected a table"),
    (lambda t: t.replace("[outer_wire]", "[outer_wire"), r"invalid TOML"),
])
def test_bad_files_name_file_and_key(tmp_path, edit, match):
    p = write(tmp_path, edit(GOOD))
    with pytest.raises(InputError, match=match) as e:
        load_conductor(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "\n" not in msg


def test_missing_file_and_unknown_name(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_conductor(tmp_path / "none.toml")
    with pytest.raises(InputError, match="neither a bundled conductor"):
        resolve_conductor("nonesuch")


def test_bundled_conductors_load_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert {"drake", "aster570"} <= set(bundled_conductors())
    c = resolve_conductor("drake")
    assert (c.diameter_m, c.mass_kg_per_m, c.rts_n, c.ej_min_nm2) == (0.028143, 1.6281, 140119.0, 43.9)
    assert c.tension_pct_rts == pytest.approx(20.0) and os.path.isabs(c.source)
    a = resolve_conductor("aster570")
    assert (a.diameter_m, a.mass_kg_per_m, a.rts_n, a.ej_min_nm2) == (0.03105, 1.571, 185300.0, 28.28)
    assert dataclasses.replace(a, tension_n=1.0).tension_n == 1.0     # frozen, replaceable
