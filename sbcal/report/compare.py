"""The report's section on stored comparisons (``sbcal compare``): read from the run store, never recomputed."""

from __future__ import annotations

import shutil
from pathlib import Path


__all__ = ["compare_section"]


def compare_section(runs, figs: Path) -> list:
    """One entry per stored comparison: its headlines, criteria and figure (copied into ``figs``)."""
    from ..core.errors import InputError
    from ..design.compare_store import read_comparison
    from ..inference.store import compare_dirs

    out = []
    for d in compare_dirs(runs):
        try:
            doc = read_comparison(d)
        except InputError:
            continue  # not one of sbcal compare's: the report shows what it can read
        fig = None
        if (d / "compare.png").is_file():
            fig = f"compare_{d.name}.png"
            shutil.copyfile(d / "compare.png", figs / fig)
        out.append({"name": d.name, "verdict": doc["verdict"], "spec": doc.get("spec"),
                    "acceptance": doc["acceptance"], "comparisons": doc["comparisons"], "figure": fig})
    return out
