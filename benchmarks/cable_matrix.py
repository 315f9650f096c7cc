"""The cross-law matrix: data made with each cable law, fitted with each fitted family (issue 13).

Usage: python benchmarks/cable_matrix.py [--seed 2029] [--rows bouc_wen iwan5 lognormal_iwan iwan_tail
       zoned_bouc_wen zoned_iwan5 time_iwan5 time_zoned_iwan5] [--families bouc_wen iwan5 iwan_tail] [--json OUT]
       [--data DIR | --recorded DIR] [--time-runs N] [--keep DIR]

On a geometry not used in development (the stubby damper of ``benchmarks/diagnose_matrix.py``), the
virtual bench records the thesis's test plan (0.1 ... 2 mm, 16 runs per test) with its cable drawn
from each row (``--rows``, alias ``--laws``): a law along the whole arm, the fitted families
(``bouc_wen``, ``iwan5``, ``iwan_tail``; ``--families`` narrows the diagnosis's comparison) and the
bench-only ``lognormal_iwan``; and two zoned cables, richer than any fitted model (issue 20): stiffer
when stuck and slipping later where the cable is swaged, 0.2 of the arm at the clamp in a law of
another shape than the middle's and 0.1 at the mass (``ROWS``):

- ``zoned_bouc_wen``: ``bouc_wen`` (n = 2) in the middle; at the clamp a Dahl knee (n = 1, the fitted
  zoned law keeps the middle's n), ``EJ_min`` x2, ``delta_EJ`` x2.5, slip curvature 3x ``chi_slip``;
  at the mass the middle's law with ``EJ_min``, ``delta_EJ`` x1.5, curvatures x2;
- ``zoned_iwan5``: ``iwan5`` in the middle; at the clamp ``lognormal_iwan`` (outside the fitted
  families; its half-rigidity curvature 2.5x the middle's), ``EJ_min`` and ``delta_EJ`` x2; at the mass
  the middle's law with ``EJ_min``, ``delta_EJ`` x1.5, curvatures x2.5.

Two rows are recorded as a shaker does (``strand_slip=...,time:1``, ``docs/virtual_bench.md``, "Time domain": the
cable integrated in time from rest, the bench's line the first harmonic of a distorted force), at 0.1, 0.2, 0.5, 1
and 2 mm with 4 runs each (``TIME_TESTS``, ``TIME_RUNS``; ~13 s a run): ``time_iwan5`` (the ``iwan5`` row's cable)
and ``time_zoned_iwan5`` (the zoned family of ``iwan5``, in-family zones: 0.2 of the arm at the clamp, ``EJ_min`` and
``delta_EJ`` x2, slip moment x5; 0.1 at the mass, x1.5, x3.75). Their verdict's curves are the stored fit's with its
harmonic refit's correction where the refit was used; beside them, the first-harmonic model's own mode (polished from
the stored median), what a fit without the harmonics gives. With 4 runs the run means alone are 1.2-2.7 % rms
from the noise-free curves (seed 2029; the bench's noise at 4-15 Hz). With ``--time-runs 16`` (record once with
``--data DIR``, 20 min for ``time_iwan5`` and 46 min for ``time_zoned_iwan5`` on one core each, then diagnose with
``--recorded DIR``) ``time_iwan5`` meets the target at every amplitude (``docs/results.md``).

``--data DIR`` only records: each row's bench CSV into DIR (``<row>.csv``) and, for the zoned rows,
how far their noise-free curves are from the same cable without zones; no diagnosis. For each data
set otherwise:

- ``sbcal diagnose``'s verdict (it must be ``strand_slip``), the best family by PSIS-LOO, and whether
  its joint posterior converged;
- every fitted family's ELPD and its difference to the best family (the diagnosis's comparison), and per
  amplitude the rms error of the verdict model's curves at its stored posterior's median set (and, printed
  beside, of the median over the draws of each line's curve, as ``sbcal predict`` shows it) against the bench's
  noise-free curves (``BenchConfig.ideal()``: the same cable without scatter or noise), magnitude [%]
  and phase [deg].

Targets: the verdict model within 2 % and 1.5 deg when the law is one of the fitted families and for the
zoned rows (whose verdict must be a zoned law), within 4 % and 3 deg across laws, at every amplitude from
0.1 to 2 mm.
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
from sbcal.inference.cable_fit import cable_likelihood, polish_mode, read_cable, stored_correction  # noqa: E402
from sbcal.model.damper import load_damper  # noqa: E402
from sbcal.diagnosis.diagnose import DiagnoseConfig, diagnose  # noqa: E402
from sbcal.model.cable_zones import CableZone  # noqa: E402
from sbcal.model.laws import fitted_laws  # noqa: E402
from sbcal.model.fem import STANDARD_GRID_HZ  # noqa: E402
from sbcal.simulate.virtual_bench import (DEFAULT_TESTS, BenchConfig, SlipLaw, record, response,  # noqa: E402
                                          test_amplitude)

LAWS = {  # law parameters; delta_EJ as a fraction of ej_static
    "bouc_wen": {"chi_slip": 0.008, "sharpness": 2.0, "delta_EJ": 0.4},
    "iwan5": {"chi_micro": 1e-4, "chi_macro": 0.05, "density_exponent": -1.0, "macro_ratio": 0.3, "delta_EJ": 0.4},
    "lognormal_iwan": {"chi_median": 0.005, "log_spread": 1.8, "delta_EJ": 0.4},
    "iwan_tail": {"chi_micro": 3e-4, "chi_tail": 0.02, "density_exponent": -0.8, "tail_exponent": -1.7, "delta_EJ": 0.4},
}
ROWS = {  # the middle's law and its parameters (as LAWS), the zones (their delta_EJ as ratios to the middle's)
    **{law: {"law": law, "params": p, "zones": ()} for law, p in LAWS.items()},
    "zoned_bouc_wen": {"law": "bouc_wen", "params": LAWS["bouc_wen"], "zones": (
        CableZone("clamp", 0.2, "dahl", (("chi_dahl", 0.024),), EJ_min_ratio=2.0, delta_EJ_ratio=2.5),
        CableZone("mass", 0.1, EJ_min_ratio=1.5, delta_EJ_ratio=1.5, chi_ratio=2.0))},
    "zoned_iwan5": {"law": "iwan5", "params": LAWS["iwan5"], "zones": (
        CableZone("clamp", 0.2, "lognormal_iwan", (("chi_median", 0.015), ("log_spread", 1.2)), EJ_min_ratio=2.0,
                  delta_EJ_ratio=2.0),
        CableZone("mass", 0.1, EJ_min_ratio=1.5, delta_EJ_ratio=1.5, chi_ratio=2.5))},
    # recorded as a shaker does (time:1): the first harmonic of a distorted force, which the fits' describing
    # function does not hold; fewer tests and runs (a run of a 37-line test integrates in ~13 s)
    "time_iwan5": {"law": "iwan5", "params": LAWS["iwan5"], "zones": (), "time": True},
    "time_zoned_iwan5": {"law": "iwan5_zoned", "zones": (), "time": True, "params": {
        **LAWS["iwan5"], "clamp_zone": 0.2, "clamp_EJ_min_ratio": 2.0, "clamp_delta_EJ_ratio": 2.0,
        "clamp_moment_ratio": 5.0, "mass_zone": 0.1, "mass_EJ_min_ratio": 1.5, "mass_delta_EJ_ratio": 1.5,
        "mass_moment_ratio": 3.75}},
}
"""The matrix's rows in the order of their seeds (``[seed, row index]``: a row added at the end leaves
the others' data unchanged)."""
TESTS = tuple(t for t in DEFAULT_TESTS if t != "2-1")  # the constant-amplitude tests: errors per amplitude
TIME_TESTS, TIME_RUNS = ("0.1-0.1", "0.2-0.2", "0.5-0.5", "1-1", "2-2"), 4  # a time row's plan


def tests_of(row: str) -> tuple:
    """The tests the row records."""
    return TIME_TESTS if ROWS[row].get("time") else TESTS


def _wrap_deg(a):
    return (a + 180.0) % 360.0 - 180.0


def bench_config(damper, row: str, zones: bool = True, time_runs: int = TIME_RUNS) -> BenchConfig:
    """The row's bench (``zones=False``: the same cable without its zones; ``time_runs`` per test of a time row)."""
    spec = ROWS[row]
    p = dict(spec["params"], delta_EJ=spec["params"]["delta_EJ"] * damper.ej_static)
    time = bool(spec.get("time"))
    slip = SlipLaw(law=spec["law"], params=tuple(p.items()), zones=spec["zones"] if zones else (), time_domain=time)
    # slip_tol 1e-8 on ln(chi): Newton stalls at ~3e-9 on this geometry's 4 Hz line (rounding), where
    # the default 1e-9 refuses the recording; a 1e-8 relative curvature error is far below the noise
    return BenchConfig(params={"EJ": 0.05 * damper.ej_static, "beta": 0.05}, effects={"strand_slip": slip},
                       runs=time_runs if time else 16, slip_tol=1e-8)


def record_row(damper, row: str, seed: int, path: Path, time_runs: int = TIME_RUNS) -> BenchConfig:
    """Record the row's bench CSV at ``path``; its config."""
    config = bench_config(damper, row, time_runs=time_runs)
    write_bench(record(damper, config, tests_of(row), rng=np.random.default_rng([seed, list(ROWS).index(row)])), path)
    return config


def zone_effect(damper, row: str) -> dict:
    """Per test: rms and largest difference of the row's noise-free curves from the same cable without
    its zones, magnitude [%] (of ln|f|) and phase [deg]."""
    zoned, uniform = (bench_config(damper, row, zones).ideal() for zones in (True, False))
    out = {}
    f = STANDARD_GRID_HZ
    for t in TESTS:
        amp = test_amplitude(t, f)
        fz, fu = (response(damper, f, amp, c.params, c.effects, tol=c.slip_tol, max_iter=c.slip_max_iter)[0]
                  for c in (zoned, uniform))
        d = np.log(fz / fu)
        out[t] = {"magnitude_rms_pct": float(100 * np.sqrt(np.mean(d.real**2))),
                  "magnitude_max_pct": float(100 * np.abs(d.real).max()),
                  "phase_rms_deg": float(np.degrees(np.sqrt(np.mean(_wrap_rad(d.imag) ** 2)))),
                  "phase_max_deg": float(np.degrees(np.abs(_wrap_rad(d.imag)).max()))}
    return out


def _wrap_rad(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def run_law(damper, law: str, seed: int, tmp: Path, families=fitted_laws(), time_runs: int = TIME_RUNS,
            recorded: Path | None = None) -> dict:
    """One row (``law`` a key of :data:`ROWS`): record (or read ``recorded/<law>.csv``), diagnose, compare the
    verdict's curves with the truth."""
    if recorded is None:
        path = tmp / f"{law}.csv"
        config = record_row(damper, law, seed, path, time_runs)
    else:  # written by --data with the same seed and runs
        path = recorded / f"{law}.csv"
        config = bench_config(damper, law, time_runs=time_runs)
    bench = clean_bench(load_bench(path))
    t0 = time.perf_counter()
    verdict = diagnose(damper, bench, seed=seed, progress=False, store=tmp / law,
                       config=DiagnoseConfig(laws=tuple(families)))
    t_diag = time.perf_counter() - t0
    comparison = verdict.get("law") or {}
    out = {"law": law, "verdict": verdict["verdict"], "verdict_law": comparison.get("best"),
           "law_settled": comparison.get("settled"), "outscored_by": comparison.get("outscored_by", []),
           "diagnose_s": t_diag, "secondary": verdict.get("secondary"), "families": comparison.get("families", {})}
    if verdict["verdict"] != "strand_slip":
        return out
    # the verdict's stored posterior (what `sbcal predict` would use): its median curves, with the harmonic
    # refit's stored correction where the refit was used, vs the noise-free bench
    run = tmp / law / damper.name / "cable-dry"
    summary, draws = read_cable(run)
    like = cable_likelihood(damper, bench, list(summary["tests"]), summary["law"])
    med = {k: np.array([np.median(v)]) for k, v in draws.items() if k in like.prior.names}
    correction = stored_correction(run)
    fuu = like.model(like.damper, like.freq_hz, **med)[0] * (1.0 if correction is None else correction)
    truth = np.concatenate([response(damper, lk.freq_hz, lk.amplitude_mm_pp, config.ideal().params,
                                     config.ideal().effects)[0] for lk in like.likes])
    over_draws = median_over_draws(like, draws, fuu, correction)
    out.update(per_test=_errors(like, summary["tests"], fuu, truth), converged=bool(summary["converged"]),
               per_test_over_draws=_errors(like, summary["tests"], over_draws, truth),
               r_hat_max=summary.get("r_hat_max"), ess_bulk_min=summary.get("ess_bulk_min"),
               wall_s=summary.get("wall_s"), harmonic_refit=summary.get("harmonic_refit"))
    if ROWS[law].get("time"):  # the first-harmonic model's own best fit (its mode, from the median) beside it
        z, _ = polish_mode(like, like.prior.z_of({k: float(v[0]) for k, v in med.items()})[0])
        first = like.model(like.damper, like.freq_hz, **dict(zip(like.prior.names, like.prior.to_natural(z[None]).T)))[0]
        out["per_test_first_harmonic"] = _errors(like, summary["tests"], first, truth)
    return out


def median_over_draws(like, draws, fuu, correction=None, n_draws: int = 400):
    """What ``sbcal predict`` shows: per line the median over (up to ``n_draws``) posterior draws of the curve's
    magnitude and phase (``correction`` applied), over the likelihood's lines; the phase taken relative to ``fuu``
    (the median set's curve), so that no line wraps."""
    names = [k for k in like.prior.names if k in draws]
    n = np.asarray(draws[names[0]]).size
    pick = np.linspace(0, n - 1, min(n, n_draws)).astype(int)
    with np.errstate(all="ignore"):
        curves = np.concatenate([like.model(like.damper, like.freq_hz, **{k: np.asarray(draws[k])[i] for k in names})
                                 for i in np.array_split(pick, max(1, pick.size // 50))])
        r = curves * (1.0 if correction is None else correction) / fuu
        return fuu * np.nanmedian(np.abs(r), axis=0) * np.exp(1j * np.nanmedian(np.angle(r), axis=0))


def _cells(per_test: dict) -> str:
    """A row's per-test errors in one line: ``test magnitude%/phase-deg ...``."""
    return " ".join(f"{t} {v['magnitude_pct']:.2f}/{v['phase_deg']:.2f}" for t, v in per_test.items())


def _errors(like, tests, fuu, truth) -> dict:
    """Per test: rms error of the curves ``fuu`` against ``truth`` (both over the likelihood's lines), magnitude [%]
    (of ln|f|) and phase [deg]."""
    rows, start = {}, 0
    for t, lk in zip(tests, like.likes):
        n = lk.freq_hz.size
        f, g = fuu[start:start + n], truth[start:start + n]
        start += n
        rows[t] = {"amplitude_mm_pp": float(lk.amplitude_mm_pp[0]),
                   "magnitude_pct": float(100 * np.sqrt(np.mean(np.log(np.abs(f) / np.abs(g)) ** 2))),
                   "phase_deg": float(np.sqrt(np.mean(_wrap_deg(np.degrees(np.angle(f) - np.angle(g))) ** 2)))}
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2029)
    ap.add_argument("--rows", "--laws", dest="rows", nargs="+", choices=list(ROWS), default=list(ROWS),
                    help="the rows to run (default all; --laws is the old name)")
    ap.add_argument("--families", nargs="+", choices=list(fitted_laws()), default=list(fitted_laws()))
    ap.add_argument("--json", metavar="OUT")
    ap.add_argument("--data", metavar="DIR", help="only record each row's bench CSV into DIR (and, for a zoned row, "
                                                  "its difference from the cable without zones); no diagnosis")
    ap.add_argument("--time-runs", type=int, default=TIME_RUNS, metavar="N",
                    help=f"runs per test of a time row (default {TIME_RUNS})")
    ap.add_argument("--keep", metavar="DIR", type=Path, help="keep the rows' bench CSVs and diagnosis stores in DIR")
    ap.add_argument("--recorded", metavar="DIR", type=Path,
                    help="diagnose the rows' bench CSVs that --data wrote into DIR (same --seed and --time-runs)")
    args = ap.parse_args(argv)
    if args.time_runs < 2:
        print(f"--time-runs {args.time_runs}: must be >= 2 (a line's scatter needs two runs)", file=sys.stderr)
        return 2
    if args.data:
        return record_only(args)
    missing = [r for r in args.rows if args.recorded and not (args.recorded / f"{r}.csv").is_file()]
    if missing:
        print(f"--recorded {args.recorded}: no {', '.join(r + '.csv' for r in missing)} (write it with --data first)",
              file=sys.stderr)
        return 2
    results, ok = [], True
    with tempfile.TemporaryDirectory() as tmp:
        if args.keep:
            args.keep.mkdir(parents=True, exist_ok=True)
            tmp = args.keep
        (Path(tmp) / "stub.toml").write_text(STUB)
        damper = load_damper(Path(tmp) / "stub.toml")
        for law in args.rows:
            r = run_law(damper, law, args.seed, Path(tmp), args.families, args.time_runs, args.recorded)
            results.append(r)
            print(f"data {law}: verdict {r['verdict']} ({r['verdict_law']} law), secondary "
                  f"{(r['secondary'] or {}).get('effect')}; "
                  f"diagnose {r['diagnose_s']:.0f} s")
            for family, f in r["families"].items():
                print(f"  {family:9s} ELPD {f['elpd']:10.1f}, best family - this one {f['delta_elpd']:8.1f} +- "
                      f"{f['se_delta']:6.1f}, converged {f.get('converged')} (R-hat max {f.get('r_hat_max')}, "
                      f"ESS min {f.get('ess_min')}, tau max {f.get('tau_max')})")
            if r["verdict"] != "strand_slip":
                ok = False
                continue
            # the targets: 2 % / 1.5 deg for a fitted family's own data (recorded in time too: issue 36) and
            # for the zoned rows (with a zoned law: issue 20), 4 % / 3 deg across laws
            data_law = ROWS[law]["law"]
            matched = r["verdict_law"] == data_law and data_law in args.families
            zoned_row = "zoned_" in law
            mag_t, ph_t = (2.0, 1.5) if matched or zoned_row else (4.0, 3.0)
            if r.get("law_settled") is False:  # compare_families: a family that did not converge scores clearly higher
                print(f"  verdict law {r['verdict_law']} NOT SETTLED ({', '.join(r['outscored_by'])} clearly higher, not "
                      "converged): its curves below are not a result: MISSED")
                ok = False
            if zoned_row and not str(r["verdict_law"]).endswith("_zoned"):
                print(f"  zoned row: verdict law {r['verdict_law']} is not zoned: MISSED")
                ok = False
            meets = all(v["magnitude_pct"] <= mag_t and v["phase_deg"] <= ph_t for v in r["per_test"].values())
            cells = _cells(r["per_test"])
            print(f"  verdict model {r['verdict_law']}: converged {r['converged']} (R-hat max {r['r_hat_max']}, ESS min "
                  f"{r['ess_bulk_min']}); rms % / deg vs noise-free: {cells}  target {mag_t:g} % / {ph_t:g} deg: "
                  + ("met" if meets else "MISSED"))
            cells = _cells(r["per_test_over_draws"])
            print(f"  (the median over the draws of each line's curve, as sbcal predict shows it: {cells})")
            if "per_test_first_harmonic" in r:
                refit = r.get("harmonic_refit") or {}
                cells = _cells(r["per_test_first_harmonic"])
                print(f"  harmonic refit: {'used' if refit.get('used') else 'not used'} ({refit.get('reason', 'not made')}); "
                      f"the first-harmonic model's mode: {cells}")
            ok &= meets and r["converged"]
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    print("all targets met" if ok else "some target missed")
    return 0 if ok else 1


def record_only(args) -> int:
    """``--data DIR``: the rows' bench CSVs, and each zoned row's distance from its uniform cable."""
    out = Path(args.data)
    out.mkdir(parents=True, exist_ok=True)
    (out / "stub.toml").write_text(STUB)
    damper = load_damper(out / "stub.toml")
    results = {}
    for row in args.rows:
        t0 = time.perf_counter()
        record_row(damper, row, args.seed, out / f"{row}.csv", args.time_runs)
        print(f"{row}: wrote {out / (row + '.csv')} ({time.perf_counter() - t0:.0f} s)")
        if ROWS[row]["zones"]:
            results[row] = zone_effect(damper, row)
            print("  noise-free, zoned vs the same cable without zones (rms / largest line), magnitude % | phase deg:")
            for t, v in results[row].items():
                print(f"  {t:8s} {v['magnitude_rms_pct']:6.1f} / {v['magnitude_max_pct']:6.1f} | "
                      f"{v['phase_rms_deg']:5.1f} / {v['phase_max_deg']:5.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
