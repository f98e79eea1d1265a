"""Feasibility restoration of the SQP method (WORHP's feasibility mode, seed 000 sec. IV.VI,
"Feasible mode": "if the line search has failed at an infeasible point ... the QP is modified
extensively to provide a search direction that focusses on the feasibility of the problem"),
on the same stage QP machinery: the objective is dropped and the l1 violation

    theta(y) = sum |h| + sum v(g) + sum v(g_N) + sum v(bounds of x)

is minimized by steps whose QP is the feasibility QP of olado.solvers.sqp.relaxation (the relaxed
QP without the objective's gradient) with penalty 1 and the metric H_R + mu I:

    min_s  sum(slacks) + 1/2 s.(H_R + mu I) s   s.t. the relaxed linearized constraints,

with Armijo backtracking on theta along s (directional derivative at most D = sum(slacks) -
theta, the l1 model's decrease, whatever the metric). H_R is the Hessian of the feasibility
problem's Lagrangian -- the constraint Hessians weighted by the last feasibility QP's multipliers,
bounded (|weights| <= 1 on the relaxed rows), unlike the optimality phase's multipliers, which
grow without bound near a degenerate point; IPOPT's restoration phase likewise keeps its
problem's exact Hessian (Waechter & Biegler 2006 sec. 3.3). The first step of the phase has no
multipliers yet: H_R = 0, WORHP's SLP recovery ("instead of a second-order approximation of the
Hessian the identity matrix is used, which has stabilizing properties"). With H_R = 0 alone the
steps converge linearly: steering-too-short crawled for 190 iterations. mu (1 at the start of the
phase) follows the agreement of the actual and the predicted reduction of theta, as WORHP's tau
does ([12]-[13]): a full step with actual >= 0.75 predicted divides it by 10, a backtracked step
or actual <= 0.25 predicted multiplies it by 10 (within 1e-8..1e8).

The step is the first that predicts a decrease of theta of: the second-order QP, the first-order
QP (H_R = 0), both with the dynamics rows exact (the states stay consistent with the controls),
and the first-order QP with the dynamics relaxed too (olado.qp.elastic ``relax_dynamics``). Only
that last QP minimizes the l1 model of theta itself: an exact-dynamics step must remove the
dynamics residual at any cost to the other rows, and an indefinite H_R trades violation for
negative curvature, so their "predicted decrease" can be negative at a point where theta still
decreases (goddard: -6.42 at theta = 6.94; cart-pole: -0.447), which used to end the solve
INFEASIBLE.

It starts when the line search of the optimality phase fails at an infeasible point, when a QP
fails there, or when the relaxed QP finds the linearized constraints irreducible at a point whose
dynamics do not hold (and whose simulated states, :func:`simulate_states`, are worse). After each
restoration step, once theta is below ``restoration_reduction`` times its value at the start (or
below constr_viol_tol) and the QP of the optimality phase is consistent again -- or at a feasible
point whatever the QP -- the optimality phase resumes from the new point. The phase ends the solve
with status INFEASIBLE at a stationary point of theta with a positive violation (at a feasible
point a stationary theta is a degeneracy of the constraints: NUMERICAL_ERROR, :func:`infeasible`):
when the relaxed-dynamics step's predicted decrease is below 1e-6 theta, the best linear decrease
with the control steps in the box |du| <= 1 + |u|_inf (a near-LP: mu = 1e-8; scale-free, unlike
the identity metric) is computed, and if that too is below 1e-6 theta or the rounding level of
theta, the solve ends, the sentence naming the largest violation left; otherwise the mu-step is
taken and mu divided by 10. A failed line search along a feasibility step is NUMERICAL_ERROR
(the linearization promised a reduction, so this proves nothing about feasibility).
"""

from __future__ import annotations

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...result import Status
from .line_search import Direction, line_search
from .state import Multipliers, Point
from . import relaxation
from . import step as qp_step


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


def feasible(setup, pt):
    """The point satisfies every constraint to constr_viol_tol."""
    return setup.merit.max_violation(pt) <= setup.options.constr_viol_tol


def infeasible(setup, st, why):
    """End the solve: locally infeasible, with the largest violation named -- only at a point with
    a positive violation (above constr_viol_tol); at a feasible point a stationary violation says
    that the constraints are degenerate there, not that the problem is infeasible: NUMERICAL_ERROR."""
    worst, _ = setup.merit.worst(st.pt)
    if feasible(setup, st.pt):
        return st.stop(Status.NUMERICAL_ERROR, (f"the constraints are degenerate at the feasible point of SQP "
                                                f"iteration {st.it}: {why} (largest violation: {worst})"))
    return st.stop(Status.INFEASIBLE, (f"the problem appears locally infeasible: {why} at SQP iteration {st.it} "
                                       f"(l1 constraint violation {theta(setup)(st.pt):.3g}); largest violation: {worst}"))


def rounding_level(pt):
    """The rounding error of theta at pt: the residuals f(x, u) - x_+ and g are differences of
    numbers of the size of the states, so theta is known to about 10 eps (sum |x^k| + sum |g|)."""
    return 10.0 * np.finfo(float).eps * float(np.sum(np.abs(pt.X[1:])) + np.sum(np.abs(pt.g)) + np.sum(np.abs(pt.gN)))


def simulate_states(setup, st):
    """Replace the iterate's states by those simulated from x0 under its controls (the dynamics
    then hold exactly), when they are finite and theta does not grow; once per iteration. True
    when the iterate was replaced. At such a point the relaxed QP with exact dynamics rows is the
    linearization of the violation of the other constraints as a function of the controls alone,
    so its stationarity test is a test of that function (olado.solvers.sqp.relaxation)."""
    if st.simulated_at == st.it:
        return False
    st.simulated_at = st.it
    p = setup.problem
    try:
        with np.errstate(all="ignore"):
            X = p.simulate(st.pt.U)
            if not np.all(np.isfinite(X)):
                return False
            cand = Point(p, X, st.pt.U, derivatives=False, clock=st.clock)
    except NonFiniteEvaluationError:
        return False
    th = theta(setup)
    if not th(cand) <= th(st.pt):
        return False
    try:
        cand.add_derivatives(p)
    except NonFiniteEvaluationError:
        return False
    st.pt = cand
    st.Bk = None
    return True


def start(setup, st):
    """Enter the restoration phase at the current iterate."""
    st.restoring = True
    st.restoration_theta = theta(setup)(st.pt)
    st.restoration_steps = 0
    st.restoration_mu = 1.0
    st.restoration_mult = None
    st.watch = None
    st.local = False


def reset_multipliers(setup, st):
    """The multipliers and the Hessian regularization the optimality phase resumes with: IPOPT's
    reset after its restoration phase (Waechter & Biegler 2006 sec. 3.3; its option
    constr_mult_reset_threshold): the least-squares estimate of the equality multipliers at the
    restored point (olado.solvers.sqp.step.least_squares_multipliers; inequalities and bounds 0),
    or 0 when it fails or its largest exceeds ``multiplier_init_max``; the inertia correction's
    shift and WORHP's tau start again from 0. The multipliers, shift and tau of the point where
    the phase started belong to the steps that failed there: on hang-glider the QP multipliers
    had grown to 5e13 (each QP's |lambda| ~ |(H(lambda) + delta I) s| with the last lambda and
    |s| ~ 5), and with them max|H| and the shift tau (|sigma| + max|H|) ~ 1e13, so that the
    resumed optimality phase took steps of 1e-12 and stopped on step_tol far from the minimum."""
    p = setup.problem
    est, iterations = qp_step.bounded_estimate(setup, st.pt)
    st.qp_iters += iterations
    st.mult = Multipliers.zeros(p.N, p.n, p.r, p.rN) if est is None else est
    st.Bk = None
    st.tau = 0.0
    st.shift = np.zeros_like(st.shift)


def may_leave(setup, st):
    """After a restoration step: theta sufficiently reduced (the optimality phase resumes when its
    QP is consistent)."""
    t = theta(setup)(st.pt)
    return st.restoration_steps > 0 and (t <= setup.options.restoration_reduction * st.restoration_theta
                                         or setup.merit.max_violation(st.pt) <= setup.options.constr_viol_tol)


def feasibility_step(setup, st, mu, u_box=None, second_order=False, relax_dynamics=False):
    """The feasibility QP with metric H_R + mu I: min sum(slacks) + 1/2 s.(H_R + mu I) s, with
    |du| <= u_box (a QPSolve); ``relax_dynamics``: the dynamics rows relaxed too. H_R, with
    ``second_order`` and once a feasibility QP has given multipliers, is the Hessian of the
    feasibility problem's Lagrangian, the constraint Hessians weighted by those multipliers
    (IPOPT's restoration phase keeps its problem's exact Hessian, Waechter & Biegler 2006 sec.
    3.3): bounded, unlike the optimality phase's multipliers (|weights| <= 1 on the relaxed rows),
    and the curvature that a first-order model misses -- with H_R = 0 the steps converge only
    linearly. H_R may be indefinite: the QP's inertia correction then shifts it; otherwise 0."""
    p = setup.problem
    N, n, m = p.N, p.n, p.m
    mult = st.restoration_mult if second_order else None
    if mult is None:
        Bk, BN, inertia = np.tile(mu * np.eye(n + m), (N, 1, 1)), mu * np.eye(n), False
    else:
        Bk, BN = st.pt.constraint_hessian(p, mult)
        Bk = Bk + mu * np.eye(n + m)
        BN = BN + mu * np.eye(n)
        inertia = True
    return relaxation.feasibility_qp(setup, st, Bk, BN, np.zeros(N + 1), eta=1.0, inertia=inertia, u_box=u_box,
                                     relax_dynamics=relax_dynamics)


def decreases(fs, theta0, floor):
    """The feasibility QP succeeded and its step reduces the l1 model of theta by more than floor."""
    return fs.result.success and theta0 - fs.slacks.total() > floor


def restoration_step(setup, st, delta, complete):
    """One iteration of the restoration phase: the feasibility QP and a line search on theta
    (``complete``: the line search's completion of the accepted point). Returns the history
    record of the step, or True (STOP, status set).

    The step is the first of: the second-order QP (once multipliers exist), the first-order QP
    (both with the dynamics rows exact, which keeps the states consistent with the controls),
    the first-order QP with every row relaxed -- whose predicted decrease of the l1 model is never
    negative, so that it alone decides stationarity (an exact-dynamics step or an indefinite H_R
    can predict an increase at a point where theta still decreases)."""
    o, p = setup.options, setup.problem
    th = theta(setup)
    theta0 = th(st.pt)
    floor = max(THETA_RTOL * theta0, rounding_level(st.pt))
    iterations = 0
    for second_order in ((True, False) if st.restoration_mult is not None else (False,)):
        fs = feasibility_step(setup, st, st.restoration_mu, second_order=second_order)
        iterations += fs.iterations
        if decreases(fs, theta0, floor):
            break
    else:
        fs = feasibility_step(setup, st, st.restoration_mu, relax_dynamics=True)
        iterations += fs.iterations
        if fs.result.success and -(fs.slacks.total() - theta0) <= THETA_RTOL * theta0:
            # little predicted decrease: is theta stationary? The best linear decrease with the control
            # steps in a box of the controls' size (near-LP, mu = MU_MIN): scale-free, unlike mu I
            box = 1.0 + float(np.max(np.abs(st.pt.U), initial=0.0))
            test = feasibility_step(setup, st, MU_MIN, u_box=box, relax_dynamics=True)
            iterations += test.iterations
            best = -(test.slacks.total() - theta0) if test.result.success else float("inf")
            if best <= floor:
                st.qp_iters += iterations
                return infeasible(setup, st, "the l1 constraint violation is stationary (no step with the control "
                                  f"steps within the box |du| <= 1 + |u| reduces its linearization by more than "
                                  f"{best:.3g})")
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
    st.restoration_mult = qp_step.qp_multipliers(res, setup.masks, p.N, p.r, p.rN)[0]
    st.restoration_steps += 1
    st.it += 1
    if may_leave(setup, st):
        reset_multipliers(setup, st)
    return {"step": found.alpha, "step_norm": step_norm, "merit": th(st.pt), "D": D,
            "qp_iterations": iterations, "ls_trials": found.trials, "mode": "restoration",
            "shift": st.restoration_mu}
