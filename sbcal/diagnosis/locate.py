"""Where the model misses: bands of off lines (of the predictive check of
:func:`sbcal.inference.checks.predictive_check`), and the statistics that screen the catalogue's effects."""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..data.labels import state_tests
from ..model.extensions import EXTENSIONS
from ..model.fem import arm_curvatures
from .fits import CURVE_QUANTITIES, DiagnoseConfig


__all__ = ["off_bands", "band_excess", "band_rms", "signatures", "rocking_signature", "structure_statistics",
           "screen_effects"]

# --- locate --------------------------------------------------------------------------------------

def off_bands(tests, likes, z, thr) -> list:
    """Neighbouring off lines (a gap of one line allowed) as bands, per test and quantity."""
    bands = []
    for t, lk, zt, th in zip(tests, likes, z, thr):
        th = np.broadcast_to(th, zt.shape)
        for q, name in enumerate(CURVE_QUANTITIES):
            off = np.flatnonzero(np.abs(zt[q]) > th[q])
            if off.size == 0:
                continue
            for g in np.split(off, np.flatnonzero(np.diff(off) > 2) + 1):
                lines = np.arange(g[0], g[-1] + 1)
                bands.append({"test": t, "quantity": name, "f_lo": float(lk.freq_hz[g[0]]),
                              "f_hi": float(lk.freq_hz[g[-1]]), "lines": [int(i) for i in lines],
                              "max_abs_z": float(np.max(np.abs(zt[q, lines])))})
    return bands


def band_excess(bands, tests, z, thr) -> tuple[float, list]:
    """The squared z of the bands beyond chance, and their lines (per test a mask ``(2, n_freq)``).

    Per band, floored at 0: a band of several lines counts its lines' z^2 less their expectation under
    chance (1 a line); a band of one line (an isolated off line) counts its z^2 less its threshold's square,
    the level the largest of all the lines reaches by chance with probability alpha (``docs/diagnose.md``,
    "Verdict"): an isolated line is what chance gives for the largest of N lines unless it passes that far.
    """
    index = {t: i for i, t in enumerate(tests)}
    inside = [np.zeros(np.shape(zt), bool) for zt in z]
    total = 0.0
    for b in bands:
        i, q, lines = index[b["test"]], CURVE_QUANTITIES.index(b["quantity"]), b["lines"]
        inside[i][q, lines] = True
        z2 = z[i][q, lines] ** 2
        chance = np.broadcast_to(thr[i], np.shape(z[i]))[q, lines] ** 2 if len(lines) == 1 else np.ones(len(lines))
        total += max(float(np.sum(z2 - chance)), 0.0)
    return total, inside


def band_rms(bands, tests, z) -> list:
    """RMS z over the lines of each band, in the order of ``bands``."""
    index = {t: i for i, t in enumerate(tests)}
    return [float(np.sqrt(np.mean(z[index[b["test"]]][CURVE_QUANTITIES.index(b["quantity"]), b["lines"]] ** 2)))
            for b in bands]


def _share(resid, weight_sq, regressor) -> tuple[float, float]:
    """Share of ``sum w r^2`` explained by ``r ~ c * regressor`` (weighted, through 0), and ``c``."""
    w = weight_sq
    num, den = np.sum(w * resid * regressor), np.sum(w * regressor * regressor)
    if den <= 0:
        return 0.0, 0.0
    c = num / den
    return float(max(0.0, 1 - np.sum(w * (resid - c * regressor) ** 2) / np.sum(w * resid * resid))), float(c)


def signatures(tests, likes, mu_mean, mu_var, z) -> dict:
    """Statistics of a model's residuals that point at measurement-chain effects."""
    ac = [np.corrcoef(zt[q, :-1], zt[q, 1:])[0, 1] for zt in z for q in (0, 1) if zt.shape[1] > 2 and np.std(zt[q]) > 0]
    out = {"lag1_correlation": float(np.nanmean(ac)) if ac else 0.0}
    ph_r, ph_w, ph_x, c_r, c_w, c_x = [], [], [], [], [], []
    for lk, m, v in zip(likes, mu_mean, mu_var):
        r = lk.residual(m[:, None, :])[:, 0]
        w = 1.0 / (lk.sigma ** 2 / lk.n + v)
        omega = 2 * np.pi * lk.freq_hz
        ph_r.append(r[1]), ph_w.append(w[1]), ph_x.append(-omega)
        reg = -omega ** 2 / np.exp(m[0] + 1j * m[1])  # d ln f / d m: log-magnitude and phase parts
        c_r.append(r.ravel()), c_w.append(w.ravel()), c_x.append(np.concatenate([reg.real, reg.imag]))
    share, delay = _share(np.concatenate(ph_r), np.concatenate(ph_w), np.concatenate(ph_x))
    out["phase_linear"] = {"share": share, "delay_s": delay}
    share, mass = _share(np.concatenate(c_r), np.concatenate(c_w), np.concatenate(c_x))
    out["magnitude_omega2"] = {"share": share, "mass_kg": mass}
    return out


def rocking_signature(fits, tests, likes, mean, var, h: float = 0.05) -> tuple[float, float]:
    """Share of a cable model's misfit that clamp rocking explains to first order, and its value [rad/m].

    The regressor is ``d ln f / d r`` at ``r = 0`` of the verdict's cable model at its posterior median
    (central difference, step ``h`` rad/m), per state's tests.
    """
    from ..inference.cable_fit import CableForward

    index = {t: i for i, t in enumerate(tests)}
    r_all, w_all, x_all = [], [], []
    for (_, state), fit in sorted(fits.items()):
        like, fwd = fit["like"], fit["like"].model
        med = {n: np.array([np.median(v)]) for n, v in fit["params"].items()}
        rocking = CableForward(fwd.law, fwd.amplitude_mm_pp, fwd.segments, ("base_rocking",), fwd.sections)
        freq = np.concatenate([lk.freq_hz for lk in like.likes])
        lo, hi = (rocking(like.damper, freq, **med, rocking_rad_per_m=np.array([r]))[0] for r in (-h, h))
        d = np.log(hi / lo) / (2 * h)  # a ratio near 1: no phase wrap
        for t, piece in zip(fit["tests"], np.split(d, np.cumsum([lk.freq_hz.size for lk in like.likes])[:-1])):
            lk = likes[index[t]]
            r_all.append(lk.residual(mean[t][:, None, :])[:, 0].ravel())
            w_all.append((1.0 / (lk.sigma ** 2 / lk.n + var[t])).ravel())
            x_all.append(np.concatenate([piece.real, piece.imag]))
    x = np.concatenate(x_all)
    if not np.all(np.isfinite(x)):
        return 0.0, 0.0
    return _share(np.concatenate(r_all), np.concatenate(w_all), x)


def structure_statistics(damper, tests, likes, fits, z) -> dict:
    """The structure statistics of the baseline's residuals (module docstring)."""
    out = signatures(tests, likes, [fits[t]["mu_mean"][0] for t in tests], [fits[t]["mu_var"][0] for t in tests], z)
    trend = {}  # EJ trend with amplitude within each cable state (constant-amplitude tests)
    for g, members in sorted(state_tests(tests).items()):
        amp, ej = [], []
        for t, lk in zip(tests, likes):
            a = lk.amplitude_mm_pp
            if t in members and np.all(np.isfinite(a)) and np.allclose(a, a[0]):
                amp.append(a[0])
                ej.append(np.median(fits[t]["params"]["EJ"]))
        if len(amp) >= 3 and np.ptp(np.log(amp)) > 0:
            res = stats.linregress(np.log(amp), np.log(ej))
            tval = res.slope / res.stderr if res.stderr > 0 else np.inf * np.sign(res.slope)
            trend[g] = {"slope": float(res.slope), "t": float(tval), "n_tests": len(amp)}
    out["amplitude_trend"] = trend
    rho = []  # misfit versus the predicted cable curvature (rms over both arms' ends), Spearman per test
    for t, lk in zip(tests, likes):
        p = {n: float(np.median(v)) for n, v in fits[t]["params"].items()}
        chi = arm_curvatures(damper, lk.freq_hz, ej1=p["EJ"], ej2=p["EJ"], beta1=p["beta"], beta2=p["beta"],
                             xc=(np.nan_to_num(lk.amplitude_mm_pp, nan=1.0) / 2e3)[None, :], a1=p["a1"], a2=p["a2"])
        curv = np.sqrt(np.mean(np.abs(chi[0]) ** 2, axis=(1, 2)))
        mis = np.sum(z[tests.index(t)] ** 2, axis=0)
        if np.ptp(curv) > 0 and np.ptp(mis) > 0:
            rho.append(stats.spearmanr(curv, mis).statistic)
    out["curvature_correlation"] = float(np.mean(rho)) if rho else 0.0
    return out


def _screen_one(eid, stat, config) -> tuple[bool, str]:
    sig = EXTENSIONS[eid].signature
    if sig == "amplitude_trend":
        # the cable law's first-order signature is a rigidity that falls with the drive amplitude: where a
        # cable state has the amplitudes to show the trend, it decides (a misfit that grows with the
        # curvature within a test is also every resonance-borne effect's); else the curvature correlation
        trend = stat.get("amplitude_trend", {})
        t_max = max((abs(v["t"]) for v in trend.values()), default=0.0)
        corr = stat.get("curvature_correlation", 0.0)
        if trend:
            return t_max >= config.screen_t, (f"|t| of the EJ-amplitude trend {t_max:.1f} (curvature correlation "
                                              f"{corr:.2f}, not used: the trend is measured)")
        return corr >= config.screen_corr, f"no cable state with 3 amplitudes: curvature correlation {corr:.2f}"
    if sig in ("phase_linear", "magnitude_omega2"):
        share = stat[sig]["share"]
        return share >= config.screen_share, f"share of the misfit explained by the signature {share:.2f}"
    return stat["lag1_correlation"] >= config.screen_corr, f"lag-1 correlation of the residuals {stat['lag1_correlation']:.2f}"


def screen_effects(stat: dict, config: DiagnoseConfig, effects) -> dict:
    """Which extensions the structure statistics admit, and why."""
    return {e: dict(zip(("kept", "why"), _screen_one(e, stat, config))) for e in effects}
