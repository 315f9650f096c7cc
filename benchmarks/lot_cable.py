"""A virtual lot whose units' cable laws are each fitted, then pooled: the design's cable law against the
lot's known unit scatter (docs/batch.md, "The design's cable law").

Each lot: ``--units`` units of damper1's design with a lognormal-Iwan strand slip (outside every fitted
family), drawn from the virtual lot's population (rigidity and its stuck part 5 %, loss factor 10 %, slip
scale 10 %: :mod:`sbcal.simulate.virtual_lot`), recorded at 0.2 and 2 mm, cleaned and calibrated per test by
the pipeline, each unit's cable fitted with the ``iwan5`` law and stored as ``sbcal cable`` stores it, then
``sbcal batch``'s population of the per-test parameters and of the cable law (:mod:`sbcal.inference.batch_cable`).

The fitted law is not the recording's, so its parameters have no exact truth; their unit scatter does
where the population moves one scale: ``EJ_min`` and ``delta_EJ`` scale with the unit's rigidity factor
(5 %), the slip curvatures ``chi_micro`` / ``chi_macro`` with its slip factor (10 %). Printed: per
parameter the population's unit scatter (90 % interval) beside that truth and beside the units' own
truths' sample scatter, the outlier probabilities, the next unit's share kept, wall times.

Run from the repository: ``python benchmarks/lot_cable.py --units 8 --seed 1 --out results_lot_cable.json``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from sbcal.data.bench import write_bench
from sbcal.data.readers import load_bench
from sbcal.inference.batch import fit_population, read_lot
from sbcal.inference.batch_cable import design_cable, read_cable_lot
from sbcal.inference.cable_fit import fit_damper_cable, store_cable
from sbcal.inference.harmonic_refit import refit_harmonics
from sbcal.inference.store import cable_dir
from sbcal.model.damper import resolve_damper
from sbcal.pipeline import Settings, clean, sample_tests
from sbcal.simulate.virtual_bench import BenchConfig, parse_effect
from sbcal.simulate.virtual_lot import LotConfig, record_lot, unit_name

SLIP = "strand_slip=law:lognormal_iwan,chi_median:0.006,log_spread:2.1,delta_EJ:42"
TESTS = ("0.2-0.2", "2-2")
SCALES = {"EJ_min": ("EJ", 0.05), "delta_EJ": ("EJ", 0.05), "chi_micro": ("slip", 0.10), "chi_macro": ("slip", 0.10)}


def run_lot(seed: int, units: int, workers: int) -> dict:
    damper = resolve_damper("damper1")
    cfg = LotConfig(units=units, bench=BenchConfig(params={"EJ": 4.4, "beta": 0.11},
                                                   effects=dict([parse_effect(SLIP)]), runs=8))
    frame, truth = record_lot(damper, cfg, TESTS, rng=np.random.default_rng([seed, 1]))
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "lot.csv"
        write_bench(frame, path)
        members = [replace(damper, name=unit_name(damper, k)) for k in range(units)]
        settings = Settings(seed=seed, workers=workers)
        store = Path(tmp) / "runs"
        t0 = time.perf_counter()
        data = clean(load_bench(path), members, store=store, settings=settings)
        sample_tests(data, [(d, t) for d in members for t in TESTS], store=store, settings=settings, progress=False)
        times["per_test_s"] = time.perf_counter() - t0
        fits = {}
        t0 = time.perf_counter()
        for m in members:
            t1 = time.perf_counter()
            got, _ = fit_damper_cable(m, data, laws=("iwan5",), seed=seed, workers=workers, progress=False)
            fit = got["iwan5"]["dry"]
            fit = refit_harmonics(fit, seed=seed, workers=workers, progress=None) or fit
            s = store_cable(fit, cable_dir(store, m.name, "dry"), meta={"seed": seed, "damper_values": asdict(m)})
            fits[m.name] = {"converged": s["converged"], "wall_s": time.perf_counter() - t1,
                            "median": {n: p["median"] for n, p in s["parameters"].items()},
                            "qualifier": s["remainder"]["qualifier"]}
            print(f"  {m.name}: cable fit {fits[m.name]['wall_s']:.0f} s, converged {s['converged']}", flush=True)
        times["cable_fits_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        lot = read_lot(store)
        doc, _ = fit_population(lot, seed=seed)
        times["batch_per_test_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        summary, next_unit, _ = design_cable(read_cable_lot(store, lot.units, "dry"), seed=seed)
        times["batch_cable_s"] = time.perf_counter() - t0
    pop = summary["population"]
    rows = {}
    for r in pop["population"]:
        p = r["parameter"]
        row = {"median_unit": r["median_unit"], "scatter_percent": r["scatter_percent"],
               "next_unit": r["next_unit"]}
        if p in SCALES:
            factor, sd = SCALES[p]
            row["truth_scatter_percent"] = 100 * sd
            row["units_sample_scatter_percent"] = 100 * float(np.std([np.log(truth[u][factor]) for u in truth], ddof=1))
        rows[p] = row
    return {"seed": seed, "units": units, "times": times, "fits": fits, "converged": pop["converged"],
            "reason": pop["reason"], "n_steps": pop["n_steps"], "kept_fraction": summary["kept_fraction"],
            "p_outlier": {u["unit"]: u["outlier_probability"] for u in pop["per_unit"]},
            "ess_median": {u["unit"]: u["ess_median"] for u in pop["per_unit"]},
            "per_test_converged": doc["converged"], "cable": rows, "truth": truth}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="results_lot_cable.json")
    args = ap.parse_args(argv)
    r = run_lot(args.seed, args.units, args.workers)
    Path(args.out).write_text(json.dumps(r, indent=1))
    t = r["times"]
    print(f"{r['units']} units, seed {r['seed']}: per-test calibration {t['per_test_s']:.0f} s, cable fits "
          f"{t['cable_fits_s']:.0f} s, batch per-test {t['batch_per_test_s']:.1f} s, cable population {t['batch_cable_s']:.1f} s "
          f"({r['n_steps']} steps, converged {r['converged']}); next unit kept {r['kept_fraction']:.2f}")
    print(f"  cable fits converged: {sum(f['converged'] for f in r['fits'].values())}/{r['units']}; highest P(outlier) "
          f"{max(r['p_outlier'].values()):.2f}; smallest unit ESS {min(r['ess_median'].values()):.0f}")
    for p, row in r["cable"].items():
        q = row["scatter_percent"]
        extra = (f"  truth {row['truth_scatter_percent']:.0f} %, units' sample {row['units_sample_scatter_percent']:.1f} %"
                 if "truth_scatter_percent" in row else "")
        print(f"  {p:16s} median unit {row['median_unit'][1]:.4g} [{row['median_unit'][0]:.4g}, {row['median_unit'][2]:.4g}], "
              f"unit scatter {q[1]:.1f} [{q[0]:.1f}, {q[2]:.1f}] %{extra}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
