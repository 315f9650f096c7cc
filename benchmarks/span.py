"""Span energy balance: wall time for one conductor, one damper with a posterior, the whole band.

Usage: python benchmarks/span.py [--draws 400] [--freq 60] [--positions 40] [--repeat 5]
                                 [--cable RUN] [--cable-draws 200] [--cable-repeat 2]

Drake (bundled), damper1 through the 6-DOF model with ``--draws`` posterior-like draws of EJ and
beta, ``--freq`` Strouhal frequencies for 1-7 m/s, 90 % bands. Prints the best wall time of
:func:`sbcal.design.span.energy_balance` with the damper beside two baselines measured in the same run:
the same balance without a damper, and one evaluation of the damper's dynamic stiffness over all
draws and frequencies; then one placement sweep (:func:`sbcal.design.placement.optimise_position`).
Target (issue): under a minute on 2 cores for the damper case.

With ``--cable RUN`` (a stored cable fit, e.g. ``runs/damper1/cable-dry`` from ``sbcal cable``, or
``DIR/runs/damper1/cable-dry`` left by ``benchmarks/transfer.py``) also the case ``sbcal span`` runs:
:func:`sbcal.design.span_study.span_study` with the run's own damper, amplitude-dependent, ``--cable-draws``
posterior draws, the whole band, 90 % bands (reading the run, building the impedance, the balance),
and the same with the files written (:func:`sbcal.design.span_study.store_span`: CSV, JSON, figure), against
the same balance with the linear 6-DOF damper at the same number of draws, measured in the same run.
"""

import argparse
import tempfile
import time

import numpy as np

from sbcal.design.conductor import resolve_conductor
from sbcal.model.damper import resolve_damper
from sbcal.design.placement import optimise_position
from sbcal.design.span import FemImpedance, energy_balance
from sbcal.design.span_study import span_study, store_span
from sbcal.design.vibration import strouhal_band

from _timing import best_time  # benchmarks/ is on sys.path when run as a script


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=400)
    ap.add_argument("--freq", type=int, default=60)
    ap.add_argument("--positions", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--cable", metavar="RUN", help="stored cable fit: also time the cable-law damper (sbcal span)")
    ap.add_argument("--cable-draws", type=int, default=200)
    ap.add_argument("--cable-repeat", type=int, default=2)
    args = ap.parse_args()

    c = resolve_conductor("drake")
    z = np.random.default_rng(0).standard_normal((2, args.draws))
    imp = FemImpedance(resolve_damper("damper1"), dict(EJ=20.0 * np.exp(0.2 * z[0]), beta=0.15 * np.exp(0.2 * z[1])))
    freq = strouhal_band(c, (1.0, 7.0), args.freq)[0]
    amp = np.full((1, freq.size), 1e-3)

    t_k = best_time(lambda: imp(freq, amp), args.repeat)
    t_bare = best_time(lambda: energy_balance(c, n_freq=args.freq), args.repeat)
    t_damp = best_time(lambda: energy_balance(c, imp, 1.1, n_freq=args.freq), args.repeat)
    r = energy_balance(c, imp, 1.1, n_freq=args.freq)
    t0 = time.perf_counter()
    p = optimise_position(c, imp, np.linspace(0.2, 2.8, args.positions), n_freq=args.freq)
    t_place = time.perf_counter() - t0

    n = args.draws * args.freq
    print(f"problem      : {c.name}, damper1 x {args.draws} draws, {args.freq} frequencies "
          f"({freq[0]:.1f}-{freq[-1]:.1f} Hz) = {n} balances")
    print(f"K* once      : {t_k * 1e3:8.2f} ms  (6-DOF dynamic stiffness, all draws and frequencies)")
    print(f"bare span    : {t_bare * 1e3:8.2f} ms  (baseline: {args.freq} balances, no damper)")
    print(f"with damper  : {t_damp * 1e3:8.2f} ms  = {t_damp / t_bare:.1f}x the bare span, "
          f"{t_damp / t_k:.0f}x one K* evaluation; {n / t_damp:.3g} balances/s")
    print(f"placement    : {t_place:8.2f} s   ({args.positions} positions; best {p.best_position_m:.2f} m, "
          f"margin q10 {p.best_margin:.2f})")
    print(f"result       : worst-case margin median {np.median(r.margin):.2f} (bare {r.margin_bare:.2f}); "
          f"target < 60 s for the damper case")
    if args.cable:
        _cable_case(c, args)
    else:
        print("cable damper : skipped (give --cable RUN, a stored cable fit)")


def _cable_case(c, args):
    """span_study with the run's own amplitude-dependent damper against the linear damper at as many draws."""
    nd = args.cable_draws
    z = np.random.default_rng(1).standard_normal((2, nd))
    fem = FemImpedance(resolve_damper("damper1"), dict(EJ=20.0 * np.exp(0.2 * z[0]), beta=0.15 * np.exp(0.2 * z[1])))

    def study():
        return span_study(c, args.cable, position_m=1.1, n_freq=args.freq, n_draws=nd)

    t_fem = best_time(lambda: energy_balance(c, fem, 1.1, n_freq=args.freq), args.repeat)
    t_study = best_time(study, args.cable_repeat)
    st = study()
    with tempfile.TemporaryDirectory() as tmp:
        t_store = best_time(lambda: store_span(st, tmp), args.cable_repeat)
    r = st.result
    print(f"cable damper : {st.damper} with its {st.state} cable ({st.law}, {st.cable}), {r.n_draws} draws x "
          f"{args.freq} frequencies = {r.n_draws * args.freq} balances")
    print(f"  linear     : {t_fem:8.2f} s   (baseline: the 6-DOF damper, {nd} draws, same band)")
    print(f"  span_study : {t_study:8.2f} s   = {t_study / t_fem:.0f}x the linear damper; + {t_store:.2f} s to write "
          f"CSV, JSON and figure; target < 60 s")
    m = r.margin
    print(f"  result     : margin median {np.median(m):.3f} [{np.quantile(m, 0.05):.3f}, {np.quantile(m, 0.95):.3f}] "
          f"(bare {r.margin_bare:.3f}); flags: " + ", ".join(f"{k} {v}" for k, v in
                                                               zip(*np.unique(r.flags, return_counts=True))))


if __name__ == "__main__":
    main()
