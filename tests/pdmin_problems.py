"""Bound-constrained DOCPs (controls only) for the PDMIN tests and benchmarks: vectorized, with
analytic first and second derivatives; the linear one simulates in a compiled loop so that
N = 100 000 is cheap."""

import numpy as np

from olado.problems import DOCP
from olado.problems.testproblems import _linear_simulate as _simulate_linear


class LinearTracking(DOCP):
    """x^{k+1} = A x^k + B u^k;  f0 = 0.5 (x - r^k)'Q(x - r^k) + 0.5 u'R u;  F = 0.5 (x - r^N)'QN(x - r^N);
    u_L^k <= u^k <= u_U^k (stationary or per stage)."""

    name = "linear-tracking"
    vectorized = True

    def __init__(self, N, A, B, Q, R, QN, ref, x0, u_bounds):
        A, B = np.atleast_2d(A).astype(float), np.atleast_2d(B).astype(float)
        n, m = B.shape
        self.A, self.B = A, B
        self.Q, self.R, self.QN = (np.atleast_2d(M).astype(float) for M in (Q, R, QN))
        self.ref = np.asarray(ref, dtype=float).reshape(N + 1, n)
        super().__init__(n, m, N, x0, u_bounds=u_bounds)

    def simulate(self, U):
        U = self.check_array(U, (self.N, self.m), "simulate", "u")
        X = np.empty((self.N + 1, self.n))
        self.counters["dynamics"] += 1
        _simulate_linear(self.A, self.B, self.x0, np.ascontiguousarray(U), X)
        return self._check_stacked(X, (self.N + 1, self.n), "simulate", "x")

    def dynamics(self, k, x, u):
        return x @ self.A.T + u @ self.B.T

    def stage_cost(self, k, x, u):
        e = x - self.ref[k]
        return 0.5 * (np.einsum("ki,ij,kj->k", e, self.Q, e) + np.einsum("ki,ij,kj->k", u, self.R, u))

    def final_cost(self, x):
        e = x - self.ref[-1]
        return 0.5 * float(e @ self.QN @ e)

    def dynamics_jacobian(self, k, x, u):
        K = len(k)
        return np.broadcast_to(self.A, (K,) + self.A.shape), np.broadcast_to(self.B, (K,) + self.B.shape)

    def stage_cost_gradient(self, k, x, u):
        return (x - self.ref[k]) @ self.Q.T, u @ self.R.T

    def final_cost_gradient(self, x):
        return self.QN @ (x - self.ref[-1])

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K = len(k)
        return (np.broadcast_to(sigma * self.Q, (K, self.n, self.n)), np.zeros((K, self.n, self.m)),
                np.broadcast_to(sigma * self.R, (K, self.m, self.m)))

    def final_hessian(self, x, sigma, lam):
        return sigma * self.QN


def scalar_tracking(N=200, umax=1.5, nonstationary=False):
    """x+ = 0.9 x + 0.1 u tracking r^k = 2 sin(4 pi k / N) with 0.05 u^2 cost: the unconstrained
    optimal u reaches about +-4, so |u| <= umax is active on long arcs. A contraction: the
    reduced Hessian has a condition number bounded independently of N."""
    k = np.arange(N + 1)
    ref = 2.0 * np.sin(4 * np.pi * k / N)
    if nonstationary:
        kk = np.arange(N)
        upper = (umax * (1.0 + 0.5 * np.cos(2 * np.pi * kk / N)))[:, None]
        lower = -(umax * (1.0 + 0.5 * np.sin(6 * np.pi * kk / N)))[:, None]
        bounds = (lower, upper)
    else:
        bounds = (-umax, umax)
    return LinearTracking(N, [[0.9]], [[0.1]], [[1.0]], [[0.05]], [[1.0]], ref[:, None], [0.0], bounds)


def double_tracking(N=300):
    """A two-state, two-control tracking problem with coupled dynamics and nonstationary bounds
    (one control bounded only from below on part of the horizon)."""
    A = [[0.95, 0.1], [-0.1, 0.9]]
    B = [[0.1, 0.0], [0.02, 0.1]]
    k = np.arange(N + 1)
    ref = np.column_stack([np.sin(6 * np.pi * k / N), 1.5 * np.cos(2 * np.pi * k / N)])
    lo = np.full((N, 2), -1.0); hi = np.full((N, 2), 1.0)
    lo[:, 1] = -0.5 - 0.25 * np.arange(N) / N
    hi[: N // 3, 1] = np.inf
    return LinearTracking(N, A, B, np.diag([1.0, 0.5]), np.diag([0.02, 0.05]), np.eye(2), ref, [0.5, -0.5], (lo, hi))


class BoundedPendulum(DOCP):
    """Nonlinear: damped pendulum swung towards rest from angle 1 with a torque |u| <= umax.

    x+ = (x1 + h x2, x2 + h (-sin x1 - 0.1 x2 + u));  f0 = h/2 (x1^2 + x2^2 + 0.1 u^2);  F = 5 |x|^2.
    """

    name = "bounded-pendulum"
    vectorized = True
    h = 0.1

    def __init__(self, N=60, umax=1.0):
        super().__init__(2, 1, N, [1.5, 0.0], u_bounds=(-umax, umax))

    def dynamics(self, k, x, u):
        h = self.h
        return np.column_stack([x[:, 0] + h * x[:, 1], x[:, 1] + h * (-np.sin(x[:, 0]) - 0.1 * x[:, 1] + u[:, 0])])

    def stage_cost(self, k, x, u):
        return 0.5 * self.h * (x[:, 0] ** 2 + x[:, 1] ** 2 + 0.1 * u[:, 0] ** 2)

    def final_cost(self, x):
        return 5.0 * float(x @ x)

    def dynamics_jacobian(self, k, x, u):
        h, K = self.h, len(k)
        A = np.zeros((K, 2, 2)); B = np.zeros((K, 2, 1))
        A[:, 0, 0] = 1.0; A[:, 0, 1] = h
        A[:, 1, 0] = -h * np.cos(x[:, 0]); A[:, 1, 1] = 1.0 - 0.1 * h
        B[:, 1, 0] = h
        return A, B

    def stage_cost_gradient(self, k, x, u):
        return self.h * x, 0.1 * self.h * u

    def final_cost_gradient(self, x):
        return 10.0 * x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        h, K = self.h, len(k)
        Hxx = np.zeros((K, 2, 2)); Hxu = np.zeros((K, 2, 1)); Huu = np.zeros((K, 1, 1))
        Hxx[:, 0, 0] = sigma * h + p[:, 1] * h * np.sin(x[:, 0])
        Hxx[:, 1, 1] = sigma * h
        Huu[:, 0, 0] = 0.1 * sigma * h
        return Hxx, Hxu, Huu

    def final_hessian(self, x, sigma, lam):
        return 10.0 * sigma * np.eye(2)
