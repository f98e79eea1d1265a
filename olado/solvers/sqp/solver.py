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
multiplier estimates -- with the exact Hessian and ``multiplier_reset``, QP multipliers above
``multiplier_init_max`` give way to the least-squares estimate at the new iterate when it stays
below that bound (olado.solvers.sqp.phases.bounded_multipliers). The Hessian is one of :mod:`olado.solvers.sqp.hessian` (block BFGS, block SR1,
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
``local_qp_tol``. So does the proximal-point crawl: a second full step in a row taken with
delta = tau = 0 and s.H s >= 0 whose curvature came at least ``local_share`` from the proximal
term, the first having reduced the KKT residual (olado.solvers.sqp.phases.crawling); in the
local phase such steps make the next local proximal factor smaller, down to ``shift_min``.

Stopping: KKT residual (max-norm of the NLP stationarity, relative to the largest |grad J|
seen) <= tol and constraint violation <= constr_viol_tol, tested at each new iterate with the
multipliers of the QP that produced it (the pair (y_k, lambda_k) of Nocedal & Wright Alg. 18.3,
so no QP is solved after convergence) and again with the multipliers of the next QP; or a step
shorter than step_tol (relative) with the constraints satisfied. A proximal term
proximal*max|H|*I in the QP Hessian (by default with the exact Hessian only) picks the shortest
step along flat directions of degenerate optima; it makes the local rate fast-linear, and turns
a QP dual error e into a step of about e / (proximal max|H|) along those directions, hence the
tighter tolerance of the last QPs.

Code layout (one solve's state is an object of its own, the solver holds only options, so one
:class:`SQPSolver` can run several solves at once):

* ``solver.py``  -- the options and :class:`SQPSolver`: the per-solve setup and the loop;
* ``state.py``   -- the setup, the evaluated point, multipliers, the watchdog's watched point and
  the mutable loop state (:class:`~olado.solvers.sqp.state.SQPState`);
* ``phases.py``  -- one major iteration as phases over the state: convergence tests, Hessian,
  QP, penalty update and re-solve decisions, line search, acceptance, history, watchdog return;
* ``step.py``    -- the QP (8)-(10) in stage form, its solution with the inertia correction of the
  Hessian shift, the QP multipliers, the second-order correction's constraint values;
* ``merit.py``   -- the L1 merit function, Powell's weights, the directional derivative;
* ``augmented.py`` -- Schittkowski's augmented-Lagrangian merit function (``merit`` option);
* ``line_search.py`` -- Armijo backtracking with the watchdog and the second-order correction;
* ``residuals.py``   -- the KKT residuals stage by stage and the Result;
* ``hessian.py``     -- the block-diagonal Hessian approximations (12), (13);
* the safeguards of WORHP (seed 000; docs/structure-exploiting-sqp.md, "Safeguards"):
  ``regularization.py`` (Hessian regularization after untrusted steps), ``relaxation.py`` (the
  relaxed QP for inconsistent linearizations), ``restoration.py`` (feasibility restoration and
  local infeasibility), ``recession.py`` (UNBOUNDED), ``trust.py`` (a trust region for a first
  step whose QP is an LP in effect).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ...errors import ConfigError
from ...qp import KKT_METHODS, OLADO_METHODS, QP_METHODS, make_qp_solver
from ...qp.stageqp import StageQP
from .augmented import AugmentedLagrangian
from .merit import Merit
from .phases import initial_state, iterate
from . import trust
from .residuals import finish
from .state import Clock, ConstraintMasks, SQPSetup
from ..common import stop_outcome
from ...interrupts import Limits
from ..certificate import CertificateSettings
from ...options import option
from ..base import Solver, SolverOptions
from .hessian import make_hessian

from ...linalg.backend import KKT_SOLVERS  # the KKT back-end names (the one table: olado.linalg.backend)


def _apply_qp_options(qp_solver, qp_name, qp_options):
    """Set ``qp_options`` (SQPOptions) on the QP solver's options, each checked like any option;
    with an external backend a key that ExternalQPOptions does not know is passed to the backend
    itself (``backend_options``); with olado's methods it is an error naming the key."""
    from ...options import validate_value

    opts = qp_solver.options
    known = {f.name for f in dataclasses.fields(opts)}
    for key, value in qp_options.items():
        if key not in known and qp_name not in OLADO_METHODS:
            opts.backend_options = {**opts.backend_options, key: value}
        else:   # validate_value also names an unknown key and the allowed ones
            setattr(opts, key, validate_value(type(opts), key, value, section="sqp.raw (qp_options)"))


def _check_bounds_only(problem):
    """``qp = bounds`` (olado.qp.bounds) solves QPs with simple bounds only: a ConfigError naming
    the problem's stage and final constraints when it has any."""
    general = [f"{k} {what}{'s' if k > 1 else ''} {sym}" for k, what, sym in
               ((problem.r, "stage constraint", "g^k"), (problem.rN, "final constraint", "g^N")) if k]
    if general:
        raise ConfigError(f"qp = 'bounds' is the QP method for problems with simple bounds on states and controls "
                          f"only, but {type(problem).__name__} has {' and '.join(general)}; use qp = 'mehrotra' "
                          f"(configs/sqp-ip.ini) or another QP method", section="sqp", key="qp")


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
    merit: str = option("l1", "merit function of the line search: 'l1', the exact penalty function with Powell's "
                        "weights (paper 001 sec. 4.2.1), or 'augmented-lagrangian', Schittkowski's (1983) augmented "
                        "Lagrangian on primal and dual variables with his penalty update (docs/structure-exploiting-"
                        "sqp.md)", choices=("l1", "augmented-lagrangian"))
    watchdog: bool = option(True, "use the watchdog technique (Chamberlain et al. 1982)")
    watchdog_steps: int = option(2, "relaxed iterations allowed before returning to the last good point", min=1)
    armijo: float = option(1e-4, "sufficient-decrease constant of the line search", min=0.0, max=0.5, min_exclusive=True)
    backtrack: float = option(0.5, "step reduction factor of the line search", min=0.01, max=0.99)
    min_step: float = option(1e-10, "smallest step length before the line search gives up", min=0.0, min_exclusive=True)
    step_tol: float = option(1e-12, "stop when |s| <= step_tol * (1 + |y|) and the point is feasible", min=0.0)
    penalty_min: float = option(1e-8, "lower bound of the exact-penalty weights", min=0.0)
    initial_multipliers: str = option("least-squares", "multipliers of the first Hessian (exact Hessian): "
                                      "'least-squares', on problems without bounds and inequalities the multipliers "
                                      "minimizing the Lagrangian gradient (IPOPT's start; 0 when their largest exceeds "
                                      "multiplier_init_max), or 'zero'", choices=("least-squares", "zero"))
    multiplier_init_max: float = option(1e3, "largest least-squares initial multiplier accepted (IPOPT's "
                                        "constr_mult_init_max)", min=0.0)
    multiplier_reset: bool = option(True, "exact Hessian: when the QP's multipliers at a new iterate exceed "
                                    "multiplier_init_max and the least-squares estimate there does not, the next "
                                    "Hessian uses the estimate (docs/structure-exploiting-sqp.md, 'Multiplier "
                                    "growth')")
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
    local_share: float = option(0.9, "local phase: two full steps in a row taken with the unshifted exact Hessian "
                                "(s.H s >= 0) whose curvature came at least this much from the proximal term, p|s|^2 / "
                                "(s.H s + p|s|^2) >= local_share, the first reducing the KKT residual, start the local "
                                "phase whatever the KKT residual, and in the local phase make the next local proximal "
                                "factor 1/shift_increase of the last, down to shift_min (1: off; "
                                "docs/structure-exploiting-sqp.md, 'Local phase')",
                                min=0.0, max=1.0)
    local_proximal: float | None = option(1e-6, "proximal factor in the local phase (see local_tol): the proximal "
                                          "term there is local_proximal * max|H| (small: fast local rate; nonzero: a "
                                          "regular QP Hessian in flat directions); None: as elsewhere (the proximal "
                                          "option)", min=0.0)
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
    untrusted_growth: float = option(10.0, "a full QP step along which the merit function grows by more than this "
                                     "times (|phi| + |D|) is never taken as a relaxed or watchdog step: with the exact "
                                     "Hessian and convexify = 'inertia' it switches on WORHP's Hessian regularization "
                                     "(tau_*) and the QP is solved again (inf: off)", min=0.0, min_exclusive=True)
    tau_init: float = option(1e-3, "WORHP's Hessian regularization H + tau (|sigma_k| + max|H|) I: tau after the first "
                             "untrusted step or failed QP (see untrusted_growth)", min=0.0, max=1.0, min_exclusive=True)
    tau_increase: float = option(10.0, "WORHP's Hessian regularization: theta, the factor by which tau grows after a "
                                 "poor model prediction and shrinks (at least) after a good one", min=1.0,
                                 min_exclusive=True)
    tau_min: float = option(1e-10, "WORHP's Hessian regularization: tau below this is set to 0 (regularization off)",
                            min=0.0)
    unbounded_steps: int = option(5, "end with status UNBOUNDED after this many consecutive accepted steps from "
                                  "feasible iterates that decreased the objective along directions of recession of the "
                                  "QP model (docs/structure-exploiting-sqp.md)", min=1)
    recession_tol: float = option(1e-6, "a step direction d is one of recession of the QP model when |H d|, the "
                                  "linearized constraint residuals and the bound violations along d are at most this "
                                  "times the objective's slope |g.d| / (1 + |y|_inf)", min=0.0)
    elastic: bool = option(True, "a QP found infeasible (inconsistent linearized constraints) is replaced by its "
                           "relaxed (elastic) form, every constraint but the dynamics relaxed by slacks charged at the "
                           "penalty eta (WORHP's relaxed QP, docs/structure-exploiting-sqp.md); off: the SQP ends "
                           "INFEASIBLE at such a QP")
    elastic_penalty: float = option(10.0, "relaxed QP: first penalty eta, times (1 + |grad J|), and at least the "
                                    "merit function's largest weight", min=0.0, min_exclusive=True)
    elastic_penalty_max: float = option(1e4, "relaxed QP: largest penalty eta, times (1 + |grad J|) (olado's "
                                        "interior-point QPs stall on relaxed QPs with eta ~ 1e6 times their Hessian's "
                                        "scale: see docs)", min=0.0, min_exclusive=True)
    elastic_progress: float = option(0.1, "relaxed QP: eta grows tenfold while the step removes less than this "
                                     "fraction of the l1 violation of the linearized constraints", min=0.0, max=1.0,
                                     min_exclusive=True)
    restoration: bool = option(True, "feasibility restoration (WORHP's feasibility mode): when the line search fails "
                               "at an infeasible point, minimize the l1 constraint violation by feasibility QPs until "
                               "it has fallen below restoration_reduction times its value and the QP is consistent, "
                               "or end INFEASIBLE at a stationary point of the violation; off: NUMERICAL_ERROR there")
    restoration_reduction: float = option(0.9, "feasibility restoration: the optimality phase resumes once the l1 "
                                          "constraint violation is below this times its value at the start",
                                          min=0.0, max=1.0, min_exclusive=True)
    stall_filter: float = option(0.5, "low-pass filter termination (WORHP): weight of the newest value in the filtered "
                                 "objective and constraint violation", min=0.0, max=1.0, min_exclusive=True)
    stall_tol: float = option(1e-10, "low-pass filter termination: the filtered objective and violation stall when "
                              "each changes by less than this relative to max(1, its value)", min=0.0)
    stall_iterations: int = option(5, "low-pass filter termination: after this many successive stalled iterations at "
                                   "a feasible point whose KKT test fails, the point is certified and the solve ends "
                                   "as acceptable if the certificate holds (0: never)", min=0)
    certificate_attempts: int = option(3, "certificates per solve (olado.solvers.certificate): when the SQP's own "
                                       "test holds but the certificate does not, the SQP iterates on, up to this "
                                       "many certificates; then the last one's verdict is the status", min=1)
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


#: the merit functions of the line search (option ``merit``)
MERITS = {"l1": Merit, "augmented-lagrangian": AugmentedLagrangian}


def make_setup(options, problem, callback):
    """The per-solve setup of an SQP solve: the QP solver with its options, the Hessian
    approximation (returned with the setup; it changes during the solve) and the convexification
    in effect."""
    o = options
    t_start = time.perf_counter()
    limits = Limits(o.max_time)
    if o.qp == "bounds":
        _check_bounds_only(problem)
    qp_solver = make_qp_solver(o.qp, kkt=o.kkt, tol=o.qp_tol, max_iter=o.qp_max_iter)
    # olado's own QP methods (interior point, active set) take qp_tol and report a failed
    # factorization (a reduced Hessian not positive definite) as NUMERICAL_ERROR: the inertia
    # correction below works with them
    interior = o.qp in OLADO_METHODS
    if o.qp in KKT_METHODS:
        qp_solver.options.warm_start_push = o.qp_warm_start_push
    _apply_qp_options(qp_solver, o.qp, o.qp_options)
    convexify = o.convexify
    if o.hessian == "exact" and convexify == "inertia" and not interior:
        # external QP solvers need a convex QP: the exact Hessian is passed with P + rho A_eq^T A_eq
        # (the same solution where the reduced Hessian is positive definite), and a QP whose reduced
        # Hessian is not is reported as failed, so that the inertia correction shifts it
        qp_solver.options.convexify = "augmented"
    hess = new_hessian(o, problem, convexify)
    masks = ConstraintMasks.of(problem)
    setup = SQPSetup(options=o, problem=problem, qp_solver=qp_solver, interior=interior, convexify=convexify,
                     inertia=hess.needs_exact and convexify == "inertia", masks=masks,
                     merit=MERITS[o.merit](problem, masks), callback=callback, limits=limits, t_start=t_start,
                     certificate=CertificateSettings.from_options(o) if o.certify else None)
    return setup, hess


def new_hessian(o, problem, convexify):
    """The Hessian approximation of a solve (exact, or a quasi-Newton matrix at its start)."""
    hess = make_hessian(o.hessian, convexify=convexify, initial_scale=o.initial_hessian_scale,
                        min_eig=o.min_eigenvalue, max_condition=o.max_condition)
    hess.initial(problem.N, problem.n, problem.m)
    return hess


class SQPSolver(Solver):
    """Powell's SQP (paper 001 sec. 4.2.1) with structure-exploiting QP subproblems."""

    name = "sqp"
    Options = SQPOptions

    def _solve(self, problem, X0, U0):
        setup, hess = make_setup(self.options, problem, self._call_callback)
        st = initial_state(setup, X0, U0, hess, Clock(setup.limits))
        with setup.limits.catch() as stop:      # a time limit or an interrupt: the last accepted iterate
            while not iterate(setup, st):
                pass
            if trust.retry_boxed(st):
                # INFEASIBLE after an LP first step the functions did not follow: once more from
                # the start with that step boxed (olado.solvers.sqp.trust)
                first = st
                st = initial_state(setup, X0, U0, new_hessian(self.options, problem, setup.convexify), st.clock)
                st = trust.second_attempt(first, st)
                while not iterate(setup, st):
                    pass
                st = trust.better_attempt(first, st)
        if stop.reason:
            st.stop(*stop_outcome(stop.reason, setup.limits, f"after {st.it} SQP iterations"))
        return finish(setup, st, {"qp": self.options.qp, "kkt": self.options.kkt, "hessian": self.options.hessian,
                                  "convexify": setup.convexify, "hessian_updates": st.hess.updates,
                                  "hessian_skipped": st.hess.skipped})
