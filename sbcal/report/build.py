"""``sbcal report``: a self-contained static HTML summary of a run store.

One ``index.html`` that carries its figures and linked files inside (data URIs): it opens alone, mailed
or moved, with no server and no network; the PNGs are also left in ``figures/`` (for slides). Each
test's section warns where its fit fails the model's own check (:mod:`sbcal.inference.fitcheck`) or its
point fit sits on a prior bound. Per damper: data quality, then per test the fit (runs, mean, posterior-predictive
band), dissipated power, the parameter table with convergence diagnostics, corner and trace plots;
across tests the amplitude map. Missing pieces (a test not sampled yet) are shown as missing. Each prediction of a new damper from a calibrated cable
(``predict-*/``, :mod:`sbcal.design.predict`) gets a section of its own, and so does each span study
(``span/*/``, :mod:`sbcal.design.span`: the stored figures, the margins to the fatigue limit, the worst line
and the service life) and each design search (``design/*/``, :mod:`sbcal.design.search`: the starting
design against the chosen one, the stored figure, ``best.toml``). The page opens with a summary of
them all (verdict and cable law per damper, each span's margins and life, each search's best design
against its start), each row linking to its section.
"""

from __future__ import annotations

import base64
import datetime as _dt
import mimetypes
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core._io import atomic_path
from ..core.errors import InputError
from ..core.workers import run_jobs
from ..inference.sampler import POLICY
from ..inference.store import cable_dirs, owner, run_dirs
from ..inference.store import data_path as store_data_path
from ..inference.store import dampers as stored_dampers
from ..inference.store import diagnose_path
from .figures import (corner_figure, curves_figure, cv_figure, diagnosis_figure, distortion_figure, fit_figure,
                      has_harmonics, law_figure, power_figure, trace_figure)


__all__ = ["build_report", "inline_files"]

@dataclass
class _Test:
    label: str
    paramset: str
    summary: dict | None = None
    figures: dict = field(default_factory=dict)
    rows: list = field(default_factory=list)
    missing: str = ""
    warnings: list = field(default_factory=list)
    checks: list = field(default_factory=list)


def _diagnosis(path: Path, figs: Path):
    """The stored ``sbcal diagnose`` result of a damper, ready for the page (None if there is none),
    with its cable laws (``cable-<state>/``) when the verdict is strand slip."""
    import json

    from ..diagnosis.remainder import shown_qualifier
    from ..inference.cable_fit import read_cable

    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        rem, word = doc.get("remainder"), doc.get("qualifier")
        if rem is not None and not (isinstance(rem, dict) and isinstance(rem.get("words"), str)
                                    and word in ("complete", "partial", None)):
            raise InputError(f"{path}: keys 'qualifier', 'remainder': expected complete, partial or null, and an "
                             "object with its sentence 'words' (as sbcal diagnose writes them)")
        doc["shown_qualifier"] = shown_qualifier(rem)
        doc["left_words"] = _left_words(rem, word)
        doc["figure"] = diagnosis_figure(doc, figs / f"{doc['damper']}_diagnosis.png")
        if doc.get("curves") and doc["after"]["effect"] != "baseline":
            doc["curves_figure"] = curves_figure(doc, figs / f"{doc['damper']}_curves.png")
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a diagnosis written by sbcal diagnose ({e})") from None
    cables, distorted = {}, {}
    for state, d in cable_dirs(*owner(path)):
        cables[state] = read_cable(d)
        if has_harmonics(cables[state][0], d / "summary.json"):
            distorted[state] = cables[state][0]
    if cables:
        doc["law_figure"] = law_figure(cables, figs / f"{doc['damper']}_law.png")
        doc["cables"] = {state: s for state, (s, _) in cables.items()}
        if distorted:
            doc["distortion_figure"] = distortion_figure(distorted, figs / f"{doc['damper']}_distortion.png")
    return doc


def _left_words(rem: dict | None, word: str | None) -> str:
    """The remainder's sentence for "What is left", after its qualifier: the statistical sentence
    without its ``partial: `` / ``complete: `` lead, and for an immaterial ``partial`` its size first."""
    if not rem:
        return ""
    words = rem["words"][len(word) + 2:] if word and rem["words"].startswith(word + ": ") else rem["words"]
    m = rem.get("materiality")
    if m and not m["material"]:
        return f"{m['detail']}; statistically partial: {words}"
    return f"{words} ({m['detail']})" if m else words


def _predictions(damper_dir: Path, figs: Path) -> list:
    """The stored predictions beside a damper's cable runs (``predict-*/``), ready for the page, each
    figure redrawn from the store."""
    from ..design.predict_plots import plot_prediction, plot_sweep
    from ..design.predict_store import stored_predictions

    out = []
    for d, pred, sweeps in stored_predictions(damper_dir):
        stem = f"{damper_dir.name}_{d.name}"
        item = {"name": d.name, "prediction": pred, "sweeps": [], "figure": None, "resonances": []}
        if pred is not None:
            item["figure"] = plot_prediction(pred, figs / f"{stem}.png").name
            unit = "mm p-p" if pred.mode == "amplitude" else "m/s"
            for i, lv in enumerate(pred.levels):
                rs = [r for r in pred.resonances if r.level == lv]
                ex = pred.freq_hz[pred.extrapolated[i]]
                item["resonances"].append({
                    "level": f"{lv:g} {unit}",
                    "resonances": "; ".join(f"{eng(r.freq_hz[1])} [{eng(r.freq_hz[0])}, {eng(r.freq_hz[2])}]"
                                            + (f" ({r.share:.0%} of draws)" if r.share < 0.95 else "") for r in rs) or "none",
                    "peak_power": eng(float(np.nanmax(pred.power_w[i, 1]))),
                    "extrapolated": f"{ex.size} lines, {ex.min():g}-{ex.max():g} Hz" if ex.size else "none",
                    "folds": ", ".join(f"{f:g}" for f in pred.freq_hz[pred.fold_share[i] > 0]) or "none"})
        for k, sw in enumerate(sweeps):
            item["sweeps"].append({"field": sw.field, "result": sw,
                                   "figure": plot_sweep(sw, figs / f"{stem}_sweep{k}.png").name})
        out.append(item)
    return out


def _copy_beside(src: Path, dest: Path) -> str | None:
    """Copy a stored file beside the page (atomically); its name, or None when there is none."""
    import shutil

    if not src.is_file():
        return None
    with atomic_path(dest, dest.suffix) as tmp:
        shutil.copyfile(src, tmp)
    return dest.name


def _band(q, key_median="median") -> str:
    """``median [q05, q95]`` of a stored quantile dict, engineering precision; ``—`` without one."""
    if not q:
        return "—"
    return f"{eng(q.get(key_median))} [{eng(q.get('q05'))}, {eng(q.get('q95'))}]"


def _years(v, unlimited: bool = True) -> str:
    """A stored service life [years]: a null is an infinite life (no damage: JSON has no inf), shown
    "unlimited" when the store says so (``unlimited``), else "—"."""
    if v is None:
        return "unlimited" if unlimited else "—"
    return eng(v)


def _years_band(q, unlimited: bool) -> str:
    """``median [q05, q95]`` of a stored life; a null quantile is an infinite life (no damage)."""
    if not q:
        return "—"
    return f"{_years(q.get('median'), unlimited)} [{_years(q.get('q05'))}, {_years(q.get('q95'))}]"


def _life(life: dict | None) -> dict | None:
    """The ``life`` of a span study's summary, as the page shows it (None without one)."""
    if not life:
        return None
    dq = life.get("damage_per_year")
    return {
        "climate": life["climate"], "across": f"{100 * float(life['across']):g} %",
        "hours": _fmt(life.get("hours_per_year"), 4),
        "bare": _years(life.get("years_bare"), bool(life.get("unlimited_bare"))),
        "damage_bare": _fmt(life.get("damage_per_year_bare"), 3) if not life.get("unlimited_bare") else "0",
        "with": _years_band(life.get("years"), bool(life.get("unlimited"))) if life.get("years") is not None else None,
        "damage": (f"{_fmt(dq.get('median'), 3)} [{_fmt(dq.get('q05'), 3)}, {_fmt(dq.get('q95'), 3)}]"
                   if dq is not None else None),
    }


def _span_studies(runs: Path, figs: Path) -> list:
    """The stored span studies (``<runs>/span/*/``, :mod:`sbcal.design.span`), ready for the page: key numbers
    from ``summary.json`` (margins, worst line, service life) and the stored figures (``span.png``,
    ``life.png``) copied beside the page (nothing is recomputed).

    Raises
    ------
    InputError
        One line: a summary that is not a span study's (:func:`sbcal.design.span_study.read_span`) or
        whose numbers are malformed.
    """
    from ..design.span_study import stored_spans

    out = []
    for d, doc in stored_spans(runs):
        try:
            out.append(_span_item(d, doc, figs))
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise InputError(f"{d / 'summary.json'}: not a span study written by sbcal span "
                             f"({type(e).__name__}: {e})") from None
    return out


def _span_item(d: Path, doc: dict, figs: Path) -> dict:
    m, c, ws, p = doc["margin"], doc["conductor"], doc.get("worst_stress_mpa") or {}, doc.get("placement")
    damped = bool(doc.get("positions_m"))
    wl = doc.get("worst_line")
    me = doc.get("model_error", "absent")  # a study stored before the key existed says nothing
    if not damped or me == "absent":
        model_error = None
    elif me:
        model_error = ("the bands hold the calibration's model error (the discrepancy its law leaves beyond the noise, sd: "
                       + ", ".join(f"{a:g} mm p-p {100 * s:.1f} % / {ph:.1f}°" for a, s, ph in
                                   zip(me["amplitude_mm_pp"], me["logmag_sd"], me["phase_sd_deg"])) + ")")
    else:
        model_error = "the bands hold the cable posterior and the tolerances only, not the calibration's model error"
    return {
        "name": d.name, "figure": _copy_beside(d / "span.png", figs / f"span_{d.name}.png"),
        "life_figure": _copy_beside(d / "life.png", figs / f"life_{d.name}.png"),
        "conductor": c, "damper": doc.get("damper", "none"), "cable": doc.get("cable", ""),
        "cable_damper": doc.get("cable_damper", ""), "state": doc.get("state", ""), "law": doc.get("law", ""),
        "positions": ", ".join(f"{x:.3g}" for x in doc.get("positions_m", [])), "ends": doc.get("ends", 1),
        "n_draws": doc.get("n_draws"), "limit": eng(doc.get("limit_mpa")),
        "margin": _band(m) if damped else "—", "margin_q10": eng(m.get("q10")) if damped else "—",
        "margin_bare": eng(doc.get("margin_bare")),
        "stress": _band(ws) if damped else "—",
        "stress_bare": eng(ws.get("bare")),
        "safe": m.get("q05") is not None and m["q05"] >= 1 if damped else None,
        "placement": None if not p else {"best": eng(p["best_position_m"]), "margin": eng(p["best_margin"]),
                                         "quantile": round(100 * p["quantile"]), "suffices": p["suffices"]},
        "worst_line": None if not wl else {
            "frequency": eng(wl["frequency_hz"]), "wind": eng(wl["wind_m_s"]),
            "stress": _band(wl.get("stress_mpa")) if damped else None, "stress_bare": eng(wl.get("stress_bare_mpa"))},
        "model_error": model_error,
        "life": _life(doc.get("life")),
        "warnings": doc.get("warnings", [])}


def _design_searches(runs: Path, figs: Path, files: Path) -> list:
    """The stored design searches (``<runs>/design/*/``, :mod:`sbcal.design.search`), ready for the page:
    the starting and the chosen design from ``summary.json``, ``design.png`` copied beside the page and
    ``best.toml`` and ``designs.csv`` copied into ``files/`` for their links (nothing is recomputed).

    Raises
    ------
    InputError
        One line: a summary that is not a design search's (:func:`sbcal.design.search_store.read_design`)
        or whose numbers are malformed.
    """
    from ..design.search_store import stored_designs

    out = []
    for d, doc in stored_designs(runs):
        try:
            out.append(_design_item(d, doc, figs, files))
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise InputError(f"{d / 'summary.json'}: not a design search written by sbcal design "
                             f"({type(e).__name__}: {e})") from None
    return out


def _design_item(d: Path, doc: dict, figs: Path, files: Path) -> dict:
    life = doc["objective"] == "life"
    start, best = doc["start"], doc["best"]
    vary = doc.get("vary") or {}
    fields = list(vary) or list(best["fields"])

    def objective(rec):
        return _years(rec.get("objective")) if life else eng(rec.get("objective"))

    def column(rec):
        return {"fields": [eng(rec["fields"].get(f)) for f in fields], "objective": objective(rec),
                "margin": _band(rec["margin"]), "margin_q10": eng(rec["margin"].get("q10")),
                "years": _years_band(rec.get("years"), True) if rec.get("years") is not None else "—",
                "position": eng(rec.get("position_m")), "mass": eng(rec.get("total_mass_kg")),
                "extrapolated": "yes" if rec.get("extrapolated") else "no", "bad": bool(rec.get("extrapolated"))}

    opt = doc["optimiser"] or {}
    q = doc.get("quantile", 0.1)
    return {
        "name": d.name, "conductor": doc.get("conductor", ""), "cable": doc.get("cable", ""),
        "space": doc.get("space", ""), "ends": doc.get("ends", 1), "life": life, "objective": doc["objective"],
        "quantile": f"{100 * float(q):g}", "climate": doc.get("climate"),
        "across": f"{100 * float(doc['across']):g} %" if doc.get("across") is not None else "",
        "vary": [(f, f"{eng(lo)}–{eng(hi)}") for f, (lo, hi) in vary.items()],
        "constraints": [(k, eng(v) if isinstance(v, (int, float)) else str(v))
                        for k, v in (doc.get("constraints") or {}).items()],
        "fields": fields, "start": column(start), "best": column(best),
        "best_damper": doc.get("best_damper", ""), "evaluations": doc["evaluations"], "seed": doc.get("seed"),
        "optimiser": {"name": opt.get("name", "?"), "popsize": opt.get("popsize"),
                      "generations": opt.get("generations"), "message": opt.get("message", ""),
                      "search": opt.get("search") or {}, "final": opt.get("final") or {}},
        "warnings": doc.get("warnings") or [], "made_by": doc.get("made_by", ""),
        "figure": _copy_beside(d / "design.png", figs / f"design_{d.name}.png"),
        "best_toml": _copy_beside(d / "best.toml", files / f"design_{d.name}_best.toml"),
        "designs_csv": _copy_beside(d / "designs.csv", files / f"design_{d.name}_designs.csv"),
    }


def _cables(runs: Path, dname: str) -> list:
    """A damper's stored cable laws for the first screen: ``[{state, law, converged, outscored_by}]`` from each
    ``cable-<state>/summary.json`` (the summary only: the figure is the diagnosis section's); ``outscored_by``:
    the families that did not converge but score clearly above the stored law (it is not settled)."""
    from ..inference.runs import read_summary

    out = []
    for state, d in cable_dirs(runs, dname):
        s = read_summary(d) or {}
        out.append({"state": state, "law": s.get("law", "?"), "converged": s.get("converged"),
                    "outscored_by": (s.get("comparison") or {}).get("outscored_by", []) if s.get("converged") else []})
    return out


def _fmt(v, digits=4):
    return "—" if v is None or not np.isfinite(v) else f"{v:.{digits}g}"


def eng(v) -> str:
    """A number in engineering precision: 3 significant digits (``2.00e+06``, ``0.125``, ``41.7``)."""
    if v is None:
        return "—"
    v = float(v)
    if not np.isfinite(v):
        return "—"
    if v != 0 and not 1e-3 <= abs(v) < 1e5:
        return f"{v:.2e}"
    return f"{v:.3g}"


def _test_item(runs: Path, dname: str, t: str, paramset: str, figs: Path) -> _Test:
    """One test's section: its stored run's figures and parameter table (or what is missing)."""
    from ..inference.fitcheck import fit_check
    from ..inference.runs import read_run
    from ..inference.store import run_dir

    d = run_dir(runs, dname, t, paramset)
    item = _Test(label=t, paramset=paramset)
    try:
        idata, s = read_run(d)
    except InputError:
        item.missing = "not sampled yet (no finished run)"
        return item
    item.summary = s
    names = list(s["parameters"])
    model_names = [n for n in names if not n.startswith("sigma_")]
    stem = f"{dname}_{t}".replace("/", "_")
    item.figures = {
        "fit": fit_figure(idata, figs / f"{stem}_fit.png", f"{dname} {t}: measured runs and posterior"),
        "power": power_figure(idata, figs / f"{stem}_power.png", f"{dname} {t}: power dissipated"),
        "corner": corner_figure(idata, model_names, figs / f"{stem}_corner.png"),
        "trace": trace_figure(idata, names, figs / f"{stem}_trace.png"),
    }
    for check in fit_check(idata):
        (item.warnings if check.fails else item.checks).append(check.words())
    on_bound = (s.get("ga") or {}).get("on_bound") or []
    if on_bound:
        item.warnings.append(f"the point fit (GA) sits on its prior bound for {', '.join(on_bound)}: the search box, "
                             "not the data, sets them (a wider prior: --priors, docs/calibration.md)")
    for n, p in s["parameters"].items():
        flag = not (p["r_hat"] <= POLICY["rhat_max"] and min(p["ess_bulk"], p.get("ess_tail", 0)) >= POLICY["ess_min"]) \
            or not s.get("converged", False)
        item.rows.append({"name": n, "median": _fmt(p["median"]), "q05": _fmt(p["q05"]), "q95": _fmt(p["q95"]),
                          "r_hat": _fmt(p["r_hat"], 4), "ess": _fmt(p["ess_bulk"], 4), "tau": _fmt(p["tau"], 3),
                          "flag": flag})
    return item


def _job(job):
    """Run one drawing job ``(function, key, args)``; module-level so a process can run it."""
    fn, key, args = job
    return key, fn(*args)


def _draw(jobs, workers: int):
    """``(key, result)`` of every drawing job, in ``workers`` processes (here when 1)."""
    return run_jobs(_job, jobs, workers=workers)


def build_report(runs_dir="runs", out_dir="report", *, paramset: str = "theta1", command: str = "",
                 progress=None, workers: int = 1) -> Path:
    """Write ``<out_dir>/index.html`` (and ``figures/``) from a run store; returns its path.

    Renders what the stages stored and recomputes nothing: the cleaning summary (``data.json``), the
    posteriors, the diagnosis (``diagnose.json``), the cable laws' summaries, the amplitude map (``map.json`` +
    ``map.nc``), the predictions, the span studies and the design searches. Copies of stored files the
    page links to (a design's ``best.toml``, ``designs.csv``) go to ``<out_dir>/files/``.

    Parameters
    ----------
    runs_dir : path-like
        The run store (``sbcal sample --out``).
    out_dir : path-like
    paramset : str
        Parameter set whose runs are reported.
    command : str
        Command line, for provenance.
    progress : callable, optional
        Called with a short text per step.
    workers : int
        Processes drawing the figures (the page is the same for any number).
    """
    import json

    from jinja2 import Environment, PackageLoader, select_autoescape

    from ..data.bench import THESIS_TESTS
    from ..inference.amplitude import plot_map, stored_maps

    say = progress or (lambda text: None)
    runs = Path(runs_dir)
    if not runs.is_dir():
        raise InputError(f"{runs}: no such run store (run 'sbcal sample' first)")
    out = Path(out_dir)
    figs = out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    dampers = []

    names = stored_dampers(runs)
    test_dirs = {d: [t for t, _ in run_dirs(runs, d, paramset, finished=False)] for d in names}
    # the figures are drawn in worker processes (what takes the time); one job a test or a damper's extras
    jobs = [(_test_item, ("test", d, t), (runs, d, t, paramset, figs)) for d in names for t in test_dirs[d]]
    jobs += [(_diagnosis, ("diagnosis", d), (diagnose_path(runs, d), figs)) for d in names]
    jobs += [(_predictions, ("predictions", d), (runs / d, figs)) for d in names]
    say(f"report: drawing the figures of {len(names)} damper(s)")
    results = dict(_draw(jobs, workers))
    for dname in names:
        say(f"report: {dname}")
        tests_dirs = test_dirs[dname]
        data_path = store_data_path(runs, dname)
        try:
            data = json.loads(data_path.read_text()) if data_path.is_file() else None
        except ValueError as e:
            raise InputError(f"{data_path}: not valid JSON ({e})") from None
        expected = list(data["tests"]) if data else []
        tests = [results.pop(("test", dname, t)) for t in tests_dirs]
        order = {t: i for i, t in enumerate(THESIS_TESTS)}
        have = {t.label for t in tests}
        for t in expected:
            if t not in have:
                tests.append(_Test(label=t, paramset=paramset, missing="not sampled yet"))
        tests.sort(key=lambda t: (order.get(t.label, len(order)), t.label))
        quality, cv_fig = [], None
        if data:
            for t, q in data["tests"].items():
                branches = q.get("branches") or {}
                quality.append({"test": t, "runs": q["runs"], "removed": ", ".join(map(str, q["removed_runs"])) or "none",
                                "amplitudes": ", ".join(f"{a:g}" for a in q["amplitude_mm_pp"]),
                                "lines": q["n_frequencies"],
                                "branches": "two response branches, both kept" if branches.get("split") else ""})
            cv_fig = cv_figure(data["quality"], figs / f"{dname}_cv.png")
        bench_note = "" if data else f"no cleaning stage stored ({data_path} is missing; 'sbcal run' writes it)"
        sampled = [t for t in tests if t.summary]
        dampers.append({"name": dname, "tests": tests, "quality": quality, "cv_fig": cv_fig, "bench_note": bench_note,
                        "diagnosis": results.pop(("diagnosis", dname)),
                        "predictions": results.pop(("predictions", dname)),
                        "n_sampled": len(sampled),
                        "n_unconverged": sum(not t.summary.get("converged", False) for t in sampled),
                        "cables": _cables(runs, dname)})

    say("report: amplitude map")
    docs = stored_maps(runs)
    map_note = "" if docs else "none stored ('sbcal map' or 'sbcal run' writes it from 3 or more amplitudes)"
    map_fig = None
    map_rows = []
    if docs:
        map_fig = "amplitude_map.png"
        plot_map(docs, figs / map_fig)
        for name, doc in docs.items():
            pl, sat = doc["powerlaw"], doc["saturating"]
            row = {"damper": name, "k": pl["k"], "n": pl["n"], "ej_inf": sat["EJ_inf"],
                   "reduction": sat.get("reduction_factor"), "preferred": doc["preferred"], "criterion": doc["criterion"],
                   "converged": doc.get("converged", False),
                   "problems": ", ".join(doc.get("inputs_not_converged", []))}
            if doc.get("beta"):
                row["beta_k"], row["beta_n"] = doc["beta"]["powerlaw"]["k"], doc["beta"]["powerlaw"]["n"]
            map_rows.append(row)

    provenance = []
    for d in dampers:
        for t in d["tests"]:
            if t.summary:
                cfg = t.summary.get("config", {})
                provenance.append({"run": f"{d['name']} {t.label} {t.paramset}", "seed": t.summary.get("seed"),
                                   "wall_s": _fmt(t.summary.get("wall_s"), 3),
                                   "command": cfg.get("command", ""),
                                   "versions": ", ".join(f"{k} {v}" for k, v in t.summary.get("versions", {}).items())})
    say("report: the lot, span studies and design searches")
    from ..inference.batch import read_batch
    from .lot import lot_section

    from ..inference.runs import read_summary
    from ..inference.store import batch_dir, design_cable_dirs

    lot = lot_section(read_batch(runs), figs, [(d, read_summary(d)) for _, d in design_cable_dirs(batch_dir(runs))])
    from .compare import compare_section

    comparisons = compare_section(runs, figs)
    spans = _span_studies(runs, figs)
    designs = _design_searches(runs, figs, out / "files")
    env = Environment(loader=PackageLoader("sbcal.report", "templates"), autoescape=select_autoescape(["html"]))
    page = env.get_template("report.html").render(
        dampers=dampers, lot=lot, comparisons=comparisons, spans=spans, designs=designs, map_fig=map_fig, map_rows=map_rows, map_note=map_note,
        provenance=provenance,
        created=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), command=command,
        runs_dir=str(runs), paramset=paramset, iv=lambda v: "—" if v is None else f"{v[0]:.3g} [{v[1]:.3g}, {v[2]:.3g}]",
        eng=eng,
    )
    index = out / "index.html"
    with atomic_path(index, ".html") as tmp:
        tmp.write_text(inline_files(page, out), encoding="utf-8")
    return index


_LINKED = re.compile(r'(src|href)="((?:figures|files)/[^"]+)"')


def inline_files(page: str, root: Path) -> str:
    """``page`` with every ``src``/``href`` to a file under ``root/figures`` or ``root/files`` replaced by the
    file itself (a base64 data URI; a link also gets ``download``, the file's name), so the page travels
    alone; ``data-src`` keeps the path, naming the figure. A path that is not there is left as it is."""
    def data_uri(m) -> str:
        path = root / m.group(2)
        if not path.is_file():
            return m.group(0)
        mime = mimetypes.guess_type(path.name)[0] or "text/plain"
        uri = f'{m.group(1)}="data:{mime};base64,{base64.b64encode(path.read_bytes()).decode("ascii")}"'
        return uri + f' data-src="{m.group(2)}"' + (f' download="{path.name}"' if m.group(1) == "href" else "")

    return _LINKED.sub(data_uri, page)

