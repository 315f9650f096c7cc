"""The report's figures, each drawn from a stored result into a PNG (``figures/``); returns its file name.

Per test: the fit (runs, their mean, the model's and a new run's 90 % bands), the dissipated power, corner
and trace plots; per damper: the runs' scatter, the diagnosis's residuals, the cable laws, the predicted
distortion and the fitted curves. Nothing is recomputed beyond quantiles of stored draws.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.plotting import pyplot, save_png


__all__ = ["corner_figure", "curves_figure", "cv_figure", "diagnosis_figure", "distortion_figure", "fit_figure",
           "has_harmonics", "law_figure", "power_figure", "trace_figure"]


_FIG_DPI = 90


def _save(fig, path: Path) -> str:
    return save_png(fig, path, dpi=_FIG_DPI).name


def fit_figure(idata, path: Path, title: str) -> str:
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


def power_figure(idata, path: Path, title: str) -> str:
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


def corner_figure(idata, names, path: Path) -> str:
    import corner

    x = np.stack([np.asarray(idata.posterior[n]).ravel() for n in names], axis=1)
    fig = corner.corner(x, labels=list(names), quantiles=[0.05, 0.5, 0.95], show_titles=True, title_fmt=".3g",
                        title_kwargs={"fontsize": 8}, label_kwargs={"fontsize": 8})
    fig.set_size_inches(1.5 * len(names) + 1, 1.5 * len(names) + 1)
    return _save(fig, path)


def trace_figure(idata, names, path: Path) -> str:
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


def cv_figure(quality: dict, path: Path) -> str:
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


def diagnosis_figure(doc, path: Path) -> str:
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


def law_figure(cables: dict, path: Path) -> str:
    """The cable law of each state: EJ and loss factor against curvature amplitude, median and 90 %
    band, with the curvature range each test reached."""
    from ..inference.cable_fit import law_curves
    from ..model.laws.zones import ZONED_SUFFIX

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


def distortion_figure(cables: dict, path: Path) -> str:
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


def has_harmonics(summary: dict, where: Path) -> bool:
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


def curves_figure(doc, path: Path) -> str:
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
