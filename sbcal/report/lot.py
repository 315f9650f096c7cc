"""The lot's section of the report and its forest plot, drawn from the stored ``sbcal batch`` result."""

from __future__ import annotations

from pathlib import Path

from ..core.plotting import pyplot, save_png


__all__ = ["forest_figure", "lot_section"]


def forest_figure(doc: dict, path) -> Path:
    """Per population dimension: each unit's own 90 % interval (grey) and its shrunk one (black) over the
    population's median-unit band (dark) and next-unit band (light); outliers in red."""
    plt = pyplot()
    dims = [f"{r['parameter']}[{r['test']}]" for r in doc["population"]]
    units = doc["per_unit"]
    fig, axes = plt.subplots(1, len(dims), figsize=(3.2 * len(dims) + 1.5, 0.32 * len(units) + 1.6), sharey=True,
                             squeeze=False)
    for ax, dim, pop in zip(axes[0], dims, doc["population"]):
        ax.axvspan(pop["next_unit"][0], pop["next_unit"][2], color="tab:blue", alpha=0.12, label="next unit, 90 %")
        ax.axvspan(pop["median_unit"][0], pop["median_unit"][2], color="tab:blue", alpha=0.35, label="median unit, 90 %")
        for k, u in enumerate(units):
            v = u["values"][dim]
            bad = u["outlier_probability"] >= 0.5
            ax.plot(v["own"][::2], [k + 0.15] * 2, color="0.6", lw=1.5)
            ax.plot(v["shrunk"][::2], [k - 0.15] * 2, color="tab:red" if bad else "k", lw=2)
            ax.plot([v["shrunk"][1]], [k - 0.15], "o", color="tab:red" if bad else "k", ms=3)
        unit = pop["unit"] if pop["unit"] != "1" else ""
        ax.set_xlabel(f"{dim} {unit}".strip())
    axes[0][0].set_yticks(range(len(units)))
    axes[0][0].set_yticklabels([f"{u['unit']}  P {u['outlier_probability']:.2f}" for u in units], fontsize=8)
    axes[0][0].invert_yaxis()
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.suptitle("units over the population: own (grey) and shrunk (black) 90 % intervals", fontsize=9)
    fig.tight_layout()
    return save_png(fig, path, dpi=90)


def lot_section(doc: dict | None, figs: Path, cables=()) -> dict | None:
    """What the page shows of a stored lot (None when the store has none); ``cables``: ``(directory,
    summary)`` of its design cable runs (:mod:`sbcal.inference.batch_cable`)."""
    if doc is None:
        return None
    from ..inference.batch import headline

    out = {"headline": headline(doc), "converged": doc["converged"], "n_units": doc["n_units"],
           "members": doc["members"], "model": doc["model"], "figure": None, "rows": [], "units": [],
           "cables": [_cable_rows(d, s) for d, s in cables]}
    if not doc["converged"]:
        return out
    out["figure"] = forest_figure(doc, figs / "lot_forest.png").name
    for r in doc["population"]:
        out["rows"].append({"dim": f"{r['parameter']}[{r['test']}]", "unit": r["unit"], "median_unit": r["median_unit"],
                            "scatter": r["scatter_percent"], "next_unit": r["next_unit"]})
    for u in doc["per_unit"]:
        out["units"].append({"unit": u["unit"], "p": u["outlier_probability"], "ess": u["ess_median"],
                             "flagged": u["flagged"], "outlier": u["outlier_probability"] >= 0.5})
    return out


def _cable_rows(directory, summary: dict) -> dict:
    """A design cable run as the page shows it: its headline, the population per parameter, where it is."""
    from ..inference.batch import headline

    pop = summary["population"]
    return {"state": summary["state"], "law": summary["law"], "path": str(directory), "converged": summary["converged"],
            "headline": headline(pop), "kept": summary.get("kept_fraction"), "n_draws": summary.get("n_draws"),
            "rows": [{"dim": r["parameter"], "median_unit": r["median_unit"], "scatter": r["scatter_percent"],
                      "next_unit": r["next_unit"]} for r in pop["population"]] if pop["converged"] else []}
