"""``sbcal batch`` on a stored lot of 12 units, beside what one unit's calibration costs.

Usage: python benchmarks/batch.py [--units 12] [--tests 0.2-0.2 2-2] [--seed 3] [--json OUT]

Records a virtual lot (damper1's design with strand slip, EJ 5 %, loss factor 10 %, slip scale 10 %), calibrates
every unit's tests with ``sbcal run --design damper1 --until sample`` (not timed as the batch: it is the
per-unit work a lab has already done), then times ``sbcal batch`` on the store (idle machine, 2 cores). The
baseline in the same run: the median wall time of one unit-test calibration from the stored summaries, so
the population's cost reads as "so many per-test calibrations" on any machine. Target (issue 39): 12 units
in <= 60 s.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from sbcal.cli.app import main as sbcal

SLIP = "strand_slip=law:lognormal_iwan,chi_median:0.006,log_spread:2.1,delta_EJ:42"


def run(units: int, tests, seed: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        bench = root / "lot.csv"
        assert sbcal(["bench", "--damper", "damper1", "--units", str(units), "--tests", *tests, "--runs-per-test", "10",
                      "--effect", SLIP, "--set", "EJ=4.4", "--set", "beta=0.11", "--seed", str(seed),
                      "-o", str(bench)]) == 0
        runs = root / "runs"
        t0 = time.perf_counter()
        assert sbcal(["run", "--bench", str(bench), "--design", "damper1", "--until", "sample", "--runs", str(runs),
                      "--quiet"]) == 0
        calibrate = time.perf_counter() - t0
        per_test = [json.loads(p.read_text())["wall_s"] for p in runs.glob("*/*/theta1/summary.json")]
        t0 = time.perf_counter()
        assert sbcal(["batch", "--runs", str(runs), "--quiet", "--seed", str(seed)]) == 0
        batch = time.perf_counter() - t0
        doc = json.loads((runs / "batch" / "summary.json").read_text())
    unit_test = statistics.median(per_test)
    return {"units": units, "tests": list(tests), "batch_s": batch, "calibrate_all_s": calibrate,
            "unit_test_sampler_s": unit_test, "batch_over_unit_test": batch / unit_test,
            "hyper_steps": doc["n_steps"], "converged": doc["converged"], "dims": len(doc["population"])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=12)
    ap.add_argument("--tests", nargs="+", default=["0.2-0.2", "2-2"])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    r = run(args.units, args.tests, args.seed)
    print(f"sbcal batch, {r['units']} units x {len(r['tests'])} tests ({r['dims']} population dimensions): "
          f"{r['batch_s']:.1f} s ({r['hyper_steps']} steps, converged {r['converged']}); one unit-test's sampler "
          f"{r['unit_test_sampler_s']:.1f} s (ratio {r['batch_over_unit_test']:.1f}); calibrating the lot "
          f"{r['calibrate_all_s']:.0f} s; target <= 60 s: {'met' if r['batch_s'] <= 60 else 'NOT met'}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
