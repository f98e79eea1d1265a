"""The active-set QP method for the stage QP (14) (paper 001 sec. 4.2.2): Goldfarb and Idnani's
dual method (Goldfarb & Idnani 1983; Powell 1985) whose equality-constrained subproblems are
solved by the block Riccati recursion in O(N) per working-set change, with Bertsekas' initial
working set or the warm start's. Reached by name (``active-set``) through
:func:`olado.qp.make_qp_solver`; docs/qp-active-set.md describes the method.
"""

from .options import ActiveSetQPOptions
from .solver import GoldfarbIdnaniQP

__all__ = ["GoldfarbIdnaniQP", "ActiveSetQPOptions"]
