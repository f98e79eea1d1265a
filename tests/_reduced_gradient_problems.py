"""Unconstrained DOCPs with analytic first and second derivatives (vectorized) for the
control-space method tests: an LQ problem with its exact Riccati solution, a damped pendulum
and a Van der Pol oscillator."""

import numpy as np

from olado.problems import DOCP


class LQ(DOCP):
    """x+ = A x + B u, f0 = 0.5 (x'Qx + u'Ru), F = 0.5 x'P x (time-invariant, n=3, m=2)."""

    name = "lq-test"
    vectorized = True

    def __init__(self, N=30, **kw):
        self.A = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.05, -0.1, 0.95]])
        self.Bm = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
        self.Q = np.diag([1.0, 0.5, 0.2])
        self.R = np.array([[0.1, 0.02], [0.02, 0.2]])
        self.P = 10.0 * np.eye(3)
        super().__init__(3, 2, N, [1.0, -1.0, 0.5], **kw)

    def dynamics(self, k, x, u):
        return x @ self.A.T + u @ self.Bm.T

    def stage_cost(self, k, x, u):
        return 0.5 * (np.einsum("ki,ij,kj->k", x, self.Q, x) + np.einsum("ki,ij,kj->k", u, self.R, u))

    def final_cost(self, x):
        return 0.5 * float(x @ self.P @ x)

    def dynamics_jacobian(self, k, x, u):
        K = len(k)
        return np.broadcast_to(self.A, (K, 3, 3)).copy(), np.broadcast_to(self.Bm, (K, 3, 2)).copy()

    def stage_cost_gradient(self, k, x, u):
        return x @ self.Q, u @ self.R

    def final_cost_gradient(self, x):
        return self.P @ x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        K = len(k)
        return (sigma * np.broadcast_to(self.Q, (K, 3, 3)).copy(), np.zeros((K, 3, 2)),
                sigma * np.broadcast_to(self.R, (K, 2, 2)).copy())

    def final_hessian(self, x, sigma, lam):
        return sigma * self.P

    def riccati_solution(self):
        """Exact optimal (X, U, J) by the discrete Riccati recursion."""
        A, B, Q, R = self.A, self.Bm, self.Q, self.R
        P = self.P.copy()
        gains = []
        for _ in range(self.N):
            K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
            P = Q + A.T @ P @ (A - B @ K)
            gains.append(K)
        gains.reverse()
        X = np.empty((self.N + 1, 3)); U = np.empty((self.N, 2))
        X[0] = self.x0
        for k in range(self.N):
            U[k] = -gains[k] @ X[k]
            X[k + 1] = A @ X[k] + B @ U[k]
        J = 0.5 * float(self.x0 @ P @ self.x0)
        return X, U, J


class Pendulum(DOCP):
    """Damped pendulum driven from rest to angle 1: f0 = 0.5 dt ((x0-1)^2 + 0.1 x1^2 + u^2),
    F = 5 ((x0-1)^2 + x1^2)."""

    name = "pendulum-unconstrained"
    vectorized = True
    dt, c = 0.1, 0.2

    def __init__(self, N=40, **kw):
        super().__init__(2, 1, N, [0.0, 0.0], **kw)

    def dynamics(self, k, x, u):
        dt = self.dt
        return np.stack([x[:, 0] + dt * x[:, 1], x[:, 1] + dt * (-np.sin(x[:, 0]) - self.c * x[:, 1] + u[:, 0])], 1)

    def stage_cost(self, k, x, u):
        return 0.5 * self.dt * ((x[:, 0] - 1) ** 2 + 0.1 * x[:, 1] ** 2 + u[:, 0] ** 2)

    def final_cost(self, x):
        return 5.0 * ((x[0] - 1) ** 2 + x[1] ** 2)

    def dynamics_jacobian(self, k, x, u):
        dt, K = self.dt, len(k)
        A = np.zeros((K, 2, 2)); A[:, 0, 0] = 1; A[:, 0, 1] = dt
        A[:, 1, 0] = -dt * np.cos(x[:, 0]); A[:, 1, 1] = 1 - dt * self.c
        B = np.zeros((K, 2, 1)); B[:, 1, 0] = dt
        return A, B

    def stage_cost_gradient(self, k, x, u):
        dt = self.dt
        return np.stack([dt * (x[:, 0] - 1), 0.1 * dt * x[:, 1]], 1), dt * u

    def final_cost_gradient(self, x):
        return np.array([10.0 * (x[0] - 1), 10.0 * x[1]])

    def stage_hessian(self, k, x, u, sigma, p, lam):
        dt, K = self.dt, len(k)
        hxx = np.zeros((K, 2, 2)); hxx[:, 0, 0] = sigma * dt + p[:, 1] * dt * np.sin(x[:, 0])
        hxx[:, 1, 1] = sigma * 0.1 * dt
        return hxx, np.zeros((K, 2, 1)), np.full((K, 1, 1), sigma * dt)

    def final_hessian(self, x, sigma, lam):
        return 10.0 * sigma * np.eye(2)


class VanDerPol(DOCP):
    """Van der Pol oscillator regulated to the origin: x0+ = x0 + dt x1,
    x1+ = x1 + dt ((1 - x0^2) x1 - x0 + u); f0 = 0.5 dt (x'x + u^2), F = x'x."""

    name = "vanderpol-unconstrained"
    vectorized = True
    dt = 0.1

    def __init__(self, N=50, **kw):
        super().__init__(2, 1, N, [1.0, 0.0], **kw)

    def dynamics(self, k, x, u):
        dt = self.dt
        x0, x1 = x[:, 0], x[:, 1]
        return np.stack([x0 + dt * x1, x1 + dt * ((1 - x0 ** 2) * x1 - x0 + u[:, 0])], 1)

    def stage_cost(self, k, x, u):
        return 0.5 * self.dt * ((x * x).sum(1) + u[:, 0] ** 2)

    def final_cost(self, x):
        return float(x @ x)

    def dynamics_jacobian(self, k, x, u):
        dt, K = self.dt, len(k)
        x0, x1 = x[:, 0], x[:, 1]
        A = np.zeros((K, 2, 2)); A[:, 0, 0] = 1; A[:, 0, 1] = dt
        A[:, 1, 0] = dt * (-2 * x0 * x1 - 1); A[:, 1, 1] = 1 + dt * (1 - x0 ** 2)
        B = np.zeros((K, 2, 1)); B[:, 1, 0] = dt
        return A, B

    def stage_cost_gradient(self, k, x, u):
        return self.dt * x, self.dt * u

    def final_cost_gradient(self, x):
        return 2 * x

    def stage_hessian(self, k, x, u, sigma, p, lam):
        dt, K = self.dt, len(k)
        x0, x1 = x[:, 0], x[:, 1]
        hxx = np.zeros((K, 2, 2))
        hxx[:, 0, 0] = sigma * dt + p[:, 1] * dt * (-2 * x1)
        hxx[:, 0, 1] = hxx[:, 1, 0] = p[:, 1] * dt * (-2 * x0)
        hxx[:, 1, 1] = sigma * dt
        return hxx, np.zeros((K, 2, 1)), np.full((K, 1, 1), sigma * dt)

    def final_hessian(self, x, sigma, lam):
        return 2 * sigma * np.eye(2)
