"""Subcommands of design: ``predict`` (a new damper), ``span`` (a damper on a conductor)."""

from __future__ import annotations

import sys

import numpy as np

from ..core.errors import InputError
from .options import parse_frequencies, quiet_option, scale_options, seed_value


__all__ = ["add_predict", "cmd_predict", "add_span", "cmd_span", "add_design", "cmd_design"]

# --- predict -----------------------------------------------------------------------------------

def add_predict(sub):
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
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("-o", "--output", metavar="OUT.csv", help="also write the CSV here")
    p.add_argument("--plot", metavar="PNG", help="also write the figure here")
    quiet_option(p)
    return p


def cmd_predict(args) -> int:
    from ..design.cable_run import load_cable_run
    from ..design.predict import predict
    from ..design.predict_plots import plot_prediction, plot_sweep
    from ..design.predict_store import store_prediction, store_sweep, write_csv
    from ..design.sweep import parse_sweep, sweep
    from ..model.damper import resolve_damper

    cable = load_cable_run(args.cable)
    damper = resolve_damper(args.damper)
    freq = parse_frequencies(args.frequencies)
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
              + (" (the calibration damper: its posterior offsets)" if res.own_offsets else "")
              + ("; with its harmonic refit's multi-harmonic correction" if res.harmonic_correction else ""))
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

def add_span(sub):
    p = sub.add_parser("span", help="a damper on a conductor span: aeolian vibration, fatigue margin, placement",
                       description="The energy balance method (docs/span.md): for each Strouhal frequency of the wind "
                                   "band the antinode amplitude Y_max, the bending amplitude Y_b at 89 mm from the clamp "
                                   "and the Poffenberger-Swart stress against the fatigue limit, with the damper's "
                                   "amplitude-dependent impedance from a stored cable fit (median and 90 % band over its "
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
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed of the draws (default 0)")
    p.add_argument("--optimise", "--optimize", action="store_true",
                   help="also find the position (one damper per equipped end) that maximises the 10 %% quantile of "
                        "the worst-case margin over the band; plot the margin against position")
    p.add_argument("--no-model-error", action="store_true",
                   help="the damper's band from the cable posterior and the tolerances alone, without the "
                        "calibration's model discrepancy (as 'sbcal predict --no-model-error'; docs/span.md)")
    p.add_argument("--life", action="store_true",
                   help="also the conductor's service life (Miner damage per year on its S-N curve) under the wind "
                        "climate of --climate, with and without the dampers (life.csv, life.png)")
    p.add_argument("--climate", metavar="SPEC",
                   help="wind climate for --life: weibull:k=K,c=C (C in m/s) or a CSV histogram (wind_m_s, "
                        "hours_per_year[, turbulence_intensity])")
    p.add_argument("--across", type=float, default=1.0, metavar="SHARE",
                   help="share of the time the wind blows across the line, for --life (default 1.0)")
    p.add_argument("--wave", choices=("travelling", "standing"), default="travelling",
                   help="damper power: travelling-wave termination (default, exact for point dampers) or the "
                        "standing-wave formula (light dampers)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default <runs>/span/<label>/, <runs> the store holding the cable run, "
                        "runs/ for a bare span)")
    p.add_argument("--json", metavar="FILE", help="also write the summary JSON here")
    quiet_option(p)
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


def cmd_span(args) -> int:
    from ..design.span_study import span_study, store_span

    wind = _parse_wind(args.wind)
    if args.draws < 2:
        raise InputError(f"--draws {args.draws}: must be >= 2")
    if args.life and not args.climate:
        raise InputError("--life: give the wind climate with --climate (e.g. weibull:k=2.0,c=4.5 or a CSV file)")
    try:
        study = span_study(args.conductor, args.damper, cable=args.cable, position_m=args.position, ends=args.dampers,
                           wind=wind, n_freq=args.lines, n_draws=args.draws, seed=args.seed, optimise=args.optimise,
                           wave=args.wave, model_error=not args.no_model_error, climate=args.climate,
                           across=args.across)
    except InputError as e:  # the library names its keywords; say them as options
        text = str(e)
        for key, opt in (("position_m: ", "--position: "), ("position: ", "--position: "), ("wind: ", "--wind: "),
                         ("n_freq: ", "--lines: "), ("optimise: ", "--optimise: ")):
            text = text.replace(key, opt, 1) if text.startswith(key) or f"; {key}" in text else text
        raise InputError(text) from None
    out = store_span(study, args.output, meta={"made_by": args.command_line}, json_path=args.json)
    for w in study.warnings:
        print(f"sbcal: warning: {w}", file=sys.stderr)
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
        wl = study.worst_line()
        me = study.model_error
        band = ("posterior and tolerances" if me is None else
                "posterior, tolerances and model discrepancy" if any(me["logmag_sd"] + me["phase_sd_deg"]) else
                "posterior and tolerances; no model discrepancy: the cable fit is complete")
        print(f"  worst line  : {wl['frequency_hz']:.3g} Hz (wind {wl['wind_m_s']:.3g} m/s), stress "
              f"{wl['stress_mpa']['median']:.3g} [{wl['stress_mpa']['q05']:.3g}, {wl['stress_mpa']['q95']:.3g}] MPa "
              f"(band: {band})")
    p = study.placement
    if p is not None:
        q = round(100 * p.quantile)
        print(f"  placement   : best {p.best_position_m:.3g} m (margin q{q:02d} {p.best_margin:.3g}, "
              f"{p.positions_m.size} positions {p.positions_m[0]:.3g}-{p.positions_m[-1]:.3g} m): "
              f"one damper {'at each end' if p.ends == 2 else 'at one end'} "
              f"{'suffices' if p.suffices else 'does NOT suffice'}")
    if study.life is not None:
        for line in study.life.words():
            print(f"  life        : {line}")
    print(f"stored in {out}/" + (f"; wrote {args.json}" if args.json else ""))
    return 0


# --- design ------------------------------------------------------------------------------------

def add_design(sub):
    p = sub.add_parser("design", help="a damper designed for a line: the design that maximises the span's margin or life",
                       description="Search a design space of damper-file fields (masses, arm lengths, offsets) for the "
                                   "damper, built with a calibrated cable, that maximises the 10 % quantile over the "
                                   "cable posterior of the worst-case fatigue margin of a conductor span (or of its "
                                   "service life), with the damper(s) at their best position (docs/design.md). "
                                   "Stored as <runs>/design/<label>/ (best.toml, designs.csv, design.png, summary.json).")
    p.add_argument("--conductor", required=True, metavar="NAME|PATH", help="bundled conductor or conductor TOML")
    p.add_argument("--cable", required=True, metavar="RUN", help="stored cable fit (e.g. runs/damper1/cable-dry)")
    p.add_argument("--damper", required=True, metavar="NAME|PATH",
                   help="the starting damper (bundled name or TOML): the fields the space does not vary keep its values")
    p.add_argument("--space", required=True, metavar="SPACE.toml",
                   help="the design space: [vary] \"mass1.mass_kg\" = [1.0, 3.0] ...; [constraints] total_mass_kg_max ...")
    p.add_argument("--objective", choices=("margin", "life"), default="margin",
                   help="maximise the 10 %% quantile of the worst-case margin (default) or of the service life")
    p.add_argument("--climate", metavar="SPEC", help="wind climate for --objective life (as sbcal span --climate)")
    p.add_argument("--across", type=float, default=1.0, metavar="SHARE",
                   help="share of the time the wind blows across the line (default 1.0)")
    p.add_argument("--dampers", type=int, choices=(1, 2), default=1, metavar="N",
                   help="span ends equipped: 1 (default) or 2")
    p.add_argument("--budget", type=int, default=120, metavar="N", help="designs evaluated at most (default 120)")
    p.add_argument("--wind", default="1:7", metavar="MIN:MAX", help="wind band [m/s] (default 1:7)")
    p.add_argument("--lines", type=int, default=60, metavar="N",
                   help="frequencies of the final evaluation (default 60, as sbcal span)")
    p.add_argument("--draws", type=int, default=200, metavar="N",
                   help="posterior draws of the final evaluation (default 200, as sbcal span)")
    p.add_argument("--search-grid", default="20,30,12", metavar="DRAWS,LINES,POSITIONS",
                   help="the cheaper grid each design of the search is evaluated on: posterior draws, lines of the "
                        "band, candidate positions (default 20,30,12); the start and the best are then evaluated "
                        "with --draws and --lines")
    p.add_argument("--no-model-error", action="store_true",
                   help="the cable posterior and tolerances alone, without the calibration's model discrepancy")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed of the optimiser and the draws (default 0)")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="output directory (default <runs>/design/<label>/, <runs> the store holding the cable run)")
    scale_options(p, "designs of a generation evaluated in parallel local processes")
    return p


def cmd_design(args) -> int:
    from ..design.cable_run import load_cable_run
    from ..design.conductor import resolve_conductor
    from ..design.life import check_across, parse_climate
    from ..design.search import design
    from ..design.search_store import design_dir, store_design
    from ..design.space import load_space
    from ..design.vibration import wind_check
    from ..model.damper import resolve_damper
    from ..pipeline import executor_for

    wind = _parse_wind(args.wind)
    wind_check(wind)
    if args.draws < 2:
        raise InputError(f"--draws {args.draws}: must be >= 2")
    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    if args.objective == "life" and not args.climate:
        raise InputError("--objective life: give the wind climate with --climate (e.g. weibull:k=2.0,c=4.5)")
    grid = _parse_grid(args.search_grid)
    climate = parse_climate(args.climate) if args.climate else None
    across = check_across(args.across)
    conductor = resolve_conductor(args.conductor)
    start = resolve_damper(args.damper)
    space = load_space(args.space, start)  # the input files first, then the run store
    cable = load_cable_run(args.cable)
    try:
        with executor_for(args.scheduler) as executor:
            res = design(conductor, cable.path, start, space, objective=args.objective, climate=climate, across=across,
                         ends=args.dampers, budget=args.budget, seed=args.seed, workers=args.workers,
                         executor=executor, wind=wind, n_freq=args.lines, n_draws=args.draws,
                         model_error=not args.no_model_error, progress=not args.quiet, search=grid)
    except InputError as e:
        text = str(e)
        for key, opt in (("budget: ", "--budget: "), ("climate: ", "--climate: "), ("objective: ", "--objective: ")):
            text = opt + text[len(key):] if text.startswith(key) else text
        raise InputError(text) from None
    out = store_design(res, args.output or design_dir(res, start.name), meta={"made_by": args.command_line})
    for w in res.warnings:
        print(f"sbcal: warning: {w}", file=sys.stderr)
    what = "margin" if res.objective == "margin" else "service life [years]"
    print(f"{conductor.name}: design of {start.name} with the {cable.damper} {cable.state} cable ({cable.law}); "
          f"{len(space.fields)} free field(s), {len(res.records)} designs evaluated "
          f"({res.optimiser['generations']} generations of {res.optimiser['popsize']})")
    for name, rec in (("start", res.start), ("best", res.best)):
        m = rec["margin"]
        fields = ", ".join(f"{k} = {v:.4g}" for k, v in rec["fields"].items())
        print(f"  {name:5s}: {fields}; total mass {rec['total_mass_kg']:.3g} kg; at {rec['position_m']:.3g} m: "
              f"{what} q10 {_number_or_unlimited(rec['objective'])} (margin {m['median']:.3g} [{m['q05']:.3g}, "
              f"{m['q95']:.3g}])"
              + ("  EXTRAPOLATED" if rec["extrapolated"] else ""))
    same = "".join(f" {opt} {value}" for opt, value, default in (
        ("--dampers", args.dampers, 1), ("--wind", args.wind, "1:7"), ("--lines", args.lines, 60),
        ("--draws", args.draws, 200), ("--seed", args.seed, 0)) if value != default)
    same += " --no-model-error" if args.no_model_error else ""
    print(f"stored in {out}/ (sbcal span --conductor {args.conductor} --damper {out}/best.toml --cable {cable.path} "
          f"--optimise{same} reproduces the best)")
    return 0


def _number_or_unlimited(x: float) -> str:
    return f"{x:.4g}" if np.isfinite(x) else "unlimited"


def _parse_grid(text: str):
    from ..design.search import Search

    try:
        d, lines, pos = (int(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--search-grid {text!r}: expected three integers DRAWS,LINES,POSITIONS, e.g. 20,30,12") from None
    if d < 2 or lines < 2 or pos < 2:
        raise InputError(f"--search-grid {text!r}: each of DRAWS, LINES, POSITIONS must be >= 2")
    return Search(n_draws=d, n_freq=lines, n_positions=pos)
