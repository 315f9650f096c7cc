"""A comparison's files: ``summary.json`` (written last), ``criteria.csv``, ``curves.csv`` and ``compare.png``.

``summary.json`` holds, per excitation, the headline, the verdict, ``p_all_within``, every criterion with its
bands, the acceptance file's contents, the notes, and the seed and versions; ``criteria.csv`` the criteria
table and ``curves.csv`` every curve and change per line with its 90 % band (a ``level`` column says which
excitation). Every file is written to a temporary file and renamed.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from ..core._io import atomic_path, json_ready, read_summary, write_json
from ..core.plotting import pyplot, save_png
from .compare import Comparison


__all__ = ["store_comparisons", "read_comparison", "compare_figure"]


def _one(c: Comparison) -> dict:
    return json_ready({
        "mode": c.before.mode, "level": c.before.level, "headline": c.headline(), "verdict": c.verdict,
        "p_all_within": c.p_all_within, "criteria": [dataclasses.asdict(k) for k in c.criteria],
        "before": {"damper": c.before.damper, "state": c.before.state, "source": c.before.source, "run": c.before.run,
                   "discrepancy": c.before.discrepancy, "n_runs": c.before.n_runs, "n_draws": int(c.before.fuu.shape[0])},
        "after": {"damper": c.after.damper, "state": c.after.state, "source": c.after.source, "run": c.after.run,
                  "discrepancy": c.after.discrepancy, "n_runs": c.after.n_runs, "n_draws": int(c.after.fuu.shape[0])},
        "freq_range_hz": [float(c.freq_hz[0]), float(c.freq_hz[-1])], "extrapolated_lines": int(c.extrapolated.sum()),
        "notes": list(c.notes),
    })


def compare_figure(comparisons, path) -> Path:
    """Per excitation: both characteristics' impedance with 90 % bands (top), and the change of |Z| with its
    band against the tolerance band (bottom), resonance changes as points with their intervals."""
    plt = pyplot()
    n = len(comparisons)
    fig, axes = plt.subplots(2, n, figsize=(6.2 * n, 6.0), squeeze=False, sharex="col")
    for k, c in enumerate(comparisons):
        f, cu = c.freq_hz, c.curves
        top, bot = axes[0][k], axes[1][k]
        for side, color in (("before", "C0"), ("after", "C3")):
            q = cu[f"{side}_impedance"]
            top.fill_between(f, q[0], q[2], color=color, alpha=0.25, lw=0)
            top.plot(f, q[1], color=color, lw=1.3, label=f"{side}: {getattr(c, side).label} ({getattr(c, side).source})")
        top.set_yscale("log")
        top.set_ylabel("|Z| [N s/m]")
        what = f"{c.before.level:g} mm p-p" if c.before.mode == "amplitude" else f"{c.before.level:g} m/s"
        top.set_title(f"{what}: {c.verdict}", fontsize=10)
        top.legend(fontsize=7)
        q = cu["impedance_change"]
        tol = c.acceptance.tolerances.get("impedance_pct")
        if tol is not None:
            bot.axhspan(-tol, tol, color="0.85", label=f"tolerance ±{tol:g} %")
        bot.fill_between(f, q[0], q[2], color="C2", alpha=0.35, lw=0, label="change of |Z|, 90 %")
        bot.plot(f, q[1], color="C2", lw=1.2)
        for crit in c.criteria:
            if crit.key == "resonance_frequency_pct" and np.isfinite(crit.before[1]):
                bot.axvline(crit.before[1], color="0.5", lw=0.6, ls=":")
        if c.extrapolated.any():
            bot.plot(f[c.extrapolated], np.zeros(int(c.extrapolated.sum())), "x", color="k", label="extrapolated")
        bot.axhline(0, color="k", lw=0.5)
        bot.set_xscale("log")
        bot.set_xlabel("frequency [Hz] (dotted: resonances before)")
        bot.set_ylabel("after / before − 1 [%]")
        bot.legend(fontsize=7)
    fig.tight_layout()
    return save_png(fig, path, dpi=90)


def store_comparisons(comparisons, directory, *, meta: dict, figure: bool = True) -> Path:
    """Write the comparison files into ``directory`` (module docstring); ``summary.json`` last."""
    d = Path(directory)
    frames, curves = [], []
    for c in comparisons:
        frames.append(c.criteria_frame().assign(level=c.before.level, mode=c.before.mode))
        curves.append(c.curves_frame().assign(level=c.before.level, mode=c.before.mode))
    for name, parts in (("criteria.csv", frames), ("curves.csv", curves)):
        with atomic_path(d / name, ".csv") as tmp:
            pd.concat(parts, ignore_index=True).to_csv(tmp, index=False)
    if figure:
        with atomic_path(d / "compare.png", ".png") as tmp:
            compare_figure(comparisons, tmp)
    doc = dict(meta)
    doc["acceptance"] = comparisons[0].acceptance.as_dict()
    doc["verdict"] = _overall([c.verdict for c in comparisons])
    doc["comparisons"] = [_one(c) for c in comparisons]
    write_json(d / "summary.json", doc, indent=1)
    return d


def _overall(verdicts) -> str:
    for v in ("fail", "inconclusive", "pass"):
        if v in verdicts:
            return v
    return "no spec"


def read_comparison(directory) -> dict:
    """A stored comparison's ``summary.json`` (one-line InputError when it is not one)."""
    return read_summary(directory, ("verdict", "comparisons", "acceptance"), "comparison", "sbcal compare")
