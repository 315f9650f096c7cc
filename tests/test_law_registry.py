"""A hysteresis law is one file: ``tests/toy_law.py`` (one Jenkins element, registered by its decorator)
reaches the prior, ``sbcal cable``, the virtual bench, the time-domain and multi-harmonic cable, and the
diagnosis's units with no other file touched; the registry refuses a law that would break them."""

import importlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from sbcal.core.errors import InputError
from sbcal.model.damper import resolve_damper
from sbcal.model.laws import LAWS, ZonedLaw, aliases, fitted_laws, law_for, parameter_units, register
from sbcal.model.laws.base import DELTA_EJ, HysteresisLaw, LawParameter

ROOT = Path(__file__).resolve().parents[1]
TOY = {"delta_EJ": 50.0, "chi_stick": 2e-3}


@pytest.fixture
def toy():
    """The toy law's module imported (its decorator registers it); the registry as it was afterwards."""
    saved = dict(LAWS)
    sys.modules.pop("tests.toy_law", None)
    try:
        yield importlib.import_module("tests.toy_law").JenkinsLaw
    finally:
        LAWS.clear()
        LAWS.update(saved)
        sys.modules.pop("tests.toy_law", None)


def test_the_bundled_laws_and_what_they_state():
    assert fitted_laws() == ("bouc_wen", "iwan5", "iwan_tail")
    assert aliases() == {"dahl": "bouc_wen", "iwan": "iwan5"}
    assert "jenkins" not in LAWS  # the toy only inside its fixture
    for law in LAWS.values():
        assert law.scale in law().parameter_names and parameter_units()[law.scale] == "1/m"
        if law.fitted:
            assert all(p.prior for p in law.parameters), law.name


def test_a_law_in_one_file_reaches_every_command(toy, capsys):
    from sbcal.cli import build_parser, main
    from sbcal.diagnosis.words import _unit
    from sbcal.inference.priors import cable_prior

    assert "jenkins" in fitted_laws() and isinstance(law_for("jenkins"), toy)
    assert isinstance(law_for("jenkins_zoned"), ZonedLaw)
    # the prior: the cable's and the law's own box
    d = resolve_damper("damper1")
    prior = cable_prior("jenkins", d)
    assert set(prior.names) == {"a1", "a2", "EJ_min", "beta_material", "delta_EJ", "chi_stick"}
    assert prior.box("chi_stick") == (True, 1e-5, 1.0)
    assert prior.box("delta_EJ") == pytest.approx((True, 0.02 * d.ej_static, d.ej_static))
    assert {"clamp_zone", "mass_moment_ratio", "chi_stick"} <= set(cable_prior("jenkins_zoned", d).names)
    # the command line: a choice with its summary in the help
    args = build_parser().parse_args(["cable", "--damper", "damper1", "--law", "jenkins"])
    assert args.law == "jenkins"
    with pytest.raises(SystemExit):
        main(["cable", "--help"])
    assert "jenkins (one Jenkins element, a sharp knee)" in " ".join(capsys.readouterr().out.split())
    # the words' units
    assert parameter_units()["chi_stick"] == "1/m" and _unit("chi_stick") == "1/m"


def test_the_toy_law_on_the_virtual_bench_and_in_time(toy):
    from sbcal.model.laws.steppers import drive, law_stepper
    from sbcal.simulate.effects import SlipLaw, parse_effect
    from sbcal.simulate.virtual_bench import response

    law = toy()
    # the bench: its scale is the value, delta_EJ the stuck cable's share as every law's
    assert parse_effect("strand_slip=law:jenkins,chi_stick:0.002") == (
        "strand_slip", SlipLaw(law="jenkins", params=(("chi_stick", 0.002),)))
    d = resolve_damper("damper1")
    f = np.linspace(8.0, 40.0, 9)
    slip = SlipLaw(law="jenkins", params=(("chi_stick", 2e-3),), elements=6)
    low, high = (response(d, f, a, {"EJ": 9.0, "beta": 0.1}, {"strand_slip": slip})[0] for a in (0.05, 2.0))
    assert np.max(np.abs(high / low - 1)) > 0.05  # the wires slip at 2 mm, not at 0.05 mm
    with pytest.raises(InputError, match="chi_stick is required"):
        SlipLaw(law="jenkins")
    # the describing function is the first harmonic of the law's own loop (a quadrature of 20 000 points:
    # its error ~1e-8 of delta_EJ at the loop's corners)
    theta = np.linspace(0.0, 2 * np.pi, 20001)[:-1]
    for chi_a in (1e-3, 5e-3, 0.1):
        m = law.steady_loop(chi_a, theta, **TOY)
        first = 2 * np.mean(m * np.exp(-1j * theta)) / chi_a
        assert abs(complex(law.slip_rigidity(chi_a, **TOY)) - first) < 1e-6 * TOY["delta_EJ"]
    # the time stepper (a Jenkins population from the backbone) runs the same loop
    kappa = 5e-3 * np.cos(np.linspace(0.0, 4 * np.pi, 4001))
    got = drive(law_stepper(law, TOY, size=1), kappa[:, None])[2000:, 0]
    np.testing.assert_allclose(got, law.steady_loop(5e-3, np.linspace(0.0, 4 * np.pi, 4001)[2000:], **TOY),
                               atol=1e-9 * TOY["delta_EJ"] * 5e-3)
    # the multi-harmonic solve's branch (Masing's rule on the backbone)
    chi = np.linspace(5e-3, -5e-3, 11)
    m, _, _ = law.loop_branch(chi, 5e-3, **TOY)
    np.testing.assert_allclose(m, law.steady_loop(5e-3, np.arccos(chi / 5e-3), **TOY), atol=1e-12)


def test_a_prior_file_overrides_a_law_box(toy, tmp_path):
    from importlib import resources

    from sbcal.inference.priors import cable_prior

    text = (resources.files("sbcal") / "priors" / "cable.toml").read_text()
    path = tmp_path / "cable.toml"
    path.write_text(text + '\n[jenkins.parameters.chi_stick]\ndist = "loguniform"\nlower = 1e-4\nupper = 0.1\n')
    assert cable_prior("jenkins", resolve_damper("damper1"), path=path).box("chi_stick") == (True, 1e-4, 0.1)
    path.write_text(text + '\n[jenkins.parameters.chi_slip]\ndist = "loguniform"\nlower = 1e-4\nupper = 0.1\n')
    with pytest.raises(InputError, match=r"cable.toml: key 'jenkins.parameters.chi_slip': not a parameter of the "
                                         r"jenkins law \(delta_EJ, chi_stick\)"):
        cable_prior("jenkins", resolve_damper("damper1"), path=path)


def test_the_docs_show_the_toy_law_as_tested():
    from .test_docs_examples import PYTHON

    toy = (ROOT / "tests" / "toy_law.py").read_text(encoding="utf-8")
    assert any(page == "cable.md" and text == toy for page, _, _, text, _ in PYTHON)


def _law(**attrs):
    body = {"__annotations__": {k: ClassVar for k in attrs}, **attrs}
    return dataclass(frozen=True)(type("Bad", (HysteresisLaw,), body))


SCALE = LawParameter("chi_x", "1/m", "a slip curvature", prior=("loguniform", 1e-5, 1.0))


@pytest.mark.parametrize("attrs, words", [
    ({"name": "x", "parameters": (DELTA_EJ, SCALE)}, "scale"),
    ({"name": "x", "parameters": (SCALE,), "scale": "chi_x"}, "delta_EJ"),
    ({"name": "iwan5", "parameters": (DELTA_EJ, SCALE), "scale": "chi_x"}, "taken by Iwan5Law"),
    ({"name": "x_zoned", "parameters": (DELTA_EJ, SCALE), "scale": "chi_x"}, "must be an identifier"),
    ({"name": "x", "parameters": (DELTA_EJ, SCALE, LawParameter("n", "1", "a shape")), "scale": "chi_x"}, "typical"),
    ({"name": "x", "parameters": (DELTA_EJ, LawParameter("chi_x", "1/m", "no box")), "scale": "chi_x",
      "fitted": True}, "no prior box"),
    ({"name": "x", "parameters": (DELTA_EJ, LawParameter("chi_x", "1/m", "", prior=("loguniform", 0.0, 1.0))),
      "scale": "chi_x"}, "prior must be"),
    ({"name": "x", "parameters": (DELTA_EJ, LawParameter("EJ_min", "1/m", "")), "scale": "EJ_min"}, "the cable's"),
])
def test_the_registry_refuses_a_law_that_would_break_a_command(attrs, words):
    before = dict(LAWS)
    with pytest.raises(TypeError, match=words):
        register(_law(**attrs))
    assert LAWS == before


@pytest.mark.long
def test_sbcal_cable_fits_the_toy_law_and_finds_its_slip_curvature(toy, tmp_path):
    """End to end: recordings of a damper whose cable is one Jenkins element (the fit's own cable model, 8
    runs of three amplitudes with 2 % noise), fitted by ``sbcal cable --law jenkins``: converged, and each
    cable parameter's posterior mean within 3.3 posterior sd of the truth (a calibrated posterior's
    z-score is about standard normal: a miss has probability 0.1 % per parameter, 0.4 % for the four).
    Measured: z = 2.5, 0.1, 2.4, -2.6 (EJ_min, beta_material, delta_EJ, chi_stick; delta_EJ and chi_stick
    trade along the slip moment, their product within 0.3 %); seeds 6-8 gave |z| <= 1.4."""
    import pandas as pd

    from sbcal.cli import main
    from sbcal.data.bench import curves_to_frame, write_bench
    from sbcal.inference.cable_fit import read_cable
    from sbcal.model.cable import CableModel
    from sbcal.model.fem import STANDARD_GRID_HZ

    d = resolve_damper("damper1")
    truth = {"EJ_min": 6.0, "beta_material": 0.08, "delta_EJ": 40.0, "chi_stick": 3e-3}
    model = CableModel(law_for("jenkins"))
    rng = np.random.default_rng(5)
    frames = []
    for test in ("0.5-0.5", "1-1", "2-2"):
        a = float(test.split("-")[0])
        fuu = model.dynamic_stiffness(d, STANDARD_GRID_HZ, a, **truth)[0]
        noise = 0.02 * (rng.standard_normal((8, fuu.size)) + 1j * rng.standard_normal((8, fuu.size)))
        frames.append(curves_to_frame(d.name, test, STANDARD_GRID_HZ, a, fuu[None] * np.exp(noise)))
    write_bench(pd.concat(frames, ignore_index=True), tmp_path / "bench.csv")
    assert main(["cable", "--damper", "damper1", "--bench", str(tmp_path / "bench.csv"), "--law", "jenkins",
                 "--runs", str(tmp_path / "runs"), "--seed", "2", "--workers", "1", "--quiet"]) == 0
    summary, draws = read_cable(tmp_path / "runs" / "damper1" / "cable-dry")
    assert summary["law"] == "jenkins" and summary["converged"], summary
    z = {n: (np.mean(draws[n]) - v) / np.std(draws[n]) for n, v in truth.items()}
    assert all(abs(v) < 3.3 for v in z.values()), z
    # the slip moment the wires hold (delta_EJ chi_stick), which the bench pins, within 2 %
    moment = np.median(draws["delta_EJ"] * draws["chi_stick"])
    assert abs(moment / (truth["delta_EJ"] * truth["chi_stick"]) - 1) < 0.02, moment
