"""Harmonic-balance speed: the 2 mm sweep of docs/cable.md's table, the laws' compiled periodic
operators beside their numpy formulation, same run.

Usage: python benchmarks/harmonic_balance.py [--repeat 3] [--reference-repeat 1] [--laws bouc_wen iwan5]

The workload of docs/cable.md, "Beyond the first harmonic": damper1 at 2 mm peak-to-peak, all 37 lines
of the standard grid, ``delta_EJ = 55``, ``EJ_min = 4``, ``beta_material = 0.03`` (viscous, as against
the time integration), ``bouc_wen`` (``chi_slip = 3e-3``, ``n = 2``) with 7 harmonics and ``iwan5``
(``chi_micro = 1e-3``, ``chi_macro = 0.02``, ``c = -0.5``, ``S = 0.1``) with 5, one core. For each law
it prints the first call (the law's tables built: the describing-function table the first-harmonic start
uses, Bouc-Wen's inverse arc), the best wall time of ``HarmonicBalance.state`` on the compiled
operators (sbcal.model.laws.kernels) and on the numpy reference (tests/law_reference.py: the laws'
periodic operators, and Bouc-Wen's steady-loop turning state, as they were), their ratio, and the
worst differences between the two: ``|f_uu / f_uu(numpy) - 1|`` and ``|distortion / distortion(numpy)
- 1|``. Target (the issue): Bouc-Wen's 37 lines <= 10 s (172 s when docs/cable.md's table was made).
The compiled kernels' first call in the process (compile, or load from numba's cache) is printed first.
"""

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core

import numpy as np  # noqa: E402

from sbcal import STANDARD_GRID_HZ  # noqa: E402
from sbcal.model.cable import CableModel  # noqa: E402
from sbcal.model.cable_harmonics import HarmonicBalance  # noqa: E402
from sbcal.model.damper import resolve_damper  # noqa: E402
from sbcal.model.laws import law_for  # noqa: E402

from _timing import best_time  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.law_reference import reference_law  # noqa: E402

AMPLITUDE_MM = 2.0
BASE = dict(EJ_min=4.0, beta_material=0.03, delta_EJ=55.0)
CASES = {  # law: (parameters, harmonics), docs/cable.md's table
    "bouc_wen": (dict(BASE, chi_slip=3e-3, sharpness=2.0), 7),
    "iwan5": (dict(BASE, chi_micro=1e-3, chi_macro=0.02, density_exponent=-0.5, macro_ratio=0.1), 5),
}


def first_kernel_call():
    """Wall time of the first call of every compiled operator (compile, or load from the cache) [s]."""
    theta = 2 * np.pi * np.arange(32) / 32
    chi = (0.02 * (np.cos(theta) + 0.5 * np.cos(3 * theta)))[None]
    dirs = np.ones(chi.shape + (1,))
    t0 = time.perf_counter()
    for name, (params, _) in CASES.items():
        law = law_for(name)
        kw = {k: np.array([[v]]) for k, v in params.items() if k in law.parameter_names}
        law.periodic_moment(chi, dirs, **kw)
        law.loop_branch(chi, chi.max(), **kw)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--reference-repeat", type=int, default=1,
                    help="calls on the numpy reference (~11 s each for bouc_wen)")
    ap.add_argument("--laws", nargs="+", default=list(CASES), choices=list(CASES))
    args = ap.parse_args()

    print(f"first call of the compiled law kernels in this process (compile, or load from numba's cache): "
          f"{first_kernel_call():.2f} s")
    d = resolve_damper("damper1")
    freq = STANDARD_GRID_HZ
    print(f"damper1, {freq.size} lines, {AMPLITUDE_MM:g} mm, one core; best of {args.repeat} (compiled), "
          f"{args.reference_repeat} (numpy)")
    print(f"{'law':10s} {'H':>2s} {'first s':>8s} {'numpy s':>8s} {'compiled s':>10s} {'x numpy':>8s} "
          f"{'|f_uu/numpy-1|':>15s} {'|dist/numpy-1|':>15s}  notes")
    for name in args.laws:
        params, harmonics = CASES[name]
        law = law_for(name)
        hb = HarmonicBalance(CableModel(law=law), harmonics=harmonics, material_loss="viscous")
        ref = HarmonicBalance(CableModel(law=reference_law(law)), harmonics=harmonics, material_loss="viscous")
        t0 = time.perf_counter()
        st = hb.state(d, freq, AMPLITUDE_MM, **params)
        t_first = time.perf_counter() - t0
        t = best_time(lambda: hb.state(d, freq, AMPLITUDE_MM, **params), args.repeat)
        out = {}
        t_ref = best_time(lambda: out.__setitem__("ref", ref.state(d, freq, AMPLITUDE_MM, **params)),
                          args.reference_repeat)
        sr = out["ref"]
        gap = np.max(np.abs(st.f_uu / sr.f_uu - 1))
        dist = np.max(np.abs(st.distortion / sr.distortion - 1))
        inner = int((~st.single_loop).sum())
        print(f"{name:10s} {harmonics:2d} {t_first:8.2f} {t_ref:8.2f} {t:10.2f} {t_ref / t:8.1f} {gap:15.1e}"
              f" {dist:15.1e}"
              f"  converged {int(st.converged.sum())}/{freq.size} (numpy {int(sr.converged.sum())}), "
              f"{inner} lines with inner loops, {st.iterations} Newton iterations (numpy {sr.iterations}), "
              f"distortion max {np.max(st.distortion):.3f}")


if __name__ == "__main__":
    main()
