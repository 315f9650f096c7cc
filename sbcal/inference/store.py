"""The run store's layout: the one module that knows where each stage's result lives.

::

    <runs>/<damper>/data.json                                  clean: per-test cleaning and quality
    <runs>/<damper>/<test>/<paramset>/posterior.nc, summary.json  a test's posterior (ga.json: the point fit)
    <runs>/<damper>/diagnose.json                              the diagnosis
    <runs>/<damper>/map.json, map.nc                           the amplitude map
    <runs>/<damper>/cable-<state>/posterior.nc, summary.json   a cable state's law
    <runs>/<damper>/predict-<new>-<state>/                     a new damper from that cable (beside it)
    <runs>/span/<label>/                                       span studies
    <runs>/design/<label>/                                     design searches (sbcal design)
    <runs>/batch/                                              the lot as a population (sbcal batch)
    <runs>/batch/cable-<state>/                                the design's cable run (the next unit's law)
    <runs>/compare/<before>-vs-<after>/                        a change of characteristic (sbcal compare)
    <runs>/compare/calibrations/<file>/                        a bench file compare calibrated (a run store)

Inside a run directory the files are its writer's (:mod:`sbcal.inference.runs`,
:func:`sbcal.inference.cable_fit.store_cable`, ...); ``summary.json`` is written last, so a directory
without it holds no finished result.
"""

from __future__ import annotations

from pathlib import Path


__all__ = ["SUMMARY", "POSTERIOR", "dampers", "damper_dir", "run_dir", "run_dirs", "point_fit_path", "data_path",
           "diagnose_path", "map_path", "cable_dir", "cable_dirs", "cable_state_of", "owner", "prediction_dir", "span_dir",
           "span_dirs", "design_dir", "design_dirs", "batch_dir", "design_cable_dir", "design_cable_dirs", "compare_dir", "compare_dirs", "compare_calibration_store"]

SUMMARY = "summary.json"
POSTERIOR = "posterior.nc"
_CABLE = "cable-"
_SPAN = "span"
_DESIGN = "design"
_BATCH = "batch"
_COMPARE = "compare"


def dampers(runs) -> list[str]:
    """The dampers a store holds results of (its directories but the span studies', designs', batch's and comparisons'), sorted."""
    root = Path(runs)
    return sorted(p.name for p in root.iterdir() if p.is_dir() and p.name not in (_SPAN, _DESIGN, _BATCH, _COMPARE)) if root.is_dir() else []


def damper_dir(runs, damper: str) -> Path:
    """``<runs>/<damper>``."""
    return Path(runs) / damper


def run_dir(runs, damper: str, test: str, paramset: str) -> Path:
    """``<runs>/<damper>/<test>/<paramset>``: a test's posterior."""
    return damper_dir(runs, damper) / test / paramset


def run_dirs(runs, damper: str, paramset: str, *, finished: bool = True) -> list[tuple[str, Path]]:
    """``[(test, directory)]`` of a damper's per-test runs of ``paramset``, by test label; only those
    with their ``summary.json`` (finished) unless ``finished`` is False."""
    root = damper_dir(runs, damper)
    if finished:
        dirs = [p.parent for p in root.glob(f"*/{paramset}/{SUMMARY}")]
    else:
        dirs = list(root.glob(f"*/{paramset}"))
    return [(d.parent.name, d) for d in sorted(dirs)]


def point_fit_path(runs, damper: str, test: str, paramset: str) -> Path:
    """``.../<test>/<paramset>/ga.json``: the thesis's point fit (``sbcal sample --method point``)."""
    return run_dir(runs, damper, test, paramset) / "ga.json"


def data_path(runs, damper: str) -> Path:
    """``<runs>/<damper>/data.json``: the clean stage's result."""
    return damper_dir(runs, damper) / "data.json"


def diagnose_path(runs, damper: str) -> Path:
    """``<runs>/<damper>/diagnose.json``."""
    return damper_dir(runs, damper) / "diagnose.json"


def map_path(runs, damper: str) -> Path:
    """``<runs>/<damper>/map.json`` (its draws, ``map.nc``, beside it)."""
    return damper_dir(runs, damper) / "map.json"


def cable_dir(runs, damper: str, state: str) -> Path:
    """``<runs>/<damper>/cable-<state>``."""
    return damper_dir(runs, damper) / f"{_CABLE}{state}"


def cable_dirs(runs, damper: str) -> list[tuple[str, Path]]:
    """``[(state, directory)]`` of a damper's finished cable runs, by state."""
    root = damper_dir(runs, damper)
    return [(cable_state_of(d), d) for d in sorted(root.glob(f"{_CABLE}*")) if (d / SUMMARY).is_file()]


def cable_state_of(directory) -> str:
    """The cable state a cable run's directory is named for (``cable-dry`` -> ``dry``)."""
    return Path(directory).name.removeprefix(_CABLE)


def owner(directory) -> tuple[Path, str]:
    """``(<runs>, <damper>)`` of a damper's result (``runs/damper1/cable-dry`` or ``runs/damper1/diagnose.json``
    -> ``(runs, "damper1")``)."""
    d = Path(directory).parent
    return d.parent, d.name


def prediction_dir(cable_run, damper: str, state: str) -> Path:
    """``<runs>/<calibration damper>/predict-<damper>-<state>``: beside the cable run it comes from."""
    return Path(cable_run).parent / f"predict-{damper}-{state}"


def span_dir(runs, label: str) -> Path:
    """``<runs>/span/<label>``."""
    return Path(runs) / _SPAN / label


def span_dirs(runs) -> list[Path]:
    """The finished span studies of a store."""
    root = Path(runs) / _SPAN
    return [d for d in sorted(root.iterdir()) if (d / SUMMARY).is_file()] if root.is_dir() else []


def design_dir(runs, label: str) -> Path:
    """``<runs>/design/<label>``."""
    return Path(runs) / _DESIGN / label


def design_dirs(runs) -> list[Path]:
    """The finished design searches of a store."""
    root = Path(runs) / _DESIGN
    return [d for d in sorted(root.iterdir()) if (d / SUMMARY).is_file()] if root.is_dir() else []


def batch_dir(runs) -> Path:
    """``<runs>/batch``: the lot's population (:mod:`sbcal.inference.batch`)."""
    return Path(runs) / _BATCH


def design_cable_dir(batch, state: str) -> Path:
    """``<batch>/cable-<state>``: the design's cable run of a lot (the next unit's law; a cable run that
    ``sbcal predict`` and ``sbcal span`` read), ``batch`` the population's directory (:func:`batch_dir`)."""
    return Path(batch) / f"{_CABLE}{state}"


def design_cable_dirs(batch) -> list[tuple[str, Path]]:
    """``[(state, directory)]`` of a lot's finished design cable runs (:func:`design_cable_dir`), by state."""
    return [(cable_state_of(d), d) for d in sorted(Path(batch).glob(f"{_CABLE}*")) if (d / SUMMARY).is_file()]


def compare_dir(runs, label: str) -> Path:
    """``<runs>/compare/<label>``: one ``sbcal compare`` result."""
    return Path(runs) / _COMPARE / label


def compare_dirs(runs) -> list[Path]:
    """The finished comparisons of a store, sorted."""
    return sorted(p.parent for p in (Path(runs) / _COMPARE).glob(f"*/{SUMMARY}"))


def compare_calibration_store(runs, bench_file) -> Path:
    """``<runs>/compare/calibrations/<stem>-<digest>``: the run store of a bench file ``sbcal compare``
    calibrated (its own store, so two files of one damper and test never share a run directory)."""
    import hashlib

    p = Path(bench_file).resolve()
    tag = hashlib.sha256(str(p).encode()).hexdigest()[:8]
    return Path(runs) / _COMPARE / "calibrations" / f"{p.name.split('.')[0]}-{tag}"
