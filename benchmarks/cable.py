"""Distributed-cable forward model speed, against the one-element strand-slip model in the same run.

Usage: python benchmarks/cable.py [--sets 32] [--repeat 5] [--elements 4]

The workload the sampler sees: ``--sets`` parameter sets (half an ensemble) x the thesis's eight dry
tests concatenated on the frequency axis (8 x 37 = 296 lines, each test's amplitude per line).
Prints the wall time of one call, evaluations (parameter sets x lines) per second, and the ratio to
:class:`sbcal.extensions.SlipModel` (one element per arm at its rms curvature, 12 Illinois steps).
Target (the cable issue): ~10-20 ms per call of 32 x 300 on one core.
"""

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from sbcal import STANDARD_GRID_HZ  # noqa: E402
from sbcal.cable import CableModel  # noqa: E402
from sbcal.damper import resolve_damper  # noqa: E402
from sbcal.extensions import SlipModel  # noqa: E402
from sbcal.hysteresis import DahlLaw, IwanLaw  # noqa: E402
from sbcal.virtual_bench import DEFAULT_TESTS, test_amplitude  # noqa: E402

from _timing import best_time  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--elements", type=int, default=None, help="elements per arm (default: the model's)")
    args = ap.parse_args()

    d = resolve_damper("damper1")
    rng = np.random.default_rng(0)
    n = args.sets
    freq = np.concatenate([STANDARD_GRID_HZ] * len(DEFAULT_TESTS))
    amp = np.concatenate([test_amplitude(t, STANDARD_GRID_HZ) for t in DEFAULT_TESTS])
    geometry = dict(a1=d.a1 * rng.uniform(0.95, 1.05, n), a2=d.a2 * rng.uniform(0.95, 1.05, n))
    base = dict(EJ_min=rng.uniform(3, 7, n), beta_material=rng.uniform(0.02, 0.1, n), **geometry)
    kw = {} if args.elements is None else {"n_elements": args.elements}
    cases = {
        "dahl": (CableModel(DahlLaw(), **kw),
                 dict(base, delta_EJ=rng.uniform(30, 60, n), chi_dahl=np.exp(rng.uniform(np.log(1e-3), np.log(5e-3), n)))),
        "iwan": (CableModel(IwanLaw(), **kw),
                 dict(base, delta_EJ=rng.uniform(30, 60, n), chi_macro=np.exp(rng.uniform(np.log(5e-3), np.log(5e-2), n)),
                      micro_exponent=rng.uniform(-0.7, 0.0, n), macro_ratio=rng.uniform(0.0, 0.5, n))),
    }
    slip = SlipModel(amp)
    slip_params = dict(EJ_slip=rng.uniform(3, 7, n), EJ_stick=rng.uniform(30, 60, n),
                       chi_slip=np.exp(rng.uniform(np.log(1e-3), np.log(5e-3), n)), slip_exponent=rng.uniform(0.8, 2, n),
                       beta_material=rng.uniform(0.02, 0.1, n), beta_friction=rng.uniform(0.2, 0.5, n), **geometry)
    evals = n * freq.size
    t_ref = best_time(lambda: slip(d, freq, **slip_params), args.repeat)
    print(f"workload: {n} sets x {freq.size} lines = {evals} evaluations per call, one core")
    print(f"{'model':32s} {'ms/call':>9s} {'evals/s':>11s} {'x SlipModel':>12s}")
    print(f"{'SlipModel (1 element, rms)':32s} {t_ref * 1e3:9.1f} {evals / t_ref:11.3g} {1.0:12.2f}")
    for name, (model, params) in cases.items():
        st = model.state(d, freq, amp, **params)
        t = best_time(lambda: model.dynamic_stiffness(d, freq, amp, **params), args.repeat)
        label = f"CableModel {name}, N={model.n_elements}"
        print(f"{label:32s} {t * 1e3:9.1f} {evals / t:11.3g} {t_ref / t:12.2f}"
              f"   (converged {st.converged.mean():.3f}, fold lines {int(st.fold.sum())}, iterations {st.iterations})")


if __name__ == "__main__":
    main()
