"""The cross-law matrix: data made with each cable law, fitted with each fitted family (issue 13).

Usage: python benchmarks/cable_matrix.py [--seed 2029] [--laws bouc_wen iwan5 lognormal_iwan iwan_tail]
       [--families bouc_wen iwan5 iwan_tail] [--json OUT]

On a geometry not used in development (the stubby damper of ``benchmarks/diagnose_matrix.py``), the
virtual bench records the thesis's test plan (0.1 ... 2 mm, 16 runs per test) with its cable drawn
from each law: the fitted families (``bouc_wen``, ``iwan5``, ``iwan_tail``; ``--families`` narrows the
diagnosis's comparison) and the bench-only ``lognormal_iwan``. For each data set:

- ``sbcal diagnose``'s verdict (it must be ``strand_slip``), the best family by PSIS-LOO, and whether
  its joint posterior converged;
- every fitted family's ELPD and its difference to the best family (the diagnosis's comparison), and per
  amplitude the rms error of the verdict model's stored posterior-median curves against the bench's
  noise-free curves (``BenchConfig.ideal()``: the same cable without scatter or noise), magnitude [%]
  and phase [deg].

Targets: the verdict model within 2 % and 1.5 deg when the law is one of the fitted families, within
4 % and 3 deg across laws, at every amplitude from 0.1 to 2 mm.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_matrix import STUB  # noqa: E402

from sbcal.data.bench import write_bench
from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import load_bench  # noqa: E402
from sbcal.inference.cable_fit import cable_likelihood, read_cable  # noqa: E402
from sbcal.model.damper import load_damper  # noqa: E402
from sbcal.diagnosis.diagnose import DiagnoseConfig, diagnose  # noqa: E402
from sbcal.model.hysteresis import FITTED_LAWS  # noqa: E402
from sbcal.simulate.virtual_bench import DEFAULT_TESTS, BenchConfig, SlipLaw, record, response  # noqa: E402

LAWS = {  # law parameters; delta_EJ as a fraction of ej_static
    "bouc_wen": {"chi_slip": 0.008, "sharpness": 2.0, "delta_EJ": 0.4},
    "iwan5": {"chi_micro": 1e-4, "chi_macro": 0.05, "density_exponent": -1.0, "macro_ratio": 0.3, "delta_EJ": 0.4},
    "lognormal_iwan": {"chi_median": 0.005, "log_spread": 1.8, "delta_EJ": 0.4},
    "iwan_tail": {"chi_micro": 3e-4, "chi_tail": 0.02, "density_exponent": -0.8, "tail_exponent": -1.7, "delta_EJ": 0.4},
}
TESTS = tuple(t for t in DEFAULT_TESTS if t != "2-1")  # the constant-amplitude tests: errors per amplitude


def _wrap_deg(a):
    return (a + 180.0) % 360.0 - 180.0


def run_law(damper, law: str, seed: int, tmp: Path, families=FITTED_LAWS) -> dict:
    p = dict(LAWS[law], delta_EJ=LAWS[law]["delta_EJ"] * damper.ej_static)
    slip = SlipLaw(law=law, params=tuple(p.items()))
    # slip_tol 1e-8 on ln(chi): Newton stalls at ~3e-9 on this geometry's 4 Hz line (rounding), where
    # the default 1e-9 refuses the recording; a 1e-8 relative curvature error is far below the noise
    config = BenchConfig(params={"EJ": 0.05 * damper.ej_static, "beta": 0.05}, effects={"strand_slip": slip}, runs=16,
                         slip_tol=1e-8)
    path = tmp / f"{law}.csv"
    write_bench(record(damper, config, TESTS, rng=np.random.default_rng([seed, list(LAWS).index(law)])), path)
    bench = clean_bench(load_bench(path))
    t0 = time.perf_counter()
    verdict = diagnose(damper, bench, seed=seed, progress=False, store=tmp / law,
                       config=DiagnoseConfig(laws=tuple(families)))
    t_diag = time.perf_counter() - t0
    comparison = verdict.get("law") or {}
    out = {"law": law, "verdict": verdict["verdict"], "verdict_law": comparison.get("best"),
           "diagnose_s": t_diag, "secondary": verdict.get("secondary"), "families": comparison.get("families", {})}
    if verdict["verdict"] != "strand_slip":
        return out
    # the verdict's stored posterior (what `sbcal predict` would use): its median curves vs the noise-free bench
    summary, draws = read_cable(tmp / law / damper.name / "cable-dry")
    like = cable_likelihood(damper, bench, list(summary["tests"]), summary["law"])
    med = {k: np.array([np.median(v)]) for k, v in draws.items() if k in like.prior.names}
    fuu = like.model(like.damper, like.freq_hz, **med)[0]
    rows, start = {}, 0
    for t, lk in zip(summary["tests"], like.likes):
        n = lk.freq_hz.size
        truth = response(damper, lk.freq_hz, lk.amplitude_mm_pp, config.ideal().params, config.ideal().effects)[0]
        f = fuu[start:start + n]
        start += n
        rows[t] = {"amplitude_mm_pp": float(lk.amplitude_mm_pp[0]),
                   "magnitude_pct": float(100 * np.sqrt(np.mean(np.log(np.abs(f) / np.abs(truth)) ** 2))),
                   "phase_deg": float(np.sqrt(np.mean(_wrap_deg(np.degrees(np.angle(f) - np.angle(truth))) ** 2)))}
    out.update(per_test=rows, converged=bool(summary["converged"]), r_hat_max=summary.get("r_hat_max"),
               ess_bulk_min=summary.get("ess_bulk_min"), wall_s=summary.get("wall_s"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2029)
    ap.add_argument("--laws", nargs="+", choices=list(LAWS), default=list(LAWS))
    ap.add_argument("--families", nargs="+", choices=list(FITTED_LAWS), default=list(FITTED_LAWS))
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args(argv)
    results, ok = [], True
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "stub.toml").write_text(STUB)
        damper = load_damper(Path(tmp) / "stub.toml")
        for law in args.laws:
            r = run_law(damper, law, args.seed, Path(tmp), args.families)
            results.append(r)
            print(f"data {law}: verdict {r['verdict']} ({r['verdict_law']} law), secondary "
                  f"{(r['secondary'] or {}).get('effect')}; "
                  f"diagnose {r['diagnose_s']:.0f} s")
            for family, f in r["families"].items():
                print(f"  {family:9s} ELPD {f['elpd']:10.1f}, best family - this one {f['delta_elpd']:8.1f} +- "
                      f"{f['se_delta']:6.1f}, converged {f.get('converged')}")
            if r["verdict"] != "strand_slip":
                ok = False
                continue
            matched = r["verdict_law"] == law and law in args.families
            mag_t, ph_t = (2.0, 1.5) if matched else (4.0, 3.0)
            meets = all(v["magnitude_pct"] <= mag_t and v["phase_deg"] <= ph_t for v in r["per_test"].values())
            cells = " ".join(f"{t} {v['magnitude_pct']:.2f}/{v['phase_deg']:.2f}" for t, v in r["per_test"].items())
            print(f"  verdict model {r['verdict_law']}: converged {r['converged']} (R-hat max {r['r_hat_max']}, ESS min "
                  f"{r['ess_bulk_min']}); rms % / deg vs noise-free: {cells}  target {mag_t:g} % / {ph_t:g} deg: "
                  + ("met" if meets else "MISSED"))
            ok &= meets and r["converged"]
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    print("all targets met" if ok else "some target missed")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
