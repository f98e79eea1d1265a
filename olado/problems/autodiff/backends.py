"""The automatic-differentiation back-ends by name, the check that the optional package of one
is installed (its extra named otherwise), and the choice of ``"auto"``: CasADi when it is
installed, else the numeric back-end (finite differences) with a one-time note; and how every
back-end reads a model's ``final`` (:func:`split_final`)."""

from __future__ import annotations

import importlib.util
import warnings

from ...errors import AutoDiffNotAvailableError, ProblemDefinitionError

#: back-end -> (module it needs, the extra that installs it); "numpy" needs nothing optional
BACKENDS = {"casadi": ("casadi", "olado[ad]"), "sympy": ("sympy", "olado[ad-sympy]"), "numpy": (None, None)}
#: the back-ends that differentiate (the others leave the derivatives to finite differences)
EXACT = ("casadi", "sympy")

_noted = False


def require_backend(name):
    """Check that the back-end ``name`` ("casadi", "sympy", "numpy" or "auto") is installed,
    without importing it: AutoDiffNotAvailableError naming the optional extra otherwise."""
    if name == "auto":
        return
    if name not in BACKENDS:
        raise ProblemDefinitionError(f"unknown automatic-differentiation back-end {name!r}; choose one of "
                                     f"auto, {', '.join(BACKENDS)}", function="autodiff", array="backend")
    module, extra = BACKENDS[name]
    if module is not None and importlib.util.find_spec(module) is None:
        raise AutoDiffNotAvailableError(
            f"exact derivatives with the {name} back-end need the optional package '{module}': "
            f"pip install {extra} (or ad_backend='numpy': the same model with finite-difference "
            "derivatives)", function="autodiff", array="backend")


def resolve_backend(name):
    """The back-end ``name`` stands for: "auto" is "casadi" when CasADi is installed, else
    "numpy" (derivatives by finite differences), said once per process by a warning naming the
    extra that gives exact ones; any other name is checked by :func:`require_backend`."""
    global _noted
    if name != "auto":
        require_backend(name)
        return name
    if importlib.util.find_spec("casadi") is not None:
        return "casadi"
    if not _noted:
        _noted = True
        warnings.warn("CasADi is not installed: olado evaluates the model with numpy and takes its "
                      "derivatives by finite differences (slower, about 8 digits for the first "
                      "derivatives, 5 for the Hessians); pip install olado[ad] for exact ones",
                      stacklevel=3)
    return "numpy"


def make_backend(name, **options):
    """The symbolic back-end ``name`` with its ``options`` (:func:`require_backend` first)."""
    require_backend(name)
    if name == "casadi":
        from .casadi_backend import CasadiBackend   # noqa: PLC0415 - its evaluators load numba
        return CasadiBackend(**options)
    if name == "sympy":
        from .sympy_backend import SympyBackend   # noqa: PLC0415
        return SympyBackend(**options)
    raise ProblemDefinitionError(f"the {name!r} back-end does not differentiate", function="autodiff", array="backend")


def split_final(value):
    """(F^N, g^N) from what a model's ``final`` returns: a cost, or a pair (cost, gN); g^N is ()
    when the model gives only the cost."""
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise ProblemDefinitionError("must return cost or (cost, gN)", function="final")
        return value[0], value[1]
    return value, ()
