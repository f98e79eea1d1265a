"""The QP method for stage QPs whose only inequalities are simple bounds on states and controls
(paper 001 sec. 2.2: the versions of Powell's and Schittkowski's SQP "for problems with only
simple bounds"): a primal-dual active-set iteration on the bounds whose equality-constrained
subproblems are Riccati solves with the fixed controls eliminated and the fixed states as
equality rows (docs/structure-exploiting-sqp.md, "Simple bounds only")."""

from .options import BoundsQPOptions
from .solver import PrimalDualActiveSetQP, general_rows

__all__ = ["PrimalDualActiveSetQP", "BoundsQPOptions", "general_rows"]
