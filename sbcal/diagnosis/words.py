"""The fitted effect's parameters: medians and intervals, per-test estimates of shared values (widened by
their Birge ratio where they disagree), and the sentence that says what was found."""

from __future__ import annotations

import string

import numpy as np

from ..inference.likelihood import JointLikelihood
from ..model.laws import parameter_units


__all__ = ["effect_parameters"]

# --- parameters in words -------------------------------------------------------------------------

def _quantiles(v) -> dict:
    q = np.quantile(v, [0.05, 0.5, 0.95])
    return {"median": float(q[1]), "q05": float(q[0]), "q95": float(q[2])}


_UNITS = {"EJ_min": "N m^2", "beta_material": "1", "fixture_mass_kg": "kg", "delay_s": "s", "beta_viscous": "1",
          "beta1": "1", "beta2": "1",
          "rocking_rad_per_m": "rad/m", "ej_exponent": "1", "EJ": "N m^2", "beta": "1", "a1": "m", "a2": "m"}


def _unit(name: str) -> str:
    """A parameter's SI unit: a law's or a zone's as its law states it (:func:`sbcal.model.laws.parameter_units`),
    else the cable's, the extensions' and the FE model's ("" when unknown)."""
    return parameter_units().get(name) or _UNITS.get(name, "")


def _scale_factor(estimates, se) -> float:
    """The Birge ratio of estimates of one value: ``sqrt(chi2 / (K - 1))`` about their precision-weighted
    mean (1 for one estimate). Above 1 they disagree beyond their errors; the Particle Data Group then
    widens the combined error by it, as :func:`_combined` and :func:`effect_parameters` do."""
    m, s = np.asarray(estimates, float), np.maximum(np.asarray(se, float), 1e-300)
    if m.size < 2:
        return 1.0
    w = 1 / s ** 2
    mean = np.sum(w * m) / np.sum(w)
    return float(np.sqrt(np.sum(w * (m - mean) ** 2) / (m.size - 1)))


def _combined(per_test: dict) -> dict:
    """Precision-weighted combination of per-test (or per-cable-state) posteriors (normal
    approximation), its error widened by their :func:`_scale_factor` where they disagree."""
    m = np.array([v["mean"] for v in per_test.values()])
    s = np.array([max(v["sd"], 1e-300) for v in per_test.values()])
    w = 1 / s ** 2
    factor = _scale_factor(m, s)
    mean, sd = float(np.sum(w * m) / np.sum(w)), float(max(1.0, factor) / np.sqrt(np.sum(w)))
    return {"median": mean, "q05": mean - 1.645 * sd, "q95": mean + 1.645 * sd, "scale_factor": factor}


def _test_estimates(fit: dict, name: str, tests) -> dict:
    """Each test's own estimate of a value a joint fit shares between them: one Gauss-Newton step
    from the posterior median on that test's run means alone (the other parameters held), with its
    noise-only standard error; ``{test: (estimate, se)}`` for the fit's ``tests`` (in its order)."""
    like = fit["like"]
    med = {n: np.atleast_1d(np.median(v)) for n, v in fit["params"].items()}
    _, lo, hi = like.prior.box(name)
    h = 1e-6 * (hi - lo)
    h = h if med[name][0] + h <= hi else -h
    base, moved = like.predict(med), like.predict(dict(med, **{name: med[name] + h}))
    out = {}
    for t, lk, a, b in zip(tests, like.likes, base, moved):
        r = lk.residual(a)[:, 0]
        jac = (r - lk.residual(b)[:, 0]) / h  # d(model)/d(value), phase wrapped by residual()
        w = lk.n / lk.sigma ** 2  # 1 / variance of a run mean
        info = float(np.sum(w * jac ** 2))
        if info > 0:  # a test the value does not move says nothing about it
            out[t] = (float(med[name][0] + np.sum(w * jac * r) / info), float(1 / np.sqrt(info)))
    return out


def effect_parameters(effect: str, fits: dict, keys, baseline_names, *, each_test: bool = False) -> dict:
    """The extension's own parameters with 90 % intervals, and what they mean on the bench.

    A value shared by several tests or cable states comes with its ``scale_factor``
    (:func:`_scale_factor` of the tests' or states' own estimates, the tests' own with ``each_test``;
    in ``values`` the largest applied): where it exceeds 1 the interval is widened by it about the
    combined value, so that a model that fits some tests worse than others does not give a value more
    precisely than the tests agree on it."""
    own = [n for n in fits[keys[0]]["names"] if n not in baseline_names]
    out = {"effect": effect, "values": {}, "per_test": {}}
    if effect.split("+")[0] == "strand_slip":
        out["per_group"] = {}
        for key in keys:  # one parameter set per cable state; "values" is the state with the most tests
            fit = fits[key]
            out["per_group"][key[1]] = {n: dict(_quantiles(fit["params"][n]), unit=_unit(n)) for n in own}
        main = max(keys, key=lambda k: len(fits[k]["mu_mean"]))
        out["values"] = out["per_group"][main[1]]
        out["law"] = fits[main]["law"]
        out["words"] = "; ".join(f"{g} cable: " + _words(effect, v, fits[(keys[0][0], g)]["law"])
                                 for g, v in out["per_group"].items())
        return out
    for n in own:
        per = {}
        for key in keys:
            v = fits[key]["params"][n]
            per[key[1]] = {"mean": float(v.mean()), "sd": float(v.std()), **_quantiles(v)}
            if each_test and isinstance(fits[key]["like"], JointLikelihood):
                # one value for a cable state's tests: do the tests, each on its own, agree on it?
                own_est = _test_estimates(fits[key], n, fits[key]["tests"])
                factor = _scale_factor(*zip(*own_est.values()))
                per[key[1]].update(sd=per[key[1]]["sd"] * max(1.0, factor), scale_factor=factor,
                                   tests={t: e for t, (e, _) in own_est.items()})
        combined = _combined(per)
        # the largest factor applied: between the states', or within a state between its tests
        combined["scale_factor"] = max([combined["scale_factor"]] + [v.get("scale_factor", 1.0) for v in per.values()])
        out["values"][n] = dict(combined, unit=_unit(n))
        for t, v in per.items():
            out["per_test"].setdefault(t, {})[n] = {k: v[k] for k in ("median", "q05", "q95", "scale_factor", "tests")
                                                    if k in v}
    out["words"] = _words(effect, out["values"])
    return out


# Each effect's finding in words; a {name} field is that parameter's median and 90 % interval in the unit
# the sentence gives. strand_slip's is made in _words: it names its law and the stuck EJ.
_FINDINGS = {
    "sensor_delay": "phase lags grow linearly with frequency: a {delay_s} ms delay between the force and "
                    "displacement channels (90 % interval)",
    "fixture_mass": "the stiffness drops by omega^2 times {fixture_mass_kg} g: a mass on the table that the "
                    "empty-table calibration did not cancel",
    "viscous_damping": "the loss factor grows with frequency: a viscous part of {beta_viscous} at 10 Hz "
                       "(proportional to f) on top of the hysteretic one",
    "asymmetric_damping": "the arms damp differently: loss factor {beta1} on arm 1 (mass 1), {beta2} on arm 2",
    "base_rocking": "the table rotates as it moves: {rocking_rad_per_m} mrad of tilt per mm of vertical motion",
    "frequency_dependent_stiffness": "the cable's EJ changes with frequency as (f / 10 Hz)^s, s = {ej_exponent}: "
                                     "a viscoelastic cable",
}
# Parameters said in another unit than they are fitted in (ms, g): (factor, format).
_SHOWN_IN = {"delay_s": (1e3, "{:.3g}"), "fixture_mass_kg": (1e3, "{:.0f}")}


def _words(effect: str, v: dict, law: str = "") -> str:
    def iv(name):
        scale, fmt = _SHOWN_IN.get(name, (1.0, "{:.3g}"))
        d = v[name]
        wide = (f" (widened {d['scale_factor']:.1f}x: the tests' own estimates disagree beyond their noise)"
                if d.get("scale_factor", 1.0) > 1 else "")
        return (f"{fmt.format(d['median'] * scale)} [{fmt.format(d['q05'] * scale)}, "
                f"{fmt.format(d['q95'] * scale)}]{wide}")
    parts = []
    for e in effect.split("+"):
        if e == "strand_slip":
            stuck = {k: v["EJ_min"][k] + v["delta_EJ"][k] for k in ("median", "q05", "q95")}
            parts.append(f"the cable's wires slip with curvature ({law} law, one law for every amplitude): EJ "
                         f"{stuck['median']:.3g} N m^2 when stuck, falling towards {iv('EJ_min')} N m^2 in full slip, "
                         f"with friction loss on top of the loss factor {iv('beta_material')} of the strand itself")
        elif e in _FINDINGS:
            text = _FINDINGS[e]
            parts.append(text.format(**{n: iv(n) for _, n, _, _ in string.Formatter().parse(text) if n}))
    return "; ".join(parts)
