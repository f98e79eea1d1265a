"""ContinuousOCP (olado/problems/continuous_ocp.py): ContinuousDOCP's class data on OCP builds
ContinuousDOCP's DOCP. A problem written both ways -- the hand-written ContinuousDOCP (model with
its Jacobian, mayer, terminal) and the ContinuousOCP (the model once) -- has the same dimensions,
x^0 (the T placeholder 0), bounds on every stage, start point, values and first derivatives, and
the same optimum; at a fixed final time a minimum-time problem has no objective. Skips without
CasADi (the comparison of exact and hand-written derivatives needs it)."""

from __future__ import annotations

import numpy as np
import pytest

import olado
from olado.problems import check_derivatives
from olado.problems.continuous import ContinuousDOCP
from olado.problems.continuous_ocp import ContinuousOCP

pytest.importorskip("casadi")


class _Data:
    """A car with quadratic drag to 1 m, at rest, in minimum time, v >= 0, |u| <= 1."""

    name = "drag-car"
    STATES = ("s", "v")
    CONTROLS = ("u",)
    X0 = (0.0, 0.0)
    T = None
    T_BOUNDS = (0.1, 20.0)
    T_GUESS = 3.0
    X_BOUNDS = ((-np.inf, 0.0), None)
    U_BOUNDS = ((-1.0,), (1.0,))
    N_TERMINAL = 2
    TERMINAL_EQUALITIES = [0, 1]
    DEFAULT_N = 31

    def control_guess(self):
        return np.full((self.steps, 1), 0.2)

    def state_guess(self):
        t = np.linspace(0.0, 1.0, self.steps + 1)
        return np.column_stack([t, 0.5 * np.ones_like(t)])


class HandCar(_Data, ContinuousDOCP):
    def model(self, X, U, order):
        v, u = X[:, 1], U[:, 0]
        K = len(v)
        F = np.stack([v, u - 0.1 * v * v, np.zeros(K)], axis=1)
        J = np.zeros((K, 3, 3))
        J[:, 0, 1], J[:, 1, 1], J[:, 1, 2] = 1.0, -0.2 * v, 1.0
        return F, J, None

    def mayer(self, x, order):
        g = np.zeros(self.n)
        g[-1] = 1.0
        return x[-1], g, np.zeros((self.n, self.n))

    def terminal(self, x, order):
        jac = np.zeros((2, self.n))
        jac[0, 0] = jac[1, 1] = 1.0
        return np.array([x[0] - 1.0, x[1]]), jac, np.zeros((2, self.n, self.n))


class OCPCar(_Data, ContinuousOCP):
    MINIMUM_TIME = True

    def ode_rhs(self, x, u):
        return [x[1], u[0] - 0.1 * x[1] ** 2]

    def ode_terminal(self, x, T):
        return [x[0] - 1.0, x[1]]


@pytest.mark.parametrize("method", ["rk4", "euler"])
def test_continuous_ocp_builds_the_continuous_docp(method):
    a, b = OCPCar(method=method), HandCar(method=method)
    assert (a.n, a.m, a.N, a.rN, a.steps, a.h) == (b.n, b.m, b.N, b.rN, b.steps, b.h) == (3, 1, 31, 2, 30, 1 / 30)
    for arr in ("x0", "x_lower", "x_upper", "u_lower", "u_upper", "final_equality_mask"):
        np.testing.assert_array_equal(getattr(a, arr), getattr(b, arr), err_msg=arr)
    assert a.x_lower[0, 1] == 0.0 and a.x0[2] == 0.0      # bounds on x^0 too, T's placeholder 0
    U = b.initial_guess()
    np.testing.assert_array_equal(a.initial_guess(), U)
    np.testing.assert_array_equal(a.initial_state_guess(U), b.initial_state_guess(U))
    U = U + 0.05 * np.random.default_rng(1).standard_normal(U.shape)
    X = b.simulate(U)
    np.testing.assert_allclose(a.simulate(U), X, rtol=1e-14, atol=1e-15)
    report = check_derivatives(a, b, X, U, rtol=1e-12, atol=1e-14, hessians=False)
    assert report.ok, str(report)
    # the hand-written Hessians are central differences of its exact gradients
    report = check_derivatives(a, b, X, U, rtol=1e-6, atol=1e-8)
    assert report.ok, str(report)


def test_continuous_ocp_same_optimum_and_fixed_time():
    """The same optimum by sqp-ip; with a fixed final time the minimum-time objective is left
    out (a constant), as ContinuousDOCP's problems with T set (steering-too-short) have it."""
    ra, rb = (olado.solve(cls(), config="configs/sqp-ip.ini") for cls in (OCPCar, HandCar))
    assert ra.success and rb.success, (ra.message, rb.message)
    assert abs(ra.objective - rb.objective) < 1e-8 and 2.0 < ra.objective < 3.0

    class FixedCar(OCPCar):
        T = 4.0

    p = FixedCar(N=20)
    assert not p.free_time and p.N == 20 and p.h == 0.2
    U = p.initial_guess()
    assert p.objective(p.simulate(U), U) == 0.0
