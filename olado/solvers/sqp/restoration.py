"""Feasibility restoration of the SQP method (WORHP's feasibility mode, seed 000 sec. IV.VI,
"Feasible mode": "if the line search has failed at an infeasible point ... the QP is modified
extensively to provide a search direction that focusses on the feasibility of the problem"),
on the same stage QP machinery: the objective is dropped and the l1 violation

    theta(y) = sum |h| + sum v(g) + sum v(g_N) + sum v(bounds of x)

is minimized by steps whose QP is the feasibility QP of olado.solvers.sqp.relaxation (the relaxed
QP without the objective's gradient) with penalty 1 and the identity as Hessian -- WORHP's SLP
recovery ("instead of a second-order approximation of the Hessian the identity matrix is used,
which has stabilizing properties"; the Lagrangian Hessian is useless here, its multipliers grow
without bound when the iterates approach a point where the constraints are degenerate):

    min_s  sum(slacks) + 1/2 |s|^2   s.t. the relaxed linearized constraints,

a proximal gradient step on theta, with Armijo backtracking on theta along it (directional
derivative D = sum(slacks) - theta <= -1/2 |s|^2).

It starts when the line search of the optimality phase fails at an infeasible point (where the
SQP used to end with NUMERICAL_ERROR). After each restoration step, once theta is below
``restoration_reduction`` times its value at the start (or below constr_viol_tol) and the QP of
the optimality phase is consistent again, the optimality phase resumes from the new point. The
phase ends the solve with status INFEASIBLE when the predicted decrease -D falls below tol * theta
or below the rounding level of theta (a stationary point of theta: the point is locally
infeasible, or its constraints are degenerate), the sentence naming the largest violation left; with NUMERICAL_ERROR when the line search along
the feasibility step fails (the linearization promised a reduction, so this proves nothing
about feasibility).
"""

from __future__ import annotations

import numpy as np

from ...result import Status
from .line_search import Direction, line_search
from . import relaxation


def theta(setup):
    """theta(q): the l1 constraint violation (the merit function with unit weights, without J)."""
    p = setup.problem
    ones = (np.ones((p.N, p.n)), np.ones((p.N, p.r)), np.ones(p.rN), np.ones((p.N + 1, p.n)), np.ones((p.N, p.m)))
    return lambda q, alpha=1.0: setup.merit.penalty(q, ones)


def infeasible(setup, st, why):
    """End the solve: locally infeasible, with the largest violation named."""
    worst, _ = setup.merit.worst(st.pt)
    return st.stop(Status.INFEASIBLE, (f"the problem appears locally infeasible: {why} at SQP iteration {st.it} "
                                       f"(l1 constraint violation {theta(setup)(st.pt):.3g}); largest violation: {worst}"))


def rounding_level(pt):
    """The rounding error of theta at pt: the residuals f(x, u) - x_+ and g are differences of
    numbers of the size of the states, so theta is known to about 10 eps (sum |x^k| + sum |g|)."""
    return 10.0 * np.finfo(float).eps * float(np.sum(np.abs(pt.X[1:])) + np.sum(np.abs(pt.g)) + np.sum(np.abs(pt.gN)))


def start(setup, st):
    """Enter the restoration phase at the current iterate."""
    st.restoring = True
    st.restoration_theta = theta(setup)(st.pt)
    st.restoration_steps = 0
    st.watch = None
    st.local = False


def may_leave(setup, st):
    """After a restoration step: theta sufficiently reduced (the optimality phase resumes when its
    QP is consistent)."""
    t = theta(setup)(st.pt)
    return st.restoration_steps > 0 and (t <= setup.options.restoration_reduction * st.restoration_theta
                                         or setup.merit.max_violation(st.pt) <= setup.options.constr_viol_tol)


def restoration_step(setup, st, delta, complete):
    """One iteration of the restoration phase: the feasibility QP and a line search on theta
    (``complete``: the line search's completion of the accepted point). Returns the history
    record of the step, or True (STOP, status set)."""
    o, p = setup.options, setup.problem
    N, n, m = p.N, p.n, p.m
    eye = np.tile(np.eye(n + m), (N, 1, 1))
    fs = relaxation.feasibility_qp(setup, st, eye, np.eye(n), np.zeros(N + 1), eta=1.0, inertia=False)
    st.qp_iters += fs.iterations
    if not fs.result.success:
        return st.stop(Status.NUMERICAL_ERROR, (f"the feasibility QP of SQP iteration {st.it} (restoration phase) "
                                                f"failed: {fs.result.message}"))
    th = theta(setup)
    theta0 = th(st.pt)
    D = fs.slacks.total() - theta0
    if -D <= max(o.tol * theta0, rounding_level(st.pt)):
        return infeasible(setup, st, "the l1 constraint violation is stationary (its feasibility QP predicts a "
                          f"decrease of {-D:.3g})")
    res = fs.result
    found = line_search(o, p, Direction(st.pt, res.X, res.U, theta0, D), th, None, relaxed_ok=False,
                        complete=complete, d_tol=rounding_level(st.pt))
    if found.point is None:   # not a proof of infeasibility (the linearization promised a reduction)
        return st.stop(Status.NUMERICAL_ERROR, (f"line search failed in the restoration phase at SQP iteration "
                                                f"{st.it}: no step down to {o.min_step:g} along the feasibility QP's "
                                                f"step reduces the l1 constraint violation {theta0:.3g}"))
    step_norm = max(float(np.max(np.abs(res.X))), float(np.max(np.abs(res.U))))
    st.pt = found.point
    st.Bk = None
    st.restoration_steps += 1
    st.it += 1
    return {"step": found.alpha, "step_norm": step_norm, "merit": th(st.pt), "D": D,
            "qp_iterations": int(res.iterations), "ls_trials": found.trials, "mode": "restoration",
            "shift": float(np.max(fs.delta))}
