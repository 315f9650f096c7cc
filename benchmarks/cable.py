"""Cable forward-model speed: the fast model's compiled kernel beside its numpy formulation, the
element model and SlipModel, same run.

Usage: python benchmarks/cable.py [--sets 16 32] [--repeat 7] [--element-repeat 2] [--no-element] [--zoned]
       [--tests N]

The workload the sampler sees: parameter sets x the thesis's eight dry tests concatenated on the
frequency axis (8 x 37 = 296 lines, each test's amplitude per line; ``--tests 1``: one test's 37, a one-test
fit's), one core. For each model it prints the best wall time of one ``dynamic_stiffness`` call,
evaluations (sets x lines) per second, and the ratio to the old one-element ``SlipModel``
(benchmarks/_slip_baseline.py: one element per arm at its rms curvature, 12 Illinois steps) measured in the
same run. ``CableModel`` is the compiled kernel (sbcal.model.cable_kernel) with the Iwan laws compiled
(sbcal.model.laws.iwan_kernel), ``numpy`` the same model on the numpy formulations they replaced
(tests/cable_reference.py, tests/law_reference.py; the table's bucket walk is compiled in both): their ratio
is the kernels' gain, and their largest difference in ``f_uu`` is printed. Targets (the kernel issue):
>= 5x on the numpy formulation, <= 4 ms for 16 sets x 296 lines. Then, at the first ``--sets``, where the
time goes in each: the compliance table, the arm constants, the one-compliance start and Newton (mean and
largest iterations per entry); and a fit's sets (near one another, as a posterior's), solved from the slipped
cable and from one set's loads, as a fit's cable model starts them (``CableForward.near``).
The first call's compile time (or cache load) is printed first.
"""

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target says

import numpy as np  # noqa: E402

from sbcal import STANDARD_GRID_HZ  # noqa: E402
from sbcal.model.cable import CableModel, _resolve
from sbcal.model.cable_element import ElementCableModel
from sbcal.model.damper import resolve_damper  # noqa: E402
from _slip_baseline import SlipModel  # noqa: E402
from sbcal.model.laws import DahlLaw, IwanLaw, LognormalIwanLaw, law_for  # noqa: E402
from sbcal.simulate.virtual_bench import DEFAULT_TESTS, test_amplitude  # noqa: E402

from _timing import best_time  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.cable_reference import NumpyCableModel  # noqa: E402
from tests.law_reference import reference_law  # noqa: E402


def workload(d, n, seed=0):
    """Random parameter sets of each law (boxes like priors/cable.toml's) and SlipModel's."""
    rng = np.random.default_rng(seed)
    geometry = dict(a1=d.a1 * rng.uniform(0.95, 1.05, n), a2=d.a2 * rng.uniform(0.95, 1.05, n))
    base = dict(EJ_min=rng.uniform(3, 7, n), beta_material=rng.uniform(0.02, 0.1, n), **geometry)
    loguniform = lambda lo, hi: np.exp(rng.uniform(np.log(lo), np.log(hi), n))  # noqa: E731
    laws = {
        "dahl": (DahlLaw(), dict(base, delta_EJ=rng.uniform(30, 60, n), chi_dahl=loguniform(1e-3, 5e-3))),
        "iwan": (IwanLaw(), dict(base, delta_EJ=rng.uniform(30, 60, n), chi_macro=loguniform(5e-3, 5e-2),
                                 micro_exponent=rng.uniform(-0.7, 0.0, n), macro_ratio=rng.uniform(0.0, 0.5, n))),
        "lognormal_iwan": (LognormalIwanLaw(), dict(base, delta_EJ=rng.uniform(30, 60, n),
                                                    chi_median=loguniform(1e-3, 5e-3), log_spread=1.5)),
        # the law sbcal fits most (its describing function compiled: sbcal.model.laws.iwan_kernel)
        "iwan5": (law_for("iwan5"), dict(base, delta_EJ=rng.uniform(30, 60, n), chi_micro=loguniform(1e-6, 1e-4),
                                         chi_macro=loguniform(5e-3, 5e-2), density_exponent=rng.uniform(-1.5, 0.5, n),
                                         macro_ratio=rng.uniform(0.0, 0.5, n))),
    }
    slip = dict(EJ_slip=rng.uniform(3, 7, n), EJ_stick=rng.uniform(30, 60, n), chi_slip=loguniform(1e-3, 5e-3),
                slip_exponent=rng.uniform(0.8, 2, n), beta_material=rng.uniform(0.02, 0.1, n),
                beta_friction=rng.uniform(0.2, 0.5, n), **geometry)
    return laws, slip


def breakdown(model, d, freq, amp, params, repeat):
    """Best wall time of each phase of the fast model's solve [s], and the Newton's iteration counts."""
    p, n_sets = _resolve(model.parameter_names, (), d, params)
    omega, x0 = 2 * np.pi * freq, amp / 2 * 1e-3
    table = model._table(p, n_sets)
    rule = model._zone_rule(p, n_sets) if model.zoned else None
    arms = model._arms(p, n_sets, omega, x0, rule)
    start = model._start(table, arms)
    sol = model._newton(table, arms, start)
    times = {
        "compliance table": best_time(lambda: model._table(p, n_sets), repeat),
        "arm constants": best_time(lambda: model._arms(p, n_sets, omega, x0, rule), repeat),
        "one-compliance start": best_time(lambda: model._start(table, arms), repeat),
        "Newton (all iterations)": best_time(lambda: model._newton(table, arms, start), repeat),
    }
    return times, sol[2]


def zoned_workload(d, n, seed=1):
    """Random sets of the zoned Iwan law (iwan5_zoned; boxes around benchmarks/zones_identifiability.py's truth)."""
    rng = np.random.default_rng(seed)
    u = lambda lo, hi: rng.uniform(lo, hi, n)  # noqa: E731
    params = dict(EJ_min=u(3, 7), beta_material=u(0.02, 0.1), delta_EJ=u(30, 60),
                  chi_micro=np.exp(u(np.log(1e-5), np.log(5e-5))), chi_macro=np.exp(u(np.log(5e-3), np.log(2e-2))),
                  density_exponent=u(-0.9, -0.5), macro_ratio=u(0.1, 0.3),
                  clamp_zone=u(0.1, 0.3), clamp_EJ_min_ratio=u(1.5, 2.5), clamp_delta_EJ_ratio=u(2, 3),
                  clamp_moment_ratio=u(5, 10), mass_zone=u(0.05, 0.15), mass_EJ_min_ratio=u(1.2, 1.8),
                  mass_delta_EJ_ratio=u(1.2, 1.8), mass_moment_ratio=u(2, 4))
    return law_for("iwan5_zoned"), params


def near_workload(params, n, seed=2):
    """``n`` sets within ~2 % (log-normal) of the first set of ``params`` in every parameter, and that set."""
    rng = np.random.default_rng(seed)
    one = {k: np.atleast_1d(v)[:1] for k, v in params.items()}
    near = {k: v * np.exp(0.02 * rng.standard_normal(n)) if np.size(params[k]) > 1 else params[k] for k, v in one.items()}
    return near, {k: v if np.size(params[k]) > 1 else params[k] for k, v in one.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--element-repeat", type=int, default=2)
    ap.add_argument("--no-element", action="store_true", help="skip the (slow) element model")
    ap.add_argument("--zoned", action="store_true", help="also the zoned Iwan law (iwan5_zoned)")
    ap.add_argument("--tests", type=int, default=len(DEFAULT_TESTS), choices=range(1, len(DEFAULT_TESTS) + 1),
                    metavar="N", help="the first N dry tests, 1-%(default)s (1: a one-test fit's 37 lines, an oiled "
                                      "state or a per-test diagnosis)")
    args = ap.parse_args()

    d = resolve_damper("damper1")
    tests = DEFAULT_TESTS[:args.tests]
    freq = np.concatenate([STANDARD_GRID_HZ] * len(tests))
    amp = np.concatenate([test_amplitude(t, STANDARD_GRID_HZ) for t in tests])
    slip_model = SlipModel(amp)
    t0 = time.perf_counter()
    CableModel(IwanLaw()).dynamic_stiffness(d, freq[:2], amp[:2], **workload(d, 1)[0]["iwan"][1])
    print(f"first call of the compiled kernel in this process (compile, or load from numba's cache): "
          f"{time.perf_counter() - t0:.2f} s")
    print(f"{freq.size} lines (the first {len(tests)} of the dry tests), damper1, one core; best of {args.repeat}")
    print(f"{'model':40s} {'sets':>5s} {'ms/call':>9s} {'evals/s':>10s} {'x SlipModel':>12s} {'x numpy':>8s}  notes")
    for n in args.sets:
        laws, slip = workload(d, n)
        if args.zoned:
            laws["iwan5_zoned"] = zoned_workload(d, n)
        evals = n * freq.size
        t_ref = best_time(lambda: slip_model(d, freq, **slip), args.repeat)
        print(f"{'SlipModel (1 element, rms)':40s} {n:5d} {t_ref * 1e3:9.1f} {evals / t_ref:10.3g} {1.0:12.2f}")
        for name, (law, params) in laws.items():
            fast, slow = CableModel(law), NumpyCableModel(reference_law(law))
            st = fast.state(d, freq, amp, **params)
            gap = np.nanmax(np.abs(fast.dynamic_stiffness(d, freq, amp, **params)
                                   / slow.dynamic_stiffness(d, freq, amp, **params) - 1))
            t_np = best_time(lambda: slow.dynamic_stiffness(d, freq, amp, **params), args.repeat)
            t = best_time(lambda: fast.dynamic_stiffness(d, freq, amp, **params), args.repeat)
            label = f", Q={fast.sections}" + (f"+2x{fast.zone_sections}" if fast.zoned else "")
            print(f"{'numpy ' + name + label:40s} {n:5d} {t_np * 1e3:9.1f} {evals / t_np:10.3g} {t_ref / t_np:12.2f}"
                  f" {1.0:8.2f}")
            print(f"{'CableModel ' + name + label:40s} {n:5d} {t * 1e3:9.1f} {evals / t:10.3g} {t_ref / t:12.2f}"
                  f" {t_np / t:8.2f}  converged {st.converged.mean():.4f}, |f_uu / numpy - 1| <= {gap:.1e}")
        if not args.no_element:
            law, params = laws["dahl"]
            element = ElementCableModel(law)
            t = best_time(lambda: element.dynamic_stiffness(d, freq, amp, **params), args.element_repeat)
            print(f"{'ElementCableModel dahl, N=' + str(element.n_elements):40s} {n:5d} {t * 1e3:9.1f}"
                  f" {evals / t:10.3g} {t_ref / t:12.2f}")

    n = args.sets[0]
    laws, _ = workload(d, n)
    if args.zoned:
        laws["iwan5_zoned"] = zoned_workload(d, n)
    print(f"\na fit's sets ({n} within ~2 % of one set in every parameter, as a posterior's lie about its mode; "
          f"{freq.size} lines; best of {args.repeat}): Newton from the slipped cable, and from that set's loads as a "
          "fit starts it (CableForward.near)")
    print(f"{'model':40s} {'sets':>5s} {'slipped ms':>11s} {'near ms':>8s} {'x':>6s}  |near / slipped - 1|")
    for name, (law, params) in laws.items():
        near, one = near_workload(params, n)
        fast = CableModel(law)
        start = fast.loads(d, freq, amp, **one)
        t_cold = best_time(lambda: fast.dynamic_stiffness(d, freq, amp, **near), args.repeat)
        t_near = best_time(lambda: fast.dynamic_stiffness(d, freq, amp, start=start, **near), args.repeat)
        gap = np.nanmax(np.abs(fast.dynamic_stiffness(d, freq, amp, start=start, **near)
                               / fast.dynamic_stiffness(d, freq, amp, **near) - 1))
        print(f"{'CableModel ' + name:40s} {n:5d} {t_cold * 1e3:11.1f} {t_near * 1e3:8.1f} {t_cold / t_near:6.2f}  "
              f"{gap:.1e}")
    print(f"\nwhere the fast model's time goes ({n} sets, {freq.size} lines; best of {args.repeat}; numpy / compiled):")
    for name, (law, params) in laws.items():
        times, its = breakdown(CableModel(law), d, freq, amp, params, args.repeat)
        ref, _ = breakdown(NumpyCableModel(reference_law(law)), d, freq, amp, params, args.repeat)
        print(f"  {name}: Newton iterations per entry mean {its.mean():.2f}, largest {its.max()}")
        for phase, t in times.items():
            print(f"    {phase:34s} {ref[phase] * 1e3:7.2f} / {t * 1e3:7.2f} ms")


if __name__ == "__main__":
    main()
