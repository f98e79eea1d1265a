"""A trust region for the first SQP step when its QP is a linear program in effect.

At the start the Hessian of the Lagrangian knows no curvature worth the name: the multipliers
are estimates (least squares, or 0), and with a linear objective (a free final time, a Mayer
cost) and mildly nonlinear dynamics the first QP has s.(H + delta I) s negligible beside the
objective's slope g.s along its step. Such a QP is an LP; its step goes to a vertex that the
bounds, not a model of the functions, decide -- and the line search on the l1 merit function
accepts it whenever the objective falls, however little of the predicted reduction of the
violation the step achieves (the penalty weights are still the estimates' size). SLP and
Sl1QP methods (Fletcher 1987, sec. 14.5; Byrd, Gould, Nocedal & Waltz 2003) therefore take LP
steps inside a trust region, shrunk while the model and the functions disagree. The SQP does the
same for its first step only (later steps have the QP's multipliers, and their curvature):

* the step is *linear* when |s.(H + delta I) s| <= LINEAR_CURVATURE |g.s|;
* its *agreement* is the actual reduction of the l1 violation theta at y + s over the reduction
  its linearization predicts (theta(y) minus the relaxed QP's slacks, 0 for a consistent QP),
  the ratio rho_k of a trust-region method (Nocedal & Wright 2006, Alg. 4.1) for the
  constraints, where the step of an LP model fails first;
* a linear step with agreement below AGREEMENT (Nocedal & Wright's 1/4) is taken as the QP gives
  it, but remembered: on most problems the SQP recovers from it (zambezi12 N = 24 from its
  balance start has such a first step, agreement 0.14, and converges in 4 iterations -- boxing it
  there doubled the QP iterations, 49 -> 95). Only when the solve then ends INFEASIBLE -- where a
  wrong verdict costs most -- is it tried again from the start (:func:`second_attempt`): the first
  step solved again at the same point with the control steps boxed, |du_i| <= kappa (1 + |u_i|),
  kappa half the largest relative control step of the rejected QP, until the agreement holds (or
  kappa falls below KAPPA_MIN: then the step is taken as the QP gives it). The second attempt's
  answer is kept when it is a success, else the first attempt's verdict (:func:`better_attempt`);
  iterations and history count both attempts. The second attempt has a budget of its own,
  max(50, 3 x the first attempt's iterations): on a problem that is infeasible indeed
  (steering-too-short, after the multiplier reset of the restoration phase) it can wander where
  the first attempt had reached its verdict in 15 iterations.

The box is relative to the controls' size, as the restoration phase's stationarity test's box
|du| <= 1 + |u| (olado.solvers.sqp.restoration). It is the QP's business only: the box rows'
multipliers are dropped from the bound multipliers (they are no constraints of the problem).

bang-bang-cart (robustness set; T free, from T = 4, u = 0): the first QP (max|H| = 2.4e-3, g.s =
-3.9, s.H s = -0.24) stepped T to its bound 0.1 with theta going from 6 to 5.73 where the
linearization promised 0 (agreement 0.045), and the SQP ended INFEASIBLE at T = 1, u = -1;
in the second attempt, boxed (kappa = 0.5, agreement 0.53), it converges to IPOPT's objective.
"""

from __future__ import annotations

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...result import Status
from .state import Point
from .step import curvature

#: the step is linear (an LP step) when its curvature term is at most this times its slope
LINEAR_CURVATURE = 0.1
#: the linearization agrees with the functions when theta falls by at least this fraction of the
#: predicted reduction
AGREEMENT = 0.25
#: no box narrower than this (relative to 1 + |u|): the step is then taken unboxed
KAPPA_MIN = 1e-3
#: the second attempt's iterations at most: SECOND_ATTEMPT_FACTOR times the first attempt's, and
#: at least SECOND_ATTEMPT_MIN (a second opinion on a verdict, not a second solve without end)
SECOND_ATTEMPT_FACTOR = 3
SECOND_ATTEMPT_MIN = 50


def linear_step(st, step):
    """|s.(H + delta I) s| <= LINEAR_CURVATURE |g.s| for the QP step s of ``step``."""
    pt = st.pt
    sHs, _ = curvature(st.Bk, st.BN, step.dX, step.dU)
    z = np.concatenate([step.dX[:-1], step.dU], axis=1)
    sHs += float(np.sum(step.delta[:-1] * np.einsum("ki,ki->k", z, z)) + step.delta[-1] * (step.dX[-1] @ step.dX[-1]))
    gs = float(np.sum(pt.lx * step.dX[:-1]) + np.sum(pt.lu * step.dU) + pt.lN @ step.dX[-1])
    return abs(sHs) <= LINEAR_CURVATURE * abs(gs)


def agreement(setup, st, step, theta):
    """The actual over the predicted reduction of theta along the full step (1 when the
    linearization predicts no reduction beyond constr_viol_tol; -inf where the functions are not
    finite)."""
    theta0 = theta(st.pt)
    predicted = theta0 - (step.slacks.total() if step.slacks is not None else 0.0)
    if not predicted > setup.options.constr_viol_tol:
        return 1.0
    try:
        with np.errstate(all="ignore"):
            cand = Point(setup.problem, st.pt.X + step.dX, st.pt.U + step.dU, derivatives=False, clock=st.clock)
            theta1 = theta(cand)
    except NonFiniteEvaluationError:
        return -np.inf
    return (theta0 - theta1) / predicted if np.isfinite(theta1) else -np.inf


def next_box(st, step):
    """The box of the next attempt: |du_i| <= kappa (1 + |u_i|), kappa half the largest relative
    control step of ``step``; None when kappa < KAPPA_MIN."""
    scale = 1.0 + np.abs(st.pt.U)
    kappa = 0.5 * float(np.max(np.abs(step.dU) / scale, initial=0.0))
    return kappa * scale if kappa >= KAPPA_MIN else None


def drop_box_multipliers(bounds, U, u_lower, u_upper, box):
    """The bound multipliers without those of the box rows: a box row tighter than the control's
    own bound is no constraint of the problem."""
    return bounds._replace(zl_u=np.where(U - box > u_lower, 0.0, bounds.zl_u),
                           zu_u=np.where(U + box < u_upper, 0.0, bounds.zu_u))


def retry_boxed(st):
    """Whether an attempt that ended INFEASIBLE took an LP first step that the functions did not
    follow (``first_suspect``) without the box: a second attempt from the start boxes it."""
    return st.status == Status.INFEASIBLE and st.first_suspect and not st.trust_armed


def second_attempt(first, st):
    """The state ``st`` (fresh, at the start) as the second attempt after ``first``: the first
    step boxed, the iterations, QP iterations and history counted on from the first attempt's
    (so max_iter and the callback's iteration numbers hold for the whole solve), with a budget of
    max(SECOND_ATTEMPT_MIN, SECOND_ATTEMPT_FACTOR x the first attempt's) iterations of its own."""
    st.trust_armed = True
    st.it = st.start_it = first.it
    st.it_limit = first.it + max(SECOND_ATTEMPT_MIN, SECOND_ATTEMPT_FACTOR * first.it)
    st.qp_iters += first.qp_iters
    st.history = list(first.history)
    return st


def better_attempt(first, second):
    """The second attempt when it ended with a success (or acceptable), else the first attempt's
    INFEASIBLE verdict, with the second's counts and a sentence on it."""
    if second.status is not None and second.status.success:
        return second
    first.it, first.qp_iters, first.history = second.it, second.qp_iters, second.history
    first.message = (f"{first.message} (a second attempt from the start with the first step's control steps "
                     f"boxed ended {second.status.value if second.status else 'without a status'}: "
                     f"{second.message})")
    return first
