"""Everything one SQP solve works on (paper 001 sec. 4.2.1): the per-solve setup, the evaluated
point y^i = (X, U) with its derivatives, the multiplier estimates, the watchdog's watched point
and the mutable loop state. The solver object itself holds only options; a solve builds one
:class:`SQPSetup` and one :class:`SQPState`, so one :class:`~olado.solvers.sqp.solver.SQPSolver`
can run several solves at once (threads, or a callback that starts another solve).

Layout of the stage arrays (the DOCP of eqs. (1)-(5) in its NLP form (6)): X (N+1, n),
U (N, m); the dynamics residuals h^k = f^k(x^k, u^k) - x^{k+1} (N, n); stage constraints
g (N, r), final constraints gN (rN,); the derivatives the QP (8)-(10) needs, per stage.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, NamedTuple

import numpy as np

from ...result import Status
from ...interrupts import Limits
from ..common import EVALUATION_KINDS, Stoppable

_now = time.perf_counter


class Clock:
    """Counts and times the problem evaluations of the SQP (the share of solve time spent in
    olado's evaluation code is reported as info["callback_share"], as for the NLP solvers).
    Every evaluation batch it records is followed by the check of the solve's ``limits``: a
    time limit or an interrupt stops the solve within one batch (olado.interrupts)."""

    def __init__(self, limits=None):
        self.counts = {k: 0 for k in EVALUATION_KINDS}
        self.time_s = 0.0
        self.limits = limits

    def add(self, kinds, t0):
        self.time_s += _now() - t0
        counts = self.counts
        for k in kinds:
            counts[k] += 1
        limits = self.limits
        if limits is not None:
            limits.check()


#: the evaluation kinds (EVALUATION_KINDS) a point's values and its first derivatives count
_VALUE_KINDS = ("objective", "constraints")
_DERIVATIVE_KINDS = ("gradient", "jacobian")


class Point:
    """Values (J, h, g, gN) and, on demand, first derivatives of the DOCP at (X, U)."""

    def __init__(self, problem, X, U, derivatives=True, clock=None):
        if clock is None:
            clock = Clock()
        self.clock = clock
        t0 = _now()
        self.X = X
        self.U = U
        self.J, f, self.g, self.gN = problem.eval_values(X, U)
        self.h = f - X[1:]
        clock.add(_VALUE_KINDS, t0)
        self.derivs = False
        if derivatives:
            self.add_derivatives(problem)

    @classmethod
    def evaluated(cls, clock, X, U, values, derivatives):
        """The Point of numbers evaluated elsewhere (a compiled solver loop): ``values`` (J, h, g,
        gN) and ``derivatives`` (lx, lu, lN, A, B, Cx, Cu, CN), nothing evaluated or counted."""
        pt = cls.__new__(cls)
        pt.clock, pt.X, pt.U = clock, X, U
        pt.J, pt.h, pt.g, pt.gN = values
        pt.lx, pt.lu, pt.lN, pt.A, pt.B, pt.Cx, pt.Cu, pt.CN = derivatives
        pt.derivs = True
        return pt

    def add_derivatives(self, p):
        """Cost gradients lx, lu, lN and Jacobians A, B (dynamics), Cx, Cu (stage), CN (final)."""
        if self.derivs:
            return
        t0 = _now()
        (self.lx, self.lu, self.lN, self.A, self.B, self.Cx, self.Cu,
         self.CN) = p.eval_first_derivatives(self.X, self.U)
        self.derivs = True
        self.clock.add(_DERIVATIVE_KINDS, t0)

    def lagrangian_hessian(self, p, mult):
        """The exact Hessian blocks (12) of the Lagrangian at (X, U) with the multipliers ``mult``:
        (blocks (N, n+m, n+m), final (n, n)), evaluated once per (point, multipliers) pair (the
        line search evaluates them at the point it accepts, olado.solvers.sqp.phases)."""
        cached = getattr(self, "_hessian", None)
        if cached is not None and cached[0] is mult:
            return cached[1], cached[2]
        N, n, m = p.N, p.n, p.m
        t0 = time.perf_counter()
        Hxx, Hxu, Huu = p.eval_stage_hessians(self.X, self.U, 1.0, mult.lam[1:], mult.Lg)
        HN = p.eval_final_hessian(self.X[-1], 1.0, mult.LgN)
        self.clock.add(("hessian",), t0)
        blocks = np.empty((N, n + m, n + m))
        blocks[:, :n, :n] = Hxx; blocks[:, :n, n:] = Hxu
        blocks[:, n:, :n] = np.transpose(Hxu, (0, 2, 1)); blocks[:, n:, n:] = Huu
        self._hessian = (mult, blocks, HN)
        return blocks, HN

    def constraint_hessian(self, p, mult):
        """The Hessian blocks of the constraint terms of the Lagrangian alone (objective weight 0),
        sum lam_{k+1}.f^k + Lg.g^k + LgN.g^N: the Hessian of the feasibility problem's Lagrangian
        (olado.solvers.sqp.restoration). Not cached."""
        N, n, m = p.N, p.n, p.m
        t0 = time.perf_counter()
        Hxx, Hxu, Huu = p.eval_stage_hessians(self.X, self.U, 0.0, mult.lam[1:], mult.Lg)
        HN = p.eval_final_hessian(self.X[-1], 0.0, mult.LgN)
        self.clock.add(("hessian",), t0)
        blocks = np.empty((N, n + m, n + m))
        blocks[:, :n, :n] = Hxx; blocks[:, :n, n:] = Hxu
        blocks[:, n:, :n] = np.transpose(Hxu, (0, 2, 1)); blocks[:, n:, n:] = Huu
        return blocks, HN

    def lagrangian_gradients(self, mult):
        """Per-block gradients of the stage Lagrangians f0 + lam_{k+1}.f + Lg.g (z-blocks) and
        of F + LgN.gN (final block); the terms linear in x_{k+1} cancel in differences."""
        lam, Lg, LgN = mult
        gx = self.lx + np.einsum("kij,ki->kj", self.A, lam[1:]) + np.einsum("kij,ki->kj", self.Cx, Lg)
        gu = self.lu + np.einsum("kij,ki->kj", self.B, lam[1:]) + np.einsum("kij,ki->kj", self.Cu, Lg)
        gN = self.lN + self.CN.T @ LgN
        return np.concatenate([gx, gu], axis=1), gN


class Multipliers(NamedTuple):
    """Multiplier estimates in the Lagrangian J + sum lam_{k+1}.(f^k - x^{k+1}) + Lg.g + LgN.gN
    (the sign convention of :mod:`olado.solvers.common`): ``lam`` (N+1, n), row k+1 for the
    dynamics of stage k (row 0 unused); ``Lg`` (N, r) (nu for equality rows, -y for g >= 0);
    ``LgN`` (rN,)."""

    lam: np.ndarray
    Lg: np.ndarray
    LgN: np.ndarray

    @classmethod
    def zeros(cls, N, n, r, rN):
        return cls(np.zeros((N + 1, n)), np.zeros((N, r)), np.zeros(rN))

    def largest(self):
        """max |multiplier| over the dynamics, stage and final constraints."""
        from .kernels import npmax_abs     # numpy's max of |a| (a NaN propagates), compiled

        return max(npmax_abs(self.lam, 0.0), npmax_abs(self.Lg, 0.0), npmax_abs(self.LgN, 0.0))


class BoundMultipliers(NamedTuple):
    """Multipliers z_L, z_U >= 0 of the simple bounds (4)-(5), shaped like X and U."""

    zl_x: np.ndarray
    zu_x: np.ndarray
    zl_u: np.ndarray
    zu_u: np.ndarray

    @classmethod
    def zeros(cls, N, n, m):
        return cls(np.zeros((N + 1, n)), np.zeros((N + 1, n)), np.zeros((N, m)), np.zeros((N, m)))


class ConstraintMasks(NamedTuple):
    """Equality / inequality components of the stage (g) and final (gN) constraints."""

    eq: np.ndarray
    ineq: np.ndarray
    eqN: np.ndarray
    ineqN: np.ndarray

    @classmethod
    def of(cls, problem):
        return cls(problem.stage_equality_mask, ~problem.stage_equality_mask,
                   problem.final_equality_mask, ~problem.final_equality_mask)


@dataclasses.dataclass
class Watch:
    """The watchdog's watched point (Chamberlain et al. 1982): where a relaxed step started, its
    QP step (dX, dU) with directional derivative D and tolerance d_tol, the shift delta of that
    QP, the curvature floor of a step that was no descent direction, the multipliers at the
    point (``mult``) and of its QP (``mult_new``), and the relaxed iterations since."""

    pt: Point
    dX: np.ndarray
    dU: np.ndarray
    D: float
    d_tol: float
    delta: np.ndarray
    floor: float
    mult: Multipliers
    mult_new: Multipliers
    count: int = 0
    expired: bool = False


@dataclasses.dataclass
class SQPSetup:
    """What stays fixed during one solve: options, problem, QP solver and the choices derived
    from them (``inertia``: exact Hessian with the inertia correction of the QP Hessian)."""

    options: Any
    problem: Any
    qp_solver: Any
    interior: bool              # one of olado's own QP methods (olado.qp.OLADO_METHODS)
    convexify: str              # the Hessian convexification in effect
    inertia: bool
    masks: ConstraintMasks
    merit: Any                  # the merit function (olado.solvers.sqp.merit.Merit)
    callback: Callable[[dict], bool]
    limits: Limits              # time limit and interrupts (olado.interrupts)
    t_start: float
    certificate: Any = None     # CertificateSettings (None: options.certify is off)


@dataclasses.dataclass
class SQPState(Stoppable):
    """The mutable state of one solve: iterate, multipliers, merit weights, watchdog, Hessian,
    inertia-correction and local-phase bookkeeping, counters and history."""

    pt: Point                   # the iterate y^i, with derivatives
    mult: Multipliers           # multipliers at pt (of the QP that produced it)
    bounds: BoundMultipliers    # bound multipliers of the last solved QP
    rho: tuple                  # exact-penalty weights (rho_h, rho_g, rho_gN, rho_bx, rho_bu)
    hess: Any                   # the Hessian approximation (olado.solvers.sqp.hessian)
    clock: Clock
    shift: np.ndarray           # Hessian shift per stage block (N: the final block) of the last accepted step
    ascent_relaxed: int         # non-descent steps that may still be tried as relaxed watchdog steps
    status: Status = Status.MAX_ITERATIONS
    message: str = ""
    it: int = 0
    qp_iters: int = 0
    history: list = dataclasses.field(default_factory=list)
    kkt_res: float = float("nan")   # KKT residual of the last test
    kkt_rel: float = 1.0            # ... relative to grad_scale
    grad_scale: float = 1e-300      # largest |grad J| seen
    Bk: np.ndarray | None = None    # Hessian blocks at (pt, mult); None: to be evaluated
    BN: np.ndarray | None = None
    hscale_of: tuple | None = None  # (Bk, BN, max|H|) measured by the iteration's Hessian phase
    watch: Watch | None = None
    failed_watch: Watch | None = None   # watched point of the last watchdog return
    returned: bool = False          # the last step was a watchdog return: the next one is not relaxed
    force_delta: np.ndarray | None = None   # shift for the next QP after a rejected step
    force_qp_tol: float | None = None       # quasi-Newton: the tighter QP tolerance a non-descent step asked for
    retries: int = 0                # QPs re-solved with a larger shift at the current point
    last_qp: Any = None             # QP result of the last accepted step (warm start of the local phase)
    local: bool = False             # local phase: full steps and a small KKT residual
    was_local: bool = False
    local_proximal_scale: float = 1.0   # the local phase's proximal factor is local_proximal times this
    dominated: tuple = (False, False)   # the last accepted step was dominated by the global / local proximal term
    kkt_prev: float = float("inf")      # KKT residual at that step's start
    qp_local: bool = False          # the local flag the current iteration's QPs were built with
    eta: float = 0.0                # penalty of the last relaxed (elastic) QP (olado.solvers.sqp.relaxation)
    tau: float = 0.0                # WORHP's regularization parameter (olado.solvers.sqp.regularization)
    recession_steps: int = 0        # consecutive accepted steps along directions of recession (olado.solvers.sqp.recession)
    unbounded: str | None = None    # the sentence of an UNBOUNDED end
    decreased: bool = False         # the last accepted step decreased the objective
    trust_box: Any = None           # |du| bound of the first step's QPs (olado.solvers.sqp.trust), or None
    first_trusted: bool = False     # the first step's trust region has been decided
    first_suspect: bool = False     # the first step was an LP step the functions did not follow
    trust_armed: bool = False       # this attempt boxes such a first step (olado.solvers.sqp.trust)
    start_it: int = 0               # the iteration this attempt started at (0, or the first attempt's count)
    it_limit: float = float("inf")  # this attempt's own iteration limit (a second attempt's budget)
    restoring: bool = False         # in the feasibility restoration phase (olado.solvers.sqp.restoration)
    restoration_theta: float = 0.0  # l1 violation where the restoration phase started
    restoration_steps: int = 0      # restoration steps since then
    restoration_mu: float = 1.0     # the restoration steps' metric mu I
    restoration_mult: Any = None    # multipliers of the last feasibility QP (its Hessian's weights), or None
    simulated_at: int = -1          # iteration at which the states were last simulated from the controls
    tau_kkt: float = 0.0            # KKT residual at the last step's start (rho_3 of the tau update)
    certificate: Any = None         # olado's certificate of the point the solve stopped at (olado.solvers.certificate)
    certificates: int = 0           # certificates computed in this solve
    tol_factor: float = 1.0         # the KKT test's tol is o.tol times this (< 1 after a failed certificate)
    filter_obj: float = float("nan")    # WORHP's low-pass filters of the objective and the violation
    filter_con: float = float("nan")
    stalled: int = 0                # successive iterations in which both filters stalled
