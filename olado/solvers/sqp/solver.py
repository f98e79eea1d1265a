"""Powell's SQP method with structure-exploiting QP subproblems (paper 001 sec. 4.2.1).

Each major iteration linearizes the DOCP at (X, U) into the QP (8)-(10) in stage form (a
:class:`~olado.qp.stageqp.StageQP`, so its KKT systems are LQ-DOCPs solved by the Riccati
recursion), solves it with the chosen QP method, and takes a step along its solution s:

    y^{i+1} = y^i + alpha s^i                                                   (11)

with alpha from Armijo backtracking on the L1 exact penalty function

    phi(y) = J(y) + sum_i rho_i |h_i(y)| + sum_j rho_j max(0, -g_j(y))  (+ bound violations)

whose weights follow Powell's (1978) rule rho_i := max(|mu_i|, (rho_i + |mu_i|)/2) with mu the QP
multipliers; D = grad J . s - sum rho |c| is the directional derivative of phi along s (Nocedal &
Wright 2006, (18.29)). The watchdog technique of Chamberlain, Powell, Lemarechal and Pedersen
(1982) lets a full step through without merit decrease ("relaxed") and returns to the watched
point when phi has not decreased sufficiently below it within ``watchdog_steps`` iterations. With
``second_order_correction`` a rejected full step is first corrected by the QP with the constraint
values c(y + s) - J s (Fletcher 1982; Nocedal & Wright sec. 18.3). The QP multipliers are the new
multiplier estimates. The Hessian is one of :mod:`olado.solvers.sqp.hessian` (block BFGS, block SR1,
exact with Gerschgorin or Levenberg convexification, Powell's BFGS with the gangster operator),
always block diagonal (12).

Exact Hessian, ``convexify = "inertia"`` (the default): the QP gets the exact Lagrangian Hessian
plus delta*I, delta chosen as in the inertia correction of Waechter & Biegler (2006, Alg. IC):
each iteration starts from ``shift_decrease`` times the last delta (0 below ``shift_min``), a QP
that fails (its Riccati factorizations find a reduced Hessian that is not positive definite and
the interior point stalls) is solved again with delta = max(``shift_increase`` delta,
``shift_init`` max|H|, ``shift_curvature`` (-s.H s / |s|^2)), s its last iterate: the negative
curvature of the unshifted Hessian along s, which a shift well below it cannot remove, so one
re-solve replaces several tenfold raises. A QP step that is no descent direction of phi (D > 0
beyond what the KKT tolerance resolves) is a sign of the same nonconvexity -- with a positive
definite reduced Hessian and rho >= |mu| it cannot happen (Nocedal & Wright Thm. 18.2) -- and is
treated the same way (s the step): delta grows and the QP is solved again at the same point.
Only ``max_ascent_steps`` such steps per solve are tried first as relaxed watchdog steps (never
in the local phase), and a watchdog return to a point whose step was no descent direction
re-solves its QP with a larger delta instead of backtracking uphill; the step after a watchdog
return is never relaxed (from the point the return reached, often the watched step's own full
step, the same QP would repeat the same relaxed steps). delta is kept per stage block (N + 1
values); with ``shift_mode = "global"`` (default) all are equal. With ``shift_mode = "stage"`` a
rejected step s, or the last iterate of a failed QP, raises delta only on the blocks without positive
curvature along it, s_k.(H_k + delta_k I) s_k <= 0 (H is block diagonal, so s.H s is the sum of
these terms and its negative part sits in those blocks); on a long horizon one window that needs
a large shift then no longer damps the steps of every other stage.

Local phase: after a full step (Armijo test met) from a point with relative KKT residual <=
``local_tol`` the next QP starts from delta = 0 (once, on entering the phase), is warm-started
from the multipliers of the last QP and a zero step (``qp_warm_start``), and is solved to
``local_qp_tol``.

Stopping: KKT residual (max-norm of the NLP stationarity, relative to the largest |grad J|
seen) <= tol and constraint violation <= constr_viol_tol, tested at each new iterate with the
multipliers of the QP that produced it (the pair (y_k, lambda_k) of Nocedal & Wright Alg. 18.3,
so no QP is solved after convergence) and again with the multipliers of the next QP; or a step
shorter than step_tol (relative) with the constraints satisfied. A proximal term
proximal*max|H|*I in the QP Hessian (by default with the exact Hessian only) picks the shortest
step along flat directions of degenerate optima; it makes the local rate fast-linear, and turns
a QP dual error e into a step of about e / (proximal max|H|) along those directions, hence the
tighter tolerance of the last QPs.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...qp import INTERIOR_POINT_METHODS, QP_METHODS, make_qp_solver
from ...qp.stageqp import StageQP
from ...result import Status
from ..common import EVALUATION_KINDS, Deadline, build_result, make_nlp
from ..base import Solver, SolverOptions, option
from .hessian import make_hessian
from ..registry import register

from ...linalg.backend import KKT_SOLVERS  # the KKT back-end names (the one table: olado.linalg.backend)


def _apply_qp_options(qp_solver, qp_name, qp_options):
    """Set ``qp_options`` (SQPOptions) on the QP solver's options, each checked like any option;
    with an external backend a key that ExternalQPOptions does not know is passed to the backend
    itself (``backend_options``); with olado's methods it is an error naming the key."""
    from ..base import validate_value

    opts = qp_solver.options
    known = {f.name for f in dataclasses.fields(opts)}
    for key, value in qp_options.items():
        if key not in known and qp_name not in INTERIOR_POINT_METHODS:
            opts.backend_options = {**opts.backend_options, key: value}
        else:   # validate_value also names an unknown key and the allowed ones
            setattr(opts, key, validate_value(type(opts), key, value, section="sqp.raw (qp_options)"))


def convex_step_qp(problem, shift=1e-4, U=None):
    """The QP of a first SQP step at U (default: the problem's initial guess), convexified for
    comparisons with external convex QP solvers: A, B from the dynamics Jacobians, Hessian blocks
    of the stage and final costs (zero multipliers) shifted per block by (most negative
    eigenvalue) + ``shift``, bounds shifted to the step. Stage and final constraints are not
    included. Used by the QP benchmark and the QP tests."""
    p = problem
    N, n, m = p.N, p.n, p.m
    U = p.initial_guess() if U is None else np.asarray(U, dtype=float)
    X = p.simulate(U)
    A, B = p.eval_dynamics_jacobians(X, U)
    hxx, hxu, huu = p.eval_stage_hessians(X, U, 1.0, np.zeros((N, n)))
    H = np.block([[hxx, hxu], [np.transpose(hxu, (0, 2, 1)), huu]])
    H = H + (np.maximum(0.0, -np.linalg.eigvalsh(H)[:, 0]) + shift)[:, None, None] * np.eye(n + m)
    HN = p.eval_final_hessian(X[-1], 1.0)
    HN = HN + (max(0.0, -np.linalg.eigvalsh(HN)[0]) + shift) * np.eye(n)
    lx, lu = p.eval_stage_cost_gradients(X, U)
    return StageQP(Q=np.concatenate([H[:, :n, :n], HN[None]]), S=H[:, :n, n:], R=H[:, n:, n:],
                   q=np.vstack([lx, p.eval_final_cost_gradient(X[-1])]), r=lu, A=A, B=B,
                   c=p.eval_dynamics(X, U) - X[1:], x0=np.zeros(n),
                   x_lower=p.x_lower - X, x_upper=p.x_upper - X, u_lower=p.u_lower - U, u_upper=p.u_upper - U)


@dataclasses.dataclass
class SQPOptions(SolverOptions):
    """Options of :class:`SQPSolver` (``[sqp]`` section of an ini file)."""

    max_iter: int = option(200, "maximum number of major (SQP) iterations", min=0)
    tol: float = option(1e-7, "KKT residual tolerance, relative to the largest gradient max-norm |grad J| seen "
                        "(at the start or later), so that the test does not depend on the objective's scale",
                        min=0.0, min_exclusive=True)
    qp: str = option("mehrotra", "QP method for the subproblems", choices=QP_METHODS)
    kkt: str = option("riccati", "KKT (matrix) solver inside the interior-point QP methods", choices=KKT_SOLVERS)
    hessian: str = option("exact", "Hessian: block BFGS, block SR1, exact, or Powell's BFGS with the gangster operator",
                          choices=("bfgs", "sr1", "exact", "powell-bfgs"))
    convexify: str = option("inertia", "exact Hessian: 'inertia' passes it to the QP and adds delta*I only when the "
                            "QP fails (its KKT factorizations find a reduced Hessian that is not positive definite) "
                            "or its step is no descent direction of the merit function (shift_* options); "
                            "'levenberg' shifts every block to be positive definite; 'gerschgorin' is modification (13)",
                            choices=("inertia", "levenberg", "gerschgorin"))
    initial_hessian_scale: float = option(0.0, "initial quasi-Newton blocks: this times the identity; 0 = automatic "
                                          "(y.y/s.y per block at the first update)", min=0.0)
    min_eigenvalue: float = option(1e-8, "smallest eigenvalue kept in a Hessian block", min=0.0, min_exclusive=True)
    max_condition: float = option(1e8, "block BFGS: a block whose condition number exceeds this after an update is "
                                  "restarted as the geometric mean of its eigenvalues times I (inf: never)", min=1.0)
    qp_tol: float = option(1e-9, "tolerance of olado's interior-point QP methods (external backends keep their own "
                           "tolerances: set them in qp_options, e.g. eps_abs / eps_rel for OSQP, tol_feas / "
                           "tol_gap_abs / tol_gap_rel for Clarabel)", min=0.0, min_exclusive=True)
    qp_max_iter: int = option(200, "iteration limit of olado's interior-point QP methods (OSQP: 100 times this, at "
                              "least 50 000; the other external backends keep their own)", min=1)
    watchdog: bool = option(True, "use the watchdog technique (Chamberlain et al. 1982)")
    watchdog_steps: int = option(2, "relaxed iterations allowed before returning to the last good point", min=1)
    armijo: float = option(1e-4, "sufficient-decrease constant of the line search", min=0.0, max=0.5, min_exclusive=True)
    backtrack: float = option(0.5, "step reduction factor of the line search", min=0.01, max=0.99)
    min_step: float = option(1e-10, "smallest step length before the line search gives up", min=0.0, min_exclusive=True)
    step_tol: float = option(1e-12, "stop when |s| <= step_tol * (1 + |y|) and the point is feasible", min=0.0)
    penalty_min: float = option(1e-8, "lower bound of the exact-penalty weights", min=0.0)
    qp_adaptive_tol: bool = option(False, "inexact SQP (Dembo, Eisenstat & Steihaug 1982): the QP tolerance is "
                                   "qp_forcing * (last KKT residual) / (1 + |grad J|), clipped to [qp_tol, qp_tol_max] "
                                   "(olado's interior-point QP methods only)")
    qp_forcing: float = option(0.1, "inexact SQP: forcing factor of the adaptive QP tolerance", min=0.0, max=1.0,
                               min_exclusive=True)
    qp_tol_max: float = option(1e-5, "inexact SQP: loosest QP tolerance (early iterations)", min=0.0, min_exclusive=True)
    feasibility_steps: bool = option(False, "when the KKT test holds but the constraint violation does not, take a "
                                     "least-change correction step (the QP without its gradient) instead of a full SQP step")
    adaptive_proximal: bool = option(False, "proximal term delta = min(proximal, relative KKT residual) * max|H| "
                                     "(Levenberg-Marquardt rule) instead of the fixed proximal * max|H|")
    curvature_tol: float = option(0.0, "inertia correction (0 = off): the QP step must satisfy s.H s >= curvature_tol * "
                                  "max|H| * |s|^2, else the Hessian is shifted and the QP solved again", min=0.0)
    qp_warm_start: str = option("local", "start the QP from the multipliers of the last accepted QP and a zero step: "
                                "'off', 'local' (only in the local phase, see local_tol) or 'always'",
                                choices=("off", "local", "always"))
    qp_warm_start_push: float = option(1e-6, "warm-started interior-point QP: slacks and multipliers are raised to at "
                                       "least this times (1 + their max) (the QP's warm_start_push)", min=0.0, max=1.0,
                                       min_exclusive=True)
    local_tol: float = option(1e-2, "local phase: after a full step (alpha = 1, Armijo test met) from a point whose "
                              "relative KKT residual is <= local_tol the next QP starts with no Hessian shift (and is "
                              "warm-started, see qp_warm_start)", min=0.0)
    local_proximal: float | None = option(1e-6, "proximal factor in the local phase (see local_tol); None: as "
                                          "elsewhere (the proximal option). The default 1e-6 is small enough for a "
                                          "fast local rate (Zambezi testing set: 1502 instead of 2111 SQP iterations, "
                                          "zambezi9 4-8 instead of 24-34) and keeps the QP Hessian regular in the "
                                          "flat directions (with 0 the local QPs' factorizations needed "
                                          "regularization: zambezi12 N = 204 took 30 % longer)", min=0.0)
    local_qp_tol: float = option(1e-10, "QP tolerance in the local phase (0: as elsewhere); the proximal term turns "
                                 "a QP dual error e into a step of about e / (proximal * max|H|) along flat "
                                 "directions, so the last QPs must be solved more accurately than qp_tol", min=0.0)
    shift_init: float = option(1e-4, "inertia correction: first Hessian shift delta*I after a failed QP or a rejected "
                               "step when none was used, relative to max|H| (Waechter & Biegler 2006, delta_0)",
                               min=0.0, min_exclusive=True)
    shift_increase: float = option(10.0, "inertia correction: factor by which delta grows after a failed QP or a "
                                   "rejected step (kappa_+)", min=1.0, min_exclusive=True)
    shift_decrease: float = option(1.0 / 3.0, "inertia correction: the next iteration starts from this times the "
                                   "last delta (kappa_-, 1/3 as in IPOPT)", min=0.0, max=1.0)
    shift_mode: str = option("global", "inertia correction: 'global' shifts every stage block by the same delta; "
                             "'stage' raises delta, after a QP step that is no descent direction, only on the stages "
                             "whose block has no positive curvature along that step (s_k.(H_k + delta_k I) s_k <= 0; "
                             "all stages if none) -- the other stages keep their Newton steps on long horizons",
                             choices=("global", "stage"))
    shift_curvature: float = option(0.5, "inertia correction: after a QP step s that is no descent direction of the "
                                    "merit function, or a failed QP with last iterate s, delta is raised to at least "
                                    "this times the negative curvature -s.H s / |s|^2 of the unshifted Hessian along s "
                                    "(0 = only the tenfold raise)", min=0.0)
    shift_min: float = option(1e-8, "inertia correction: a starting delta below shift_min * max|H| is replaced by 0",
                              min=0.0)
    max_ascent_steps: int = option(1, "relaxed watchdog steps allowed per solve along a QP step that is no descent "
                                   "direction of the merit function (exact Hessian, convexify='inertia'; never in the "
                                   "local phase); after that such a step makes the Hessian shift grow and the QP be "
                                   "solved again", min=0)
    qp_tol_min: float = option(1e-13, "quasi-Newton Hessians with olado's QP methods: a QP step that is no descent "
                               "direction of the merit function is solved again at the same point with a 100 "
                               "times smaller tolerance, down to this (0: never; the step is then backtracked)",
                               min=0.0)
    max_shift_retries: int = option(10, "QP re-solves with a larger Hessian shift at one point when the QP step is "
                                    "no descent direction of the merit function", min=0)
    second_order_correction: bool = option(False, "when a full step along a descent direction fails the Armijo test, "
                                           "try the second-order correction step once (Fletcher 1982; Nocedal & Wright "
                                           "sec. 18.3): the QP again with the constraint values c(y + s) - J s")
    qp_options: dict = option({}, "extra options of the QP solver, in an ini file the [sqp.raw] section: options of "
                              "olado's interior-point methods (InteriorPointQPOptions, e.g. initial_mu) or of "
                              "ExternalQPOptions (eps_abs, tol_feas, ...); for an external backend any other key "
                              "goes to the backend unchanged", ini=False, raw=True)
    proximal: float | None = option(None, "proximal term delta*I added to the QP Hessian, delta = proximal * max|H|: "
                                    "picks the shortest step when the reduced Hessian is singular (flat directions, "
                                    "degenerate optima); it vanishes at the solution (s = 0). None (default): 1e-4 with "
                                    "the exact Hessian, 0 with the quasi-Newton ones (their blocks keep the initial "
                                    "scale in directions no step has explored, so max|H| overstates the curvature and "
                                    "the term stalls the SQP)", min=0.0)


class _Clock:
    """Counts and times the problem evaluations of the SQP (the share of solve time spent in
    olado's evaluation code is reported as info["callback_share"], as for the NLP solvers)."""

    def __init__(self):
        self.counts = {k: 0 for k in EVALUATION_KINDS}
        self.time_s = 0.0

    def add(self, kinds, t0):
        self.time_s += time.perf_counter() - t0
        for k in kinds:
            self.counts[k] += 1


class _Point:
    """Values and derivatives of the DOCP at (X, U), evaluated together."""

    def __init__(self, problem, X, U, derivatives=True, clock=None):
        p = problem
        self.clock = clock if clock is not None else _Clock()
        t0 = time.perf_counter()
        self.X, self.U = X, U
        self.J = p.objective(X, U)
        self.h = p.eval_dynamics(X, U) - X[1:]
        self.g = p.eval_stage_constraints(X, U)
        self.gN = p.eval_final_constraints(X[-1])
        self.clock.add(("objective", "constraints"), t0)
        self.derivs = False
        if derivatives:
            self.add_derivatives(problem)

    def add_derivatives(self, p):
        if self.derivs:
            return
        t0 = time.perf_counter()
        X, U = self.X, self.U
        self.lx, self.lu = p.eval_stage_cost_gradients(X, U)
        self.lN = p.eval_final_cost_gradient(X[-1])
        self.A, self.B = p.eval_dynamics_jacobians(X, U)
        self.Cx, self.Cu = p.eval_stage_constraint_jacobians(X, U)
        self.CN = p.eval_final_constraint_jacobian(X[-1])
        self.derivs = True
        self.clock.add(("gradient", "jacobian"), t0)

    def lagrangian_gradients(self, lam, Lg, LgN):
        """Per-block gradients of the stage Lagrangians f0 + lam_{k+1}.f + Lg.g (z-blocks) and
        of F + LgN.gN (final block); the terms linear in x_{k+1} cancel in differences."""
        gx = self.lx + np.einsum("kij,ki->kj", self.A, lam[1:]) + np.einsum("kij,ki->kj", self.Cx, Lg)
        gu = self.lu + np.einsum("kij,ki->kj", self.B, lam[1:]) + np.einsum("kij,ki->kj", self.Cu, Lg)
        gN = self.lN + self.CN.T @ LgN
        return np.concatenate([gx, gu], axis=1), gN


@register
class SQPSolver(Solver):
    """Powell's SQP (paper 001 sec. 4.2.1) with structure-exploiting QP subproblems."""

    name = "sqp"
    Options = SQPOptions
    description = "Powell's SQP, L1 merit + watchdog, block Hessians, interior-point QP with the Riccati KKT solver"

    def _solve(self, problem, X0, U0):
        o = self.options
        p = problem
        N, n, m, r, rN = p.N, p.n, p.m, p.r, p.rN
        nlp = make_nlp(p)
        timed = _Clock()
        t_start = time.perf_counter()
        deadline = Deadline(o.max_time)
        eq, ineq = p.stage_equality_mask, ~p.stage_equality_mask
        eqN, ineqN = p.final_equality_mask, ~p.final_equality_mask
        qp_solver = make_qp_solver(o.qp, kkt=o.kkt, tol=o.qp_tol, max_iter=o.qp_max_iter)
        interior = o.qp in INTERIOR_POINT_METHODS
        if interior:
            qp_solver.options.warm_start_push = o.qp_warm_start_push
        _apply_qp_options(qp_solver, o.qp, o.qp_options)
        convexify = o.convexify
        if o.hessian == "exact" and convexify == "inertia" and not interior:
            # external QP solvers need a convex QP and do not report a failed factorization:
            # shift every block to positive definiteness instead
            convexify = "levenberg"
        self._convexify = convexify
        hess = make_hessian(o.hessian, convexify=convexify, initial_scale=o.initial_hessian_scale, min_eig=o.min_eigenvalue,
                            max_condition=o.max_condition)
        hess.initial(N, n, m)
        inertia = hess.needs_exact and convexify == "inertia"
        # start: controls clipped into their bounds, x0 exact
        U = np.clip(U0, p.u_lower, p.u_upper)
        X = np.array(X0, dtype=float)
        X[0] = p.x0
        pt = _Point(p, X, U, clock=timed)
        lam = np.zeros((N + 1, n))
        Lg = np.zeros((N, r))          # multiplier of g in "f0 + lam.f + Lg.g" (Lg = nu for =, -y for >=)
        LgN = np.zeros(rN)
        zl_x = np.zeros((N + 1, n)); zu_x = np.zeros((N + 1, n)); zl_u = np.zeros((N, m)); zu_u = np.zeros((N, m))
        # exact-penalty weights (rho_h, rho_g, rho_gN, rho_bx, rho_bu)
        rho = (np.zeros((N, n)), np.zeros((N, r)), np.zeros(rN), np.zeros((N + 1, n)), np.zeros((N, m)))
        history, qp_iters = [], 0
        status, message = Status.MAX_ITERATIONS, f"maximum number of SQP iterations ({o.max_iter}) reached"
        watch = None
        grad_scale = 1e-300
        self._kkt_rel = 1.0
        shift = np.zeros(N + 1)    # Hessian shift per stage block (N: the final block) of the last accepted step
        force_delta = None         # shift for the next QP after a rejected step (non-descent direction)
        ascent_relaxed = o.max_ascent_steps  # non-descent steps that may still be tried as relaxed watchdog steps
        returned = False           # the last step was a watchdog return: the next one is not relaxed
        failed_watch = None        # watched point of the last watchdog return (see relaxed_ok)
        retries = 0                # QPs re-solved with a larger shift at the current point
        force_qp_tol = None        # quasi-Newton: the tighter QP tolerance a non-descent step asked for
        last_qp = None             # QP result of the last accepted step (warm start of the local phase)
        local = was_local = False  # local phase: full steps and a small KKT residual
        Bk = BN = None             # Hessian blocks at (pt, multipliers); None = to be evaluated
        it = 0
        kkt_res = float("nan")

        def violations(q):
            """Constraint violations (arrays) at a point, for the merit function."""
            vg = np.where(eq, np.abs(q.g), np.maximum(-q.g, 0.0)) if r else q.g
            vgN = np.where(eqN, np.abs(q.gN), np.maximum(-q.gN, 0.0)) if rN else q.gN
            vbx = np.maximum(p.x_lower - q.X, 0.0) + np.maximum(q.X - p.x_upper, 0.0)
            vbx[0] = 0.0
            vbu = np.maximum(p.u_lower - q.U, 0.0) + np.maximum(q.U - p.u_upper, 0.0)
            return np.abs(q.h), vg, vgN, vbx, vbu

        def max_violation(q):
            return max(float(np.max(v, initial=0.0)) for v in violations(q))

        def penalty_term(q, weights):
            return sum(float(np.sum(w * v)) for w, v in zip(weights, violations(q)))

        def merit(q, weights=None):
            """The L1 exact penalty function phi(y) with the current (or the given) weights."""
            return q.J + penalty_term(q, rho if weights is None else weights)

        def restore(w):
            """Back to the watched point (watchdog return); its multipliers and derivatives."""
            w["pt"].add_derivatives(p)
            return w["pt"], w["lam"], w["Lg"], w["LgN"]

        while True:
            if deadline.expired():
                status, message = Status.MAX_TIME, f"time limit of {o.max_time:g} s reached after {it} SQP iterations"
                break
            if it >= o.max_iter:
                break
            if it > 0 and retries == 0 and force_delta is None and force_qp_tol is None:
                # convergence test at the new iterate with the multipliers of the QP that produced it
                # (the pair (y_k, lambda_k) of Nocedal & Wright Alg. 18.3): no QP when it holds
                kkt0, gscale = self._kkt_residual(p, pt, lam, Lg, LgN, zl_x, zu_x, zl_u, zu_u)
                grad_scale = max(grad_scale, gscale)
                viol0 = max_violation(pt)
                if viol0 <= o.constr_viol_tol and kkt0 <= o.tol * grad_scale:
                    kkt_res = kkt0
                    status, message = Status.SUCCESS, (f"converged in {it} SQP iterations: KKT residual {kkt0:.2e}, "
                                                       f"constraint violation {viol0:.2e}")
                    break
            # ---------------------------------------------------------------- QP subproblem (8)-(10)
            if Bk is None:
                if hess.needs_exact:
                    t0 = time.perf_counter()
                    Hxx, Hxu, Huu = p.eval_stage_hessians(pt.X, pt.U, 1.0, lam[1:], Lg)
                    HN = p.eval_final_hessian(pt.X[-1], 1.0, LgN)
                    timed.add(("hessian",), t0)
                    blocks = np.empty((N, n + m, n + m))
                    blocks[:, :n, :n] = Hxx; blocks[:, :n, n:] = Hxu
                    blocks[:, n:, :n] = np.transpose(Hxu, (0, 2, 1)); blocks[:, n:, n:] = Huu
                    hess.set_exact(blocks, HN)
                Bk, BN = hess.current()
            hscale = max(1e-300, float(np.max(np.abs(Bk), initial=0.0)), float(np.max(np.abs(BN), initial=0.0)))
            if interior:
                qp_solver.options.tol = self._qp_tolerance(kkt_res, grad_scale)
                if local and o.local_qp_tol > 0:
                    qp_solver.options.tol = min(qp_solver.options.tol, o.local_qp_tol)
                if force_qp_tol is not None:
                    qp_solver.options.tol = min(qp_solver.options.tol, force_qp_tol)
            force_qp_tol = None
            # the Hessian shift to start from (inertia correction, Waechter & Biegler 2006 Alg. IC):
            # the one a rejected step asked for, none in the local phase, else a fraction of the last
            if not inertia:
                delta0 = np.zeros(N + 1)
            elif force_delta is not None:
                delta0 = force_delta
            elif local and not was_local:
                delta0 = np.zeros(N + 1)   # entering the local phase: the unshifted Hessian first
            else:
                delta0 = shift * o.shift_decrease
                delta0[delta0 < o.shift_min * hscale] = 0.0
            force_delta = None
            warm = last_qp if (o.qp_warm_start == "always" or (o.qp_warm_start == "local" and local)) else None
            self._in_local = local
            qres, delta = self._solve_qp(qp_solver, p, pt, Bk, BN, eq, ineq, eqN, ineqN, inertia=inertia,
                                         delta=delta0, warm=warm)
            qp_iters += self._qp_iterations
            if not qres.success:
                st = qres.status
                if st == Status.INFEASIBLE:
                    status = Status.INFEASIBLE
                    message = (f"the QP subproblem of SQP iteration {it} is infeasible: the linearized constraints "
                               f"are inconsistent ({qres.message})")
                else:
                    status = Status.NUMERICAL_ERROR
                    message = f"the QP subproblem of SQP iteration {it} failed: {qres.message}"
                break
            dX, dU = qres.X, qres.U
            # new multiplier estimates from the QP
            lam_new = qres.lam.copy()
            Lg_new = np.zeros((N, r))
            if r:
                Lg_new[:, eq] = qres.nu[:N, : int(eq.sum())]
                Lg_new[:, ineq] = -(qres.yc_lower - qres.yc_upper)
            LgN_new = np.zeros(rN)
            if rN:
                LgN_new[eqN] = qres.nu[N, : int(eqN.sum())]
                LgN_new[ineqN] = -(qres.yN_lower - qres.yN_upper)
            zl_x, zu_x, zl_u, zu_u = qres.zx_lower, qres.zx_upper, qres.zu_lower, qres.zu_upper
            # ---------------------------------------------------------------- convergence test
            kkt_res, gscale = self._kkt_residual(p, pt, lam_new, Lg_new, LgN_new, zl_x, zu_x, zl_u, zu_u)
            grad_scale = max(grad_scale, gscale)
            self._kkt_rel = kkt_res / grad_scale
            viol = max_violation(pt)
            step_norm = max(float(np.max(np.abs(dX))), float(np.max(np.abs(dU))))
            y_norm = max(float(np.max(np.abs(pt.X))), float(np.max(np.abs(pt.U))))
            if viol <= o.constr_viol_tol and kkt_res <= o.tol * grad_scale:
                lam, Lg, LgN = lam_new, Lg_new, LgN_new
                status, message = Status.SUCCESS, (f"converged in {it} SQP iterations: KKT residual {kkt_res:.2e}, "
                                                   f"constraint violation {viol:.2e}")
                break
            if viol <= o.constr_viol_tol and step_norm <= o.step_tol * (1 + y_norm):
                lam, Lg, LgN = lam_new, Lg_new, LgN_new
                status, message = Status.ACCEPTABLE, (f"step below step_tol at SQP iteration {it} with a feasible point; "
                                                      f"KKT residual {kkt_res:.2e}")
                break
            if o.feasibility_steps and kkt_res <= o.tol * grad_scale and viol > o.constr_viol_tol:
                # optimal to tolerance but not feasible enough: a QP with the gradient removed gives
                # the least-change (H-norm) correction onto the linearized constraints; it keeps the
                # iterate from wandering along flat directions of degenerate optima
                fres, _ = self._solve_qp(qp_solver, p, pt, Bk, BN, eq, ineq, eqN, ineqN, inertia=inertia,
                                         delta=delta, warm=None, zero_gradient=True)
                qp_iters += self._qp_iterations
                if fres.success:
                    cand = _Point(p, pt.X + fres.X, pt.U + fres.U, derivatives=False, clock=timed)
                    if max_violation(cand) < viol:
                        cand.add_derivatives(p)
                        pt = cand
                        lam, Lg, LgN = lam_new, Lg_new, LgN_new
                        Bk = None
                        it += 1
                        history.append({"iter": it, "objective": pt.J, "violation": max_violation(pt), "kkt": kkt_res,
                                        "step": 1.0, "step_norm": max(float(np.max(np.abs(fres.X))), float(np.max(np.abs(fres.U)))),
                                        "merit": float("nan"), "penalty": float("nan"),
                                        "qp_iterations": int(fres.iterations), "ls_trials": 0, "mode": "feasibility"})
                        if o.verbose >= 2:
                            print(f"{it:5d} {pt.J:16.9e} {history[-1]['violation']:10.2e} {kkt_res:10.2e} {1.0:8.2e} "
                                  f"{history[-1]['step_norm']:10.2e} {'':9s} {int(fres.iterations):4d}  feasibility")
                        continue
            # ---------------------------------------------------------------- penalty update (Powell 1978)
            zbx = zl_x + zu_x; zbu = zl_u + zu_u
            rho_new = tuple(np.maximum(np.maximum(mu, 0.5 * (w + mu)), o.penalty_min)
                            for w, mu in zip(rho, (np.abs(lam_new[1:]), np.abs(Lg_new), np.abs(LgN_new), zbx, zbu)))
            # directional derivative of phi along the QP step (Powell 1978; Nocedal & Wright (18.29))
            phi0 = merit(pt, rho_new)
            D = (float(np.sum(pt.lx * dX[:-1]) + np.sum(pt.lu * dU) + pt.lN @ dX[-1]) - penalty_term(pt, rho_new))
            # a directional derivative below what the optimality tolerance resolves -- a gradient
            # error of tol * |grad J| along the step, or the rounding level of phi -- counts as descent
            d_tol = (10.0 * np.finfo(float).eps * max(1.0, abs(phi0))
                     + o.tol * grad_scale * (float(np.sum(np.abs(dX[1:]))) + float(np.sum(np.abs(dU)))))
            descent = D <= d_tol
            # no relaxed step right after a watchdog return: from the point the return reached (often
            # the watched step's own full step again) the same QP would give the same relaxed steps
            relaxed_ok = (descent or (ascent_relaxed > 0 and not local)) and not returned
            # nor a relaxed step before the merit function is sufficiently below the watched point
            # of the last return: a return whose line search ends short of the watched step lets the
            # next full step reach the watched point again, and its relaxed steps would repeat
            # (zambezi12 N = 48, weighted-corrector QP: the same four iterates for 200 iterations)
            if failed_watch is not None:
                if merit(pt) <= merit(failed_watch["pt"]) - o.armijo * max(abs(failed_watch["D"]), failed_watch["d_tol"]):
                    failed_watch = None
                else:
                    relaxed_ok = False
            if (not inertia and interior and not descent and o.qp_tol_min > 0
                    and qp_solver.options.tol > o.qp_tol_min and watch is None):
                # quasi-Newton (positive definite blocks): a step that is no descent direction of phi
                # comes from the QP's inexact solution -- solve it again, 100 times more accurately
                # (zambezi10 N = 12, block BFGS: D = +2.4e-11 at a KKT residual of 4.7e-8; the
                # uphill backtracking moved 2^-7 of the step for the last 110 of 200 iterations)
                force_qp_tol = max(o.qp_tol_min, 0.01 * qp_solver.options.tol)
                continue
            if (inertia and not descent and retries < o.max_shift_retries
                    and not (relaxed_ok and o.watchdog and watch is None)):
                # not a descent direction of phi: with a positive definite reduced Hessian and
                # rho >= |multipliers| it would be (Nocedal & Wright Thm. 18.2), so the Hessian is
                # shifted further and the QP solved again at the same point
                force_delta = self._raise_shift_along(delta, hscale, Bk, BN, dX, dU)
                retries += 1
                continue
            rho = rho_new
            # ---------------------------------------------------------------- line search on phi
            soc = None
            if o.second_order_correction:
                def soc(cand, pt=pt, dX=dX, dU=dU, delta=delta, qres=qres):
                    """Second-order correction (Fletcher 1982; Nocedal & Wright sec. 18.3): the QP at
                    pt again with the constraint values c(pt + s) - J s of the rejected trial point."""
                    nonlocal qp_iters
                    offsets = self._soc_offsets(p, pt, cand, dX, dU)
                    cres, _ = self._solve_qp(qp_solver, p, pt, Bk, BN, eq, ineq, eqN, ineqN, inertia=False,
                                             delta=delta, warm=qres, offsets=offsets)
                    qp_iters += self._qp_iterations
                    self._soc_qp_iterations += self._qp_iterations
                    if not cres.success:
                        return None
                    return cres.X, cres.U
            self._soc_qp_iterations = 0
            alpha, new_pt, ls_trials, mode = self._line_search(
                p, pt, dX, dU, phi0, D, merit, watch, relaxed_ok=relaxed_ok, soc=soc, d_tol=d_tol,
                backtrack_uphill=not inertia)
            if new_pt is None and watch is not None:
                # back to the last good point; along its direction only if that is a descent direction
                pt, lam, Lg, LgN = restore(watch)
                Bk = None
                w, watch = watch, None
                new_pt = None
                if w["D"] < 0.0:
                    dX, dU, D, delta = w["dX"], w["dU"], w["D"], w["delta"]
                    lam_new, Lg_new, LgN_new = w["lam_new"], w["Lg_new"], w["LgN_new"]
                    alpha, new_pt, ls_trials, mode = self._line_search(p, pt, dX, dU, merit(pt), D, merit, None)
                    mode = "watchdog-return"
                    returned = new_pt is not None
                failed_watch = w
                if new_pt is None:
                    if inertia:
                        force_delta = self._raise_shift(w["delta"], hscale)
                        ascent_relaxed = 0
                        retries = 0
                        continue
            if new_pt is None:
                if inertia and not descent and retries < o.max_shift_retries:
                    force_delta = self._raise_shift_along(delta, hscale, Bk, BN, dX, dU)
                    retries += 1
                    continue
                status, message = Status.NUMERICAL_ERROR, (f"line search failed at SQP iteration {it}: no step down to "
                                                           f"{o.min_step:g} decreases the L1 merit function (D={D:.2e})")
                lam, Lg, LgN = lam_new, Lg_new, LgN_new
                break
            retries = 0
            if mode != "watchdog-return":
                returned = False
            # watchdog bookkeeping
            if o.watchdog:
                if mode == "relaxed" and not descent:
                    ascent_relaxed -= 1
                if mode == "relaxed":
                    watch = {"pt": pt, "dX": dX, "dU": dU, "D": D, "d_tol": d_tol, "count": 0, "delta": delta,
                             "floor": 0.0 if descent else self._curvature_floor(Bk, BN, dX, dU),
                             "lam": lam, "Lg": Lg, "LgN": LgN, "lam_new": lam_new, "Lg_new": Lg_new, "LgN_new": LgN_new}
                elif watch is not None:
                    watch["count"] += 1
                    # sufficient decrease below the watched point (Chamberlain et al. 1982); after a
                    # relaxed step that was no descent direction, by at least armijo * |D|
                    if merit(new_pt) <= merit(watch["pt"]) - o.armijo * max(abs(watch["D"]), watch["d_tol"]):
                        watch = None
                    elif watch["count"] >= o.watchdog_steps:
                        watch["expired"] = True
            # ---------------------------------------------------------------- Hessian update
            new_pt.add_derivatives(p)
            if not hess.needs_exact:
                g_old, gN_old = pt.lagrangian_gradients(lam_new, Lg_new, LgN_new)
                g_new, gN_new = new_pt.lagrangian_gradients(lam_new, Lg_new, LgN_new)
                s_blocks = np.concatenate([new_pt.X[:-1] - pt.X[:-1], new_pt.U - pt.U], axis=1)
                hess.update(s_blocks, new_pt.X[-1] - pt.X[-1], g_new - g_old, gN_new - gN_old)
            pt = new_pt
            lam, Lg, LgN = lam_new, Lg_new, LgN_new
            Bk = None
            shift = delta
            last_qp = dataclasses.replace(qres, X=np.zeros_like(qres.X), U=np.zeros_like(qres.U))
            # local phase: a full step from a point whose relative KKT residual is small
            was_local = local
            local = mode == "full" and self._kkt_rel <= o.local_tol
            it += 1
            rec = {"iter": it, "objective": pt.J, "violation": max_violation(pt), "kkt": kkt_res, "step": alpha,
                   "step_norm": step_norm, "merit": merit(pt),
                   "penalty": float(max(w.max(initial=0) for w in (rho[0], rho[1], rho[3], rho[4]))),
                   "qp_iterations": int(qres.iterations), "ls_trials": ls_trials, "mode": mode, "shift": float(np.max(delta)),
                   "D": D, "warm": warm is not None}
            history.append(rec)
            if o.verbose >= 2:
                if it == 1:
                    print(f"{'iter':>5} {'objective':>16} {'violation':>10} {'kkt':>10} {'alpha':>8} {'|s|':>10} {'penalty':>9} {'qp':>4}  mode")
                print(f"{it:5d} {pt.J:16.9e} {rec['violation']:10.2e} {kkt_res:10.2e} {alpha:8.2e} {step_norm:10.2e} "
                      f"{rec['penalty']:9.2e} {rec['qp_iterations']:4d}  {mode}")
            if self._call_callback(dict(rec)):
                status, message = Status.USER_STOP, f"stopped by the callback after SQP iteration {it}"
                break
            if watch is not None and watch.get("expired"):
                # merit not below the watched point after watchdog_steps relaxed iterations: return
                if merit(pt) > merit(watch["pt"]) - o.armijo * max(abs(watch["D"]), watch["d_tol"]):
                    w, watch = watch, None
                    pt, lam, Lg, LgN = restore(w)
                    back_pt = None
                    if w["D"] < 0.0:
                        alpha, back_pt, _, _ = self._line_search(p, pt, w["dX"], w["dU"], merit(pt), w["D"], merit, None)
                    failed_watch = w
                    if back_pt is not None:
                        back_pt.add_derivatives(p)
                        pt = back_pt
                        returned = True
                        lam, Lg, LgN = w["lam_new"], w["Lg_new"], w["LgN_new"]
                    elif inertia:
                        # the relaxed step was no descent direction: solve the QP at the watched point
                        # again with a larger shift, and try no more non-descent steps
                        force_delta = self._raise_shift(w["delta"], hscale, floor=w["floor"])
                        ascent_relaxed = 0
                    local = False
                watch = None
        # ---------------------------------------------------------------- result
        solve_time = time.perf_counter() - t_start
        y = nlp.pack(pt.X, pt.U)
        lam_nlp = np.concatenate([lam[1:].ravel(), Lg.ravel(), LgN])
        zl, zu = nlp.pack(zl_x, zl_u), nlp.pack(zu_x, zu_u)
        res = build_result(nlp=nlp, y=y, lam=lam_nlp, zl=zl, zu=zu, status=status, message=message,
                           iterations=it, history=history, timed=timed, solve_time_s=solve_time,
                           kkt_residual=kkt_res, kkt_note="max-norm NLP stationarity at the final point with the QP multipliers (olado SQP)",
                           info={"qp": o.qp, "kkt": o.kkt, "hessian": o.hessian, "convexify": convexify,
                                 "hessian_updates": hess.updates, "hessian_skipped": hess.skipped})
        res.qp_iterations = qp_iters
        return res

    # ------------------------------------------------------------------------------------------
    def _qp_tolerance(self, kkt_res, grad_scale):
        """Tolerance of the next interior-point QP: ``qp_tol``, or with ``qp_adaptive_tol`` the
        inexact-SQP rule clip(qp_forcing * KKT residual / (1 + |grad J|), qp_tol, qp_tol_max)."""
        o = self.options
        if not o.qp_adaptive_tol or not math.isfinite(kkt_res):
            return o.qp_tol if not o.qp_adaptive_tol else max(o.qp_tol, o.qp_tol_max)
        return min(max(o.qp_tol, o.qp_forcing * kkt_res / (1.0 + grad_scale)), max(o.qp_tol, o.qp_tol_max))

    def _solve_qp(self, qp_solver, p, pt, Bk, BN, eq, ineq, eqN, ineqN, inertia, delta, warm=None, zero_gradient=False,
                  offsets=None):
        """Solve the QP subproblem with delta*I (+ the proximal term) added to the Hessian. With
        ``inertia`` (exact Hessian, convexify="inertia") a QP whose KKT factorization fails -- a
        reduced Hessian that is not positive definite -- is solved again with delta raised to
        max(shift_increase * delta, shift_init * max|H|, shift_curvature * the negative curvature
        of H along the failed QP's last iterate) (the inertia correction of Waechter & Biegler
        2006 sec. 3.1, applied to the QP). ``warm`` is a QPResult to start the QP from.
        Returns (QPResult, shift used)."""
        o = self.options
        self._qp_iterations = 0
        scale = max(1e-300, float(np.max(np.abs(Bk), initial=0.0)), float(np.max(np.abs(BN), initial=0.0)))
        # Levenberg-Marquardt-like: delta shrinks with the relative KKT residual of the last
        # iterate (kept superlinear), but never exceeds proximal * max|H|
        prox = min(self._proximal(), self._kkt_rel) * scale if o.adaptive_proximal else self._proximal() * scale
        n, m = p.n, p.m
        for attempt in range(30):
            if np.any(delta + prox > 0):
                Bd = Bk + (delta[:-1] + prox)[:, None, None] * np.eye(n + m)
                BNd = BN + (delta[-1] + prox) * np.eye(n)
            else:
                Bd, BNd = Bk, BN
            qp = self._build_qp(p, pt, Bd, BNd, eq, ineq, eqN, ineqN, offsets)
            if zero_gradient:
                qp.q[:] = 0.0
                qp.r[:] = 0.0
            qres = qp_solver.solve(qp, warm_start=warm)
            self._qp_iterations += int(qres.iterations)
            if inertia and o.curvature_tol > 0 and qres.success and not self._curvature_ok(Bd, BNd, qres, scale):
                # inertia-free curvature test (Chiang & Zavala 2016): a step along which the QP
                # Hessian has (almost) no positive curvature is no descent direction of the merit
                # function -- shift and solve again
                delta = self._raise_shift(delta, scale)
                continue
            qshift = self._qp_shift(qp_solver, qres)
            if not inertia or qres.success or qres.status not in (Status.NUMERICAL_ERROR, Status.UNBOUNDED,
                                                                  Status.MAX_ITERATIONS, Status.FAILED):
                return qres, delta + qshift
            # a failed QP: raise the shift (with shift_mode = 'stage' on the blocks without positive
            # curvature along its last iterate, when it has one)
            if qres.X is not None and np.all(np.isfinite(qres.X)) and np.all(np.isfinite(qres.U)):
                delta = self._raise_shift_along(delta, scale, Bk, BN, qres.X, qres.U)
            else:
                delta = self._raise_shift(delta, scale)
        return qres, delta

    def _proximal(self):
        """The proximal factor: the option, or by default 1e-4 with the exact Hessian and 0 with the
        quasi-Newton ones. Quasi-Newton blocks keep their initial scale (~1) in directions that no
        step has explored (variables that stay at a bound), so max|H| is ~1e3 times the learned
        curvature (~1e-3 on zambezi12) and 1e-4 max|H| damped every step: block SR1 took more than
        200 SQP iterations at N = 48..252 with it, 25-75 without (docs/structure-exploiting-sqp.md)."""
        o = self.options
        if getattr(self, "_in_local", False) and o.local_proximal is not None:
            return o.local_proximal
        if o.proximal is not None:
            return o.proximal
        return 1e-4 if o.hessian == "exact" else 0.0

    def _raise_shift(self, delta, hscale, stages=None, floor=0.0):
        """The inertia correction's next shift: max(shift_increase * delta_k, shift_init * max|H|,
        floor) on the stage blocks in ``stages`` (a boolean mask over the N + 1 blocks; all if None)."""
        o = self.options
        new = np.maximum(o.shift_increase * delta, max(o.shift_init * hscale, floor))
        return new if stages is None else np.where(stages, new, delta)

    def _raise_shift_along(self, delta, hscale, Bk, BN, dX, dU):
        """The next shift after a rejected QP step, or a failed QP's last iterate, s = (dX, dU):
        raised on the blocks without positive curvature along s (shift_mode = 'stage'; all
        otherwise) to at least the curvature floor of s."""
        return self._raise_shift(delta, hscale, self._flat_stages(Bk, BN, delta, hscale, dX, dU),
                                 floor=self._curvature_floor(Bk, BN, dX, dU))

    def _curvature_floor(self, Bk, BN, dX, dU):
        """After a QP step s that is no descent direction of the merit function (or the last
        iterate s of a QP that failed): shift_curvature times the negative curvature of the
        unshifted Hessian along s, -s.H s / |s|^2 (0 if none). s comes from a QP whose reduced
        Hessian had about that much negative curvature, so a shift well below it cannot restore
        descent; a tenfold raise per rejected QP would need several QPs to get there."""
        sHs, ss = self._curvature(Bk, BN, dX, dU)
        if not ss > 0.0:
            return 0.0
        return self.options.shift_curvature * max(0.0, -sHs / ss)

    def _flat_stages(self, Bk, BN, delta, hscale, dX, dU):
        """With shift_mode = 'stage': the blocks without positive curvature along the rejected step
        s (s_k.(H_k + (delta_k + proximal max|H|) I) s_k <= 0, H block diagonal so s.H s is their
        sum), or None (all blocks) when there is none or shift_mode = 'global'."""
        if self.options.shift_mode != "stage":
            return None
        prox = self._proximal() * hscale
        z = np.concatenate([dX[:-1], dU], axis=1)
        curv = np.empty(len(delta))
        curv[:-1] = np.einsum("ki,kij,kj->k", z, Bk, z) + (delta[:-1] + prox) * np.einsum("ki,ki->k", z, z)
        curv[-1] = dX[-1] @ BN @ dX[-1] + (delta[-1] + prox) * (dX[-1] @ dX[-1])
        flat = curv <= 0.0
        return flat if flat.any() else None

    @staticmethod
    def _soc_offsets(p, pt, cand, dX, dU):
        """Constraint values for the second-order correction QP: c(pt + s) - J(pt) s for the
        dynamics (h = f - x_+), the stage and the final constraints (the bounds are linear)."""
        h = cand.h - (np.einsum("kij,kj->ki", pt.A, dX[:-1]) + np.einsum("kij,kj->ki", pt.B, dU) - dX[1:])
        g = cand.g - (np.einsum("kij,kj->ki", pt.Cx, dX[:-1]) + np.einsum("kij,kj->ki", pt.Cu, dU)) if p.r else cand.g
        gN = cand.gN - pt.CN @ dX[-1] if p.rN else cand.gN
        return h, g, gN

    @staticmethod
    def _qp_shift(qp_solver, qres):
        """The shift an interior-point QP in nonconvex = "shift" mode added to its Hessian (0 otherwise)."""
        opts = getattr(qp_solver, "options", None)
        if getattr(opts, "nonconvex", "regularize") != "shift":
            return 0.0
        reg = float(getattr(qres, "regularization", 0.0) or 0.0)
        return reg if reg > 10.0 * opts.regularization else 0.0

    def _curvature_ok(self, Bd, BNd, qres, scale):
        """s^T H s >= curvature_tol * max|H| * |s|^2 for the QP step s."""
        sHs, ss = self._curvature(Bd, BNd, qres.X, qres.U)
        return sHs >= self.options.curvature_tol * scale * ss

    @staticmethod
    def _curvature(Bk, BN, dX, dU):
        """(s.H s, s.s) for s = (dX, dU) and the block-diagonal H of the stage blocks Bk and BN."""
        z = np.concatenate([dX[:-1], dU], axis=1)
        sHs = float(np.einsum("ki,kij,kj->", z, Bk, z) + dX[-1] @ BN @ dX[-1])
        return sHs, float(np.sum(z * z) + dX[-1] @ dX[-1])

    @staticmethod
    def _build_qp(p, pt, Bk, BN, eq, ineq, eqN, ineqN, offsets=None):
        """The QP (8)-(10) in the step (dx, du) at the point pt, in stage form. ``offsets`` =
        (h, g, gN) replaces the constraint values of the linearization (second-order correction)."""
        N, n = p.N, p.n
        X, U = pt.X, pt.U
        h, g, gN = (pt.h, pt.g, pt.gN) if offsets is None else offsets
        Q = np.empty((N + 1, n, n))
        Q[:-1] = Bk[:, :n, :n]; Q[-1] = BN
        kw = {}
        if p.r and eq.any():
            kw.update(E=pt.Cx[:, eq, :], F=pt.Cu[:, eq, :], e=g[:, eq])
        if p.r and ineq.any():
            C = np.concatenate([pt.Cx[:, ineq, :], pt.Cu[:, ineq, :]], axis=2)
            kw.update(C=C, c_lower=-g[:, ineq], c_upper=np.full((N, int(ineq.sum())), np.inf))
        if p.rN and eqN.any():
            kw.update(EN=pt.CN[eqN], eN=gN[eqN])
        if p.rN and ineqN.any():
            kw.update(CN=pt.CN[ineqN], cN_lower=-gN[ineqN], cN_upper=np.full(int(ineqN.sum()), np.inf))
        xl = p.x_lower - X; xu = p.x_upper - X
        xl[0] = -np.inf; xu[0] = np.inf      # x0 is fixed by the x0 row; its bounds are not the QP's business
        return StageQP(Q=Q, R=Bk[:, n:, n:], S=Bk[:, :n, n:], q=np.vstack([pt.lx, pt.lN[None, :]]), r=pt.lu,
                       A=pt.A, B=pt.B, c=h, x0=p.x0 - X[0], x_lower=xl, x_upper=xu,
                       u_lower=p.u_lower - U, u_upper=p.u_upper - U, **kw)

    @staticmethod
    def _kkt_residual(p, pt, lam, Lg, LgN, zl_x, zu_x, zl_u, zu_u):
        """Max-norm of the NLP stationarity (x_1..x_N and u; x_0 is fixed) and the gradient scale."""
        gz, gN = pt.lagrangian_gradients(lam, Lg, LgN)
        n = p.n
        gx = gz[:, :n].copy(); gu = gz[:, n:]
        gx[1:] -= lam[1:-1]                      # the -lam_{k}.x_k term of the previous dynamics row
        gN = gN - lam[-1]
        gx = gx - zl_x[:-1] + zu_x[:-1]
        gN = gN - zl_x[-1] + zu_x[-1]
        gu = gu - zl_u + zu_u
        res = max(float(np.max(np.abs(gx[1:]), initial=0.0)), float(np.max(np.abs(gu), initial=0.0)),
                  float(np.max(np.abs(gN), initial=0.0)))
        scale = max(float(np.max(np.abs(pt.lx), initial=0.0)), float(np.max(np.abs(pt.lu), initial=0.0)),
                    float(np.max(np.abs(pt.lN), initial=0.0)))
        return res, scale

    def _line_search(self, p, pt, dX, dU, phi0, D, merit, watch, relaxed_ok=True, soc=None, d_tol=0.0,
                     backtrack_uphill=True):
        """Armijo backtracking on the L1 merit. With the watchdog enabled, no watch active and
        ``relaxed_ok``, a full step that fails the Armijo test is still taken ("relaxed"). Along a
        direction that is no descent direction (D >= 0) only the full step is tried unless
        ``backtrack_uphill`` (quasi-Newton Hessians, where D >= 0 only comes from an inexact QP
        solution and no Hessian shift is available). Returns
        (alpha, point, trials, mode) or (alpha, None, trials, mode) when no acceptable step was
        found. ``soc(trial point)`` -> corrected step (dX, dU) or None: when the full step along a
        descent direction fails the Armijo test, the second-order correction is tried once, and
        accepted if it meets the Armijo test of the full step (mode "soc")."""
        o = self.options
        alpha, trials = 1.0, 0
        # merit changes below the rounding level of phi (or d_tol, what the optimality tolerance
        # resolves along the step) are not distinguished
        noise = max(10.0 * np.finfo(float).eps * max(1.0, abs(phi0)), d_tol)
        while alpha >= o.min_step:
            trials += 1
            X = pt.X + alpha * dX
            U = pt.U + alpha * dU
            try:
                cand = _Point(p, X, U, derivatives=False, clock=pt.clock)
                phi = merit(cand)
            except Exception as exc:  # non-finite values at the trial point: shorten the step
                from ..common import is_nonfinite_error

                if not is_nonfinite_error(exc):
                    raise
                phi = math.inf
                cand = None
            if cand is not None and phi <= phi0 + o.armijo * alpha * D + noise:
                return alpha, cand, trials, ("full" if alpha == 1.0 else "backtrack")
            if alpha == 1.0 and cand is not None and soc is not None and D < -noise:
                corr = soc(cand)
                if corr is not None:
                    trials += 1
                    try:
                        ccand = _Point(p, pt.X + corr[0], pt.U + corr[1], derivatives=False, clock=pt.clock)
                        if merit(ccand) <= phi0 + o.armijo * D + noise:
                            return 1.0, ccand, trials, "soc"
                    except Exception as exc:  # non-finite values at the corrected point
                        from ..common import is_nonfinite_error

                        if not is_nonfinite_error(exc):
                            raise
            if alpha == 1.0 and cand is not None and o.watchdog and watch is None and relaxed_ok and math.isfinite(phi):
                return alpha, cand, trials, "relaxed"
            if watch is not None and alpha == 1.0 and cand is not None and math.isfinite(phi) and not watch.get("expired"):
                return alpha, cand, trials, "watchdog"
            if D >= -noise and not backtrack_uphill:
                break
            alpha *= o.backtrack
        return alpha, None, trials, "failed"
