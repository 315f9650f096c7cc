"""Missing physics: locate where the model and the recordings differ, name the physics left out,
model it and show the fit improve (``docs/diagnose.md``).

1. **Baseline**: the per-test model (``theta1``: EJ, beta, a1, a2) with the noise-only likelihood (no
   model-error scales: the model must explain the runs within the bench's scatter), sampled per test.
2. **Locate**: the residual of each test's run mean, line by line, standardised by the likelihood's
   t of the run mean and the posterior spread of the model, ``z``. A line is *off* when ``|z|``
   exceeds the t quantile that keeps the family-wise false-alarm rate over all lines at ``alpha``
   (Bonferroni); neighbouring off lines form a band. The **global check** adds up the residual as a
   whole (the normal scores of every ``z``, squared, against chi-square with the lines' degrees of
   freedom less the fitted parameters): an effect spread thinly over every line, none of them beyond
   the per-line alarm, still shows there. Structure statistics point at candidate physics.
3. **Name**: each screened catalogue extension is refitted (``strand_slip``: the cable law of
   :mod:`sbcal.inference.cable_fit`, every fitted family, jointly over the amplitudes of each cable state; the
   best family by PSIS-LOO) and compared with the baseline by PSIS-LOO grouped by run.
4. **Verdict**: ``none`` when neither the lines nor the global check find a misfit; else the best
   extension when it beats the baseline clearly (``delta_elpd > clear_se * se``) *and* removes at least
   ``min_explained`` of the misfit over chance where it is (:func:`_misfit`: the bands' squared z beyond
   chance, an isolated off line only beyond its threshold; and, when the global check fails, the excess
   of all the other lines); else ``unexplained``.
5. **Secondary**: on the verdict's model the misfit is located again; where some remains, the
   measurement-chain effects that compose with it (:data:`sbcal.inference.cable_fit.SECONDARY`,
   :data:`sbcal.model.extensions.CHAIN`) are screened and refitted on top, and the same rule names a
   ``secondary`` effect (else null).
6. **What is left**: the verdict's model (with its secondary effect) is judged by the rule of step 2:
   ``complete`` when no line is off and the global check passes, else ``partial``, with the remainder
   located and described (:mod:`sbcal.diagnosis.remainder`) and the model's discrepancy per amplitude
   (:func:`sbcal.inference.checks.discrepancy`; zero when complete), which widens the fitted curves'
   bands. ``unexplained`` has no qualifier: its remainder is the baseline's misfit.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from ..core.errors import InputError
from ..core.workers import one_blas_thread, run_jobs
from ..data.bench import rows_digest
from ..inference.cable_fit import SECONDARY, CableFit, store_cable
from ..inference.checks import discrepancy, materiality, predictive_check, qualifier
from ..inference.runs import versions
from ..inference.stats import elpd_difference
from ..inference.store import cable_dir
from ..model.damper import Damper
from ..model.extensions import CHAIN, EXTENSIONS
from .fits import (DiagnoseConfig, choose_law, fit_jobs, late_laws, model_name, posterior_record, run_fits, screen_cable_jobs,
                   zoned_law)
from .remainder import remainder
from .locate import (band_excess, band_rms, off_bands, rocking_signature, screen_effects, signatures,
                     structure_statistics)
from .words import effect_parameters


__all__ = ["DiagnoseConfig", "diagnose", "curves_frame"]

# --- what one diagnosis shares ----------------------------------------------------------------------

@dataclass(frozen=True)
class _Case:
    """One damper's diagnosis: its tests, their baseline likelihoods (the run means every check
    standardises), the settings, and how fits are made (:func:`sbcal.diagnosis.fits.fit_jobs`)."""

    damper: Damper
    data: object
    tests: tuple
    likes: tuple
    config: DiagnoseConfig
    seed: int
    prior_path: object
    progress: bool

    @property
    def n_runs(self) -> dict:
        return {t: lk.y.shape[1] for t, lk in zip(self.tests, self.likes)}

    def fit(self, models, stage: str, starts=None) -> dict:
        """Fit ``models`` (``(primary, secondary effects)`` pairs) in one batch of jobs; ``{key: fit}``
        (``starts``: a cable fit's start per cable state, as :func:`sbcal.diagnosis.fits.fit_jobs` takes)."""
        jobs = []
        for primary, secondary in models:
            jobs += fit_jobs(primary, secondary, damper=self.damper, data=self.data, tests=self.tests,
                             seed=self.seed, config=self.config, prior_path=self.prior_path, starts=starts)
        jobs = screen_cable_jobs(jobs, self.config, self.label(f"{stage}: each cable family's start"))
        return run_fits(jobs, self.config, self.label(stage))

    def label(self, stage: str) -> str | None:
        return f"diagnose {self.damper.name}: {stage}" if self.progress else None


# --- models' checks and summaries ------------------------------------------------------------------

def _model_curves(fits, keys):
    """Per test: posterior mean, variance and median of the model curves ``(2, n_freq)``."""
    mean, var, med = {}, {}, {}
    for key in keys:
        fit = fits[key]
        for t, m, v, d in zip(fit["tests"], fit["mu_mean"], fit["mu_var"], fit["mu_median"]):
            mean[t], var[t], med[t] = m, v, d
    return mean, var, med


def _check_model(fits, keys, case: _Case):
    """A fitted model's predictive check and PSIS-LOO: ``(z, thresholds, coverage, elpd_i, global, check)``
    (``check``: the :class:`sbcal.inference.checks.Check` the first, second, third and fifth come from)."""
    mean, var, _ = _model_curves(fits, keys)
    tests, n_runs = case.tests, case.n_runs
    n_params = sum(fits[k]["n_params"] for k in keys)
    c = predictive_check(case.likes, [mean[t] for t in tests], [var[t] for t in tests], case.config.alpha, n_params)
    parts = {}
    for key in keys:  # a fit's pointwise ELPD, runs of its tests in order
        ts = fits[key]["tests"]
        e = fits[key]["loo"].pointwise
        parts.update(zip(ts, np.split(e, np.cumsum([n_runs[t] for t in ts])[:-1])))
    return c.z, c.thresholds, c.coverage_90, np.concatenate([parts[t] for t in tests]), c.global_, c


def _summary(name, fits, *, keys, check, bands, tests, ref_i=None) -> dict:
    """Numbers of one model from its :func:`_check_model`: ELPD, misfit, coverage, convergence; with the
    reference model's pointwise ELPD ``ref_i``, the difference to it."""
    z, thr, coverage, elpd_i, glob, _ = check
    out = {"effect": name, "elpd": float(elpd_i.sum()),
           "elpd_se": float(np.sqrt(elpd_i.size * np.var(elpd_i))),
           "coverage_90": coverage,
           "lines_off": int(sum(np.sum(np.abs(zt) > th) for zt, th in zip(z, thr))),
           "n_lines": int(sum(zt.size for zt in z)),
           "rms_z": float(np.sqrt(np.mean(np.concatenate([zt.ravel() for zt in z]) ** 2))),
           "band_rms_z": band_rms(bands, tests, z),
           "global": glob,
           "converged": all(fits[k]["converged"] for k in keys),
           "r_hat_max": max(fits[k]["convergence"]["r_hat_max"] for k in keys),
           "ess_bulk_min": min(fits[k]["convergence"]["ess_bulk_min"] for k in keys),
           "tau_max": max(fits[k]["convergence"]["tau_max"] for k in keys),
           "steps_max": max(fits[k]["convergence"]["n_steps"] for k in keys),
           "not_converged": {" ".join(k[:2]): fits[k]["convergence"]["reason"] for k in keys if not fits[k]["converged"]}}
    if ref_i is not None:
        out["delta_elpd"], out["se"] = elpd_difference(ref_i, elpd_i)
    return out


def _misfit(bands, tests, check, *, global_part: bool) -> float:
    """The misfit an extension must remove, as its excess over chance where the misfit is.

    ``check`` is a model's :func:`_check_model`; ``bands`` and ``global_part`` say where the misfit is (the
    reference model's bands, and whether its global check failed), so that two models are measured on the
    same lines. The bands' squared z beyond chance (:func:`sbcal.diagnosis.locate.band_excess`: an isolated
    off line only by how far it passes what chance gives for the largest of all lines); with ``global_part``,
    added, the excess over chance of the lines outside the bands: their squared normal scores (what the
    global check sums) less their share of its degrees of freedom, floored at 0. Without bands and with the
    global part it is the global excess ``chi2 - dof``.
    """
    z, thr, _, _, glob, c = check
    total, inside = band_excess(bands, tests, z, thr)
    if global_part:
        u2 = np.concatenate([np.ravel(s) ** 2 for s in c.scores])
        out = ~np.concatenate([m.ravel() for m in inside])
        total += max(float(np.sum(u2[out])) - glob["dof"] * out.sum() / u2.size, 0.0)
    return total


def _explained(bands, tests, *, ref_check, new_check, global_alpha: float) -> float:
    """The share of the reference model's misfit (:func:`_misfit`) a new model removes; the global part
    counts when the reference model fails the global check (p < ``global_alpha``)."""
    where = ref_check[4]["p_value"] < global_alpha
    before = _misfit(bands, tests, ref_check, global_part=where)
    if before <= 0:
        return 0.0
    return float(1 - _misfit(bands, tests, new_check, global_part=where) / before)


# --- the diagnosis -------------------------------------------------------------------------------

def _compare(candidates, spec_of, fits_all, *, ref_check, bands, case: _Case):
    """Check and rank candidate models against a reference model's check; ``(ranking, summaries, checks, kept)``."""
    tests = case.tests
    ranking, summaries, checks, kept, laws = [], {}, {}, {}, {}
    for e in candidates:
        name = spec_of(e)
        keys_fits, comparison = choose_law(fits_all, name)
        kept[e] = keys_fits
        keys = sorted(keys_fits)
        checks[e] = _check_model(keys_fits, keys, case)
        s = _summary(name, keys_fits, keys=keys, check=checks[e], bands=bands, tests=tests, ref_i=ref_check[3])
        s["explained"] = _explained(bands, tests, ref_check=ref_check, new_check=checks[e],
                                    global_alpha=case.config.global_alpha)
        if comparison is not None:
            s["law"] = comparison
            laws[e] = comparison
        summaries[e] = s
        ranking.append({"effect": e, "delta_elpd": s["delta_elpd"], "se": s["se"], "explained": s["explained"],
                        "converged": s["converged"], "r_hat_max": s["r_hat_max"], "ess_bulk_min": s["ess_bulk_min"]})
    ranking.sort(key=lambda r: -r["delta_elpd"])
    return ranking, summaries, checks, kept, laws


def _decide(misfit: bool, ranking, config) -> str | None:
    """The verdict: the best converged extension by ELPD when it passes the rule; a model whose
    posterior did not converge cannot be the verdict (it stays in the ranking, flagged)."""
    if not misfit:
        return None
    best = next((r for r in ranking if r["converged"]), None)
    if best and best["delta_elpd"] > config.clear_se * best["se"] and best["explained"] >= config.min_explained:
        return best["effect"]
    return "unexplained"


def _composable(primary: str) -> tuple:
    """The effects that can ride on top of ``primary``."""
    if primary == "strand_slip":
        return tuple(SECONDARY)
    if primary in ("baseline",) + CHAIN:
        return tuple(e for e in CHAIN if e != primary)
    if primary == "base_rocking":
        return CHAIN
    return ()


def diagnose(damper: Damper, data, tests=None, *, seed: int = 0, config: DiagnoseConfig = DiagnoseConfig(),
             progress: bool = True, effects=None, prior_path=None, store=None) -> dict:
    """Locate, name, model and show the physics a damper's recordings have and the model lacks.

    Parameters
    ----------
    damper : Damper
    data : CleanBench
        The recordings with their stored cleaning (:class:`sbcal.data.clean_bench.CleanBench`): every fit
        is of the tests' kept runs.
    tests : sequence of str, optional
        Test labels (default: all of the damper's tests).
    seed : int
        Seeds every fit, each through a stream keyed by what it is (:func:`sbcal.core.seeds.job_seed`): the
        same seed, the same numbers; a cable fit's are ``sbcal cable``'s.
    config : DiagnoseConfig
    progress : bool
        Progress bars on stderr (when it is a terminal).
    effects : sequence of str, optional
        Restrict the catalogue (default: all of :data:`sbcal.model.extensions.EXTENSIONS`).
    prior_path : path-like, optional
        The prior file of the base parameters (``--priors``; default the bundled ``priors/default.toml``).
    store : path-like, optional
        A run store: a strand-slip verdict's cable-law posteriors are written to
        ``<store>/<damper>/cable-<state>/`` (the fit ``sbcal cable`` makes).

    Returns
    -------
    dict
        JSON-ready: ``verdict``, ``qualifier`` (``complete``/``partial``; null for ``unexplained``),
        ``remainder`` (what the verdict's model leaves, with its sentence ``words``), ``discrepancy``
        (per amplitude; null without a model), ``ranking``, ``bands``, ``parameters``, ``before``, ``after``,
        ``secondary``, ``law``, ``global``, ``statistics``, ``screen``, ``per_test``, ``rule``,
        ``settings`` (see ``docs/diagnose.md``); and ``curves`` (for :func:`curves_frame`).
    """
    t0 = time.perf_counter()
    available = data.tests(damper.name)
    tests = list(available if tests is None else tests)
    for t in tests:
        if t not in available:
            raise InputError(f"{data.source}: damper {damper.name!r} has no test {t!r} (has: {', '.join(available)})")
    if not tests:
        raise InputError(f"{data.source}: no tests for damper {damper.name!r}")
    catalogue = list(EXTENSIONS if effects is None else effects)
    for e in catalogue:
        if e not in EXTENSIONS:
            raise InputError(f"unknown effect {e!r}; known: {', '.join(EXTENSIONS)}")
    # 1-2. baseline and locate
    jobs = fit_jobs("baseline", (), damper=damper, data=data, tests=tests, seed=seed, config=config,
                    prior_path=prior_path)
    case = _Case(damper, data, tuple(tests), tuple(j.target for j in jobs), config, seed, prior_path, progress)
    likes = case.likes
    fits = run_fits(jobs, config, case.label("per-test fits"))
    base_fits = {k[1]: v for k, v in fits.items()}
    base_keys = [("baseline", t) for t in tests]
    n_runs = case.n_runs
    base_check = _check_model(fits, base_keys, case)
    z0, thr0, _, base_i, glob0, _ = base_check
    bands = off_bands(tests, likes, z0, thr0)
    misfit = qualifier(base_check[5], config.global_alpha) == "partial"  # the rule that judges what a model leaves
    statistics = structure_statistics(damper, tests, likes, base_fits, z0)
    screen = screen_effects(statistics, config, EXTENSIONS)
    before = _summary("baseline", fits, keys=base_keys, check=base_check, bands=bands, tests=tests)

    # 3. name: refit the screened candidates
    candidates = [e for e in catalogue if screen[e]["kept"]] if misfit else []
    if candidates:
        fits.update(case.fit([(e, ()) for e in candidates], f"{len(candidates)} candidate extension(s)"))
    while "strand_slip" in candidates and (late := late_laws(fits, "strand_slip")):  # screened below an unconverged law
        fits.update(replace(case, config=replace(config, laws=late)).fit([("strand_slip", ())],
                                                                         f"screened law(s) {', '.join(late)} after all"))
    law, starts = zoned_law(fits, "strand_slip", config) if "strand_slip" in candidates else (None, None)
    if law is not None:  # the uniform law leaves a misfit: its law changing along the arm, from the uniform one
        fits.update(replace(case, config=replace(config, laws=(law,))).fit([("strand_slip", ())], f"zoned law {law}",
                                                                           starts=starts))
    ranking, summaries, checks, kept, laws = _compare(candidates, lambda e: e, fits, ref_check=base_check,
                                                      bands=bands, case=case)

    # 4. verdict
    verdict = _decide(misfit, ranking, config) or "none"
    shown = verdict if verdict in EXTENSIONS else (ranking[0]["effect"] if ranking else None)
    after = summaries[shown] if shown else before
    shown_fits = kept.get(shown, {})
    per_test = []
    if shown:
        z_after, _, _, after_i, _, _ = checks[shown]
        start = 0
        for t, zb, za in zip(tests, z0, z_after):
            n = n_runs[t]
            d, se = elpd_difference(base_i[start:start + n], after_i[start:start + n])
            start += n
            per_test.append({"test": t, "delta_elpd": d, "se": se, "rms_z_before": float(np.sqrt(np.mean(zb ** 2))),
                             "rms_z_after": float(np.sqrt(np.mean(za ** 2)))})

    # 4b. the verdict's cable law refitted with the multi-harmonic solve where it is needed; what follows
    # (secondary, what is left, curves, the stored run) reads the refit where it is used
    refits = {}
    if verdict == "strand_slip" and config.harmonics:
        shown_fits, refits = _refit_harmonics(damper, shown_fits, seed=seed, workers=config.workers)
        if any(r["used"] for r in refits.values()):
            checks[verdict] = _check_model(shown_fits, sorted(shown_fits), case)

    # 5. secondary: locate again on the verdict's model, refit what composes with it
    secondary, final = None, None
    if config.secondary and verdict in EXTENSIONS and _composable(verdict):
        secondary, final = _secondary(verdict, shown_fits, checks[verdict], case)

    # 6. what is left: the qualifier, the remainder, the discrepancy downstream bands carry
    rem, disc, curve_sd = _what_is_left(verdict, case, base_check=base_check, base_mean=_model_curves(fits, base_keys)[0],
                                        bands=bands, ranking=ranking,
                                        shown=(checks[verdict], shown_fits) if verdict in EXTENSIONS else None,
                                        final=final, secondary=secondary)

    parameters = (effect_parameters(shown, shown_fits, sorted(shown_fits), base_fits[tests[0]]["names"]) if shown
                  else {})
    cables = _cable_fits(damper, shown_fits)
    curves = _curves(case, fits, base_keys, shown, shown_fits, curve_sd,
                     harmonics=[fit.harmonics for fit in cables.values()])
    if store is not None and verdict == "strand_slip":
        _store_cables(damper, cables, shown_fits, store=store, seed=seed, comparison=laws.get("strand_slip"))

    result = {
        "damper": damper.name, "tests": tests, "seed": seed, "verdict": verdict, "qualifier": rem["qualifier"],
        "remainder": rem, "discrepancy": disc, "harmonic_refit": refits,
        "bench": {"path": str(data.source), "rows_sha256": rows_digest(data, damper.name),
                  "removed_runs": {t: list(data.removed_runs(damper.name, t)) for t in tests}},
        "rule": (f"a misfit when a line of the baseline is off (|z| beyond the t quantile at family-wise alpha = "
                 f"{config.alpha:g} over all lines) or the residual as a whole exceeds chance (chi-square of the lines' "
                 f"normal scores, p < {config.global_alpha:g}); then the best extension if delta_elpd > "
                 f"{config.clear_se:g} se and it removes >= {config.min_explained:.0%} of the misfit over chance where it is "
                 "(per band its squared z less 1 a line, an isolated off line less its threshold squared; and when the "
                 "global check fails, the excess over chance of the lines outside the bands); else unexplained; "
                 "no misfit: none. The same "
                 "rule names a secondary effect on the verdict's model, and judges what the final model leaves: "
                 "no misfit, complete; else partial."),
        "ranking": ranking,
        "bands": [{k: b[k] for k in ("test", "quantity", "f_lo", "f_hi", "max_abs_z")} for b in bands],
        "global": glob0,
        "parameters": parameters,
        "law": laws.get("strand_slip"),
        "before": before,
        "after": after,
        "secondary": secondary,
        "per_test": per_test,
        "residuals": {t: {"freq_hz": lk.freq_hz.tolist(), "z_before": zb.tolist(),
                          "z_after": (checks[shown][0][i] if shown else zb).tolist()}
                      for i, (t, lk, zb) in enumerate(zip(tests, likes, z0))},
        "curves": curves,
        "statistics": statistics,
        "screen": screen,
        "settings": asdict(config),
        "versions": versions(),
        "wall_s": time.perf_counter() - t0,
    }
    return result


def _secondary(primary, primary_fits, primary_check, case: _Case) -> tuple[dict, tuple | None]:
    """The second effect on top of the verdict's model (module docstring, step 5): its JSON, and the model
    with it when one is named (``(effect, check, fits)``), else None."""
    tests, likes, config = case.tests, case.likes, case.config
    z1, thr1, _, _, glob1, _ = primary_check
    bands1 = off_bands(tests, likes, z1, thr1)
    misfit = qualifier(primary_check[5], config.global_alpha) == "partial"
    joint = primary == "strand_slip"
    mean, var, _ = _model_curves(primary_fits, sorted(primary_fits))
    sig = signatures(tests, likes, [mean[t] for t in tests], [var[t] for t in tests], z1)
    options = _composable(primary)
    screen = screen_effects(sig, config, options)
    if joint and "base_rocking" in options:
        # no shape of its own to test the residuals for: the share its linearisation explains
        share, value = rocking_signature(primary_fits, tests, likes, mean, var)
        sig["rocking_linear"] = {"share": share, "rocking_rad_per_m": value}
        screen["base_rocking"] = {"kept": share >= config.screen_share,
                                  "why": f"share of the misfit explained by the linearised rocking {share:.2f}"}
    candidates = [e for e in options if screen[e]["kept"]] if misfit else []
    out = {"effect": None, "misfit": misfit, "bands": len(bands1), "global": glob1, "screen": screen,
           "statistics": sig, "ranking": []}
    if not candidates:
        return out, None
    if joint:  # on top of the verdict's cable law only
        case = replace(case, config=replace(config, laws=(next(iter(primary_fits.values()))["law"],)))
    fits = case.fit([(primary, (e,)) for e in candidates], f"secondary: {len(candidates)} candidate(s)")
    fits.update(primary_fits)
    ranking, summaries, checks, kept, _ = _compare(candidates, lambda e: model_name(primary, (e,)), fits,
                                                   ref_check=primary_check, bands=bands1, case=case)
    choice = _decide(True, ranking, config)
    out["ranking"] = ranking
    best = ranking[0]["effect"]
    out["after"] = summaries[best]
    out["before"] = _summary(primary, primary_fits, keys=sorted(primary_fits), check=primary_check, bands=bands1,
                             tests=tests)
    if choice in options:
        out["effect"] = choice
        base_names = tuple(n for n in next(iter(primary_fits.values()))["names"])
        out["parameters"] = effect_parameters(choice, kept[choice], sorted(kept[choice]), base_names, each_test=True)
        out["residuals"] = {t: {"z_before": zb.tolist(), "z_after": za.tolist()}
                            for t, zb, za in zip(tests, z1, checks[choice][0])}
        return out, (choice, checks[choice], kept[choice])
    return out, None


def _what_is_left(verdict, case: _Case, *, base_check, base_mean, bands, ranking, shown, final, secondary):
    """The verdict's qualifier and remainder (:func:`sbcal.diagnosis.remainder.remainder`), its model's
    discrepancy (:func:`sbcal.inference.checks.discrepancy`), and per test the sd of the model curves with
    the discrepancy (``{test: (2, n_freq)}``, for the fitted curves' bands; None without a model)."""
    tests, likes = case.tests, case.likes
    if verdict == "unexplained":
        rem = remainder(None, base_check[5], base_check[5], tests=tests, likes=likes, model_mean=base_mean, bands=bands,
                        tried=ranking, config=case.config)
        return rem, None, None
    if verdict == "none":
        rem = remainder("the per-test model", base_check[5], base_check[5], tests=tests, likes=likes, model_mean={},
                        bands=[], tried=[], config=case.config)
        return rem, None, None
    name, check, fits, added = verdict, shown[0], shown[1], None
    if final is not None:
        added, check, fits = final
        name = model_name(verdict, (added,))
    mean, var, _ = _model_curves(fits, sorted(fits))
    c = check[5]
    rem = remainder(name, c, base_check[5], tests=tests, likes=likes, model_mean=mean,
                    bands=off_bands(tests, likes, c.z, c.thresholds), tried=(secondary or {}).get("ranking", []),
                    config=case.config, explained_by=added, screen=(secondary or {}).get("screen"))
    disc = discrepancy(likes, [mean[t] for t in tests], [var[t] for t in tests], partial=rem["qualifier"] == "partial")
    if rem["qualifier"] == "partial":  # is it material? (docs/diagnose.md, "Complete within")
        rem = dict(rem, materiality=materiality(disc, likes))
    level = dict(zip(disc["amplitude_mm_pp"], zip(disc["logmag_sd"], np.radians(disc["phase_sd_deg"]))))
    sd = {}
    for t, lk in zip(tests, likes):  # the discrepancy at each line's amplitude (zero where it has none)
        d = np.array([level.get(a, (0.0, 0.0)) for a in lk.amplitude_mm_pp]).T  # (2, n_freq)
        sd[t] = np.sqrt(var[t] + d ** 2)
    return rem, disc, sd


def _curves(case: _Case, fits, base_keys, shown, shown_fits, sd=None, harmonics=()) -> dict:
    """Posterior-median model curves per test of the baseline and the shown model (log-magnitude, phase);
    with ``sd`` (per test, ``(2, n_freq)``) the shown model's curves also carry it (``logmag_sd``,
    ``phase_sd``: the posterior spread with the discrepancy, for the curves' bands); with ``harmonics`` (the
    shown cable law's per cable state, :func:`sbcal.inference.distortion.predicted_distortion`) they carry
    per line the predicted force ``distortion``, ``harmonics_gap`` and ``harmonics_converged``."""
    tests, likes = case.tests, case.likes
    out = {}
    _, _, base = _model_curves(fits, base_keys)
    models = {"baseline": base}
    if shown:
        _, _, med = _model_curves(shown_fits, sorted(shown_fits))
        models[shown] = med
    for name, med in models.items():
        out[name] = {t: {"freq_hz": lk.freq_hz.tolist(), "amplitude_mm_pp": lk.amplitude_mm_pp.tolist(),
                         "logmag": med[t][0].tolist(), "phase": med[t][1].tolist()} for t, lk in zip(tests, likes)}
    if shown and sd:
        for t in tests:
            out[shown][t].update(logmag_sd=sd[t][0].tolist(), phase_sd=sd[t][1].tolist())
    for h in harmonics:
        for t in h["distortion"]:
            out[shown][t].update(distortion=h["distortion"][t], harmonics_gap=h["gap"][t],
                                 harmonics_converged=h["converged"][t])
            if "measured" in h:  # the recordings' own distortion and the harmonic switch (sbcal import's files)
                out[shown][t].update(distortion_measured=h["measured"][t], harmonics_switch=h["switch"][t])
    out["data"] = {t: {"logmag": lk.ybar[0].tolist(), "phase": lk.ybar[1].tolist()} for t, lk in zip(tests, likes)}
    return out


def curves_frame(doc: dict):
    """The fitted curves of a diagnosis (baseline and verdict model, posterior median per line) in the
    bench CSV columns (``run`` 0) plus ``model``, ``distortion`` (the cable law's predicted force distortion
    [1], NaN where it was not computed or did not converge) and ``distortion_measured`` (the recordings' own,
    median over the runs; NaN where the bench file has none): a DataFrame for ``sbcal diagnose --curves``."""
    import pandas as pd

    from ..data.bench import curves_to_frame

    frames = []
    for model, per_test in doc["curves"].items():
        if model == "data":
            continue
        for t, c in per_test.items():
            fuu = np.exp(np.asarray(c["logmag"]) + 1j * np.asarray(c["phase"]))
            frame = curves_to_frame(doc["damper"], t, c["freq_hz"], np.asarray(c["amplitude_mm_pp"]), fuu[None, :],
                                    runs=[0])
            frame["model"] = model
            frame["distortion"] = np.array(c.get("distortion", [None] * len(c["freq_hz"])), dtype=float)
            frame["distortion_measured"] = np.array(c.get("distortion_measured", [None] * len(c["freq_hz"])),
                                                    dtype=float)
            frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _cable_fits(damper, fits) -> dict:
    """The cable-law fits among a model's ``fits`` (those that carry a ``law``) as :class:`CableFit`, by key."""
    out = {}
    for key, f in sorted(fits.items()):
        if "law" not in f:
            continue
        out[key] = CableFit(damper=damper.name, state=key[1], law=f["law"], tests=f["tests"], effects=(),
                            result=f["result"], like=f["like"], loo=f["loo"], refit=f.get("refit"),
                            distortion=f.get("harmonics"))  # made by the harmonic refit's job where it ran
    return out


def _plan_job(fit):
    """One cable state's harmonic refit up to its posterior (a module-level function of one job, for
    :func:`run_jobs`): ``(plan, the plain fit's predicted distortion)``, ``plan`` as
    :func:`sbcal.inference.harmonic_refit.plan_refit` returns it."""
    from ..inference.harmonic_refit import plan_refit

    with one_blas_thread():
        return plan_refit(fit), fit.harmonics


def _sample_job(job):
    """One planned refit's posterior: ``(refit or the plain fit, with its record; the predicted distortion of the
    one that stands)`` (the plain fit carries its own: solved only for a used refit)."""
    from ..inference.harmonic_refit import sample_refit

    fit, plan, seed, workers = job
    with one_blas_thread():
        out = sample_refit(fit, plan, seed=seed, workers=workers)
        return out, out.harmonics


def _refit_harmonics(damper, fits, *, seed, workers) -> tuple[dict, dict]:
    """The strand-slip verdict's cable fits refitted with the multi-harmonic solve where it is needed
    (:func:`sbcal.inference.harmonic_refit.refit_harmonics`): ``(fits, records)``, each used refit in place of
    its fit (its draws, likelihood, PSIS-LOO and posterior curves), ``records`` by cable state.

    The cable states' screens and fixed points run side by side, ``workers`` at a time (one core's work each:
    polishes, rounds of the multi-harmonic solve); then the refits past their screens are sampled side by side,
    the ``workers`` shared among them (the draws do not depend on the processes)."""
    from ..inference.harmonic_refit import RefitPlan

    cables = _cable_fits(damper, fits)
    planned = dict(zip(cables, run_jobs(_plan_job, list(cables.values()), workers=workers)))
    to_sample = [key for key, (plan, _) in planned.items() if isinstance(plan, RefitPlan)]
    share = max(1, workers // max(1, len(to_sample)))
    jobs = [(replace(cables[k], distortion=planned[k][1]), planned[k][0], seed, share) for k in to_sample]
    sampled = dict(zip(to_sample, run_jobs(_sample_job, jobs, workers=workers)))
    out, records = dict(fits), {}
    for key, fit in cables.items():
        refit, harmonics = sampled.get(key, planned[key])
        out[key] = dict(fits[key], harmonics=harmonics)
        if refit is None:
            continue
        records[fit.state] = refit.refit
        if refit.refit["used"]:
            out[key] = dict(out[key], **posterior_record(refit.like, fit.tests, refit.result))
        out[key] = dict(out[key], refit=refit.refit)
    return out, records


def _store_cables(damper, cables, fits, *, store, seed, comparison) -> None:
    """Write the verdict's cable-law posteriors (``cables``: :func:`_cable_fits` of ``fits``, whose predicted
    distortion the diagnosis's curves made) as ``<store>/<damper>/cable-<state>/``."""
    for key, fit in cables.items():
        f = fits[key]
        store_cable(fit, cable_dir(store, damper.name, fit.state),
                    meta={"seed": seed, "made_by": "sbcal diagnose", "damper_values": asdict(damper)},
                    comparison=comparison, curves=(f["mu_mean"], f["mu_var"]))  # its posterior curves, made once
