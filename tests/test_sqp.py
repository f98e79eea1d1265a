"""Powell's SQP with structure-exploiting QP subproblems (paper 001 sec. 4.2.1)."""

import numpy as np
import pytest

import olado
from olado.config import load_config
from olado.problems import DOCP
from olado.problems.zambezi import zambezi_problem
from olado.result import Status
from olado.solvers.sqp import SQPSolver

from toy_problems import Pendulum

ipopt = pytest.importorskip("cyipopt")


@pytest.fixture(scope="module")
def pendulum_reference():
    p = Pendulum(N=20)
    return p, olado.solve(p, solver="ipopt", tol=1e-10)


@pytest.mark.parametrize("hessian", ["exact", "bfgs", "sr1", "powell-bfgs"])
def test_every_hessian_option_reaches_the_ipopt_solution(pendulum_reference, hessian):
    p, ref = pendulum_reference
    r = SQPSolver(hessian=hessian, max_iter=200).solve(p)
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-8)
    assert np.allclose(r.u, ref.u, atol=1e-5) and np.allclose(r.x, ref.x, atol=1e-5)
    assert r.max_constraint_violation < 1e-8
    # multipliers of the final equality and the dynamics agree with IPOPT's (same sign convention)
    assert np.allclose(r.multipliers["dynamics"], ref.multipliers["dynamics"], atol=1e-4)
    assert np.allclose(r.multipliers["final_constraints"], ref.multipliers["final_constraints"], atol=1e-4)


def test_exact_hessian_converges_quadratically(pendulum_reference):
    p, _ = pendulum_reference
    # the default proximal term (1e-4 max|H|) makes the local rate fast-linear; without it the
    # exact-Hessian SQP is Newton's method on the KKT system
    assert SQPSolver(hessian="exact", tol=1e-12).solve(p).iterations <= 6
    r = SQPSolver(hessian="exact", tol=1e-12, proximal=0.0).solve(p)
    kkt = [h["kkt"] for h in r.history]
    assert r.success and r.iterations <= 6
    # quadratic rate: once below 1e-1, each residual is at most ~ C * (previous)^2
    tail = [k for k in kkt if k < 1e-1]
    assert len(tail) >= 2
    for a, b in zip(tail, tail[1:]):
        assert b <= 10 * a ** 2 + 1e-12


@pytest.mark.parametrize("qp", ["mehrotra", "gondzio", "weighted"])
def test_zambezi12_sqp_ip_matches_ipopt(qp):
    p = zambezi_problem("zambezi12", N=24)
    ref = olado.solve(p, solver="ipopt", tol=1e-10)
    r = SQPSolver(qp=qp, hessian="exact").solve(p)
    assert r.success, r.message
    assert r.iterations <= 8          # paper 001 Table 1: 4 iterations at N = 24
    assert abs(r.objective - ref.objective) <= 1e-7 * abs(ref.objective)
    assert r.qp_iterations > 0 and r.max_constraint_violation < 1e-8


@pytest.mark.parametrize("kkt", ["superlu-reduced", "superlu-full", "gmres"])
def test_kkt_back_ends_give_the_same_sqp_iterates(kkt):
    p = zambezi_problem("zambezi12", N=12)
    a = SQPSolver(kkt="riccati").solve(p)
    b = SQPSolver(kkt=kkt).solve(p)
    assert a.iterations == b.iterations
    assert b.objective == pytest.approx(a.objective, rel=1e-10)


def test_sqp_ip_config_file_and_registry():
    cfg = load_config("configs/sqp-ip.ini")
    assert cfg.solver == "sqp" and cfg.options.qp == "mehrotra" and cfg.options.kkt == "riccati"
    assert "sqp" in olado.solvers.available_solvers()
    r = olado.solve(zambezi_problem("zambezi12", N=12), config="configs/sqp-ip.ini")
    assert r.success and r.solver == "sqp"


def test_external_qp_solver_in_the_sqp_loop():
    pytest.importorskip("qpsolvers")
    p = zambezi_problem("zambezi12", N=12)
    ref = SQPSolver().solve(p)
    r = SQPSolver(qp="clarabel", hessian="sr1", max_iter=300).solve(p)
    assert r.success, r.message
    assert r.objective == pytest.approx(ref.objective, rel=1e-7)


def test_statuses_max_iter_and_callback(pendulum_reference):
    p, _ = pendulum_reference
    r = SQPSolver(max_iter=1).solve(p)
    assert r.status == Status.MAX_ITERATIONS and r.iterations == 1 and not r.success
    seen = []
    r = SQPSolver(callback=lambda info: seen.append(info) or len(seen) >= 2).solve(p)
    assert r.status == Status.USER_STOP and r.iterations == 2
    assert {"objective", "violation", "kkt", "step", "penalty", "qp_iterations"} <= set(seen[0])


class Infeasible(DOCP):
    """x+ = x + u with |u| <= 1 cannot reach x_N = 10 from 0 in 3 steps."""

    def __init__(self):
        super().__init__(1, 1, 3, [0.0], u_bounds=(-1.0, 1.0), n_final_constraints=1, final_equalities=[0])

    def dynamics(self, k, x, u):
        return x + u

    def stage_cost(self, k, x, u):
        return float(u @ u)

    def final_cost(self, x):
        return 0.0

    def final_constraints(self, x):
        return x - 10.0


def test_inconsistent_linearization_is_reported_as_infeasible():
    r = SQPSolver().solve(Infeasible())
    assert r.status == Status.INFEASIBLE and not r.success
    assert "infeasible" in r.message
