"""What the verdict's model still leaves: the qualifier (``complete`` or ``partial``), where the rest of the
misfit is, its shape in a bench engineer's words, its share of the original misfit, and what was tried on
it (``docs/diagnose.md``, "What is left")."""

from __future__ import annotations

import numpy as np

from ..inference.checks import qualifier


__all__ = ["headline", "remainder", "shown_qualifier"]

_PEAK_REACH = 1  # lines: a band this close to a resonance of the model is "near" it


def _peaks(f, y) -> np.ndarray:
    """Interior local maxima of ``y`` over the lines ``f``, each refined by a parabola through its
    neighbours: their frequencies [Hz]."""
    i = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])) + 1
    out = []
    for k in i:
        c = np.polyfit(f[k - 1:k + 2] - f[k], y[k - 1:k + 2], 2)
        out.append(f[k] - c[1] / (2 * c[0]) if c[0] < 0 else f[k])
    return np.asarray(out, float)


def _amplitude(lk) -> str:
    a = lk.amplitude_mm_pp
    a = a[np.isfinite(a)]
    if a.size == 0:
        return ""
    return f"{a[0]:g} mm" if np.allclose(a, a[0]) else f"{a.min():g}-{a.max():g} mm"


def _band(band, lk, model_mean) -> dict:
    """A band of off lines in engineering terms: the mean gap of the run means to the model there (magnitude
    in %, phase in deg), the model's resonance it is near, and how far the recorded peak lies from it."""
    lines = np.asarray(band["lines"])
    r = lk.residual(model_mean[:, None, :])[:, 0]
    f = lk.freq_hz
    out = {k: band[k] for k in ("test", "quantity", "f_lo", "f_hi", "max_abs_z")}
    out["amplitude"] = _amplitude(lk)
    out["magnitude_pct"] = float(np.expm1(np.mean(r[0, lines])) * 100)
    out["phase_deg"] = float(np.degrees(np.mean(r[1, lines])))
    peaks = _peaks(f, model_mean[0])
    out["resonance_hz"] = out["peak_shift_hz"] = None
    if peaks.size:
        step = np.median(np.diff(f)) if f.size > 1 else 1.0
        near = peaks[np.argmin(np.abs(peaks - np.clip(peaks, band["f_lo"], band["f_hi"])))]
        if band["f_lo"] - _PEAK_REACH * step <= near <= band["f_hi"] + _PEAK_REACH * step:
            out["resonance_hz"] = float(near)
            recorded = _peaks(f, lk.ybar[0])
            if recorded.size:
                closest = recorded[np.argmin(np.abs(recorded - near))]
                if abs(closest - near) <= _PEAK_REACH * step:
                    out["peak_shift_hz"] = float(closest - near)
    words = [f"the recordings {abs(out['magnitude_pct']):.1f} % {'stiffer' if out['magnitude_pct'] > 0 else 'softer'}",
             f"phase {'lead' if out['phase_deg'] > 0 else 'lag'} {abs(out['phase_deg']):.1f} deg"]
    if out["peak_shift_hz"] is not None:
        words.append(f"the recorded peak {abs(out['peak_shift_hz']):.2g} Hz {'above' if out['peak_shift_hz'] > 0 else 'below'}")
    where = f"near the model's resonance at {out['resonance_hz']:.3g} Hz" if out["resonance_hz"] else "between resonances"
    out["words"] = (f"{out['test']} ({out['amplitude']}) {out['f_lo']:g}-{out['f_hi']:g} Hz, {band['quantity']}, {where}: "
                    + ", ".join(words))
    return out


def _screened(screen: dict) -> str:
    """The screen's statistic of each effect it kept out, short: a share of the misfit its signature
    explains, else the statistic named."""
    parts = []
    for e, v in screen.items():
        if v["kept"]:
            continue
        head, _, number = v["why"].rpartition(" ")
        parts.append(f"{e} {float(number):.0%}" if head.startswith("share") else f"{e} ({head} {number})")
    return ", ".join(parts)


def _tried(tried, screen) -> str:
    if tried:
        return "tried: " + ", ".join(f"{t['effect']} removes {max(t['explained'], 0.0):.0%}" for t in tried)
    out = "no catalogued effect passed the screen on it"
    shown = _screened(screen or {})
    return f"{out}: the share of it each one's signature explains: {shown}" if shown else out


def remainder(model: str | None, check, base_check, *, tests, likes, model_mean, bands, tried, config,
              explained_by: str | None = None, screen: dict | None = None) -> dict:
    """The qualifier and the description of what ``model`` leaves.

    Parameters
    ----------
    model : str or None
        The verdict's model (``strand_slip``, ``strand_slip+sensor_delay``, ...); None for ``unexplained``
        (the baseline's misfit is then the remainder, and the qualifier null).
    check, base_check : Check
        The predictive check of that model and of the baseline (:func:`sbcal.inference.checks.predictive_check`).
    tests, likes : sequence
        The diagnosis's tests and their noise-only likelihoods.
    model_mean : dict
        Per test, the posterior mean of the model's curves ``(2, n_freq)``.
    bands : list of dict
        The model's bands of off lines (:func:`sbcal.diagnosis.locate.off_bands`).
    tried : list of dict
        The effects refitted on this remainder (``effect``, ``explained``, ...), best first.
    config : DiagnoseConfig
    explained_by : str, optional
        The secondary effect already in ``model`` (not counted as tried on what is left).
    screen : dict, optional
        The screen of the effects that could have been tried (``{effect: {"kept", "why"}}``): those it
        kept out are named with their statistic when nothing was tried.

    Returns
    -------
    dict
        JSON-ready: ``qualifier``, ``words`` (one sentence), ``model``, ``rms_z``, ``lines_off``,
        ``n_lines``, ``global``, ``share`` (of the baseline's excess over chance), ``bands`` (with their
        shape), ``tests`` (those whose own values fail the check), ``tried``.
    """
    word = qualifier(check, config.global_alpha) if model is not None else None
    excess = base_check.global_["excess"]
    share = float(max(check.global_["excess"], 0.0) / excess) if excess > 0 else 0.0
    index = {t: i for i, t in enumerate(tests)}
    shaped = [_band(b, likes[index[b["test"]]], model_mean[b["test"]])
              for b in sorted(bands, key=lambda b: -b["max_abs_z"])]
    p = check.test_p_values()
    off_tests = [t for t, pt in zip(tests, p) if pt < config.global_alpha / len(tests)
                 or any(b["test"] == t for b in bands)]
    tried = [{k: t[k] for k in ("effect", "explained", "delta_elpd", "se") if k in t}
             for t in tried if t["effect"] != explained_by]
    out = {"qualifier": word, "model": model, "rms_z": check.rms_z, "lines_off": check.lines_off,
           "n_lines": check.n_lines, "global": check.global_, "share": share, "bands": shaped, "tests": off_tests,
           "tried": tried, "screened_out": {e: v["why"] for e, v in (screen or {}).items() if not v["kept"]}}
    name = model or "the per-test model"
    numbers = f"rms z {check.rms_z:.2f}, {check.lines_off} of {check.n_lines} lines off"
    if word == "complete":
        out["words"] = (f"complete: what {name} leaves is consistent with the bench's noise ({numbers}, "
                        f"global p {check.global_['p_value']:.2g})")
        return out
    amps = {t: _amplitude(likes[index[t]]) for t in off_tests}
    if len(off_tests) == len(tests) and len(tests) > 1:
        spread = "at every amplitude"
    elif off_tests:
        spread = f"at {len(off_tests)} of {len(tests)} tests ({', '.join(amps[t] or t for t in off_tests)})"
    else:
        spread = "spread thinly over the lines"
    most = (f"; most at {shaped[0]['words']}" if shaped else "")
    head = (f"partial: {name} leaves {share:.1%} of the misfit over chance ({numbers}) {spread}{most}"
            if model is not None else f"the misfit ({numbers}) {spread}{most}")
    out["words"] = f"{head}; not explained by any modelled effect ({_tried(tried, screen)})"
    return out


def headline(rem: dict) -> str:
    """The remainder's sentence led by its size when it has one (``materiality``,
    :func:`sbcal.inference.checks.materiality`): ``complete within 0.5 % and 0.3 deg: ... Statistically:
    partial: ...``, or the ``partial`` sentence with its size; else ``words`` as it is."""
    m = rem.get("materiality")
    if not m:
        return rem["words"]
    if m["material"]:
        return f"{rem['words']} ({m['detail']})"
    return f"{m['words']}. Statistically, {rem['words']}"


def shown_qualifier(rem: dict | None) -> str | None:
    """The qualifier a reader sees: ``complete within X % and Y deg`` for an immaterial ``partial``."""
    if not rem:
        return None
    m = rem.get("materiality")
    return m["qualifier"] if m else rem.get("qualifier")
