"""``sbcal import`` of a large TDMS file: wall time and peak memory against reading the file once.

Usage: python benchmarks/import_tdms.py [--gb 1.0] [--rate 10000] [--keep DIR]

Writes a TDMS file of four float64 channels (Force A, Force B, Table acceleration, Drive frequency) holding a
stepped sine over the 37 standard lines (a linear damper's force with 5 % third and 2 % fifth harmonics,
sensor noise and offsets, a ramp into every dwell and a pause after it), in segments of 2**16 samples as a
LabVIEW logger writes them; then, each in its own process, times

- the baseline: every channel read once through npTDMS's streaming reader, in slices of 2**20 samples
  (the least any importer must do);
- ``sbcal import FILE --map channels.toml -o out.csv`` (the command a user runs);

and prints wall times, their ratio, each process's peak resident memory, and the worst line's error against
the synthetic truth. The issue's target: 1 GB imported in <= 60 s with <= 500 MB on 2 cores.
"""

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sbcal.model.fem import STANDARD_GRID_HZ

CHANNELS = ("Force A", "Force B", "Table acceleration", "Drive frequency")
SEGMENT = 2 ** 16
X0 = 1e-3  # base amplitude [m] (2 mm p-p)
MAP = """[labels]
damper = "damper1"
test = "2-2"
run = 1

[force]
channels = ["Force A", "Force B"]
unit = "N"

[base]
channel = "Table acceleration"
quantity = "acceleration"
unit = "m/s^2"

[frequency]
source = "channel"
channel = "Drive frequency"

[amplitude]
mm_pp = 2.0
"""


def truth(f):
    """A damper-like dynamic stiffness [N/m]: a mass-spring with loss, resonant at 12 Hz."""
    w = 2 * np.pi * f
    return 4000.0 * (1 + 0.2j) * (2 * np.pi * 12) ** 2 / ((2 * np.pi * 12) ** 2 * (1 + 0.2j) - w ** 2) * 1.0


def write_file(path: Path, gb: float, rate: float, seed: int = 0):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    rng = np.random.default_rng(seed)
    n_total = int(gb * 2 ** 30 / (8 * len(CHANNELS)))
    f = STANDARD_GRID_HZ
    per_dwell = n_total // f.size
    pause = int(0.25 * rate)
    props = {"wf_increment": 1.0 / rate, "wf_start_offset": 0.0}
    units = {"Force A": "N", "Force B": "N", "Table acceleration": "m/s^2", "Drive frequency": "Hz"}
    with TdmsWriter(str(path)) as w:
        w.write_segment([RootObject({"damper": "damper1"}), GroupObject("stepped_sine")])
        written = 0
        for k, fk in enumerate(f):
            n = per_dwell if k < f.size - 1 else n_total - written
            w_k = 2 * np.pi * fk
            h = truth(fk)
            ramp = int(8 * rate / fk)
            for lo in range(0, n, SEGMENT):
                i = np.arange(lo, min(lo + SEGMENT, n))
                t = i / rate
                on = i < n - pause
                env = np.where(on, np.clip(i / ramp, 0, 1), 0.0)
                x = X0 * env * np.cos(w_k * t)
                a = -w_k ** 2 * x
                force = env * X0 * np.abs(h) * (np.cos(w_k * t + np.angle(h)) + 0.05 * np.cos(3 * w_k * t + 0.3)
                                                + 0.02 * np.cos(5 * w_k * t - 0.7))
                chans = {"Force A": 0.55 * force, "Force B": 0.45 * force, "Table acceleration": a,
                         "Drive frequency": np.where(on, fk, 0.0)}
                for name in CHANNELS[:3]:
                    chans[name] = chans[name] + 1e-3 * np.std(chans[name]) * rng.standard_normal(i.size) + 0.01
                w.write_segment([ChannelObject("stepped_sine", name, chans[name],
                                               properties=dict(props, unit_string=units[name])) for name in CHANNELS])
            written += n
    return n_total


BASELINE = """
import sys
from nptdms import TdmsFile
with TdmsFile.open(sys.argv[1]) as f:
    for ch in f["stepped_sine"].channels():
        n = len(ch)
        for lo in range(0, n, 2 ** 20):
            ch[lo:min(lo + 2 ** 20, n)].sum()
"""


IMPORT = """
import sys
from sbcal.cli import main
rc = main(["import", sys.argv[1], "--map", sys.argv[2], "-o", sys.argv[3], "--quiet"])
if rc:
    raise SystemExit(rc)
"""

def drop_caches() -> bool:
    """Empty the page cache (root on Linux) so the next read comes from the disk; False where not allowed."""
    try:
        subprocess.run(["sync"], check=True)
        Path("/proc/sys/vm/drop_caches").write_text("3\n")
        return True
    except OSError:
        return False


def timed(code, *argv, cold=False):
    """Wall time [s] and peak RSS [MB] of ``python -c code argv...`` in its own process (its own
    ``ru_maxrss``, printed by the process itself as it exits)."""
    wrapped = code + "\nimport resource\nprint('PEAK', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    if cold and not drop_caches():
        raise SystemExit("--cold: cannot drop the page cache here (needs root on Linux)")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", wrapped, *map(str, argv)], capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"failed ({out.returncode}): {out.stderr.strip()}")
    wall = time.perf_counter() - t0
    peak = [line for line in out.stdout.splitlines() if line.startswith("PEAK")][-1].split()[1]
    return wall, int(peak) / 1024


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gb", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=10000.0)
    ap.add_argument("--keep", metavar="DIR", help="write the file here and keep it")
    ap.add_argument("--cold", action="store_true", help="drop the page cache before each timed process (root)")
    ap.add_argument("--source", choices=("channel", "signal"), default="channel",
                    help="where the dwells' frequencies come from: the drive channel or the base signal itself")
    args = ap.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="sbcal-import-"))
    root.mkdir(parents=True, exist_ok=True)
    path = root / "big.tdms"
    t0 = time.perf_counter()
    n = write_file(path, args.gb, args.rate)
    print(f"wrote {path}: {path.stat().st_size / 2**30:.2f} GiB, {n} samples x {len(CHANNELS)} channels at "
          f"{args.rate:g} Hz ({n / args.rate / 60:.0f} min), {time.perf_counter() - t0:.0f} s")
    cmap = MAP if args.source == "channel" else MAP.replace('source = "channel"\nchannel = "Drive frequency"',
                                                             'source = "signal"')
    (root / "channels.toml").write_text(cmap)
    # each in a fresh process
    base_s, base_mb = timed(BASELINE, path, cold=args.cold)
    imp_s, imp_mb = timed(IMPORT, path, root / "channels.toml", root / "out.csv", cold=args.cold)
    import pandas as pd

    out = pd.read_csv(root / "out.csv")
    h = out["stiffness_n_per_m"] * np.exp(1j * np.radians(out["phase_deg"]))
    err = np.abs(h / truth(out["frequency_hz"].to_numpy()) - 1)
    print(f"dwell frequencies from the {'drive channel' if args.source == 'channel' else 'base signal'}")
    print(f"page cache: {'dropped before each (cold reads)' if args.cold else 'warm (the file just written)'}")
    print(f"baseline (read every channel once): {base_s:.1f} s, peak {base_mb:.0f} MB")
    print(f"sbcal import: {imp_s:.1f} s ({imp_s / base_s:.1f} x the baseline), peak {imp_mb:.0f} MB; "
          f"{len(out)} lines, worst |h / truth - 1| {err.max():.1e}")
    print(f"target: <= 60 s and <= 500 MB: {'met' if imp_s <= 60 and imp_mb <= 500 else 'NOT met'}")
    if not args.keep:
        path.unlink()


if __name__ == "__main__":
    main()
