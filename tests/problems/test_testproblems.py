"""Tests of the built-in test problems (olado/problems/testproblems.py): analytic derivatives vs
finite differences, the LQ problem against an independent Riccati recursion, IPOPT solves of the
nonlinear problems at N = 50 against the recorded regression values, long horizons."""

from __future__ import annotations

import numpy as np
import pytest

import olado
from olado.errors import ProblemDefinitionError
from olado.problems import PROBLEMS, check_derivatives
from olado.problems.testproblems import (CSTR, PROBLEMS as TEST_PROBLEMS, REGRESSION_VALUES,
                                         LinearQuadratic, VanDerPol)

NONLINEAR = ["vanderpol", "vanderpol-box", "vanderpol-path", "rayleigh", "rayleigh-box", "cstr"]
ALL = ["lq", "lq-box"] + NONLINEAR


def make(name, method=None, **kw):
    if method is not None:
        kw["method"] = method
    return PROBLEMS[name](**kw)


def cases():
    for name in ALL:
        for method in ([None] if name.startswith("lq") else ["rk4", "euler"]):
            yield name, method


CASES = list(cases())
IDS = [f"{n}-{m}" if m else n for n, m in CASES]


def test_registered():
    assert set(ALL) <= set(PROBLEMS)
    assert set(TEST_PROBLEMS) == set(ALL)
    assert {k[0] for k in REGRESSION_VALUES} == set(ALL)


# ============================================================================ derivatives
@pytest.mark.parametrize("name,method", CASES, ids=IDS)
def test_derivatives_against_finite_differences(name, method):
    # Euler on the stiff CSTR needs short steps (see the CSTR docstring)
    p = make(name, method, N=100 if name == "cstr" else 30)
    first = check_derivatives(p, noise=0.1, hessians=False)
    assert first.ok, str(first)
    # second differences of values (the reference) lose digits on CSTR's steep exponential
    rtol = 1e-3 if name == "cstr" else 1e-5
    full = check_derivatives(p, noise=0.1, rtol=rtol, atol=1e-5)
    assert full.ok, str(full)


def _lagrangian_gradient(p, X, U, P, sigma):
    lx, lu = p.eval_stage_cost_gradients(X, U)
    A, B = p.eval_dynamics_jacobians(X, U)
    return np.concatenate([sigma * lx + np.einsum("ki,kij->kj", P, A),
                           sigma * lu + np.einsum("ki,kij->kj", P, B)], axis=1)


@pytest.mark.parametrize("name,method", [c for c in CASES if c[0] in ("vanderpol", "rayleigh", "cstr")],
                         ids=lambda v: str(v))
def test_stage_hessians_are_derivatives_of_analytic_gradients(name, method):
    """Tighter than the value-based check: central differences of the analytic Lagrangian
    gradient, per column of the stage Hessian."""
    p = make(name, method, N=100 if name == "cstr" else 30)
    rng = np.random.default_rng(3)
    U = p.initial_guess() + 0.1 * rng.standard_normal((p.N, p.m))
    X = p.simulate(U)
    P = rng.standard_normal((p.N, p.n))
    sigma = 0.7
    hxx, hxu, huu = p.eval_stage_hessians(X, U, sigma, P)
    H = np.block([[hxx, hxu], [np.swapaxes(hxu, 1, 2), huu]])
    Z = np.concatenate([X[:-1], U], axis=1)
    n = p.n
    for j in range(p.n + p.m):
        h = 1e-6
        Zp, Zm = Z.copy(), Z.copy()
        Zp[:, j] += h
        Zm[:, j] -= h
        gp = _lagrangian_gradient(p, np.vstack([Zp[:, :n], X[-1:]]), Zp[:, n:], P, sigma)
        gm = _lagrangian_gradient(p, np.vstack([Zm[:, :n], X[-1:]]), Zm[:, n:], P, sigma)
        col = (gp - gm) / (2 * h)
        np.testing.assert_allclose(H[:, :, j], col, rtol=1e-6, atol=1e-6)


def test_rk4_cost_is_quadrature_of_running_cost():
    """With zero dynamics sensitivity to the cost state, the RK4 stage cost of a constant
    trajectory is exactly h L: Van der Pol at the rest point x = 0, u = 0 has L = 0; shift u."""
    p = VanDerPol(N=4, x0=[0.0, 0.0])
    X = np.zeros((5, 2))
    U = np.zeros((4, 1))
    np.testing.assert_allclose(p.eval_stage_costs(X, U), 0.0)
    np.testing.assert_allclose(p.eval_dynamics(X, U), 0.0)
    # Euler step by hand
    q = VanDerPol(N=4, method="euler")
    x = np.array([[0.3, -0.2]])
    u = np.array([[0.5]])
    h = q.h
    f = np.array([(1 - 0.04) * 0.3 + 0.2 + 0.5, 0.3])
    np.testing.assert_allclose(q.dynamics(np.array([0]), x, u)[0], x[0] + h * f)
    np.testing.assert_allclose(q.stage_cost(np.array([0]), x, u)[0], h * (0.09 + 0.04 + 0.25))


def test_rk4_converges_to_fourth_order():
    """Simulated final state: errors against a fine RK4 reference shrink by ~16 per halving."""
    U = lambda N: np.full((N, 1), 0.3)   # noqa: E731
    ref = VanDerPol(N=4096).simulate(U(4096))[-1]
    errs = [np.abs(VanDerPol(N=N).simulate(U(N))[-1] - ref).max() for N in (25, 50, 100)]
    assert errs[0] / errs[1] > 12 and errs[1] / errs[2] > 12


def test_step_parameter_and_validation():
    p = VanDerPol(N=10, h=0.1)
    assert p.h == 0.1 and p.T == pytest.approx(1.0)
    q = VanDerPol(N=10, T=2.0)
    assert q.h == pytest.approx(0.2)
    with pytest.raises(ProblemDefinitionError):
        VanDerPol(N=10, method="midpoint")
    with pytest.raises(ProblemDefinitionError):
        VanDerPol(N=0)
    with pytest.raises(ProblemDefinitionError):
        VanDerPol(N=5, h=-1.0)
    assert make("vanderpol-path", N=5).x_lower[0, 0] == -0.4
    assert np.all(make("rayleigh-box", N=5).u_upper == 1.0)
    assert make("cstr", N=5).initial_guess()[0, 0] == 2.0
    assert VanDerPol(N=1).simulate(np.zeros((1, 1))).shape == (2, 2)


@pytest.mark.parametrize("name", NONLINEAR)
def test_long_horizon_builds_and_evaluates(name):
    """N = 100 000 builds and evaluates (timings live in benchmarks/, not here)."""
    p = make(name, N=100_000)
    U = p.initial_guess()
    X = p.simulate(U)
    assert np.all(np.isfinite(X))
    assert np.isfinite(p.objective(X, U))
    A, B = p.eval_dynamics_jacobians(X, U)
    assert A.shape == (100_000, 2, 2) and np.all(np.isfinite(A))
    hxx, _, _ = p.eval_stage_hessians(X, U, 1.0, np.ones((100_000, 2)))
    assert np.all(np.isfinite(hxx))


# ============================================================================ LQ: Riccati
def riccati_solution(p):
    """Finite-horizon discrete Riccati recursion written out in numpy (Bryson and Ho 1975):
    returns the optimal controls, states and cost of the unconstrained LQ problem."""
    A, B, Q, S, R, QN = p.A, p.B, p.Q, p.S, p.R, p.QN
    N = p.N
    P = QN.copy()
    gains = [None] * N
    for k in range(N - 1, -1, -1):
        G = R + B.T @ P @ B
        K = np.linalg.solve(G, S.T + B.T @ P @ A)
        P = Q + A.T @ P @ A - (S + A.T @ P @ B) @ K
        P = 0.5 * (P + P.T)
        gains[k] = K
    x = p.x0.copy()
    X, U = [x], []
    for k in range(N):
        u = -gains[k] @ x
        x = A @ x + B @ u
        U.append(u)
        X.append(x)
    J = 0.5 * p.x0 @ P @ p.x0
    return np.array(X), np.array(U), J


def test_lq_data_has_an_unstable_mode_and_positive_definite_cost():
    p = LinearQuadratic(N=5)
    assert np.max(np.abs(np.linalg.eigvals(p.A))) > 1.0
    H = np.block([[p.Q, p.S], [p.S.T, p.R]])
    assert np.min(np.linalg.eigvalsh(H)) > 0


def test_lq_riccati_cost_equals_objective_of_its_trajectory():
    p = LinearQuadratic(N=20)
    X, U, J = riccati_solution(p)
    np.testing.assert_allclose(p.simulate(U), X, rtol=1e-12, atol=1e-12)
    assert p.objective(X, U) == pytest.approx(J, rel=1e-12)


@pytest.mark.parametrize("N", [1, 3, 50])
def test_lq_ipopt_matches_riccati(N):
    pytest.importorskip("cyipopt")
    p = LinearQuadratic(N=N)
    X, U, J = riccati_solution(p)
    res = olado.solve(p, solver="ipopt", tol=1e-12)
    assert res.success
    assert res.objective == pytest.approx(J, rel=1e-8, abs=1e-10)
    np.testing.assert_allclose(res.u, U, atol=1e-8)
    np.testing.assert_allclose(res.x, X, atol=1e-8)
    if N == 50:
        assert J == pytest.approx(REGRESSION_VALUES[("lq", None)], rel=1e-10)


def test_lq_box_bounds_are_active_and_cost_higher():
    pytest.importorskip("cyipopt")
    p = PROBLEMS["lq-box"](N=50)
    res = olado.solve(p, solver="ipopt", tol=1e-10)
    assert res.success
    assert np.max(np.abs(res.u)) == pytest.approx(1.0, abs=1e-6)
    assert res.objective > riccati_solution(LinearQuadratic(N=50))[2]
    assert res.objective == pytest.approx(REGRESSION_VALUES[("lq-box", None)], rel=1e-7)


# ============================================================================ nonlinear: IPOPT
@pytest.mark.parametrize("name,method", [c for c in CASES if c[1] is not None], ids=lambda v: str(v))
def test_ipopt_solves_nonlinear_problem_at_N50(name, method):
    pytest.importorskip("cyipopt")
    p = make(name, method, N=50)
    res = olado.solve(p, solver="ipopt", tol=1e-10)
    assert res.success, res.message
    assert res.max_constraint_violation <= 1e-8
    assert res.objective == pytest.approx(REGRESSION_VALUES[(name, method)], rel=1e-7)
    # the bounds of the variants are active at the optimum
    if name.endswith("-box"):
        assert np.any(np.isclose(res.u, p.u_lower, atol=1e-6) | np.isclose(res.u, p.u_upper, atol=1e-6))
    if name == "vanderpol-path":
        assert np.min(res.x[:, 0]) == pytest.approx(-0.4, abs=1e-6)
        assert res.objective > REGRESSION_VALUES[("vanderpol-box", method)]


def test_cstr_is_multimodal():
    """From u = 0 IPOPT finds the local minimum ~0.2444, from the default guess the global one."""
    pytest.importorskip("cyipopt")
    p = CSTR(N=200)
    local = olado.solve(p, solver="ipopt", tol=1e-10, guess=np.zeros((200, 1)))
    best = olado.solve(p, solver="ipopt", tol=1e-10)
    assert local.success and best.success
    assert local.objective == pytest.approx(0.24443, abs=1e-4)
    assert best.objective == pytest.approx(0.13311, abs=1e-4)
