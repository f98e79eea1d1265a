"""One major iteration of the SQP method (paper 001 sec. 4.2.1), as phases over the solve's
:class:`~olado.solvers.sqp.state.SQPState`:

1. limits and the convergence test at the iterate with the multipliers of the QP that produced
   it (the pair (y_k, lambda_k) of Nocedal & Wright 2006, Alg. 18.3: no QP after convergence);
2. the Hessian blocks (12): exact (inertia-corrected in the QP) or the quasi-Newton matrices;
3. the QP (8)-(10) and its multipliers (olado.solvers.sqp.step);
4. the convergence test with the new multipliers, the first step's trust region
   (olado.solvers.sqp.trust), and an optional feasibility step;
5. Powell's penalty update, the directional derivative D of the merit function, and the
   decision to re-solve the QP (a step that is no descent direction: larger Hessian shift, or
   with quasi-Newton Hessians a more accurate QP);
6. the line search on the merit function with the watchdog (olado.solvers.sqp.line_search);
7. accepting the step y^{i+1} = y^i + alpha s^i (11): watchdog bookkeeping, quasi-Newton update,
   local phase; the history record and the callback; the watchdog's return to the watched point.

A phase that ends the iteration early returns :data:`STOP` (the solve ends, ``st.status`` set)
or :data:`NEXT` (the next iteration, e.g. the QP solved again at the same point); ``None`` lets
the iteration go on.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...linalg.backend import INERTIA_CHECKING
from ...result import Status
from ..certificate import certify, verdict_status
from .line_search import Direction, SearchResult, line_search
from .merit import descent_tolerance, watch_target
from .residuals import kkt_residual, stage_complementarity
from .state import BoundMultipliers, Multipliers, Point, SQPState, Watch
from . import recession, regularization, relaxation, restoration, trust
from . import step as qp_step
from .step import ShiftRule, hessian_scale, qp_multipliers, qp_tolerance, soc_offsets

STOP = True
NEXT = False


@dataclasses.dataclass
class Step:
    """The QP step of the current iteration and what the phases derive from it."""

    qres: Any                   # the QP result
    delta: np.ndarray           # the Hessian shift it was solved with
    dX: np.ndarray
    dU: np.ndarray
    mult_new: Multipliers       # its multipliers, the new estimates
    hscale: float               # max|H|
    warm: bool                  # the QP was warm-started
    slacks: Any = None          # the relaxed QP's slacks (linearized violations at the step), or None
    bounds: Any = None          # its bound multipliers (BoundMultipliers)
    viol: float = float("nan")          # constraint violation at the iterate
    step_norm: float = float("nan")
    rho_new: tuple = ()                 # Powell's penalty weights for this step
    phi0: float = float("nan")          # merit at the iterate with rho_new
    D: float = float("nan")             # directional derivative of the merit along the step
    d_tol: float = 0.0
    descent: bool = True
    relaxed_ok: bool = True
    search: SearchResult | None = None


def initial_state(setup, X0, U0, hess, clock):
    """The state at the start: controls clipped into their bounds, x0 exact, zero multipliers
    and penalty weights."""
    o, p = setup.options, setup.problem
    N, n, m, r, rN = p.N, p.n, p.m, p.r, p.rN
    U = np.clip(U0, p.u_lower, p.u_upper)
    X = np.array(X0, dtype=float)
    X[0] = p.x0
    pt = Point(p, X, U, clock=clock)
    mult, qp_iters = initial_multipliers(setup, pt)
    return SQPState(pt=pt, mult=mult, qp_iters=qp_iters, bounds=BoundMultipliers.zeros(N, n, m),
                    rho=setup.merit.initial_weights(), hess=hess, clock=clock, shift=np.zeros(N + 1),
                    ascent_relaxed=o.max_ascent_steps,
                    message=f"maximum number of SQP iterations ({o.max_iter}) reached")


def strictly_inactive(setup, pt):
    """True when no bound of x^1..x^N, u and no inequality row is active (or violated) at pt."""
    p, (_, ineq, _, ineqN) = setup.problem, setup.masks
    inside = (np.all(pt.X[1:] > p.x_lower[1:]) and np.all(pt.X[1:] < p.x_upper[1:])
              and np.all(pt.U > p.u_lower) and np.all(pt.U < p.u_upper))
    return bool(inside and not (p.r and np.any(pt.g[:, ineq] <= 0.0)) and not (p.rN and np.any(pt.gN[ineqN] <= 0.0)))


def detects_nonconvexity(setup):
    """True when the QP subproblems notice a reduced Hessian that is not positive definite, so
    that the inertia correction shifts it: the exact Hessian with convexify = inertia, on olado's
    QP methods with a KKT back-end that checks the inertia (the Riccati recursion) or on an
    external QP (olado.qp.external reports such a QP as failed)."""
    return setup.inertia and (not setup.interior or setup.options.kkt in INERTIA_CHECKING)


def initial_multipliers(setup, pt):
    """The multipliers of the first iteration's Hessian, and the QP iterations spent on them:
    with ``initial_multipliers = least-squares``, QPs that detect nonconvexity
    (:func:`detects_nonconvexity`) and a start at which no bound and no inequality is active, the
    least-squares estimate (Nocedal & Wright 2006 (18.21); IPOPT's
    start, Waechter & Biegler 2006 sec. 3.6; :func:`olado.solvers.sqp.step.least_squares_multipliers`)
    unless its largest exceeds ``multiplier_init_max``; else 0. Without them the first QP sees the
    objective's curvature only (on cstr its convex model took a step of 2 in u into another
    minimum's basin). Where bounds or inequalities are active the estimate would have to know
    their multipliers -- the first QP's business: there the first Hessian stays the objective's
    (on Zambezi, whose starts have controls at their bounds, the equality-only estimate doubled
    the iterations from the balance start). The estimate usually makes the first Hessian
    indefinite: a QP that does not notice (the sparse KKT back-ends, convexify = gerschgorin) took
    cstr's first step into the other basin with it, so those keep the objective's Hessian."""
    p, o = setup.problem, setup.options
    zero = Multipliers.zeros(p.N, p.n, p.r, p.rN)
    if not (o.initial_multipliers == "least-squares" and detects_nonconvexity(setup) and strictly_inactive(setup, pt)):
        return zero, 0
    est, iterations = qp_step.bounded_estimate(setup, pt)
    return (zero if est is None else est), iterations


def iterate(setup, st: SQPState) -> bool:
    """One major iteration; True when the solve stops (``st.status`` says why)."""
    if limits_reached(setup, st) or converged_at_iterate(setup, st) or stalled_at_acceptable_point(setup, st):
        return STOP
    hscale = hessian_phase(setup, st)
    step = qp_phase(setup, st, hscale)
    if not isinstance(step, Step):
        return step
    for phase in (test_with_new_multipliers, first_step_trust, feasibility_step, merit_phase, search_phase):
        end = phase(setup, st, step)
        if end is not None:
            return end
    accept(setup, st, step)
    if report(setup, st, step):
        return STOP
    if st.unbounded is not None:
        return st.stop(Status.UNBOUNDED, st.unbounded)
    end_expired_watch(setup, st, step)
    return NEXT


# ---------------------------------------------------------------------------- 1. limits, test
def limits_reached(setup, st):
    """The iteration limit; the time limit and interrupts raise (olado.interrupts: the solver's
    loop ends with the last accepted iterate)."""
    setup.limits.check()
    return st.it >= min(setup.options.max_iter, st.it_limit)


def kkt_test(setup, st, kkt_res, mult, bounds, viol):
    """WORHP's optimality test [3]-[6] (seed 000 sec. IV.II) with the SQP's scaling: stationarity
    ``kkt_res`` <= tol * (largest |grad J| seen), complementarity and multiplier signs at the
    iterate <= tol * max(1, |J|) (the multipliers of a QP belong to the bounds and inequalities
    active at the QP's solution y + s; at y they must be complementary too, else a residual is
    cancelled by the multiplier of a bound that y does not touch), violation <= constr_viol_tol.
    After a certificate that failed where this test held, tol is tightened (``st.tol_factor``)."""
    o = setup.options
    tol = o.tol * st.tol_factor
    if not (viol <= o.constr_viol_tol and kkt_res <= tol * st.grad_scale):
        return False
    return stage_complementarity(setup.problem, st.pt, mult, bounds) <= tol * max(1.0, abs(st.pt.J))


def certified_stop(setup, st, status, message, mult, promote=False):
    """Stop with ``status`` (SUCCESS or ACCEPTABLE) when olado's certificate of the iterate holds
    (olado.solvers.certificate; at the acceptable level for ACCEPTABLE), setting ``st.mult``.
    Otherwise iterate on (False) -- unless a derivative is wrong (the iterates cannot help that) or
    ``certificate_attempts`` certificates have been computed: then stop with the certificate's
    verdict (ACCEPTABLE or UNCERTIFIED, the message naming the residual that fails). With
    ``promote`` an ACCEPTABLE stop whose certificate holds at its full tolerance is a SUCCESS."""
    if setup.certificate is None:
        st.mult = mult
        return st.stop(status, message)
    cert = certify(setup.problem, st.pt.X, st.pt.U, {"dynamics": mult.lam[1:], "stage_constraints": mult.Lg,
                                                      "final_constraints": mult.LgN}, setup.certificate)
    st.certificates += 1
    done = cert.level == "success" or (cert.level == "acceptable" and status == Status.ACCEPTABLE)
    if not (done or cert.gradient_check_note or st.certificates >= setup.options.certificate_attempts):
        # the SQP's own test is looser here than the certificate's: tighten it by the ratio
        err = max(cert.stationarity_scaled, cert.complementarity_scaled)
        if err > setup.certificate.tol:
            st.tol_factor *= max(0.5 * setup.certificate.tol / err, 1e-8)
        return False
    st.mult, st.certificate = mult, cert
    if promote and cert.level == "success":
        status, message = Status.SUCCESS, f"{message}; olado's certificate holds"
    return st.stop(*verdict_status(cert, status, message))


def converged_at_iterate(setup, st):
    """The KKT test at a new iterate with the multipliers of the QP that produced it (not after a
    QP re-solve at the same point)."""
    if not (st.it > st.start_it and st.retries == 0 and st.force_delta is None and st.force_qp_tol is None):
        return False
    kkt0, gscale = kkt_residual(setup.problem, st.pt, st.mult, st.bounds)
    st.grad_scale = max(st.grad_scale, gscale)
    viol0 = setup.merit.max_violation(st.pt)
    if kkt_test(setup, st, kkt0, st.mult, st.bounds, viol0):
        st.kkt_res = kkt0
        return certified_stop(setup, st, Status.SUCCESS, (f"converged in {st.it} SQP iterations: KKT residual "
                                                          f"{kkt0:.2e}, constraint violation {viol0:.2e}"), st.mult)
    return False


#: low-pass filter termination: the KKT residual counts as stalled when it fell by less than this
#: factor over the last stall_iterations iterations (a slow but steady decrease is progress)
STALL_KKT_FACTOR = 0.5


def stalled_at_acceptable_point(setup, st):
    """WORHP's low-pass filter termination (seed 000 sec. IV.II): the filtered objective and
    constraint violation (updated in :func:`report`) have not moved for ``stall_iterations``
    iterations at a feasible point, and the KKT residual fell by less than STALL_KKT_FACTOR
    meanwhile -- no more progress is made with the given inputs (e.g. inexact derivatives). The
    point ends the solve if olado's certificate holds there: SUCCESS when it holds at the
    certificate's tolerance, ACCEPTABLE at the acceptable level only."""
    o = setup.options
    k = o.stall_iterations
    if not (k and st.stalled >= k and len(st.history) > k):
        return False
    if not st.history[-1]["kkt"] > STALL_KKT_FACTOR * st.history[-1 - k]["kkt"]:
        return False
    st.stalled = 0
    message = (f"stalled at SQP iteration {st.it}: the filtered objective and constraint violation changed by "
               f"less than {o.stall_tol:g} (relative) and the KKT residual by less than a factor "
               f"{STALL_KKT_FACTOR:g} in {k} iterations at a feasible point")
    return certified_stop(setup, st, Status.ACCEPTABLE, message, st.mult, promote=True)


# ---------------------------------------------------------------------------- 2. Hessian
def hessian_phase(setup, st):
    """The Hessian blocks at (pt, multipliers), evaluated once per iterate; returns max|H|."""
    if st.Bk is None:
        hess, p, pt = st.hess, setup.problem, st.pt
        if hess.needs_exact:
            hess.set_exact(*pt.lagrangian_hessian(p, st.mult))
        st.Bk, st.BN = hess.current()
    scale = hessian_scale(st.Bk, st.BN)
    st.hscale_of = (st.Bk, st.BN, scale)     # for the iteration's QPs (olado.solvers.sqp.step.solve_qp)
    return scale


# ---------------------------------------------------------------------------- 3. QP
def starting_shift(setup, st, hscale):
    """The Hessian shift to start from (inertia correction, Waechter & Biegler 2006 Alg. IC):
    the one a rejected step asked for, none on entering the local phase, else a fraction of the
    last."""
    N = setup.problem.N
    if not setup.inertia:
        return np.zeros(N + 1)
    if st.force_delta is not None:
        delta = st.force_delta
    elif st.local and not st.was_local:
        delta = np.zeros(N + 1)     # entering the local phase: the unshifted Hessian first
    else:
        delta = ShiftRule(setup.options).start(st.shift, hscale)
    if st.tau > 0.0:                # WORHP's regularization [11], once a step was untrusted
        delta = np.maximum(delta, regularization.tau_shift(st.tau, st.Bk, st.BN, hscale))
    return delta


def qp_phase(setup, st, hscale):
    """Solve the QP at the iterate: the Step, or STOP (status set) / NEXT when the QP failed."""
    o, p, qp_solver = setup.options, setup.problem, setup.qp_solver
    if setup.interior:
        qp_solver.options.tol = qp_tolerance(o, st.kkt_res, st.grad_scale)
        if st.local and o.local_qp_tol > 0:
            qp_solver.options.tol = min(qp_solver.options.tol, o.local_qp_tol)
        if st.force_qp_tol is not None:
            qp_solver.options.tol = min(qp_solver.options.tol, st.force_qp_tol)
    st.force_qp_tol = None
    delta0 = starting_shift(setup, st, hscale)
    st.force_delta = None
    warm = st.last_qp if (o.qp_warm_start == "always" or (o.qp_warm_start == "local" and st.local)) else None
    st.qp_local = st.local
    if st.restoring and st.restoration_steps == 0:      # entering the restoration phase
        return restoration_iteration(setup, st, delta0)
    box = st.trust_box if st.it == st.start_it else None    # the first step's trust region (olado.solvers.sqp.trust)
    qs = qp_step.solve_qp(setup, st, st.pt, st.Bk, st.BN, delta0, inertia=setup.inertia, warm=warm, u_box=box)
    st.qp_iters += qs.iterations
    qres = qs.result
    if st.restoring:
        if not ((qres.success and restoration.may_leave(setup, st)) or restoration.feasible(setup, st.pt)):
            return restoration_iteration(setup, st, qs.delta)
        # the optimality phase resumes with this QP's step; at a feasible point also when the QP
        # failed (the relaxed QP, else the failure is the optimality phase's: no restoration helps)
        st.restoring = False
    if not qres.success and o.elastic and (qres.status == Status.INFEASIBLE or (
            qres.status in RELAXABLE and not (st.watch is not None and setup.inertia))):
        # inconsistent linearization: the relaxed (elastic) QP instead (olado.solvers.sqp.relaxation),
        # from the starting shift (a failed QP's shift was raised by the inertia correction in vain)
        shift = qs.delta if qres.status == Status.INFEASIBLE else delta0
        rel = relaxation.solve_relaxed(setup, st, st.Bk, st.BN, shift, u_box=box)
        st.qp_iters += rel.solve.iterations
        if rel.stationary:
            return restoration.infeasible(setup, st, "the linearized constraints are inconsistent and no step "
                                          "reduces their l1 violation")
        if rel.irreducible and not st.restoring:
            # irreducible with a dynamics residual: the states simulated from the controls (where
            # the relaxed QP's stationarity test is honest), else the restoration phase decides
            if restoration.simulate_states(setup, st):
                return NEXT
            if o.restoration:
                restoration.start(setup, st)
                return NEXT
        if rel.solve.result.success:
            st.eta = rel.eta
            qs, qres = rel.solve, rel.solve.result
    if not qres.success:
        return qp_failed(setup, st, qres)
    mult_new, st.bounds = qp_multipliers(qres, setup.masks, p.N, p.r, p.rN)
    if box is not None:
        st.bounds = trust.drop_box_multipliers(st.bounds, st.pt.U, p.u_lower, p.u_upper, box)
    return Step(qres=qres, delta=qs.delta, dX=qres.X, dU=qres.U, mult_new=mult_new, hscale=hscale,
                warm=warm is not None, slacks=qs.slacks, bounds=st.bounds)


#: QP failures after which the relaxed QP is tried: an inconsistent linearization is reported as
#: INFEASIBLE by a QP method that detects it, but an interior-point QP without an infeasibility
#: test stops on a numerical difficulty or its iteration limit instead (the relaxed QP is always
#: feasible, so it decides: its slacks measure the inconsistency). Not during a watch (exact
#: Hessian): there a failed QP means a bad relaxed step, and qp_failed returns to the watched point
RELAXABLE = (Status.INFEASIBLE, Status.NUMERICAL_ERROR, Status.MAX_ITERATIONS)


def restoration_iteration(setup, st, delta):
    """One step of the restoration phase (olado.solvers.sqp.restoration), logged like an SQP
    iteration: NEXT, or STOP (infeasible, or the callback)."""
    rec = restoration.restoration_step(setup, st, delta, completion(setup, st, st.mult))
    if rec is STOP:
        return STOP
    return STOP if log_iteration(setup, st, rec) else NEXT


def qp_failed(setup, st, qres):
    """A QP that failed even after the inertia correction (and its relaxed form). Reached by
    relaxed (watchdog) steps: back to the watched point with WORHP's regularization switched on
    (tau, olado.solvers.sqp.regularization) and no more relaxed steps (NEXT). At an infeasible
    point: the restoration phase (NEXT). At a feasible point after a step that decreased the
    objective, a QP that is unbounded ends the solve UNBOUNDED; otherwise the solve ends (STOP)."""
    w = st.watch
    if w is not None and setup.inertia:
        st.watch = None
        st.pt, st.mult = restore(setup, w)
        st.Bk = None
        st.failed_watch = w
        st.ascent_relaxed = 0
        st.tau = regularization.raise_tau(st.tau, setup.options)
        st.force_delta = w.delta
        st.retries = 0
        st.local = False
        return NEXT
    if (qres.status == Status.UNBOUNDED and st.decreased
            and recession.feasible(setup, st.pt, setup.merit.max_violation(st.pt))):
        return st.stop(Status.UNBOUNDED, (f"the problem appears unbounded below: the last step decreased the "
                                          f"objective to {st.pt.J:.6g}, and the QP subproblem of SQP iteration "
                                          f"{st.it} at this feasible iterate is unbounded ({qres.message})"))
    if (setup.options.restoration and not st.restoring
            and setup.merit.max_violation(st.pt) > setup.options.constr_viol_tol):
        restoration.start(setup, st)    # WORHP's recovery from a failed QP at an infeasible point
        return NEXT
    if qres.status == Status.INFEASIBLE:
        return st.stop(Status.INFEASIBLE, (f"the QP subproblem of SQP iteration {st.it} is infeasible: the "
                                           f"linearized constraints are inconsistent ({qres.message})"))
    return st.stop(Status.NUMERICAL_ERROR, f"the QP subproblem of SQP iteration {st.it} failed: {qres.message}")


# ---------------------------------------------------------------------------- 4. test, feasibility
def test_with_new_multipliers(setup, st, step):
    """KKT test at the iterate with the QP's multipliers; or a step below step_tol at a feasible
    point (ACCEPTABLE)."""
    o = setup.options
    st.kkt_res, gscale = kkt_residual(setup.problem, st.pt, step.mult_new, st.bounds)
    st.grad_scale = max(st.grad_scale, gscale)
    st.kkt_rel = st.kkt_res / st.grad_scale
    step.viol = viol = setup.merit.max_violation(st.pt)
    step.step_norm = max(float(np.max(np.abs(step.dX))), float(np.max(np.abs(step.dU))))
    y_norm = max(float(np.max(np.abs(st.pt.X))), float(np.max(np.abs(st.pt.U))))
    if kkt_test(setup, st, st.kkt_res, step.mult_new, st.bounds, viol) and certified_stop(
            setup, st, Status.SUCCESS, (f"converged in {st.it} SQP iterations: KKT residual {st.kkt_res:.2e}, "
                                        f"constraint violation {viol:.2e}"), step.mult_new):
        return STOP
    if viol <= o.constr_viol_tol and step.step_norm <= o.step_tol * (1 + y_norm) and certified_stop(
            setup, st, Status.ACCEPTABLE, (f"step below step_tol at SQP iteration {st.it} with a feasible point; "
                                           f"KKT residual {st.kkt_res:.2e}"), step.mult_new):
        return STOP
    return None


def first_step_trust(setup, st, step):
    """The first step's trust region (olado.solvers.sqp.trust). A linear first step (an LP step)
    whose reduction of the l1 violation falls short of trust.AGREEMENT times the predicted one is
    taken but remembered (``first_suspect``: an INFEASIBLE end is then tried again from the start,
    :func:`olado.solvers.sqp.trust.second_attempt`); in that second attempt it is solved again at
    the same point with the control steps boxed (NEXT) until the agreement holds. A step that is
    not linear, or agrees, is trusted."""
    if st.it > st.start_it or st.first_trusted or st.restoring:
        return None
    if st.trust_box is None and not trust.linear_step(st, step):
        st.first_trusted = True
        return None
    if trust.agreement(setup, st, step, restoration.theta(setup)) >= trust.AGREEMENT:
        st.first_trusted = True
        return None
    box = trust.next_box(st, step) if st.trust_armed else None
    if box is None:
        st.first_suspect = st.trust_box is None
        st.first_trusted = True
        return None
    st.trust_box = box
    st.force_delta = step.delta
    return NEXT


def feasibility_step(setup, st, step):
    """``feasibility_steps``: optimal to tolerance but not feasible enough -- a QP with the
    gradient removed gives the least-change (H-norm) correction onto the linearized constraints;
    it keeps the iterate from wandering along flat directions of degenerate optima."""
    o, p = setup.options, setup.problem
    if not (o.feasibility_steps and st.kkt_res <= o.tol * st.grad_scale and step.viol > o.constr_viol_tol):
        return None
    fs = qp_step.solve_qp(setup, st, st.pt, st.Bk, st.BN, step.delta, inertia=setup.inertia, zero_gradient=True)
    st.qp_iters += fs.iterations
    fres = fs.result
    if not fres.success:
        return None
    try:
        cand = Point(p, st.pt.X + fres.X, st.pt.U + fres.U, derivatives=False, clock=st.clock)
        if not setup.merit.max_violation(cand) < step.viol:
            return None
        completion(setup, st, step.mult_new)(cand)
    except NonFiniteEvaluationError:     # non-finite values or derivatives there: no correction step
        return None
    st.pt = cand
    st.mult = step.mult_new
    st.Bk = None
    st.it += 1
    st.history.append({"iter": st.it, "objective": cand.J, "violation": setup.merit.max_violation(cand),
                       "kkt": st.kkt_res, "step": 1.0,
                       "step_norm": max(float(np.max(np.abs(fres.X))), float(np.max(np.abs(fres.U)))),
                       "merit": float("nan"), "penalty": float("nan"), "qp_iterations": int(fres.iterations),
                       "ls_trials": 0, "mode": "feasibility"})
    if o.verbose >= 2:
        h = st.history[-1]
        print(f"{st.it:5d} {cand.J:16.9e} {h['violation']:10.2e} {st.kkt_res:10.2e} {1.0:8.2e} "
              f"{h['step_norm']:10.2e} {'':9s} {int(fres.iterations):4d}  feasibility")
    return NEXT


# ---------------------------------------------------------------------------- 5. merit, re-solve
def merit_phase(setup, st, step):
    """Powell's penalty update, D along the step, and whether the step may be a relaxed one;
    then the decision to solve the QP again at the same point instead of searching along it."""
    o, merit, pt = setup.options, setup.merit, st.pt
    step.rho_new = merit.update(st.rho, step, st.bounds, o, st.it,
                                lambda: regularization.step_curvature(st.Bk, st.BN, step.delta, step.dX, step.dU))
    step.phi0 = merit.value(pt, step.rho_new)
    step.D = merit.derivative(pt, step, step.rho_new)
    step.d_tol = descent_tolerance(step.phi0, o.tol, st.grad_scale, step.dX, step.dU)
    step.descent = step.D <= step.d_tol
    # no relaxed step right after a watchdog return: from the point the return reached (often
    # the watched step's own full step again) the same QP would give the same relaxed steps
    step.relaxed_ok = (step.descent or (st.ascent_relaxed > 0 and not st.local)) and not st.returned
    # nor a relaxed step before the merit function is sufficiently below the watched point of
    # the last return: a return whose line search ends short of the watched step lets the next
    # full step reach the watched point again, and its relaxed steps would repeat
    if st.failed_watch is not None:
        if merit.value(pt, st.rho) <= watch_target(merit, st.failed_watch, st.rho, o.armijo):
            st.failed_watch = None
        else:
            step.relaxed_ok = False
    if (not setup.inertia and setup.interior and not step.descent and o.qp_tol_min > 0
            and setup.qp_solver.options.tol > o.qp_tol_min and st.watch is None):
        # quasi-Newton (positive definite blocks): a step that is no descent direction of phi
        # comes from the QP's inexact solution -- solve it again, 100 times more accurately
        st.force_qp_tol = max(o.qp_tol_min, 0.01 * setup.qp_solver.options.tol)
        return NEXT
    if (setup.inertia and not step.descent and st.retries < o.max_shift_retries
            and not (step.relaxed_ok and o.watchdog and st.watch is None)):
        # not a descent direction of phi: with a positive definite reduced Hessian and
        # rho >= |multipliers| it would be (Nocedal & Wright Thm. 18.2), so the Hessian is
        # shifted further and the QP solved again at the same point
        return shift_and_resolve(setup, st, step)
    st.rho = step.rho_new
    return None


def shift_and_resolve(setup, st, step):
    """Solve the QP again at the same point with delta raised along the rejected step."""
    st.force_delta = ShiftRule(setup.options).raise_along(step.delta, step.hscale, st.Bk, st.BN,
                                                          step.dX, step.dU, st.qp_local)
    st.retries += 1
    return NEXT


# ---------------------------------------------------------------------------- 6. line search
def merit_of(setup, st):
    """phi with the current penalty weights, as a function of a point (and a step length, unused)."""
    return lambda q, alpha=1.0: setup.merit.value(q, st.rho)


def second_order_correction(setup, st, step):
    """soc(trial point) for the line search (Fletcher 1982; Nocedal & Wright sec. 18.3): the QP
    at pt again with the constraint values c(pt + s) - J s of the rejected trial point."""
    pt, Bk, BN = st.pt, st.Bk, st.BN

    def soc(cand):
        offsets = soc_offsets(setup.problem, pt, cand, step.dX, step.dU)
        cs = qp_step.solve_qp(setup, st, pt, Bk, BN, step.delta, inertia=False, warm=step.qres, offsets=offsets)
        st.qp_iters += cs.iterations
        if not cs.result.success:
            return None
        return cs.result.X, cs.result.U

    return soc


def completion(setup, st, mult):
    """complete(point) for the line search: the derivatives, and with the exact Hessian the
    Hessian blocks with the multipliers ``mult`` the point will carry, evaluated when the point
    is about to be accepted, so that a non-finite derivative rejects the step instead of ending
    the solve."""
    p, exact = setup.problem, st.hess.needs_exact

    def complete(cand):
        cand.add_derivatives(p)
        if exact:
            cand.lagrangian_hessian(p, mult)
    return complete


def restore(setup, watch):
    """Back to the watched point (watchdog return): it and its multipliers, with derivatives."""
    watch.pt.add_derivatives(setup.problem)
    return watch.pt, watch.mult


def search_phase(setup, st, step):
    """The line search along the step; when it fails during a watch, the return to the watched
    point (along the watched step if that was a descent direction: the step's D, delta and
    multipliers become the watched ones, mode "watchdog-return"). A failure ends the iteration:
    a larger Hessian shift at the same point (exact Hessian), else NUMERICAL_ERROR."""
    o, merit = setup.options, merit_of(setup, st)
    soc = second_order_correction(setup, st, step) if o.second_order_correction else None
    direction = Direction(st.pt, step.dX, step.dU, step.phi0, step.D)
    found = line_search(o, setup.problem, direction, setup.merit.along(st.rho, step), st.watch,
                        relaxed_ok=step.relaxed_ok, soc=soc,
                        d_tol=step.d_tol, backtrack_uphill=not setup.inertia,
                        complete=completion(setup, st, step.mult_new),
                        untrusted=lambda phi: regularization.untrusted(phi, step.phi0, step.D, o),
                        stop_untrusted=setup.inertia and st.retries < o.max_shift_retries)
    if found.mode == "untrusted":
        # the model does not describe the step at all: regularize the Hessian (WORHP [11]) and
        # solve the QP again at the same point
        st.tau = regularization.raise_tau(st.tau, o)
        st.force_delta = np.maximum(step.delta, regularization.tau_shift(st.tau, st.Bk, st.BN, step.hscale))
        st.retries += 1
        return NEXT
    if found.point is None and st.watch is not None:
        w, st.watch = st.watch, None
        st.pt, st.mult = restore(setup, w)
        st.Bk = None
        if w.D < 0.0:
            step.dX, step.dU, step.D, step.delta, step.mult_new = w.dX, w.dU, w.D, w.delta, w.mult_new
            back = line_search(o, setup.problem, Direction(st.pt, w.dX, w.dU, merit(st.pt), w.D), merit, None,
                               complete=completion(setup, st, w.mult_new))
            found = back._replace(mode="watchdog-return")
            st.returned = back.point is not None
        st.failed_watch = w
        if found.point is None and setup.inertia:
            st.force_delta = ShiftRule(o).raise_(w.delta, step.hscale)
            st.ascent_relaxed = 0
            st.retries = 0
            return NEXT
    if found.point is None:
        if setup.inertia and not step.descent and st.retries < o.max_shift_retries:
            return shift_and_resolve(setup, st, step)
        if o.restoration and not st.restoring and step.viol > o.constr_viol_tol:
            restoration.start(setup, st)     # WORHP's feasibility mode
            st.retries = 0
            return NEXT
        st.mult = step.mult_new
        return st.stop(Status.NUMERICAL_ERROR, (f"line search failed at SQP iteration {st.it}: no step down to "
                                                f"{o.min_step:g} decreases the merit function (D={step.D:.2e})"))
    step.search = found
    return None


# ---------------------------------------------------------------------------- 7. accept, report
def accept(setup, st, step):
    """Take the step: watchdog bookkeeping, quasi-Newton update, the new iterate and
    multipliers, the local phase."""
    o, p = setup.options, setup.problem
    new_pt, mode = step.search.point, step.search.mode
    st.retries = 0
    if mode != "watchdog-return":
        st.returned = False
    if o.watchdog:
        watchdog_bookkeeping(setup, st, step)
    new_pt.add_derivatives(p)
    if not st.hess.needs_exact:
        pt = st.pt
        g_old, gN_old = pt.lagrangian_gradients(step.mult_new)
        g_new, gN_new = new_pt.lagrangian_gradients(step.mult_new)
        s_blocks = np.concatenate([new_pt.X[:-1] - pt.X[:-1], new_pt.U - pt.U], axis=1)
        st.hess.update(s_blocks, new_pt.X[-1] - pt.X[-1], g_new - g_old, gN_new - gN_old)
    # before tau's update and st.Bk's reset: the proximal-point crawl, under the global proximal
    # factor and under the one the step's QP had (olado.solvers.sqp.phases.crawling)
    crawl, crawl_local = crawling(setup, st, step)
    if st.tau > 0.0:
        tau_update(setup, st, step, new_pt)
    st.rho = setup.merit.accepted(st.rho, step, step.search.alpha)
    st.unbounded = recession.count(setup, st, step, new_pt.J)
    st.decreased = new_pt.J < st.pt.J
    st.pt = new_pt
    st.mult = bounded_multipliers(setup, st, step.mult_new)
    st.Bk = st.hscale_of = None
    st.shift = step.delta
    # the next QP's warm start: its multipliers and a zero step (its kkt and objective are not
    # measured: the copy does not keep this QP's data alive)
    st.last_qp = step.qres.replaced(X=np.zeros_like(step.qres.X), U=np.zeros_like(step.qres.U), kkt={},
                                    objective=float("nan"))
    # local phase: a full step from a point whose relative KKT residual is small, or the
    # proximal-point crawl (two full steps whose curvature came mostly from the proximal term)
    st.was_local = st.local
    st.local = mode == "full" and (st.kkt_rel <= o.local_tol or crawl)
    st.local_proximal_scale = local_proximal_scale(o, st.local_proximal_scale, st.local, crawl_local)
    st.it += 1


def proximal_dominated(setup, st, step, factor, curvature=None):
    """True when the step is a proximal-point step in effect: taken with the exact Hessian
    unshifted (delta = 0, tau = 0), with positive curvature s.H s >= 0 of its own, and the
    proximal term p = ``factor`` * max|H| supplies at least ``local_share`` of its curvature,
    omega = p |s|^2 / (s.H s + p |s|^2) >= local_share. Along s the QP then solves (H + p I) s = -r
    with s.H s / |s|^2 = c << p, and the SQP converges like the proximal-point method, linearly
    at the rate p / (c + p) = omega (Rockafellar 1976): hang-glider, global phase: omega 0.97,
    the KKT residual falling 0.2 -> 0.08 in 50 full steps; goddard's singular arc, local phase
    (factor 1e-6): omega 0.98, the residual x0.98 per step. With s.H s < 0 the proximal term
    convexifies the model along s (no crawl: Zambezi's global steps). ``curvature``: (s.H s, |s|^2)
    with the Hessian blocks of the step's QP (st.Bk), when the caller has it (:func:`crawling`
    computes it once for both factors)."""
    o = setup.options
    if not (setup.inertia and o.local_share < 1.0 and st.tau == 0.0 and not np.any(step.delta)):
        return False
    sHs, ss = curvature if curvature is not None else qp_step.curvature(st.Bk, st.BN, step.dX, step.dU)
    prox = factor * qp_step.shift_scale(step.hscale) * ss
    return ss > 0.0 and prox > 0.0 and sHs >= 0.0 and prox >= o.local_share * (sHs + prox)


def crawling(setup, st, step):
    """(crawl, crawl_local): this full step and the last accepted one are both dominated by the
    global proximal term (:func:`proximal_dominated`; by the local one, in the local phase), and
    the last one reduced the KKT residual -- the linear rate the proximal term predicts, observed
    (a single dominated step proves nothing: the first step of a Mayer problem, H = 0 at zero
    multipliers, is one, and so was goddard's second, whose residual grew x166 with sqp-gondzio).
    Updates the remembered dominance and residual (``st.dominated``, ``st.kkt_prev``)."""
    o = setup.options
    dominated = dominated_local = False
    if step.search.mode == "full" and setup.inertia:
        curv = qp_step.curvature(st.Bk, st.BN, step.dX, step.dU)
        dominated = proximal_dominated(setup, st, step, qp_step.proximal_factor(o, False), curv)
        dominated_local = (st.qp_local and o.local_proximal is not None and proximal_dominated(
            setup, st, step, qp_step.proximal_factor(o, True, st.local_proximal_scale), curv))
    progress = st.kkt_res < st.kkt_prev
    crawl = dominated and st.dominated[0] and progress
    crawl_local = dominated_local and st.dominated[1] and progress
    st.dominated, st.kkt_prev = (dominated, dominated_local), st.kkt_res
    return crawl, crawl_local


def local_proximal_scale(o, scale, local, crawl_local):
    """The next local phase's proximal factor, as a multiple of ``local_proximal``: after the
    crawl under the local factor (:func:`crawling`), 1/``shift_increase`` of
    the last, down to ``shift_min`` (the smallest shift relative to max|H| the inertia correction
    keeps); back to 1 when the local phase ends. The shift of a Levenberg-Marquardt method falls
    the same way while its model agrees (full steps); on a singular arc the reduced Hessian's
    curvature along the singular control (goddard: ~2e-8 max|H|) is below every fixed factor."""
    if not local:
        return 1.0
    if crawl_local and o.local_proximal > 0.0:
        return max(scale / o.shift_increase, o.shift_min / o.local_proximal)
    return scale


def bounded_multipliers(setup, st, mult):
    """The multipliers the new iterate carries into its Hessian: the QP's, or with
    ``multiplier_reset`` (exact Hessian), when their largest exceeds ``multiplier_init_max`` and
    the least-squares estimate at the iterate (IPOPT's initial estimate, Waechter & Biegler 2006
    sec. 3.6, with the same bound constr_mult_init_max) stays below it, the estimate. Far from a
    solution the QP multipliers -(J^T)^+ (grad J + (H(lambda) + delta I) s) of a long step grow
    with the last multipliers through H(lambda) s, and the next Hessian with them: hang-glider's
    grew 14 -> 5e13 in nine full steps, cart-pole's 1.3e3 -> 1.4e7 in five (every step alpha = 1,
    so WORHP's damped update lambda + alpha (lambda_QP - lambda) is the same run); near a solution
    whose multipliers exceed the bound the estimate does too, and the QP's are kept."""
    o = setup.options
    if not (o.multiplier_reset and st.hess.needs_exact and mult.largest() > o.multiplier_init_max):
        return mult
    est, iterations = qp_step.bounded_estimate(setup, st.pt)
    st.qp_iters += iterations
    return mult if est is None else est


def tau_update(setup, st, step, new_pt):
    """WORHP's update of tau (olado.solvers.sqp.regularization, [12]-[14]) after the step to
    new_pt: actual against predicted merit reduction, and the rate of the KKT residual."""
    alpha = step.search.alpha
    actual = step.phi0 - setup.merit.along(step.rho_new, step)(new_pt, alpha)
    sHs = regularization.step_curvature(st.Bk, st.BN, step.delta, step.dX, step.dU)
    ratio = st.kkt_res / st.tau_kkt if st.tau_kkt > 0 else 1.0
    st.tau = regularization.update_tau(st.tau, setup.options, actual, alpha, step.D, sHs, ratio)
    st.tau_kkt = st.kkt_res


def watchdog_bookkeeping(setup, st, step):
    """A relaxed step starts a watch at the current point; a later step ends it when the merit
    is sufficiently below the watched point, or marks it expired after watchdog_steps steps."""
    o, mode = setup.options, step.search.mode
    if mode == "relaxed" and not step.descent:
        st.ascent_relaxed -= 1
    if mode == "relaxed":
        floor = 0.0 if step.descent else ShiftRule(o).curvature_floor(st.Bk, st.BN, step.dX, step.dU)
        st.watch = Watch(pt=st.pt, dX=step.dX, dU=step.dU, D=step.D, d_tol=step.d_tol, delta=step.delta,
                         floor=floor, mult=st.mult, mult_new=step.mult_new)
    elif st.watch is not None:
        st.watch.count += 1
        if setup.merit.value(step.search.point, st.rho) <= watch_target(setup.merit, st.watch, st.rho, o.armijo):
            st.watch = None
        elif st.watch.count >= o.watchdog_steps:
            st.watch.expired = True


def report(setup, st, step):
    """The history record of the iteration, the iteration log, and the callback (True: stop)."""
    rho, found = st.rho, step.search
    return log_iteration(setup, st, {
        "step": found.alpha, "step_norm": step.step_norm, "merit": setup.merit.value(st.pt, rho),
        "penalty": setup.merit.largest_weight(rho),
        "qp_iterations": int(step.qres.iterations), "ls_trials": found.trials, "mode": found.mode,
        "shift": float(np.max(step.delta)), "D": step.D, "warm": step.warm,
        "eta": st.eta if step.slacks is not None else float("nan"), "tau": st.tau})


def log_iteration(setup, st, fields):
    """Append the record {iter, objective, violation, kkt} + ``fields`` of iteration st.it to the
    history, print it (verbose >= 2) and call the callback (True: stop)."""
    o, pt = setup.options, st.pt
    rec = {"iter": st.it, "objective": pt.J, "violation": setup.merit.max_violation(pt), "kkt": st.kkt_res}
    rec.update(fields)
    rec.setdefault("penalty", float("nan"))
    st.history.append(rec)
    update_filters(o, st, pt.J, rec["violation"])
    if o.verbose >= 2:
        if st.it == 1:
            print(f"{'iter':>5} {'objective':>16} {'violation':>10} {'kkt':>10} {'alpha':>8} {'|s|':>10} {'penalty':>9} {'qp':>4}  mode")
        print(f"{st.it:5d} {pt.J:16.9e} {rec['violation']:10.2e} {st.kkt_res:10.2e} {rec['step']:8.2e} "
              f"{rec['step_norm']:10.2e} {rec['penalty']:9.2e} {rec['qp_iterations']:4d}  {rec['mode']}")
    if setup.callback(dict(rec)):
        return st.stop(Status.USER_STOP, f"stopped by the callback after SQP iteration {st.it}")
    return False


def update_filters(o, st, J, viol):
    """WORHP's low-pass filters (seed 000 sec. IV.II) Filter^k = a v^k + (1 - a) Filter^(k-1) of the
    objective and the constraint violation (a = ``stall_filter``); ``st.stalled`` counts the
    successive iterations at a feasible point in which both moved by less than ``stall_tol``
    relative to max(1, |Filter^k|)."""
    if not np.isfinite(st.filter_obj):
        st.filter_obj, st.filter_con, st.stalled = J, viol, 0
        return
    a = o.stall_filter
    new_obj = a * J + (1.0 - a) * st.filter_obj
    new_con = a * viol + (1.0 - a) * st.filter_con
    still = (abs(new_obj - st.filter_obj) < o.stall_tol * max(1.0, abs(new_obj))
             and abs(new_con - st.filter_con) < o.stall_tol * max(1.0, abs(new_con)) and viol <= o.constr_viol_tol)
    st.filter_obj, st.filter_con = new_obj, new_con
    st.stalled = st.stalled + 1 if still else 0


def end_expired_watch(setup, st, step):
    """Merit not below the watched point after watchdog_steps relaxed iterations: return to it,
    along its step if that was a descent direction; otherwise (exact Hessian) solve its QP again
    with a larger shift, and try no more non-descent steps."""
    o, merit = setup.options, merit_of(setup, st)
    w = st.watch
    if w is None or not w.expired:
        return
    st.watch = None
    if not merit(st.pt) > watch_target(setup.merit, w, st.rho, o.armijo):
        return
    st.pt, st.mult = restore(setup, w)
    back = None
    if w.D < 0.0:
        back = line_search(o, setup.problem, Direction(st.pt, w.dX, w.dU, merit(st.pt), w.D), merit, None,
                           complete=completion(setup, st, w.mult_new)).point
    st.failed_watch = w
    if back is not None:
        st.pt = back
        st.returned = True
        st.mult = w.mult_new
    elif setup.inertia:
        st.force_delta = ShiftRule(o).raise_(w.delta, step.hscale, floor=w.floor)
        st.ascent_relaxed = 0
    st.local = False
