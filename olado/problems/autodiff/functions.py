"""Elementary functions for models written once: the same code on numbers and arrays (numpy),
CasADi SX and SymPy expressions (docs/autodiff.md)."""

from __future__ import annotations

import numpy as np

__all__ = ["sin", "cos", "tan", "exp", "log", "sqrt", "tanh", "atan", "atan2", "asin", "acos",
           "sinh", "cosh", "fabs", "fmax", "fmin"]


def _elementary(name, casadi_name=None, sympy_name=None, numpy_name=None):
    """An elementary function that works on numbers and arrays (numpy), CasADi SX and SymPy
    expressions alike, so that a model's code is the same for every back-end."""
    casadi_name = casadi_name or name
    sympy_name = sympy_name or name
    numpy_fn = getattr(np, numpy_name or name)

    def fn(*args):
        mod = type(args[0]).__module__ if args else ""
        for a in args:
            mod = type(a).__module__
            if mod.startswith(("casadi", "sympy")):
                break
        if mod.startswith("casadi"):
            import casadi   # noqa: PLC0415 - the extra is imported on use
            return getattr(casadi, casadi_name)(*args)
        if mod.startswith("sympy"):
            import sympy    # noqa: PLC0415
            return getattr(sympy, sympy_name)(*args)
        return numpy_fn(*args)

    fn.__name__ = name
    fn.__doc__ = f"{name} of a number, array, CasADi or SymPy expression."
    return fn


sin, cos, tan, exp, log, sqrt, tanh = (_elementary(nm) for nm in ("sin", "cos", "tan", "exp", "log", "sqrt", "tanh"))
sinh, cosh = _elementary("sinh"), _elementary("cosh")
atan = _elementary("atan", numpy_name="arctan")
asin = _elementary("asin", numpy_name="arcsin")
acos = _elementary("acos", numpy_name="arccos")
atan2 = _elementary("atan2", numpy_name="arctan2")
fabs = _elementary("fabs", sympy_name="Abs", numpy_name="abs")
fmax = _elementary("fmax", sympy_name="Max", numpy_name="fmax")
fmin = _elementary("fmin", sympy_name="Min", numpy_name="fmin")
