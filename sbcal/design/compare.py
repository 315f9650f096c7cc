"""Did the damper change? Two characteristics compared as posteriors (``sbcal compare``, ``docs/compare.md``).

The two calibrations are independent (two tests, each with its own runs): draw ``s`` of *before* is
paired with draw ``pi(s)`` of *after* (a random permutation), and every quantity's change is computed pair
by pair, so its distribution is that of after/before - 1 under both posteriors. Per criterion of the
acceptance file (:mod:`sbcal.design.acceptance`):

* ``resonance_frequency_pct``: each resonance's frequency, ``f_after / f_before - 1`` (resonances matched
  by order when both curves have as many, else by the nearest median frequency; an unmatched one fails when
  its peak is clear, :data:`CLEAR_PEAK`, and is noted otherwise);
* ``resonance_power_pct``: the power dissipated at each resonance, likewise;
* ``impedance_pct``: ``|Z_after| / |Z_before| - 1`` at every common line of the range, judged on the
  largest over the lines (the curve within the band at *every* line, per pair);
* ``phase_deg``: the impedance phase's change [deg], the largest over the lines;
* ``power_pct``: the power dissipated per line, the largest relative change over the lines.

``P(within)`` is the share of pairs whose change lies within the tolerance; ``P(beyond) = 1 - P(within)``.
The rule: **pass** when ``P(within) >= 0.95``, **fail** when ``P(beyond) >= 0.95``, else **inconclusive**.
The damper's verdict uses the joint event (every criterion within, pair by pair): pass when
``P(all within) >= 0.95``, fail when any criterion fails, else inconclusive. For an inconclusive criterion
the runs per test that would most likely decide it: the change's posterior sd shrinks as ``1/sqrt(runs)``
where noise sets it, and the criterion is decided when the tolerance lies 1.645 sd from the median change
(``runs_needed``; ``None`` when the median sits on the tolerance, or the draws come from a cable law).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..core.errors import InputError
from .acceptance import Acceptance
from .characteristic import Characteristic, power
from .predict import nan_quantiles


__all__ = ["DECIDE", "CLEAR_PEAK", "Criterion", "Comparison", "compare_characteristics", "lab_gap"]

DECIDE = 0.95
"""The probability a decision needs: pass at P(within) >= 0.95, fail at P(beyond) >= 0.95."""

CLEAR_PEAK = 0.10
"""A resonance only one side has fails its criteria when its median peak is this prominent in ln R (10 %, twice
the finder's least, :data:`sbcal.design.resonance.PROMINENCE`); a weaker one (a mode's shoulder at the range's
edge, a peak on the threshold) is noted and not judged."""

_Z90 = 1.6448536269514722  # the normal's 95 % quantile: a one-sided 95 % decision


@dataclass(frozen=True)
class Criterion:
    """One scalar's change and its verdict.

    Attributes
    ----------
    key : str
        The tolerance's key (:data:`sbcal.design.acceptance.TOLERANCES`).
    name : str
        What it is: ``"resonance 2 frequency"``, ``"impedance |Z| (largest over 5-40 Hz)"``.
    unit : str
        ``"%"`` or ``"deg"``.
    change : tuple of float
        (q05, median, q95) of the change (% or deg; for a largest-over-lines criterion, of the signed
        change at the line where it is largest in size, per pair).
    before, after : tuple of float
        (q05, median, q95) of the quantity itself, where it is a scalar (else NaN).
    tolerance : float or None
    p_within : float or None
    verdict : str
        ``"pass"``, ``"fail"``, ``"inconclusive"`` or ``"no spec"``.
    runs_needed : int or None
        Runs per test that would most likely decide an inconclusive criterion.
    note : str
    """

    key: str
    name: str
    unit: str
    change: tuple
    before: tuple = (math.nan,) * 3
    after: tuple = (math.nan,) * 3
    tolerance: float | None = None
    p_within: float | None = None
    verdict: str = "no spec"
    runs_needed: int | None = None
    note: str = ""


@dataclass(frozen=True, eq=False)
class Comparison:
    """The change from *before* to *after* (:func:`compare_characteristics`).

    Attributes
    ----------
    before, after : Characteristic
    acceptance : Acceptance
    criteria : tuple of Criterion
    verdict : str
        The damper's: ``pass``, ``fail``, ``inconclusive`` or ``no spec``.
    p_all_within : float or None
        Share of pairs with every criterion within its tolerance.
    freq_hz : ndarray, shape (F,)
        The common lines.
    curves : dict of str -> ndarray, shape (3, F)
        (q05, median, q95) per line of ``before_/after_`` ``impedance`` [N s/m], ``phase`` [deg], ``power`` [W],
        and the changes ``impedance_change`` [%], ``phase_change`` [deg], ``power_change`` [%].
    extrapolated : ndarray of bool, shape (F,)
        Either side extrapolated its cable law there.
    notes : tuple of str
        What is shared and what was assumed.
    """

    before: Characteristic
    after: Characteristic
    acceptance: Acceptance
    criteria: tuple
    verdict: str
    p_all_within: float | None
    freq_hz: np.ndarray
    curves: dict
    extrapolated: np.ndarray
    notes: tuple = field(default=())

    def headline(self) -> str:
        """The first line: ``after: fail - resonance 2 frequency moved -9.4 % [-10.8, -8.1] against +-5 %, P(beyond) 1.00``."""
        who = f"{self.after.label} against {self.before.label}"
        if not self.criteria:
            return f"{who}: no criterion could be evaluated"
        if self.verdict == "no spec":
            c = max(self.criteria, key=lambda c: abs(c.change[1]) / (1.0 if c.unit == "deg" else 10.0))
            return f"{who}: change {_moved(c)} (no acceptance file: no decision)"
        order = {"fail": 0, "inconclusive": 1, "pass": 2}
        # the deciding criterion: the surest failure, else the least sure, else the least sure pass
        c = min(self.criteria, key=lambda c: (order[c.verdict], -(1 - c.p_within) if c.verdict == "fail" else c.p_within))
        tail = (f"P(beyond) {1 - c.p_within:.2f}" if c.verdict == "fail" else f"P(within) {c.p_within:.2f}")
        joint = "" if self.p_all_within is None else f"; every criterion within: P {self.p_all_within:.2f}"
        return f"{who}: {self.verdict} — {_moved(c)} against ±{c.tolerance:g} {c.unit}, {tail}{joint}"

    def criteria_frame(self) -> pd.DataFrame:
        rows = []
        for c in self.criteria:
            rows.append({"criterion": c.name, "key": c.key, "unit": c.unit, "change_q05": c.change[0],
                         "change_median": c.change[1], "change_q95": c.change[2], "before_q05": c.before[0],
                         "before_median": c.before[1], "before_q95": c.before[2], "after_q05": c.after[0],
                         "after_median": c.after[1], "after_q95": c.after[2], "tolerance": c.tolerance,
                         "p_within": c.p_within, "verdict": c.verdict, "runs_needed": c.runs_needed, "note": c.note})
        return pd.DataFrame(rows)

    def curves_frame(self) -> pd.DataFrame:
        out = {"frequency_hz": self.freq_hz}
        for k, v in self.curves.items():
            for i, q in enumerate(("q05", "median", "q95")):
                out[f"{k}_{q}"] = v[i]
        out["extrapolated"] = self.extrapolated
        return pd.DataFrame(out)


def _moved(c: Criterion) -> str:
    lo, med, hi = c.change
    sign = "+" if med >= 0 else "−"
    return f"{c.name} moved {sign}{abs(med):.1f} {c.unit} [{lo:+.1f}, {hi:+.1f}]"


def _q(x) -> tuple:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return (math.nan,) * 3
    return tuple(float(v) for v in np.quantile(x, (0.05, 0.5, 0.95)))


def _common_lines(before: Characteristic, after: Characteristic):
    """Indices of the lines both characteristics have (within 1e-6 relative)."""
    fb, fa = before.freq_hz, after.freq_hz
    j = np.searchsorted(fa, fb).clip(0, fa.size - 1)
    j2 = (j - 1).clip(0)
    pick = np.where(np.abs(fa[j] - fb) <= np.abs(fa[j2] - fb), j, j2)
    ok = np.abs(fa[pick] - fb) <= 1e-6 * fb
    return np.flatnonzero(ok), pick[ok]


def _match(rb: tuple, ra: tuple) -> list:
    """Pairs (i, j) of before's and after's resonances; unmatched ones as (i, None) / (None, j)."""
    if len(rb) == len(ra):
        return list(zip(range(len(rb)), range(len(ra))))
    pairs, used = [], set()
    for i, r in enumerate(rb):
        dist = [abs(math.log(a["median_hz"] / r["median_hz"])) if j not in used else math.inf for j, a in enumerate(ra)]
        j = int(np.argmin(dist)) if dist else None
        if j is not None and dist[j] < math.log(1.25):
            pairs.append((i, j))
            used.add(j)
        else:
            pairs.append((i, None))
    pairs += [(None, j) for j in range(len(ra)) if j not in used]
    return pairs


def _runs_needed(change, tol: float, n_runs: int) -> int | None:
    """Runs per test (both tests) at which the tolerance would lie 1.645 sd from the median change."""
    x = np.asarray(change, float)
    x = x[np.isfinite(x)]
    if n_runs <= 0 or x.size < 10:
        return None
    med, sd = float(np.median(np.abs(x))), float(np.std(x))
    gap = abs(tol - med)
    if gap < 1e-3 * tol or sd == 0:
        return None
    return int(math.ceil(n_runs * (_Z90 * sd / gap) ** 2))


def _judge(key, name, unit, change, size, tol, n_runs, before=None, after=None, note="") -> tuple:
    """A :class:`Criterion` and its per-pair within mask (None without a tolerance)."""
    c = dict(key=key, name=name, unit=unit, change=_q(change), note=note,
             before=_q(before) if before is not None else (math.nan,) * 3,
             after=_q(after) if after is not None else (math.nan,) * 3)
    if tol is None:
        return Criterion(**c), None
    within = np.isfinite(size) & (size <= tol)
    p = float(within.mean())
    verdict = "pass" if p >= DECIDE else "fail" if 1 - p >= DECIDE else "inconclusive"
    need = _runs_needed(change, tol, n_runs) if verdict == "inconclusive" else None
    return Criterion(**c, tolerance=tol, p_within=p, verdict=verdict, runs_needed=need), within


def _largest(change):
    """Per pair, the signed change at the line where it is largest in size, and that size."""
    a = np.abs(change)
    j = np.nanargmax(np.where(np.isfinite(a), a, -1.0), axis=1)
    signed = change[np.arange(change.shape[0]), j]
    return signed, np.abs(signed)


def compare_characteristics(before: Characteristic, after: Characteristic, acceptance: Acceptance, *,
                            rng: np.random.Generator) -> Comparison:
    """The change from ``before`` to ``after`` and the verdict (module docstring).

    Raises
    ------
    InputError
        The two share fewer than three lines, or different excitations.
    """
    if before.mode != after.mode or not math.isclose(before.level, after.level, rel_tol=1e-9):
        raise InputError(f"before and after at different excitations ({before.mode} {before.level:g}, "
                         f"{after.mode} {after.level:g})")
    ib, ia = _common_lines(before, after)
    if ib.size < 3:
        raise InputError(f"{before.run} and {after.run}: {ib.size} common line(s); at least 3 are needed")
    f = before.freq_hz[ib]
    x0 = before.x0[ib]
    n = min(before.fuu.shape[0], after.fuu.shape[0])
    sb = rng.permutation(before.fuu.shape[0])[:n]
    sa = rng.permutation(after.fuu.shape[0])[:n]
    zb, za = before.fuu[sb][:, ib], after.fuu[sa][:, ia]
    omega = 2 * np.pi * f
    imp_b, imp_a = np.abs(zb) / omega, np.abs(za) / omega
    ph_b, ph_a = np.degrees(np.angle(zb) - np.pi / 2), np.degrees(np.angle(za) - np.pi / 2)  # of Z = f_uu / (i omega)
    pw_b, pw_a = power(f, zb, x0), power(f, za, x0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d_imp = 100 * (imp_a / imp_b - 1)
        d_ph = np.angle(za / zb, deg=True)
        d_pw = 100 * (pw_a / pw_b - 1)
    tol = acceptance.tolerances
    n_runs = min(before.n_runs, after.n_runs)
    lo, hi = f[0], f[-1]
    crit, masks = [], []

    def add(result):
        crit.append(result[0])
        if result[1] is not None:
            masks.append(result[1])

    for i, j in _match(before.resonances, after.resonances):
        k = (j if i is None else i) + 1
        if i is None or j is None:
            who, r = ("after", after.resonances[j]) if i is None else ("before", before.resonances[i])
            clear = r["prominence"] >= CLEAR_PEAK
            note = (f"only {who} has this resonance (at {r['median_hz']:g} Hz, prominence {r['prominence']:.2f} in ln R)"
                    + ("" if clear else ": a weak peak, not judged"))
            for key, what in (("resonance_frequency_pct", "frequency"), ("resonance_power_pct", "power")):
                judged = clear and key in tol
                crit.append(Criterion(key=key, name=f"resonance {k} {what}", unit="%", change=(math.nan,) * 3,
                                      tolerance=tol.get(key) if judged else None, p_within=0.0 if judged else None,
                                      verdict="fail" if judged else "no spec", note=note))
                if judged:
                    masks.append(np.zeros(n, bool))
            continue
        rb, ra = before.resonances[i], after.resonances[j]
        for key, what, q in (("resonance_frequency_pct", "frequency", "freq_hz"), ("resonance_power_pct", "power", "power_w")):
            xb, xa = rb[q][sb], ra[q][sa]
            with np.errstate(invalid="ignore", divide="ignore"):
                ch = 100 * (xa / xb - 1)
            share = float(np.mean(np.isfinite(ch)))
            note = "" if share == 1 else f"{100 * (1 - share):.0f} % of the pairs lack the peak (counted beyond)"
            add(_judge(key, f"resonance {k} {what}", "%", ch, np.abs(ch), tol.get(key), n_runs, xb, xa, note))
    rng_txt = f"{lo:g}-{hi:g} Hz"
    for key, name, ch in (("impedance_pct", f"impedance |Z| (largest over {rng_txt})", d_imp),
                          ("phase_deg", f"impedance phase (largest over {rng_txt})", d_ph),
                          ("power_pct", f"power dissipated (largest over {rng_txt})", d_pw)):
        if key in ("phase_deg", "power_pct") and key not in tol:
            continue  # shown as curves; a criterion only when the file asks for it
        signed, size = _largest(ch)
        add(_judge(key, name, "deg" if key == "phase_deg" else "%", signed, size, tol.get(key), n_runs))
    if acceptance.decides:
        joint = np.logical_and.reduce(masks) if masks else np.zeros(n, bool)
        p_all = float(joint.mean())
        verdicts = [c.verdict for c in crit if c.tolerance is not None]
        verdict = "fail" if "fail" in verdicts else "pass" if p_all >= DECIDE else "inconclusive"
    else:
        p_all, verdict = None, "no spec"
    curves = {}
    for name, b, a in (("impedance", imp_b, imp_a), ("phase", ph_b, ph_a), ("power", pw_b, pw_a)):
        curves[f"before_{name}"] = nan_quantiles(b)
        curves[f"after_{name}"] = nan_quantiles(a)
    curves["impedance_change"], curves["phase_change"], curves["power_change"] = (
        nan_quantiles(d_imp), nan_quantiles(d_ph), nan_quantiles(d_pw))
    notes = [f"before: {before.source} ({before.discrepancy}); after: {after.source} ({after.discrepancy})",
             "the two calibrations are treated as independent: draws paired at random"]
    if before.damper == after.damper:
        notes.append(f"both are {before.damper}, on one bench: a fixture or sensor effect shared by the two tests "
                     "cancels in the change; one that moved between them is read as the damper's change")
    ext = before.extrapolated[ib] | after.extrapolated[ia]
    if ext.any():
        notes.append(f"{int(ext.sum())} line(s) extrapolate a cable law beyond its calibrated curvatures")
    return Comparison(before=before, after=after, acceptance=acceptance, criteria=tuple(crit), verdict=verdict,
                      p_all_within=p_all, freq_hz=f, curves=curves, extrapolated=ext, notes=tuple(notes))


def lab_gap(before_means, after_means, freq_hz, x0, acceptance: Acceptance) -> dict:
    """Today's lab practice, for comparison: the run-mean curves laid over each other.

    Each criterion is read off the run means directly (resonances by the same peak finder on the mean curve,
    the largest point-by-point gap over the lines) and fails when the gap exceeds the tolerance; no
    uncertainty. ``before_means``, ``after_means``: complex (F,) run-mean ``f_uu`` on common lines.

    Returns
    -------
    dict
        ``verdict`` (``pass``/``fail``) and ``gaps`` (key -> largest |change|).
    """
    from .resonance import resonance_draws

    zb, za = np.asarray(before_means)[None], np.asarray(after_means)[None]
    f = np.asarray(freq_hz, float)
    gaps = {}
    rb, ra = resonance_draws(f, zb, x0), resonance_draws(f, za, x0)
    for i, j in _match(tuple(rb), tuple(ra)):
        for key, q in (("resonance_frequency_pct", "freq_hz"), ("resonance_power_pct", "power_w")):
            if i is None or j is None:
                r = ra[j] if i is None else rb[i]
                g = math.inf if r["prominence"] >= CLEAR_PEAK else 0.0
            else:
                g = abs(100 * (ra[j][q][0] / rb[i][q][0] - 1))
            gaps[key] = max(gaps.get(key, 0.0), g if math.isfinite(g) else math.inf)
    gaps["impedance_pct"] = float(np.max(np.abs(100 * (np.abs(za[0]) / np.abs(zb[0]) - 1))))
    gaps["phase_deg"] = float(np.max(np.abs(np.angle(za[0] / zb[0], deg=True))))
    pb, pa = power(f, zb[0], x0), power(f, za[0], x0)
    gaps["power_pct"] = float(np.max(np.abs(100 * (pa / pb - 1))))
    fail = any(gaps.get(k, 0.0) > t for k, t in acceptance.tolerances.items())
    return {"verdict": "fail" if fail else "pass", "gaps": gaps}
