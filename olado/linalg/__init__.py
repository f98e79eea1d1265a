"""The matrix work the solvers share: stage-block containers and the Riccati LQ-DOCP solver."""

from .riccati import LQSolution, NotPositiveDefiniteError, RiccatiFactorization, solve_lq_docp

__all__ = ["LQSolution", "NotPositiveDefiniteError", "RiccatiFactorization", "solve_lq_docp"]
