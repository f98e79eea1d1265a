"""Feasibility restoration of the SQP method (WORHP's feasibility mode, seed 000 sec. IV.VI,
"Feasible mode": "if the line search has failed at an infeasible point ... the QP is modified
extensively to provide a search direction that focusses on the feasibility of the problem"),
on the same stage QP machinery: the objective is dropped and the l1 violation

    theta(y) = sum |h| + sum v(g) + sum v(g_N) + sum v(bounds of x)

is minimized by steps whose QP is the feasibility QP of olado.solvers.sqp.relaxation (the relaxed
QP without the objective's gradient) with penalty 1 and a multiple of the identity as Hessian --
WORHP's SLP recovery ("instead of a second-order approximation of the Hessian the identity matrix
is used, which has stabilizing properties"; the Lagrangian Hessian is useless here, its
multipliers grow without bound when the iterates approach a point where the constraints are
degenerate):

    min_s  sum(slacks) + mu/2 |s|^2   s.t. the relaxed linearized constraints,

a proximal-gradient step on theta, with Armijo backtracking on theta along it (directional
derivative D = sum(slacks) - theta <= -mu/2 |s|^2). The identity presumes a scaled problem; mu
(1 at the start of the phase) therefore follows the agreement of the actual and the predicted
reduction of theta, as WORHP's tau does ([12]-[13]): a full step with actual >= 0.75 predicted
divides it by 10, a backtracked step or actual <= 0.25 predicted multiplies it by 10 (within
1e-8..1e8).

It starts when the line search of the optimality phase fails at an infeasible point (where the
SQP used to end with NUMERICAL_ERROR). After each restoration step, once theta is below
``restoration_reduction`` times its value at the start (or below constr_viol_tol) and the QP of
the optimality phase is consistent again, the optimality phase resumes from the new point. The
phase ends the solve with status INFEASIBLE at a stationary point of theta (the point is locally
infeasible, or its constraints are degenerate): when the step's predicted decrease is below tol *
1e-6 theta, the best linear decrease with the control steps in the box |du| <= 1 + |u|_inf (a
near-LP: mu = 1e-8; scale-free, unlike the identity metric) is computed, and if that too is below
1e-6 theta or the rounding level of theta, the solve ends, the sentence naming the largest
violation left (otherwise the mu-step is taken and mu divided by 10); with NUMERICAL_ERROR when the line search along
the feasibility step fails (the linearization promised a reduction, so this proves nothing
about feasibility).
"""

from __future__ import annotations

import numpy as np

from ...result import Status
from .line_search import Direction, line_search
from . import relaxation


#: range of the restoration metric mu I
MU_MIN, MU_MAX = 1e-8, 1e8
#: theta is stationary when no control step in the box reduces its linearization by more than
#: this times theta
THETA_RTOL = 1e-6


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
    st.restoration_mu = 1.0
    st.watch = None
    st.local = False


def may_leave(setup, st):
    """After a restoration step: theta sufficiently reduced (the optimality phase resumes when its
    QP is consistent)."""
    t = theta(setup)(st.pt)
    return st.restoration_steps > 0 and (t <= setup.options.restoration_reduction * st.restoration_theta
                                         or setup.merit.max_violation(st.pt) <= setup.options.constr_viol_tol)


def feasibility_step(setup, st, mu, u_box=None):
    """The feasibility QP with metric mu I: min sum(slacks) + mu/2 |s|^2, with |du| <= u_box
    (a QPSolve)."""
    p = setup.problem
    N, n, m = p.N, p.n, p.m
    eye = np.tile(mu * np.eye(n + m), (N, 1, 1))
    return relaxation.feasibility_qp(setup, st, eye, mu * np.eye(n), np.zeros(N + 1), eta=1.0, inertia=False,
                                     u_box=u_box)


def restoration_step(setup, st, delta, complete):
    """One iteration of the restoration phase: the feasibility QP and a line search on theta
    (``complete``: the line search's completion of the accepted point). Returns the history
    record of the step, or True (STOP, status set)."""
    o, p = setup.options, setup.problem
    th = theta(setup)
    theta0 = th(st.pt)
    fs = feasibility_step(setup, st, st.restoration_mu)
    iterations = fs.iterations
    if fs.result.success and -(fs.slacks.total() - theta0) <= THETA_RTOL * theta0:
        # little predicted decrease: is theta stationary? The best linear decrease with the control
        # steps in a box of the controls' size (near-LP, mu = MU_MIN): scale-free, unlike mu I
        box = 1.0 + float(np.max(np.abs(st.pt.U), initial=0.0))
        test = feasibility_step(setup, st, MU_MIN, u_box=box)
        iterations += test.iterations
        best = -(test.slacks.total() - theta0) if test.result.success else float("inf")
        if best <= max(THETA_RTOL * theta0, rounding_level(st.pt)):
            st.qp_iters += iterations
            return infeasible(setup, st, "the l1 constraint violation is stationary (no control step within the "
                              f"box |du| <= 1 + |u| reduces its linearization by more than {best:.3g})")
        st.restoration_mu = max(MU_MIN, 0.1 * st.restoration_mu)    # not stationary: longer steps
    st.qp_iters += iterations
    if not fs.result.success:
        return st.stop(Status.NUMERICAL_ERROR, (f"the feasibility QP of SQP iteration {st.it} (restoration "
                                                f"phase) failed: {fs.result.message}"))
    D = fs.slacks.total() - theta0
    res = fs.result
    if -D <= rounding_level(st.pt):
        return infeasible(setup, st, "the l1 constraint violation is stationary to rounding (its feasibility QP "
                          f"predicts a decrease of {-D:.3g})")
    found = line_search(o, p, Direction(st.pt, res.X, res.U, theta0, D), th, None, relaxed_ok=False,
                        complete=complete, d_tol=rounding_level(st.pt))
    if found.point is None:   # not a proof of infeasibility (the linearization promised a reduction)
        return st.stop(Status.NUMERICAL_ERROR, (f"line search failed in the restoration phase at SQP iteration "
                                                f"{st.it}: no step down to {o.min_step:g} along the feasibility QP's "
                                                f"step reduces the l1 constraint violation {theta0:.3g}"))
    # the metric follows the agreement of actual and predicted reduction (as WORHP's tau, [12]-[13])
    ratio = (theta0 - th(found.point)) / (-found.alpha * D)
    if found.alpha == 1.0 and ratio >= 0.75:
        st.restoration_mu = max(MU_MIN, 0.1 * st.restoration_mu)
    elif found.alpha < 1.0 or ratio <= 0.25:
        st.restoration_mu = min(MU_MAX, 10.0 * st.restoration_mu)
    step_norm = max(float(np.max(np.abs(res.X))), float(np.max(np.abs(res.U))))
    st.pt = found.point
    st.Bk = None
    st.restoration_steps += 1
    st.it += 1
    return {"step": found.alpha, "step_norm": step_norm, "merit": th(st.pt), "D": D,
            "qp_iterations": iterations, "ls_trials": found.trials, "mode": "restoration",
            "shift": st.restoration_mu}
