"""Dynamic-programming methods for unconstrained DOCPs: DDP and Pantoja's stagewise Newton
method, both with a Levenberg shift of the Hessian eigenvalues (paper 001 sec. 2.2; Yakowitz and
Rutherford 1984; Pantoja 1988).

The problem is eq. (1)-(2) without constraints (3) or bounds (4)-(5), seen as a function of the
controls: min_u J(u) = sum_k f_0^k(x^k, u^k) + F^N(x^N), x^{k+1} = f^k(x^k, u^k), x^0 fixed.
Constrained problems go to ``pdmin`` (control bounds) or ``penalty`` (general constraints), or
to the SQP / NLP solvers.

Backward pass (one compiled sweep, k = N-1 .. 0), from V_x^N = F_x, V_xx^N = F_xx:

    Q_x  = f0_x + A^T V_x'                 Q_u  = f0_u + B^T V_x'
    Q_xx = H_xx + A^T V_xx' A              Q_uu = H_uu + B^T V_xx' B       Q_ux = H_ux + B^T V_xx' A
    k    = -Qt_uu^{-1} Q_u                 K    = -Qt_uu^{-1} Qt_ux
    V_x  = Q_x  + K^T Qv_uu k + K^T Q_u  + Q_ux^T k
    V_xx = Q_xx + K^T Qv_uu K + K^T Q_ux + Q_ux^T K

with A = f_x, B = f_u and (H_xx, H_ux, H_uu) the second derivatives of f0^k + w^{k+1}.f^k, where
the weight w^{k+1} of the second-order dynamics terms is what separates the two methods:

* ``ddp`` (Mayne; Jacobson and Mayne 1970; Yakowitz and Rutherford 1984): w^{k+1} = V_x^{k+1},
  the value-function gradient of the backward pass itself. Since the problem's stage Hessian is
  linear in its weights, H(1, V_x) = H(1, 0) + sum_i V_x,i H(0, e_i): the cost Hessian and the
  n dynamics Hessians (n+1 vectorized ``eval_stage_hessians`` calls, O(N) each) are contracted
  with V_x inside the sweep. The forward pass is the closed-loop nonlinear rollout
  u^k = ubar^k + alpha k^k + K^k (x^k - xbar^k), x^{k+1} = f^k(x^k, u^k).
  (``second_order_dynamics = false`` drops the dynamics Hessians: iLQR, Li and Todorov 2004.)
* ``stagewise-newton`` (Pantoja 1988; Dunn and Bertsekas 1989): w^{k+1} = p^{k+1}, the costates
  of the adjoint recursion at the nominal controls. The sweep is then the Riccati recursion of
  the LQ problem  min g.du + 1/2 du.H du  over du (H the reduced Hessian, written in stage
  form with linearized dynamics), so the step -- obtained by the linear forward sweep
  dx^0 = 0, du^k = k^k + K^k dx^k, dx^{k+1} = A dx^k + B du^k -- is exactly the Newton step
  du = -H^{-1} g of the reduced problem. The line search is on J(u + alpha du).

Shift (regularization) mu >= 0, the "shifting of the Hessian eigenvalues" of the paper:

* ``regularization = control`` (default): Qt_uu = Q_uu + mu I, Qt_ux = Q_ux and Qv_uu = Qt_uu.
  This is the exact value function of the problem with the proximal term mu/2 |u - ubar|^2, so
  for the stagewise Newton method the step is du = -(H + mu I)^{-1} g: every eigenvalue of the
  reduced Hessian shifted by mu (Levenberg-Marquardt).
* ``regularization = state`` (Tassa, Erez and Todorov 2012, eq. 10-11): mu I added to V_xx' in
  Q_uu and Q_ux only (Qt_uu = Q_uu + mu B^T B, Qt_ux = Q_ux + mu B^T A), Qv_uu = Q_uu.

mu is raised until every stage's Qt_uu has a Cholesky factor (all Qt_uu positive definite; for
stagewise Newton with control shift exactly when H + mu I is positive definite) and when the line
search fails, and lowered after every successful iteration. ``shift_schedule = tassa``
(default; Tassa et al. 2012, sec. II.F): increase delta <- max(f, f delta), mu <- max(mu_min,
mu delta); decrease delta <- min(1/f, delta/f), mu <- mu delta, or 0 once below mu_min
(f = ``shift_factor``). ``shift_schedule = inertia`` (the inertia correction of Waechter and
Biegler 2006, sec. 3.1, also used by olado's SQP): every iteration tries mu = 0 first, then
max(mu_min, last/3) (1e-4 if no shift was needed before), multiplied by 8 (100 the first time)
until it succeeds.

Line search (both methods): alpha = 1, backtrack, ... accepted when the actual change of J is at
least ``armijo`` times the expected one, dV(alpha) = alpha sum k.Q_u + alpha^2/2 sum k.Qv_uu k < 0
(Jacobson and Mayne's expected-decrease test, as in Tassa et al. 2012).

Stopping: SUCCESS when the max-norm of the reduced gradient dJ/du (adjoint recursion) is <=
``tol``; when the expected decrease -dV(1) drops below ``decrease_tol * (1 + |J|)`` (no
measurable progress left), the full step is taken and the solver stops: SUCCESS if the gradient
then meets ``tol``, else ACCEPTABLE. MAX_ITERATIONS, MAX_TIME, USER_STOP (callback) as usual;
NUMERICAL_ERROR when mu exceeds ``shift_max``.

Cost per iteration O(N): the stage derivatives of all stages at once, the compiled backward and
linear forward sweeps. The DDP rollout calls the per-stage dynamics once per stage in sequence,
as :meth:`DOCP.simulate` does (the closed-loop control depends on the state just computed).

Code: an iteration is the phases ``_stopped``, the second derivatives, ``_step`` (backward
passes with the shift raised until the line search ``_line_search`` succeeds) and ``_advance``
of :class:`_DynamicProgrammingSolver` over the solve's
:class:`~olado.solvers.control.ddp_state.DPState` (with its :class:`ShiftSchedule`); the solver
holds only options.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numba as nb
import numpy as np

from ...errors import NonFiniteEvaluationError
from ...interrupts import Limits
from .ddp_state import Accepted, DPState, ShiftSchedule, Sweeps
from ...linalg.riccati_kernels import chol_inplace as _chol_inplace, chol_solve_vec as _chol_solve_vec
from ...result import Result, Status
from ...options import option
from ..base import Solver, SolverOptions
from ..common import stop_outcome
from .control_space import _adjoint, unsupported_features

__all__ = ["DDPSolver", "StagewiseNewtonSolver", "DDPOptions", "StagewiseNewtonOptions",
           "unsupported_features", "stagewise_newton_step"]


# ============================================================================ compiled sweeps
@nb.njit(cache=True)
def _backward_pass(lx, lu, A, B, Hxx, Hxu, Huu, Txx, Txu, Tuu, use_tensor, VxN, VxxN, mu, state_reg,
                   kff, Kfb, Vx, Vxx):
    """Backward sweep of the module docstring. Fills kff (N,m), Kfb (N,m,n), Vx (N+1,n),
    Vxx (N+1,n,n). Returns (stage whose shifted Q_uu is not positive definite or -1, d1, d2)
    with d1 = sum k.Q_u and d2 = sum k.Qv_uu k (expected change dV(a) = a d1 + a^2/2 d2)."""
    N, n = lx.shape
    m = lu.shape[1]
    VA = np.empty((n, n)); VB = np.empty((n, m))
    Qx = np.empty(n); Qu = np.empty(m)
    Qxx = np.empty((n, n)); Quu = np.empty((m, m)); Qux = np.empty((m, n))
    Qtuu = np.empty((m, m)); Qtux = np.empty((m, n)); L = np.zeros((m, m))
    Qvuu = np.empty((m, m)); col = np.empty(m)
    t1 = np.empty((m, n)); t2 = np.empty(m)
    for i in range(n):
        Vx[N, i] = VxN[i]
        for j in range(n):
            Vxx[N, i, j] = 0.5 * (VxxN[i, j] + VxxN[j, i])
    d1 = 0.0
    d2 = 0.0
    for k in range(N - 1, -1, -1):
        # first-order terms
        for j in range(n):
            s = lx[k, j]
            for i in range(n):
                s += A[k, i, j] * Vx[k + 1, i]
            Qx[j] = s
        for j in range(m):
            s = lu[k, j]
            for i in range(n):
                s += B[k, i, j] * Vx[k + 1, i]
            Qu[j] = s
        # V_xx' A and V_xx' B
        for i in range(n):
            for j in range(n):
                s = 0.0
                for q in range(n):
                    s += Vxx[k + 1, i, q] * A[k, q, j]
                VA[i, j] = s
            for j in range(m):
                s = 0.0
                for q in range(n):
                    s += Vxx[k + 1, i, q] * B[k, q, j]
                VB[i, j] = s
        for i in range(n):
            for j in range(n):
                s = Hxx[k, i, j]
                for q in range(n):
                    s += A[k, q, i] * VA[q, j]
                Qxx[i, j] = s
        for i in range(m):
            for j in range(m):
                s = Huu[k, i, j]
                for q in range(n):
                    s += B[k, q, i] * VB[q, j]
                Quu[i, j] = s
            for j in range(n):
                s = Hxu[k, j, i]
                for q in range(n):
                    s += B[k, q, i] * VA[q, j]
                Qux[i, j] = s
        # DDP: second-order dynamics terms weighted by V_x^{k+1}
        if use_tensor:
            for q in range(n):
                w = Vx[k + 1, q]
                if w == 0.0:
                    continue
                for i in range(n):
                    for j in range(n):
                        Qxx[i, j] += w * Txx[k, q, i, j]
                for i in range(m):
                    for j in range(m):
                        Quu[i, j] += w * Tuu[k, q, i, j]
                    for j in range(n):
                        Qux[i, j] += w * Txu[k, q, j, i]
        # shift
        for i in range(m):
            for j in range(m):
                Qtuu[i, j] = 0.5 * (Quu[i, j] + Quu[j, i])
            for j in range(n):
                Qtux[i, j] = Qux[i, j]
        if state_reg:
            for i in range(m):
                for j in range(m):
                    s = 0.0
                    for q in range(n):
                        s += B[k, q, i] * B[k, q, j]
                    Qtuu[i, j] += mu * s
                for j in range(n):
                    s = 0.0
                    for q in range(n):
                        s += B[k, q, i] * A[k, q, j]
                    Qtux[i, j] += mu * s
            for i in range(m):
                for j in range(m):
                    Qvuu[i, j] = 0.5 * (Quu[i, j] + Quu[j, i])
        else:
            for i in range(m):
                Qtuu[i, i] += mu
            for i in range(m):
                for j in range(m):
                    Qvuu[i, j] = Qtuu[i, j]
        for i in range(m):
            for j in range(m):
                L[i, j] = Qtuu[i, j]
        if not _chol_inplace(L, m):
            return k, d1, d2
        # gains
        for i in range(m):
            col[i] = -Qu[i]
        _chol_solve_vec(L, m, col)
        for i in range(m):
            kff[k, i] = col[i]
        for j in range(n):
            for i in range(m):
                col[i] = -Qtux[i, j]
            _chol_solve_vec(L, m, col)
            for i in range(m):
                Kfb[k, i, j] = col[i]
        # value function: V_x = Q_x + K^T Qv k + K^T Q_u + Q_ux^T k
        for i in range(m):
            s = 0.0
            for j in range(m):
                s += Qvuu[i, j] * kff[k, j]
            t2[i] = s                       # Qv k
        for j in range(n):
            s = Qx[j]
            for i in range(m):
                s += Kfb[k, i, j] * (t2[i] + Qu[i]) + Qux[i, j] * kff[k, i]
            Vx[k, j] = s
        # V_xx = Q_xx + K^T Qv K + K^T Q_ux + Q_ux^T K
        for i in range(m):
            for j in range(n):
                s = 0.0
                for q in range(m):
                    s += Qvuu[i, q] * Kfb[k, q, j]
                t1[i, j] = s + Qux[i, j]    # Qv K + Q_ux
        for i in range(n):
            for j in range(n):
                s = Qxx[i, j]
                for q in range(m):
                    s += Kfb[k, q, i] * t1[q, j] + Qux[q, i] * Kfb[k, q, j]
                Vxx[k, i, j] = s
        for i in range(n):
            for j in range(i + 1, n):
                s = 0.5 * (Vxx[k, i, j] + Vxx[k, j, i])
                Vxx[k, i, j] = s
                Vxx[k, j, i] = s
        for i in range(m):
            d1 += kff[k, i] * Qu[i]
            d2 += kff[k, i] * t2[i]
    return -1, d1, d2


@nb.njit(cache=True)
def _linear_forward(A, B, kff, Kfb, dU, dX):
    """Linearized forward sweep: dx^0 = 0, du^k = k^k + K^k dx^k, dx^{k+1} = A dx^k + B du^k."""
    N, n = A.shape[0], A.shape[1]
    m = B.shape[2]
    for i in range(n):
        dX[0, i] = 0.0
    for k in range(N):
        for i in range(m):
            s = kff[k, i]
            for j in range(n):
                s += Kfb[k, i, j] * dX[k, j]
            dU[k, i] = s
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += A[k, i, j] * dX[k, j]
            for j in range(m):
                s += B[k, i, j] * dU[k, j]
            dX[k + 1, i] = s


# ============================================================================ helpers


class _Derivatives:
    """First derivatives, costates and reduced gradient of a DOCP at (X, U)."""

    def __init__(self, problem, X, U):
        self.X, self.U = X, U
        lx, lu = problem.eval_stage_cost_gradients(X, U)
        A, B = problem.eval_dynamics_jacobians(X, U)
        self.pN = np.ascontiguousarray(problem.eval_final_cost_gradient(X[-1]))
        self.lx, self.lu = np.ascontiguousarray(lx), np.ascontiguousarray(lu)
        self.A, self.B = np.ascontiguousarray(A), np.ascontiguousarray(B)
        N, n, m = problem.N, problem.n, problem.m
        self.costate = np.empty((N + 1, n))
        self.g = np.empty((N, m))
        _adjoint(self.lx, self.lu, self.A, self.B, self.pN, self.costate, self.g)
        self.gnorm = float(np.max(np.abs(self.g), initial=0.0))


_EMPTY4 = np.zeros((0, 0, 0, 0))


def _second_derivatives(problem, d, method, second_order_dynamics):
    """(Hxx, Hxu, Huu, Txx, Txu, Tuu, use_tensor, HN) for the backward pass (module docstring)."""
    X, U = d.X, d.U
    N, n = problem.N, problem.n
    HN = np.ascontiguousarray(problem.eval_final_hessian(X[-1], 1.0))
    if method == "stagewise-newton":
        Hxx, Hxu, Huu = problem.eval_stage_hessians(X, U, 1.0, d.costate[1:])
        return (*(np.ascontiguousarray(a) for a in (Hxx, Hxu, Huu)), _EMPTY4, _EMPTY4, _EMPTY4, False, HN)
    Hxx, Hxu, Huu = problem.eval_stage_hessians(X, U, 1.0, np.zeros((N, n)))
    if not second_order_dynamics:
        return (*(np.ascontiguousarray(a) for a in (Hxx, Hxu, Huu)), _EMPTY4, _EMPTY4, _EMPTY4, False, HN)
    m = problem.m
    Txx = np.empty((N, n, n, n)); Txu = np.empty((N, n, n, m)); Tuu = np.empty((N, n, m, m))
    E = np.zeros((N, n))
    for i in range(n):           # n vectorized calls: the Hessian of component i of f^k, all stages
        E[:, i] = 1.0
        Txx[:, i], Txu[:, i], Tuu[:, i] = problem.eval_stage_hessians(X, U, 0.0, E)
        E[:, i] = 0.0
    return (*(np.ascontiguousarray(a) for a in (Hxx, Hxu, Huu)), Txx, Txu, Tuu, True, HN)


@nb.njit(cache=True)
def _feedback(U, Kfb, X, Xbar, k):
    """u^k += K^k (x^k - xbar^k) (one stage of the DDP rollout, in place)."""
    n = X.shape[1]
    for i in range(U.shape[1]):
        s = 0.0
        for j in range(n):
            s += Kfb[k, i, j] * (X[k, j] - Xbar[k, j])
        U[k, i] += s


def _rollout(problem, Xbar, Ubar, kff, Kfb, alpha):
    """DDP forward pass: closed-loop nonlinear simulation u^k = ubar^k + alpha k^k + K^k (x^k - xbar^k).

    The shapes of the user's dynamics were validated by the initial simulation; the trajectory is
    checked for non-finite values once at the end (the error names the first bad stage)."""
    N = problem.N
    X = np.empty_like(Xbar)
    U = Ubar + alpha * kff
    X[0] = problem.x0
    problem.counters["dynamics"] += 1
    dyn = problem.dynamics
    with np.errstate(over="ignore", invalid="ignore"):
        if problem.vectorized:
            ks = np.arange(N)
            for k in range(N):
                _feedback(U, Kfb, X, Xbar, k)
                X[k + 1] = np.reshape(dyn(ks[k:k + 1], X[k:k + 1], U[k:k + 1]), -1)
        else:
            for k in range(N):
                _feedback(U, Kfb, X, Xbar, k)
                X[k + 1] = dyn(k, X[k], U[k])
    if not (np.isfinite(X).all() and np.isfinite(U).all()):
        bad = int(np.argwhere(~np.isfinite(X).all(axis=1))[0, 0]) - 1 if not np.isfinite(X).all() else 0
        raise NonFiniteEvaluationError("non-finite value in the closed-loop rollout", function="dynamics",
                                       stage=max(bad, 0), array="x_next")
    return X, U


def stagewise_newton_step(problem, U, shift=0.0, regularization="control"):
    """The stagewise Newton step du (N, m) of the reduced problem at U (Pantoja 1988):
    du = -(H + shift I)^{-1} g with control regularization. Raises ValueError when the shifted
    reduced Hessian is not positive definite (some stage's Q_uu has no Cholesky factor)."""
    U = np.ascontiguousarray(U, dtype=float)
    X = problem.simulate(U)
    d = _Derivatives(problem, X, U)
    Hxx, Hxu, Huu, Txx, Txu, Tuu, use_t, HN = _second_derivatives(problem, d, "stagewise-newton", False)
    N, n, m = problem.N, problem.n, problem.m
    kff = np.empty((N, m)); Kfb = np.empty((N, m, n)); Vx = np.empty((N + 1, n)); Vxx = np.empty((N + 1, n, n))
    fail, d1, d2 = _backward_pass(d.lx, d.lu, d.A, d.B, Hxx, Hxu, Huu, Txx, Txu, Tuu, use_t, d.pN, HN,
                                  float(shift), regularization == "state", kff, Kfb, Vx, Vxx)
    if fail >= 0:
        raise ValueError(f"the shifted Q_uu of stage {fail} is not positive definite")
    dU = np.empty((N, m)); dX = np.empty((N + 1, n))
    _linear_forward(d.A, d.B, kff, Kfb, dU, dX)
    return dU


# ============================================================================ options
@dataclasses.dataclass
class _DPOptions(SolverOptions):
    max_iter: int = option(200, "maximum number of iterations", min=0)
    tol: float = option(1e-8, "stop when the max-norm of the reduced gradient dJ/du is <= tol", min=0.0,
                        min_exclusive=True)
    decrease_tol: float = option(1e-15, "take the last (full) step and stop once the expected decrease -dV(1) "
                                 "is <= decrease_tol * (1 + |J|)", min=0.0)
    regularization: str = option("control", "where the shift mu goes: 'control' adds mu*I to Q_uu (the reduced "
                                 "Hessian's eigenvalues shifted by mu), 'state' adds mu*I to V_xx' (Tassa et al. "
                                 "2012)", choices=("control", "state"))
    shift_schedule: str = option("tassa", "'tassa': mu lowered geometrically after each success (Tassa et al. 2012); "
                                 "'inertia': every iteration tries mu = 0 first, then the last shift / 3, x8 "
                                 "(Waechter and Biegler 2006)", choices=("tassa", "inertia"))
    shift_init: float = option(0.0, "initial shift mu ('tassa' schedule)", min=0.0)
    shift_min: float = option(1e-6, "smallest nonzero shift; a decrease below it sets mu = 0", min=0.0,
                              min_exclusive=True)
    shift_max: float = option(1e10, "largest shift before the solver gives up (NUMERICAL_ERROR)", min=0.0,
                              min_exclusive=True)
    shift_factor: float = option(2.0, "base factor of the 'tassa' shift schedule", min=1.0,
                                 min_exclusive=True)
    armijo: float = option(1e-4, "accept a step when the actual decrease is >= armijo * the expected decrease",
                           min=0.0, max=0.5, min_exclusive=True)
    backtrack: float = option(0.5, "step reduction factor of the line search", min=0.01, max=0.99)
    min_step: float = option(1e-8, "smallest step alpha before the shift is raised instead", min=0.0,
                             min_exclusive=True)


@dataclasses.dataclass
class DDPOptions(_DPOptions):
    """Options of :class:`DDPSolver` (``[ddp]`` section of an ini file)."""

    second_order_dynamics: bool = option(True, "include the second-order dynamics terms V_x . f_zz (false: iLQR)")


@dataclasses.dataclass
class StagewiseNewtonOptions(_DPOptions):
    """Options of :class:`StagewiseNewtonSolver` (``[stagewise-newton]`` section of an ini file)."""


# ============================================================================ solvers
class _DynamicProgrammingSolver(Solver):
    """Shared iteration of DDP and the stagewise Newton method (module docstring): phases over
    the solve's DPState (the solver holds only options)."""

    method = ""

    def _solve(self, problem, X0, U0):
        o = self.options
        p = problem
        t_start = time.perf_counter()
        bad = unsupported_features(p)
        if bad:
            return Result(status=Status.INVALID_PROBLEM,
                          message=(f"{self.name} solves unconstrained DOCPs only; this problem has "
                                   + ", ".join(bad) + ". Use 'pdmin' (bounds on the controls) or 'penalty' "
                                   "(general constraints and state bounds), or 'sqp' / 'ipopt'."),
                          objective=float("nan"), x=np.array(X0, dtype=float), u=np.array(U0, dtype=float),
                          info={"method": self.method, "unsupported": bad})
        limits = Limits(o.max_time)
        U = np.array(U0, dtype=float)
        X = p.simulate(U)
        J = p.objective(X, U)
        st = DPState(X=X, U=U, J=J, d=_Derivatives(p, X, U), shift=ShiftSchedule(o), sweeps=Sweeps(p.N, p.n, p.m),
                      limits=limits, message=f"maximum number of iterations ({o.max_iter}) reached")
        with limits.catch() as stop:    # a time limit or an interrupt: the last accepted iterate
            while not self._iterate(p, st):
                pass
        if stop.reason:
            st.stop(*stop_outcome(stop.reason, limits, f"after {st.it} iterations"))
        elapsed = time.perf_counter() - t_start
        return Result(
            status=st.status, message=st.message, objective=float(st.J), x=st.X, u=st.U,
            multipliers={"dynamics": st.d.costate[1:].copy(), "stage_constraints": np.zeros((p.N, 0)),
                         "final_constraints": np.zeros(0)},
            max_constraint_violation=0.0, kkt_residual=st.d.gnorm, iterations=st.it, history=st.history,
            time_s=elapsed,
            info={"method": self.method, "regularization": o.regularization, "final_shift": st.shift.mu,
                  "backward_passes": st.n_backward, "line_search_trials": st.n_trials,
                  "kkt_residual_kind": "max-norm of the reduced gradient dJ/du from the adjoint recursion "
                                       "(= NLP stationarity with the costates as dynamics multipliers)"},
        )

    def _iterate(self, p, st):
        """One iteration; True when the solve stops."""
        o = self.options
        if self._stopped(st):
            return True
        try:
            H = _second_derivatives(p, st.d, self.method, bool(getattr(o, "second_order_dynamics", True)))
        except NonFiniteEvaluationError as exc:
            return st.stop(Status.NUMERICAL_ERROR, f"non-finite second derivatives at iteration {st.it}: {exc}")
        st.limits.check()
        accepted, passes, shift_used = self._step(p, st, H)
        st.n_backward += passes
        if accepted is None:
            return st.stop(Status.NUMERICAL_ERROR, (
                f"iteration {st.it}: the shift mu exceeded shift_max={o.shift_max:g} without a positive definite "
                f"Q_uu at every stage and a step that decreases J (reduced gradient norm {st.d.gnorm:.2e})"))
        st.shift.decrease()
        return self._advance(p, st, accepted, passes, shift_used)

    def _stopped(self, st):
        """Converged (reduced gradient <= tol), after the last step, or out of iterations; the
        time limit and interrupts raise (olado.interrupts)."""
        o = self.options
        if st.d.gnorm <= o.tol:
            return st.stop(Status.SUCCESS, (f"converged in {st.it} iterations: reduced gradient norm "
                                            f"{st.d.gnorm:.2e} <= tol {o.tol:g}"))
        if st.last_step:
            return st.stop(Status.ACCEPTABLE, (f"stopped after {st.it} iterations: the expected decrease is below "
                                               f"decrease_tol (reduced gradient norm {st.d.gnorm:.2e})"))
        if st.it >= o.max_iter:
            return True
        st.limits.check()
        return False

    def _step(self, p, st, H):
        """Backward passes with a rising shift until every Q_uu is positive definite and the line
        search succeeds. Returns (Accepted or None when mu exceeded shift_max, passes, the shift
        of the last successful backward pass)."""
        o, d, w = self.options, st.d, st.sweeps
        Hxx, Hxu, Huu, Txx, Txu, Tuu, use_t, HN = H
        shift_used = st.shift.start()
        passes = 0
        while True:
            st.limits.check()
            mu = st.shift.mu
            fail, d1, d2 = _backward_pass(d.lx, d.lu, d.A, d.B, Hxx, Hxu, Huu, Txx, Txu, Tuu, use_t, d.pN, HN,
                                          mu, o.regularization == "state", w.kff, w.Kfb, w.Vx, w.Vxx)
            passes += 1
            if fail >= 0 or not (math.isfinite(d1) and math.isfinite(d2)):
                if st.shift.raise_():
                    return None, passes, shift_used
                continue
            shift_used = mu
            if -(d1 + 0.5 * d2) <= o.decrease_tol * (1.0 + abs(st.J)):
                st.last_step = True
            if self.method == "stagewise-newton":
                _linear_forward(d.A, d.B, w.kff, w.Kfb, w.dU, w.dX)
            accepted = self._line_search(p, st, d1, d2)
            if accepted is not None:
                return accepted, passes, shift_used
            st.last_step = False
            if st.shift.raise_():
                return None, passes, shift_used

    def _line_search(self, p, st, d1, d2):
        """alpha = 1, backtrack, ...: accepted when the change of J is at least armijo times the
        expected one dV(alpha) (or unchecked, the last step). DDP: the closed-loop rollout;
        stagewise Newton: J(u + alpha du). A non-finite trial point fails its test."""
        o, w = self.options, st.sweeps
        alpha = 1.0
        while alpha >= o.min_step:
            st.n_trials += 1
            try:
                if self.method == "stagewise-newton":
                    st.trial_U = st.U + alpha * w.dU
                    st.trial_X = p.simulate(st.trial_U)
                else:
                    st.trial_X, st.trial_U = _rollout(p, st.X, st.U, w.kff, w.Kfb, alpha)
                Jn = p.objective(st.trial_X, st.trial_U)
            except NonFiniteEvaluationError:
                Jn = math.inf
            st.limits.check()
            dV = alpha * d1 + 0.5 * alpha * alpha * d2
            if st.last_step or (math.isfinite(Jn) and Jn - st.J <= o.armijo * dV):
                return Accepted(alpha, st.trial_X, st.trial_U, Jn, dV)
            alpha *= o.backtrack
        return None

    def _advance(self, p, st, acc, passes, shift_used):
        """Move to the accepted point (back to the previous one after an unchecked last step that
        raised the gradient, or when the derivatives there are not finite); record, log, callback."""
        o = self.options
        step_norm = float(np.max(np.abs(acc.U - st.U), initial=0.0))
        J_old = st.J
        try:
            d_new = _Derivatives(p, acc.X, acc.U)
        except NonFiniteEvaluationError as exc:
            return st.stop(Status.NUMERICAL_ERROR, f"non-finite derivatives after iteration {st.it + 1}: {exc}")
        # the new point and its derivatives in one step (an interrupt never finds them apart),
        # unless the unchecked last step did not help: then the previous point is kept
        if not (st.last_step and d_new.gnorm > st.d.gnorm and d_new.gnorm > o.tol):
            st.X, st.U, st.J, st.d = acc.X, acc.U, acc.J, d_new
        st.it += 1
        rec = {"iter": st.it, "objective": st.J, "grad_norm": st.d.gnorm, "shift": shift_used, "step": acc.alpha,
               "expected_decrease": -acc.dV, "actual_decrease": J_old - st.J, "step_norm": step_norm,
               "backward_passes": passes}
        st.history.append(rec)
        if o.verbose >= 2:
            if st.it == 1:
                print(f"{self.name}: {p.describe().splitlines()[0]}")
                print(f"{'iter':>5} {'objective':>20} {'|grad|':>10} {'shift':>9} {'alpha':>9} "
                      f"{'exp.decr':>10} {'|du|':>10} {'bp':>3}")
            print(f"{st.it:5d} {st.J:20.12e} {st.d.gnorm:10.3e} {shift_used:9.2e} {acc.alpha:9.2e} {-acc.dV:10.3e} "
                  f"{step_norm:10.3e} {passes:3d}")
        if self._call_callback(dict(rec)):
            return st.stop(Status.USER_STOP, f"stopped by the callback after iteration {st.it}")
        return False


class DDPSolver(_DynamicProgrammingSolver):
    """Differential dynamic programming with full second-order dynamics terms and an eigenvalue
    shift of Q_uu (Yakowitz and Rutherford 1984; Tassa et al. 2012 schedule)."""

    name = "ddp"
    method = "ddp"
    Options = DDPOptions


class StagewiseNewtonSolver(_DynamicProgrammingSolver):
    """Pantoja's stagewise Newton method: the exact (shifted) Newton step of the reduced problem
    by a Riccati-like recursion with the nominal costates (Pantoja 1988; Dunn and Bertsekas 1989)."""

    name = "stagewise-newton"
    method = "stagewise-newton"
    Options = StagewiseNewtonOptions
