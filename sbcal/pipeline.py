"""The whole job, one way: clean -> sample -> diagnose -> map -> report, through the run store.

Each stage writes its result to the run store (where: :mod:`sbcal.inference.store`) and later stages
read stored results: clean -> ``data.json``, sample -> each test's posterior, diagnose ->
``diagnose.json`` (and the cable runs), map -> ``map.json`` + ``map.nc``, report -> ``<report>/index.html``
(it renders the store and recomputes nothing).

**Fresh or redone.** Every stored result carries ``inputs``: digests of everything it was made
from — the bench rows it used (the test's rows for a posterior, the damper's for its other stages),
the damper description, the prior file(s), the settings, the seed and the sbcal version (a map: the
digests of the posteriors it rests on). A stored result is reused only when its inputs equal the
current ones; otherwise the stage is redone, and :func:`run` says which input changed.

Tests and dampers are independent jobs, run through any ``concurrent.futures``-style executor: a
process pool here, or a Dask distributed cluster (``executor_for(scheduler=ADDRESS)``). Every job's
random numbers come from the seed alone (never from the order of jobs or the worker it lands on), so
the same seed gives the same numbers locally and on a cluster.
"""

from __future__ import annotations

import hashlib
import json
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from .core._io import write_json
from .core.errors import InputError
from .core.workers import default_workers, one_blas_thread, run_jobs
from .data.bench import rows_digest
from .data.clean_bench import CleanBench
from .data.cleaning import DEFAULT_Z_THRESHOLD, quality_table
from .data.summary import bench_summary
from .inference.store import data_path, diagnose_path
from .model.damper import Damper


__all__ = ["Settings", "inputs_digest", "file_digest", "changed", "executor_for", "clean_damper", "clean",
           "sample_inputs",
           "sample_tests", "diagnose_inputs", "diagnose_dampers", "map_damper", "run", "calibrate_bench",
           "STAGES"]

STAGES = ("clean", "sample", "diagnose", "map", "report")  # the order of ``run``; ``--until`` names one


@dataclass(frozen=True)
class Settings:
    """What a run is made with, besides the data: parameter set, seed, priors and engine settings.

    Attributes
    ----------
    paramset : str
    seed : int
    priors : str or None
        A prior file (``--priors``); None is the bundled ``priors/default.toml``.
    sampler : SamplerConfig
    diagnose : DiagnoseConfig
    z_threshold : float
        Outlier-run threshold of the cleaning.
    workers : int
        Local processes (ignored on a cluster).
    """

    paramset: str = "theta1"
    seed: int = 0
    priors: str | None = None
    sampler: object = None
    diagnose: object = None
    z_threshold: float = DEFAULT_Z_THRESHOLD
    workers: int = field(default_factory=default_workers)

    def __post_init__(self):
        from .diagnosis.diagnose import DiagnoseConfig
        from .inference.sampler import SamplerConfig

        if self.sampler is None:
            object.__setattr__(self, "sampler", SamplerConfig())
        if self.diagnose is None:
            object.__setattr__(self, "diagnose", DiagnoseConfig())


# --- digests -------------------------------------------------------------------------------

def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def inputs_digest(obj) -> str:
    """sha256 of a JSON-serialisable object (keys sorted)."""
    return _sha(json.dumps(obj, sort_keys=True, default=str).encode())


def file_digest(path=None, bundled: str = "default.toml") -> str:
    """sha256 of a prior file (the bundled one when ``path`` is None)."""
    from .inference.priors import default_path

    if path is None:
        return _sha(default_path(bundled).read_bytes())
    try:
        return _sha(Path(path).read_bytes())
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None


def _damper_digest(damper: Damper) -> str:
    # tolerances matter to predictions only: a calibration's inputs are the nominal values
    return inputs_digest({k: v for k, v in asdict(damper).items() if k not in ("source", "tolerance")})


def _version() -> str:
    from .core.version import __version__

    return __version__


def changed(stored: dict | None, current: dict) -> list[str]:
    """Which inputs differ (``["new"]`` when nothing is stored); empty when the stored result is fresh."""
    if not stored or "inputs" not in stored:
        return ["new"]
    old = stored["inputs"]
    current = json.loads(json.dumps(current))  # as stored: tuples are lists in JSON
    return [k for k in current if old.get(k) != current[k]] + [k for k in old if k not in current]


_WHY = {"bench_rows": "bench rows changed", "damper": "damper description changed", "priors": "prior file changed",
        "settings": "settings changed", "seed": "seed changed", "sbcal": "sbcal version changed",
        "posteriors": "per-test posteriors changed", "new": "not stored yet",
        "format": "stored before sbcal judged what a verdict leaves", "paramset": "parameter set changed"}


def _why(keys) -> str:
    return ", ".join(_WHY.get(k, f"{k} changed") for k in keys)


# --- executors -----------------------------------------------------------------------------

@contextmanager
def executor_for(scheduler: str | None = None):
    """A context giving the executor of a running Dask distributed cluster at ``scheduler``
    (``pip install "sbcal[dask]"``), or None (local work: process pools where they help).

    The Dask client is closed on exit (a client left open would stay the default scheduler of the
    process, and xarray would take its locks when writing netCDF)."""
    if not scheduler:
        yield None
        return
    try:
        from dask.distributed import Client
    except ImportError:
        raise InputError("--scheduler needs Dask distributed: pip install \"sbcal[dask]\"") from None
    try:
        client = Client(scheduler, timeout="5s", set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise InputError(f"--scheduler {scheduler}: no Dask scheduler answers ({e})") from None
    try:
        yield client.get_executor()
    finally:
        client.close()


# --- stages --------------------------------------------------------------------------------

def clean_damper(bench, damper: Damper, *, store, settings: Settings) -> tuple[dict, str]:
    """Stage 1: per-test cleaning and quality of one damper -> ``<store>/<damper>/data.json``.

    Returns ``(doc, status)``.
    """
    path = data_path(store, damper.name)
    inputs = {"bench_rows": rows_digest(bench, damper.name), "settings": {"z_threshold": settings.z_threshold},
              "sbcal": _version()}
    stored = _read_json(path)
    why = changed(stored, inputs)
    if not why:
        return stored, "reused"
    summary = bench_summary(_only(bench, damper.name), settings.z_threshold)[damper.name]
    quality = {}
    for label in summary:
        q = quality_table(bench.test(damper.name, label))
        quality[label] = {c: q[c].tolist() for c in ("frequency_hz", "magnitude_cv", "phase_cv")}
    doc = {"damper": damper.name, "bench": str(bench.source), "tests": summary, "quality": quality, "inputs": inputs}
    write_json(path, doc, indent=1)
    return doc, f"redone ({_why(why)})"


def clean(bench, dampers, *, store, settings: Settings, say=None) -> CleanBench:
    """Stage 1 for every damper (:func:`clean_damper`, reused where fresh), and the cleaned bench that
    every later stage reads: the stored decisions, not a new cleaning. ``say`` gets one line per damper."""
    removed = {}
    for damper in dampers:
        doc, status = clean_damper(bench, damper, store=store, settings=settings)
        if say is not None:
            say(f"{damper.name}: clean: {status}")
        stored = CleanBench.from_stored(bench, {damper.name: doc["tests"]}, z_threshold=settings.z_threshold,
                                        source=str(data_path(store, damper.name)))
        removed.update(stored.removed)
    return CleanBench(bench, removed, settings.z_threshold)


def _only(bench, damper: str):
    """The bench restricted to one damper (a summary of its rows only)."""
    from .data.bench import BenchData

    return BenchData(source=bench.source, frame=bench.frame[bench.frame["damper"] == damper].reset_index(drop=True))


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        return None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not valid JSON ({e.msg}, line {e.lineno})") from None


def sample_inputs(data, damper: Damper, *, test: str, settings: Settings) -> dict:
    """What a test's posterior is made from (stored as its ``inputs``)."""
    sampler = {k: v for k, v in asdict(settings.sampler).items() if k != "workers"}
    return {"bench_rows": rows_digest(data, damper.name, test), "damper": _damper_digest(damper),
            "priors": file_digest(settings.priors), "paramset": settings.paramset,
            "settings": {"sampler": sampler, "z_threshold": settings.z_threshold},
            "seed": settings.seed, "sbcal": _version()}


@dataclass(frozen=True)
class SampleJob:
    """One test's posterior, as a worker runs it (picklable: it travels to a process or a cluster)."""

    damper: Damper
    data: CleanBench
    test: str
    store: str
    settings: Settings
    inputs: dict
    command: str = ""


@dataclass(frozen=True)
class DiagnoseJob:
    """One damper's diagnosis, as a worker runs it."""

    damper: Damper
    data: CleanBench
    store: str
    settings: Settings
    inputs: dict
    command: str = ""
    progress: bool = False


def _sample_job(job: SampleJob):
    from .inference.calibrate import calibrate_test

    s = job.settings
    with one_blas_thread():
        return calibrate_test(job.damper, job.data, job.test, paramset=s.paramset, seed=s.seed, out=job.store,
                              config=replace(s.sampler, workers=1), prior_path=s.priors, progress=False,
                              command=job.command, inputs=job.inputs)


def sample_tests(data: CleanBench, work, *, store, settings: Settings, executor=None, command: str = "",
                 reuse: bool = True, progress: bool = True) -> dict:
    """Stage 2: the posterior of every ``(damper, test)`` in ``work`` (reused where fresh), from the kept
    runs of the cleaned bench ``data`` (:func:`clean`).

    Jobs run in ``executor`` (a cluster), else in ``settings.workers`` local processes. Returns
    ``{(damper name, test): (summary, status)}``.
    """
    from .inference.runs import read_summary
    from .inference.store import run_dir

    out, jobs = {}, []
    for damper, t in work:
        inputs = sample_inputs(data, damper, test=t, settings=settings)
        stored = read_summary(run_dir(store, damper.name, t, settings.paramset))
        why = changed(stored, inputs)
        if reuse and not why:
            out[damper.name, t] = (stored, "reused")
        else:
            jobs.append(SampleJob(damper, data, t, store, settings, inputs, command))
            out[damper.name, t] = (None, f"redone ({_why(why)})" if reuse else "sampled")
    label = f"sampling {len(jobs)} test(s)" if progress and jobs else None
    done = run_jobs(_sample_job, jobs, workers=settings.workers, executor=executor, label=label)
    for job, summary in zip(jobs, done):
        key = (job.damper.name, job.test)
        out[key] = (summary, out[key][1])
    return out


def diagnose_inputs(data: CleanBench, damper: Damper, *, settings: Settings) -> dict:
    """What a damper's diagnosis is made from (stored as its ``inputs``)."""
    diag = {k: v for k, v in asdict(settings.diagnose).items() if k != "workers"}
    diag["z_threshold"] = settings.z_threshold
    return {"bench_rows": rows_digest(data, damper.name), "damper": _damper_digest(damper),
            "priors": {"default": file_digest(settings.priors), "extensions": file_digest(None, "extensions.toml"),
                       "cable": file_digest(None, "cable.toml")},
            "settings": diag, "seed": settings.seed, "sbcal": _version()}


def _diagnose_job(job: DiagnoseJob):
    from .diagnosis.diagnose import diagnose

    s = job.settings
    with one_blas_thread():
        doc = diagnose(job.damper, job.data, seed=s.seed, config=s.diagnose, progress=job.progress,
                       prior_path=s.priors, store=job.store)
    doc["command"] = job.command
    doc["inputs"] = job.inputs
    write_json(diagnose_path(job.store, job.damper.name), doc, indent=1)
    return doc


def diagnose_dampers(data: CleanBench, dampers, *, store, settings: Settings, executor=None, command: str = "",
                     reuse: bool = True, progress: bool = True) -> dict:
    """Stage 3: the diagnosis of every damper (reused where fresh) -> ``<store>/<damper>/diagnose.json``.

    Locally a diagnosis runs its fits in ``settings.diagnose.workers`` processes, one damper after the other
    (side by side, four processes on two cores took as long: ``docs/results.md``, "Performance"); on a cluster
    each damper's diagnosis is one job. Returns ``{damper name: (doc, status)}``.
    """
    out, jobs = {}, []
    for damper in dampers:
        inputs = diagnose_inputs(data, damper, settings=settings)
        stored = _read_json(diagnose_path(store, damper.name))
        why = changed(stored, inputs)
        if not why and "remainder" not in stored:
            why = ["format"]
        if reuse and not why:
            out[damper.name] = (stored, "reused")
        else:
            out[damper.name] = (None, f"redone ({_why(why)})" if reuse else "diagnosed")
            jobs.append(DiagnoseJob(damper, data, store, settings, inputs, command, progress and executor is None))
    if executor is not None:  # on a cluster each diagnosis is one job: its fits run in that worker, one at a time
        jobs = [replace(j, settings=replace(j.settings, diagnose=replace(j.settings.diagnose, workers=1))) for j in jobs]
    for job, doc in zip(jobs, run_jobs(_diagnose_job, jobs, executor=executor)):
        out[job.damper.name] = (doc, out[job.damper.name][1])
    return out


def map_damper(store, damper: str, *, settings: Settings, include_oiled: bool = False,
               reuse: bool = True, workers: int | None = None) -> tuple[dict | None, str]:
    """Stage 4: the amplitude map of one damper from its stored posteriors -> ``map.json`` + ``map.nc``.

    ``workers``: processes for the map fit's ensembles (default ``settings.workers``; the draws do not depend on
    them). Returns ``(doc, status)``; ``doc`` is None when the damper has no tests at 3 or more amplitudes.
    """
    from .inference.amplitude import map_from_store
    from .inference.sampler import SamplerConfig

    config = SamplerConfig(workers=settings.workers if workers is None else workers)
    return map_from_store(store, damper, settings.paramset, seed=settings.seed, include_oiled=include_oiled,
                          reuse=reuse, config=config)


def _map_job(job):
    store, damper, settings, workers = job
    with one_blas_thread():
        return map_damper(store, damper, settings=settings, workers=workers)


def calibrate_bench(path, state: str, *, runs, settings: Settings, damper=None, amplitude=None,
                    progress: bool = False) -> tuple:
    """Clean and sample a bench file's constant-amplitude tests of one cable ``state`` (only the one at
    ``amplitude`` [mm p-p] when given) into its own run store (:func:`sbcal.inference.store.compare_calibration_store`):
    what ``sbcal compare`` does with a bench file. Stages and seeds as :func:`run`'s; reused while fresh.

    Returns
    -------
    (store, damper name)
    """
    import numpy as np

    from .data.labels import parse_label
    from .data.readers import load_bench
    from .inference.store import compare_calibration_store
    from .model.damper import bundled_dampers, resolve_damper

    bench = load_bench(path)
    names = bench.dampers()
    if damper is not None:
        d = resolve_damper(damper)
        if d.name not in names:
            raise InputError(f"{path}: no rows of damper {d.name!r} (has: {', '.join(names)})")
    elif len(names) == 1:
        if names[0] not in bundled_dampers():
            raise InputError(f"{path}: damper {names[0]!r} is not bundled; give its file with --damper PATH")
        d = resolve_damper(names[0])
    else:
        raise InputError(f"{path}: {len(names)} dampers ({', '.join(names)}); pick one with --damper")
    tests = []
    for t in bench.tests(d.name):
        p = parse_label(t)
        if p and p.constant and p.state == state and (amplitude is None or np.isclose(p.below_mm_pp, amplitude)):
            tests.append(t)
    if not tests:
        what = f" at {amplitude:g} mm p-p" if amplitude is not None else ""
        raise InputError(f"{path}: damper {d.name} has no constant-amplitude test{what} in state {state!r}")
    store = compare_calibration_store(runs, path)
    data = clean(bench, [d], store=store, settings=settings)
    sample_tests(data, [(d, t) for t in tests], store=store, settings=settings, progress=progress)
    return store, d.name


def run(bench, dampers, *, store, report_dir, settings: Settings, executor=None, command: str = "",
        progress: bool = True, say=print, until: str = "report") -> Path | None:
    """The whole job for ``dampers``, stage after stage, reusing what is fresh; returns the report path.

    ``say`` gets one line per stage, damper and test: reused or redone, and why. ``until`` (one of
    :data:`STAGES`) stops after that stage, its results stored; then no report is written (None).
    """
    from .report.build import build_report

    if until not in STAGES:
        raise InputError(f"until: expected one of {', '.join(STAGES)}, got {until!r}")
    data = clean(bench, dampers, store=store, settings=settings, say=say)
    if until == "clean":
        return None
    work = [(d, t) for d in dampers for t in data.tests(d.name)]
    for (name, t), (summary, status) in sample_tests(data, work, store=store, settings=settings, executor=executor,
                                                     command=command, progress=progress).items():
        flag = "" if summary is None or summary.get("converged") else f"; NOT CONVERGED ({summary.get('reason')})"
        say(f"{name}: sample {t}: {status}{flag}")
    if until == "sample":
        return None
    from .diagnosis.remainder import headline

    for name, (doc, status) in diagnose_dampers(data, dampers, store=store, settings=settings, executor=executor,
                                                command=command, progress=progress).items():
        say(f"{name}: diagnose: {status}; verdict {doc['verdict']} — {headline(doc['remainder'])}")
    if until == "diagnose":
        return None
    side = 1 if executor is not None else min(settings.workers, len(dampers))  # a map is ~10 s, much of it on one core
    maps = run_jobs(_map_job, [(store, d.name, settings, max(1, settings.workers // side)) for d in dampers],
                    workers=side)
    for damper, (doc, status) in zip(dampers, maps):
        say(f"{damper.name}: map: {status}" + ("" if doc is None else f"; preferred {doc['preferred']}"
                                                + ("" if doc["converged"] else "; NOT CONVERGED")))
    if until == "map":
        return None
    index = build_report(store, report_dir, paramset=settings.paramset, command=command, workers=settings.workers)
    say(f"report: {index}")
    return index
