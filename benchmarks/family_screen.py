"""The family screen against the sampled comparison it stands in for (docs/cable.md, "Families not worth sampling").

Usage: python benchmarks/family_screen.py [--benches bundled:damper1 virtual:bouc_wen ...] [--seed 0] [--workers 2]

For each bench: every compared family's start per cable state (``sbcal.inference.cable_start.screen``), the
screen's verdict, then every family sampled all the same from those starts (the unscreened comparison,
``compare_families``). Prints per family the log-likelihood at the start summed over the states, the ELPD, the
gap at the starts against the ELPD difference to the best converged family, and whether the screen dropped it;
and the wall time of the starts and of each family's fits (the time a screened family saves).

Benches: ``bundled:DAMPER`` (the bundled recordings, dry + oiled), ``virtual:LAW`` (damper1 on the virtual
bench, 0.2/0.5/1/2 mm x 6 runs, seed 7, the cable of :data:`VIRTUAL`).
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sbcal.data.bench import write_bench  # noqa: E402
from sbcal.data.clean_bench import clean_bench  # noqa: E402
from sbcal.data.labels import state_tests  # noqa: E402
from sbcal.data.readers import default_bench_path, load_bench  # noqa: E402
from sbcal.inference.cable_compare import compare_families  # noqa: E402
from sbcal.inference.cable_fit import cable_likelihood, cable_seed, compared_laws, fit_cable  # noqa: E402
from sbcal.inference.cable_start import screen  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.laws import fitted_laws  # noqa: E402
from sbcal.simulate.effects import parse_effect  # noqa: E402
from sbcal.simulate.virtual_bench import BenchConfig, record  # noqa: E402

VIRTUAL = {"bouc_wen": "strand_slip=law:bouc_wen,chi_slip:0.01,delta_EJ:30",
           "iwan5": "strand_slip=law:iwan5,chi_macro:0.02,delta_EJ:30"}
VIRTUAL_TESTS = ["0.2-0.2", "0.5-0.5", "1-1", "2-2"]


def bench_spec(text: str) -> str:
    """``--benches`` entries: ``bundled:DAMPER`` or ``virtual:LAW`` (one line from argparse otherwise)."""
    kind, _, name = text.partition(":")
    if not ((kind == "bundled" and name) or (kind == "virtual" and name in VIRTUAL)):
        raise argparse.ArgumentTypeError(f"{text!r}: expected bundled:DAMPER or virtual:{{{','.join(VIRTUAL)}}}")
    return text


def bench(spec: str):
    kind, name = spec.split(":")
    if kind == "bundled":
        data = clean_bench(load_bench(default_bench_path()), dampers=[name])
        return resolve_damper(name), data, list(data.tests(name))
    damper = resolve_damper("damper1")
    effect, slip = parse_effect(VIRTUAL[name])
    path = Path(tempfile.mkdtemp()) / "bench.csv"
    write_bench(record(damper, BenchConfig(effects={effect: slip}, runs=6), VIRTUAL_TESTS,
                       rng=np.random.default_rng(7)), path)
    return damper, clean_bench(load_bench(path)), VIRTUAL_TESTS


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--benches", nargs="+", type=bench_spec, default=["bundled:damper1", "bundled:damper2", "virtual:bouc_wen",
                                                      "virtual:iwan5"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    for spec in args.benches:
        damper, data, tests = bench(spec)
        groups = state_tests(tests)
        laws = compared_laws(fitted_laws(), tests)
        jobs = {law: {s: (cable_likelihood(damper, data, m, law), cable_seed(args.seed, damper.name, s, law))
                      for s, m in sorted(groups.items())} for law in laws}
        t = time.perf_counter()
        modes, screened = screen(jobs, workers=args.workers)
        t_starts = time.perf_counter() - t
        fits, walls = {}, {}
        for law in laws:
            t = time.perf_counter()
            fits[law] = {s: fit_cable(damper, data, m, law, seed=args.seed, workers=args.workers,
                                      start=modes[law][s].z) for s, m in sorted(groups.items())}
            walls[law] = time.perf_counter() - t
        c = compare_families(fits)
        print(f"{spec}: starts of {len(laws)} families x {len(groups)} states {t_starts:.0f} s; "
              f"best converged {c['best']} (converged {c['converged']})")
        for law in laws:
            ll = sum(m.log_lik for m in modes[law].values())
            f = c["families"][law]
            gap = sum(m.log_lik for m in modes[c["best"]].values()) - ll
            s = screened.get(law)
            word = f"screened below {s['below']} (margin {s['threshold']:.0f})" if s else "kept"
            print(f"  {law:10s} log-lik at the start {ll:10.1f}  ELPD {f['elpd']:10.1f}  gap to {c['best']} at the "
                  f"starts {gap:8.1f}  ELPD difference {-f['delta_elpd']:8.1f} +- {f['se_delta']:.1f}  "
                  f"converged {f['converged']}  fits {walls[law]:.0f} s  {word}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
