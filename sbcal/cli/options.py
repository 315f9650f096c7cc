"""What the subcommands share: the one-line-error parser, option groups, value parsers, the bench and the
pipeline settings from the options."""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from ..core.errors import InputError, InputWarning
from ..core.workers import default_workers


__all__ = [
    "Parser", "deprecated_alias", "quiet_option", "seed_value", "parse_set", "parse_frequencies", "bench_options", "damper_options", "workers_option", "scale_options",
    "bench_for", "check_dampers", "cleaned_for", "settings_from", "print_summary",
]

class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage dump) and exit status 2."""

    def error(self, message):
        # the CLI prints "sbcal: error: ..." itself: name the subcommand only ("run: argument --x: ...")
        sub = self.prog.removeprefix("sbcal").strip()
        raise InputError(f"{sub}: {message}" if sub else message)


class _Deprecated(argparse.Action):
    """An old spelling of an option: stores to the new one's ``dest`` and says so in an :class:`InputWarning` (one
    line, once: :func:`sbcal.cli.app.main` prints them)."""

    def __init__(self, option_strings, dest, new: str = "", append: bool = False, **kw):
        self.new, self.append = new, append
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        warnings.warn(f"{option_string} is deprecated (kept for one release): use {self.new}", InputWarning, stacklevel=2)
        if self.append:  # a repeatable old flag feeding a list-valued new one
            values = list(getattr(namespace, self.dest, None) or []) + [values]
        setattr(namespace, self.dest, values)


def deprecated_alias(p, old: str, new: str, dest: str, *, append: bool = False) -> None:
    """Keep ``old`` working for one release as a hidden spelling of ``new`` (one deprecation line when used);
    ``append``: the old flag was repeatable, one value each time, the new one takes a list."""
    p.add_argument(old, dest=dest, action=_Deprecated, new=new, append=append, help=argparse.SUPPRESS)


def quiet_option(p) -> None:
    """``--quiet``, one meaning on every command: no progress bars or stage lines (results, warnings and errors
    still print)."""
    p.add_argument("--quiet", action="store_true", help="no progress bars or stage lines (results, warnings and errors still print)")


def seed_value(text: str) -> int:
    """``--seed``: an integer >= 0 (numpy's SeedSequence takes no negative entropy)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def parse_set(items) -> dict:
    """``["EJ=9", "beta=0.3"]`` -> ``{"EJ": 9.0, "beta": 0.3}``, names checked against the model and
    geometry values against the damper file's plausible ranges (``a1=5`` is 5 m: refused)."""
    from ..model.fem import PARAMETER_NAMES
    from ..model.damper import plausible
    from ..core._io import finite_number

    out = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        if name not in PARAMETER_NAMES:
            raise InputError(f"--set {item!r}: unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}")
        out[name] = finite_number(value, f"--set {item!r}")
        if name in _POSITIVE and out[name] <= 0:
            raise InputError(f"--set {item!r}: {name} must be > 0")
        if name in _NON_NEGATIVE and out[name] < 0:
            raise InputError(f"--set {item!r}: {name} must be >= 0")
        plausible(name, out[name], f"--set {item!r}", "--set takes SI units")  # as the damper file's geometry
    return out


# model parameters that are sizes (rigidities, masses, inertias, lengths) or loss factors
_POSITIVE = ("EJ", "m1", "m2", "mc", "J1", "J2", "Jc", "mu", "L1", "L2")
_NON_NEGATIVE = ("beta", "beta1", "beta2")


def parse_frequencies(text: str) -> np.ndarray:
    from ..model.fem import STANDARD_GRID_HZ

    if text == "standard":
        return STANDARD_GRID_HZ.copy()
    try:
        f = np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise InputError(f"--frequencies {text!r}: expected 'standard' or comma-separated numbers [Hz]") from None
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"--frequencies {text!r}: frequencies must be finite and > 0")
    return f


def bench_options(p, what="bench file"):
    p.add_argument("--bench", metavar="PATH", help=f"{what}: .csv, .csv.gz, .xlsx or .parquet (default: the bundled data)")
    p.add_argument("--sheet", metavar="NAME", help="read only this sheet of an .xlsx workbook (default: every sheet)")


def damper_options(p):
    """``--damper`` (one, default damper1) and the bench file it is read from."""
    p.add_argument("--damper", default="damper1", metavar="NAME|PATH",
                   help="bundled damper name or TOML path (default damper1)")
    bench_options(p)


def workers_option(p, what):
    p.add_argument("--workers", type=int, default=default_workers(), metavar="N",
                   help=f"{what} (default: 2 or the cores there are)")


def scale_options(p, workers_help="jobs in parallel local processes"):
    workers_option(p, workers_help)
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="send the jobs to a running Dask distributed cluster (e.g. tcp://host:8786; "
                        "pip install \"sbcal[dask]\")")
    quiet_option(p)


def bench_for(args):
    """The ``--bench`` file, or the bundled data."""
    from ..data.readers import default_bench_path, load_bench

    if args.bench:
        return load_bench(args.bench, sheet=getattr(args, "sheet", None))
    path = default_bench_path()
    if not path.is_file():
        raise InputError(f"no bundled bench data ({path} is missing); pass --bench PATH")
    return load_bench(path, sheet=getattr(args, "sheet", None))


def check_dampers(bench, dampers) -> None:
    """Every damper of ``dampers`` has rows in ``bench``; else one line naming the file and what it has."""
    for d in dampers:
        if d.name not in bench.dampers():
            raise InputError(f"{bench.source}: no rows of damper {d.name!r} (has: {', '.join(bench.dampers())})")


def cleaned_for(bench, dampers, *, store, settings, quiet: bool = False):
    """``bench`` cleaned by the pipeline's clean stage in the run store ``store`` (its stored decision
    reused while fresh, else made and stored, which is said on stderr unless ``quiet``): the runs every
    later stage reads."""
    import sys

    from ..pipeline import clean

    check_dampers(bench, dampers)

    def say(line):
        if ": redone" in line and not quiet:
            print(line, file=sys.stderr)

    return clean(bench, dampers, store=store, settings=settings, say=say)


def settings_from(args, **extra):
    from ..pipeline import Settings

    if getattr(args, "workers", 1) < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    priors = getattr(args, "priors", None)
    if priors:
        from ..pipeline import file_digest

        file_digest(priors)  # fail early on a missing prior file
    return Settings(paramset=getattr(args, "params", "theta1"), seed=args.seed, priors=priors,
                    workers=getattr(args, "workers", 1), **extra)


def print_summary(name, t, paramset, s):
    p = s["parameters"]
    flag = "" if s["converged"] else f"  NOT CONVERGED ({s['reason']})"
    print(f"{name} {t} {paramset}: EJ {p['EJ']['median']:.3g} [{p['EJ']['q05']:.3g}, "
          f"{p['EJ']['q95']:.3g}] N m^2, " + ", ".join(
              f"{n} {p[n]['median']:.3g} [{p[n]['q05']:.3g}, {p[n]['q95']:.3g}]"
              for n in p if n.startswith("beta")) + f", R-hat max {s['r_hat_max']:.3f}, "
          f"ESS min {min(s['ess_bulk_min'], s['ess_tail_min']):.0f}, {s['wall_s']:.1f} s{flag}")
