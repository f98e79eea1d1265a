"""Options of the simple-bounds QP method (docs/structure-exploiting-sqp.md, "Simple bounds only")."""

from __future__ import annotations

import dataclasses

from ...linalg.backend import KKT_SOLVERS
from ...options import option


@dataclasses.dataclass
class BoundsQPOptions:
    """Options of :class:`~olado.qp.bounds.PrimalDualActiveSetQP`."""

    tol: float = option(1e-9, "relative tolerance: a free variable violates a bound b when it lies beyond it by more "
                        "than tol (1 + |b|); a fixed variable's multiplier has the wrong sign when it is below "
                        "-tol (1 + max|gradient|); also the fallback interior-point method's tolerance", min=0.0,
                        min_exclusive=True)
    pdas_max_iter: int = option(40, "primal-dual active-set iterations (one Riccati factorization each) before the "
                                "solve is handed to the fallback method", min=1)
    state_bounds: str = option("interior-point", "QPs with finite bounds on states x_1..x_N: 'interior-point' solves "
                               "them by the fallback method (its barrier terms on the states are diagonal additions to "
                               "Q_xx of the plain Riccati recursion), 'active-set' iterates on them too (a fixed state "
                               "is an equality row of the general recursion, about 20 times the cost of a plain "
                               "factorization on zambezi12, and the iteration often cycles: docs)",
                               choices=("interior-point", "active-set"))
    init_eps: float = option(1e-8, "cold start: the bounds on which the zero step lies (|b| <= init_eps, Bertsekas' "
                             "epsilon-active set) start fixed", min=0.0)
    fallback: str = option("mehrotra", "interior-point method that solves a QP the active-set iteration gives up on "
                           "(a cycle, no fixed point within pdas_max_iter, a working set whose reduced Hessian is not "
                           "positive definite or whose fixed states are inconsistent, a QP with general rows)",
                           choices=("mehrotra", "gondzio", "weighted", "franke"))
    nonconvex: str = option("fail", "a working set whose reduced Hessian is not positive definite (a nonconvex "
                            "QP): 'fail' ends with NUMERICAL_ERROR naming the stage, after which the SQP's inertia "
                            "correction shifts the Hessian (as the active-set method does); 'fallback' solves the QP "
                            "by the fallback method (whose barrier terms may convexify it)",
                            choices=("fallback", "fail"))
    max_iter: int = option(200, "the fallback interior-point method's iteration limit", min=0)
    kkt: str = option("riccati", "KKT back-end of the fallback interior-point method", choices=KKT_SOLVERS)
    warm_start_push: float = option(1e-2, "the fallback interior-point method's warm_start_push", min=0.0, max=1.0,
                                    min_exclusive=True)
    verbose: int = option(0, "0 silent, 1 summary, 2 one line per active-set iteration", min=0, max=12)
