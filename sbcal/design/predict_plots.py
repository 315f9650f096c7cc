"""Figures of a prediction and of a design sweep."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.plotting import pyplot, save_png
from .predict import Prediction, clamp_amplitude
from .sweep import SweepResult


__all__ = ["plot_prediction", "plot_sweep"]

# --- figures -----------------------------------------------------------------------------------------

def _save(fig, path) -> Path:
    return save_png(fig, path, dpi=90)


def _spans(f, mask):
    """Contiguous runs of True lines as (lo, hi) frequency spans, half a line step either side."""
    f = np.asarray(f, float)
    edges = np.concatenate([[f[0] - (f[1] - f[0]) / 2 if f.size > 1 else f[0] * 0.98],
                            (f[1:] + f[:-1]) / 2, [f[-1] + (f[-1] - f[-2]) / 2 if f.size > 1 else f[0] * 1.02]])
    out, start = [], None
    for i, m in enumerate(list(mask) + [False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((edges[start], edges[i]))
            start = None
    return out


def plot_prediction(pred: Prediction, path, *, observed: dict | None = None) -> Path:
    """Magnitude, phase and dissipated power per condition: median, 90 % band, resonances (triangles
    with their 90 % range), extrapolated lines shaded (hatched). ``observed``: ``{level: (freq_hz,
    stiffness_n_per_m, phase_deg)}`` recorded run means to overlay."""
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    unit = "mm p-p" if pred.mode == "amplitude" else "m/s"
    f = pred.freq_hz
    shaded = False
    for i, lv in enumerate(pred.levels):
        color = f"C{i % 10}"
        label = f"{lv:g} {unit}"
        for ax, q in zip(axes, (pred.stiffness_n_per_m[i], pred.phase_deg[i], pred.power_w[i])):
            ax.fill_between(f, q[0], q[2], color=color, alpha=0.22, lw=0)
            ax.plot(f, q[1], color=color, lw=1.3, label=label if ax is axes[0] else None)
            for lo, hi in _spans(f, pred.extrapolated[i]):
                ax.axvspan(lo, hi, facecolor="none", edgecolor=color, hatch="///", alpha=0.5, lw=0,
                           label="extrapolated (beyond the calibrated curvature)" if not shaded and ax is axes[0] else None)
                shaded = True
        for r in pred.resonances:
            if r.level == lv:
                f05, f50, f95 = r.freq_hz
                axes[2].errorbar([f50], [r.power_w[1]], xerr=[[f50 - f05], [f95 - f50]], fmt="v", color=color, ms=6,
                                 capsize=3)
        if observed and lv in observed:
            fo, mo, po = (np.asarray(a, float) for a in observed[lv])
            x0 = clamp_amplitude(pred.mode, lv, fo)
            axes[0].plot(fo, mo, ".", color=color, mec="k", mew=0.4, ms=6)
            axes[1].plot(fo, po, ".", color=color, mec="k", mew=0.4, ms=6)
            axes[2].plot(fo, 0.5 * 2 * np.pi * fo * mo * np.sin(np.radians(po)) * x0**2, ".", color=color, mec="k",
                         mew=0.4, ms=6)
    axes[0].set(yscale="log", ylabel="|F/X| [N/m]")
    axes[1].set(ylabel="phase [deg]")
    axes[2].set(yscale="log", ylabel="dissipated power [W]", xlabel="frequency [Hz]")
    mode = "constant amplitude" if pred.mode == "amplitude" else "constant velocity"
    axes[0].set_title(f"{pred.damper}: predicted with the {pred.cable_damper} {pred.state} cable ({pred.law}), "
                      f"{mode}; median and 90 % band of {pred.n_draws} draws" + ("; dots: recorded" if observed else ""),
                      fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _save(fig, path)


def plot_sweep(result: SweepResult, path) -> Path:
    """Resonance frequencies (top) and peak dissipated power (bottom) against the design value, median
    and 90 % band per condition; values whose band bends the arms beyond the calibration hatched."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    x = result.values
    unit = "mm p-p" if result.mode == "amplitude" else "m/s"
    markers = "os^Dv<>p"
    for i, lv in enumerate(result.levels):
        color = f"C{i % 10}"
        for k in range(result.resonance_hz.shape[2]):
            q = result.resonance_hz[:, i, k]
            if not np.isfinite(q[:, 1]).any():
                continue
            axes[0].fill_between(x, q[:, 0], q[:, 2], color=color, alpha=0.18, lw=0)
            axes[0].plot(x, q[:, 1], color=color, marker=markers[k % len(markers)], ms=4, lw=1.2,
                         label=f"{lv:g} {unit}, resonance {k + 1}")
        p = result.peak_power_w[:, i]
        axes[1].fill_between(x, p[:, 0], p[:, 2], color=color, alpha=0.22, lw=0)
        axes[1].plot(x, p[:, 1], color=color, lw=1.3, label=f"{lv:g} {unit}")
        for lo, hi in _spans(x, result.extrapolated[:, i]):
            for ax in axes:
                ax.axvspan(lo, hi, facecolor="none", edgecolor=color, hatch="///", alpha=0.5, lw=0)
    axes[0].set(ylabel="resonance frequency [Hz]", title=f"{result.damper}: sweep of {result.field} "
                f"({result.cable_damper} {result.state} cable, {result.n_draws} draws; hatched: extrapolated)")
    axes[1].set(ylabel="peak dissipated power [W]", yscale="log", xlabel=result.field)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, ncol=2)
    axes[0].title.set_fontsize(9)
    fig.tight_layout()
    return _save(fig, path)
