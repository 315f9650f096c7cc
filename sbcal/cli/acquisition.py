"""``sbcal import``: raw recordings of the data acquisition system to a bench file (``docs/import.md``)."""

from __future__ import annotations

import sys

from .options import quiet_option


__all__ = ["add_import", "cmd_import"]


def add_import(sub):
    p = sub.add_parser("import", help="raw time series (TDMS, HDF5, MDF4, CSV) to a bench CSV with measured noise",
                       description="Read the stepped-sine time series a shaker's acquisition recorded, find each "
                                   "dwell, check it settled, and write its first harmonics as bench lines with the "
                                   "standard error from the period-to-period variation, the force's harmonic "
                                   "distortion and the amplitude achieved (docs/import.md).")
    p.add_argument("raw", nargs="+", metavar="RAW",
                   help="recordings: .tdms, .h5/.hdf5, .mf4/.mdf, .csv; .uff/.unv frequency response functions")
    p.add_argument("--map", required=True, metavar="CHANNELS.toml",
                   help="the channel map: force and base channels, units, the dwells' frequency source, labels")
    p.add_argument("--fixture", nargs="+", default=(), metavar="RAW",
                   help="recordings of the bare fixture (no damper): its complex force per line is subtracted")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv", help="the bench CSV to write")
    quiet_option(p)
    return p


def cmd_import(args) -> int:
    from ..data.acquisition import import_recordings, load_channel_map, write_import

    cmap = load_channel_map(args.map)
    result = import_recordings(args.raw, cmap, fixture=args.fixture, quiet=args.quiet)
    write_import(result, args.output)
    for line in result.warnings:
        print(f"sbcal: warning: {line}", file=sys.stderr)
    f = result.frame
    print(f"imported {len(args.raw)} file(s): {len(f)} lines, {f.groupby(['damper', 'test', 'run']).ngroups} run(s); "
          f"{len(result.warnings)} warning(s)")
    for (damper, test), g in f.groupby(["damper", "test"], sort=False):
        se = (g["stiffness_se_n_per_m"] / g["stiffness_n_per_m"]).median()
        print(f"  {damper} {test}: runs {','.join(map(str, sorted(g['run'].unique())))}, "
              f"{g['frequency_hz'].min():g}-{g['frequency_hz'].max():g} Hz, median SE {100 * se:.3g} % / "
              f"{g['phase_se_deg'].median():.3g} deg, largest distortion {100 * g['distortion'].max():.3g} %")
    print(f"wrote {args.output}")
    return 0
