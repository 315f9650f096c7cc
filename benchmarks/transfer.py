"""Transfer proof: calibrate the cable on one geometry, predict a clearly different one.

Usage: python benchmarks/transfer.py [--work DIR] [--draws 300] [--seed 0]

1. Calibration geometry: damper1; its recordings are the bundled bench data's dry tests (the virtual
   bench's lognormal-Iwan cable, ``scripts/make_default_data.py``).
2. New geometry :data:`NEW` (lighter masses, other offsets, longer arms; same cable and clamp): the
   same virtual bench records it with the same concealed cable (``make_default_data.config_for``,
   damper1's dry cable) and the same scatter, noise and outlier runs, 24 runs at each of the
   thesis's constant amplitudes. The calibration never sees these recordings.
3. The cable law: ``sbcal cable --damper damper1 --law iwan5`` (the family that fits this cable:
   docs/cable.md), stored under ``DIR/runs`` (reused when there).
4. The new route: :func:`sbcal.design.predict.predict` for NEW at each amplitude (tolerances: the default
   +-5 % on the offsets; bands with the calibration's model discrepancy, the default, and without),
   compared with NEW's run means (outlier runs removed as the calibration removes them; magnitude:
   geometric mean, phase: mean): the share of the lines whose run mean lies inside the 90 % band
   (magnitude, phase, both; every band, of the true curve, widened in quadrature by 1.645 times the run
   mean's own standard error), and the rms error of the median (magnitude %, phase deg).
5. The thesis's route on the same data: one EJ and beta per test of damper1 (``sbcal sample --all``,
   theta1, stored under ``DIR/runs``), the power laws ``EJ(A) = k A^-n`` and ``beta(A) = k A^-n``
   fitted to them by :func:`sbcal.inference.amplitude.fit_law` (what ``sbcal map`` does for EJ; the tests'
   scatter about the law included in the draws), applied at the same base amplitude in the 6-DOF
   model of NEW with the same +-5 % offsets; its band with its own model error too (the per-test
   fit's learned ``sigma_mag``, ``sigma_phase`` at that amplitude, drawn from its posterior), and
   without.
6. Extrapolation: NEW at 4 mm p-p and at 0.1 m/s constant velocity, lines marked.

Prints the table; writes ``DIR/transfer.png`` (prediction against NEW's run means) and
``DIR/transfer_velocity.png``. Slow the first time (the cable fit: tens of minutes on 2 cores).
"""

import argparse
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from sbcal.inference.amplitude import fit_law, points_from_runs  # noqa: E402
from sbcal.data.bench import write_bench
from sbcal.data.cleaning import remove_outlier_runs
from sbcal.data.readers import load_bench  # noqa: E402
from sbcal.model.damper import Damper  # noqa: E402
from sbcal.model.fem import dynamic_stiffness  # noqa: E402
from sbcal.design.predict import predict
from sbcal.design.predict_plots import plot_prediction
from sbcal.design.predict_store import store_prediction  # noqa: E402
from sbcal.simulate.virtual_bench import record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
AMPS = (0.1, 0.2, 0.3, 0.4, 0.5, 1.0, 2.0)
NEW = Damper(name="transfer", m1=2.2, J1=0.0095, a1=0.022, m2=1.5, J2=0.004, a2=-0.012, mc=1.05, Jc=0.0015, ac=0.0,
             L1=0.26, L2=0.17, mu=0.53, ej_static=113.0)
SEED_NEW = 20240521


def _bundled_config():
    spec = importlib.util.spec_from_file_location("make_default_data", ROOT / "scripts" / "make_default_data.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.config_for


def sh(*argv):
    print("$", " ".join(argv), flush=True)
    subprocess.run(argv, check=True)


def record_new(path: Path):
    if path.is_file():
        return load_bench(path)
    config = _bundled_config()("damper1", "1-1")  # damper1's dry cable and the bench's artefacts
    frames = [record(NEW, config, [f"{a:g}-{a:g}"], rng=np.random.default_rng([SEED_NEW, j]))
              for j, a in enumerate(AMPS)]
    write_bench(pd.concat(frames, ignore_index=True), path)
    return load_bench(path)


def run_means(bench, test):
    """Lines, run means (geometric in magnitude) and the run means' standard errors (ln|f|, deg)."""
    td = remove_outlier_runs(bench.test(NEW.name, test)).data
    mag = np.exp(np.nanmean(np.log(td.magnitude), axis=0))  # NaN where a run lacks the line
    phase = np.nanmean(td.phase_deg, axis=0)
    n = np.sum(np.isfinite(td.magnitude), axis=0)
    se = (np.nanstd(np.log(td.magnitude), axis=0, ddof=1) / np.sqrt(n),
          np.nanstd(td.phase_deg, axis=0, ddof=1) / np.sqrt(n))
    return td.freq_hz, mag, phase, se


def thesis_route(runs: Path, draws: int, seed: int):
    """Per amplitude: draws of EJ and beta from the power laws of damper1's per-test posteriors, and of
    that amplitude's test's learned model error (sigma_mag, sigma_phase)."""
    from sbcal.inference.runs import posterior_draws

    keep = lambda t: "oiled" not in t  # noqa: E731
    laws = {name: fit_law(points_from_runs(runs, "damper1", name, include=keep), "powerlaw", seed=seed + i)
            for i, name in enumerate(("EJ", "beta"))}
    sigmas = {r.amplitude: r.draws for r in posterior_draws(runs, "damper1", "theta1", ("sigma_mag", "sigma_phase"))
              if r.amplitude is not None and keep(r.test)}
    rng = np.random.default_rng(seed)
    out = {}
    for a in AMPS:
        vals = []
        for law in laws.values():
            d = law.draws
            i = rng.integers(0, d["k"].size, draws)
            log_mean = np.log(d["k"][i]) - d["n"][i] * np.log(a)
            vals.append(np.exp(log_mean + d["scatter"][i] * rng.standard_normal(draws)))
        j = rng.integers(0, sigmas[a]["sigma_mag"].size, draws)
        out[a] = vals + [sigmas[a]["sigma_mag"][j], sigmas[a]["sigma_phase"][j]]
    return out, {k: {n: float(np.median(v)) for n, v in law.draws.items()} for k, law in laws.items()}


def with_error(fuu, sd_mag, sd_phase, rng, reps=10):
    """Draws of f times independent normal model errors (per draw: its own scales), (reps * S, F)."""
    e = rng.standard_normal((2, reps) + fuu.shape)
    return (fuu[None] * np.exp(e[0] * sd_mag[None, :, None] + 1j * e[1] * sd_phase[None, :, None])).reshape(-1, fuu.shape[1])


def quantiles(fuu):
    q = (0.05, 0.5, 0.95)
    return np.quantile(np.abs(fuu), q, axis=0), np.quantile(np.degrees(np.angle(fuu)), q, axis=0)


def score(freq, q_mag, q_phase, mag, phase, se=None):
    """Coverage of the run means by the 90 % bands and the rms error of the medians. With ``se`` (the run
    means' standard errors, ln|f| and deg) each half-band is widened in quadrature by 1.645 se: the
    bands are of the damper's true curve, a run mean is that curve plus its own noise."""
    lo_m, hi_m = np.log(q_mag[1] / q_mag[0]), np.log(q_mag[2] / q_mag[1])
    lo_p, hi_p = q_phase[1] - q_phase[0], q_phase[2] - q_phase[1]
    if se is not None:
        lo_m, hi_m = (np.hypot(h, 1.645 * se[0]) for h in (lo_m, hi_m))
        lo_p, hi_p = (np.hypot(h, 1.645 * se[1]) for h in (lo_p, hi_p))
    in_m = (np.log(mag / q_mag[1]) >= -lo_m) & (np.log(mag / q_mag[1]) <= hi_m)
    in_p = (phase - q_phase[1] >= -lo_p) & (phase - q_phase[1] <= hi_p)
    return {"mag": in_m.mean(), "phase": in_p.mean(), "both": (in_m & in_p).mean(),
            "rms_mag_pct": 100 * np.sqrt(np.mean((q_mag[1] / mag - 1) ** 2)),
            "rms_phase_deg": np.sqrt(np.mean((q_phase[1] - phase) ** 2))}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="transfer-work", help="work directory (recordings, run store, figures)")
    ap.add_argument("--draws", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    work = Path(args.work)
    runs = work / "runs"
    work.mkdir(parents=True, exist_ok=True)
    bench = record_new(work / "transfer_bench.csv")
    cable = runs / "damper1" / "cable-dry"
    if not (cable / "summary.json").is_file():
        sh(sys.executable, "-m", "sbcal.cli", "cable", "--damper", "damper1", "--law", "iwan5", "--runs", str(runs),
           "--quiet")
    if not list((runs / "damper1").glob("*/theta1/summary.json")):
        sh(sys.executable, "-m", "sbcal.cli", "sample", "--all", "--damper", "damper1", "--runs", str(runs), "--quiet")

    pred = predict(cable, NEW, amplitude_mm_pp=list(AMPS), n_draws=args.draws, seed=args.seed)
    store_prediction(pred, meta={"made_by": "benchmarks/transfer.py"})
    bare = predict(cable, NEW, amplitude_mm_pp=list(AMPS), n_draws=args.draws, seed=args.seed, model_error=False)
    thesis, medians = thesis_route(runs, args.draws, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    offsets = {k: getattr(NEW, k) * (1 + 0.05 * rng.uniform(-1, 1, args.draws)) for k in ("a1", "a2")}
    observed, rows = {}, []
    for i, a in enumerate(AMPS):
        f, mag, phase, se = run_means(bench, f"{a:g}-{a:g}")
        assert np.allclose(f, pred.freq_hz)
        observed[a] = (f, mag, phase)
        new = score(f, pred.stiffness_n_per_m[i], pred.phase_deg[i], mag, phase, se)
        new0 = score(f, bare.stiffness_n_per_m[i], bare.phase_deg[i], mag, phase, se)
        ej, beta, sd_mag, sd_phase = thesis[a]
        fuu = dynamic_stiffness(NEW, f, EJ=ej, beta=beta, **offsets)
        old = score(f, *quantiles(with_error(fuu, sd_mag, sd_phase, rng)), mag, phase, se)
        old0 = score(f, *quantiles(fuu), mag, phase, se)
        rows.append((a, new, new0, old, old0, int(pred.extrapolated[i].sum())))
    plot_prediction(pred, work / "transfer.png", observed=observed)

    print(f"\ncable: {cable} ({pred.law}); new damper {NEW.name}: m1 {NEW.m1}, m2 {NEW.m2} kg, L1 {NEW.L1}, L2 {NEW.L2} m "
          f"(damper1: 3.1, 2.48 kg, 0.20, 0.15 m); {pred.n_draws} draws, seed {args.seed}")
    me = pred.model_error
    print("model discrepancy from the calibration (sd ln|f| / phase deg per amplitude): " + ", ".join(
        f"{a:g} mm {m:.3f} / {p:.2f}" for a, m, p in zip(me["amplitude_mm_pp"], me["logmag_sd"], me["phase_sd_deg"])))
    print(f"thesis route: EJ = {medians['EJ']['k']:.3g} A^-{medians['EJ']['n']:.3f}, "
          f"beta = {medians['beta']['k']:.3g} A^{-medians['beta']['n']:+.3f} (medians)")
    for w in pred.warnings:
        print("warning:", w)

    def cov(r):
        return f"{r['mag']:.0%} / {r['phase']:.0%} / {r['both']:.0%}"

    def err(r):
        return f"{r['rms_mag_pct']:.1f} / {r['rms_phase_deg']:.2f}"

    print("\nrun means of the new damper inside the 90 % band (the cable law's widened by the run means' own "
          "noise): magnitude / phase / both; rms error of the median: magnitude % / phase deg")
    print("| amplitude [mm p-p] | cable law: in band | (without model error) | rms error | thesis route: in band | "
          "(without model error) | rms error | extrapolated lines |")
    print("|---|---|---|---|---|---|---|---|")
    for a, new, new0, old, old0, n_ex in rows:
        print(f"| {a:g} | {cov(new)} | {cov(new0)} | {err(new)} | {cov(old)} | {cov(old0)} | {err(old)} | {n_ex} |")
    mean = [{k: np.mean([r[j][k] for r in rows]) for k in rows[0][1]} for j in range(1, 5)]
    print(f"| all | {cov(mean[0])} | {cov(mean[1])} | {err(mean[0])} | {cov(mean[2])} | {cov(mean[3])} | "
          f"{err(mean[2])} | |")

    # extrapolation marks: beyond the calibration's curvature
    ext = predict(cable, NEW, amplitude_mm_pp=[4.0], n_draws=min(args.draws, 100), seed=args.seed)
    vel = predict(cable, NEW, velocity_m_s=[0.1], n_draws=min(args.draws, 100), seed=args.seed)
    plot_prediction(vel, work / "transfer_velocity.png")
    for p, what in ((ext, "4 mm p-p"), (vel, "0.1 m/s")):
        f = p.freq_hz[p.extrapolated[0]]
        print(f"extrapolated at {what}: {f.size} of {p.freq_hz.size} lines"
              + (f" ({f.min():g}-{f.max():g} Hz)" if f.size else "")
              + f"; largest curvature {np.nanmax(p.curvature_max):.3g} 1/m against the calibrated "
              f"{p.calibrated_curvature[1]:.3g} 1/m")
    print(f"figures: {work / 'transfer.png'}, {work / 'transfer_velocity.png'}")


if __name__ == "__main__":
    main()
