"""Small DOCPs with hand-written analytic derivatives, shared by the core tests."""

import numpy as np

from olado.problems import DOCP


class Pendulum(DOCP):
    """Damped pendulum, Euler-discretized, with one mixed stage constraint and a final equality.

    x = (angle, rate), u = torque; f0 = 0.5 (x.x + u^2) + 0.1 cos(x1 u); F = x.x;
    g^k = 1 - x1^2 - 0.5 u^2 >= 0 (component 0);  g^N = x0 - 0.2 = 0 (equality).
    """

    name = "pendulum"
    dt = 0.1

    def __init__(self, N=6, **kw):
        kw.setdefault("u_bounds", (-2.0, 2.0))
        super().__init__(2, 1, N, [1.0, 0.0], n_stage_constraints=1, n_final_constraints=1,
                         final_equalities=[0], **kw)

    def dynamics(self, k, x, u):
        dt = self.dt
        return np.array([x[0] + dt * x[1], x[1] + dt * (-np.sin(x[0]) - 0.1 * x[1] + u[0] * (1 + 0.01 * k))])

    def stage_cost(self, k, x, u):
        return 0.5 * (x @ x + u[0] ** 2) + 0.1 * np.cos(x[1] * u[0])

    def final_cost(self, x):
        return float(x @ x)

    def stage_constraints(self, k, x, u):
        return np.array([1.0 - x[1] ** 2 - 0.5 * u[0] ** 2])

    def final_constraints(self, x):
        return np.array([x[0] - 0.2])

    # analytic derivatives
    def dynamics_jacobian(self, k, x, u):
        dt = self.dt
        A = np.array([[1.0, dt], [-dt * np.cos(x[0]), 1 - 0.1 * dt]])
        B = np.array([[0.0], [dt * (1 + 0.01 * k)]])
        return A, B

    def stage_cost_gradient(self, k, x, u):
        s = np.sin(x[1] * u[0])
        return np.array([x[0], x[1] - 0.1 * s * u[0]]), np.array([u[0] - 0.1 * s * x[1]])

    def final_cost_gradient(self, x):
        return 2 * x

    def stage_constraints_jacobian(self, k, x, u):
        return np.array([[0.0, -2 * x[1]]]), np.array([[-u[0]]])

    def final_constraints_jacobian(self, x):
        return np.array([[1.0, 0.0]])

    def stage_hessian(self, k, x, u, sigma, p, lam):
        c = np.cos(x[1] * u[0]); s = np.sin(x[1] * u[0])
        hxx = sigma * np.array([[1.0, 0.0], [0.0, 1 - 0.1 * c * u[0] ** 2]])
        hxx[0, 0] += p[1] * self.dt * np.sin(x[0])
        hxx[1, 1] += lam[0] * -2.0
        hxu = sigma * np.array([[0.0], [-0.1 * (s + c * x[1] * u[0])]])
        huu = sigma * np.array([[1 - 0.1 * c * x[1] ** 2]]) + lam[0] * np.array([[-1.0]])
        return hxx, hxu, huu

    def final_hessian(self, x, sigma, lam):
        return 2 * sigma * np.eye(2)


class PendulumFD(Pendulum):
    """The same problem with no analytic derivatives at all (finite differences only)."""

    name = "pendulum-fd"
    dynamics_jacobian = DOCP.dynamics_jacobian
    stage_cost_gradient = DOCP.stage_cost_gradient
    final_cost_gradient = DOCP.final_cost_gradient
    stage_constraints_jacobian = DOCP.stage_constraints_jacobian
    final_constraints_jacobian = DOCP.final_constraints_jacobian
    stage_hessian = DOCP.stage_hessian
    final_hessian = DOCP.final_hessian


class PendulumVectorized(Pendulum):
    """The same problem written for all stages at once."""

    name = "pendulum-vec"
    vectorized = True

    def dynamics(self, k, x, u):
        dt = self.dt
        return np.stack([x[:, 0] + dt * x[:, 1],
                         x[:, 1] + dt * (-np.sin(x[:, 0]) - 0.1 * x[:, 1] + u[:, 0] * (1 + 0.01 * k))], axis=1)

    def stage_cost(self, k, x, u):
        return 0.5 * ((x * x).sum(1) + u[:, 0] ** 2) + 0.1 * np.cos(x[:, 1] * u[:, 0])

    def stage_constraints(self, k, x, u):
        return (1.0 - x[:, 1] ** 2 - 0.5 * u[:, 0] ** 2)[:, None]

    dynamics_jacobian = DOCP.dynamics_jacobian
    stage_cost_gradient = DOCP.stage_cost_gradient
    stage_constraints_jacobian = DOCP.stage_constraints_jacobian
    stage_hessian = DOCP.stage_hessian
