"""The one progress display of every long stage: a tqdm bar on stderr (tqdm is what emcee uses).

Quiet when asked (``--quiet``) or when stderr is not a terminal (a log file or CI gets no bars).
"""

from __future__ import annotations

import sys

from tqdm.auto import tqdm


__all__ = ["progress_bar", "enabled"]


def enabled(quiet: bool = False) -> bool:
    """Whether bars are shown: not ``quiet`` and stderr is a terminal."""
    return not quiet and sys.stderr.isatty()


def progress_bar(label: str | None, total: float | None = None, unit: str = "it"):
    """A bar labelled ``label``; ``None`` (or stderr not a terminal) gives a silent one.

    Use as a context manager; ``bar.update(k)``, ``bar.total = ...`` and ``bar.set_postfix_str(text)``.
    """
    return tqdm(total=total, desc=label or "", unit=unit, disable=label is None or not enabled(),
                file=sys.stderr, leave=False, dynamic_ncols=True)
