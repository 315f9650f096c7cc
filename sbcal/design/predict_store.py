"""Predictions and sweeps in the run store: ``runs/<damper>/predict-<new>-<state>/`` (CSV, JSON, figure)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..core._io import atomic_path, write_json
from ..core.errors import InputError
from ..inference.store import prediction_dir
from .predict import Prediction, Resonance
from .predict_plots import plot_prediction, plot_sweep
from .sweep import SweepResult, unjson


__all__ = [
    "write_csv", "store_prediction", "read_prediction", "store_sweep", "read_sweep",
    "stored_predictions",
]

# --- the store -------------------------------------------------------------------------------------

def write_csv(result, path) -> None:
    """Write a :class:`Prediction` or :class:`SweepResult` (its ``to_frame()``) as CSV, atomically;
    ``extrapolated`` as ``true``/``false``."""
    _write_csv(result.to_frame(), path)


def _write_csv(frame: pd.DataFrame, path) -> None:
    out = frame.copy()
    out["extrapolated"] = out["extrapolated"].map({True: "true", False: "false"})
    with atomic_path(path, ".csv") as tmp:
        out.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")


def store_prediction(pred: Prediction, directory=None, *, meta: dict | None = None, figure: bool = True) -> Path:
    """Write ``prediction.csv``, ``prediction.png`` and (last) ``summary.json``, each atomically, into
    ``directory`` (default :func:`prediction_dir`); returns the directory."""
    d = Path(directory) if directory is not None else prediction_dir(pred.cable, pred.damper, pred.state)
    _write_csv(pred.to_frame(), d / "prediction.csv")
    if figure:
        plot_prediction(pred, d / "prediction.png")
    write_json(d / "summary.json", dict(pred.summary(), **(meta or {})), indent=1)
    return d


def _read_summary(directory, what: str) -> dict:
    p = Path(directory) / "summary.json"
    if not p.is_file():
        raise InputError(f"{directory}: no stored {what} (summary.json missing)")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not valid JSON ({e.msg}, line {e.lineno})") from None


def read_prediction(directory) -> Prediction:
    """A stored prediction (:func:`store_prediction`) back as a :class:`Prediction`."""
    s = _read_summary(directory, "prediction")
    try:
        frame = pd.read_csv(Path(directory) / "prediction.csv")
        f = np.asarray(s["freq_hz"], float)
        nl, nf = len(s["levels"]), f.size
        by = {t: g for t, g in frame.groupby("test", sort=False)}

        def col(name):
            return np.stack([by[t][name].to_numpy(float) for t in s["tests"]]).reshape(nl, nf)

        def band(stem, mid):
            return np.stack([col(f"{stem}_q05"), col(mid), col(f"{stem}_q95")], axis=1)

        extra = np.stack([by[t]["extrapolated"].astype(str).str.lower().eq("true").to_numpy() for t in s["tests"]])
        return Prediction(
            damper=s["damper"], damper_values=s["damper_values"], cable=s["cable"], cable_damper=s["cable_damper"],
            state=s["state"], law=s["law"], mode=s["mode"], levels=np.asarray(s["levels"], float), freq_hz=f,
            amplitude_mm_pp=col("amplitude_mm_pp"), stiffness_n_per_m=band("stiffness", "stiffness_n_per_m"),
            phase_deg=band("phase", "phase_deg"), power_w=band("power", "power_w"),
            curvature_max=np.asarray(s["curvature_max"], float), extrapolated=extra,
            fold_share=np.asarray(s["fold_share"], float), converged_share=np.asarray(s["converged_share"], float),
            resonances=tuple(Resonance(**{**r, "freq_hz": tuple(r["freq_hz"]), "power_w": tuple(r["power_w"])})
                             for r in s["resonances"]),
            calibrated_curvature=tuple(s["calibrated_curvature"]), n_draws=s["n_draws"], seed=s["seed"],
            tolerance_pct=s["tolerance_pct"], own_offsets=s["own_offsets"], bench_effects=s["bench_effects"],
            model_error=s.get("model_error"), warnings=tuple(s["warnings"]), versions=s.get("versions", {}))
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise InputError(f"{directory}: not a prediction written by sbcal predict ({type(e).__name__}: {e})") from None


def store_sweep(result: SweepResult, directory=None, *, meta: dict | None = None, figure: bool = True) -> Path:
    """Write ``sweep.csv``, ``sweep.png`` and (last) ``summary.json`` into ``directory`` (default
    ``<prediction_dir>/sweep-<field>``); returns the directory."""
    d = Path(directory) if directory is not None else (
        prediction_dir(result.cable, result.damper, result.state) / f"sweep-{result.field}")
    _write_csv(result.to_frame(), d / "sweep.csv")
    if figure:
        plot_sweep(result, d / "sweep.png")
    write_json(d / "summary.json", dict(result.summary(), **(meta or {})), indent=1)
    return d


def read_sweep(directory) -> SweepResult:
    """A stored sweep (:func:`store_sweep`) back as a :class:`SweepResult`."""
    s = _read_summary(directory, "sweep")
    try:
        nv, nl = len(s["values"]), len(s["levels"])
        hz = unjson(s["resonance_hz"]).reshape(nv, nl, -1, 3)
        return SweepResult(
            damper=s["damper"], field=s["field"], values=np.asarray(s["values"], float), cable=s["cable"],
            cable_damper=s["cable_damper"], state=s["state"], law=s["law"], mode=s["mode"],
            levels=np.asarray(s["levels"], float), resonance_hz=hz,
            resonance_share=unjson(s["resonance_share"]).reshape(nv, nl, -1),
            peak_power_w=unjson(s["peak_power_w"]).reshape(nv, nl, 3),
            extrapolated=np.asarray(s["extrapolated"], bool), fold_share=np.asarray(s["fold_share"], float),
            n_draws=s["n_draws"], seed=s["seed"], tolerance_pct=s["tolerance_pct"], own_offsets=s["own_offsets"],
            bench_effects=s["bench_effects"], warnings=tuple(s["warnings"]), versions=s.get("versions", {}))
    except (KeyError, ValueError, TypeError) as e:
        raise InputError(f"{directory}: not a sweep written by sbcal predict ({type(e).__name__}: {e})") from None


def stored_predictions(damper_dir) -> list:
    """Every stored prediction beside a damper's cable runs: ``[(directory, Prediction or None,
    [SweepResult, ...])]``, sorted by directory name."""
    out = []
    root = Path(damper_dir)
    for d in sorted(root.glob("predict-*")) if root.is_dir() else []:
        if not d.is_dir():
            continue
        pred = read_prediction(d) if (d / "summary.json").is_file() else None
        sweeps = [read_sweep(s) for s in sorted(d.glob("sweep-*")) if (s / "summary.json").is_file()]
        if pred is not None or sweeps:
            out.append((d, pred, sweeps))
    return out
