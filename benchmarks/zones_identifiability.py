"""Which parameters of a zoned cable law the bench's amplitudes pin down (``docs/cable.md``, "Zones").

Usage: python benchmarks/zones_identifiability.py [--law iwan5] [--seed S] [--tests 0.1 0.2 0.5 1 2] [--json OUT]

Data: the fast cable model itself with a zoned law (``iwan5_zoned`` by default; finer sections than the
fit's, 24 in the middle and 12 per zone) on damper2's geometry, swaged ends stiffer and slipping later
(clamp zone 0.2 of the arm, mass zone 0.1), commanded amplitudes ``--tests`` [mm p-p], 8 runs each with
the virtual bench's default noise (3 % / 1.5 deg below 15 Hz, 0.8 % / 0.4 deg above) and re-clamping
scatter of EJ (1.5 %). In-family data on purpose: identifiability is a property of the model and the
bench's amplitudes, not of a law mismatch.

Prints per parameter: the truth, the posterior median and 90 % interval, and the interval's width as a
share of the prior box (in the sampled coordinate: log for scales): **pinned** below 25 %, **weak**
below 60 %, else **prior** (the prior carries it). Also the strongest posterior correlations (the
trade-offs), the convergence and the wall time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import pandas as pd

from sbcal.data.bench import curves_to_frame, write_bench
from sbcal.data.clean_bench import clean_bench
from sbcal.data.readers import load_bench
from sbcal.inference.cable_fit import fit_cable
from sbcal.model.cable import CableModel
from sbcal.model.damper import resolve_damper
from sbcal.model.fem import STANDARD_GRID_HZ
from sbcal.model.laws import law_for

MIDDLE = {
    "iwan5": {"delta_EJ": 0.35, "chi_micro": 2e-5, "chi_macro": 0.01, "density_exponent": -0.8, "macro_ratio": 0.2},
    "bouc_wen": {"delta_EJ": 0.35, "chi_slip": 0.004, "sharpness": 1.5},
}
ZONES = {"clamp_zone": 0.2, "clamp_EJ_min_ratio": 2.0, "clamp_delta_EJ_ratio": 2.5, "clamp_moment_ratio": 7.5,
         "mass_zone": 0.1, "mass_EJ_min_ratio": 1.5, "mass_delta_EJ_ratio": 1.5, "mass_moment_ratio": 3.0}


def make_bench(damper, law: str, tests, seed: int, path: Path, runs: int = 8):
    """Noisy runs of the zoned cable (module docstring) written to ``path`` and read back; and the truth."""
    rng = np.random.default_rng(seed)
    truth = {"EJ_min": 0.05 * damper.ej_static, "beta_material": 0.05,
             **{k: v * (damper.ej_static if k == "delta_EJ" else 1.0) for k, v in MIDDLE[law].items()}, **ZONES}
    model = CableModel(law_for(law + "_zoned"), sections=24, zone_sections=12)
    f = STANDARD_GRID_HZ
    sig_mag = 0.008 + (0.03 - 0.008) / (1 + np.exp((f - 15.0) / 2.0))
    sig_ph = np.radians(0.4 + (1.5 - 0.4) / (1 + np.exp((f - 15.0) / 2.0)))
    frames = []
    for amp in tests:
        scale = np.exp(0.015 * rng.standard_normal(runs))  # re-clamping: the cable's rigidity per run
        sets = dict(truth, EJ_min=truth["EJ_min"] * scale, delta_EJ=truth["delta_EJ"] * scale)
        fuu = model.dynamic_stiffness(damper, f, amp, **sets)
        fuu = fuu * np.exp(sig_mag * rng.standard_normal(fuu.shape) + 1j * sig_ph * rng.standard_normal(fuu.shape))
        frames.append(curves_to_frame(damper.name, f"{amp:g}-{amp:g}", f, amp, fuu))
    write_bench(pd.concat(frames, ignore_index=True), path)
    return load_bench(path), truth


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--law", choices=list(MIDDLE), default="iwan5")
    ap.add_argument("--seed", type=int, default=4100)
    ap.add_argument("--tests", type=float, nargs="+", default=[0.1, 0.2, 0.5, 1.0, 2.0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args(argv)
    damper = resolve_damper("damper2")
    with tempfile.TemporaryDirectory() as tmp:
        bench, truth = make_bench(damper, args.law, args.tests, args.seed, Path(tmp) / "bench.csv")
    data = clean_bench(bench)
    t0 = time.perf_counter()
    fit = fit_cable(damper, data, data.tests(damper.name), args.law + "_zoned", seed=args.seed, workers=args.workers)
    wall = time.perf_counter() - t0
    res, prior = fit.result, fit.like.prior
    flat = res.flat()
    z = prior.z_of(flat)
    rows = {}
    print(f"{args.law}_zoned on {len(args.tests)} amplitudes ({', '.join(f'{a:g}' for a in args.tests)} mm): "
          f"converged {res.converged} ({res.convergence_dict()['reason']}), R-hat max "
          f"{res.convergence_dict()['r_hat_max']:.3f}, ESS min {res.convergence_dict()['ess_bulk_min']:.0f}, {wall:.0f} s")
    for i, name in enumerate(prior.names):
        lo, hi = np.quantile(z[:, i], [0.05, 0.95])
        share = float((hi - lo) / (prior.z_upper[i] - prior.z_lower[i]))
        q = np.quantile(flat[name], [0.05, 0.5, 0.95])
        word = "pinned" if share < 0.25 else ("weak" if share < 0.6 else "prior")
        rows[name] = {"truth": truth.get(name), "median": float(q[1]), "q05": float(q[0]), "q95": float(q[2]),
                      "share_of_prior": share, "word": word}
        t = truth.get(name)
        print(f"  {name:22s} truth {('%.4g' % t) if t is not None else '-':>9s}  median {q[1]:.4g} [{q[0]:.4g}, {q[2]:.4g}]"
              f"  90 % interval {100 * share:5.1f} % of the prior: {word}")
    corr = np.corrcoef(z.T)
    pairs = sorted(((abs(corr[i, j]), prior.names[i], prior.names[j], corr[i, j]) for i in range(len(prior.names))
                    for j in range(i)), reverse=True)[:6]
    print("  strongest correlations (sampled coordinates): " + "; ".join(f"{a}-{b} {c:+.2f}" for _, a, b, c in pairs))
    if args.json:
        Path(args.json).write_text(json.dumps({"law": args.law, "tests": args.tests, "seed": args.seed, "wall_s": wall,
                                               "convergence": res.convergence_dict(), "parameters": rows,
                                               "correlations": [[a, b, c] for _, a, b, c in pairs]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
