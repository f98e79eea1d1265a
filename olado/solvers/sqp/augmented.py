"""Schittkowski's augmented Lagrangian merit function on primal and dual variables (Schittkowski
1983, "On the convergence of a sequential quadratic programming method with an augmented
Lagrangian line search function"; paper 001 sec. 2.2 and 4.2.1, its SQP of Schittkowski's type;
WORHP offers the same merit function, seed 000 sec. IV.IV), ``merit = augmented-lagrangian``.

With every constraint of the DOCP written as an equality e_i(y) = 0 (the dynamics h, the equality
rows of g and g_N) or an inequality c_j(y) >= 0 (the inequality rows, the finite bounds of x^1..x^N
and u, each side a constraint of its own), multiplier estimates v (lambda_i of the equalities in
the Lagrangian J + lambda.e, y_j >= 0 of the inequalities in J - y.c) and penalties r > 0:

    Phi_r(y, v) = J(y) + sum_i (lambda_i e_i + r_i/2 e_i^2)
                       + sum_{j in A} (-y_j c_j + r_j/2 c_j^2) - sum_{j not in A} y_j^2 / (2 r_j),
    A = {j : c_j <= y_j / r_j},

(continuously differentiable). The line search runs along primal and dual variables at once,

    psi(alpha) = Phi_r(y + alpha s, v + alpha (u - v)),      u the QP's multipliers,

with psi'(0) = grad_y Phi . s + grad_v Phi . (u - v); the accepted step length also moves the
estimates, v := v + alpha (u - v). Schittkowski's penalty update, before the line search,

    r_j := max(sigma_j r_j, 2 m (u_j - v_j)^2 / (s^T B s)),     sigma_j = min(1, k / sqrt(r_j)),

(m the number of constraints, k the iteration, B the QP Hessian) makes s a descent direction of
psi for a positive definite B and lets penalties that are no longer needed fall slowly; the
implementation of this update in HQP (Franke), the SQP library paper 001 builds on, omits the
factor 1/(1 - delta) of the paper, and so does this one. Starting values r = 1, v = 0 (HQP's).
The weights of this merit function are ``ALWeights`` (the penalties and the estimates); the
constraint-violation measures are the L1 merit's (olado.solvers.sqp.merit.Merit), whose interface
this class implements.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .merit import Merit


class ALWeights(NamedTuple):
    """Penalties and multiplier estimates of the augmented Lagrangian, as flat vectors over the
    equalities (``r_e``, ``lam``) and the inequalities (``r_c``, ``y``)."""

    r_e: np.ndarray
    r_c: np.ndarray
    lam: np.ndarray
    y: np.ndarray


class AugmentedLagrangian(Merit):
    """Schittkowski's augmented Lagrangian merit function (module docstring)."""

    name = "augmented-lagrangian"

    def __init__(self, problem, masks):
        super().__init__(problem, masks)
        p = problem
        xl, xu = p.x_lower.copy(), p.x_upper.copy()
        xl[0], xu[0] = -np.inf, np.inf          # x^0 is fixed
        self._boxes = (np.isfinite(xl), np.isfinite(xu), np.isfinite(p.u_lower), np.isfinite(p.u_upper))
        self._xl, self._xu = xl, xu

    # ------------------------------------------------------------------ constraints as flat vectors
    def equalities(self, q):
        (eq, _, eqN, _), p = self.masks, self.problem
        return np.concatenate([q.h.ravel(), q.g[:, eq].ravel() if p.r else [], q.gN[eqN] if p.rN else []])

    def inequalities(self, q):
        """c(y) >= 0: the inequality rows of g, g_N and the finite bounds (lower, then upper sides)."""
        (_, ineq, _, ineqN), p = self.masks, self.problem
        fxl, fxu, ful, fuu = self._boxes
        return np.concatenate([q.g[:, ineq].ravel() if p.r else [], q.gN[ineqN] if p.rN else [],
                               (q.X - self._xl)[fxl], (self._xu - q.X)[fxu],
                               (q.U - p.u_lower)[ful], (p.u_upper - q.U)[fuu]])

    def linearized(self, pt, dX, dU):
        """(grad e . s, grad c . s) along the step s = (dX, dU) from the Jacobians at pt."""
        (eq, ineq, eqN, ineqN), p = self.masks, self.problem
        dyn = np.einsum("kij,kj->ki", pt.A, dX[:-1]) + np.einsum("kij,kj->ki", pt.B, dU) - dX[1:]
        Cd = (np.einsum("kij,kj->ki", pt.Cx, dX[:-1]) + np.einsum("kij,kj->ki", pt.Cu, dU)) if p.r else None
        CNd = pt.CN @ dX[-1] if p.rN else None
        fxl, fxu, ful, fuu = self._boxes
        de = np.concatenate([dyn.ravel(), Cd[:, eq].ravel() if p.r else [], CNd[eqN] if p.rN else []])
        dc = np.concatenate([Cd[:, ineq].ravel() if p.r else [], CNd[ineqN] if p.rN else [],
                             dX[fxl], -dX[fxu], dU[ful], -dU[fuu]])
        return de, dc

    def multipliers(self, mult, bounds):
        """(lambda, y) of the equalities and inequalities from the SQP's multipliers."""
        (eq, ineq, eqN, ineqN), p = self.masks, self.problem
        fxl, fxu, ful, fuu = self._boxes
        lam = np.concatenate([mult.lam[1:].ravel(), mult.Lg[:, eq].ravel() if p.r else [],
                              mult.LgN[eqN] if p.rN else []])
        y = np.concatenate([-mult.Lg[:, ineq].ravel() if p.r else [], -mult.LgN[ineqN] if p.rN else [],
                            bounds.zl_x[fxl], bounds.zu_x[fxu], bounds.zl_u[ful], bounds.zu_u[fuu]])
        return lam, np.maximum(y, 0.0)

    # ------------------------------------------------------------------ the merit function's interface
    def initial_weights(self):
        p = self.problem
        N, n, r, rN = p.N, p.n, p.r, p.rN
        n_e = N * n + (N * int(self.masks.eq.sum()) if r else 0) + (int(self.masks.eqN.sum()) if rN else 0)
        n_c = (N * int(self.masks.ineq.sum()) if r else 0) + (int(self.masks.ineqN.sum()) if rN else 0)
        n_c += sum(int(b.sum()) for b in self._boxes)
        return ALWeights(np.ones(n_e), np.ones(n_c), np.zeros(n_e), np.zeros(n_c))

    def largest_weight(self, weights):
        return max(float(np.max(weights.r_e, initial=0.0)), float(np.max(weights.r_c, initial=0.0)))

    def elastic_floor(self, weights):
        """The least penalty eta of a relaxed QP: the largest multiplier estimate |v|. An elastic
        penalty stands for a multiplier (the relaxed QP is the QP once eta exceeds its
        multipliers), as Powell's L1 weights do; the penalties r weigh squared violations and grow
        with (u - v)^2, and as a floor of eta (whose slack rows' multipliers u are eta) they made
        eta grow like eta^2 from one relaxed QP to the next on an infeasible problem
        (vanderpol-contradict: 15, 1.6e4, 4.9e8, 6.4e20)."""
        return max(float(np.max(np.abs(weights.lam), initial=0.0)), float(np.max(weights.y, initial=0.0)))

    def update(self, weights, step, bounds, options, iteration, sHs):
        """Schittkowski's penalty update (module docstring) with the step's QP multipliers u."""
        lam_u, y_u = self.multipliers(step.mult_new, bounds)
        m = len(weights.r_e) + len(weights.r_c)
        dBd = sHs()
        k = max(iteration, 1)

        def new(r, u, v):
            grown = np.minimum(1.0, k / np.sqrt(r)) * r
            if dBd > 0.0:
                grown = np.maximum(grown, 2.0 * m * (u - v) ** 2 / dBd)
            return np.maximum(grown, options.penalty_min)

        return weights._replace(r_e=new(weights.r_e, lam_u, weights.lam), r_c=new(weights.r_c, y_u, weights.y))

    def value(self, q, weights):
        return self._value(q, weights, weights.lam, weights.y)

    def _value(self, q, weights, lam, y):
        e, c = self.equalities(q), self.inequalities(q)
        r_e, r_c = weights.r_e, weights.r_c
        act = c <= y / r_c
        return (q.J + float(np.sum(lam * e + 0.5 * r_e * e * e))
                + float(np.sum(np.where(act, -y * c + 0.5 * r_c * c * c, -0.5 * y * y / r_c))))

    def derivative(self, pt, step, weights):
        """psi'(0) = grad_y Phi . s + grad_v Phi . (u - v) (module docstring)."""
        lam_u, y_u = self.multipliers(step.mult_new, step.bounds)
        e, c = self.equalities(pt), self.inequalities(pt)
        de, dc = self.linearized(pt, step.dX, step.dU)
        r_e, r_c, lam, y = weights
        act = c <= y / r_c
        gJ = float(np.sum(pt.lx * step.dX[:-1]) + np.sum(pt.lu * step.dU) + pt.lN @ step.dX[-1])
        d_primal = gJ + float(np.sum((lam + r_e * e) * de)) + float(np.sum(np.where(act, -(y - r_c * c) * dc, 0.0)))
        d_dual = float(np.sum(e * (lam_u - lam))) + float(np.sum(np.where(act, -c, -y / r_c) * (y_u - y)))
        return d_primal + d_dual

    def along(self, weights, step):
        """psi: Phi at a point reached with step length alpha, with the estimates v + alpha (u - v)."""
        lam_u, y_u = self.multipliers(step.mult_new, step.bounds)
        lam0, y0 = weights.lam, weights.y
        return lambda q, alpha=1.0: self._value(q, weights, lam0 + alpha * (lam_u - lam0), y0 + alpha * (y_u - y0))

    def accepted(self, weights, step, alpha):
        """v := v + alpha (u - v) at the accepted point."""
        lam_u, y_u = self.multipliers(step.mult_new, step.bounds)
        return weights._replace(lam=weights.lam + alpha * (lam_u - weights.lam), y=weights.y + alpha * (y_u - weights.y))
