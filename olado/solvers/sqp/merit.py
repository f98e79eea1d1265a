"""The L1 exact penalty (merit) function of the SQP line search (paper 001 sec. 4.2.1, the step
length alpha of eq. (11)):

    phi(y) = J(y) + sum_i rho_i |h_i(y)| + sum_j rho_j max(0, -g_j(y))  (+ bound violations)

with equality rows of g counted as |g_j|, the bounds (4)-(5) of x^1..x^N and u as their
violations, and Powell's (1978) weights rho_i := max(|mu_i|, (rho_i + |mu_i|)/2, penalty_min)
from the QP multipliers mu. D = grad J . s - sum rho |c| is the directional derivative of phi
along the QP step s (Nocedal & Wright 2006, (18.29)).
"""

from __future__ import annotations

import numpy as np

from ..diagnosis import largest_violation_of


class Merit:
    """Constraint violations and phi for one problem (masks of its equality components)."""

    def __init__(self, problem, masks):
        self.problem = problem
        self.masks = masks
        self._work = None       # the compiled penalty's work vector (olado.solvers.sqp.kernels)

    def violations(self, q):
        """Constraint violations (arrays) at the point q: (|h|, g, gN, x bounds, u bounds).
        Computed once per point (its values do not change; the KKT test, the penalty and the
        history ask for them several times an iteration): the arrays are read-only to callers."""
        return self._measured(q)[0]

    def _measured(self, q):
        """(violations, their largest entry, the penalties computed so far) of the point q, kept
        on the point; the penalties as a list of (weights, value) pairs (the same weights object:
        the merit value at a point is asked for several times with the same weights)."""
        cached = getattr(q, "_violations", None)
        if cached is not None and cached[0] is self:
            return cached[1]
        out = self._violations(q)
        try:
            q._violations = (self, out)
        except AttributeError:     # a point type without attributes of its own
            pass
        return out

    def _violations(self, q):
        p, (eq, _, eqN, _) = self.problem, self.masks
        if _compiled(q):
            from . import kernels
            *arrays, worst = kernels.violations(q.h, q.g, q.gN, q.X, q.U, eq, eqN, p.x_lower, p.x_upper,
                                                p.u_lower, p.u_upper)
            return tuple(arrays), worst, []
        vg = np.where(eq, np.abs(q.g), np.maximum(-q.g, 0.0)) if p.r else q.g
        vgN = np.where(eqN, np.abs(q.gN), np.maximum(-q.gN, 0.0)) if p.rN else q.gN
        vbx = np.maximum(p.x_lower - q.X, 0.0) + np.maximum(q.X - p.x_upper, 0.0)
        vbx[0] = 0.0
        vbu = np.maximum(p.u_lower - q.U, 0.0) + np.maximum(q.U - p.u_upper, 0.0)
        out = (np.abs(q.h), vg, vgN, vbx, vbu)
        return out, max(float(v.max(initial=0.0)) for v in out), []

    def worst(self, q):
        """The largest constraint violation at q, named as olado's infeasibility diagnosis names
        it (olado.solvers.diagnosis): (sentence, value), e.g. "final_constraints[component 0]
        (violation 7)" or "dynamics[stage 3, component 1] (violation 0.2)"."""
        value, where = largest_violation_of(self.problem, q)
        return (f"{where.where()} (violation {value:.3g})" if where is not None else "no constraint"), value

    def max_violation(self, q):
        return self._measured(q)[1]

    def penalty(self, q, weights):
        """sum rho |c| at q with the weights ``weights`` (kept per point and weights object)."""
        viol, _, known = self._measured(q)
        for w, value in known:
            if w is weights:
                return value
        w0, w1, w2, w3, w4 = weights
        if (_compiled(q) and w0.flags.c_contiguous and w1.flags.c_contiguous and w2.flags.c_contiguous
                and w3.flags.c_contiguous and w4.flags.c_contiguous):
            from . import kernels
            if self._work is None:
                self._work = np.empty(max(v.size for v in viol))
            # flat views (C-contiguous: the same order), so that the kernel compiles once
            value = kernels.penalty(w0.ravel(), viol[0].ravel(), w1.ravel(), viol[1].ravel(), w2.ravel(),
                                    viol[2].ravel(), w3.ravel(), viol[3].ravel(), w4.ravel(), viol[4].ravel(), self._work)
        else:
            value = sum(float((w * v).sum()) for w, v in zip(weights, viol))
        known.append((weights, value))
        return value

    # ------------------------------------------------------------------ the merit function's interface
    # (shared with olado.solvers.sqp.augmented.AugmentedLagrangian; the phases call only these)
    name = "l1"

    def initial_weights(self):
        """The weights before the first step: all 0."""
        p = self.problem
        return zero_weights(p.N, p.n, p.r, p.rN, p.m)

    def largest_weight(self, weights):
        from .kernels import npmax_abs     # the weights are >= 0: max |w| is numpy's max w (a NaN propagates)

        return max(npmax_abs(w, 0.0) for w in weights)

    def elastic_floor(self, weights):
        """The least penalty eta of a relaxed QP (olado.solvers.sqp.relaxation) for these
        weights: the largest weight, so that Powell's update gives rho <= eta."""
        return self.largest_weight(weights)

    def update(self, weights, step, bounds, options, iteration, sHs):
        """The weights for this step: Powell's rule with the step's QP multipliers."""
        return powell_weights(weights, step.mult_new, bounds, options.penalty_min)

    def derivative(self, pt, step, weights):
        """D along the step (Nocedal & Wright (18.29)); after a relaxed QP plus the penalty of the
        linearized violation its slacks leave (olado.solvers.sqp.relaxation)."""
        D = directional_derivative(self, pt, step.dX, step.dU, weights)
        if step.slacks is not None:
            D += self.slack_penalty(step.slacks, weights)
        return D

    def slack_penalty(self, slacks, weights):
        """sum rho v(c + J s): the weights times the slacks of a relaxed QP (the linearized
        violations at its step; the dynamics and the control bounds stay exact)."""
        (eq, ineq, eqN, ineqN), p = self.masks, self.problem
        total = float(np.sum(weights[3][1:] * slacks.x[1:]))
        if p.r:
            total += float(np.sum(weights[1][:, eq] * slacks.e) + np.sum(weights[1][:, ineq] * slacks.c))
        if p.rN:
            total += float(np.sum(weights[2][eqN] * slacks.eN) + np.sum(weights[2][ineqN] * slacks.cN))
        return total

    def along(self, weights, step):
        """phi(point, alpha) for the line search along the step (the weights fixed)."""
        return lambda q, alpha=1.0: self.value(q, weights)

    def accepted(self, weights, step, alpha):
        """The weights at the accepted point (unchanged)."""
        return weights

    def value(self, q, weights):
        """phi(q) with the penalty weights ``weights``."""
        return q.J + self.penalty(q, weights)


_EPS = float(np.finfo(float).eps)


def _compiled(q):
    """The compiled passes (olado.solvers.sqp.kernels) apply to the point q: its arrays are float."""
    f = np.float64
    return q.h.dtype == f and q.g.dtype == f and q.gN.dtype == f and q.X.dtype == f and q.U.dtype == f


def zero_weights(N, n, r, rN, m):
    """Initial exact-penalty weights (rho_h, rho_g, rho_gN, rho_bx, rho_bu), all 0."""
    return (np.zeros((N, n)), np.zeros((N, r)), np.zeros(rN), np.zeros((N + 1, n)), np.zeros((N, m)))


def powell_weights(rho, mult, bounds, penalty_min):
    """Powell's (1978) update rho := max(|mu|, (rho + |mu|)/2, penalty_min), componentwise, with
    mu the QP multipliers ``mult`` (dynamics, stage, final) and ``bounds`` (z_L + z_U)."""
    zbx = bounds.zl_x + bounds.zu_x
    zbu = bounds.zl_u + bounds.zu_u
    return tuple(np.maximum(np.maximum(mu, 0.5 * (w + mu)), penalty_min)
                 for w, mu in zip(rho, (np.abs(mult.lam[1:]), np.abs(mult.Lg), np.abs(mult.LgN), zbx, zbu)))


def directional_derivative(merit, pt, dX, dU, weights):
    """D = grad J . s - sum rho |c| along the step s = (dX, dU) at pt (Nocedal & Wright (18.29))."""
    return gradient_slope(pt, dX, dU) - merit.penalty(pt, weights)


def gradient_slope(pt, dX, dU):
    """grad J . s: numpy's sums of lx * dX[:-1] and lu * dU (pairwise; compiled for contiguous
    arrays, olado.solvers.sqp.kernels) plus lN . dX_N."""
    Xs = dX[:-1]
    if Xs.flags.c_contiguous and dU.flags.c_contiguous and pt.lx.flags.c_contiguous and pt.lu.flags.c_contiguous:
        from .kernels import gradient_sums
        return float(gradient_sums(pt.lx.ravel(), Xs.ravel(), pt.lu.ravel(), dU.ravel()) + pt.lN @ dX[-1])
    return float(np.sum(pt.lx * Xs) + np.sum(pt.lu * dU) + pt.lN @ dX[-1])


def descent_tolerance(phi0, tol, grad_scale, dX, dU):
    """A directional derivative below what the optimality tolerance resolves -- a gradient error
    of tol * |grad J| along the step, or the rounding level of phi -- counts as descent."""
    if dX.flags.c_contiguous and dU.flags.c_contiguous:
        from ...linalg.numpy_sums import abs_sum    # numpy's pairwise sum of |a|, compiled
        size = abs_sum(dX[1:]) + abs_sum(dU)
    else:
        size = float(np.sum(np.abs(dX[1:]))) + float(np.sum(np.abs(dU)))
    return 10.0 * _EPS * max(1.0, abs(phi0)) + tol * grad_scale * size


def watch_target(merit, watch, weights, armijo):
    """The merit value the iterates must reach below the watched point (Chamberlain et al. 1982):
    phi(watched) - armijo * max(|D|, d_tol) (after a relaxed step that was no descent direction,
    by at least armijo * |D|)."""
    return merit.value(watch.pt, weights) - armijo * max(abs(watch.D), watch.d_tol)
