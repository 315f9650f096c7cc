"""Test labels, read one way: ``"A-B[-state]"``.

A bench test is labelled by its commanded amplitudes in mm peak-to-peak: A up to the step frequency
and B above it (``"0.5-0.5"`` constant, ``"2-1"`` stepped), and optionally the cable's state
(``"1-1-oiled"``; no suffix is the ``dry`` cable). The virtual bench, the cable fit, ``predict`` and
``span`` all read labels through :func:`parse_label`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


__all__ = ["TestLabel", "parse_label", "cable_state", "state_tests", "DRY"]

DRY = "dry"
"""The cable state of a label without a suffix."""

_LABEL = re.compile(r"^(\d+(?:\.\d+)?)-(\d+(?:\.\d+)?)(?:-(.+))?$")


@dataclass(frozen=True)
class TestLabel:
    """A parsed test label.

    Attributes
    ----------
    text : str
    below_mm_pp, above_mm_pp : float
        Commanded amplitude [mm p-p] up to and above the step frequency.
    state : str
        The cable state (``"dry"`` without a suffix).
    """

    __test__ = False  # not a pytest test class

    text: str
    below_mm_pp: float
    above_mm_pp: float
    state: str

    @property
    def constant(self) -> bool:
        """One amplitude over the whole sweep (``A-A``)."""
        return self.below_mm_pp == self.above_mm_pp

    @property
    def amplitudes(self) -> tuple:
        return (self.below_mm_pp, self.above_mm_pp)


def parse_label(label) -> TestLabel | None:
    """The label's amplitudes and cable state; None when it is not of the form ``A-B[-state]``."""
    m = _LABEL.match(str(label))
    if not m:
        return None
    return TestLabel(str(label), float(m.group(1)), float(m.group(2)), m.group(3) or DRY)


def cable_state(label) -> str:
    """The cable state of a test label: its suffix after the amplitudes, ``dry`` without one (a label of
    another form is its own state)."""
    p = parse_label(label)
    return p.state if p else str(label)


def state_tests(tests) -> dict:
    """``{state: [tests]}`` in the order the tests come."""
    out = {}
    for t in tests:
        out.setdefault(cable_state(t), []).append(t)
    return out
