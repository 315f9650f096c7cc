import pytest

from sbcal import InputError, load_damper
from sbcal.model.damper import bundled_dampers, resolve_damper

GOOD = """
name = "x"
[clamp]
mass_kg = 1.0
inertia_kg_m2 = 0.001
[mass1]
mass_kg = 2.5
inertia_kg_m2 = 0.01
offset_m = 0.025
[mass2]
mass_kg = 2.0
inertia_kg_m2 = 0.008
offset_m = -0.015
[cable]
length1_m = 0.18
length2_m = 0.14
linear_density_kg_m = 0.5
ej_static_nm2 = 100.0
"""


def write(tmp_path, text):
    p = tmp_path / "d.toml"
    p.write_text(text)
    return p


def test_bundled_dampers_load():
    assert {"damper1", "damper2"} <= set(bundled_dampers())
    d = resolve_damper("damper1")
    assert d.name == "damper1"
    assert (d.m1, d.J1, d.a1, d.a2, d.ej_static) == (3.1005, 0.0163, 0.0283, -0.0154, 113.0)


def test_good_file_with_extra_keys_and_defaults(tmp_path):
    d = load_damper(write(tmp_path, GOOD + "\n[extra]\nfoo = 'bar'\n"))
    assert d.name == "x" and d.ac == 0.0 and d.mu == 0.5 and d.L1 == 0.18
    assert d.total_mass == pytest.approx(1.0 + 2.5 + 2.0 + 0.5 * 0.32)


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace('name = "x"\n', ""), r"key 'name': missing"),
    (lambda t: t.replace("length2_m = 0.14\n", ""), r"key 'cable.length2_m': missing"),
    (lambda t: t.replace("mass_kg = 2.5", 'mass_kg = "heavy"'), r"key 'mass1.mass_kg': expected a number"),
    (lambda t: t.replace("mass_kg = 2.5", "mass_kg = true"), r"key 'mass1.mass_kg': expected a number"),
    (lambda t: t.replace("mass_kg = 2.0", "mass_kg = 0.0"), r"key 'mass2.mass_kg': must be > 0"),
    (lambda t: t.replace("length1_m = 0.18", "length1_m = -0.18"), r"key 'cable.length1_m': must be > 0"),
    (lambda t: t.replace("linear_density_kg_m = 0.5", "linear_density_kg_m = -0.5"), r"linear_density_kg_m': must be >= 0"),
    (lambda t: t.replace("ej_static_nm2 = 100.0", "ej_static_nm2 = nan"), r"ej_static_nm2': value nan is not finite"),
    (lambda t: t.replace("[clamp]\nmass_kg = 1.0\ninertia_kg_m2 = 0.001\n", ""), r"table '\[clamp\]': missing"),
    (lambda t: t.replace("[cable]", "[cable\n"), r"invalid TOML"),
])
def test_rejections_name_file_and_key(tmp_path, edit, match):
    p = write(tmp_path, edit(GOOD))
    with pytest.raises(InputError, match=match) as e:
        load_damper(p)
    msg = str(e.value)
    assert str(p) in msg and "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_damper(tmp_path / "nope.toml")
    with pytest.raises(InputError, match="neither a bundled damper"):
        resolve_damper("damper9")
