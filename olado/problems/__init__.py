"""What is solved: the DOCP class hierarchy, the NLP view and the built-in problems."""

from .docp import DOCP, LagrangeDOCP, MayerDOCP
from .nlp import StructuredNLP
from .derivatives import check_derivatives, DerivativeReport


def _registry():
    problems = {}
    try:
        from .zambezi import PROBLEMS as _z
        problems.update(_z)
    except ImportError:  # pragma: no cover - during development only
        pass
    from .testproblems import PROBLEMS as _t
    problems.update(_t)
    from .catalog import lazy_factories   # the literature problems: modules imported on use
    problems.update(lazy_factories())
    return problems


def get_problems() -> dict:
    """Name -> factory(N=..., **kwargs) of the built-in problems."""
    return _registry()


def __getattr__(name):
    if name == "PROBLEMS":
        return _registry()
    raise AttributeError(name)


__all__ = ["DOCP", "LagrangeDOCP", "MayerDOCP", "StructuredNLP", "check_derivatives",
           "DerivativeReport", "get_problems", "PROBLEMS"]
