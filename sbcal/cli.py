"""The ``sbcal`` command line: a thin adapter over the library.

Each subcommand is a pair ``_add_<name>(subparsers)`` / ``_cmd_<name>(args) -> int``; bad input
ends in one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import shlex
import sys

import numpy as np

from .core.errors import InputError
from .core.version import __version__
from .core.workers import default_workers, one_blas_thread


__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message}")


def _parse_set(items) -> dict:
    """``["EJ=9", "beta=0.3"]`` -> ``{"EJ": 9.0, "beta": 0.3}``, names checked against the model."""
    from .model.fem import PARAMETER_NAMES

    out = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        if name not in PARAMETER_NAMES:
            raise InputError(f"--set {item!r}: unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}")
        try:
            x = float(value)
        except ValueError:
            raise InputError(f"--set {item!r}: {value!r} is not a number") from None
        if not np.isfinite(x):
            raise InputError(f"--set {item!r}: value is not finite")
        out[name] = x
    return out


def _parse_frequencies(text: str) -> np.ndarray:
    from .model.fem import STANDARD_GRID_HZ

    if text == "standard":
        return STANDARD_GRID_HZ.copy()
    try:
        f = np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise InputError(f"--frequencies {text!r}: expected 'standard' or comma-separated numbers [Hz]") from None
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"--frequencies {text!r}: frequencies must be finite and > 0")
    return f


# --- simulate ----------------------------------------------------------------------------------

def _add_simulate(sub):
    p = sub.add_parser("simulate", help="write the model's prediction as a bench CSV",
                       description="Evaluate the forward model and write f_uu as a bench CSV (run = 1).")
    p.add_argument("--damper", required=True, help="bundled damper name or TOML path")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter value (repeatable)")
    p.add_argument("--amplitude", type=float, default=1.0, metavar="MM", help="amplitude [mm p-p] (default 1)")
    p.add_argument("--test", metavar="LABEL", help="test label (default: from the amplitude, e.g. 1-1)")
    p.add_argument("--frequencies", default="standard", metavar="standard|LIST",
                   help="'standard' (37 lines, 4-40 Hz) or comma-separated Hz")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    return p


def _cmd_simulate(args) -> int:
    from .data.bench import curves_to_frame, test_label, write_bench
    from .model.damper import resolve_damper
    from .model.fem import dynamic_stiffness

    damper = resolve_damper(args.damper)
    params = _parse_set(args.set)
    freq = _parse_frequencies(args.frequencies)
    if not (np.isfinite(args.amplitude) and args.amplitude > 0):
        raise InputError(f"--amplitude {args.amplitude}: must be > 0")
    fuu = dynamic_stiffness(damper, freq, **params)
    test = args.test or test_label(args.amplitude)
    write_bench(curves_to_frame(damper.name, test, freq, args.amplitude, fuu), args.output)
    print(f"wrote {args.output}: {damper.name} {test}, {freq.size} lines")
    return 0


# --- sample ------------------------------------------------------------------------------------

def _bench_options(p, what="bench file"):
    p.add_argument("--bench", metavar="PATH", help=f"{what}: .csv, .csv.gz, .xlsx or .parquet (default: the bundled data)")
    p.add_argument("--sheet", metavar="NAME", help="read only this sheet of an .xlsx workbook (default: every sheet)")


def _workers_option(p, what):
    p.add_argument("--workers", type=int, default=default_workers(), metavar="N",
                   help=f"{what} (default: 2 or the cores there are)")


def _scale_options(p, workers_help="jobs in parallel local processes"):
    _workers_option(p, workers_help)
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the jobs to a running Dask distributed cluster (e.g. tcp://host:8786; "
                        "pip install \"sbcal[dask]\")")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_sample(sub):
    p = sub.add_parser("sample", help="posterior of EJ and beta per test (emcee), stored as ArviZ netCDF",
                       description="Sample the posterior of one test (--test) or every test (--all) of a "
                                   "damper and store runs/<damper>/<test>/<paramset>/posterior.nc + summary.json.")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--test", action="append", metavar="LABEL", help="test label (repeatable)")
    which.add_argument("--all", action="store_true", help="every test of the damper in the bench file")
    p.add_argument("--damper", default="damper1", help="bundled damper name or TOML path (default damper1)")
    _bench_options(p)
    p.add_argument("--params", default="theta1", metavar="SET", help="parameter set (default theta1)")
    p.add_argument("--priors", "--prior", dest="priors", metavar="PATH",
                   help="prior file (default: the bundled priors/default.toml)")
    p.add_argument("--method", choices=("bayes", "point", "ga"), default="bayes",
                   help="bayes: the posterior (default); point: the thesis's point fit only, its cost minimised by "
                        "differential evolution (the baseline; 'ga' is the same, named after the thesis's "
                        "genetic algorithm)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", default="runs", metavar="DIR", help="run store (default runs/)")
    _scale_options(p, "tests in parallel processes")
    return p


def _bench_for(args):
    """The ``--bench`` file, or the bundled data."""
    from .data.readers import default_bench_path, load_bench

    if args.bench:
        return load_bench(args.bench, sheet=getattr(args, "sheet", None))
    path = default_bench_path()
    if not path.is_file():
        raise InputError(f"no bundled bench data ({path} is missing); pass --bench PATH")
    return load_bench(path, sheet=getattr(args, "sheet", None))


def _settings(args, **extra):
    from .pipeline import Settings

    if getattr(args, "workers", 1) < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    if args.priors:
        from .pipeline import file_digest

        file_digest(args.priors)  # fail early on a missing prior file
    return Settings(paramset=getattr(args, "params", "theta1"), seed=args.seed, priors=args.priors,
                    workers=getattr(args, "workers", 1), **extra)


def _print_summary(name, t, paramset, s):
    p = s["parameters"]
    flag = "" if s["converged"] else f"  NOT CONVERGED ({s['reason']})"
    print(f"{name} {t} {paramset}: EJ {p['EJ']['median']:.3g} [{p['EJ']['q05']:.3g}, "
          f"{p['EJ']['q95']:.3g}] N m^2, " + ", ".join(
              f"{n} {p[n]['median']:.3g} [{p[n]['q05']:.3g}, {p[n]['q95']:.3g}]"
              for n in p if n.startswith("beta")) + f", R-hat max {s['r_hat_max']:.3f}, "
          f"ESS min {min(s['ess_bulk_min'], s['ess_tail_min']):.0f}, {s['wall_s']:.1f} s{flag}")


def _cmd_sample(args) -> int:
    from .inference.calibrate import point_fit_test
    from .model.damper import resolve_damper
    from .pipeline import executor_for, sample_tests

    damper = resolve_damper(args.damper)
    bench = _bench_for(args)
    tests = bench.tests(damper.name) if args.all else args.test
    for t in tests:
        bench.test(damper.name, t)  # fail early, before any sampling, on an unknown label
    settings = _settings(args)
    if args.method in ("point", "ga"):
        for t in tests:
            doc = point_fit_test(damper, bench, t, paramset=args.params, seed=args.seed, out=args.out,
                                 prior_path=args.priors)
            vals = ", ".join(f"{k}={v:.4g}" for k, v in doc["parameters"].items())
            print(f"{damper.name} {t} {args.params} (GA point fit): {vals}; cost {doc['cost']:.4g}, "
                  f"{doc['generations']} generations, {doc['wall_s']:.1f} s")
        return 0
    with executor_for(args.scheduler) as executor:
        done = sample_tests(bench, [(damper, t) for t in tests], args.out, settings, executor=executor,
                            command=args.command_line, reuse=False, progress=not args.quiet)
    for (name, t), (s, _) in done.items():
        _print_summary(name, t, args.params, s)
    print(f"stored in {args.out}/{damper.name}/<test>/{args.params}/")
    return 0


# --- data --------------------------------------------------------------------------------------

def _add_data(sub):
    p = sub.add_parser("data", help="check bench recordings: runs, grid, amplitudes, CV, outlier runs",
                       description="Validate a bench CSV and report per damper and test: runs, frequency grid, "
                                   "amplitudes, the median coefficient of variation (thesis 2.5) at <= 15 Hz and "
                                   "> 15 Hz before -> after removing outlier runs (Z-score on whole curves, 2.6).")
    _bench_options(p)
    p.add_argument("--json", metavar="OUT", help="also write the summary as JSON")
    p.add_argument("--z-threshold", type=float, default=None, metavar="Z",
                   help="outlier run-score threshold (default 3)")
    return p


def _fmt_cv(cv: dict, name: str) -> str:
    def pair(d):
        return "/".join("-" if v is None else f"{v:.1f}" for v in d[name].values())
    return f"{pair(cv['raw'])} -> {pair(cv['clean'])}"


def _cmd_data(args) -> int:
    from .core._io import write_json
    from .data.cleaning import DEFAULT_Z_THRESHOLD
    from .data.summary import bench_summary, summary_notes

    z = DEFAULT_Z_THRESHOLD if args.z_threshold is None else args.z_threshold
    bench = _bench_for(args)
    summary = bench_summary(bench, z)
    if args.json:
        write_json(args.json, summary, indent=1)
    n_tests = sum(len(t) for t in summary.values())
    print(f"{bench.source}: {len(bench.frame)} rows; dampers: {len(summary)}, tests: {n_tests}; "
          f"outlier runs: score > {z:g}; CV: median % at f<=15/f>15 Hz, all runs -> kept runs")
    for damper, tests in summary.items():
        print(damper)
        print(f"  {'test':<12}{'runs':>5}  {'removed':<12}{'lines':>5}  {'f [Hz]':<11}{'amp [mm p-p]':<14}"
              f"{'CV |F|':<22}CV phase")
        for label, t in tests.items():
            removed = ",".join(map(str, t["removed_runs"])) or "-"
            amps = ",".join(f"{a:g}" for a in t["amplitude_mm_pp"])
            grid = f"{t['frequency_min_hz']:g}-{t['frequency_max_hz']:g}"
            print(f"  {label:<12}{t['runs']:>5}  {removed:<12}{t['n_frequencies']:>5}  {grid:<11}{amps:<14}"
                  f"{_fmt_cv(t['cv_median_pct'], 'magnitude'):<22}{_fmt_cv(t['cv_median_pct'], 'phase')}")
            for note in summary_notes(t):
                print(f"    ^ {note}")
    if args.json:
        print(f"wrote {args.json}")
    return 0


# --- map ---------------------------------------------------------------------------------------

def _add_map(sub):
    p = sub.add_parser("map", help="EJ and beta versus amplitude: power law and saturating law with intervals",
                       description="Fit EJ(A) = k (A/1mm)^-n and EJ(A) = EJ_inf + c A^-n to the stored per-test "
                                   "posteriors (errors in variables), and the loss factor's trend.")
    p.add_argument("--damper", default="damper1", help="damper whose map --json holds (default damper1)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    p.add_argument("--params", default="theta1", metavar="SET", help="parameter set of the runs (default theta1)")
    p.add_argument("--table", metavar="CSV", help="fit a plain table (amplitude_mm_pp, ej_nm2[, ej_sd]) instead")
    p.add_argument("--include-oiled", action="store_true", help="keep oiled tests in the fit")
    p.add_argument("--joint", action="store_true",
                   help="also run the joint model: one emcee run over all constant-amplitude tests of --damper "
                        "with EJ on the power law (k, n sampled), beta per test (a minute or two)")
    _bench_options(p, "bench file for --joint")
    p.add_argument("--json", metavar="OUT", help="write the fit as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="figure: EJ and beta versus amplitude, every damper in the run store")
    p.add_argument("--seed", type=int, default=0)
    return p


def _cmd_map(args) -> int:
    from pathlib import Path

    from .core._io import write_json
    from .inference.amplitude import amplitude_map, map_from_store, points_from_table, stored_maps

    if args.table:
        doc, _ = amplitude_map(points_from_table(args.table), seed=args.seed)
        docs = {"table": doc}
        key = "table"
    else:
        root = Path(args.runs)
        from .design.span_study import SPAN_STORE

        names = sorted(p.name for p in root.iterdir() if p.is_dir() and p.name != SPAN_STORE) if root.is_dir() else []
        for name in names:  # every damper's map is a stage of the run store (map.json + map.nc)
            map_from_store(args.runs, name, args.params, seed=args.seed, include_oiled=args.include_oiled)
        docs = stored_maps(args.runs)
        if args.damper not in docs:
            have = ", ".join(docs) or "none"
            raise InputError(f"{args.runs}: no finished {args.params} runs of {args.damper!r} at 3+ amplitudes "
                             f"(dampers with enough runs: {have}); run 'sbcal sample --all --damper {args.damper}' first")
        key = args.damper
        if args.joint:
            from .inference.amplitude import joint_from_runs
            from .model.damper import resolve_damper

            doc = docs[key]
            joint = joint_from_runs(resolve_damper(args.damper), _bench_for(args), args.runs, doc, args.params,
                                    seed=args.seed, progress=f"{args.damper} joint")
            doc["joint"] = joint
            flag = "" if joint["converged"] else f" NOT CONVERGED ({joint['convergence']['reason']})"
            print(f"{key}: joint model k {joint['k'][0]:.3g} [{joint['k'][1]:.3g}, {joint['k'][2]:.3g}] N m^2, "
                  f"n {joint['n'][0]:.3f} [{joint['n'][1]:.3f}, {joint['n'][2]:.3f}], R-hat {joint['r_hat']:.3f}, "
                  f"{joint['wall_s']:.0f} s{flag}; {joint['comparison']}")
    for name, doc in docs.items():
        pl, sat = doc["powerlaw"], doc["saturating"]
        print(f"{name}: EJ = k (A/1mm)^-n with k {pl['k'][0]:.3g} [{pl['k'][1]:.3g}, {pl['k'][2]:.3g}] N m^2, "
              f"n {pl['n'][0]:.3f} [{pl['n'][1]:.3f}, {pl['n'][2]:.3f}]; saturating EJ_inf "
              f"{sat['EJ_inf'][0]:.3g} [{sat['EJ_inf'][1]:.3g}, {sat['EJ_inf'][2]:.3g}]"
              + (f", EJ_static/EJ_inf {sat['reduction_factor'][0]:.3g} "
                 f"[{sat['reduction_factor'][1]:.3g}, {sat['reduction_factor'][2]:.3g}]" if "reduction_factor" in sat else "")
              + f"; preferred: {doc['preferred']}"
              + ("" if doc["converged"] else "  NOT CONVERGED: " + _map_problems(doc)))
        if doc.get("beta"):
            b = doc["beta"]["powerlaw"]
            print(f"{name}: beta = k (A/1mm)^-n with k {b['k'][0]:.3g} [{b['k'][1]:.3g}, {b['k'][2]:.3g}], "
                  f"n {b['n'][0]:.3f} [{b['n'][1]:.3f}, {b['n'][2]:.3f}]")
    if args.json:
        def public(doc):  # the law draws are for plots, not JSON
            return {k: v for k, v in doc.items() if k != "draws"}

        out = public(docs[key])
        out["others"] = {k: public(v) for k, v in docs.items() if k != key}
        write_json(args.json, out, indent=2)
    if args.plot:
        from .inference.amplitude import plot_map

        plot_map(docs, args.plot)
    return 0


def _map_problems(doc) -> str:
    """Why a map is flagged: its own fits or the per-test posteriors it rests on."""
    parts = [f"{law} fit: {doc[law]['convergence']['reason']}" for law in ("powerlaw", "saturating")
             if not doc[law]["convergence"]["converged"]]
    if doc.get("inputs_not_converged"):
        parts.append("per-test posteriors not converged: " + ", ".join(doc["inputs_not_converged"]))
    return "; ".join(parts)


# --- report and run ----------------------------------------------------------------------------

def _add_report(sub):
    p = sub.add_parser("report", help="write an HTML summary of the stored runs",
                       description="Write a self-contained static HTML report (index.html + figures/) of what the "
                                   "run store holds; it recomputes nothing.")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="report directory (default report/)")
    p.add_argument("--params", default="theta1", metavar="SET", help="parameter set (default theta1)")
    _workers_option(p, "processes drawing the figures")
    return p


def _cmd_report(args) -> int:
    from .report.build import build_report

    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    index = build_report(args.runs, args.output, paramset=args.params, command=args.command_line,
                         workers=args.workers)
    print(f"wrote {index}")
    return 0


def _add_run(sub):
    from .pipeline import STAGES

    p = sub.add_parser("run", help="the whole job: clean, sample every test, diagnose, map, report",
                       description="Every stage for the chosen dampers, one way through the run store: clean, "
                                   "sample every test, diagnose missing physics, fit the amplitude map, write the "
                                   "HTML report. A stored result is reused only when everything it was made from is "
                                   "unchanged (bench rows, damper file, prior file, settings, seed, sbcal version); "
                                   "each stage says reused or redone, and why.")
    p.add_argument("--damper", action="append", metavar="NAME|PATH",
                   help="damper (repeatable; default: every damper of the bench file that is bundled)")
    _bench_options(p)
    p.add_argument("--params", default="theta1", metavar="SET")
    p.add_argument("--priors", metavar="PATH", help="prior file (default: the bundled priors/default.toml)")
    p.add_argument("--seed", type=int, default=0)
    _scale_options(p)
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="report directory (default report/)")
    p.add_argument("--until", default="report", choices=STAGES, metavar="STAGE",
                   help=f"stop after this stage, its results stored ({', '.join(STAGES)}; default report: the whole job)")
    return p


def _cmd_run(args) -> int:
    from .model.damper import bundled_dampers, resolve_damper
    from .pipeline import executor_for, run

    bench = _bench_for(args)
    names = args.damper or [d for d in bench.dampers() if d in bundled_dampers()]
    if not names:
        raise InputError(f"{bench.source}: none of its dampers ({', '.join(bench.dampers())}) is bundled; "
                         "name a description with --damper PATH")
    dampers = [resolve_damper(n) for n in names]
    for d in dampers:
        if d.name not in bench.dampers():
            raise InputError(f"{bench.source}: no rows of damper {d.name!r} (has: {', '.join(bench.dampers())})")
    settings = _settings(args)
    with executor_for(args.scheduler) as executor:
        index = run(bench, dampers, args.runs, args.output, settings, executor=executor,
                    command=args.command_line, progress=not args.quiet, until=args.until)
    print(f"wrote {index}" if index is not None else f"stopped after {args.until}: results stored in {args.runs}")
    return 0


# --- bench -------------------------------------------------------------------------------------

def _add_bench(sub):
    p = sub.add_parser("bench", help="record the virtual shaker bench (concealed physics) as a bench CSV",
                       description="Run the virtual bench (docs/virtual_bench.md): repeated runs of each test from "
                                   "physics richer than the calibration model, with run-to-run scatter, "
                                   "measurement noise and outlier runs, written as a bench CSV.")
    p.add_argument("--damper", required=True, help="bundled damper name or TOML path")
    p.add_argument("--effect", action="append", metavar="NAME=VALUE",
                   help="concealed effect (repeatable): strand_slip, fixture_mass, sensor_delay, viscous_damping, "
                        "asymmetric_damping, base_rocking, frequency_dependent_stiffness, fixture_resonance")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="model parameter (repeatable; default EJ = 0.1 ej_static, beta = 0.3)")
    p.add_argument("--tests", nargs="+", metavar="LABEL",
                   help="test labels A-B (default: the thesis's plan 0.1-0.1 0.2-0.2 0.3-0.3 0.4-0.4 0.5-0.5 "
                        "1-1 2-2 2-1)")
    p.add_argument("--runs", type=int, default=24, metavar="N", help="runs per test (default 24)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (default 0)")
    p.add_argument("--ideal", action="store_true", help="no run-to-run scatter, noise or outliers")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    return p


def _cmd_bench(args) -> int:
    from .data.bench import write_bench
    from .model.damper import resolve_damper
    from .simulate.virtual_bench import DEFAULT_TESTS, BenchConfig, parse_effect, record

    damper = resolve_damper(args.damper)
    params = _parse_set(args.set)
    effects = {}
    for spec in args.effect or ():
        try:
            name, value = parse_effect(spec)
        except InputError as e:
            raise InputError(f"--{e}") from None
        if name in effects:
            raise InputError(f"--effect {spec!r}: {name} is given twice")
        effects[name] = value
    if args.runs < 1:
        raise InputError(f"--runs {args.runs}: must be >= 1")
    if args.seed < 0:
        raise InputError(f"--seed {args.seed}: must be >= 0")
    config = BenchConfig(params=params, effects=effects, runs=args.runs)
    tests = args.tests or DEFAULT_TESTS
    frame = record(damper, config.ideal() if args.ideal else config, tests, rng=np.random.default_rng(args.seed))
    write_bench(frame, args.output)
    print(f"wrote {args.output}: {damper.name}, {len(tests)} tests x {args.runs} runs, "
          f"effects: {', '.join(effects) or 'none'}")
    return 0


# --- diagnose ----------------------------------------------------------------------------------

def _add_diagnose(sub):
    p = sub.add_parser("diagnose", help="locate the misfit, name the missing physics, model it, show the fit improve",
                       description="Fit the per-test model, locate where the recordings leave its predictive band, "
                                   "refit the catalogue's physics extensions the residuals point to, compare them "
                                   "by PSIS-LOO and give a verdict (docs/diagnose.md).")
    p.add_argument("--damper", default="damper1", metavar="NAME|PATH",
                   help="bundled damper name or TOML path (default damper1)")
    _bench_options(p)
    p.add_argument("--tests", nargs="+", metavar="LABEL", help="test labels (default: all of the damper's)")
    p.add_argument("--priors", metavar="PATH", help="prior file of the base parameters (default: the bundled one)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the diagnosis as JSON")
    p.add_argument("--curves", metavar="OUT.csv",
                   help="write the fitted curves (posterior median per line) of the per-test model and of the verdict's "
                        "model in the bench CSV columns plus a 'model' column")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="also store it as DIR/<damper>/diagnose.json for the report, and a strand-slip verdict's "
                        "cable law as DIR/<damper>/cable-<state>/ (default runs/)")
    _scale_options(p, "fits in parallel local processes")
    return p


def _cmd_diagnose(args) -> int:
    from dataclasses import replace
    from pathlib import Path

    from .core._io import write_json
    from .diagnosis.diagnose import diagnose
    from .model.damper import resolve_damper
    from .pipeline import diagnose_inputs, executor_for

    damper = resolve_damper(args.damper)
    bench = _bench_for(args)
    settings = _settings(args)
    config = replace(settings.diagnose, workers=args.workers)
    with executor_for(args.scheduler) as executor:
        if executor is not None:  # the diagnosis as one job on the cluster
            result = executor.submit(diagnose, damper, bench, args.tests, seed=args.seed,
                                     config=replace(config, workers=1), progress=False,
                                     prior_path=args.priors, store=args.runs).result()
        else:
            result = diagnose(damper, bench, args.tests, seed=args.seed, config=config, progress=not args.quiet,
                              prior_path=args.priors, store=args.runs)
    result["command"] = args.command_line
    if args.tests is None:  # a whole-damper diagnosis: 'sbcal run' may reuse it while its inputs hold
        result["inputs"] = diagnose_inputs(bench, damper, settings)
    if args.json:
        write_json(args.json, result, indent=1)
    stored = Path(args.runs) / damper.name / "diagnose.json"
    write_json(stored, result, indent=1)
    if args.curves:
        from .data.bench import write_bench
        from .diagnosis.diagnose import curves_frame

        write_bench(curves_frame(result), args.curves)
    print(f"{damper.name}: verdict {result['verdict']}" + (f" ({result['law']['best']} law)" if result.get("law") else ""))
    for b in result["bands"][:12]:
        print(f"  off: {b['test']} {b['quantity']} {b['f_lo']:g}-{b['f_hi']:g} Hz (|z| up to {b['max_abs_z']:.1f})")
    if len(result["bands"]) > 12:
        print(f"  ... {len(result['bands']) - 12} more bands")
    for r in result["ranking"]:
        print(f"  {r['effect']:30s} delta ELPD {r['delta_elpd']:10.1f} +- {r['se']:7.1f}, "
              f"removes {r['explained']:.0%} of the misfit in the bands")
    if result["parameters"]:
        print(f"  {result['parameters']['words']}")
    b, a = result["before"], result["after"]
    print(f"  before: rms z {b['rms_z']:.2f}, 90% band coverage {b['coverage_90']:.3f}, "
          f"{b['lines_off']}/{b['n_lines']} lines off")
    if a is not b and a["effect"] != "baseline":
        flag = "" if a["converged"] else f"  NOT CONVERGED ({'; '.join(a['not_converged'].values())})"
        print(f"  after ({a['effect']}): rms z {a['rms_z']:.2f}, 90% band coverage {a['coverage_90']:.3f}, "
              f"{a['lines_off']}/{a['n_lines']} lines off{flag}")
    sec = result.get("secondary")
    if sec and sec.get("effect"):
        print(f"  secondary: {sec['effect']}: {sec['parameters']['words']}")
    elif sec is not None:
        print("  secondary: none" + ("" if sec["misfit"] else " (no misfit left beyond chance)"))
    print(f"stored in {stored}" + (f" and {args.json}" if args.json else "")
          + (f"; curves in {args.curves}" if args.curves else ""))
    return 0


# --- cable -------------------------------------------------------------------------------------

_LAW_ALIASES = {"dahl": "bouc_wen", "iwan": "iwan5"}  # the families that contain Dahl's and Segalman's laws


def _add_cable(sub):
    from .model.hysteresis import FITTED_LAWS

    p = sub.add_parser("cable", help="fit the cable's hysteresis law jointly over all amplitudes of each cable state",
                       description="Fit one strand-slip law per cable state (dry; a test suffix such as -oiled is "
                                   "another state) over all its tests at once, on the distributed cable model "
                                   "(docs/cable.md), and store each state's posterior as "
                                   "<runs>/<damper>/cable-<state>/posterior.nc + summary.json.")
    p.add_argument("--damper", default="damper1", metavar="NAME|PATH",
                   help="bundled damper name or TOML path (default damper1)")
    _bench_options(p)
    p.add_argument("--law", default="best", choices=list(FITTED_LAWS) + list(_LAW_ALIASES) + ["best"],
                   help="law family: bouc_wen (the Bouc-Wen family, Dahl's law at sharpness 1; alias dahl), iwan5 "
                        "(Iwan with two cut-offs, Segalman's 4-parameter law as a limit; alias iwan), iwan_tail (Iwan "
                        "whose density ends in a power-law tail; compared only where every cable state has two tests "
                        "or more), or best (every family that can be compared, the best by PSIS-LOO; default)")
    p.add_argument("--priors", metavar="PATH", help="prior file of the geometry boxes (default: the bundled one)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    _workers_option(p, "processes per fit")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _cmd_cable(args) -> int:
    from dataclasses import asdict
    from pathlib import Path

    from .inference.cable_fit import fit_damper_cable, store_cable
    from .model.damper import resolve_damper

    damper = resolve_damper(args.damper)
    bench = _bench_for(args)
    if damper.name not in bench.dampers():
        raise InputError(f"{bench.source}: no rows of damper {damper.name!r} (has: {', '.join(bench.dampers())})")
    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    laws = None if args.law == "best" else (_LAW_ALIASES.get(args.law, args.law),)
    fits, comparison = fit_damper_cable(damper, bench, laws=laws, seed=args.seed, prior_path=args.priors,
                                        workers=args.workers, progress=not args.quiet)
    best = comparison["best"]
    for state, fit in sorted(fits[best].items()):
        out = Path(args.runs) / damper.name / f"cable-{state}"
        s = store_cable(fit, out, meta={"seed": args.seed, "made_by": args.command_line, "damper_values": asdict(damper)},
                        comparison=comparison if len(fits) > 1 else None)
        flag = "" if s["converged"] else f"  NOT CONVERGED ({s['reason']})"
        vals = ", ".join(f"{n} {p['median']:.3g} [{p['q05']:.3g}, {p['q95']:.3g}]" for n, p in s["parameters"].items())
        print(f"{damper.name} cable {state} ({best}, {len(fit.tests)} tests): {vals}; R-hat max {s['r_hat_max']:.3f}, "
              f"ESS min {min(s['ess_bulk_min'], s['ess_tail_min']):.0f}, {s['wall_s']:.0f} s{flag}")
        print(f"  stored in {out}/")
    if len(fits) > 1:
        print("  families by PSIS-LOO (summed over the cable states): " + "; ".join(
            f"{law} {v['delta_elpd']:.1f} +- {v['se_delta']:.1f}" for law, v in comparison["families"].items())
            + f" (best: {best})")
    return 0


# --- predict -----------------------------------------------------------------------------------

def _add_predict(sub):
    p = sub.add_parser("predict", help="a new damper from the calibrated cable: dynamic stiffness, power, resonances",
                       description="The posterior predictive of a damper built with a calibrated cable (docs/predict.md): "
                                   "dynamic stiffness (magnitude, phase), dissipated power and the resonance frequencies, "
                                   "each as median and 90 % band, propagating the cable posterior and the damper's "
                                   "tolerances; lines that bend the arms beyond the calibrated curvature are marked. "
                                   "Stored as <runs>/<calibration damper>/predict-<damper>-<state>/.")
    p.add_argument("--cable", required=True, metavar="RUN",
                   help="stored cable-law posterior written by 'sbcal cable' (e.g. runs/damper1/cable-dry)")
    p.add_argument("--damper", required=True, metavar="NAME|PATH", help="the new damper: bundled name or TOML path")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--amplitude", type=float, nargs="+", metavar="MM",
                      help="constant clamp amplitudes [mm p-p] (default: the calibration's constant-amplitude tests)")
    mode.add_argument("--velocity", type=float, nargs="+", metavar="M_PER_S",
                      help="constant clamp velocities [m/s] (IEC 61897's characteristic test, e.g. 0.1)")
    p.add_argument("--frequencies", default="standard", metavar="standard|LIST",
                   help="'standard' (37 lines, 4-40 Hz) or comma-separated Hz; a sweep's resonance search spans them")
    p.add_argument("--sweep", metavar="NAME=START:STOP:N",
                   help="design sweep of a damper-file field (e.g. cable.length1_m=0.15:0.30:7): resonances and peak "
                        "power against it")
    p.add_argument("--draws", type=int, default=None, metavar="N",
                   help="posterior draws used (default 300; 200 for a sweep)")
    p.add_argument("--no-model-error", action="store_true",
                   help="bands of the cable posterior and the tolerances alone, without the calibration's residual "
                        "scale (docs/predict.md)")
    p.add_argument("--bench-effects", action="store_true",
                   help="apply the calibration bench's fitted measurement-chain effects (delay, fixture mass, rocking)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("-o", "--output", metavar="OUT.csv", help="also write the CSV here")
    p.add_argument("--plot", metavar="PNG", help="also write the figure here")
    return p


def _cmd_predict(args) -> int:
    from .design.cable_run import load_cable_run
    from .design.predict import predict
    from .design.predict_plots import plot_prediction, plot_sweep
    from .design.predict_store import store_prediction, store_sweep, write_csv
    from .design.sweep import parse_sweep, sweep
    from .model.damper import resolve_damper

    cable = load_cable_run(args.cable)
    damper = resolve_damper(args.damper)
    freq = _parse_frequencies(args.frequencies)
    if args.draws is not None and args.draws < 2:
        raise InputError(f"--draws {args.draws}: must be >= 2")
    meta = {"made_by": args.command_line}
    warning = cable.convergence_warning()
    if warning:
        print(f"sbcal: warning: {warning}", file=sys.stderr)
    unit = "m/s" if args.velocity else "mm p-p"
    if args.sweep:
        key, values = parse_sweep(args.sweep)
        res = sweep(cable, damper, key, values, amplitude_mm_pp=args.amplitude, velocity_m_s=args.velocity,
                    freq_hz=freq, n_draws=args.draws or 200, seed=args.seed, bench_effects=args.bench_effects)
        out = store_sweep(res, meta=meta)
        print(f"{damper.name}: sweep of {key} over {values[0]:g}..{values[-1]:g} ({values.size} values), "
              f"{cable.damper} {cable.state} cable ({cable.law}), {res.n_draws} draws")
        for i, lv in enumerate(res.levels):
            for v, x in enumerate(values):
                hz = res.resonance_hz[v, i]
                peaks = ", ".join(f"{q[1]:.3g}" for q in hz if np.isfinite(q[1]))
                flag = "  EXTRAPOLATED" if res.extrapolated[v, i] else ""
                print(f"  {lv:g} {unit}, {key} = {x:g}: resonances {peaks or '-'} Hz; peak power "
                      f"{res.peak_power_w[v, i, 1]:.3g} W{flag}")
        plot = plot_sweep
    else:
        res = predict(cable, damper, amplitude_mm_pp=args.amplitude, velocity_m_s=args.velocity, freq_hz=freq,
                      n_draws=args.draws or 300, seed=args.seed, bench_effects=args.bench_effects,
                      model_error=not args.no_model_error)
        out = store_prediction(res, meta=meta)
        print(f"{damper.name}: predicted with the {cable.damper} {cable.state} cable ({cable.law}), {res.n_draws} draws"
              + (" (the calibration damper: its posterior offsets)" if res.own_offsets else ""))
        for i, lv in enumerate(res.levels):
            rs = [r for r in res.resonances if r.level == lv]
            text = "; ".join(f"{r.freq_hz[1]:.3g} [{r.freq_hz[0]:.3g}, {r.freq_hz[2]:.3g}] Hz" for r in rs) or "none"
            n_ex, folds = int(res.extrapolated[i].sum()), res.freq_hz[res.fold_share[i] > 0]
            print(f"  {lv:g} {unit}: resonances {text}; peak power {np.nanmax(res.power_w[i, 1]):.3g} W"
                  + (f"; {n_ex} extrapolated lines ({res.freq_hz[res.extrapolated[i]].min():g}-"
                     f"{res.freq_hz[res.extrapolated[i]].max():g} Hz)" if n_ex else "")
                  + (f"; folds at {', '.join(f'{x:g}' for x in folds)} Hz" if folds.size else ""))
        for w in res.warnings:
            if w != warning:
                print(f"sbcal: warning: {w}", file=sys.stderr)
        plot = plot_prediction
    if args.output:
        write_csv(res, args.output)
    if args.plot:
        plot(res, args.plot)
    print(f"stored in {out}/" + (f"; wrote {args.output}" if args.output else "") + (f" and {args.plot}" if args.plot else ""))
    return 0


# --- span --------------------------------------------------------------------------------------

def _add_span(sub):
    p = sub.add_parser("span", help="a damper on a conductor span: aeolian vibration, fatigue margin, placement",
                       description="The energy balance method (docs/span.md): for each Strouhal frequency of the wind "
                                   "band the antinode amplitude Y_max, the bending amplitude Y_b at 89 mm from the clamp "
                                   "and the Poffenberger-Swart stress against the fatigue limit, with the damper's "
                                   "amplitude-dependent impedance from a stored cable fit (median and 90 %% band over its "
                                   "posterior) and without a damper. Stored as <runs>/span/<conductor>-<damper>-<state>/ "
                                   "(span.csv, span.png, summary.json; placement.csv with --optimise).")
    p.add_argument("--conductor", required=True, metavar="NAME|PATH",
                   help="bundled conductor (drake, aster570) or a conductor TOML file (docs/span.md)")
    p.add_argument("--damper", metavar="RUN|NAME|PATH|none",
                   help="a stored cable fit (e.g. runs/damper1/cable-dry: its own damper and cable), or a damper "
                        "(bundled name or TOML path) built with the cable of --cable RUN; none or omitted: the bare span")
    p.add_argument("--cable", metavar="RUN", help="stored cable fit for a new damper given by --damper NAME|PATH")
    p.add_argument("--position", type=float, nargs="+", metavar="M",
                   help="damper distance from the suspension clamp [m] (several: several dampers at one end); "
                        "required with a damper unless --optimise")
    p.add_argument("--dampers", type=int, choices=(1, 2), default=1, metavar="N",
                   help="span ends equipped: 1 (default) or 2 (the same dampers mirrored at both ends)")
    p.add_argument("--wind", default="1:7", metavar="MIN:MAX", help="wind band [m/s] (default 1:7; at most 0:15)")
    p.add_argument("--lines", type=int, default=60, metavar="N", help="frequencies in the band (default 60)")
    p.add_argument("--draws", type=int, default=200, metavar="N", help="posterior draws used (default 200)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the draws (default 0)")
    p.add_argument("--optimise", "--optimize", action="store_true",
                   help="also find the position (one damper per equipped end) that maximises the 10 %% quantile of "
                        "the worst-case margin over the band; plot the margin against position")
    p.add_argument("--wave", choices=("travelling", "standing"), default="travelling",
                   help="damper power: travelling-wave termination (default, exact for point dampers) or the "
                        "standing-wave formula (light dampers)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default <runs>/span/<label>/, <runs> the store holding the cable run, "
                        "runs/ for a bare span)")
    p.add_argument("--json", metavar="FILE", help="also write the summary JSON here")
    p.add_argument("--quiet", action="store_true", help="print only the output directory (warnings still on stderr)")
    return p


def _parse_wind(text: str) -> tuple:
    lo, sep, hi = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(lo), float(hi)
    except ValueError:
        raise InputError(f"--wind {text!r}: expected MIN:MAX in m/s, e.g. 1:7") from None


def _margin_words(m: float) -> str:
    return "under the limit" if m >= 1 else "ABOVE the limit"


def _cmd_span(args) -> int:
    from .design.span_study import span_study, store_span

    wind = _parse_wind(args.wind)
    if args.draws < 2:
        raise InputError(f"--draws {args.draws}: must be >= 2")
    try:
        study = span_study(args.conductor, args.damper, cable=args.cable, position_m=args.position, ends=args.dampers,
                           wind=wind, n_freq=args.lines, n_draws=args.draws, seed=args.seed, optimise=args.optimise,
                           wave=args.wave)
    except InputError as e:  # the library names its keywords; say them as options
        text = str(e)
        for key, opt in (("position_m: ", "--position: "), ("position: ", "--position: "), ("wind: ", "--wind: "),
                         ("n_freq: ", "--lines: "), ("optimise: ", "--optimise: ")):
            text = text.replace(key, opt, 1) if text.startswith(key) or f"; {key}" in text else text
        raise InputError(text) from None
    out = store_span(study, args.output, meta={"made_by": args.command_line}, json_path=args.json)
    for w in study.warnings:
        print(f"sbcal: warning: {w}", file=sys.stderr)
    if not args.quiet:
        r, c = study.result, study.result.conductor
        ws = study.worst_stress_mpa()
        if study.cable:
            how = "its own cable" if study.cable_damper == study.damper else f"the {study.cable_damper} cable"
            src = f"{study.damper} with {how} ({study.state}, {study.law}; {study.cable}), {r.n_draws} draws"
        else:
            src = "no damper"
        print(f"{c.name}: {c.tension_pct_rts:.0f} % RTS, {c.span_length_m:g} m span; winds {r.wind_mps[0]:g}-"
              f"{r.wind_mps[-1]:g} m/s ({r.freq_hz.size} lines, {r.freq_hz[0]:.3g}-{r.freq_hz[-1]:.3g} Hz); {src}")
        print(f"  fatigue limit {r.limit_pa * 1e-6:.3g} MPa; margin = limit / worst stress over the band")
        print(f"  no damper   : worst stress {ws['bare']:.3g} MPa, margin {r.margin_bare:.3g} "
              f"({_margin_words(r.margin_bare)})")
        if r.positions_m:
            m = r.margin
            q05, q50, q95 = np.quantile(m, [0.05, 0.5, 0.95])
            where = ", ".join(f"{x:.3g}" for x in r.positions_m)
            ends = "both ends" if r.ends == 2 else "one end"
            print(f"  with damper : {r.n_dampers} damper{'s' if r.n_dampers > 1 else ''} at {where} m from the clamp "
                  f"({ends}): worst stress "
                  f"{ws['median']:.3g} [{ws['q05']:.3g}, {ws['q95']:.3g}] MPa, margin {q50:.3g} [{q05:.3g}, {q95:.3g}] "
                  f"(median [5 %, 95 %]; {_margin_words(q05)} for 95 % of the draws)")
        p = study.placement
        if p is not None:
            q = round(100 * p.quantile)
            print(f"  placement   : best {p.best_position_m:.3g} m (margin q{q:02d} {p.best_margin:.3g}, "
                  f"{p.positions_m.size} positions {p.positions_m[0]:.3g}-{p.positions_m[-1]:.3g} m): "
                  f"one damper {'at each end' if p.ends == 2 else 'at one end'} "
                  f"{'suffices' if p.suffices else 'does NOT suffice'}")
    print(f"stored in {out}/" + (f"; wrote {args.json}" if args.json else ""))
    return 0


# One line per subcommand; each helper pair lives above, in the order of this table.
_COMMANDS = {
    "simulate": (_add_simulate, _cmd_simulate),
    "sample": (_add_sample, _cmd_sample),
    "map": (_add_map, _cmd_map),
    "report": (_add_report, _cmd_report),
    "run": (_add_run, _cmd_run),
    "data": (_add_data, _cmd_data),
    "bench": (_add_bench, _cmd_bench),
    "diagnose": (_add_diagnose, _cmd_diagnose),
    "cable": (_add_cable, _cmd_cable),
    "predict": (_add_predict, _cmd_predict),
    "span": (_add_span, _cmd_span),
}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sbcal", description="Bayesian calibration of Stockbridge dampers.")
    parser.add_argument("--version", action="version", version=f"sbcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for add, _ in _COMMANDS.values():
        add(sub)
    return parser


def main(argv=None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input)."""
    parser = build_parser()
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        args = parser.parse_args(argv)
        args.command_line = " ".join(["sbcal"] + [shlex.quote(a) for a in argv])  # provenance
        if args.command is None:
            parser.print_help()
            return 2
        with one_blas_thread():  # every process of sbcal's: see sbcal/core/workers.py
            return _COMMANDS[args.command][1](args)
    except InputError as e:
        print(f"sbcal: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return 0
    except OSError as e:  # the file system refused (unwritable output, disk full ...): one line, no traceback
        where = f"{e.filename}: " if e.filename else ""
        print(f"sbcal: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sbcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
