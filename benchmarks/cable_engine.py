"""Sampling engines on the cable posteriors that do not converge in the step cap, side by side.

Usage: python benchmarks/cable_engine.py [--posteriors uniform oiled zoned dry-zoned matrix matrix-uniform matrix-row]
       [--engines emcee emcee-t emcee-screen emcee-plain emcee-unsheared emcee-share-only emcee-no-redraw emcee-slanted
       nautilus]
       [--steps 1500] [--workers 2] [--seed 4100] [--json OUT]

Posteriors (``--posteriors``):

- ``uniform``: damper1's dry cable state under ``iwan5`` on the bundled bench (8 tests, 6 parameters + the
  geometry);
- ``oiled``: damper1's oiled cable state under ``iwan5`` (one test: a weakly determined law, a thin curved
  ridge);
- ``zoned``: the in-family ``iwan5_zoned`` of ``benchmarks/zones_identifiability.py`` (damper2, 5 amplitudes
  x 8 runs of the zoned fast model itself; 17 parameters);
- ``dry-zoned``: damper1's dry cable state on the bundled bench under ``iwan5_zoned``, started as
  :func:`sbcal.inference.cable_fit.fit_damper_cable` starts it (its ``iwan5`` fit's median, every zone ratio
  1; that uniform fit, ~40 s, is not in the engine's wall time). One of its ensembles strands in a mode
  without posterior mass unless the engine starts it again (``docs/cable.md``, "Stranded ensembles");
- ``matrix``: the misspecified ``zoned_iwan5`` row of ``benchmarks/cable_matrix.py`` (the stubby damper,
  16 runs per test, a log-normal clamp zone no family holds) fitted with ``iwan5_zoned``;
- ``matrix-uniform``: the same runs under the uniform ``iwan5`` (the family the row's zoned fit starts from);
- ``matrix-row``: ``matrix`` started as the row's diagnosis starts it (its ``iwan5`` fit's median, every zone
  ratio 1; that uniform fit, ~14 min, is not in the engine's wall time).

Engines (``--engines``), each to sbcal's convergence rule where it has one:

- ``emcee``: sbcal's engine as a cable fit ran it before the slanted redraw (:func:`sbcal.inference.cable_fit.sample_cable`: 4
  ensembles of differential evolution and an independence move from a t bent along the posterior's widest
  directions, half of each chain burnt, in the coordinates of :mod:`sbcal.inference.cable_coords`, the onsets
  redrawn with the others held), capped at ``--steps`` steps per ensemble;
- ``emcee-t``: the same engine with the t alone and a fifth burnt (a test's fit; the cable fits' engine
  before the bend): the baseline of ``emcee``;
- ``emcee-unsheared``: ``emcee`` on the same posterior in the coordinates of the boxes alone, from the same
  start and streams: the cable fit before :mod:`sbcal.inference.cable_coords` (``ln delta_EJ`` sampled as
  it is, not with the log of the share of the law's drop the bench sees added), the baseline of ``emcee``;
- ``emcee-share-only``: ``emcee`` with ``delta_EJ``'s shear alone, the law's seen ratios (``iwan5``'s
  ``macro_ratio``, :class:`sbcal.inference.cable_coords.SeenRatio`) sampled as they are: the cable fit before the
  second shear, its baseline;
- ``emcee-no-redraw``: ``emcee`` without the redraw of the law's unseen onsets
  (:attr:`sbcal.inference.priors.Prior.redrawn`, ``SamplerConfig.redraw_every = 0``): the cable fit before it, its
  baseline;
- ``emcee-slanted``: ``emcee`` with half of each redraw moving the other coordinates along their slopes on the
  redrawn one (``SamplerConfig.redraw_slant``; the cable fits' default since the bundled results were regenerated with it,
  while ``emcee`` and the other ``emcee-*`` engines keep the others held, as the cable fit did before);
- ``nautilus``: neural-network-boosted importance nested sampling (``pip install nautilus-sampler``; not a
  dependency of sbcal), with its effective sample size ``n_eff`` as its diagnostic and the evidence.

Prints per (posterior, engine): wall time, likelihood evaluations, the convergence diagnostics (R-hat max,
bulk/tail ESS min, tau max; nautilus: n_eff), ESS per minute of the worst parameter, and the posterior
mean of each parameter against the truth where one is known. One heavy job: run it on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.inference.cable_fit import (cable_config, cable_likelihood, fit_cable, sample_cable,  # noqa: E402
                                      zoned_start)
from sbcal.inference.cable_coords import seen_share_target  # noqa: E402
from sbcal.inference.cable_fit import _near  # noqa: E402
from sbcal.inference.likelihood import JointLikelihood  # noqa: E402
from sbcal.inference.sampler import SamplerConfig  # noqa: E402
from sbcal.model.damper import load_damper, resolve_damper  # noqa: E402


class _Counted:
    """A target that counts its evaluations (picklable: the counts of worker processes are not seen, so
    the engines are run with the count kept in this process where it matters)."""

    def __init__(self, target):
        self.target, self.calls = target, 0
        self.prior = target.prior

    def __call__(self, z):
        z = np.atleast_2d(z)
        self.calls += len(z)
        return self.target(z)


def posterior(name: str, seed: int):
    """``(likelihood, truth, start)`` of one benchmark posterior (truth: natural values by name, or {};
    start: the fit's start, natural values by name, or None for the fit's own search)."""
    if name == "uniform":
        d = resolve_damper("damper1")
        data = clean_bench(load_bench(default_bench_path()))
        tests = [t for t in data.tests(d.name) if not t.endswith("oiled")]
        return cable_likelihood(d, data, tests, "iwan5"), {}, None
    if name == "oiled":
        d = resolve_damper("damper1")
        data = clean_bench(load_bench(default_bench_path()))
        return cable_likelihood(d, data, [t for t in data.tests(d.name) if t.endswith("oiled")], "iwan5"), {}, None
    if name == "zoned":
        from zones_identifiability import make_bench
        d = resolve_damper("damper2")
        with tempfile.TemporaryDirectory() as tmp:
            bench, truth = make_bench(d, "iwan5", [0.1, 0.2, 0.5, 1.0, 2.0], seed, Path(tmp) / "bench.csv")
        data = clean_bench(bench)
        return cable_likelihood(d, data, data.tests(d.name), "iwan5_zoned"), truth, None
    if name == "dry-zoned":
        d = resolve_damper("damper1")
        data = clean_bench(load_bench(default_bench_path()))
        dry = [t for t in data.tests(d.name) if not t.endswith("oiled")]
        uniform = fit_cable(d, data, dry, "iwan5", seed=0)
        return cable_likelihood(d, data, dry, "iwan5_zoned"), {}, zoned_start(uniform.median(), uniform.like.prior)
    if name.startswith("matrix"):
        from cable_matrix import record_row
        from diagnose_matrix import STUB
        with tempfile.TemporaryDirectory() as tmp:
            (Path(tmp) / "stub.toml").write_text(STUB)
            d = load_damper(Path(tmp) / "stub.toml")
            record_row(d, "zoned_iwan5", 2029, Path(tmp) / "bench.csv")  # cable_matrix.py's seed
            data = clean_bench(load_bench(Path(tmp) / "bench.csv"))
        tests = data.tests(d.name)
        if name == "matrix-uniform":
            return cable_likelihood(d, data, tests, "iwan5"), {}, None
        start = None
        if name == "matrix-row":  # as the row's diagnosis starts it
            uniform = fit_cable(d, data, tests, "iwan5", seed=0)
            start = zoned_start(uniform.median(), uniform.like.prior)
        return cable_likelihood(d, data, tests, "iwan5_zoned"), {}, start
    raise SystemExit(f"unknown posterior {name!r}")


def share_only_target(like, start):
    """``sample_cable``'s target with ``delta_EJ``'s shear alone (the law's seen ratios sampled as they are)."""
    target = seen_share_target(_near(like, start), start)
    pr = target.prior
    return JointLikelihood(target.likes, replace(pr, shears=pr.shears[-1:]), target.model)


def run_emcee(like, seed, steps, workers, bend=True, screen=None, start=None, shear=True, share_only=False,
              redraw=True, slant=False) -> dict:
    cfg = cable_config(like.prior.ndim, workers=workers, max_steps=steps)
    if not redraw:
        cfg = replace(cfg, redraw_every=0)
    cfg = replace(cfg, redraw_slant=slant)
    if screen is not None:
        cfg = replace(cfg, screen=screen)
    if not bend:
        cfg = replace(cfg, bend=0, burn_fraction=SamplerConfig.burn_fraction)
    t0 = time.perf_counter()
    if not shear or share_only:  # sample_cable's start and streams, the engine on another target
        from sbcal.inference.cable_start import cable_start, fit_streams
        from sbcal.inference.sampler import sample

        s_start, s_sample = fit_streams(np.random.SeedSequence(seed))
        if isinstance(start, dict):
            start = {n: start.get(n, m) for n, m in like.prior.middle().items()}
        elif start is None:
            start = cable_start(like, np.random.default_rng(s_start))
        if share_only:
            natural = start if isinstance(start, dict) else dict(zip(like.prior.names, like.prior.to_natural(
                np.asarray(start, float)[None])[0]))
            res = sample(share_only_target(like, natural), seed=s_sample, config=cfg, start=natural)
        else:
            res = sample(like, seed=s_sample, config=cfg, start=start)
    else:
        res = sample_cable(like, seed=np.random.SeedSequence(seed), config=cfg, start=start)
    wall = time.perf_counter() - t0
    c = res.convergence_dict()
    worst_ess = min(c["ess_bulk_min"], c["ess_tail_min"])
    flat = dict(res.flat())
    return {"wall_s": wall, "converged": res.converged, "r_hat_max": c["r_hat_max"], "ess_min": worst_ess,
            "tau_max": c["tau_max"], "steps": res.n_steps, "ess_per_min": worst_ess / (wall / 60),
            "acceptance": float(np.mean(res.acceptance)), "reason": res.reason[:200], "calls": res.calls,
            "redrawn": list(res.redrawn) if res.config.redraw_every else [],
            "calls_per_step": res.calls / res.n_steps, "restarts": [list(x) for x in res.restarts],
            "mean": {k: float(np.mean(v)) for k, v in flat.items()}, "tau": {k: float(v) for k, v in res.tau.items()},
            "r_hat": {k: float(v) for k, v in res.r_hat.items()},
            "ensemble_median": {k: np.median(v, axis=1).tolist() for k, v in res.draws.items()},
            "ensemble_log_prob_median": np.median(res.log_prob, axis=1).tolist()}


def run_nautilus(like, seed, n_live=2000, n_eff=4000) -> dict:
    from nautilus import Prior, Sampler  # not a dependency of sbcal: measured here only

    pr = like.prior
    prior = Prior()
    for i, n in enumerate(pr.names):
        prior.add_parameter(n, dist=(pr.z_lower[i], pr.z_upper[i]))
    target = _Counted(like)

    def loglike(z):
        lp = target(z)
        return np.where(np.isfinite(lp), lp, -1e300)

    t0 = time.perf_counter()
    s = Sampler(prior, loglike, n_live=n_live, vectorized=True, pass_dict=False, seed=seed)
    s.run(verbose=False, n_eff=n_eff, discard_exploration=True)
    wall = time.perf_counter() - t0
    pts, logw, _ = s.posterior()
    w = np.exp(logw - logw.max())
    w /= w.sum()
    nat = pr.to_natural(pts)
    return {"wall_s": wall, "calls": target.calls, "n_eff": float(s.n_eff), "log_z": float(s.log_z),
            "ess_per_min": float(s.n_eff) / (wall / 60),
            "mean": {n: float(np.sum(w * nat[:, i])) for i, n in enumerate(pr.names)}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--posteriors", nargs="+", default=["zoned"], choices=["uniform", "oiled", "zoned", "dry-zoned", "matrix",
                                                                       "matrix-uniform", "matrix-row"])
    ap.add_argument("--engines", nargs="+", default=["emcee"], choices=["emcee", "emcee-t", "emcee-screen", "emcee-plain", "emcee-unsheared", "emcee-share-only",
                                                                    "emcee-no-redraw", "emcee-slanted", "nautilus"])
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=4100)
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args(argv)
    out = {}
    for name in args.posteriors:
        like, truth, start = posterior(name, args.seed)
        print(f"{name}: {like.prior.ndim} parameters, {like.freq_hz.size} lines")
        for engine in args.engines:
            if engine == "nautilus":
                r = run_nautilus(like, args.seed)
                print(f"  nautilus: {r['wall_s']:.0f} s, {r['calls']} evaluations, n_eff {r['n_eff']:.0f}, "
                      f"{r['ess_per_min']:.1f} ESS/min, log Z {r['log_z']:.1f}")
            else:
                r = run_emcee(like, args.seed, args.steps, args.workers, bend=engine != "emcee-t",
                              screen={"emcee-screen": True, "emcee-plain": False}.get(engine), start=start,
                              shear=engine != "emcee-unsheared", share_only=engine == "emcee-share-only",
                              redraw=engine != "emcee-no-redraw", slant=engine == "emcee-slanted")
                print(f"  {engine}: {r['wall_s']:.0f} s, {r['steps']} steps, converged {r['converged']}, R-hat max "
                      f"{r['r_hat_max']:.3f}, ESS min {r['ess_min']:.0f} ({r['ess_per_min']:.1f}/min), tau max "
                      f"{r['tau_max']:.0f}, acceptance {r['acceptance']:.3f}, {r['calls_per_step']:.1f} sets called a step"
                      + (f", ensembles started again (ensemble, step) {r['restarts']}" if r["restarts"] else ""))
            for k, v in truth.items():
                if k in r["mean"]:
                    print(f"    {k:22s} mean {r['mean'][k]:.4g}  truth {v:.4g}")
            out[f"{name}/{engine}"] = r
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
