"""Subcommands of the recordings and the calibration: ``simulate``, ``sample``, ``data``, ``map``,
``report``, ``run``, ``bench``."""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from .options import (bench_for, bench_options, check_dampers, cleaned_for, deprecated_alias, parse_frequencies,
                      parse_set, print_summary, quiet_option, scale_options, seed_value, settings_from,
                      workers_option)


__all__ = [
    "add_simulate", "cmd_simulate", "add_sample", "cmd_sample", "add_data", "cmd_data", "add_map", "cmd_map",
    "add_report", "cmd_report", "add_run", "cmd_run", "add_bench", "cmd_bench",
]

# --- simulate ----------------------------------------------------------------------------------

def add_simulate(sub):
    p = sub.add_parser("simulate", help="write the model's prediction as a bench CSV",
                       description="Evaluate the forward model and write f_uu as a bench CSV (run = 1).")
    p.add_argument("--damper", required=True, help="bundled damper name or TOML path")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter value (repeatable)")
    p.add_argument("--amplitude", type=float, default=1.0, metavar="MM", help="amplitude [mm p-p] (default 1)")
    p.add_argument("--test", metavar="LABEL", help="test label (default: from the amplitude, e.g. 1-1)")
    p.add_argument("--frequencies", default="standard", metavar="standard|LIST",
                   help="'standard' (37 lines, 4-40 Hz) or comma-separated Hz")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    quiet_option(p)
    return p


def cmd_simulate(args) -> int:
    from ..data.bench import curves_to_frame, test_label, write_bench
    from ..model.damper import resolve_damper
    from ..model.fem import dynamic_stiffness

    damper = resolve_damper(args.damper)
    params = parse_set(args.set)
    freq = parse_frequencies(args.frequencies)
    if not (np.isfinite(args.amplitude) and args.amplitude > 0):
        raise InputError(f"--amplitude {args.amplitude}: must be > 0")
    fuu = dynamic_stiffness(damper, freq, **params)
    test = args.test or test_label(args.amplitude)
    write_bench(curves_to_frame(damper.name, test, freq, args.amplitude, fuu), args.output)
    print(f"wrote {args.output}: {damper.name} {test}, {freq.size} lines")
    return 0


def add_sample(sub):
    p = sub.add_parser("sample", help="posterior of EJ and beta per test (emcee), stored as ArviZ netCDF",
                       description="Sample the posterior of some tests (--tests) or every test (--all) of a "
                                   "damper and store runs/<damper>/<test>/<paramset>/posterior.nc + summary.json.")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--tests", nargs="+", metavar="LABEL", help="test labels")
    deprecated_alias(which, "--test", "--tests", "tests", append=True)
    which.add_argument("--all", action="store_true", help="every test of the damper in the bench file")
    p.add_argument("--damper", default="damper1", help="bundled damper name or TOML path (default damper1)")
    bench_options(p)
    p.add_argument("--params", default="theta1", metavar="SET", help="parameter set (default theta1)")
    p.add_argument("--priors", metavar="PATH", help="prior file (default: the bundled priors/default.toml)")
    deprecated_alias(p, "--prior", "--priors", "priors")
    p.add_argument("--method", choices=("bayes", "point", "ga"), default="bayes",
                   help="bayes: the posterior (default); point: the thesis's point fit only, its cost minimised by "
                        "differential evolution (the baseline; 'ga' is the same, named after the thesis's "
                        "genetic algorithm)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    deprecated_alias(p, "--out", "--runs", "runs")
    scale_options(p, "tests in parallel processes")
    return p


def cmd_sample(args) -> int:
    from ..inference.calibrate import point_fit_test
    from ..inference.priors import load_prior
    from ..model.damper import resolve_damper
    from ..pipeline import executor_for, sample_tests

    damper = resolve_damper(args.damper)
    bench = bench_for(args)
    tests = bench.tests(damper.name) if args.all else args.tests
    for t in tests:
        bench.test(damper.name, t)  # fail early, before any sampling, on an unknown label
    settings = settings_from(args)
    load_prior(args.params, damper, args.priors)  # fail early on a bad set or file, before anything is stored
    data = cleaned_for(bench, [damper], store=args.runs, settings=settings, quiet=args.quiet)
    if args.method in ("point", "ga"):
        for t in tests:
            doc = point_fit_test(damper, data, t, paramset=args.params, seed=args.seed, out=args.runs,
                                 prior_path=args.priors)
            vals = ", ".join(f"{k}={v:.4g}" for k, v in doc["parameters"].items())
            print(f"{damper.name} {t} {args.params} (GA point fit): {vals}; cost {doc['cost']:.4g}, "
                  f"{doc['generations']} generations, {doc['wall_s']:.1f} s")
        return 0
    with executor_for(args.scheduler) as executor:
        done = sample_tests(data, [(damper, t) for t in tests], store=args.runs, settings=settings, executor=executor,
                            command=args.command_line, reuse=False, progress=not args.quiet)
    for (name, t), (s, _) in done.items():
        print_summary(name, t, args.params, s)
    print(f"stored in {args.runs}/{damper.name}/<test>/{args.params}/")
    return 0


# --- data --------------------------------------------------------------------------------------

def add_data(sub):
    p = sub.add_parser("data", help="check bench recordings: runs, grid, amplitudes, CV, outlier runs",
                       description="Validate a bench CSV and report per damper and test: runs, frequency grid, "
                                   "amplitudes, the median coefficient of variation (thesis 2.5) at <= 15 Hz and "
                                   "> 15 Hz before -> after removing outlier runs (Z-score on whole curves, 2.6).")
    bench_options(p)
    p.add_argument("--json", metavar="OUT", help="also write the summary as JSON")
    p.add_argument("--z-threshold", type=float, default=None, metavar="Z",
                   help="outlier run-score threshold (default 3)")
    quiet_option(p)
    return p


def _fmt_cv(cv: dict, name: str) -> str:
    def pair(d):
        return "/".join("-" if v is None else f"{v:.1f}" for v in d[name].values())
    return f"{pair(cv['raw'])} -> {pair(cv['clean'])}"


def cmd_data(args) -> int:
    from ..core._io import write_json
    from ..data.cleaning import DEFAULT_Z_THRESHOLD
    from ..data.summary import bench_summary, summary_notes

    z = DEFAULT_Z_THRESHOLD if args.z_threshold is None else args.z_threshold
    bench = bench_for(args)
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

def add_map(sub):
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
    bench_options(p, "bench file for --joint")
    p.add_argument("--json", metavar="OUT", help="write the fit as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="figure: EJ and beta versus amplitude, every damper in the run store")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED")
    quiet_option(p)
    return p


def cmd_map(args) -> int:
    from ..core._io import write_json
    from ..inference.amplitude import amplitude_map, map_from_store, points_from_table, stored_maps

    if args.table:
        doc, fits = amplitude_map(points_from_table(args.table), seed=args.seed)
        docs = {"table": dict(doc, draws={law: f.draws for law, f in fits.items()})}  # the draws for --plot's band
        key = "table"
    else:
        from ..inference.store import dampers

        for name in dampers(args.runs):  # every damper's map is a stage of the run store (map.json + map.nc)
            map_from_store(args.runs, name, args.params, seed=args.seed, include_oiled=args.include_oiled)
        docs = stored_maps(args.runs)
        if args.damper not in docs:
            have = ", ".join(docs) or "none"
            raise InputError(f"{args.runs}: no finished {args.params} runs of {args.damper!r} at 3+ amplitudes "
                             f"(dampers with enough runs: {have}); run 'sbcal sample --all --damper {args.damper}' first")
        key = args.damper
        if args.joint:
            from ..inference.amplitude import joint_from_runs
            from ..model.damper import resolve_damper

            doc = docs[key]
            damper = resolve_damper(args.damper)
            data = cleaned_for(bench_for(args), [damper], store=args.runs, settings=settings_from(args))
            joint = joint_from_runs(damper, data, args.runs, doc, args.params,
                                    seed=args.seed, progress=None if args.quiet else f"{args.damper} joint")
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
        from ..inference.amplitude import plot_map

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

def add_report(sub):
    p = sub.add_parser("report", help="write an HTML summary of the stored runs",
                       description="Write a self-contained static HTML report (one index.html, its figures inside; figures/ beside it) of what the "
                                   "run store holds; it recomputes nothing.")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="report directory (default report/)")
    p.add_argument("--params", default="theta1", metavar="SET", help="parameter set (default theta1)")
    workers_option(p, "processes drawing the figures")
    quiet_option(p)
    return p


def cmd_report(args) -> int:
    from ..report.build import build_report

    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    index = build_report(args.runs, args.output, paramset=args.params, command=args.command_line,
                         workers=args.workers)
    print(f"wrote {index}")
    return 0


def add_run(sub):
    from ..pipeline import STAGES

    p = sub.add_parser("run", help="the whole job: clean, sample every test, diagnose, map, report",
                       description="Every stage for the chosen dampers, one way through the run store: clean, "
                                   "sample every test, diagnose missing physics, fit the amplitude map, write the "
                                   "HTML report. A stored result is reused only when everything it was made from is "
                                   "unchanged (bench rows, damper file, prior file, settings, seed, sbcal version); "
                                   "each stage says reused or redone, and why.")
    p.add_argument("--damper", action="append", metavar="NAME|PATH",
                   help="damper (repeatable; default: every damper of the bench file that is bundled); with "
                        "--design, a unit's name in the bench file")
    p.add_argument("--design", metavar="NAME|PATH",
                   help="the bench file's dampers are units of this design (a production lot: then sbcal batch)")
    bench_options(p)
    p.add_argument("--params", default="theta1", metavar="SET")
    p.add_argument("--priors", metavar="PATH", help="prior file (default: the bundled priors/default.toml)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED")
    scale_options(p)
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="report directory (default report/)")
    p.add_argument("--until", default="report", choices=STAGES, metavar="STAGE",
                   help=f"stop after this stage, its results stored ({', '.join(STAGES)}; default report: the whole job)")
    return p


def cmd_run(args) -> int:
    from dataclasses import replace

    from ..model.damper import bundled_dampers, resolve_damper
    from ..pipeline import executor_for, run

    bench = bench_for(args)
    if args.design:  # a lot: every damper of the file (or each --damper name) is a unit of this design
        design = resolve_damper(args.design)
        dampers = [replace(design, name=n) for n in (args.damper or bench.dampers())]
    else:
        names = args.damper or [d for d in bench.dampers() if d in bundled_dampers()]
        if not names:
            raise InputError(f"{bench.source}: none of its dampers ({', '.join(bench.dampers())}) is bundled; "
                             "name a description with --damper PATH, or the design of a lot's units with --design")
        dampers = [resolve_damper(n) for n in names]
    check_dampers(bench, dampers)
    settings = settings_from(args)
    with executor_for(args.scheduler) as executor:
        index = run(bench, dampers, store=args.runs, report_dir=args.output, settings=settings, executor=executor,
                    command=args.command_line, progress=not args.quiet, until=args.until)
    print(f"wrote {index}" if index is not None else f"stopped after {args.until}: results stored in {args.runs}")
    return 0


# --- bench -------------------------------------------------------------------------------------

def add_bench(sub):
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
    p.add_argument("--runs-per-test", type=int, default=24, metavar="N", help="runs per test (default 24)")
    deprecated_alias(p, "--runs", "--runs-per-test", "runs_per_test")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("--ideal", action="store_true", help="no run-to-run scatter, noise or outliers")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv",
                   help="the bench CSV; with --raw the truth lines of the raw files (no line noise or outliers)")
    lot = p.add_argument_group("a production lot (docs/batch.md)")
    lot.add_argument("--units", type=int, metavar="N",
                     help="record N units of the design drawn from a population (EJ 5 %%, loss factor 10 %%, slip "
                          "scale 10 %%), named <damper>-u01 ...")
    lot.add_argument("--outlier-unit", type=int, metavar="K", help="with --units: unit K (1-based) planted at EJ -15 %%")
    raw = p.add_argument_group("raw recordings (time-domain strand slip only; docs/virtual_bench.md)")
    raw.add_argument("--raw", metavar="DIR", help="write each run's time series as DIR/<damper>_<test>_run<k>.tdms "
                                                  "(or .h5) and the channel map DIR/channels.toml; -o gets their "
                                                  "truth lines")
    raw.add_argument("--raw-format", choices=("tdms", "hdf5"), help="raw file format (default tdms)")
    raw.add_argument("--sample-rate", type=float, metavar="HZ", help="sampling rate (default 2560)")
    raw.add_argument("--sensor-noise", type=float, metavar="REL",
                     help="white noise per channel over its RMS (default 1e-3; 0: none)")
    raw.add_argument("--hold-periods", type=int, metavar="N", help="steady periods held at each line (default 40)")
    quiet_option(p)
    return p


def _bench_raw(args, damper, config, tests) -> int:
    """``sbcal bench --raw``: each run's raw file, the channel map and the truth lines as the bench CSV."""
    from pathlib import Path

    from ..data.bench import write_bench
    from ..simulate.raw_bench import iter_raw, truth_frame, write_channel_map, write_raw
    from ..simulate.virtual_bench import test_amplitude

    slip = config.effects.get("strand_slip")
    if slip is None or not slip.time_domain:
        raise InputError("--raw: the raw recordings need the time-domain strand slip "
                         "(--effect strand_slip=...,time:1)")
    for test in tests:
        test_amplitude(test, 1.0)  # every label checked before any file is written
    flags = {"rate_hz": "--sample-rate", "noise": "--sensor-noise", "hold_periods": "--hold-periods"}
    options = {key: getattr(args, flag[2:].replace("-", "_")) for key, flag in flags.items()}
    options = {key: value for key, value in options.items() if value is not None}  # else the library's defaults
    rng = np.random.default_rng(args.seed)
    runs = []
    try:
        for test in tests:
            for run in iter_raw(damper, config, test, rng=rng, progress=None if args.quiet else f"{damper.name} {test}", **options):
                write_raw(args.raw, run, args.raw_format or "tdms")
                runs.append(run)
    except InputError as e:
        key, colon, rest = str(e).partition(":")
        if colon and key in flags:  # a setting's own message, named by its option
            raise InputError(f"{flags[key]}:{rest}") from None
        raise
    write_channel_map(Path(args.raw) / "channels.toml")
    write_bench(truth_frame(runs), args.output)
    print(f"wrote {len(runs)} raw files and channels.toml to {args.raw}, truth lines to {args.output}: "
          f"{damper.name}, {len(tests)} tests x {args.runs_per_test} runs")
    return 0


def _bench_lot(args, damper, config, tests) -> int:
    """``sbcal bench --units N``: a virtual lot of one design (:mod:`sbcal.simulate.virtual_lot`)."""
    from ..data.bench import write_bench
    from ..simulate.virtual_lot import LotConfig, record_lot

    if args.units < 1:
        raise InputError(f"--units {args.units}: must be >= 1")
    if args.outlier_unit is not None and not 1 <= args.outlier_unit <= args.units:
        raise InputError(f"--outlier-unit {args.outlier_unit}: expected a unit 1..{args.units}")
    lot = LotConfig(units=args.units, bench=config,
                    outlier=None if args.outlier_unit is None else args.outlier_unit - 1)
    frame, truth = record_lot(damper, lot, tests, rng=np.random.default_rng(args.seed))
    write_bench(frame, args.output)
    planted = [u for u, t in truth.items() if t["outlier"]]
    print(f"wrote {args.output}: {args.units} units of {damper.name} ({next(iter(truth))} ...), {len(tests)} tests x "
          f"{args.runs_per_test} runs, effects: {', '.join(config.effects) or 'none'}"
          + (f"; {planted[0]} planted at EJ {lot.outlier_ej:+.0%}" if planted else ""))
    return 0


def cmd_bench(args) -> int:
    from ..data.bench import write_bench
    from ..model.damper import resolve_damper
    from ..simulate.virtual_bench import DEFAULT_TESTS, BenchConfig, parse_effect, record

    damper = resolve_damper(args.damper)
    params = parse_set(args.set)
    effects = {}
    for spec in args.effect or ():
        try:
            name, value = parse_effect(spec)
        except InputError as e:
            raise InputError(f"--{e}") from None
        if name in effects:
            raise InputError(f"--effect {spec!r}: {name} is given twice")
        effects[name] = value
    if args.runs_per_test < 1:
        raise InputError(f"--runs-per-test {args.runs_per_test}: must be >= 1")
    config = BenchConfig(params=params, effects=effects, runs=args.runs_per_test)
    tests = args.tests or DEFAULT_TESTS
    if args.raw:
        return _bench_raw(args, damper, config.ideal() if args.ideal else config, tests)
    for flag in ("raw_format", "sample_rate", "sensor_noise", "hold_periods"):
        if getattr(args, flag) is not None:
            raise InputError(f"--{flag.replace('_', '-')}: only with --raw DIR")
    if args.units is not None:
        return _bench_lot(args, damper, config.ideal() if args.ideal else config, tests)
    if args.outlier_unit is not None:
        raise InputError("--outlier-unit: only with --units N")
    frame = record(damper, config.ideal() if args.ideal else config, tests, rng=np.random.default_rng(args.seed))
    write_bench(frame, args.output)
    print(f"wrote {args.output}: {damper.name}, {len(tests)} tests x {args.runs_per_test} runs, "
          f"effects: {', '.join(effects) or 'none'}")
    return 0
