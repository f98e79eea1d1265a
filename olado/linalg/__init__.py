"""The matrix work the solvers share (docs/architecture.md, "The matrix side"): the stage-wise QP
container, the Riccati LQ-DOCP solver and the general sparse KKT back-ends."""

from .kkt import KKT_SOLVERS, KKTSolveError, make_kkt_solver
from .riccati import LQSolution, NotPositiveDefiniteError, RiccatiFactorization, solve_lq_docp


__all__ = ["KKT_SOLVERS", "KKTSolveError", "make_kkt_solver", "LQSolution", "NotPositiveDefiniteError",
           "RiccatiFactorization", "solve_lq_docp", "QPResult", "StageQP", "qp_kkt_residuals"]
