"""A design search stored and read back (``<runs>/design/<label>/``): ``best.toml`` (a damper file),
``designs.csv``, ``design.png`` and, last, ``summary.json``."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..core._io import json_ready
from ..core.plotting import pyplot, save_png
from ..inference.store import design_dir as store_design_dir
from ..inference.store import design_dirs, owner
from ..model.damper import damper_toml
from .search import DesignResult


__all__ = ["design_label", "design_dir", "plot_design", "store_design", "read_design", "stored_designs"]


def design_label(result: DesignResult, start_name: str) -> str:
    """``<conductor>-<start damper>[-<cable damper>]-<state>[-2ends][-life]`` (the cable damper named when
    it is not the starting one, as a span study's label)."""
    cable = Path(result.cable)
    damper = cable.parent.name
    state = cable.name.removeprefix("cable-")
    parts = [result.conductor.name, start_name] + ([damper] if damper != start_name else []) + [state]
    if result.ends == 2:
        parts.append("2ends")
    if result.objective == "life":
        parts.append("life")
    return re.sub(r"[^A-Za-z0-9._-]+", "_", "-".join(parts))


def design_dir(result: DesignResult, start_name: str, runs_dir=None) -> Path:
    """``<runs>/design/<label>``, ``<runs>`` defaulting to the store holding the cable run."""
    return store_design_dir(runs_dir if runs_dir is not None else owner(result.cable)[0],
                            design_label(result, start_name))


def plot_design(result: DesignResult, path) -> None:
    """The objective of every evaluated design against each free field and against the total mass
    (extrapolated designs hollow), the starting and chosen designs marked; one PNG, atomically."""
    plt = pyplot()
    frame = result.to_frame()
    cols = list(result.space.fields) + ["total_mass_kg"]
    fig, axes = plt.subplots(1, len(cols), figsize=(4.2 * len(cols), 3.8), squeeze=False)
    ok = ~frame["extrapolated"].to_numpy(bool)
    ylabel = ("margin" if result.objective == "margin" else "service life [years]") + " q10 (search grid)"
    for ax, col in zip(axes[0], cols):
        x, y = frame[col].to_numpy(float), frame["objective"].to_numpy(float)
        ax.scatter(x[ok], y[ok], s=10, color="C0", label="designs evaluated")
        if (~ok).any():
            ax.scatter(x[~ok], y[~ok], s=12, facecolors="none", edgecolors="C3", label="extrapolated (not chosen)")
        for rec, name, color in ((result.start, "start", "k"), (result.best, "best", "C2")):
            xv = rec["total_mass_kg"] if col == "total_mass_kg" else rec["fields"].get(col, np.nan)
            ax.scatter([xv], [rec["objective"]], marker="*", s=120, color=color,
                       label=f"{name} (full evaluation)")
        ax.set(xlabel=col, ylabel=ylabel)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"{result.conductor.name}: design search, objective {result.objective}", fontsize=10)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


def store_design(result: DesignResult, directory, *, meta: dict | None = None) -> Path:
    """Write ``best.toml``, ``designs.csv``, ``design.png`` and, last, ``summary.json`` into
    ``directory``, each atomically. Returns the directory."""
    from ..core._io import atomic_path, write_json

    d = Path(directory)
    best = result.best_damper
    comment = (f"designed by sbcal design for {result.conductor.name} with the cable of {result.cable}\n"
               f"objective {result.objective}: q10 {result.best['objective']:.6g} (start {result.start['objective']:.6g})")
    with atomic_path(d / "best.toml", ".toml") as tmp:
        Path(tmp).write_text(damper_toml(best, comment=comment))
    with atomic_path(d / "designs.csv", ".csv") as tmp:
        result.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
    plot_design(result, d / "design.png")
    write_json(d / "summary.json", json_ready(dict(result.summary(), **(meta or {}))), indent=1, allow_nan=False)
    return d


def read_design(directory) -> dict:
    """The ``summary.json`` of a stored design search, checked for its main keys."""
    from ..core._io import read_summary

    return read_summary(directory, ("start", "best", "objective", "optimiser", "evaluations"), "design search",
                        "sbcal design")


def stored_designs(runs_dir) -> list:
    """Every design search of a run store: ``[(directory, summary dict)]`` sorted by directory name."""
    return [(d, read_design(d)) for d in design_dirs(runs_dir)]
