"""The ``sbcal`` command line: a thin adapter over the library.

Each subcommand is a pair ``_add_<name>(subparsers)`` / ``_cmd_<name>(args) -> int``; bad input
ends in one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from . import __version__
from .errors import InputError

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message}")


def _parse_set(items) -> dict:
    """``["EJ=9", "beta=0.3"]`` -> ``{"EJ": 9.0, "beta": 0.3}``, names checked against the model."""
    from .fem import PARAMETER_NAMES

    out = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        if name not in PARAMETER_NAMES:
            raise InputError(f"--set {item!r}: unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}")
        try:
            x = float(value)
        except ValueError:
            raise InputError(f"--set {item!r}: {value!r} is not a number") from None
        if not np.isfinite(x):
            raise InputError(f"--set {item!r}: value is not finite")
        out[name] = x
    return out


def _parse_frequencies(text: str) -> np.ndarray:
    from .fem import STANDARD_GRID_HZ

    if text == "standard":
        return STANDARD_GRID_HZ.copy()
    try:
        f = np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise InputError(f"--frequencies {text!r}: expected 'standard' or comma-separated numbers [Hz]") from None
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"--frequencies {text!r}: frequencies must be finite and > 0")
    return f


# --- simulate ----------------------------------------------------------------------------------

def _add_simulate(sub):
    p = sub.add_parser("simulate", help="write the model's prediction as a bench CSV",
                       description="Evaluate the forward model and write f_uu as a bench CSV (run = 1).")
    p.add_argument("--damper", required=True, help="bundled damper name or TOML path")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter value (repeatable)")
    p.add_argument("--amplitude", type=float, default=1.0, metavar="MM", help="amplitude [mm p-p] (default 1)")
    p.add_argument("--test", metavar="LABEL", help="test label (default: from the amplitude, e.g. 1-1)")
    p.add_argument("--frequencies", default="standard", metavar="standard|LIST",
                   help="'standard' (37 lines, 4-40 Hz) or comma-separated Hz")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    return p


def _cmd_simulate(args) -> int:
    from .bench import curves_to_frame, test_label, write_bench
    from .damper import resolve_damper
    from .fem import dynamic_stiffness

    damper = resolve_damper(args.damper)
    params = _parse_set(args.set)
    freq = _parse_frequencies(args.frequencies)
    if not (np.isfinite(args.amplitude) and args.amplitude > 0):
        raise InputError(f"--amplitude {args.amplitude}: must be > 0")
    fuu = dynamic_stiffness(damper, freq, **params)
    test = args.test or test_label(args.amplitude)
    write_bench(curves_to_frame(damper.name, test, freq, args.amplitude, fuu), args.output)
    print(f"wrote {args.output}: {damper.name} {test}, {freq.size} lines")
    return 0


# One line per subcommand; each helper pair lives above, in the order of this table.
_COMMANDS = {
    "simulate": (_add_simulate, _cmd_simulate),
}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sbcal", description="Bayesian calibration of Stockbridge dampers.")
    parser.add_argument("--version", action="version", version=f"sbcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for add, _ in _COMMANDS.values():
        add(sub)
    return parser


def main(argv=None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 2
        return _COMMANDS[args.command][1](args)
    except InputError as e:
        print(f"sbcal: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sbcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
