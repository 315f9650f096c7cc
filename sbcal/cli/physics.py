"""Subcommands of the missing physics and the cable law: ``diagnose``, ``cable``."""

from __future__ import annotations

from ..diagnosis.remainder import headline
from ..inference.store import cable_dir, diagnose_path
from .options import quiet_option, bench_for, cleaned_for, damper_options, scale_options, seed_value, settings_from, workers_option


__all__ = ["add_diagnose", "cmd_diagnose", "add_cable", "cmd_cable"]

# --- diagnose ----------------------------------------------------------------------------------

def add_diagnose(sub):
    p = sub.add_parser("diagnose", help="locate the misfit, name the missing physics, model it, show the fit improve",
                       description="Fit the per-test model, locate where the recordings leave its predictive band, "
                                   "refit the catalogue's physics extensions the residuals point to, compare them "
                                   "by PSIS-LOO and give a verdict, qualified complete or partial by what its model "
                                   "still leaves (docs/diagnose.md).")
    damper_options(p)
    p.add_argument("--tests", nargs="+", metavar="LABEL", help="test labels (default: all of the damper's)")
    p.add_argument("--priors", metavar="PATH", help="prior file of the base parameters (default: the bundled one)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the diagnosis as JSON")
    p.add_argument("--curves", metavar="OUT.csv",
                   help="write the fitted curves (posterior median per line) of the per-test model and of the verdict's "
                        "model in the bench CSV columns plus a 'model' column")
    p.add_argument("--runs", default="runs", metavar="DIR",
                   help="also store it as DIR/<damper>/diagnose.json for the report, and a strand-slip verdict's "
                        "cable law as DIR/<damper>/cable-<state>/ (default runs/)")
    scale_options(p, "fits in parallel local processes")
    return p


def cmd_diagnose(args) -> int:
    from dataclasses import replace

    from ..core._io import write_json
    from ..diagnosis.diagnose import diagnose
    from ..model.damper import resolve_damper
    from ..pipeline import diagnose_inputs, executor_for

    damper = resolve_damper(args.damper)
    settings = settings_from(args)
    bench = bench_for(args)
    for t in args.tests or []:
        bench.test(damper.name, t)  # an unknown label fails before anything is stored
    data = cleaned_for(bench, [damper], store=args.runs, settings=settings, quiet=args.quiet)
    config = replace(settings.diagnose, workers=args.workers)
    with executor_for(args.scheduler) as executor:
        if executor is not None:  # the diagnosis as one job on the cluster
            result = executor.submit(diagnose, damper, data, args.tests, seed=args.seed,
                                     config=replace(config, workers=1), progress=False,
                                     prior_path=args.priors, store=args.runs).result()
        else:
            result = diagnose(damper, data, args.tests, seed=args.seed, config=config, progress=not args.quiet,
                              prior_path=args.priors, store=args.runs)
    result["command"] = args.command_line
    if args.tests is None:  # a whole-damper diagnosis: 'sbcal run' may reuse it while its inputs hold
        result["inputs"] = diagnose_inputs(data, damper, settings=settings)
    if args.json:
        write_json(args.json, result, indent=1)
    stored = diagnose_path(args.runs, damper.name)
    write_json(stored, result, indent=1)
    if args.curves:
        from ..data.bench import write_bench
        from ..diagnosis.diagnose import curves_frame

        write_bench(curves_frame(result), args.curves)
    law = result.get("law")
    unsettled = (f", NOT SETTLED: {', '.join(law['outscored_by'])} scored clearly higher but did not converge"
                 if law and law["converged"] and not law["settled"] else "")
    print(f"{damper.name}: verdict {result['verdict']}" + (f" ({law['best']} law{unsettled})" if law else "")
          + f" — {headline(result['remainder'])}")
    for line in _patched_lines(law or {}):
        print(line)
    for b in result["bands"][:12]:
        print(f"  off: {b['test']} {b['quantity']} {b['f_lo']:g}-{b['f_hi']:g} Hz (|z| up to {b['max_abs_z']:.1f})")
    if len(result["bands"]) > 12:
        print(f"  ... {len(result['bands']) - 12} more bands")
    for r in result["ranking"]:
        print(f"  {r['effect']:30s} delta ELPD {r['delta_elpd']:10.1f} +- {r['se']:7.1f}, "
              f"removes {r['explained']:.0%} of the misfit where it is"
              + ("" if r["converged"] else " (NOT converged: cannot be the verdict)"))
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


def add_cable(sub):
    from ..model.laws import LAWS, aliases, fitted_laws, zoned

    families = fitted_laws()
    named = {law: [a for a, f in aliases().items() if f == law] for law in families}

    def said(law):  # a family in the help: what it is, its aliases, where it is compared
        cls = LAWS[law]
        more = [f"alias {', '.join(named[law])}"] if named[law] else []
        if cls.min_tests > 1:
            more.append(f"compared only where every cable state has {cls.min_tests} tests or more")
        return f"{law} ({'; '.join([cls.summary or cls.__name__] + more)})"

    p = sub.add_parser("cable", help="fit the cable's hysteresis law jointly over all amplitudes of each cable state",
                       description="Fit one strand-slip law per cable state (dry; a test suffix such as -oiled is "
                                   "another state) over all its tests at once, on the distributed cable model "
                                   "(docs/cable.md), and store each state's posterior as "
                                   "<runs>/<damper>/cable-<state>/posterior.nc + summary.json.")
    damper_options(p)
    p.add_argument("--law", default="best",
                   choices=list(families) + [zoned(law) for law in families] + list(aliases()) + ["best"],
                   help="law family: " + ", ".join(said(law) for law in families) + "; each with _zoned: the law "
                        "changing along the arm, with clamp and mass zones of their own (docs/cable.md); or best "
                        "(every family that can be compared, then the best one's zoned law where the uniform law "
                        "leaves a misfit; the best converged by PSIS-LOO; default)")
    p.add_argument("--priors", metavar="PATH", help="prior file of the geometry boxes (default: the bundled one)")
    p.add_argument("--seed", type=seed_value, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("--runs", default="runs", metavar="DIR", help="run store (default runs/)")
    workers_option(p, "processes per fit")
    quiet_option(p)
    return p


def cmd_cable(args) -> int:
    from dataclasses import asdict

    from ..inference.cable_fit import fit_damper_cable, store_cable
    from ..inference.harmonic_refit import refit_harmonics
    from ..inference.stats import CLEAR_SE
    from ..model.damper import resolve_damper

    damper = resolve_damper(args.damper)
    data = cleaned_for(bench_for(args), [damper], store=args.runs, settings=settings_from(args), quiet=args.quiet)
    from ..model.laws import aliases

    laws = None if args.law == "best" else (aliases().get(args.law, args.law),)
    fits, comparison = fit_damper_cable(damper, data, laws=laws, seed=args.seed, prior_path=args.priors,
                                        workers=args.workers, progress=not args.quiet)
    best = comparison["best"]
    compared = len(fits) > 1 or bool(comparison["screened"])  # a comparison of families was made
    for state, fit in sorted(fits[best].items()):  # refitted with the multi-harmonic solve where it is needed
        label = None if args.quiet else f"{damper.name} cable {state} ({best}, harmonics)"
        fit = refit_harmonics(fit, seed=args.seed, workers=args.workers, progress=label) or fit
        out = cable_dir(args.runs, damper.name, state)
        s = store_cable(fit, out, meta={"seed": args.seed, "made_by": args.command_line, "damper_values": asdict(damper)},
                        comparison=comparison if compared else None)
        flag = "" if s["converged"] else f"  NOT CONVERGED ({s['reason']})"
        vals = ", ".join(f"{n} {p['median']:.3g} [{p['q05']:.3g}, {p['q95']:.3g}]" for n, p in s["parameters"].items())
        print(f"{damper.name} cable {state} ({best}, {len(fit.tests)} tests): {vals}; R-hat max {s['r_hat_max']:.3f}, "
              f"ESS min {min(s['ess_bulk_min'], s['ess_tail_min']):.0f}, {s['wall_s']:.0f} s{flag}")
        r, d = s["remainder"], s["discrepancy"]
        size = f"{r['materiality']['words']}; " if r.get("materiality") else ""
        left = ("consistent with the noise: no model discrepancy" if r["qualifier"] == "complete" else
                size + "model discrepancy carried by predict and span (sd ln|f| / phase): " + ", ".join(
                    f"{a:g} mm {m:.3f} / {p:.2f} deg" for a, m, p in
                    zip(d["amplitude_mm_pp"], d["logmag_sd"], d["phase_sd_deg"])))
        print(f"  what the law leaves: {r['qualifier']} (rms z {r['rms_z']:.2f}, {r['lines_off']} of {r['n_lines']} "
              f"lines off); {left}")
        print(f"  {_distortion_words(s['harmonics'])}")
        if s.get("harmonic_refit"):
            print(f"  {_refit_words(s['harmonic_refit'])}")
        print(f"  stored in {out}/")
    if compared:
        print("  families by PSIS-LOO (summed over the cable states): " + "; ".join(
            f"{law} {v['delta_elpd']:.1f} +- {v['se_delta']:.1f}" + ("" if v["converged"] else f" ({_unconverged_words(v)})")
            for law, v in comparison["families"].items())
            + f" (best: {best}" + ("" if comparison["converged"] else ", NOT CONVERGED: no family converged") + ")")
        for law, v in comparison["screened"].items():
            print(f"  not sampled: {law}, whose start lies {v['log_lik_gap']:.0f} nats of log-likelihood below "
                  f"{v['below']}'s (screened beyond {v['threshold']:.0f}: its ELPD could not come near)")
        for line in _patched_lines(comparison):
            print(line)
        if comparison["higher_not_converged"]:
            print(f"  not compared: {', '.join(comparison['higher_not_converged'])} scored higher but did not converge "
                  "(a comparison rests on converged posteriors only)")
        if comparison["converged"] and not comparison["settled"]:
            print(f"  NOT SETTLED: {', '.join(comparison['outscored_by'])} scored clearly above {best} (by more than "
                  f"{CLEAR_SE:g} se) but did not converge: the data reject the stored {best} law, whose draws are not "
                  "a result (predict, span and design warn; compare refuses)")
    return 0


def _patched_lines(comparison: dict) -> list:
    """One line per zoned family the comparison set aside as a patch (``patched``), as both commands print it."""
    return [f"  not a law along the arm: {name} scored higher, but its zones patch a mismatched law "
            f"({comparison['families'][name]['patch']})" for name in comparison.get("patched", [])]


def _unconverged_words(v: dict) -> str:
    """'not converged' with a family's worst R-hat, ESS and tau where the comparison has them."""
    if v.get("r_hat_max") is None:
        return "not converged"
    return f"not converged: R-hat {v['r_hat_max']:.3f}, ESS {v['ess_min']:.0f}, tau {v['tau_max']:.0f}"


def _refit_words(r: dict) -> str:
    """One line on a stored fit's harmonic refit (:func:`sbcal.inference.harmonic_refit.refit_harmonics`)."""
    head = (f"harmonic refit on {r['lines']} line(s) ({r['basis']}; fixed point in {r['rounds']} round(s), last move "
            f"{r['change']:.2f} SE; largest correction {100 * r['largest_correction']:.1f} %)")
    return f"{head}: {'used' if r['used'] else 'not used'} — {r['reason']}"


def _distortion_words(harmonics: dict) -> str:
    """One line on a stored fit's predicted force distortion (:func:`sbcal.inference.distortion.predicted_distortion`):
    the largest and where, and the largest gap of the first-harmonic model the fit used."""
    big, gap = harmonics["largest"]["distortion"], harmonics["largest"]["gap"]
    orders = f"harmonics {harmonics['orders'][0]}-{harmonics['orders'][-1]}"
    if big is None:
        return f"predicted force distortion ({orders}): no line converged"
    missed = harmonics["n_not_converged"]
    return (f"predicted force distortion (posterior median, {orders}): largest {100 * big['value']:.1f} % at "
            f"{big['test']} {big['freq_hz']:g} Hz ({big['amplitude_mm_pp']:g} mm); the fit's first-harmonic f_uu is off "
            f"the multi-harmonic one by up to {100 * gap['value']:.1f} % (at {gap['test']} {gap['freq_hz']:g} Hz)"
            + (f"; {missed} line(s) not converged" if missed else "") + f" [{harmonics['wall_s']:.0f} s]"
            + _measured_words(harmonics.get("comparison")))


def _measured_words(c: dict | None) -> str:
    """The recordings' own distortion against the prediction (bench files from ``sbcal import``)."""
    if not c:
        return ""
    ratio = "" if c["median_ratio"] is None else f", measured/predicted median {c['median_ratio']:.2f}"
    verdict = (f"the multi-harmonic solve is needed on {c['n_switch']} line(s) (not yet in the fit)" if c["n_switch"]
               else "the first-harmonic fit stands")
    return (f"; measured on {c['n_measured']} line(s): agrees with the law on {c['n_agree']}{ratio}: {verdict}")
