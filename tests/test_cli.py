import argparse

import numpy as np
import pandas as pd
import pytest

from sbcal.cli import main
from sbcal.model.damper import load_damper
from sbcal.model.fem import STANDARD_GRID_HZ
from sbcal.model.reference import dynamic_stiffness_loop

from .test_damper import GOOD


def test_simulate_other_geometry_reproduces_loop(tmp_path):
    toml = tmp_path / "g.toml"
    toml.write_text(GOOD.replace('name = "x"', 'name = "geom"'))
    out = tmp_path / "sim.csv"
    rc = main(["simulate", "--damper", str(toml), "--set", "EJ=14", "--set", "beta1=0.4", "--set", "beta2=0.2",
               "--set", "a1=0.026", "--amplitude", "0.5", "-o", str(out)])
    assert rc == 0
    s = pd.read_csv(out)
    assert list(s.columns) == ["damper", "test", "run", "frequency_hz", "amplitude_mm_pp", "stiffness_n_per_m", "phase_deg"]
    assert len(s) == 37 and (s.damper == "geom").all() and (s.test == "0.5-0.5").all() and (s.run == 1).all()
    assert (s.amplitude_mm_pp == 0.5).all()
    ref = dynamic_stiffness_loop(load_damper(toml), STANDARD_GRID_HZ, EJ=14, beta1=0.4, beta2=0.2, a1=0.026)
    np.testing.assert_allclose(s.stiffness_n_per_m, np.abs(ref), rtol=1e-9)
    np.testing.assert_allclose(s.phase_deg, np.degrees(np.angle(ref)), rtol=1e-9)


def test_simulate_frequency_list_and_test_label(tmp_path):
    out = tmp_path / "s.csv"
    assert main(["simulate", "--damper", "damper2", "--set", "EJ=9", "--set", "beta=0.3",
                 "--frequencies", "5,7.5,33", "--test", "mine", "-o", str(out)]) == 0
    s = pd.read_csv(out)
    assert list(s.frequency_hz) == [5, 7.5, 33] and (s.test == "mine").all() and (s.damper == "damper2").all()


@pytest.mark.parametrize("argv, match", [
    (["--set", "EX=9"], "unknown parameter 'EX'"),
    (["--set", "EJ"], "expected NAME=VALUE"),
    (["--set", "EJ=abc"], "is not a number"),
    (["--frequencies", "4,x"], "--frequencies"),
    (["--frequencies", "4,-1"], "must be finite and > 0"),
    (["--amplitude", "0"], "--amplitude"),
])
def test_simulate_bad_options(tmp_path, capsys, argv, match):
    out = tmp_path / "s.csv"
    rc = main(["simulate", "--damper", "damper1", "-o", str(out)] + argv)
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_simulate_bad_files(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[clamp\n")
    for damper, match in ((str(bad), "invalid TOML"), (str(tmp_path / "missing.toml"), "no such file")):
        rc = main(["simulate", "--damper", damper, "-o", str(tmp_path / "o.csv")])
        err = capsys.readouterr().err
        assert rc == 2 and match in err and str(tmp_path) in err and err.count("\n") == 1
    assert not (tmp_path / "o.csv").exists()


def test_no_command_and_unknown_option(capsys):
    assert main([]) == 2
    assert main(["simulate", "--damper", "damper1", "-o", "x.csv", "--bogus"]) == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments: --bogus" in err and err.count("\n") == 1


def test_unwritable_output_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["simulate", "--damper", "damper1", "-o", str(blocker / "sub" / "s.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and str(blocker) in err and err.count("\n") == 1 and "Traceback" not in err
    rc = main(["report", "--runs", str(tmp_path), "-o", str(blocker / "rep")])
    err = capsys.readouterr().err
    assert rc == 2 and str(blocker) in err and err.count("\n") == 1


@pytest.mark.parametrize("argv, message", [
    (["sample", "--tests", "0.5-0.5", "--seed", "-1"], "sample: argument --seed: expected an integer >= 0, got -1"),
    (["bench", "--damper", "damper1", "--seed", "x", "-o", "b.csv"], "bench: argument --seed: expected an integer >= 0"),
    (["simulate", "--damper", "damper1", "--set", "EJ=-9", "-o", "s.csv"], "--set 'EJ=-9': EJ must be > 0"),
    (["simulate", "--damper", "damper1", "--set", "beta=-0.1", "-o", "s.csv"], "--set 'beta=-0.1': beta must be >= 0"),
])
def test_bad_values_are_one_line_before_any_work(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not any(tmp_path.iterdir())  # nothing written, not even the run store's data.json


def test_help_has_no_doubled_percent_and_errors_name_the_program_once(capsys):
    from sbcal.cli.app import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, parser in sub.choices.items():
        assert "%%" not in parser.format_help(), name
    assert main(["run", "--bogus"]) == 2
    assert capsys.readouterr().err.strip() == "sbcal: error: unrecognized arguments: --bogus"


def test_every_subcommand_spells_the_shared_options_one_way(capsys):
    # one spelling per concept: the run store --runs DIR, the output -o/--output, the seed --seed SEED,
    # --quiet with one meaning; old spellings hidden (deprecated for one release) and still working
    from sbcal.cli.app import build_parser

    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    quiet_help = {a.help for sp in sub.choices.values() for a in sp._actions if "--quiet" in a.option_strings}
    assert len(quiet_help) == 1
    for name, parser in sub.choices.items():
        opts = {o: a for a in parser._actions for o in a.option_strings}
        assert "--quiet" in opts, name
        if "--seed" in opts:
            assert opts["--seed"].metavar == "SEED", name
        for o, a in opts.items():
            if a.dest == "runs" and a.help != argparse.SUPPRESS and name != "bench":  # bench --runs N: runs per test
                assert o == "--runs" and a.metavar == "DIR", (name, o)
            if o == "-o":
                assert a.option_strings == ["-o", "--output"], name
            if a.dest == "tests" and a.help != argparse.SUPPRESS:  # the tests: --tests LABEL [LABEL ...]
                assert o == "--tests" and a.nargs == "+" and a.metavar == "LABEL", (name, o)
    assert main(["sample", "--tests", "9-9", "--out", "nowhere"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "sbcal: warning: --out is deprecated (kept for one release): use --runs" and "9-9" in err[1]
    assert main(["sample", "--test", "0.5-0.5", "--test", "9-9", "--runs", "nowhere"]) == 2  # repeatable, as it was
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "sbcal: warning: --test is deprecated (kept for one release): use --tests" and "9-9" in err[-1]
