"""The ``sbcal`` command line: a thin adapter over the library.

Each subcommand is a pair ``add_<name>(subparsers)`` / ``cmd_<name>(args) -> int`` in the module of its
concern; bad input ends in one line on stderr and exit status 2, never a traceback."""

from __future__ import annotations

import argparse
import shlex
import sys
import warnings

from ..core.errors import InputError, InputWarning
from ..core.version import __version__
from ..core.workers import one_blas_thread
from .acquisition import add_import, cmd_import
from .compare import add_compare, cmd_compare
from .calibration import (add_bench, add_data, add_map, add_report, add_run, add_sample, add_simulate, cmd_bench,
                          cmd_data, cmd_map, cmd_report, cmd_run, cmd_sample, cmd_simulate)
from .design import add_design, add_predict, add_span, cmd_design, cmd_predict, cmd_span
from .lot import add_batch, cmd_batch
from .options import Parser
from .physics import add_cable, add_diagnose, cmd_cable, cmd_diagnose


__all__ = ["main", "build_parser"]

# One line per subcommand; each pair lives in the module of its concern.
_COMMANDS = {
    "simulate": (add_simulate, cmd_simulate),
    "sample": (add_sample, cmd_sample),
    "map": (add_map, cmd_map),
    "report": (add_report, cmd_report),
    "run": (add_run, cmd_run),
    "import": (add_import, cmd_import),
    "data": (add_data, cmd_data),
    "bench": (add_bench, cmd_bench),
    "diagnose": (add_diagnose, cmd_diagnose),
    "cable": (add_cable, cmd_cable),
    "predict": (add_predict, cmd_predict),
    "span": (add_span, cmd_span),
    "design": (add_design, cmd_design),
    "batch": (add_batch, cmd_batch),
    "compare": (add_compare, cmd_compare),
}


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="sbcal", description="Bayesian calibration of Stockbridge dampers.")
    parser.add_argument("--version", action="version", version=f"sbcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for add, _ in _COMMANDS.values():
        add(sub)
    return parser


def _one_line(shown: set):
    """``warnings.showwarning`` that prints an :class:`InputWarning` once, as one line, and the rest as Python does."""
    default = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, InputWarning):
            if str(message) not in shown:
                shown.add(str(message))
                print(f"sbcal: warning: {message}", file=sys.stderr)
            return
        default(message, category, filename, lineno, file, line)

    return show


def main(argv=None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input)."""
    parser = build_parser()
    with warnings.catch_warnings():
        warnings.simplefilter("always", InputWarning)
        warnings.showwarning = _one_line(set())
        return _main(parser, argv)


def _main(parser, argv) -> int:
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        args = parser.parse_args(argv)
        args.command_line = " ".join(["sbcal"] + [shlex.quote(a) for a in argv])  # provenance
        if args.command is None:
            parser.print_help()
            return 2
        with one_blas_thread():  # every process of sbcal's: see sbcal/core/workers.py
            return _COMMANDS[args.command][1](args)
    except InputError as e:
        print(f"sbcal: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into head & co.
        sys.stderr.close()
        return 0
    except OSError as e:  # the file system refused (unwritable output, disk full ...): one line, no traceback
        where = f"{e.filename}: " if e.filename else ""
        print(f"sbcal: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sbcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
