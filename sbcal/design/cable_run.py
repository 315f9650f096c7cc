"""A stored cable-law run as ``predict`` and ``span`` read it, and the posterior draws they take from it
(with the new damper's geometric tolerances drawn beside them)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.labels import parse_label
from ..inference.store import cable_state_of
from ..model.damper import GEOMETRY, Damper


__all__ = ["EXTRAPOLATION_MARGIN", "RANGE_STATUS", "CableRun", "load_cable_run", "is_calibration_damper", "streams",
           "subset", "cable_params", "drawn_tolerances", "unit_draws", "drawn_geometry"]

EXTRAPOLATION_MARGIN = 0.10
"""A state of the cable is outside the calibration when its largest arm curvature exceeds the largest
curvature the calibration's tests reached by more than this fraction, or falls below their least by as
much: a margin for the difference between the posterior median's state, which the calibrated range
is taken from, and the median over draws it is compared with."""

RANGE_STATUS = ("ok", "extrapolated", "below_range")
"""Codes of :meth:`CableRun.range_status`: 0 inside the calibrated curvature range, 1 beyond it, 2
below it (the words of the span's status codes, :data:`sbcal.design.span.STATUS`)."""

_EFFECT_PARAMS = ("delay_s", "fixture_mass_kg", "rocking_rad_per_m")


# --- the stored cable ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CableRun:
    """A stored cable-law posterior, read once.

    Attributes
    ----------
    path : Path
        The run directory (``<runs>/<damper>/cable-<state>``).
    summary : dict
        Its ``summary.json``.
    draws : dict of str -> ndarray, shape (n_draws,)
        Posterior draws by parameter (chains pooled).
    law : str
        The law's family (:data:`sbcal.model.laws.LAWS`).
    calibration : Damper or None
        The calibration damper, from the stored ``damper_values`` (None when not stored).
    curvature_range : tuple of float
        Least and largest curvature amplitude [1/m] the calibration's tests reached (``tests_reached``;
        NaN when not stored): the range the law is calibrated over (:meth:`range_status`).
    """

    path: Path
    summary: dict
    draws: dict
    law: str
    calibration: Damper | None
    curvature_range: tuple

    @property
    def damper(self) -> str:
        return str(self.summary.get("damper", self.path.parent.name))

    @property
    def state(self) -> str:
        return str(self.summary.get("state", cable_state_of(self.path)))

    @property
    def n_draws(self) -> int:
        return int(next(iter(self.draws.values())).size)

    @property
    def harmonic(self) -> bool:
        """Whether the fit is a used harmonic refit's (:mod:`sbcal.inference.harmonic_refit`): its draws were
        fitted with the multi-harmonic solve's correction, so what is predicted from them carries it too."""
        return bool((self.summary.get("harmonic_refit") or {}).get("used"))

    def constant_amplitudes(self) -> list:
        """The amplitudes [mm p-p] of the calibration's constant-amplitude tests (``A-A``), sorted."""
        out = set()
        for t in self.summary.get("tests", []):
            p = parse_label(t)
            if p and p.constant:
                out.add(p.below_mm_pp)
        return sorted(out)

    def range_status(self, curvature_max) -> np.ndarray:
        """Where states of the cable lie against the calibrated curvature range: the one rule of
        ``predict`` and ``span``.

        Parameters
        ----------
        curvature_max : array_like, shape (...)
            Per state (a line, or a damper on a span at one frequency): the median over the posterior
            draws of the largest curvature amplitude along the arms [1/m]; NaN counts as inside.

        Returns
        -------
        ndarray of int8, shape (...)
            Codes of :data:`RANGE_STATUS`: 1 above ``curvature_range[1] * (1 + EXTRAPOLATION_MARGIN)``,
            2 below ``curvature_range[0] / (1 + EXTRAPOLATION_MARGIN)``, else 0; all 0 when the run
            stores no range (:meth:`range_warning`).
        """
        top = np.asarray(curvature_max, float)
        lo, hi = self.curvature_range
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return np.zeros(top.shape, dtype=np.int8)
        above, below = top > hi * (1 + EXTRAPOLATION_MARGIN), top < lo / (1 + EXTRAPOLATION_MARGIN)
        return np.where(above, 1, np.where(below, 2, 0)).astype(np.int8)

    def range_warning(self) -> str:
        """'' when the run stores its calibrated curvature range, else one line saying it does not."""
        if np.all(np.isfinite(self.curvature_range)):
            return ""
        return (f"{self.path}/summary.json: key 'tests_reached': missing, so no calibrated curvature range: "
                "extrapolation not assessed")

    def convergence_warning(self) -> str:
        """'' when the posterior converged and its law is settled, else one line saying which parameters did
        not converge, or which family that did not converge scores clearly above the stored law
        (``comparison.outscored_by``, :func:`sbcal.inference.cable_compare.compare_families`)."""
        from ..inference.sampler import POLICY

        s = self.summary
        if s.get("converged", False):
            comparison = s.get("comparison") or {}
            families = comparison.get("families") or {}
            above = [f"{law} ({families[law]['delta_elpd']:.0f} +- {families[law]['se_delta']:.0f} nats)"
                     if isinstance(families.get(law), dict) and {"delta_elpd", "se_delta"} <= set(families[law])
                     else str(law) for law in comparison.get("outscored_by") or ()]
            if not above:
                return ""
            return (f"{self.path}: the {self.law} law is not settled: {', '.join(above)} scored clearly higher but did "
                    "not converge, so the data reject the stored law: the bands may be misplaced")
        bad = [n for n, p in s.get("parameters", {}).items()
               if not (p.get("r_hat", np.inf) <= POLICY["rhat_max"]
                       and min(p.get("ess_bulk", 0), p.get("ess_tail", 0)) >= POLICY["ess_min"])]
        which = (f"R-hat > {POLICY['rhat_max']} or ESS < {POLICY['ess_min']:.0f} for {', '.join(bad)}" if bad
                 else "every parameter passes R-hat and ESS")
        why = str(s.get("reason") or "no reason stored").split(":")[0].split(";")[0]  # its first clause
        return (f"{self.path}: the cable posterior did not converge ({why}; {which}): the bands may be too "
                "narrow or misplaced")


def load_cable_run(run) -> CableRun:
    """Read a stored cable-law posterior (see :class:`CableRun`); ``run`` a directory or a CableRun.

    Raises
    ------
    InputError
        One line: no such directory, no cable-law run in it, its posterior missing.
    """
    from ..inference.cable_fit import read_cable
    from ..model.laws import law_for

    if isinstance(run, CableRun):
        return run
    path = Path(run)
    if not path.is_dir():
        raise InputError(f"{path}: no such cable run (a directory written by 'sbcal cable', "
                         "e.g. runs/damper1/cable-dry)")
    summary, draws = read_cable(path)
    law = summary["law"]
    try:
        needed = ("EJ_min", "beta_material") + law_for(law).parameter_names
    except (KeyError, ValueError, InputError):
        raise InputError(f"{path}: summary.json: unknown law {law!r}") from None
    missing = [n for n in needed if n not in draws]
    if missing:
        raise InputError(f"{path}: posterior.nc has no draws of {missing[0]!r} (the {law} law needs {', '.join(needed)})")
    values = summary.get("damper_values")
    calibration = None
    if isinstance(values, dict):
        names = {f.name for f in dataclasses.fields(Damper)}
        kw = {k: v for k, v in values.items() if k in names}
        kw["tolerance"] = tuple(tuple(t) for t in kw.get("tolerance", ()))
        try:
            calibration = Damper(**kw)
        except TypeError:
            calibration = None
    reached = summary.get("tests_reached") or {}
    if reached:
        rng = (min(float(r["curvature_min"]) for r in reached.values()),
               max(float(r["curvature_max"]) for r in reached.values()))
    else:
        rng = (float("nan"), float("nan"))
    return CableRun(path=path, summary=summary, draws={k: np.asarray(v, float) for k, v in draws.items()},
                    law=law, calibration=calibration, curvature_range=rng)


def is_calibration_damper(cable: CableRun, damper: Damper) -> bool:
    """Whether ``damper`` is the run's calibration damper: the same name and the same geometry, and the
    run's posterior holds its offsets ``a1``, ``a2`` (a lot's design run holds none: a damper of the design
    takes its offsets from its tolerances, as a new damper does)."""
    c = cable.calibration
    if c is None or c.name != damper.name or not all(n in cable.draws for n in ("a1", "a2")):
        return False
    return all(np.isclose(getattr(c, k), getattr(damper, k), rtol=1e-12, atol=0.0) for k in GEOMETRY)


# --- the draws -------------------------------------------------------------------------------------

def streams(seed):
    """Independent generators: the posterior subset and the geometry draws."""
    choice, geometry = np.random.SeedSequence(seed).spawn(2)
    return np.random.default_rng(choice), np.random.default_rng(geometry)


def subset(cable: CableRun, n_draws: int, rng) -> np.ndarray:
    """Indices of the posterior draws used (all of them, in order, when n_draws >= the stored number)."""
    return subset_indices(cable.n_draws, n_draws, rng)


def subset_indices(n_total: int, n_draws: int, rng) -> np.ndarray:
    """``n_draws`` of ``n_total`` stored draws, sorted, without replacement (all, in order, when there are
    no more than that): the one subset rule of every reader of stored posteriors."""
    if n_draws >= n_total:
        return np.arange(n_total)
    return np.sort(rng.choice(n_total, size=n_draws, replace=False))


def cable_params(cable: CableRun, idx, bench_effects: bool, own_offsets: bool) -> dict:
    """The cable law's posterior draws ``idx`` by parameter (with the offsets and bench effects asked for)."""
    from ..model.laws import law_for

    names = ["EJ_min", "beta_material", *law_for(cable.law).parameter_names]
    if own_offsets:
        names += [n for n in ("a1", "a2") if n in cable.draws]
    if bench_effects:
        names += [n for n in _EFFECT_PARAMS if n in cable.draws]
    return {n: cable.draws[n][idx] for n in names}


def drawn_tolerances(designs, own_offsets: bool) -> dict:
    """The tolerances drawn: the damper's (:meth:`Damper.tolerances`), without fields that are zero in
    every design and, for the calibration damper, without its offsets (the posterior's)."""
    return {k: float(v) for k, v in designs[0].tolerances().items()
            if any(getattr(d, k) != 0.0 for d in designs) and not (own_offsets and k in ("a1", "a2"))}


def unit_draws(tolerance: dict, n: int, rng) -> dict:
    """``U(-1, 1)`` per toleranced field (sorted by name, so a seed fixes every field's draws)."""
    return {k: rng.uniform(-1.0, 1.0, n) for k in sorted(tolerance)}


def drawn_geometry(damper: Damper, tolerance: dict, units: dict) -> dict:
    """Per-draw geometry ``nominal + |nominal| pct/100 u`` of the toleranced fields (zero stays zero)."""
    out = {}
    for k, u in units.items():
        v = getattr(damper, k)
        if v != 0.0:
            out[k] = v + abs(v) * tolerance[k] / 100.0 * u
    return out
