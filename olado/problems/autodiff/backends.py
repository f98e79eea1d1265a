"""The automatic-differentiation back-ends by name, and the check that the optional package of one
is installed (its extra named otherwise)."""

from __future__ import annotations

import importlib.util

from ...errors import AutoDiffNotAvailableError, ProblemDefinitionError

#: back-end -> (module it needs, the extra that installs it)
BACKENDS = {"casadi": ("casadi", "olado[ad]"), "sympy": ("sympy", "olado[ad-sympy]")}


def require_backend(name):
    """Check that the back-end ``name`` ("casadi" or "sympy") is installed, without importing it:
    AutoDiffNotAvailableError naming the optional extra otherwise."""
    if name not in BACKENDS:
        raise ProblemDefinitionError(f"unknown automatic-differentiation back-end {name!r}; choose one of "
                                     f"{', '.join(BACKENDS)}", function="autodiff", array="backend")
    module, extra = BACKENDS[name]
    if importlib.util.find_spec(module) is None:
        raise AutoDiffNotAvailableError(
            f"exact derivatives with the {name} back-end need the optional package '{module}': "
            f"pip install {extra} (or write the derivatives by hand, or use finite differences: "
            "a plain DOCP subclass)", function="autodiff", array="backend")


def make_backend(name, **options):
    """The back-end ``name`` with its ``options`` (:func:`require_backend` first)."""
    require_backend(name)
    if name == "casadi":
        from .casadi_backend import CasadiBackend   # noqa: PLC0415 - its evaluators load numba
        return CasadiBackend(**options)
    from .sympy_backend import SympyBackend   # noqa: PLC0415
    return SympyBackend(**options)
