"""Where a cable fit starts, and the family screen: which families are worth sampling."""

import numpy as np
import pytest

from sbcal.inference.cable_fit import cable_seed
from sbcal.inference.cable_start import (SCREEN_FLOOR, SCREEN_PER_PARAMETER, FamilyMode, fit_streams,
                                         screen_families)


def _modes(**families):
    """``{law: {state: FamilyMode}}`` from ``law=((log_lik, ndim) per state)``."""
    return {law: {f"s{i}": FamilyMode(z=np.zeros(n), log_lik=ll, ndim=n) for i, (ll, n) in enumerate(states)}
            for law, states in families.items()}


def test_a_family_is_screened_only_beyond_its_margin():
    # two states; iwan5 9 + 9 parameters, bouc_wen 7 + 7: margin 10 nats a parameter of both, 320 nats
    margin = SCREEN_PER_PARAMETER * (18 + 14)
    assert margin == 320.0
    best = (27000.0, 9), (3500.0, 9)
    just_in = _modes(iwan5=best, bouc_wen=((27000.0 - margin + 1.0, 7), (3500.0, 7)))
    just_out = _modes(iwan5=best, bouc_wen=((27000.0 - margin - 1.0, 7), (3500.0, 7)))
    assert screen_families(just_in) == {}
    got = screen_families(just_out)
    assert set(got) == {"bouc_wen"} and got["bouc_wen"]["below"] == "iwan5"
    assert got["bouc_wen"]["log_lik_gap"] == pytest.approx(margin + 1.0) and got["bouc_wen"]["threshold"] == margin
    # the gap is summed over the states: a family behind in one state and ahead in the other is judged on the sum
    traded = _modes(iwan5=best, bouc_wen=((27000.0 - 400.0, 7), (3500.0 + 100.0, 7)))
    assert screen_families(traded) == {}
    # small families: the floor
    small = _modes(a=((100.0, 2),), b=((100.0 - SCREEN_FLOOR + 1.0, 2),))
    assert 10 * 4 < SCREEN_FLOOR and screen_families(small) == {}


def test_a_family_whose_model_fails_is_screened_and_none_when_all_fail():
    got = screen_families(_modes(iwan5=((500.0, 9),), bouc_wen=((-np.inf, 7),)))
    assert set(got) == {"bouc_wen"} and got["bouc_wen"]["log_lik_gap"] is None
    assert screen_families(_modes(iwan5=((-np.inf, 9),), bouc_wen=((-np.inf, 7),))) == {}


def test_the_screen_starts_a_fit_where_the_fit_would_start():
    """The screen's start of a family is made with the fit's own start stream, and asking does not move the
    stream: a kept family's draws are those of the unscreened fit."""
    seed = cable_seed(0, "damper1", "dry", "iwan5")
    a = fit_streams(seed)
    b = fit_streams(seed)
    assert seed.n_children_spawned == 0
    reference = cable_seed(0, "damper1", "dry", "iwan5").spawn(2)  # how a fit split its stream before the screen
    for x, y, r in zip(a, b, reference):
        assert x.spawn_key == y.spawn_key == r.spawn_key
        assert np.array_equal(x.generate_state(4), r.generate_state(4))
    assert not np.array_equal(a[0].generate_state(4), a[1].generate_state(4))


def test_a_family_screened_below_one_that_did_not_converge_is_sampled_after_all(monkeypatch):
    """Measured on the virtual bench (iwan5 cable, 4 amplitudes x 6 runs): iwan5's start was 215 nats above
    Bouc-Wen's, which the screen dropped, and iwan5 did not converge in the cap; without the second round no
    family would have a converged posterior. Here with stand-in fits: the round structure of
    ``fit_damper_cable``."""
    from types import SimpleNamespace

    import sbcal.inference.cable_fit as cable_fit

    lls = {"iwan5": 4052.0, "bouc_wen": 3837.0, "iwan_tail": 3696.0}  # the measured starts (threshold 160-180)
    ndim = {"iwan5": 9, "bouc_wen": 7, "iwan_tail": 9}
    conv = {"iwan5": False, "bouc_wen": True, "iwan_tail": True}
    fitted = []

    def fake_screen(jobs, **_):
        modes = {law: {"dry": FamilyMode(z=np.zeros(ndim[law]), log_lik=lls[law], ndim=ndim[law])} for law in jobs}
        return modes, screen_families(modes)

    def fake_fit(damper, data, members, law, *, start, **_):
        fitted.append(law)
        assert start.shape == (ndim[law],)  # each fit starts where the screen found its start
        pointwise = np.full(24, lls[law] / 24)
        return cable_fit.CableFit(damper="d", state="dry", law=law, tests=tuple(members), effects=(), like=None,
                                  result=SimpleNamespace(converged=conv[law]), loo=SimpleNamespace(pointwise=pointwise))

    monkeypatch.setattr(cable_fit, "screen", fake_screen)
    monkeypatch.setattr(cable_fit, "cable_likelihood", lambda *a, **k: None)
    monkeypatch.setattr(cable_fit, "fit_cable", fake_fit)
    data = SimpleNamespace(tests=lambda name: ["0.2-0.2", "0.5-0.5", "1-1", "2-2"])
    fits, comparison = cable_fit.fit_damper_cable(SimpleNamespace(name="d"), data, laws=tuple(lls), progress=False)
    # round 1: iwan5 alone (the others 215 and 356 nats below); it did not converge, so round 2 screens the
    # other two against each other (141 < 160 nats apart: both kept)
    assert fitted == ["iwan5", "bouc_wen", "iwan_tail"]
    assert comparison["best"] == "bouc_wen" and comparison["converged"] and comparison["screened"] == {}
    assert comparison["higher_not_converged"] == ["iwan5"]
    # had iwan5 converged, one round, the other two never sampled
    conv["iwan5"], fitted[:] = True, []
    fits, comparison = cable_fit.fit_damper_cable(SimpleNamespace(name="d"), data, laws=tuple(lls), progress=False)
    assert fitted == ["iwan5"] and set(comparison["screened"]) == {"bouc_wen", "iwan_tail"}


def test_the_diagnosis_fits_a_screened_law_when_the_one_above_did_not_converge():
    from types import SimpleNamespace

    from sbcal.diagnosis.fits import choose_law, late_laws

    def record(law, ll, converged, screened=None):
        return {"result": SimpleNamespace(converged=converged), "like": None, "law": law, "screened": screened,
                "loo": SimpleNamespace(pointwise=np.full(24, ll / 24))}

    first = {"bouc_wen": {"log_lik_gap": 215.0, "threshold": 160.0, "below": "iwan5"}}
    fits = {("baseline", "1-1"): {}, ("strand_slip", "dry", "iwan5"): record("iwan5", 4052.0, False, first)}
    assert late_laws(fits, "strand_slip") == ("bouc_wen",)
    _, comparison = choose_law(fits, "strand_slip")
    assert comparison["screened"] == first and not comparison["converged"]
    fits[("strand_slip", "dry", "bouc_wen")] = record("bouc_wen", 3837.0, True, {})
    assert late_laws(fits, "strand_slip") == ()
    kept, comparison = choose_law(fits, "strand_slip")
    assert comparison["best"] == "bouc_wen" and comparison["screened"] == {} and set(kept) == {("strand_slip", "dry")}
    # converged above it: nothing more to fit
    fits = {("strand_slip", "dry", "iwan5"): record("iwan5", 4052.0, True, first)}
    assert late_laws(fits, "strand_slip") == ()
