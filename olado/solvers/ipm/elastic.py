"""IPOPT's restoration phase as a DOCP (Waechter and Biegler 2006, sec. 3.3, eq. (30)), solved by
the same interior-point method: the dynamics and the stage constraints are relaxed by elastic
variables p, n >= 0 that enter as extra controls (the structure of the QP's elastic mode,
olado.qp.elastic), so the restoration problem is again an LQ-DOCP per Newton step,

    min  rho sum (p + n) + zeta/2 |D_R (x - x_R)|^2 + zeta/2 |D_R (u - u_R)|^2
    s.t. x^{k+1} = f^k(x^k, u^k) - p_h^k + n_h^k,   g^k(x^k, u^k) - p_g^k + n_g^k  (= 0 | >= 0),
         g^N(x^N) as before (no control reaches it), the bounds of x and u,

with rho = 1000, zeta = sqrt(mu), D_R = diag(min(1, 1 / |x_R|)) (IPOPT's resto_penalty_parameter
and proximity weights). The elastic variables start at IPOPT's closed form (eq. (33)) for the
residuals at the current point. The phase ends as soon as an iterate is acceptable to the
original filter with theta reduced to kappa_resto = 0.9 of its start; a converged restoration
problem whose elastic variables stay positive is a local minimizer of the l1 violation: the
problem is locally infeasible.
"""

from __future__ import annotations

import numpy as np

RHO = 1000.0


class ElasticDOCP:
    """The restoration problem of ``problem`` at the reference point (XR, UR) with barrier
    parameter mu: a duck-typed DOCP (the evaluations the interior-point solver calls) with
    controls (u, p_h, n_h, p_g, n_g)."""

    def __init__(self, problem, XR, UR, mu):
        p = self.base = problem
        self.N, self.n, self.r, self.rN = p.N, p.n, p.r, p.rN
        self.m0 = p.m
        self.m = p.m + 2 * p.n + 2 * p.r
        self.x0 = p.x0
        self.stage_equality_mask = p.stage_equality_mask
        self.final_equality_mask = p.final_equality_mask
        self.x_lower, self.x_upper = p.x_lower, p.x_upper
        ne = self.m - self.m0
        self.u_lower = np.concatenate([p.u_lower, np.zeros((p.N, ne))], axis=1)
        self.u_upper = np.concatenate([p.u_upper, np.full((p.N, ne), np.inf)], axis=1)
        self.XR, self.UR = XR.copy(), UR.copy()
        self.zeta = float(np.sqrt(mu))
        self.Dx = np.minimum(1.0, 1.0 / np.maximum(np.abs(XR), 1e-300)) ** 2
        self.Du = np.minimum(1.0, 1.0 / np.maximum(np.abs(UR), 1e-300)) ** 2
        self.name = f"restoration of {getattr(p, 'name', type(p).__name__)}"

    # -- the controls
    def split(self, U):
        m, n, r = self.m0, self.n, self.r
        return U[:, :m], U[:, m:m + n], U[:, m + n:m + 2 * n], U[:, m + 2 * n:m + 2 * n + r], U[:, m + 2 * n + r:]

    def start_controls(self, X, U, mu):
        """(u, p_h, n_h, p_g, n_g) with the elastic variables of eq. (33) for the dynamics residuals
        and the stage constraint violations at (X, U)."""
        p = self.base
        h = p.eval_dynamics(X, U) - X[1:]
        g = p.eval_stage_constraints(X, U)
        cg = np.where(self.stage_equality_mask, g, np.minimum(g, 0.0))
        parts = [U]
        for c in (h, cg):
            a = (mu - RHO * c) / (2 * RHO)
            nn = a + np.sqrt(a * a + mu * c / (2 * RHO))
            parts += [c + nn, nn]
        return np.concatenate(parts, axis=1)

    # -- the evaluations the solver calls
    def objective(self, X, U):
        u, ph, nh, pg, ng = self.split(U)
        el = ph.sum() + nh.sum() + pg.sum() + ng.sum()
        prox = (self.Dx[1:] * (X[1:] - self.XR[1:]) ** 2).sum() + (self.Du * (u - self.UR) ** 2).sum()
        return float(RHO * el + 0.5 * self.zeta * prox)

    def eval_dynamics(self, X, U):
        u, ph, nh, _, _ = self.split(U)
        return self.base.eval_dynamics(X, u) - ph + nh

    def eval_stage_constraints(self, X, U):
        u, _, _, pg, ng = self.split(U)
        return self.base.eval_stage_constraints(X, u) - pg + ng

    def eval_final_constraints(self, xN):
        return self.base.eval_final_constraints(xN)

    def eval_stage_cost_gradients(self, X, U):
        u = self.split(U)[0]
        lx = self.zeta * self.Dx[:-1] * (X[:-1] - self.XR[:-1])
        lx[0] = 0.0
        lu = np.concatenate([self.zeta * self.Du * (u - self.UR), np.full((self.N, self.m - self.m0), RHO)], axis=1)
        return lx, lu

    def eval_final_cost_gradient(self, xN):
        return self.zeta * self.Dx[-1] * (xN - self.XR[-1])

    def eval_dynamics_jacobians(self, X, U):
        A, B = self.base.eval_dynamics_jacobians(X, self.split(U)[0])
        N, n, r = self.N, self.n, self.r
        eye = np.broadcast_to(np.eye(n), (N, n, n))
        return A, np.concatenate([B, -eye, eye, np.zeros((N, n, 2 * r))], axis=2)

    def eval_stage_constraint_jacobians(self, X, U):
        Cx, Cu = self.base.eval_stage_constraint_jacobians(X, self.split(U)[0])
        N, n, r = self.N, self.n, self.r
        eye = np.broadcast_to(np.eye(r), (N, r, r))
        return Cx, np.concatenate([Cu, np.zeros((N, r, 2 * n)), -eye, eye], axis=2)

    def eval_final_constraint_jacobian(self, xN):
        return self.base.eval_final_constraint_jacobian(xN)

    def eval_stage_hessians(self, X, U, sigma, P, L):
        Hxx, Hxu, Huu = self.base.eval_stage_hessians(X, self.split(U)[0], 0.0, P, L)
        N, n, m0, m = self.N, self.n, self.m0, self.m
        Hxx = Hxx + sigma * self.zeta * np.einsum("ki,ij->kij", self.Dx[:-1], np.eye(n))
        Hxu2 = np.zeros((N, n, m)); Hxu2[:, :, :m0] = Hxu
        Huu2 = np.zeros((N, m, m)); Huu2[:, :m0, :m0] = Huu + sigma * self.zeta * np.einsum("ki,ij->kij", self.Du, np.eye(m0))
        return Hxx, Hxu2, Huu2

    def eval_final_hessian(self, xN, sigma, lN):
        return self.base.eval_final_hessian(xN, 0.0, lN) + sigma * self.zeta * np.diag(self.Dx[-1])

    def elastic_sum(self, U):
        _, ph, nh, pg, ng = self.split(U)
        return float(ph.sum() + nh.sum() + pg.sum() + ng.sum())
