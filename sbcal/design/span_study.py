"""A span study (``sbcal span``): a stored damper (or none) on a conductor, its figure, stored and read back
(``<runs>/span/<label>/``)."""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.plotting import pyplot, save_png
from ..data.labels import parse_label
from ..inference.store import span_dir as store_span_dir
from ..inference.store import owner, span_dirs
from ..model.damper import Damper
from .cable_run import RANGE_STATUS
from .conductor import Conductor
from .life import Life, check_across, parse_climate, plot_life, service_life
from .placement import Placement, optimise_position
from .span import AMPLITUDE_FLOOR_M, SpanResult, checked_positions, energy_balance, jsonable, quantiles_90
from .vibration import wind_check


__all__ = [
    "plot_span", "SpanStudy", "span_study", "span_dir", "store_span", "read_span",
    "stored_spans", "law_range_check",
]

# ---------------------------------------------------------------------------------------------
# Plot


def plot_span(result: SpanResult, path, *, placement: Placement | None = None) -> None:
    """Y_max/D and stress against frequency with and without the dampers, the powers, and (with
    ``placement``) the margin against position; one PNG written atomically."""
    plt = pyplot()
    r, d = result, result.conductor.diameter_m
    f = r.freq_hz
    n = 4 if placement is not None else 3
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.0))
    label = f"{r.n_dampers} damper(s) at {', '.join(f'{x:.2f}' for x in r.positions_m)} m" if r.positions_m else ""

    ax = axes[0]
    ax.plot(f, r.ymax_bare_m / d, "k--", lw=1, label="no damper")
    if r.positions_m:
        lo, mid, hi = quantiles_90(r.ymax_m / d)
        ax.fill_between(f, lo, hi, color="C0", alpha=0.25)
        ax.plot(f, mid, color="C0", label=f"{label} (median, 90 %)")
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="Y_max / D", title="Antinode amplitude")

    ax = axes[1]
    ax.plot(f, r.stress_bare_pa * 1e-6, "k--", lw=1, label="no damper")
    if r.positions_m:
        lo, mid, hi = quantiles_90(r.stress_pa * 1e-6)
        ax.fill_between(f, lo, hi, color="C0", alpha=0.25)
        ax.plot(f, mid, color="C0", label="with dampers (median, 90 %)")
    ax.axhline(r.limit_pa * 1e-6, color="C3", lw=1, label=f"limit {r.limit_pa * 1e-6:.1f} MPa")
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="stress amplitude [MPa]",
           title="Poffenberger-Swart stress at 89 mm")

    ax = axes[2]
    ax.plot(f, r.p_wind_bare_w, "k--", lw=1, label="wind = self-damping, no damper")
    for arr, name, color in ((r.p_wind_w, "wind input", "C0"), (r.p_self_w, "self-damping", "C1"),
                             (r.p_damper_w, "dampers", "C2")):
        if name == "dampers" and not r.positions_m:
            continue
        ax.plot(f, np.median(arr, axis=0), color=color, label=name)
    ax.set(yscale="log", xlabel="frequency [Hz]", ylabel="power over the span [W]", title="Powers at Y_max (median)")

    if placement is not None:
        ax = axes[3]
        q = round(100 * placement.quantile)
        ax.plot(placement.positions_m, placement.margin, "o-", color="C0", ms=3, label=f"{q} % quantile over draws")
        ax.plot(placement.positions_m, placement.margin_median, color="C0", lw=1, alpha=0.5, label="median")
        ax.axhline(1.0, color="C3", lw=1, label="margin 1")
        ax.axvline(placement.best_position_m, color="k", lw=0.8, ls=":")
        ax.set(xlabel="damper position from the clamp [m]", ylabel="worst-case margin over the band",
               title=f"Placement ({placement.ends} end(s))")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path, dpi=110)


# ---------------------------------------------------------------------------------------------
# A study (``sbcal span``): a stored damper on a conductor, stored and read back

_NO_DAMPER = ("none", "")


@dataclass(frozen=True, eq=False)
class SpanStudy:
    """The energy balance of one conductor with one damper design, and where the damper came from.

    Attributes
    ----------
    result : SpanResult
        At the given position (or, with a placement and no position, at the best position).
    placement : Placement or None
        The margin against position (``optimise``).
    damper : str
        The damper's name; ``"none"`` for a bare span.
    cable : str
        The stored cable-law run the damper's impedance comes from ("" for a bare span).
    cable_damper, state, law : str
        That run's calibration damper, cable state and law family.
    seed : int
        Seed of the posterior subset and the geometry draws.
    calibrated_amplitude_mm_pp : tuple of float
        Least and largest clamp amplitude of the cable run's tests [mm p-p] (empty without a damper).
    calibrated_curvature : tuple of float
        Least and largest curvature amplitude [1/m] the calibration's tests reached along the arms:
        the range the cable law is calibrated over (empty without a damper or when the run stores none).
    extrapolated_hz, below_range_hz : tuple of float
        Frequencies at which some damper's state lies beyond, or below, the calibrated curvature range:
        the median over draws of the largest curvature along its arms
        (:meth:`sbcal.design.cable_run.CableRun.range_status`, the rule of ``sbcal predict``).
    life : Life or None
        The service life under a wind climate (:func:`sbcal.design.life.service_life`), when asked.
    model_error : dict or None
        The calibration's model discrepancy the damper's impedance carries
        (:class:`sbcal.design.predict.ModelError` ``as_dict()``), None when off or not stored.
    warnings : tuple of str
        The balance's and the study's (cable posterior not converged, law extrapolated).
    """

    result: SpanResult
    placement: Placement | None = None
    damper: str = "none"
    cable: str = ""
    cable_damper: str = ""
    state: str = ""
    law: str = ""
    seed: int = 0
    calibrated_amplitude_mm_pp: tuple = ()
    calibrated_curvature: tuple = ()
    extrapolated_hz: tuple = ()
    below_range_hz: tuple = ()
    model_error: dict | None = None
    life: Life | None = None
    warnings: tuple = ()

    @property
    def label(self) -> str:
        """``<conductor>-<damper>[-<cable damper>]-<state>[-2ends]``, or ``<conductor>-bare``."""
        parts = [self.result.conductor.name]
        if self.cable:
            parts += [self.damper] + ([self.cable_damper] if self.cable_damper != self.damper else []) + [self.state]
        else:
            parts.append("bare")
        if self.result.ends == 2:
            parts.append("2ends")
        return re.sub(r"[^A-Za-z0-9._-]+", "_", "-".join(parts))

    def worst_stress_mpa(self) -> dict:
        """Largest stress over the band [MPa]: with the dampers (median, 5 %, 95 % over draws) and bare."""
        r = self.result
        worst = r.limit_pa / r.margin * 1e-6  # margin = limit / max stress; an unsolved draw gives inf
        return {"median": jsonable(np.median(worst)), "q05": jsonable(np.quantile(worst, 0.05)),
                "q95": jsonable(np.quantile(worst, 0.95)), "bare": jsonable(r.limit_pa / r.margin_bare * 1e-6)}

    def worst_line(self) -> dict:
        """The line of the band with the largest stress: with the dampers (the largest median over
        draws; the bare span's own worst line for a bare span). ``{frequency_hz, wind_m_s,
        stress_mpa: {median, q05, q95}, stress_bare_mpa}``."""
        r = self.result
        s = np.where(np.isnan(r.stress_pa), np.inf, r.stress_pa)  # an unsolved draw counts as the worst
        med = np.median(s, axis=0)
        i = int(np.argmax(med)) if r.positions_m else int(np.nanargmax(r.stress_bare_pa))
        lo, mid, hi = np.quantile(s[:, i], [0.05, 0.5, 0.95]) * 1e-6
        return {"frequency_hz": float(r.freq_hz[i]), "wind_m_s": float(r.wind_mps[i]),
                "stress_mpa": {"median": jsonable(mid), "q05": jsonable(lo), "q95": jsonable(hi)},
                "stress_bare_mpa": jsonable(r.stress_bare_pa[i] * 1e-6)}

    def to_dict(self) -> dict:
        """JSON-ready: the source of the damper, :meth:`SpanResult.to_dict` and the placement."""
        doc = {"label": self.label, "damper": self.damper, "cable": self.cable, "cable_damper": self.cable_damper,
               "state": self.state, "law": self.law, "seed": self.seed,
               "calibrated_amplitude_mm_pp": list(self.calibrated_amplitude_mm_pp),
               "calibrated_curvature": list(self.calibrated_curvature),
               "extrapolated_hz": list(self.extrapolated_hz), "below_range_hz": list(self.below_range_hz)}
        doc |= self.result.to_dict()
        doc["worst_stress_mpa"] = self.worst_stress_mpa()
        doc["worst_line"] = self.worst_line()
        doc["model_error"] = self.model_error
        doc["placement"] = self.placement.to_dict() if self.placement is not None else None
        doc["life"] = self.life.to_dict() if self.life is not None else None
        doc["warnings"] = list(self.warnings)
        return doc


def _damper_source(damper, cable):
    """(CableRun or None, Damper or None) from the study's ``damper`` and ``cable`` arguments."""
    from ..model.damper import resolve_damper
    from .cable_run import load_cable_run

    bare = damper is None or (isinstance(damper, str) and damper.strip().lower() in _NO_DAMPER)
    if bare:
        if cable is not None:
            raise InputError("damper: a cable run was given without a damper; give the new damper's file with it, "
                             "or the run itself as the damper")
        return None, None
    if not isinstance(damper, Damper) and Path(str(damper)).is_dir():
        if cable is not None:
            raise InputError(f"damper: {damper} is a stored cable run, which brings its own damper; give a damper "
                             "file instead to build a new damper with the cable run")
        run = load_cable_run(damper)
        if run.calibration is None:
            raise InputError(f"{run.path}/summary.json: key 'damper_values': missing, so the run's damper is unknown; "
                             "give the damper's file as the damper and this run as the cable")
        return run, run.calibration
    d = damper if isinstance(damper, Damper) else resolve_damper(damper)
    if cable is None:
        where = d.source or d.name
        raise InputError(f"{where}: damper {d.name!r} has no cable law: give a stored cable fit with it "
                         "(cable=RUN, sbcal span --cable RUN, e.g. runs/damper1/cable-dry)")
    return load_cable_run(cable), d


def _calibrated_amplitudes(run) -> tuple:
    """(least, largest) amplitude [mm p-p] of a cable run's tests, from their labels ``A-B``."""
    labels = (parse_label(t) for t in run.summary.get("tests", []))
    amps = [a for p in labels if p for a in p.amplitudes]
    return (min(amps), max(amps)) if amps else ()


def law_range_check(run, imp, result: SpanResult) -> tuple[dict, list]:
    """Where the dampers' states lie against the cable's calibrated curvature range.

    Per damper position and frequency, the median over draws of the largest curvature along its arms
    at its clamp amplitude X_d (the states the balance used) is judged by
    :meth:`sbcal.design.cable_run.CableRun.range_status`. Returns ``{word: frequencies [Hz] at which
    some damper is so}`` for ``"extrapolated"`` and ``"below_range"``, and one warning for each that occurs.
    """
    xd = result.damper_amplitude_m  # (J, S, F) [m, 0-peak]; NaN where no balance was found
    # a damper at a node is evaluated at the floor amplitude, as the balance evaluates it
    curv = np.array([imp.curvature_max(result.freq_hz, np.maximum(np.nan_to_num(x), AMPLITUDE_FLOOR_M)) for x in xd])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a frequency no draw balanced stays NaN
        top = np.nanmedian(np.where(np.isfinite(xd), curv, np.nan), axis=1)  # (J, F)
    status = run.range_status(top)
    lo, hi = run.curvature_range
    f, n = result.freq_hz, result.freq_hz.size
    out, notes = {}, []
    for code, word in enumerate(RANGE_STATUS[1:], start=1):
        hit = (status == code).any(axis=0)
        out[word] = tuple(float(x) for x in f[hit])
        if not hit.any():
            continue
        where = f"at {hit.sum()} of {n} frequencies ({f[hit].min():.3g}-{f[hit].max():.3g} Hz)"
        if word == "extrapolated":
            notes.append(f"the dampers bend the cable's arms to {np.nanmax(top[:, hit]):.3g} 1/m (median over draws) "
                         f"{where}, beyond the {hi:.3g} 1/m of the cable's calibration: the cable law is "
                         "extrapolated there")
        else:
            notes.append(f"the dampers bend the cable's arms to only {np.nanmin(top[:, hit]):.3g} 1/m (median over "
                         f"draws) {where}, below the {lo:.3g} 1/m of the cable's calibration: the cable law is "
                         "extrapolated to small curvatures there")
    return out, notes


def span_study(conductor, damper=None, *, cable=None, position_m=None, ends: int = 1, wind=(1.0, 7.0),
               n_freq: int = 60, n_draws: int = 200, seed: int = 0, optimise: bool = False, positions_m=None,
               quantile: float = 0.1, wave: str = "travelling", search_draws: int = 40, model_error: bool = True,
               climate=None, across: float = 1.0) -> SpanStudy:
    """One conductor, one damper design from a stored cable fit (or none): the energy balance with
    posterior bands, the bare span beside it, and optionally the placement. Reads the cable run;
    never refits.

    Parameters
    ----------
    conductor : Conductor or str
        A :class:`Conductor`, a bundled name (``drake``, ``aster570``) or a TOML path.
    damper : None, "none", path-like, str or Damper
        None or ``"none"``: the bare span. A stored cable-fit directory (``runs/damper1/cable-dry``):
        that run's calibration damper with its own cable. Otherwise a damper (bundled name, TOML
        path or :class:`sbcal.model.damper.Damper`) built with the cable of ``cable``.
    cable : path-like, optional
        The stored cable-fit directory for a new damper.
    position_m : float or sequence of float, optional
        Damper distance(s) from the suspension clamp [m]; required with a damper unless ``optimise``
        (then the study's result is at the best position).
    ends, wind, n_freq, wave
        As in :func:`energy_balance`.
    n_draws, seed
        Posterior draws and their seed, as in :func:`sbcal.design.impedance.impedance_from_cable`.
    optimise : bool
        Also run :func:`optimise_position` (one damper per equipped end) over ``positions_m``
        (default: its own grid) maximising the ``quantile`` of the worst-case margin.
    search_draws : int
        Draws of the placement's scan (a subset: each position is a full balance; 40 draws estimate
        the 10 % quantile of the margin to a few per cent at a fifth of the cost of 200). The result
        at the chosen position is then computed with all ``n_draws``.
    model_error : bool
        Add the calibration's model discrepancy to the damper's impedance, as ``sbcal predict`` adds it
        to its bands (:mod:`sbcal.design.impedance`); a run that stores none gives a warning.
    climate : Climate or str, optional
        A wind climate (:func:`sbcal.design.life.parse_climate`: ``weibull:k=2.0,c=4.5`` or a CSV
        histogram): the study then holds the service life with and without the dampers.
    across : float
        Share of the time the wind blows across the line (0, 1], for the life.

    Returns
    -------
    SpanStudy

    Raises
    ------
    InputError
        One line: a conductor file missing a field, a position outside the span, a damper with no
        cable law (a directory that is not a cable fit, a damper file without ``cable``), a wind band
        outside the wind laws' range.
    """
    from .conductor import resolve_conductor
    from .impedance import impedance_from_cable

    c = conductor if isinstance(conductor, Conductor) else resolve_conductor(conductor)
    run, dmp = _damper_source(damper, cable)
    wind_check(wind)
    if climate is not None:
        climate, across = parse_climate(climate), check_across(across)
    if run is None:
        if position_m is not None:
            raise InputError("position: a bare span has no damper position; give a damper with it")
        if optimise:
            raise InputError("optimise: the placement needs a damper")
        r = energy_balance(c, None, None, wind=wind, n_freq=n_freq, wave=wave)
        life = service_life(r, climate, across=across) if climate is not None else None
        return SpanStudy(result=r, life=life, warnings=r.warnings)
    if position_m is None and not optimise:
        raise InputError("position: give the damper's distance from the suspension clamp [m] (or optimise it)")
    for xs in (position_m, positions_m):
        if xs is not None:
            try:
                checked_positions(c, xs, ends)
            except InputError as e:
                raise InputError(f"{c.source or c.name}: span_length_m = {c.span_length_m:g} m; {e}") from None
    notes = [w for w in (run.convergence_warning(), run.range_warning()) if w]
    imp = impedance_from_cable(run, dmp, n_draws=n_draws, seed=seed, model_error=model_error)
    if model_error and imp.model_error is None:
        notes.append(f"{run.path}/summary.json: no 'discrepancy' (a cable run stored before sbcal kept it): "
                     "the band holds the cable posterior and the tolerances only, not the model error")
    placement = None
    if optimise:
        scan = imp if search_draws >= n_draws else impedance_from_cable(run, dmp, n_draws=search_draws, seed=seed,
                                                                        model_error=model_error)
        placement = optimise_position(c, scan, positions_m, ends=ends, quantile=quantile, wind=wind, n_freq=n_freq,
                                      wave=wave)
    at = position_m if position_m is not None else placement.best_position_m
    r = energy_balance(c, imp, at, ends=ends, wind=wind, n_freq=n_freq, wave=wave)
    law_range, law_notes = law_range_check(run, imp, r)
    if imp.harmonic:
        unsolved = sum(t.unsolved for t in imp.tables)
        notes.append("the damper's impedance carries the cable run's harmonic refit correction (multi-harmonic solve at "
                     "the draws' median, tabulated over lines and clamp amplitudes)"
                     + (f"; the solve did not converge at {unsolved} table point(s): left first-harmonic" if unsolved else ""))
    curvature = tuple(float(v) for v in run.curvature_range) if np.all(np.isfinite(run.curvature_range)) else ()
    return SpanStudy(result=r, placement=placement, damper=dmp.name, cable=str(run.path), cable_damper=run.damper,
                     state=run.state, law=run.law, seed=int(seed), calibrated_amplitude_mm_pp=_calibrated_amplitudes(run),
                     calibrated_curvature=curvature, extrapolated_hz=law_range["extrapolated"],
                     below_range_hz=law_range["below_range"],
                     model_error=imp.model_error.as_dict() if imp.model_error is not None else None,
                     life=service_life(r, climate, across=across) if climate is not None else None,
                     warnings=tuple(r.warnings) + tuple(notes + law_notes))


def span_dir(study: SpanStudy, runs_dir=None) -> Path:
    """``<runs>/span/<label>``; ``<runs>`` defaults to the store holding the cable run (its
    grandparent: ``runs/damper1/cable-dry`` -> ``runs``), or ``runs`` for a bare span."""
    if runs_dir is None:
        runs_dir = owner(study.cable)[0] if study.cable else Path("runs")
    return store_span_dir(runs_dir, study.label)


def store_span(study: SpanStudy, directory=None, *, meta: dict | None = None, json_path=None) -> Path:
    """Write ``span.csv`` (per frequency, :meth:`SpanResult.to_frame`), ``span.png``
    (:func:`plot_span`), ``placement.csv`` (with a placement), ``life.csv`` and ``life.png`` (with a
    life, :meth:`sbcal.design.life.Life.to_frame`, :func:`sbcal.design.life.plot_life`) and, last, ``summary.json``
    (:meth:`SpanStudy.to_dict` and ``meta``), each atomically, into ``directory`` (default
    :func:`span_dir`); also the JSON at ``json_path``. Returns the directory."""
    from ..core._io import atomic_path, write_json

    d = Path(directory) if directory is not None else span_dir(study)
    with atomic_path(d / "span.csv", ".csv") as tmp:
        study.result.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
    if study.placement is not None:
        with atomic_path(d / "placement.csv", ".csv") as tmp:
            study.placement.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
    plot_span(study.result, d / "span.png", placement=study.placement)
    if study.life is not None:
        with atomic_path(d / "life.csv", ".csv") as tmp:
            study.life.to_frame().to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")
        plot_life(study.life, d / "life.png")
    doc = dict(study.to_dict(), **(meta or {}))
    if json_path is not None:
        write_json(json_path, doc, indent=1, allow_nan=False)
    write_json(d / "summary.json", doc, indent=1, allow_nan=False)
    return d


def read_span(directory) -> dict:
    """The ``summary.json`` of a stored span study (:func:`store_span`), checked for its main keys."""
    from ..core._io import read_summary

    return read_summary(directory, ("label", "conductor", "margin", "margin_bare", "per_frequency"), "span study",
                        "sbcal span")


def stored_spans(runs_dir) -> list:
    """Every span study of a run store: ``[(directory, summary dict)]`` sorted by directory name."""
    return [(d, read_span(d)) for d in span_dirs(runs_dir)]
