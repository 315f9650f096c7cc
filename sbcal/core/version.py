"""sbcal's version: the installed distribution's (``pyproject.toml`` holds the one number)."""

from importlib.metadata import PackageNotFoundError, version


__all__ = ["__version__"]

try:
    __version__ = version("sbcal")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"
