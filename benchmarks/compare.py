"""``sbcal compare`` of two stored calibrations: wall time, against one test's calibration as the baseline.

Two virtual-bench recordings of damper1 (test 1-1, 24 runs; strand slip, a 10 % stiffness loss between them)
are calibrated once from their bench files (the baseline: one test's posterior, measured here), then
``sbcal compare`` of the two stored calibrations runs as a user runs it (a new process, Python's start and
imports included), three times; the target is <= 30 s on 2 cores.

    python benchmarks/compare.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from compare_matrix import BASE, DAMPER, changed  # the matrix's bench, one source of truth

    from sbcal.pipeline import Settings, calibrate_bench
    from sbcal.simulate.virtual_bench import record

    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        rng = np.random.default_rng(38)
        stores = []
        cal = []
        for name, cfg in (("before", BASE), ("after", changed("stiffness", 0.10))):
            path = t / f"{name}.csv"
            record(DAMPER, cfg, ["1-1"], rng=rng).to_csv(path, index=False)
            t0 = time.perf_counter()
            store, damper = calibrate_bench(path, "dry", runs=t / "runs", settings=Settings(seed=1, workers=1))
            cal.append(time.perf_counter() - t0)
            stores.append(str(Path(store) / damper))
        walls = []
        for k in range(3):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "sbcal.cli", "compare", "--before", stores[0], "--after", stores[1],
                            "--spec", "example", "--quiet", "-o", str(t / f"out{k}")], check=True,
                           stdout=subprocess.DEVNULL)
            walls.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import sbcal.cli.app"], check=True)
        startup = time.perf_counter() - t0
    base = float(np.mean(cal))
    best = min(walls)
    print(f"calibration of one bench file (clean + sample, the baseline): {base:.1f} s (mean of 2)")
    print(f"sbcal compare of the two stored calibrations: {best:.1f} s best of 3 ({', '.join(f'{w:.1f}' for w in walls)}); "
          f"{best / base:.2f}x the baseline; Python start and sbcal's imports {startup:.1f} s of it; target <= 30 s")


if __name__ == "__main__":
    main()
