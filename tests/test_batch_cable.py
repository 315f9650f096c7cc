"""``sbcal batch`` over the units' cable fits: the design's cable law as a population, and the cable run
of its next unit that ``sbcal predict`` reads (docs/batch.md, "The design's cable law").

The units' stored cable posteriors are made here in seconds, as tests/test_predict.py makes one: draws
about each unit's known law, packed by the real writer :func:`sbcal.inference.cable_fit.store_cable`.
The units' laws are drawn from a known population, so what the pooling recovers has a truth.
"""

import json
import shutil
from dataclasses import asdict, replace

import numpy as np
import pandas as pd
import pytest

from sbcal import STANDARD_GRID_HZ, InputError
from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.design.cable_run import is_calibration_damper, load_cable_run
from sbcal.design.predict import predict
from sbcal.inference.batch import Lot, _unit_draws
from sbcal.inference.batch_cable import design_cable, read_cable_lot, write_design_cable
from sbcal.inference.cable_fit import CableFit, cable_config, cable_likelihood, store_cable, stored_correction
from sbcal.inference.likelihood import JointLikelihood
from sbcal.inference.sampler import SampleResult
from sbcal.inference.stats import loo
from sbcal.inference.store import cable_dir
from sbcal.model.cable import CableModel
from sbcal.model.damper import resolve_damper
from sbcal.model.laws import law_for

LAW = "iwan5"
POPULATION = dict(EJ_min=4.4, beta_material=0.11, delta_EJ=42.0, chi_micro=3e-4, chi_macro=0.03,
                  density_exponent=-1.0, macro_ratio=0.05)
SCATTER = {"delta_EJ": 0.10, "chi_macro": 0.10}   # the units' log scatter about the population; none elsewhere
POSTERIOR_SD = 0.02                                # each unit's posterior sd (log; additive on density_exponent)
TESTS = ("0.2-0.2", "1-1")
CHAINS, DRAWS = 2, 100


def _bench(root):
    """One damper1 recording (the law's own curves, 1 % noise): every unit's fit reads it, only the draws differ."""
    path = root / "bench.csv"
    if not path.is_file():
        d = resolve_damper("damper1")
        rng = np.random.default_rng(0)
        model, frames = CableModel(law_for(LAW)), []
        for t in TESTS:
            a = float(t.split("-")[0])
            fuu = model.dynamic_stiffness(d, STANDARD_GRID_HZ, a, **POPULATION)[0]
            noise = 0.01 * (rng.standard_normal((6, fuu.size)) + 1j * rng.standard_normal((6, fuu.size)))
            frames.append(curves_to_frame(d.name, t, STANDARD_GRID_HZ, a, fuu[None] * np.exp(noise)))
        write_bench(pd.concat(frames, ignore_index=True), path)
    return path


def _unit(root, runs, unit, truth, *, seed, law=LAW, converged=True, n_draws=DRAWS, source=None, correction=None):
    """Store unit ``unit``'s cable fit (state dry) with draws about ``truth``; the EJ_min and delta_EJ draws
    correlated (-0.8) as a stuck strand's rigidity trades against the slipped one's."""
    d = resolve_damper("damper1")
    like = cable_likelihood(d, clean_bench(load_bench(_bench(root))), list(TESTS), law)
    if correction is not None:  # as a used harmonic refit leaves it
        like = JointLikelihood(like.likes, like.prior, replace(like.model, correction=correction(like.freq_hz.size)))
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((len(like.prior.names), CHAINS, n_draws))
    z[like.prior.names.index("delta_EJ")] = -0.8 * z[like.prior.names.index("EJ_min")] + 0.6 * z[like.prior.names.index("delta_EJ")]
    draws = {}
    for k, n in enumerate(like.prior.names):
        base = truth.get(n, getattr(d, n, None))
        draws[n] = base + 1.5 * POSTERIOR_SD * z[k] if n == "density_exponent" else base * np.exp(POSTERIOR_SD * z[k])
    ll = like.pointwise_log_likelihood({n: v.ravel() for n, v in draws.items()}).reshape(CHAINS, n_draws, -1)
    one, many = {n: 1.0 for n in like.prior.names}, {n: 1e3 for n in like.prior.names}
    res = SampleResult(names=tuple(like.prior.names), draws=draws, log_prob=np.zeros((CHAINS, n_draws)), log_likelihood=ll,
                       tau=one, acceptance=np.full(CHAINS, 0.3), r_hat=one if converged else dict(one, delta_EJ=1.2),
                       ess_bulk=many, ess_tail=many, n_steps=100, burn=20, thin=1, converged=converged,
                       reason="" if converged else "R-hat above 1.01", start={}, wall_s=0.0,
                       config=cable_config(len(like.prior.names)))
    fit = CableFit(damper=unit, state="dry", law=law, tests=TESTS, effects=(), result=res, like=like, loo=loo(ll))
    values = asdict(replace(d, name=unit, source=source or d.source))
    store_cable(fit, cable_dir(runs, unit, "dry"), meta={"seed": seed, "damper_values": values})


def _truths(n, seed):
    rng = np.random.default_rng(seed)
    return [{k: v * np.exp(SCATTER.get(k, 0.0) * rng.standard_normal()) for k, v in POPULATION.items()}
            for _ in range(n)]


@pytest.fixture(scope="module")
def lot(tmp_path_factory):
    """Eight units of damper1's design whose cable laws scatter about POPULATION by SCATTER."""
    root = tmp_path_factory.mktemp("cable-lot")
    runs = root / "runs"
    truths = _truths(8, seed=11)
    units = [f"damper1-u{k:02d}" for k in range(1, 9)]
    for k, (u, t) in enumerate(zip(units, truths)):
        _unit(root, runs, u, t, seed=100 + k)
    return root, runs, units, truths


def test_a_harmonic_refits_correction_is_stored_with_its_draws(lot, tmp_path):
    """A fit made with a per-line correction (a used harmonic refit) stores it beside its draws, line by line
    as the stored ``freq_hz``; a first-harmonic fit stores none."""
    root, runs, units, truths = lot
    assert stored_correction(runs / units[0] / "cable-dry") is None
    rng = np.random.default_rng(5)
    made = []

    def correction(n):
        made.append(np.exp(0.05 * rng.standard_normal(n) + 0.03j * rng.standard_normal(n)))
        return made[-1]

    _unit(root, tmp_path, "damper1-h", truths[0], seed=3, correction=correction)
    got = stored_correction(tmp_path / "damper1-h" / "cable-dry")
    assert got is not None and got.shape == made[0].shape == (2 * STANDARD_GRID_HZ.size,)
    assert np.array_equal(got, made[0])


def test_a_units_draws_keep_a_tests_parameters_together():
    """One stored draw of a test gives all its parameters: their correlation survives the pooling's pairing."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal(500)
    draws = {"u": {("EJ", "t1"): np.exp(a), ("beta", "t1"): 0.5 + 0.1 * np.tanh(a), ("EJ", "t2"): np.exp(rng.standard_normal(500))}}
    lot = Lot(units=("u",), tests=("t1", "t2"), params=("EJ", "beta"), boxes={"EJ": (True, 0.1, 10.0), "beta": (False, 0.0, 1.0)},
              draws=draws, design={}, excluded={}, paramset="x")
    x = _unit_draws(lot, [("EJ", "t1"), ("EJ", "t2"), ("beta", "t1")], rng)[0].x
    assert np.all(np.diff(x[np.argsort(x[:, 0]), 2]) >= 0)    # the same stored draw of test t1: beta rises with EJ
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < 0.2    # independent tests: paired at random (300 draws: sd 0.06)


@pytest.mark.long
def test_the_design_cable_law_recovers_the_population(lot, tmp_path):
    root, runs, units, truths = lot
    cl = read_cable_lot(runs, units, "dry")
    assert cl.law == LAW and cl.lot.params == ("EJ_min", "beta_material", *law_for(LAW).parameter_names)
    summary, next_unit, hyper = design_cable(cl, seed=3)
    assert summary["converged"], summary["reason"]
    pop = {r["parameter"]: r for r in summary["population"]["population"]}
    # the median unit against the units' own geometric mean: each unit's posterior is centred on its truth,
    # so the only error is the reweighting's (300 draws of sd 0.02 per unit: 0.02 / sqrt(2400) in the mean)
    # and the scatter's shrinkage; 3 % is > 10 of its standard errors and < a third of the scatter
    for p in ("EJ_min", "delta_EJ", "chi_macro"):
        geo = np.exp(np.mean([np.log(t[p]) for t in truths]))
        assert pop[p]["median_unit"][1] == pytest.approx(geo, rel=0.03)
    # the next unit carries the lot's scatter: delta_EJ's sample log-sd over 8 units is
    # SCATTER * (1 +- 0.27) (chi-square, 7 degrees of freedom, 90 %), the posterior sd adds 0.02 in
    # quadrature; EJ_min does not scatter between units (its spread is the posteriors' and the prior's)
    sample_sd = np.std([np.log(t["delta_EJ"]) for t in truths], ddof=1)
    spread = np.std(np.log(next_unit["delta_EJ"]))
    assert 0.7 * sample_sd < spread < 1.6 * np.hypot(sample_sd, POSTERIOR_SD)
    assert np.std(np.log(next_unit["EJ_min"])) < 0.5 * spread
    assert summary["kept_fraction"] > 0.95 and summary["n_draws"] == next_unit["EJ_min"].size
    assert set(summary["tests_reached"]) == set(TESTS) and summary["tests"] == list(TESTS)
    assert summary["damper_values"]["name"] == "damper1-design"

    out = write_design_cable(tmp_path / "cable-dry", summary, next_unit, hyper)
    run = load_cable_run(out)
    assert run.law == LAW and run.n_draws == summary["n_draws"] and not run.convergence_warning()
    assert not is_calibration_damper(run, run.calibration)   # no offsets in its draws: a damper of the design draws them
    # a damper of the design predicted from the lot is wider than from one unit by the unit scatter
    one = predict(cable_dir(runs, units[0], "dry"), resolve_damper("damper1"), amplitude_mm_pp=[1.0], n_draws=100,
                  seed=0, model_error=False)
    design = predict(out, run.calibration, amplitude_mm_pp=[1.0], n_draws=100, seed=0, model_error=False)
    w_one = np.log(one.stiffness_n_per_m[0, 2] / one.stiffness_n_per_m[0, 0])
    w_design = np.log(design.stiffness_n_per_m[0, 2] / design.stiffness_n_per_m[0, 0])
    assert np.median(w_design) > 1.5 * np.median(w_one)


def test_read_cable_lot_refuses_what_cannot_be_pooled(lot, tmp_path):
    root, runs, units, truths = lot
    bad = tmp_path / "runs"
    shutil.copytree(runs, bad)
    doc = json.loads((cable_dir(bad, units[2], "dry") / "summary.json").read_text())
    (cable_dir(bad, units[2], "dry") / "summary.json").write_text(json.dumps(dict(doc, law="bouc_wen")))
    with pytest.raises(InputError, match=rf"cable-dry/summary.json: law 'bouc_wen', unit '{units[0]}' has 'iwan5'"):
        read_cable_lot(bad, units, "dry")
    with pytest.raises(InputError, match="no cable fit of state 'wet'"):
        read_cable_lot(runs, units, "wet")
    with pytest.raises(InputError, match="a population needs at least 3"):
        read_cable_lot(runs, units[:2], "dry")
    shutil.rmtree(bad)
    shutil.copytree(runs, bad)
    _unit(root, bad, units[1], truths[1], seed=8, converged=False)
    cl = read_cable_lot(bad, units, "dry")
    assert units[1] not in cl.lot.units and "did not converge" in cl.lot.excluded[units[1]]
