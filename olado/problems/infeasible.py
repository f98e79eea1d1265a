"""Deliberately infeasible problems: variants of feasible ones whose constraints no trajectory
can meet, each with the reason (a proof, not an observation). A solver should end with the
INFEASIBLE status on them and name the constraints that stay violated.

=========================  ==================================================================
``lq-unreachable``         ``lq-box`` with a terminal state outside the reachable set
``cart-too-short``         ``bang-bang-cart`` in the fixed time 3 < 1 + sqrt 6
``chain-too-short``        ``hanging-chain`` with L = 2 below the end points' distance sqrt 5
``catalyst-overfull``      ``catalyst-mixing`` with x1(1) + x2(1) >= 1.05
``steering-too-short``     ``particle-steering`` in the fixed time 0.4
``vanderpol-contradict``   ``vanderpol`` with the path constraints x1 >= 0.2 and x1 <= 0.1
``batch-overyield``        ``batch-reactor`` with x2(1) >= 1.05
=========================  ==================================================================
"""

from __future__ import annotations

import numpy as np

from .cops import CatalystMixing, HangingChain, ParticleSteering
from .literature import BangBangCart, BatchReactor
from .testproblems import LinearQuadratic, VanDerPol

__all__ = ["LQUnreachable", "CartTooShort", "CatalystOverfull", "SteeringTooShort",
           "VanDerPolContradict", "BatchOveryield", "PROBLEMS"]


class LQUnreachable(LinearQuadratic):
    """``lq-box`` (|u_i| <= 1, N = 50) with the terminal constraint x^N = (20, -20, 20, -20).

    Infeasible: the states reachable in N steps form the polytope A^N x0 + sum_k A^(N-1-k) B U_k,
    |U_k| <= 1; the target lies outside it (an LP with these linear constraints has no feasible
    point; tests/problems/test_robustness_problems.py solves that LP).
    """

    TARGET = np.array([20.0, -20.0, 20.0, -20.0])

    def __init__(self, N=50, **options):
        options.setdefault("name", "lq-unreachable")
        super().__init__(N=N, umax=1.0, n_final_constraints=4, final_equalities=[0, 1, 2, 3], **options)

    def final_constraints(self, x):
        return x - self.TARGET

    def final_constraints_jacobian(self, x):
        return np.eye(4)


class CartTooShort(BangBangCart):
    """``bang-bang-cart`` (x'' = u, |u| <= 1, (1, 1) -> (0, 0)) in the fixed time T = 3, shorter
    than the minimum time 1 + sqrt(6) = 3.449; no objective (a feasibility problem).

    Infeasible: no control reaches the origin before the minimum time; for the discrete problem
    (RK4 is exact here: x^{k+1} = x + h v + h^2/2 u, v^{k+1} = v + h u) the tests show it by an
    LP with these linear constraints.
    """

    name = "cart-too-short"
    T = 3.0
    DEFAULT_N = 50
    MINIMUM_TIME = False


class CatalystOverfull(CatalystMixing):
    """``catalyst-mixing`` with the terminal constraint x1(1) + x2(1) >= 1.05.

    Infeasible: (x1 + x2)' = -(1 - u) x2 <= 0 while x2 >= 0 (x2' >= -(1 - u) x2 - u 10 x2 keeps
    x2 >= 0 from x2(0) = 0 with x1 >= 0), so x1 + x2 <= x1(0) + x2(0) = 1 along every
    trajectory; RK4's error at N = 50 is far below the 0.05 margin.
    """

    name = "catalyst-overfull"
    N_TERMINAL = 1

    def ode_terminal(self, x, T):
        return [x[0] + x[1] - 1.05]


class SteeringTooShort(ParticleSteering):
    """``particle-steering`` in the fixed time T = 0.4; no objective (a feasibility problem).

    Infeasible: x3' = a cos u <= a = 100, so x3(0.4) <= 40 < 45 = x3(T) required; in the
    discrete problem each RK4 step adds h a cos u^k <= h a to x3 exactly (its right-hand side
    does not depend on the state).
    """

    name = "steering-too-short"
    T = 0.4
    DEFAULT_N = 50


class VanDerPolContradict(VanDerPol):
    """``vanderpol`` with the contradicting path constraints x1 - 0.2 >= 0 and 0.1 - x1 >= 0 at
    every stage k = 0..N-1.

    Infeasible: the two constraints add up to -0.1 >= 0 at every stage, whatever the trajectory
    (and x1(0) = 0 violates the first).
    """

    def __init__(self, N=50, **options):
        options.setdefault("name", "vanderpol-contradict")
        super().__init__(N, path_constraints=lambda t, x, u, p: [x[0] - 0.2, 0.1 - x[0]], **options)


class BatchOveryield(BatchReactor):
    """``batch-reactor`` with the terminal constraint x2(1) >= 1.05.

    Infeasible: (x1 + x2)' = -u^2/2 x1 <= 0 with x1 >= 0 (x1' = -(u + u^2/2) x1 keeps its sign), so
    x2(1) <= x1(1) + x2(1) <= 1; RK4's error at N = 50 is far below the 0.05 margin.
    """

    name = "batch-overyield"
    N_TERMINAL = 1

    def ode_terminal(self, x, T):
        return [x[1] - 1.05]


def _factory(cls, doc):
    def make(N=None, method="rk4"):
        return cls(N=N, method=method)
    make.__doc__ = doc
    return make


def _lq_unreachable(N=50):
    """lq-box with an unreachable terminal state (infeasible); see LQUnreachable."""
    return LQUnreachable(N=N)


def _vanderpol_contradict(N=50, method="rk4"):
    """Van der Pol with x1 >= 0.2 and x1 <= 0.1 at every stage (infeasible)."""
    return VanDerPolContradict(N=N, method=method)


def _chain_too_short(N=None, method="rk4"):
    """Hanging chain with L = 2 < sqrt 5, the end points' distance (infeasible)."""
    return HangingChain(N=N, method=method, length=2.0, name="chain-too-short")


#: name -> factory (registered lazily by olado.problems.catalog)
PROBLEMS = {
    "lq-unreachable": _lq_unreachable,
    "cart-too-short": _factory(CartTooShort, "Minimum-time cart in the fixed time 3 < 1 + sqrt 6 (infeasible)."),
    "chain-too-short": _chain_too_short,
    "catalyst-overfull": _factory(CatalystOverfull, "Catalyst mixing with x1(1) + x2(1) >= 1.05 (infeasible)."),
    "steering-too-short": _factory(SteeringTooShort, "Particle steering in the fixed time 0.4 (infeasible)."),
    "vanderpol-contradict": _vanderpol_contradict,
    "batch-overyield": _factory(BatchOveryield, "Batch reactor with x2(1) >= 1.05 (infeasible)."),
}
