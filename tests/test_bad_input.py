"""Every door refuses bad input the same way: exit 2, one line naming the file and key (or option) and
the problem, no traceback, nothing written. One row per case, each input kind at least once."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sbcal.cli import main
from sbcal.data.readers import default_bench_path

ROOT = Path(__file__).resolve().parents[1] / "sbcal"


def _damper(**replace):
    """The bundled damper1 file with lines replaced: {"old line start": "new line"}."""
    lines = (ROOT / "models" / "damper1.toml").read_text().splitlines()
    for old, new in replace.items():
        lines = [new if ln.startswith(old) else ln for ln in lines]
    return "\n".join(lines) + "\n"


_FIRST_MASS1 = {"mass_kg = 3.1005": "mass_g = 3100"}


def _bench(change):
    """A bench CSV: test 1-1 of the bundled damper1, changed by ``change(frame)``."""
    b = pd.read_csv(default_bench_path())
    b = b[(b.damper == "damper1") & (b.test == "1-1")].reset_index(drop=True)
    return change(b).to_csv(index=False)


def _set(col, f):
    return lambda b: b.assign(**{col: f(b[col])})


def _duplicate_first_line(b):
    f = b["frequency_hz"].to_numpy().copy()
    f[1] = f[0]
    return b.assign(frequency_hz=f)


def _text_at_line_5(b):
    s = b["stiffness_n_per_m"].astype(object)
    s.iloc[3] = "n/a"
    return b.assign(stiffness_n_per_m=s)


def _conductor(**replace):
    lines = (ROOT / "conductors" / "drake.toml").read_text().splitlines()
    for old, new in replace.items():
        lines = [new if ln.startswith(old) else ln for ln in lines]
    return "\n".join(lines) + "\n"


_SPEC = ('name = "mine"\n[excitation]\namplitude_mm_pp = 1.0\nfrequency_hz = [5.0, 30.0]\n'
         '[tolerance]\nresonance_frequency_pct = 5.0\n')

_PRIORS = (ROOT / "priors" / "default.toml").read_text()

DATA = ["data", "--bench", "bench.csv"]
SIM = ["simulate", "--damper", "d.toml", "-o", "out.csv"]
SPAN = ["span", "--conductor", "c.toml", "--damper", "none", "-o", "span-out"]

# (id, files {name: text}, argv, what the line must say)
CASES = [
    # damper TOML (formats.md 1)
    ("damper-unknown-unit-key", {"d.toml": _damper(**_FIRST_MASS1)}, SIM, "'mass1.mass_kg': missing (the file has 'mass1.mass_g')"),
    ("damper-arm-in-mm", {"d.toml": _damper(**{"length1_m": "length1_m = 200"})}, SIM, "200 m is outside"),
    ("damper-offset-in-mm", {"d.toml": _damper(**{"offset_m = 0.0283": "offset_m = 28.3"})}, SIM, "'mass1.offset_m': 28.3 m"),
    ("damper-mass-in-g", {"d.toml": _damper(**{"mass_kg = 3.1005": "mass_kg = 3100.5"})}, SIM, "'mass1.mass_kg': 3100.5 kg"),
    ("damper-text-number", {"d.toml": _damper(**{"mass_kg = 3.1005": 'mass_kg = "3.1"'})}, SIM, "expected a number"),
    ("damper-negative-inertia", {"d.toml": _damper(**{"inertia_kg_m2 = 0.0163": "inertia_kg_m2 = -1"})}, SIM, "must be >= 0"),
    ("damper-no-name", {"d.toml": _damper(**{"name =": "# no name"})}, SIM, "key 'name': missing"),
    ("damper-bad-toml", {"d.toml": "name = 'x'\n[clamp\n"}, SIM, "invalid TOML"),
    ("damper-missing-file", {}, SIM, "d.toml: no such file"),
    ("damper-tolerance-key", {"d.toml": _damper() + "[tolerance]\n\"cable.ej_static_nm2\" = 5\n"}, SIM, "tolerance.cable.ej_static_nm2"),
    ("damper-tolerance-100", {"d.toml": _damper() + "[tolerance]\n\"mass1.offset_m\" = 100\n"}, SIM, "below 100"),
    # bench CSV (formats.md 2)
    ("bench-amplitude-in-m", {"bench.csv": _bench(_set("amplitude_mm_pp", lambda x: x / 1e3))}, DATA, "metres typed as millimetres"),
    ("bench-phase-in-rad", {"bench.csv": _bench(_set("phase_deg", np.radians))}, DATA, "radians?"),
    ("bench-stiffness-in-kn", {"bench.csv": _bench(_set("stiffness_n_per_m", lambda x: x / 1e3))}, DATA, "kN/m or N/mm"),
    ("bench-missing-column", {"bench.csv": _bench(lambda b: b.drop(columns="phase_deg"))}, DATA, "missing column 'phase_deg'"),
    ("bench-text-value", {"bench.csv": _bench(_text_at_line_5)}, DATA, "line 5: column 'stiffness_n_per_m'"),
    ("bench-negative-frequency", {"bench.csv": _bench(_set("frequency_hz", lambda x: -x))}, DATA, "column 'frequency_hz'"),
    ("bench-run-not-integer", {"bench.csv": _bench(_set("run", lambda x: x + 0.5))}, DATA, "column 'run'"),
    ("bench-duplicate-row", {"bench.csv": _bench(_duplicate_first_line)}, DATA, "duplicate of line 2"),
    ("bench-empty", {"bench.csv": ""}, DATA, "bench.csv"),
    ("bench-missing", {}, DATA, "bench.csv: no such file"),
    # conductor TOML
    ("conductor-negative-diameter", {"c.toml": _conductor(**{"diameter_m = 0.028": "diameter_m = -0.028"})}, SPAN, "diameter_m"),
    ("conductor-text", {"c.toml": _conductor(**{"rts_n": 'rts_n = "high"'})}, SPAN, "rts_n"),
    ("conductor-unknown-preset", {"c.toml": _conductor(**{"preset =": 'preset = "nobody"'})}, SPAN, "preset"),
    ("conductor-unknown-key", {"c.toml": _conductor(**{"span_length_m": "span_lenght_m = 400.0"})}, SPAN, "span_l"),
    # acceptance TOML (sbcal compare --spec)
    ("spec-tolerance-zero", {"a.toml": _SPEC.replace("resonance_frequency_pct = 5.0", "resonance_frequency_pct = 0")},
     ["compare", "--before", "runs/damper1", "--after", "runs/damper1@oiled", "--spec", "a.toml"], "a.toml"),
    ("spec-unknown-key", {"a.toml": _SPEC + "resonance_freq_pct = 5\n"},
     ["compare", "--before", "runs/damper1", "--after", "runs/damper1@oiled", "--spec", "a.toml"], "resonance_freq_pct"),
    # priors TOML (sbcal sample --prior)
    ("prior-renamed-parameter", {"p.toml": _PRIORS.replace("[parameters.EJ]", "[parameters.EX]", 1)},
     ["sample", "--tests", "0.5-0.5", "--priors", "p.toml", "--runs", "r"], "'parameters.EJ': missing (used by set 'theta1')"),
    ("prior-bad-dist", {"p.toml": _PRIORS.replace('dist = "uniform"', 'dist = "unifrom"', 1)},
     ["sample", "--tests", "0.5-0.5", "--priors", "p.toml", "--runs", "r"], "expected one of uniform, loguniform"),
    ("prior-bad-toml", {"p.toml": "[EJ\n"}, ["sample", "--tests", "0.5-0.5", "--priors", "p.toml", "--runs", "r"], "invalid TOML"),
    # design space TOML
    ("space-unknown-key", {"s.toml": '[vary]\n"mass1.mass_g" = [1.0, 3.0]\n'},
     ["design", "--conductor", "drake", "--cable", "runs/damper1/cable-dry", "--damper", "damper1", "--space", "s.toml"], "mass1.mass_g"),
    # options
    ("seed-negative", {}, ["sample", "--tests", "0.5-0.5", "--seed", "-1"], "--seed: expected an integer >= 0"),
    ("seed-text", {}, ["bench", "--damper", "damper1", "--seed", "x", "-o", "b.csv"], "--seed: expected an integer >= 0"),
    ("set-negative-ej", {}, ["simulate", "--damper", "damper1", "--set", "EJ=-9", "-o", "s.csv"], "EJ must be > 0"),
    ("set-negative-beta", {}, ["simulate", "--damper", "damper1", "--set", "beta=-0.1", "-o", "s.csv"], "beta must be >= 0"),
    ("set-unknown-parameter", {}, ["simulate", "--damper", "damper1", "--set", "EX=9", "-o", "s.csv"], "unknown parameter 'EX'"),
    ("set-not-a-number", {}, ["simulate", "--damper", "damper1", "--set", "EJ=abc", "-o", "s.csv"], "is not a number"),
    ("set-offset-in-mm", {}, ["simulate", "--damper", "damper1", "--set", "a1=28.3", "-o", "s.csv"],
     "28.3 m is outside -0.5 to 0.5 m, the plausible range for an offset"),
    ("set-mass-in-g", {}, ["simulate", "--damper", "damper1", "--set", "m2=850", "-o", "s.csv"],
     "850 kg is outside 0.02 to 50 kg"),
    ("frequencies-text", {}, ["simulate", "--damper", "damper1", "--frequencies", "4,x", "-o", "s.csv"], "--frequencies"),
    ("amplitude-zero", {}, ["simulate", "--damper", "damper1", "--amplitude", "0", "-o", "s.csv"], "--amplitude"),
    ("unknown-option", {}, ["run", "--bogus"], "unrecognized arguments: --bogus"),
    ("unknown-law", {}, ["cable", "--law", "nolaw"], "--law"),
    ("map-negative-table", {"t.csv": "amplitude_mm_pp,EJ,beta\n0.5,-5.0,0.1\n1.0,6.0,0.1\n"},
     ["map", "--table", "t.csv", "--json", "m.json"], "t.csv"),
    # run stores
    ("compare-missing-run", {}, ["compare", "--before", "runs/nothing", "--after", "runs/nothing@oiled"], "runs/nothing"),
    ("batch-missing-store", {}, ["batch", "--runs", "lot-runs"], "lot-runs"),
    ("predict-missing-cable", {}, ["predict", "--cable", "runs/damper1/cable-dry", "--damper", "damper1"], "cable-dry"),
    ("span-missing-cable", {}, ["span", "--conductor", "drake", "--damper", "runs/damper1/cable-dry"], "cable-dry"),
    # raw DAQ files (sbcal import)
    ("import-empty-csv", {"r.csv": "", "m.toml": (Path(__file__).resolve().parents[1] / "docs" / "import.md").read_text().split("```toml\n")[1].split("```")[0]}, ["import", "r.csv", "--map", "m.toml", "-o", "b.csv"], "r.csv"),
]


@pytest.mark.parametrize("files, argv, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, monkeypatch, capsys, files, argv, message):
    monkeypatch.chdir(tmp_path)
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("sbcal") and "Traceback" not in err, err
    assert message in err, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing written


def test_the_table_covers_forty_cases_and_every_input_kind():
    kinds = {c[0].split("-")[0] for c in CASES}
    assert len(CASES) >= 40
    assert {"damper", "bench", "conductor", "spec", "prior", "space", "seed", "set", "import"} <= kinds


def test_a_close_unknown_damper_key_is_one_warning_and_the_run_goes_on(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "d.toml").write_text(_damper(**{"length2_m": "length2_m = 0.15\nlenght2_m = 3"}))
    assert main(SIM) == 0
    err = capsys.readouterr().err
    assert err == "sbcal: warning: d.toml: key 'cable.lenght2_m': unknown, ignored; did you mean 'cable.length2_m'?\n"
