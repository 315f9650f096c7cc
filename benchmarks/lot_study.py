"""Virtual-bench lots through the whole lab workflow, then ``sbcal batch``'s population, over seeds.

Each lot: 12 units of damper1's design drawn from a known population (:mod:`sbcal.simulate.virtual_lot`),
each recorded on the virtual bench, cleaned and calibrated per test by the pipeline (``sbcal run``'s
stages), then the population fitted from the stored posteriors (:mod:`sbcal.inference.batch`). Kinds:

- ``linear``: no strand slip, EJ 5 %, beta 10 %, no outlier: the per-test EJ and beta *are* the unit's,
  so the population's median unit and scatter have exact truths, for the coverage of the 90 % intervals;
- ``slip``: a lognormal-Iwan strand slip with EJ 5 %, beta 10 %, slip scale 10 %, no outlier;
- ``slip-outlier``: the same with unit 7 planted at EJ -15 %;
- ``slip-outlier-30``: planted at EJ -30 % (the power where the effect is larger than the lot's spread).

Writes one JSON line per lot to ``--out`` (resumable: lots already there are skipped) and prints the
rates. Run from the repository: ``python benchmarks/lot_study.py --seeds 20 --out lot_study.jsonl``.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from sbcal.data.bench import write_bench
from sbcal.data.readers import load_bench
from sbcal.inference.batch import fit_population, read_lot
from sbcal.inference.population import from_population_coordinates
from sbcal.model.damper import resolve_damper
from sbcal.pipeline import Settings, clean, sample_tests
from sbcal.simulate.virtual_bench import BenchConfig, parse_effect
from sbcal.simulate.virtual_lot import LotConfig, record_lot, unit_name

SLIP = "strand_slip=law:lognormal_iwan,chi_median:0.006,log_spread:2.1,delta_EJ:42"
KINDS = {
    "linear": dict(tests=("0.5-0.5",), effects={}, params={"EJ": 11.3, "beta": 0.3}, outlier=None),
    "slip": dict(tests=("0.2-0.2", "2-2"), effects=dict([parse_effect(SLIP)]), params={"EJ": 4.4, "beta": 0.11},
                 outlier=None),
    "slip-outlier": dict(tests=("0.2-0.2", "2-2"), effects=dict([parse_effect(SLIP)]),
                         params={"EJ": 4.4, "beta": 0.11}, outlier=6),
    "slip-outlier-30": dict(tests=("0.2-0.2", "2-2"), effects=dict([parse_effect(SLIP)]),
                            params={"EJ": 4.4, "beta": 0.11}, outlier=6, outlier_ej=-0.30),
}


def run_lot(kind: str, seed: int, *, workers: int = 2, units: int = 12) -> dict:
    spec = KINDS[kind]
    damper = resolve_damper("damper1")
    cfg = LotConfig(units=units, outlier=spec["outlier"], outlier_ej=spec.get("outlier_ej", -0.15),
                    bench=BenchConfig(params=spec["params"], effects=spec["effects"], runs=8))
    t0 = time.perf_counter()
    frame, truth = record_lot(damper, cfg, spec["tests"], rng=np.random.default_rng([seed, 1]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "lot.csv"
        write_bench(frame, path)
        bench = load_bench(path)
        members = [replace(damper, name=unit_name(damper, k)) for k in range(units)]
        settings = Settings(seed=seed, workers=workers)
        store = Path(tmp) / "runs"
        data = clean(bench, members, store=store, settings=settings)
        sample_tests(data, [(d, t) for d in members for t in spec["tests"]], store=store, settings=settings,
                     progress=False)
        t1 = time.perf_counter()
        lot = read_lot(store)
        doc, draws = fit_population(lot, seed=seed)
        t2 = time.perf_counter()
    p_out = {u["unit"]: u["outlier_probability"] for u in doc["per_unit"]}
    planted = [u for u, t in truth.items() if t["outlier"]]
    out = {"kind": kind, "seed": seed, "converged": doc["converged"], "excluded": doc["excluded"],
           "calibrate_s": t1 - t0, "batch_s": t2 - t1, "p_outlier": p_out, "planted": planted,
           "min_ess": min(u["ess_median"] for u in doc["per_unit"])}
    if kind == "linear":
        # exact truths: the population's median unit and its scatter (log EJ; the logit of beta's box
        # fraction, whose scatter is beta's log scatter times 1 / (1 - u) to first order)
        cover = {}
        hyper = {k: np.asarray(v).ravel() for k, v in draws["hyper"].items()}
        for p, true_med, true_tau in (("EJ", math.log(11.3), 0.05),):
            label = f"{p}[{spec['tests'][0]}]"
            for what, value in ((".mean", true_med), (".scatter", true_tau)):
                q = np.quantile(hyper[label + what], (0.05, 0.95))
                cover[p + what] = bool(q[0] <= value <= q[1])
        lo, hi = lot.boxes["beta"][1:]
        u = (0.3 - lo) / (hi - lo)
        label = f"beta[{spec['tests'][0]}]"
        for what, value in ((".mean", math.log(u / (1 - u))), (".scatter", 0.10 / (1 - u))):
            q = np.quantile(hyper[label + what], (0.05, 0.95))
            cover["beta" + what] = bool(q[0] <= value <= q[1])
        out["covered"] = cover
        out["median_unit_EJ"] = float(np.median(from_population_coordinates(hyper[f"EJ[{spec['tests'][0]}].mean"],
                                                                            lot.boxes["EJ"])))
    return out


def binomial_band(n: int, p: float) -> tuple[float, float]:
    s = math.sqrt(p * (1 - p) / n)
    return p - 2 * s, p + 2 * s


def report(rows: list[dict]) -> str:
    lines = []
    for kind in KINDS:
        rs = [r for r in rows if r["kind"] == kind]
        if not rs:
            continue
        conv = sum(r["converged"] for r in rs)
        lines.append(f"{kind}: {len(rs)} lots, {conv} converged, calibration {np.median([r['calibrate_s'] for r in rs]):.0f} s "
                     f"and batch {np.median([r['batch_s'] for r in rs]):.1f} s per lot (median), min unit ESS "
                     f"{min(r['min_ess'] for r in rs):.0f}")
        others = [max(p for u, p in r["p_outlier"].items() if u not in r["planted"]) for r in rs]
        lines.append(f"  no other unit above 0.5: {sum(o < 0.5 for o in others)}/{len(rs)} "
                     f"(largest other P per lot: median {np.median(others):.2f}, max {max(others):.2f})")
        if kind.startswith("slip-outlier"):
            planted = [r["p_outlier"][r["planted"][0]] for r in rs]
            lines.append(f"  planted unit P >= 0.95: {sum(p >= 0.95 for p in planted)}/{len(rs)}, P >= 0.5: "
                         f"{sum(p >= 0.5 for p in planted)}/{len(rs)} (P per lot: median {np.median(planted):.2f}, "
                         f"min {min(planted):.2f})")
        if kind == "linear":
            lo, hi = binomial_band(len(rs), 0.9)
            for key in rs[0]["covered"]:
                k = sum(r["covered"][key] for r in rs)
                lines.append(f"  90 % interval of {key} covers the truth: {k}/{len(rs)} "
                             f"(nominal 0.90, +-2 binomial SE: {lo:.2f}-{hi:.2f})")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1000, help="seeds first-seed .. first-seed + seeds - 1")
    ap.add_argument("--kinds", nargs="+", default=["linear", "slip", "slip-outlier"], choices=list(KINDS))
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="lot_study.jsonl")
    args = ap.parse_args(argv)
    out = Path(args.out)
    rows = [json.loads(line) for line in out.read_text().splitlines()] if out.exists() else []
    done = {(r["kind"], r["seed"]) for r in rows}
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for kind in args.kinds:
            if (kind, seed) in done:
                continue
            r = run_lot(kind, seed, workers=args.workers, units=args.units)
            rows.append(r)
            with out.open("a") as fh:
                fh.write(json.dumps(r) + "\n")
            print(f"{kind} seed {seed}: converged {r['converged']}, max P "
                  f"{max(r['p_outlier'].values()):.2f}, {r['calibrate_s']:.0f} + {r['batch_s']:.1f} s", flush=True)
    print(report(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
