"""Figures, one way: matplotlib on its file backend, each PNG written whole or not at all."""

from __future__ import annotations

from pathlib import Path

from ._io import atomic_path


__all__ = ["pyplot", "save_png"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend: files only, no display (servers, worker processes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path, *, dpi: int) -> Path:
    """Write ``fig`` as a PNG at ``path`` (through a temporary file, then renamed) and close it."""
    path = Path(path)
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)
    return path
