"""olado: discrete-time optimal control problems, revived from the C++ OLADO library.

    import olado
    result = olado.solve(problem, solver="ipopt", tol=1e-8)
    print(result.summary())

Importing olado is cheap: the problem classes, solvers and their optional back-ends (cyipopt,
numba-compiled kernels) load on first use.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# public name -> module that defines it (loaded on first access, PEP 562)
_LAZY = {
    "solve": "olado.api",
    "Result": "olado.result",
    "Status": "olado.result",
    "Certificate": "olado.result",
    "certify": "olado.solvers.certificate",
    "Infeasibility": "olado.result",
    "Violation": "olado.result",
    "ViolatedArray": "olado.result",
    "diagnose": "olado.solvers.diagnosis",
    "DOCP": "olado.problems",
    "LagrangeDOCP": "olado.problems",
    "MayerDOCP": "olado.problems",
    "StructuredNLP": "olado.problems",
    "OCP": "olado.problems.ocp",
    "load_config": "olado.config",
    "SolverConfig": "olado.config",
    "OladoError": "olado.errors",
    "ConfigError": "olado.errors",
    "ProblemDefinitionError": "olado.errors",
    "SolverError": "olado.errors",
    "SolverNotAvailableError": "olado.errors",
    "NonFiniteEvaluationError": "olado.errors",
    "ResultFileError": "olado.errors",
    "ProblemInUseError": "olado.errors",
}
_SUBMODULES = ("errors", "interrupts", "result", "config", "options", "api", "problems", "solvers", "linalg", "qp", "cli", "bench")

__all__ = ["__version__", "errors", *_LAZY]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        module = importlib.import_module(f"olado.{name}")
        globals()[name] = module
        return module
    raise AttributeError(f"module 'olado' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__) | set(_SUBMODULES))
