"""Bounds of state steps that the QP's equality rows fix (olado.solvers.sqp.step.fixed_states,
drop_fixed_bounds): the states a parameter stage copies from x0, and a final state fixed by a
singleton row. At their limits such bounds are active at every feasible point, the QP has no
strictly feasible point, and the interior-point QP's multipliers grow without bound (goddard with
sqp-ip: 1.27e6, ACCEPTABLE +8.6e-5 above IPOPT). References: hand computations, a dense KKT solve
of the QP, IPOPT's stored objective of the robustness set."""

from pathlib import Path

import numpy as np
import pytest

import olado
from olado.problems.suites import load_references, load_suite
from olado.qp import make_qp_solver
from olado.qp.stageqp import StageQP, qp_kkt_residuals
from olado.result import Status
from olado.solvers.sqp.step import drop_fixed_bounds, fixed_states

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _parameter_stage_qp(seed=0, N=5, n=3):
    """A QP whose stage 0 is a parameter stage -- x_1 = (x0_0, x0_1, u_0) -- and whose final row
    2 x_N[1] - 2 t = 0 fixes x_N[1] = t, with bounds at the fixed values: x_1[0] >= x0_0,
    x_1[1] <= x0_1, x_N[1] >= t (all active at every feasible point); no other bound."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((N + 1, n, n)); Q = M @ M.transpose(0, 2, 1) / n + 0.1 * np.eye(n)
    R = np.full((N, 1, 1), 0.5)
    A = 0.8 * rng.standard_normal((N, n, n)) / np.sqrt(n); B = rng.standard_normal((N, n, 1))
    A[0] = np.diag([1.0, 1.0, 0.0]); B[0] = np.array([[0.0], [0.0], [1.0]])
    c = 0.1 * rng.standard_normal((N, n)); c[0] = 0.0
    x0 = np.array([0.2, -0.1, 0.0])
    t = 0.3
    xl = np.full((N + 1, n), -np.inf); xu = np.full((N + 1, n), np.inf)
    xl[1, 0] = x0[0]; xu[1, 1] = x0[1]; xl[N, 1] = t
    qp = StageQP(Q=Q, R=R, q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, 1)), A=A, B=B, c=c, x0=x0,
                 EN=np.array([[0.0, 2.0, 0.0]]), eN=np.array([-2.0 * t]), x_lower=xl, x_upper=xu)
    return qp, t


def _dense_solution(qp):
    """The QP's solution from its dense KKT system over the equality rows only (its bounds are
    active at every feasible point, so they do not change the solution): (y, max |multiplier|)."""
    d = qp.to_sparse()
    P, Aeq = d["P"].toarray(), d["A_eq"].toarray()
    nv, ne = P.shape[0], Aeq.shape[0]
    K = np.block([[P, Aeq.T], [Aeq, np.zeros((ne, ne))]])
    sol = np.linalg.solve(K, np.concatenate([-d["q"], d["b_eq"]]))
    return sol[:nv], float(np.max(np.abs(sol[nv:])))


def _dropped(qp):
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    drop_fixed_bounds(qp.A, qp.B, qp.c, qp.x0, xl, xu, qp.EN, qp.eN)
    d = {f: getattr(qp, f) for f in ("Q", "R", "S", "q", "r", "A", "B", "c", "x0", "EN", "eN", "u_lower", "u_upper")}
    return StageQP(x_lower=xl, x_upper=xu, **d)


def test_fixed_states_of_a_parameter_stage_and_a_singleton_final_row():
    qp, t = _parameter_stage_qp()
    fixed, value = fixed_states(qp.A, qp.B, qp.c, qp.x0, qp.EN, qp.eN)
    expected = np.zeros_like(fixed)
    expected[0] = True                      # the x0 row
    expected[1] = [True, True, False]       # copied by the parameter stage; x_1[2] = u_0
    expected[-1, 1] = True                  # the singleton final row
    np.testing.assert_array_equal(fixed, expected)
    np.testing.assert_allclose(value[1, :2], qp.x0[:2])
    assert value[-1, 1] == pytest.approx(t)


def test_an_euler_position_is_fixed_one_stage_only():
    # x = (position, velocity), x_{k+1} = x_k + h (v_k, u_k): x_1's position only
    h, N = 0.1, 4
    A = np.tile(np.array([[1.0, h], [0.0, 1.0]]), (N, 1, 1)); B = np.tile(np.array([[0.0], [h]]), (N, 1, 1))
    c = np.full((N, 2), 0.01)
    fixed, value = fixed_states(A, B, c, np.array([1.0, 2.0]))
    np.testing.assert_array_equal(fixed[1:], [[True, False], [False, False], [False, False], [False, False]])
    assert value[1, 0] == pytest.approx(1.0 + h * 2.0 + 0.01)


def _clock(N=50, offset=0.1):
    """x = (t, v): t_{k+1} = t_k + offset (no control), v_{k+1} = v_k + u_k."""
    A = np.tile(np.eye(2), (N, 1, 1)); B = np.tile(np.array([[0.0], [1.0]]), (N, 1, 1))
    c = np.zeros((N, 2)); c[:, 0] = offset
    return A, B, c


def test_a_clock_is_fixed_over_the_horizon():
    N = 50
    A, B, c = _clock(N)
    fixed, value = fixed_states(A, B, c, np.array([0.5, 0.0]))
    assert fixed[:, 0].all() and not fixed[1:, 1].any()
    np.testing.assert_allclose(value[:, 0], 0.5 + 0.1 * np.arange(N + 1))    # the stage-by-stage path
    # without bounds on t, or with zero offsets from a zero start, the one vectorized test
    bounds = np.zeros((N + 1, 2), dtype=bool)
    skipped, _ = fixed_states(A, B, c, np.array([0.5, 0.0]), wanted=bounds)
    np.testing.assert_array_equal(skipped, fixed)
    A, B, c = _clock(N, offset=0.0)
    bounds[:, 0] = True
    skipped, zero = fixed_states(A, B, c, np.zeros(2), wanted=bounds)
    np.testing.assert_array_equal(skipped, fixed)
    assert not zero.any()


def test_only_satisfied_bounds_of_fixed_states_are_dropped():
    qp, t = _parameter_stage_qp()
    xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
    xl[1, 0] = qp.x0[0] + 1e-3              # violated by the fixed value: kept (the QP is infeasible)
    xl[2, 0] = -1.0                          # x_2 is not fixed: kept
    drop_fixed_bounds(qp.A, qp.B, qp.c, qp.x0, xl, xu, qp.EN, qp.eN)
    assert xl[1, 0] == qp.x0[0] + 1e-3 and xl[2, 0] == -1.0
    assert xu[1, 1] == np.inf and xl[-1, 1] == -np.inf


def test_the_qp_without_the_fixed_bounds_solves_the_qp():
    """The same solution as the dense KKT solve, the original QP's KKT conditions with zero
    multipliers on the dropped bounds, and multipliers of the dense solve's size."""
    qp, _ = _parameter_stage_qp()
    y, largest = _dense_solution(qp)
    reduced = _dropped(qp)
    res = make_qp_solver("mehrotra", tol=1e-10).solve(reduced)
    assert res.status is Status.SUCCESS, res.message
    np.testing.assert_allclose(qp.pack(res.X, res.U), y, atol=1e-8)
    kkt = qp_kkt_residuals(qp, res)             # the original QP, bounds included
    assert max(kkt.values()) < 1e-8, kkt
    mults = max(float(np.max(np.abs(a), initial=0.0)) for a in (res.lam, res.nu, res.zx_lower, res.zx_upper))
    assert mults == pytest.approx(largest, rel=1e-6)


@pytest.mark.slow
def test_goddard_with_sqp_ip_reaches_ipopts_optimum():
    """Before: ACCEPTABLE at +8.6e-5 relative above IPOPT after 19 iterations, the QP multipliers
    1.27e6 (IPOPT's largest 4.8) and the Hessian shift raised to 4e7."""
    problem, guess = next(e for e in load_suite("robustness") if e.name == "goddard").build()
    ref = load_references()["entries"]["goddard"]["objective"]
    r = olado.solve(problem, guess=guess, config=CONFIGS / "sqp-ip.ini")
    assert r.status is Status.SUCCESS, r.message
    assert r.objective == pytest.approx(ref, rel=1e-6)
    assert r.iterations <= 60
