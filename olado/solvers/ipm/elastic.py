"""IPOPT's restoration phase as a DOCP (Waechter and Biegler 2006, sec. 3.3, eq. (30)), solved by
the same interior-point method: every constraint row is relaxed by elastic variables p, n >= 0,

    min  rho sum (p + n) + zeta/2 |D_R (x - x_R)|^2 + zeta/2 |D_R (u - u_R)|^2
    s.t. x^{k+1} = f^k(x^k, u^k) - p_h^k + n_h^k,   g^k(x^k, u^k) - p_g^k + n_g^k  (= 0 | >= 0),
         g^N(x^N) - p_N + n_N  (= 0 | >= 0),   the bounds of x and u,

with rho = 1000, zeta = sqrt(mu) (mu the restoration problem's barrier parameter, followed as it
decreases), D_R = diag(min(1, 1 / |x_R|)) (IPOPT's resto_penalty_parameter and proximity
weights). The dynamics and stage elastic variables are extra controls of their stage (the
structure of the QP's elastic mode, olado.qp.elastic); the final rows depend on x^N alone, which
no control of stage N-1 reaches directly, so their elastic variables are carried by extra
states e = (p_N, n_N) with e^{k+1} = w^k, controls w^k >= 0 costing rho each: e^N = w^{N-1} is
IPOPT's pair (one variable, one barrier term), and the w^k of the other stages enter nothing but
their own terms rho w - mu ln w, so they sit at w = mu / rho (their start) and leave the
restoration problem IPOPT's; it stays an LQ-DOCP per Newton step (one Riccati factorization). The inequality rows keep the
slacks of the original problem (IPOPT relaxes d(x) - s), and the elastic variables start at the
closed form (33) for the residuals c of the current point (p - n = c).
"""

from __future__ import annotations

import numpy as np

#: IPOPT's resto_penalty_parameter
RHO = 1000.0


def elastic_start(c, mu):
    """Eq. (33): the minimizer (p, n) of rho (p + n) - mu ln p - mu ln n subject to p - n = c."""
    a = (mu - RHO * c) / (2 * RHO)
    n = a + np.sqrt(a * a + mu * c / (2 * RHO))
    return c + n, n


class ElasticDOCP:
    """The restoration problem of ``problem`` at the reference point (XR, UR) with barrier
    parameter mu: a duck-typed DOCP (the evaluations the interior-point solver calls) with
    states (x, p_N, n_N) and controls (u, p_h, n_h, p_g, n_g, w)."""

    def __init__(self, problem, XR, UR, mu):
        p = self.base = problem
        self.N, self.r, self.rN = p.N, p.r, p.rN
        self.n0, self.m0 = p.n, p.m
        self.n = p.n + 2 * p.rN
        self.m = p.m + 2 * p.n + 2 * p.r + 2 * p.rN
        self.x0 = np.concatenate([np.asarray(p.x0, float), np.zeros(2 * p.rN)])
        self.stage_equality_mask = p.stage_equality_mask
        self.final_equality_mask = p.final_equality_mask
        N, ne = p.N, 2 * p.rN
        self.x_lower = np.concatenate([p.x_lower, np.full((N + 1, ne), -np.inf)], axis=1)
        self.x_upper = np.concatenate([p.x_upper, np.full((N + 1, ne), np.inf)], axis=1)
        nel = self.m - self.m0
        self.u_lower = np.concatenate([p.u_lower, np.zeros((N, nel))], axis=1)
        self.u_upper = np.concatenate([p.u_upper, np.full((N, nel), np.inf)], axis=1)
        self.XR, self.UR = XR.copy(), UR.copy()
        self.zeta = float(np.sqrt(mu))
        self.Dx = np.minimum(1.0, 1.0 / np.maximum(np.abs(XR), 1e-300)) ** 2
        self.Du = np.minimum(1.0, 1.0 / np.maximum(np.abs(UR), 1e-300)) ** 2
        self.name = f"restoration of {getattr(p, 'name', type(p).__name__)}"

    # -- the variables
    def split(self, U):
        """(u, p_h, n_h, p_g, n_g, w) of the controls."""
        m, n, r = self.m0, self.n0, self.r
        cuts = np.cumsum([m, n, n, r, r])
        return tuple(np.split(U, cuts, axis=1))

    def split_states(self, X):
        """(x, e) of the states, e = (p_N, n_N) accumulated."""
        return X[:, :self.n0], X[:, self.n0:]

    def start(self, X, U, res, mu):
        """The states and controls of the restoration problem's start at the original point (X, U)
        with residuals ``res`` (olado.solvers.ipm.newton.Residuals: h, equality rows, inequality
        rows d - s): every elastic pair from eq. (33) for its residual, the final rows' pair as
        w^{N-1} = e^N, the other w^k = mu / rho (their minimizer)."""
        N = self.N
        ph, nh = elastic_start(res.h, mu)
        cg = np.zeros((N, self.r))
        cg[:, self.stage_equality_mask] = res.e
        cg[:, ~self.stage_equality_mask] = res.d
        pg, ng = elastic_start(cg, mu)
        cN = np.zeros(self.rN)
        cN[self.final_equality_mask] = res.eN
        cN[~self.final_equality_mask] = res.dN
        pN, nN = elastic_start(cN, mu)
        w = np.full((N, 2 * self.rN), mu / RHO)
        w[-1] = np.concatenate([pN, nN])
        E = np.zeros((N + 1, 2 * self.rN))
        E[1:] = w
        return np.concatenate([X, E], axis=1), np.concatenate([U, ph, nh, pg, ng, w], axis=1)

    def elastic_sum(self, X, U):
        """sum (p + n): the l1 violation the restoration problem's penalty sees."""
        _, ph, nh, pg, ng, _ = self.split(U)
        return float(ph.sum() + nh.sum() + pg.sum() + ng.sum() + self.split_states(X)[1][-1].sum())

    # -- the evaluations the solver calls
    def eval_values(self, X, U):
        """(J, f, g, gN): DOCP.eval_values' default (the solvers' Point calls this one entry)."""
        return self.objective(X, U), self.eval_dynamics(X, U), self.eval_stage_constraints(X, U), \
            self.eval_final_constraints(X[-1])

    def eval_first_derivatives(self, X, U):
        """(lx, lu, lN, A, B, Cx, Cu, CN): DOCP.eval_first_derivatives' default, in its order."""
        lx, lu = self.eval_stage_cost_gradients(X, U)
        lN = self.eval_final_cost_gradient(X[-1])
        A, B = self.eval_dynamics_jacobians(X, U)
        Cx, Cu = self.eval_stage_constraint_jacobians(X, U)
        return lx, lu, lN, A, B, Cx, Cu, self.eval_final_constraint_jacobian(X[-1])

    def objective(self, X, U):
        u, ph, nh, pg, ng, w = self.split(U)
        x = self.split_states(X)[0]
        el = ph.sum() + nh.sum() + pg.sum() + ng.sum() + w.sum()
        prox = (self.Dx[1:] * (x[1:] - self.XR[1:]) ** 2).sum() + (self.Du * (u - self.UR) ** 2).sum()
        return float(RHO * el + 0.5 * self.zeta * prox)

    def eval_dynamics(self, X, U):
        u, ph, nh, _, _, w = self.split(U)
        x, e = self.split_states(X)
        return np.concatenate([self.base.eval_dynamics(x, u) - ph + nh, w], axis=1)

    def eval_stage_constraints(self, X, U):
        u, _, _, pg, ng, _ = self.split(U)
        return self.base.eval_stage_constraints(self.split_states(X)[0], u) - pg + ng

    def eval_final_constraints(self, xN):
        e = xN[self.n0:]
        return self.base.eval_final_constraints(xN[:self.n0]) - e[:self.rN] + e[self.rN:]

    def eval_stage_cost_gradients(self, X, U):
        u = self.split(U)[0]
        N, n0 = self.N, self.n0
        lx = np.zeros((N, self.n))
        lx[:, :n0] = self.zeta * self.Dx[:-1] * (X[:-1, :n0] - self.XR[:-1])
        lx[0] = 0.0
        lu = np.concatenate([self.zeta * self.Du * (u - self.UR), np.full((N, self.m - self.m0), RHO)], axis=1)
        return lx, lu

    def eval_final_cost_gradient(self, xN):
        g = np.zeros(self.n)
        g[:self.n0] = self.zeta * self.Dx[-1] * (xN[:self.n0] - self.XR[-1])
        return g

    def eval_dynamics_jacobians(self, X, U):
        A0, B0 = self.base.eval_dynamics_jacobians(self.split_states(X)[0], self.split(U)[0])
        N, n0, n, m0, r, ne = self.N, self.n0, self.n, self.m0, self.r, 2 * self.rN
        A = np.zeros((N, n, n))
        A[:, :n0, :n0] = A0
        B = np.zeros((N, n, self.m))
        B[:, :n0, :m0] = B0
        B[:, :n0, m0:m0 + n0] = -np.eye(n0)
        B[:, :n0, m0 + n0:m0 + 2 * n0] = np.eye(n0)
        B[:, n0:, m0 + 2 * n0 + 2 * r:] = np.eye(ne)
        return A, B

    def eval_stage_constraint_jacobians(self, X, U):
        Cx0, Cu0 = self.base.eval_stage_constraint_jacobians(self.split_states(X)[0], self.split(U)[0])
        N, n0, m0, r = self.N, self.n0, self.m0, self.r
        Cx = np.zeros((N, r, self.n))
        Cx[:, :, :n0] = Cx0
        Cu = np.zeros((N, r, self.m))
        Cu[:, :, :m0] = Cu0
        Cu[:, :, m0 + 2 * n0:m0 + 2 * n0 + r] = -np.eye(r)
        Cu[:, :, m0 + 2 * n0 + r:m0 + 2 * n0 + 2 * r] = np.eye(r)
        return Cx, Cu

    def eval_final_constraint_jacobian(self, xN):
        C0 = self.base.eval_final_constraint_jacobian(xN[:self.n0])
        rN = self.rN
        return np.concatenate([C0, -np.eye(rN), np.eye(rN)], axis=1)

    def eval_stage_hessians(self, X, U, sigma, P, L=None):
        """The Lagrangian's stage blocks: the base problem's with the multipliers of its dynamics
        (the first n rows of P) and stage rows, no objective (the elastic terms are linear), plus
        sigma zeta D_R of the proximity term."""
        x = self.split_states(X)[0]
        Hxx0, Hxu0, Huu0 = self.base.eval_stage_hessians(x, self.split(U)[0], 0.0, P[:, :self.n0], L)
        N, n0, n, m0, m = self.N, self.n0, self.n, self.m0, self.m
        Hxx = np.zeros((N, n, n))
        Hxx[:, :n0, :n0] = Hxx0 + sigma * self.zeta * np.einsum("ki,ij->kij", self.Dx[:-1], np.eye(n0))
        Hxu = np.zeros((N, n, m))
        Hxu[:, :n0, :m0] = Hxu0
        Huu = np.zeros((N, m, m))
        Huu[:, :m0, :m0] = Huu0 + sigma * self.zeta * np.einsum("ki,ij->kij", self.Du, np.eye(m0))
        return Hxx, Hxu, Huu

    def eval_final_hessian(self, xN, sigma, lN=None):
        H = np.zeros((self.n, self.n))
        H[:self.n0, :self.n0] = (self.base.eval_final_hessian(xN[:self.n0], 0.0, lN)
                                 + sigma * self.zeta * np.diag(self.Dx[-1]))
        return H
