"""Which cable law family the data choose: PSIS-LOO summed over the cable states, among converged posteriors.

A comparison rests on converged posteriors only; a converged winner that a family which did not converge beats
clearly is not *settled*; a zoned family whose zones only patch a mismatched law (a zone length on its bound, or
differing between cable states) cannot win; and the zoned law of the best family is the one fitted next where the
winner leaves a misfit (``docs/cable.md``, "Verdicts rest on converged posteriors only").
"""

from __future__ import annotations

import numpy as np

from ..model.laws import zoned
from ..model.laws.zones import ZONE_PARAMETERS, ZONED_SUFFIX
from .stats import CLEAR_SE, elpd_difference


__all__ = ["compare_families", "zone_patch", "zoned_candidate", "ZONE_BOUND_SHARE"]

ZONE_BOUND_SHARE = 0.05
"""A zone's length whose posterior median lies within this share of its prior box's width from an end is on its
bound (:func:`zone_patch`)."""


def _worst_state(by_state: dict) -> dict:
    """A family's convergence over its cable states, the worst of each: ``r_hat_max``, ``ess_min`` (bulk or
    tail), ``tau_max`` [steps], and the reason of the first state that did not converge (None where no result
    says: a stand-in's)."""
    res = [f.result for _, f in sorted(by_state.items())]
    if not all(hasattr(r, "r_hat_max") for r in res):
        return {"r_hat_max": None, "ess_min": None, "tau_max": None, "reason": None}
    return {"r_hat_max": float(max(r.r_hat_max for r in res)),
            "ess_min": float(min(min(r.ess_bulk_min, r.ess_tail_min) for r in res)),
            "tau_max": float(max(max(r.tau.values()) for r in res)),
            "reason": next((r.reason for r in res if not r.converged), None)}


def compare_families(fits: dict, screened: dict | None = None) -> dict:
    """The best family by PSIS-LOO summed over cable states, among those whose posterior converged in
    every state, and each family's difference to it.

    A family whose posterior did not converge cannot win (its ELPD rests on draws that do not
    represent its posterior); it is listed, flagged, and named in ``higher_not_converged`` when its
    ELPD is above the winner's. When no family converged, the highest ELPD is ``best`` with
    ``converged`` False (a caller must not present it as a result).

    A converged winner is not *settled* when a family that did not converge scores clearly above it
    (``delta_elpd > CLEAR_SE * se_delta``, the diagnosis's rule, :data:`sbcal.inference.stats.CLEAR_SE`):
    the data reject the winner's law for one the sampler could not finish, so its draws are not a result
    either (on a time-domain recording of an ``iwan5`` cable, a converged ``iwan_tail`` 652 +- 52 nats below
    the unconverged ``iwan5`` missed the truth by 19.6 % at 2 mm: docs/cable.md). Such families are named in
    ``outscored_by``; ``settled`` is ``converged`` and none.

    A converged zoned family whose zones only patch a mismatched law (:func:`zone_patch`) cannot win either: its
    reason is the family's ``patch``, and it is named in ``patched`` when its ELPD is above the winner's (the
    winner's misfit then stands, and its qualifier says so).

    ``fits``: ``{law: {state: CableFit}}`` (the same states and runs for every law); ``screened``: the
    families not sampled (:func:`sbcal.inference.cable_start.screen_families`), kept in the result. Returns
    ``{"best": law, "converged": bool, "settled": bool, "higher_not_converged": [law], "outscored_by": [law],
    "patched": [law], "families": {law: {"elpd", "se", "delta_elpd", "se_delta", "converged", "r_hat_max", "ess_min",
    "tau_max", "reason", "patch"}}, "screened": {law: {"log_lik_gap", "threshold", "below"}}}`` (the convergence numbers the worst over
    the family's cable states).
    """
    pointwise = {law: np.concatenate([fits[law][s].loo.pointwise for s in sorted(fits[law])]) for law in fits}
    elpd = {law: float(p.sum()) for law, p in pointwise.items()}
    converged = {law: all(bool(f.result.converged) for f in fits[law].values()) for law in fits}
    patch = {law: zone_patch(fits[law]) if converged[law] else None for law in fits}
    pool = [law for law in elpd if converged[law] and not patch[law]] or list(elpd)
    best = max(pool, key=elpd.get)
    out = {}
    for law, p in pointwise.items():
        d, se = elpd_difference(pointwise[best], p)
        out[law] = {"elpd": elpd[law], "se": float(np.sqrt(p.size * np.var(p))), "delta_elpd": d, "se_delta": se,
                    "converged": converged[law], **_worst_state(fits[law]), "patch": patch[law]}
    higher = sorted((law for law in elpd if not converged[law] and elpd[law] > elpd[best]), key=lambda k: -elpd[k])
    outscored = [law for law in higher if out[law]["delta_elpd"] > CLEAR_SE * out[law]["se_delta"]]
    return {"best": best, "converged": converged[best], "settled": converged[best] and not outscored,
            "higher_not_converged": higher, "outscored_by": outscored,
            "patched": sorted(law for law in patch if patch[law] and elpd[law] > elpd[best]), "families": out,
            "screened": dict(screened or {})}


def zone_patch(by_state: dict) -> str | None:
    """Why a zoned family's fit reads as zones patching a mismatched law rather than a law that changes along
    the arm, or None (a uniform family, a stand-in without draws, or zones that hold).

    Swaged ends are geometry: their zones have a length the data place inside the prior's box, the same in every
    cable state (oil changes the friction, not where the swage presses). A fit that spends its zones on another
    mismatch (a law no family contains) pushes a zone's length to its box's end, or lets it differ between the
    states: on the bundled dry cables, whose strands slip by one law along the whole arm, the converged
    ``iwan5_zoned`` fits put damper1's clamp zone at 0.40 (the box's upper end) and damper2's at 0.05 (its
    lower end), 700 and 263 nats above ``iwan5`` (``docs/cable.md``, "Stranded ensembles"). Two rules, on each
    zone length (``clamp_zone``, ``mass_zone``): its posterior median within :data:`ZONE_BOUND_SHARE` of its
    box's width from an end, in any state; its 90 % intervals disjoint between two states.

    ``by_state``: ``{state: CableFit}`` of one family. Returns one line naming the zone, the numbers and the rule.
    """
    fits = [f for _, f in sorted(by_state.items()) if f.law.endswith(ZONED_SUFFIX)]
    if not fits or any(getattr(f.result, "draws", None) is None or f.like is None for f in fits):
        return None
    for name in (p.name for p in ZONE_PARAMETERS if p.name.endswith("_zone")):
        spans = []
        for f in fits:
            prior = f.like.prior
            lo, hi = (float(v[prior.names.index(name)]) for v in (prior.lower, prior.upper))
            q05, q50, q95 = np.quantile(np.asarray(f.result.draws[name], float), [0.05, 0.5, 0.95])
            share = ZONE_BOUND_SHARE * (hi - lo)
            if q50 < lo + share or q50 > hi - share:
                return (f"{name} on its bound in the {f.state} state: median {q50:.3f} in its box "
                        f"[{lo:g}, {hi:g}] (within {ZONE_BOUND_SHARE:.0%} of its width from an end)")
            spans.append((f.state, q05, q95))
        for i, (s1, a1, b1) in enumerate(spans):
            for s2, a2, b2 in spans[i + 1:]:
                if b1 < a2 or b2 < a1:
                    return (f"{name} differs between the states: {s1} [{a1:.3f}, {b1:.3f}], {s2} [{a2:.3f}, {b2:.3f}] "
                            "(90 % intervals disjoint)")
    return None


def zoned_candidate(comparison: dict, partial: bool) -> str | None:
    """The zoned family (:mod:`sbcal.model.laws.zones`) to fit after the uniform ones, or None.

    The zoned law of the family with the highest ELPD, converged or not: a misspecified uniform law
    need not converge where its zoned law would (a uniform fit of a cable that is stiffer at its ends
    sits on a ridge of trade-offs that the zones remove), so the screen looks at what fits best, and the
    comparison of converged fits (:func:`compare_families`) judges the result. Fitted where the best
    converged family leaves a misfit (``partial``: the qualifier of :mod:`sbcal.inference.checks` in some
    cable state) or where the winner is not settled (none converged, or one that did not scores clearly
    above it); where a settled uniform law explains the runs within their noise, a law that changes along
    the arm has nothing left to explain.
    """
    families = comparison["families"]
    top = max(families, key=lambda law: families[law]["elpd"])
    if top.endswith(ZONED_SUFFIX) or not (partial or not comparison["settled"]):
        return None
    law = zoned(top)
    return None if law in families else law
