"""Name -> solver class registry used by olado.solve, the ini configuration and the CLI."""

from __future__ import annotations

from ..errors import ConfigError

SOLVERS: dict = {}


def register(cls):
    """Class decorator: make a solver available under ``cls.name``."""
    SOLVERS[cls.name] = cls
    return cls


def get_solver_class(name: str):
    _load_builtin()
    try:
        return SOLVERS[name]
    except KeyError:
        raise ConfigError(f"unknown solver {name!r}", allowed=", ".join(sorted(SOLVERS))) from None


def available_solvers() -> dict:
    _load_builtin()
    return dict(SOLVERS)


def _load_builtin():
    # Importing the modules registers their solvers.
    from .control import ddp, pdmin, penalty, reduced_gradient  # noqa: F401
    from .nlp import ipopt, scipy_nlp  # noqa: F401
    from .sqp import solver  # noqa: F401
