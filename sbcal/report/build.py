"""``sbcal report``: a self-contained static HTML summary of a run store.

One ``index.html`` with its PNG figures beside it (``figures/``); opens from disk with no server
and no network. Per damper: data quality, then per test the fit (runs, mean, posterior-predictive
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

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core._io import atomic_path
from ..core.errors import InputError
from ..core.plotting import pyplot, save_png
from ..core.workers import run_jobs
from ..inference.sampler import POLICY
from ..inference.store import cable_dirs, owner, run_dirs
from ..inference.store import data_path as store_data_path
from ..inference.store import dampers as stored_dampers
from ..inference.store import diagnose_path


__all__ = ["build_report"]

_FIG_DPI = 90


def _save(fig, path: Path) -> str:
    return save_png(fig, path, dpi=_FIG_DPI).name


@dataclass
class _Test:
    label: str
    paramset: str
    summary: dict | None = None
    figures: dict = field(default_factory=dict)
    rows: list = field(default_factory=list)
    missing: str = ""


def _fit_figure(idata, path: Path, title: str) -> str:
    """Measured runs, their mean, the model's 90 % band and the predictive 90 % band for a new run."""
    plt = pyplot()
    f = np.asarray(idata.constant_data["freq_hz"])
    obs_m = np.exp(np.asarray(idata.observed_data["logmag"]))
    obs_p = np.degrees(np.asarray(idata.observed_data["phase"]))
    pp = idata.posterior_predictive
    fig, axes = plt.subplots(2, 1, figsize=(8, 6.2), sharex=True)
    for ax, obs, new, model, unit in (
        (axes[0], obs_m, np.exp(np.asarray(pp["logmag"])), np.exp(np.asarray(pp["model_logmag"])), "|F/X| [N/m]"),
        (axes[1], obs_p, np.degrees(np.asarray(pp["phase"])), np.degrees(np.asarray(pp["model_phase"])), "phase [deg]"),
    ):
        new = new.reshape(-1, f.size)
        model = model.reshape(-1, f.size)
        lo, hi = np.quantile(new, [0.05, 0.95], axis=0)
        ax.fill_between(f, lo, hi, color="C1", alpha=0.25, label="posterior predictive 90 % (a new run)")
        mlo, mmid, mhi = np.quantile(model, [0.05, 0.5, 0.95], axis=0)
        ax.fill_between(f, mlo, mhi, color="C3", alpha=0.35, label="model curve 90 %")
        ax.plot(f, mmid, color="C3", lw=1.2, label="model curve, median")
        for i, run in enumerate(obs):
            ax.plot(f, run, color="0.55", lw=0.5, alpha=0.6, label="measured runs" if i == 0 else None)
        ax.plot(f, np.nanmean(obs, axis=0), "k.", ms=4, label="mean of runs")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].set_title(title)
    axes[1].set_xlabel("frequency [Hz]")
    axes[0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    return _save(fig, path)


def _power_figure(idata, path: Path, title: str) -> str:
    """Dissipated power P = 0.5 omega Im(f_uu) X0^2 of the model curves, with its 90 % band."""
    plt = pyplot()
    f = np.asarray(idata.constant_data["freq_hz"])
    x0 = np.asarray(idata.constant_data["amplitude_mm_pp"]) / 2 * 1e-3  # peak base amplitude [m]
    pp = idata.posterior_predictive
    im = (np.exp(np.asarray(pp["model_logmag"])) * np.sin(np.asarray(pp["model_phase"]))).reshape(-1, f.size)
    p = 0.5 * 2 * np.pi * f * im * x0**2
    obs = np.exp(np.asarray(idata.observed_data["logmag"])) * np.sin(np.asarray(idata.observed_data["phase"]))
    pobs = np.nanmean(0.5 * 2 * np.pi * f * obs * x0**2, axis=0)
    lo, mid, hi = np.quantile(p, [0.05, 0.5, 0.95], axis=0)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    ax.fill_between(f, lo, hi, color="C2", alpha=0.3, label="model, 90 %")
    ax.plot(f, mid, color="C2", label="model, median")
    ax.plot(f, pobs, "k.", ms=4, label="measured (mean of runs)")
    ax.set(xlabel="frequency [Hz]", ylabel="dissipated power [W]", yscale="log", title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def _corner_figure(idata, names, path: Path) -> str:
    import corner

    x = np.stack([np.asarray(idata.posterior[n]).ravel() for n in names], axis=1)
    fig = corner.corner(x, labels=list(names), quantiles=[0.05, 0.5, 0.95], show_titles=True, title_fmt=".3g",
                        title_kwargs={"fontsize": 8}, label_kwargs={"fontsize": 8})
    fig.set_size_inches(1.5 * len(names) + 1, 1.5 * len(names) + 1)
    return _save(fig, path)


def _trace_figure(idata, names, path: Path) -> str:
    """Draws per ensemble (chain): well-mixed ensembles overlap."""
    plt = pyplot()
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.2 * len(names) + 0.5), sharex=True)
    for ax, n in zip(np.atleast_1d(axes), names):
        v = np.asarray(idata.posterior[n])
        for c in range(v.shape[0]):
            ax.plot(v[c], lw=0.3, alpha=0.7)
        ax.set_ylabel(n, fontsize=8)
    np.atleast_1d(axes)[-1].set_xlabel("draw (walkers' thinned draws, one colour per ensemble)")
    fig.tight_layout()
    return _save(fig, path)


def _cv_figure(quality: dict, path: Path) -> str:
    """CV per line of every test, from the stored cleaning stage (``data.json``'s ``quality``)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for t, q in quality.items():
        axes[0].plot(q["frequency_hz"], q["magnitude_cv"], lw=1, label=t)
        axes[1].plot(q["frequency_hz"], q["phase_cv"], lw=1, label=t)
    axes[0].set(xlabel="frequency [Hz]", ylabel="CV of |F/X| [%]", title="Run-to-run spread, magnitude")
    axes[1].set(xlabel="frequency [Hz]", ylabel="CV of phase [%]", title="Run-to-run spread, phase")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def _diagnosis_figure(doc, path: Path) -> str:
    """Standardised residuals of every test (rows) before (grey) and after (red) the chosen extension."""
    plt = pyplot()
    res = doc["residuals"]
    tests = list(res)
    fig, axes = plt.subplots(len(tests), 2, figsize=(10, 1.5 * len(tests) + 1.0), sharex=True, squeeze=False)
    after = doc["after"]["effect"]
    for i, t in enumerate(tests):
        f = np.asarray(res[t]["freq_hz"])
        for q, name in enumerate(("magnitude", "phase")):
            ax = axes[i, q]
            zb, za = np.asarray(res[t]["z_before"][q]), np.asarray(res[t]["z_after"][q])
            for b in doc["bands"]:
                if b["test"] == t and b["quantity"] == name:
                    ax.axvspan(b["f_lo"] - 0.25, b["f_hi"] + 0.25, color="C1", alpha=0.2, lw=0)
            ax.axhspan(-3, 3, color="C2", alpha=0.15, lw=0)
            ax.plot(f, np.clip(zb, -50, 50), color="0.5", lw=1, marker=".", ms=3, label="per-test model")
            if after != "baseline":
                ax.plot(f, np.clip(za, -50, 50), color="C3", lw=1.2, marker=".", ms=3, label=after)
            ax.set_ylim(-55, 55)
            ax.text(0.01, 0.95, f"{t} {name}", transform=ax.transAxes, va="top", fontsize=8,
                    bbox=dict(fc="white", ec="none", alpha=0.8))
            ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="lower right")
    for q in (0, 1):
        axes[-1, q].set_xlabel("frequency [Hz]")
    fig.supylabel("z = residual of the run mean / predictive sd (clipped at ±50)", fontsize=9)
    fig.suptitle(f"{doc['damper']}: where the model misses (orange: located bands; green: |z| < 3)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _law_figure(cables: dict, path: Path) -> str:
    """The cable law of each state: EJ and loss factor against curvature amplitude, median and 90 %
    band, with the curvature range each test reached."""
    from ..inference.cable_fit import law_curves
    from ..model.zones import ZONED_SUFFIX

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (state, (summary, draws)) in enumerate(sorted(cables.items())):
        color = f"C{i % 10}"
        reached = summary.get("tests_reached", {})
        lo = min((r["curvature_min"] for r in reached.values()), default=1e-4)
        hi = max((r["curvature_max"] for r in reached.values()), default=1e-1)
        chi = np.geomspace(max(lo / 10, 1e-7), hi * 10, 120)
        keep = np.linspace(0, next(iter(draws.values())).size - 1, min(400, next(iter(draws.values())).size)).astype(int)
        zoned = summary["law"].endswith(ZONED_SUFFIX)
        for zone, style in (("middle", "-"), ("clamp", "--"), ("mass", ":")) if zoned else (("middle", "-"),):
            ej, loss = law_curves(summary["law"], {k: v[keep] for k, v in draws.items()}, chi, zone=zone)
            where = f", {zone}" + (" of the arm" if zone == "middle" else " zone") if zoned else ""
            for ax, y in ((axes[0], ej), (axes[1], loss)):
                q05, q50, q95 = np.quantile(y, [0.05, 0.5, 0.95], axis=0)
                if zone == "middle":
                    ax.fill_between(chi, q05, q95, color=color, alpha=0.25)
                ax.plot(chi, q50, color=color, lw=1.5, ls=style,
                        label=f"{state} cable ({summary['law']}{where}), median" + (" and 90 %" if zone == "middle" else ""))
        for k, (t, r) in enumerate(sorted(reached.items())):  # the range each test bent the arms over
            yk = 0.96 - 0.05 * k - 0.4 * i
            axes[0].plot([r["curvature_min"], r["curvature_max"]], [yk, yk], transform=axes[0].get_xaxis_transform(),
                         color=color, lw=3, alpha=0.6, solid_capstyle="butt")
            axes[0].text(r["curvature_max"], yk, f" {t}", transform=axes[0].get_xaxis_transform(), fontsize=6,
                         va="center", color=color)
    axes[0].set(xscale="log", yscale="log", xlabel="curvature amplitude [1/m]", ylabel="EJ = Re EJ* [N m$^2$]",
                title="Cable rigidity (bars: curvature range each test reached)")
    axes[1].set(xscale="log", xlabel="curvature amplitude [1/m]", ylabel="loss factor Im EJ* / Re EJ*",
                title="Cable loss factor")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return _save(fig, path)


def _distortion_figure(cables: dict, path: Path) -> str:
    """The base force's harmonic distortion each cable state's law predicts at its posterior median, per line
    (the stored ``harmonics`` of ``cable-<state>/summary.json``): one panel a state, one curve a test, gaps
    where the multi-harmonic solve did not converge; where the recordings carry their own distortion
    (``harmonics.measured``, from ``sbcal import``), open circles of the test's colour, filled where the
    harmonic switch is on."""
    plt = pyplot()
    states = sorted(cables)
    fig, axes = plt.subplots(1, len(states), figsize=(5.5 * len(states), 3.6), squeeze=False)
    for ax, state in zip(axes[0], states):
        h = cables[state]["harmonics"]
        amps = {t: np.asarray(a, float) for t, a in h["amplitude_mm_pp"].items()}
        top = max(float(a.max()) for a in amps.values())
        peak = 0.0
        for t in sorted(amps, key=lambda k: (amps[k].max(), k)):
            # a test's colour by its largest amplitude, over two decades below the state's largest
            color = plt.cm.viridis(np.log(amps[t].max() / top) / np.log(1e-2) if top > 0 else 0.0)
            y = 100 * np.array(h["distortion"][t], dtype=float)
            peak = max(peak, float(np.nanmax(y, initial=0.0)))
            ax.plot(h["freq_hz"][t], y, color=color, lw=1.2, marker=".", ms=3,
                    label=f"{t} ({', '.join(f'{a:g}' for a in np.unique(amps[t]))} mm)")
            if "measured" in h:
                m = 100 * np.array(h["measured"][t], dtype=float)
                on = np.array([bool(v) for v in h["switch"][t]])
                peak = max(peak, float(np.nanmax(m, initial=0.0)))
                f = np.asarray(h["freq_hz"][t], float)
                ax.scatter(f, m, s=14, facecolors=[color if o else "none" for o in on], edgecolors=[color], lw=0.8)
        # headroom above the curves for the legend
        if "measured" in h:
            ax.scatter([], [], s=14, facecolors="none", edgecolors="grey", label="measured (filled: switch on)")
        ax.set(xlabel="frequency [Hz]", ylabel="force distortion [%]", ylim=(0, 1.35 * peak or 1.0),
               title=f"{state} cable ({cables[state]['law']}): harmonics {h['orders'][0]}-{h['orders'][-1]}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=4, loc="upper center")
    fig.tight_layout()
    return _save(fig, path)


def _has_harmonics(summary: dict, where: Path) -> bool:
    """Whether a cable summary holds the predicted distortion the report draws (a store written before it
    was computed has none); one line naming ``where`` when it is not as ``store_cable`` writes it."""
    h = summary.get("harmonics")
    if h is None:
        return False
    try:
        ok = (bool(h["orders"]) and {"distortion", "gap"} <= set(h["largest"]) and all(
            len(h["freq_hz"][t]) == len(h["amplitude_mm_pp"][t]) == len(v) > 0 for t, v in h["distortion"].items()))
    except (KeyError, TypeError, AttributeError):
        ok = False
    if not ok:
        raise InputError(f"{where}: key 'harmonics': expected orders, largest and per test freq_hz, amplitude_mm_pp "
                         "and distortion of one length (as sbcal cable writes it)")
    return True


def _curves_figure(doc, path: Path) -> str:
    """Each test's run means with the per-test model's and the verdict model's fitted curves (the latter's
    90 % band holds the posterior's spread and, for a ``partial`` verdict, the model discrepancy)."""
    plt = pyplot()
    curves = doc.get("curves", {})
    base = curves.get("baseline", {})
    model = doc["after"]["effect"]
    unified = curves.get(model, {})
    tests = list(base)
    fig, axes = plt.subplots(len(tests), 2, figsize=(10, 1.6 * len(tests) + 1.0), sharex=True, squeeze=False)
    for i, t in enumerate(tests):
        f = np.asarray(base[t]["freq_hz"])
        data = curves.get("data", {}).get(t)
        for q, (name, conv) in enumerate((("logmag", np.exp), ("phase", np.degrees))):
            ax = axes[i, q]
            if data is not None:
                ax.plot(f, conv(np.asarray(data[name])), "k.", ms=3, label="mean of the runs")
            ax.plot(f, conv(np.asarray(base[t][name])), color="0.5", lw=1, label="per-test model")
            if t in unified:
                mid = np.asarray(unified[t][name])
                ax.plot(f, conv(mid), color="C3", lw=1.2, label=model)
                if f"{name}_sd" in unified[t]:  # 90 % band: the posterior's spread and the model discrepancy
                    half = 1.645 * np.asarray(unified[t][f"{name}_sd"])
                    ax.fill_between(f, conv(mid - half), conv(mid + half), color="C3", alpha=0.2, lw=0,
                                    label="90 % band (with the discrepancy)")
            ax.text(0.01, 0.95, f"{t} {'|F/X| [N/m]' if q == 0 else 'phase [deg]'}", transform=ax.transAxes,
                    va="top", fontsize=8, bbox=dict(fc="white", ec="none", alpha=0.8))
            if q == 0:
                ax.set_yscale("log")
            ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="lower right")
    for q in (0, 1):
        axes[-1, q].set_xlabel("frequency [Hz]")
    fig.suptitle(f"{doc['damper']}: fitted curves, the per-test model and {model}", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _diagnosis(path: Path, figs: Path):
    """The stored ``sbcal diagnose`` result of a damper, ready for the page (None if there is none),
    with its cable laws (``cable-<state>/``) when the verdict is strand slip."""
    import json

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
        doc["figure"] = _diagnosis_figure(doc, figs / f"{doc['damper']}_diagnosis.png")
        if doc.get("curves") and doc["after"]["effect"] != "baseline":
            doc["curves_figure"] = _curves_figure(doc, figs / f"{doc['damper']}_curves.png")
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{path}: not a diagnosis written by sbcal diagnose ({e})") from None
    cables, distorted = {}, {}
    for state, d in cable_dirs(*owner(path)):
        cables[state] = read_cable(d)
        if _has_harmonics(cables[state][0], d / "summary.json"):
            distorted[state] = cables[state][0]
    if cables:
        doc["law_figure"] = _law_figure(cables, figs / f"{doc['damper']}_law.png")
        doc["cables"] = {state: s for state, (s, _) in cables.items()}
        if distorted:
            doc["distortion_figure"] = _distortion_figure(distorted, figs / f"{doc['damper']}_distortion.png")
    return doc


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
    """A damper's stored cable laws for the first screen: ``[{state, law, converged}]`` from each
    ``cable-<state>/summary.json`` (the summary only: the figure is the diagnosis section's)."""
    from ..inference.runs import read_summary

    out = []
    for state, d in cable_dirs(runs, dname):
        s = read_summary(d) or {}
        out.append({"state": state, "law": s.get("law", "?"), "converged": s.get("converged")})
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
        "fit": _fit_figure(idata, figs / f"{stem}_fit.png", f"{dname} {t}: measured runs and posterior"),
        "power": _power_figure(idata, figs / f"{stem}_power.png", f"{dname} {t}: power dissipated"),
        "corner": _corner_figure(idata, model_names, figs / f"{stem}_corner.png"),
        "trace": _trace_figure(idata, names, figs / f"{stem}_trace.png"),
    }
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
            cv_fig = _cv_figure(data["quality"], figs / f"{dname}_cv.png")
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

    lot = lot_section(read_batch(runs), figs)
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
        tmp.write_text(page, encoding="utf-8")
    return index

