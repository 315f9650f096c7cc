"""scipy.special's C functions for compiled code: each real-argument function of
``scipy.special.cython_special`` made a numba intrinsic, the same values as the ``scipy.special`` ufunc.

A compiled function refers to a symbol of its own name (not to an address), so numba's on-disk cache
stays valid from one process to the next; the symbol is bound to scipy's export when this module is
imported.
"""

from __future__ import annotations

import ctypes

from llvmlite import binding as _llvm
from llvmlite import ir as _ir
from numba import types
from numba.core import cgutils
from numba.extending import get_cython_function_address, intrinsic


__all__ = ["hyp2f1", "betainc", "beta"]


def _export(name: str, n_args: int) -> str:
    """The key of scipy's export of ``name`` for ``n_args`` doubles: a fused function's double specialisation
    (``__pyx_fuse_1hyp2f1``, ``__pyx_fuse_0betainc`` in scipy 1.15-1.17) found by its signature, so that
    a renumbering of the fused types does not break the import."""
    from scipy.special import cython_special

    name_of = ctypes.pythonapi.PyCapsule_GetName
    name_of.restype, name_of.argtypes = ctypes.c_char_p, [ctypes.py_object]
    signature = ("double (" + ", ".join(["double"] * n_args)).encode()
    for key, capsule in cython_special.__pyx_capi__.items():
        if (key == name or key.endswith("fuse_0" + name) or key.endswith("fuse_1" + name)) \
                and name_of(capsule).startswith(signature):
            return key
    raise ImportError(f"scipy.special.cython_special exports no real {name}: sbcal's compiled laws need it")


def _symbol(name: str, n_args: int) -> str:
    """Bind a symbol of sbcal's own to scipy's export of ``name`` (``n_args`` doubles); return the symbol."""
    symbol = f"sbcal_scipy_{name}_double"
    _llvm.add_symbol(symbol, get_cython_function_address("scipy.special.cython_special", _export(name, n_args)))
    return symbol


def _call(symbol: str, n_args: int):
    """``(signature, codegen)`` of an intrinsic calling ``symbol`` (its trailing skip-dispatch flag 0)."""

    def codegen(context, builder, signature, values):
        d = _ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, _ir.FunctionType(d, [d] * n_args + [_ir.IntType(32)]),
                                            symbol)
        return builder.call(fn, list(values) + [_ir.Constant(_ir.IntType(32), 0)])

    return types.float64(*([types.float64] * n_args)), codegen


_HYP2F1, _BETAINC, _BETA = _symbol("hyp2f1", 4), _symbol("betainc", 3), _symbol("beta", 2)


@intrinsic
def hyp2f1(typingctx, a, b, c, x):
    """``scipy.special.hyp2f1(a, b, c, x)``, real ``x`` (compiled code only)."""
    return _call(_HYP2F1, 4)


@intrinsic
def betainc(typingctx, a, b, x):
    """``scipy.special.betainc(a, b, x)``: the regularised incomplete beta function (compiled code only)."""
    return _call(_BETAINC, 3)


@intrinsic
def beta(typingctx, a, b):
    """``scipy.special.beta(a, b)`` (compiled code only)."""
    return _call(_BETA, 2)
