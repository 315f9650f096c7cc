"""What ``sbcal compare`` compares: a RUN argument read as characteristics (``docs/compare.md``).

A RUN is either

* a calibrated damper in a run store, ``<runs>/<damper>`` (its ``dry`` cable) or ``<runs>/<damper>@<state>``
  (``runs/damper1@oiled``): its per-test posteriors, and its cable fit ``cable-<state>`` where there is one; or
* a bench file (``.csv``, ``.xlsx``, ``.parquet``; ``FILE@<state>`` likewise) of one damper (or the one
  ``--damper`` names), which is cleaned and sampled first (:func:`sbcal.pipeline.calibrate_bench`), by the pipeline's stages and
  with ``sbcal run``'s seed conventions, into its own run store ``<runs>/compare/calibrations/<file>-<digest>/``
  (a test's posterior is reused while its inputs are unchanged).

Per excitation the characteristic comes from the test at that constant amplitude when both runs have one,
else from the state's cable law, else the comparison is refused in one line
(:mod:`sbcal.design.characteristic`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.labels import DRY
from .acceptance import Acceptance
from .characteristic import constant_tests, from_cable, from_test


__all__ = ["RunRef", "parse_run", "resolve", "characteristics", "geometry_differs", "compare_runs"]

_BENCH_SUFFIXES = (".csv", ".gz", ".xlsx", ".parquet", ".tsv", ".txt")


@dataclass(frozen=True)
class RunRef:
    """A resolved RUN: a damper of a run store in one cable state."""

    runs: str
    damper: str
    state: str
    text: str

    @property
    def label(self) -> str:
        return self.damper if self.state == DRY else f"{self.damper}@{self.state}"


def _split(text: str) -> tuple[str, str]:
    path, _, state = str(text).partition("@")
    return path, state or DRY


def parse_run(text: str) -> tuple[str, str, bool]:
    """``(path, state, is_bench_file)`` of a RUN argument; the path must exist."""
    path, state = _split(text)
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: no such run (expected <runs>/<damper>[@state] or a bench file)")
    is_file = p.is_file()
    if is_file and not p.name.lower().endswith(_BENCH_SUFFIXES):
        raise InputError(f"{path}: not a bench file (.csv, .xlsx, .parquet) nor a damper directory of a run store")
    return path, state, is_file


def resolve(text: str, *, calibrate=None) -> RunRef:
    """A RUN argument as a :class:`RunRef`; a bench file is handed to ``calibrate(path, state, text)``
    (the pipeline's :func:`sbcal.pipeline.calibrate_bench`), which returns the run it made."""
    path, state, is_file = parse_run(text)
    if is_file:
        if calibrate is None:
            raise InputError(f"{path}: a bench file needs calibrating first (sbcal compare does it)")
        return calibrate(path, state, text)
    p = Path(path)
    return RunRef(str(p.parent), p.name, state, text)


def _cable(ref: RunRef) -> Path | None:
    from ..inference.store import SUMMARY, cable_dir

    d = cable_dir(ref.runs, ref.damper, ref.state)
    return d if (d / SUMMARY).is_file() else None


def _levels(before: RunRef, after: RunRef, acc: Acceptance, paramset: str) -> list:
    """``[(mode, level, before source, after source)]``: each source a test directory or a cable directory."""
    tb = constant_tests(before.runs, before.damper, before.state, paramset)
    ta = constant_tests(after.runs, after.damper, after.state, paramset)
    if acc.level is None:  # no acceptance file: every amplitude both tested
        common = sorted(set(tb) & set(ta))
        if not common:
            raise InputError(f"{before.text} ({', '.join(f'{a:g}' for a in sorted(tb)) or 'no'} mm p-p) and "
                             f"{after.text} ({', '.join(f'{a:g}' for a in sorted(ta)) or 'no'} mm p-p) share no "
                             "constant-amplitude test; give --spec with the excitation")
        return [("amplitude", a, tb[a], ta[a]) for a in common]
    if acc.mode == "amplitude":
        hit_b = next((d for a, d in tb.items() if np.isclose(a, acc.level)), None)
        hit_a = next((d for a, d in ta.items() if np.isclose(a, acc.level)), None)
        if hit_b is not None and hit_a is not None:
            return [("amplitude", acc.level, hit_b, hit_a)]
    out = []
    for ref in (before, after):
        c = _cable(ref)
        if c is None:
            what = (f"a constant velocity of {acc.level:g} m/s" if acc.mode == "velocity"
                    else f"{acc.level:g} mm p-p, which it was not tested at")
            raise InputError(f"{ref.text}: the acceptance file asks for {what}, and {ref.label} has no cable-law fit "
                             f"to predict it (run 'sbcal cable --damper {ref.damper}')")
        out.append(c)
    return [(acc.mode, acc.level, out[0], out[1])]


def characteristics(before: RunRef, after: RunRef, acc: Acceptance, *, paramset: str, n_draws: int, rng) -> list:
    """``[(before Characteristic, after Characteristic)]``, one pair per excitation (:func:`_levels`)."""
    from ..model.fem import STANDARD_GRID_HZ

    pairs = []
    for mode, level, db, da in _levels(before, after, acc, paramset):
        two = []
        for d in (db, da):
            if d.name.startswith("cable-"):
                f = STANDARD_GRID_HZ
                if acc.freq_range_hz is not None:
                    lo, hi = acc.freq_range_hz
                    f = f[(f >= lo) & (f <= hi)]
                    if f.size < 3:
                        raise InputError(f"{acc.source}: key 'excitation.frequency_hz': {lo:g}-{hi:g} Hz holds "
                                         f"{f.size} line(s) of the standard grid; at least 3 are needed")
                two.append(from_cable(d, mode=mode, level=level, freq_hz=f, n_draws=n_draws, rng=rng))
            else:
                two.append(from_test(d, freq_range=acc.freq_range_hz, n_draws=n_draws, rng=rng))
        pairs.append(tuple(two))
    return pairs


def geometry_differs(before, after) -> list:
    """The damper fields in which the two characteristics' dampers differ (beyond 1e-9 relative)."""
    from ..model.damper import GEOMETRY

    out = []
    for k in GEOMETRY:
        a, b = before.damper_values.get(k), after.damper_values.get(k)
        if a is None or b is None:
            continue
        if not np.isclose(float(a), float(b), rtol=1e-9, atol=0.0):
            out.append(k)
    return out


def compare_runs(before: str, after: str, acceptance: Acceptance | None = None, *, paramset: str = "theta1",
                 n_draws: int = 1000, seed: int = 0, calibrate=None) -> tuple[list, list]:
    """Did the damper change? Every excitation's :class:`sbcal.design.compare.Comparison` of two RUNs.

    Parameters
    ----------
    before, after : str
        RUN arguments (module docstring): ``<runs>/<damper>[@state]``, or a bench file when ``calibrate``
        is given (:func:`resolve`).
    acceptance : Acceptance, optional
        :func:`sbcal.design.acceptance.read_acceptance`'s; None: the change at every amplitude both tested,
        no decision.
    paramset : str
    n_draws : int
        Posterior draws a side.
    seed : int
        Fixes the draws' subsets, the discrepancy draws and the pairing.
    calibrate : callable, optional
        ``calibrate(path, state, text) -> RunRef`` for a bench-file RUN.

    Returns
    -------
    comparisons : list of Comparison
    warnings : list of str

    Raises
    ------
    InputError
        A missing run; no excitation both runs cover; different geometry under ``same_design``; ...
    """
    from .acceptance import default_acceptance
    from .compare import compare_characteristics

    acc = acceptance or default_acceptance()
    for text in (before, after):
        parse_run(text)  # both exist before any work
    refs = [resolve(t, calibrate=calibrate) for t in (before, after)]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 38]))
    pairs = characteristics(*refs, acc, paramset=paramset, n_draws=n_draws, rng=rng)
    warnings = []
    differs = geometry_differs(*pairs[0])
    if differs:
        msg = f"{refs[0].label} and {refs[1].label} differ in damper geometry ({', '.join(differs)})"
        if acc.same_design:
            raise InputError(f"{acc.source}: same_design = true, but {msg}")
        warnings.append(f"{msg}: the change includes the design's")
    return [compare_characteristics(b, a, acc, rng=rng) for b, a in pairs], warnings
