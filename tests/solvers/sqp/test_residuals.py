"""The SQP's Result residuals, computed stage by stage (olado.solvers.sqp.residuals), agree
with the flat computation on the NLP view (olado.solvers.common) to rounding."""

import numpy as np
import pytest

from olado.problems import DOCP
from olado.problems.nlp import StructuredNLP
from olado.problems.zambezi import zambezi_problem
from olado.solvers.common import (complementarity_residual, fill_fixed_bound_multipliers,
                                  stationarity_residual)
from olado.solvers.sqp.residuals import stage_kkt
from olado.solvers.sqp.solver import SQPSolver
from olado.solvers.sqp.state import BoundMultipliers, Multipliers, Point

from fixtures.toy_problems import Pendulum


class MixedPendulum(Pendulum):
    """Pendulum with every kind of constraint: stage rows g >= 0 and = 0, final rows = 0 and >= 0,
    state bounds with a fixed entry (x^2_0 = 0.9) and a fixed control (u^3 = 0.5)."""

    def __init__(self, N=8):
        xl = np.full((N + 1, 2), -3.0); xu = np.full((N + 1, 2), 3.0)
        xl[2, 0] = xu[2, 0] = 0.9
        ul = np.full((N, 1), -2.0); uu = np.full((N, 1), 2.0)
        ul[3] = uu[3] = 0.5
        super(Pendulum, self).__init__(2, 1, N, [1.0, 0.0], x_bounds=(xl, xu), u_bounds=(ul, uu),
                                       n_stage_constraints=2, n_final_constraints=2,
                                       stage_equalities=[1], final_equalities=[0])

    def stage_constraints(self, k, x, u):
        return np.array([1.0 - x[1] ** 2 - 0.5 * u[0] ** 2, x[0] * u[0] - 0.1])

    def final_constraints(self, x):
        return np.array([x[0] - 0.2, 1.0 - x @ x])

    # the constraint derivatives by finite differences
    stage_constraints_jacobian = DOCP.stage_constraints_jacobian
    final_constraints_jacobian = DOCP.final_constraints_jacobian
    stage_hessian = DOCP.stage_hessian
    final_hessian = DOCP.final_hessian


def flat_kkt(p, X, U, mult, bounds):
    """What olado.solvers.common.build_result computes on the NLP view."""
    nlp = StructuredNLP(p)
    y = nlp.pack(X, U)
    lam = np.concatenate([mult.lam[1:].ravel(), mult.Lg.ravel(), mult.LgN])
    zl, zu = nlp.pack(bounds.zl_x, bounds.zl_u), nlp.pack(bounds.zu_x, bounds.zu_u)
    grad, jac, c = nlp.gradient(y), nlp.jacobian_matrix(y), nlp.constraints(y)
    zl, zu = fill_fixed_bound_multipliers(nlp, y, lam, zl, zu, grad=grad, jac=jac)
    stat = float(np.max(np.abs(stationarity_residual(grad, jac, lam, zl, zu))))
    scale = float(np.max(np.abs(grad)) + np.max(np.abs(jac.data)) * np.max(np.abs(lam), initial=0.0))
    return (stat, complementarity_residual(nlp, y, c, lam, zl, zu), nlp.max_violation(y, c),
            nlp.unpack(zl), nlp.unpack(zu), scale)


def assert_agree(p, X, U, mult, bounds):
    pt = Point(p, X, U)
    got = stage_kkt(p, pt, mult, bounds)
    stat, compl, viol, (zlx, zlu), (zux, zuu), scale = flat_kkt(p, X, U, mult, bounds)
    eps = np.finfo(float).eps
    # sums of a few products in another order: rounding of the largest terms
    assert abs(got.stationarity - stat) <= 16 * eps * scale
    assert got.complementarity == compl              # the same elementwise products
    assert got.violation == viol
    for a, b in ((got.bounds.zl_x, zlx), (got.bounds.zu_x, zux), (got.bounds.zl_u, zlu), (got.bounds.zu_u, zuu)):
        np.testing.assert_allclose(a, b, rtol=0, atol=16 * eps * scale)
    return got, stat


def random_multipliers(p, rng):
    N, n, m, r, rN = p.N, p.n, p.m, p.r, p.rN
    mult = Multipliers(rng.normal(size=(N + 1, n)), rng.normal(size=(N, r)), rng.normal(size=rN))
    bounds = BoundMultipliers(*(rng.normal(size=s) for s in ((N + 1, n), (N + 1, n), (N, m), (N, m))))
    return mult, bounds


@pytest.mark.parametrize("make", [lambda: MixedPendulum(), lambda: Pendulum(N=12),
                                  lambda: zambezi_problem("zambezi12", N=24)], ids=["mixed", "pendulum", "zambezi12"])
def test_stage_residuals_equal_the_flat_ones_at_random_points_and_multipliers(make):
    p = make()
    rng = np.random.default_rng(7)
    for _ in range(3):
        U = np.clip(p.initial_guess() + 0.3 * rng.normal(size=(p.N, p.m)), p.u_lower - 0.1, p.u_upper + 0.1)
        X = p.simulate(U) + 0.05 * rng.normal(size=(p.N + 1, p.n))      # dynamics violated too
        got, stat = assert_agree(p, X, U, *random_multipliers(p, rng))
        assert got.stationarity > 1e-3 and got.complementarity > 1e-3 and got.violation > 1e-3


@pytest.mark.parametrize("make", [lambda: Pendulum(N=20), lambda: zambezi_problem("zambezi12", N=24)],
                         ids=["pendulum", "zambezi12"])
def test_the_result_residuals_equal_the_flat_ones_at_the_sqp_solution(make):
    p = make()
    r = SQPSolver().solve(p)
    assert r.success, r.message
    mu = r.multipliers
    mult = Multipliers(np.vstack([np.zeros((1, p.n)), mu["dynamics"]]), mu["stage_constraints"], mu["final_constraints"])
    bounds = BoundMultipliers(mu["bound_lower_x"], mu["bound_upper_x"], mu["bound_lower_u"], mu["bound_upper_u"])
    got, _ = assert_agree(p, r.x, r.u, mult, bounds)
    assert r.info["stationarity_residual"] == got.stationarity
    assert r.info["complementarity_residual"] == got.complementarity
    assert r.max_constraint_violation == got.violation < 1e-8
    assert r.info["nlp"] == StructuredNLP(p).counts()
