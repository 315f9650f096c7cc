"""The ``sbcal`` command line (``main``); each subcommand lives in the module of its concern."""

from .app import build_parser, main


__all__ = ["main", "build_parser"]
