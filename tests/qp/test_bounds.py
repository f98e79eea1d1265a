"""The simple-bounds QP method (olado.qp.bounds): the primal-dual active-set iteration on random
bounds-only stage QPs against Clarabel (solution, objective) and olado's Mehrotra method at a
tight tolerance (multipliers); its warm start, its fallback to the interior-point method and its
statuses."""

import numpy as np
import pytest

from fixtures.qp_problems import assert_multipliers_match, clarabel_solution, random_qp, replace
from olado.errors import ConfigError
from olado.qp import KKT_METHODS, OLADO_METHODS, QP_METHODS, make_qp_solver
from olado.qp.bounds import PrimalDualActiveSetQP, general_rows
from olado.qp.bounds.eqp import Boxes, solve_eqp
from olado.qp.interior_point import MehrotraQP
from olado.qp.stageqp import qp_kkt_residuals
from olado.result import Status

MULTIPLIERS = ("lam", "zx_lower", "zx_upper", "zu_lower", "zu_upper")


def control_bounds_qp(seed, N=20, n=4, m=3, scale=5.0, fixed=False):
    """A convex bounds-only QP with bounds on the controls only; the gradient is scaled so that
    many control bounds are active at the solution."""
    qp = random_qp(seed, N=N, n=n, m=m, nc=0, ncN=0)
    kw = dict(q=scale * qp.q, r=scale * qp.r, x_lower=None, x_upper=None)
    if fixed:
        ul, uu = qp.u_lower.copy(), qp.u_upper.copy()
        ul[2, 1] = uu[2, 1] = 0.05
        kw.update(u_lower=ul, u_upper=uu)
    return replace(qp, **kw)


def agrees(qp, res, tol=1e-6):
    Xr, Ur, Jr = clarabel_solution(qp)
    assert res.objective == pytest.approx(Jr, rel=1e-8, abs=1e-8)
    assert np.max(np.abs(res.X - Xr)) < tol and np.max(np.abs(res.U - Ur)) < tol
    ref = MehrotraQP(tol=1e-12).solve(qp)
    assert ref.success
    assert_multipliers_match(res, ref, MULTIPLIERS)


# ============================================================================= the active-set iteration
@pytest.mark.parametrize("case", [dict(seed=0), dict(seed=1, N=6, n=3, m=2), dict(seed=2, N=30, n=2, m=1),
                                  dict(seed=3, fixed=True), dict(seed=4, scale=1.0)],
                         ids=lambda c: "-".join(f"{k}{v}" for k, v in c.items()))
def test_control_bounds_agree_with_clarabel_and_mehrotra(case):
    qp = control_bounds_qp(**case)
    res = PrimalDualActiveSetQP(tol=1e-10).solve(qp)
    assert res.status is Status.SUCCESS and res.solver == "bounds", res.message
    assert res.iterations == len(res.history) >= 1
    agrees(qp, res)
    assert res.kkt == qp_kkt_residuals(qp, res)
    # exact complementarity: the free variables have zero multipliers, the fixed ones sit at their bound
    assert res.kkt["complementarity"] == 0.0 and res.kkt["dual_sign"] == 0.0
    assert res.kkt["stationarity"] < 1e-9 and res.kkt["primal"] < 1e-9
    lo, hi = res.active_set["u"]
    assert np.allclose(res.U[lo], qp.u_lower[lo], atol=1e-12) and np.allclose(res.U[hi], qp.u_upper[hi], atol=1e-12)
    assert lo.sum() + hi.sum() > 0


@pytest.mark.parametrize("seed,N,n,m,fixed", [(1, 8, 3, 2, False), (3, 8, 3, 2, False), (1, 20, 4, 3, True),
                                              (3, 20, 4, 3, True)])
def test_state_bounds_as_rows_of_the_general_recursion(seed, N, n, m, fixed):
    """state_bounds = 'active-set': fixed states are equality rows of the general recursion; on
    these QPs the iteration itself finds the solution, with states at their bounds."""
    qp = random_qp(seed, N=N, n=n, m=m, nc=0, ncN=0, fixed=fixed)
    res = PrimalDualActiveSetQP(tol=1e-10, state_bounds="active-set").solve(qp)
    assert res.status is Status.SUCCESS and res.solver == "bounds", res.message
    lo, hi = res.active_set["x"]
    assert lo.sum() + hi.sum() > (2 if fixed else 0)
    agrees(qp, res)


def test_eqp_eliminates_fixed_controls_exactly():
    """The EQP with some controls fixed is the LQ problem in the remaining variables: its solution
    is that of the dense KKT system with the fixed controls as equality rows."""
    qp = control_bounds_qp(5, N=5, n=3, m=2)
    B = Boxes(qp)
    side = np.zeros(B.lo.size, dtype=np.int8)
    j = B.nx + np.array([1, 4, 7])
    side[j] = np.where(np.isfinite(B.hi[j]), 1, -1)
    pt = solve_eqp(qp, B, side)
    d = qp.to_sparse()
    rows = np.zeros((j.size, qp.n_vars))
    nz = qp.n + qp.m
    for r, jj in enumerate(j):
        k, i = divmod(jj - B.nx, qp.m)
        rows[r, k * nz + qp.n + i] = 1.0
    vals = np.where(side[j] == 1, B.hi[j], B.lo[j])
    Aeq = np.vstack([d["A_eq"].toarray(), rows])
    beq = np.concatenate([d["b_eq"], vals])
    P = d["P"].toarray()
    K = np.block([[P, Aeq.T], [Aeq, np.zeros((Aeq.shape[0], Aeq.shape[0]))]])
    sol = np.linalg.solve(K, np.concatenate([-d["q"], beq]))
    X, U = qp.unpack(sol[:qp.n_vars])
    assert np.allclose(pt.X, X, atol=1e-10) and np.allclose(pt.U, U, atol=1e-10)
    # the multipliers of the fixed controls' rows (P y + q + A^T mult = 0) are the bound multipliers v
    # read off the stationarity residual
    mult = sol[qp.n_vars + d["A_eq"].shape[0]:]
    assert np.allclose(pt.v[j], mult, atol=1e-9) and np.all(np.abs(mult) > 1e-3)
    free = np.ones(B.lo.size, bool); free[j] = False
    assert np.max(np.abs(pt.v[free])) < 1e-10


def test_warm_start_from_a_neighbouring_qp_needs_one_factorization():
    qp = control_bounds_qp(6, N=40)
    first = PrimalDualActiveSetQP(tol=1e-10).solve(qp)
    near = replace(qp, q=qp.q * (1 + 1e-4), r=qp.r * (1 + 1e-4))
    cold = PrimalDualActiveSetQP(tol=1e-10).solve(near)
    warm = PrimalDualActiveSetQP(tol=1e-10).solve(near, warm_start=first)
    assert cold.success and warm.success and warm.solver == "bounds"
    assert warm.iterations == 1 < cold.iterations
    assert np.allclose(warm.X, cold.X, atol=1e-10) and np.allclose(warm.U, cold.U, atol=1e-10)
    # a warm start without an active set (another method's result): the sides whose multiplier exceeds the slack
    ip = MehrotraQP(tol=1e-10).solve(qp)
    warm_ip = PrimalDualActiveSetQP(tol=1e-10).solve(near, warm_start=ip)
    assert warm_ip.success and warm_ip.iterations <= 2 and np.allclose(warm_ip.U, cold.U, atol=1e-9)


# ============================================================================= fallback and statuses
def test_state_bounds_go_to_the_interior_point_method_by_default():
    qp = random_qp(1, N=8, n=3, m=2, nc=0, ncN=0)
    res = PrimalDualActiveSetQP(tol=1e-10).solve(qp)
    assert res.success and res.solver == "bounds+mehrotra"
    assert "solved by mehrotra" in res.message and "bounds states" in res.message
    assert res.history[0]["fallback"] == "mehrotra"
    agrees(qp, res)


def test_general_rows_go_to_the_fallback():
    qp = random_qp(2, N=8, nc=2, ncN=1, eq=True)
    assert "stage equality rows" in general_rows(qp) and "final inequality rows" in general_rows(qp)
    res = PrimalDualActiveSetQP(tol=1e-10, fallback="gondzio").solve(qp)
    assert res.success and res.solver == "bounds+gondzio" and "not simple bounds only" in res.message
    Xr, Ur, Jr = clarabel_solution(qp)
    assert res.objective == pytest.approx(Jr, rel=1e-8) and np.allclose(res.U, Ur, atol=1e-6)


def test_iteration_limit_hands_over_to_the_fallback():
    qp = control_bounds_qp(0)
    res = PrimalDualActiveSetQP(tol=1e-10, pdas_max_iter=1).solve(qp)
    assert res.success and res.solver == "bounds+mehrotra" and "pdas_max_iter = 1" in res.message
    assert res.iterations > 1
    agrees(qp, res)


def nonconvex_qp():
    """A QP whose Hessian is indefinite in the controls: the EQP of the bounds active at the zero
    step (none) is not strictly convex."""
    qp = control_bounds_qp(7, N=10, n=3, m=2, scale=1.0)
    R = qp.R.copy()
    R[4] -= 3.0 * np.eye(2)
    return replace(qp, R=R)


def test_nonconvex_working_set_fails_or_falls_back():
    qp = nonconvex_qp()
    fail = PrimalDualActiveSetQP(nonconvex="fail").solve(qp)
    assert fail.status is Status.NUMERICAL_ERROR and "not positive definite at stage k=4" in fail.message
    fb = PrimalDualActiveSetQP(nonconvex="fallback").solve(qp)
    ref = MehrotraQP(tol=1e-9).solve(qp)
    assert fb.solver == "bounds+mehrotra" and fb.status is ref.status and "stage k=4" in fb.message


def test_infeasible_x0_and_bad_boxes_are_reported_by_the_fallback():
    qp = control_bounds_qp(8, N=5)
    xl = np.full((qp.N + 1, qp.n), -np.inf)
    xl[0] = qp.x0 + 1.0
    res = PrimalDualActiveSetQP().solve(replace(qp, x_lower=xl))
    assert res.status is Status.INFEASIBLE and "x0 violates" in res.message
    ul = qp.u_lower.copy()
    ul[1, 0] = qp.u_upper[1, 0] + 1.0 if np.isfinite(qp.u_upper[1, 0]) else 1e3
    uu = qp.u_upper.copy()
    uu[1, 0] = ul[1, 0] - 1.0
    res = PrimalDualActiveSetQP().solve(replace(qp, u_lower=ul, u_upper=uu))
    assert res.status is Status.INFEASIBLE and "lower bound above upper bound" in res.message


# ============================================================================= registry and options
def test_registry_and_options():
    assert "bounds" in OLADO_METHODS and "bounds" in QP_METHODS and "bounds" in KKT_METHODS
    s = make_qp_solver("bounds", kkt="superlu-reduced", tol=1e-8, max_iter=30)
    assert isinstance(s, PrimalDualActiveSetQP)
    assert s.options.kkt == "superlu-reduced" and s.options.tol == 1e-8 and s.options.max_iter == 30
    with pytest.raises(ConfigError, match="fallback"):
        make_qp_solver("bounds", fallback="osqp")
    with pytest.raises(ConfigError, match="state_bounds"):
        PrimalDualActiveSetQP(state_bounds="penalty")


def test_limits_are_checked_at_every_iteration():
    """An interrupt requested before the QP starts ends the active-set iteration at its first
    factorization inside the solve's catch block (the fallback's check is the interior point's)."""
    import signal

    from olado.interrupts import InterruptGuard, Limits, request_interrupt

    qp = control_bounds_qp(0)
    ref = PrimalDualActiveSetQP().solve(qp)
    assert ref.solver == "bounds" and ref.iterations > 1
    with InterruptGuard():
        request_interrupt(signal.SIGINT)
        limits = Limits()
        with limits.catch() as stop:
            PrimalDualActiveSetQP().solve(qp, limits=limits)
        assert stop.reason == "interrupted"
