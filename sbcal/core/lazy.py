"""Names a package exports from its submodules, imported on first use (PEP 562).

``import sbcal`` stays as light as the forward model: the command line imports it for every command,
and the sampler's, ArviZ's and the design tools' modules load only when a script asks for one of their
names.
"""

from __future__ import annotations

import importlib
import sys


__all__ = ["lazy_exports"]


def lazy_exports(package: str, names: dict[str, str]):
    """Module ``__getattr__`` and ``__dir__`` for ``package`` exporting ``names``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : dict of str -> str
        Exported name -> the module that defines it, relative to ``package`` (``".inference.calibrate"``).

    Returns
    -------
    (__getattr__, __dir__)
        To assign at the package's top level; a name is imported once, then cached in the package.
    """
    def __getattr__(name: str):
        if name not in names:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(names[name], package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(names))

    return __getattr__, __dir__
