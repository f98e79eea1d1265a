"""Reduced-gradient methods in the control space (paper 001 sec. 2.2; Findeisen, Szymanowski and
Wierzbicki 1980; Wierzbicki 1984).

The states are eliminated by simulation and the unconstrained problem

    min_u J(u) = sum_k f_0^k(x^k(u), u^k) + F^N(x^N(u)),    x^{k+1} = f^k(x^k, u^k), x^0 fixed,

is solved by a descent method u_{i+1} = u_i + a_i d_i on the N*m controls, with the reduced
gradient g = dJ/du from the adjoint recursion and reduced-Hessian products from the
second-order adjoint (:class:`olado.solvers.control.control_space.ReducedProblem`). Four solvers:

``gradient``         d = -g (steepest descent in the control space).
``cg``               d = -g + beta d_prev, option ``formula``:
                       fletcher-reeves    beta = g+.g+ / g.g
                       polak-ribiere      beta = max(0, g+.(g+ - g) / g.g)          (PR+, Powell 1986)
                       sinnot-luenberger  beta = g+.(g+ - g) / d.(g+ - g)
                     (the last is the conjugacy condition d+.H d = 0 with H d replaced by the gradient
                     difference (g+ - g)/a, i.e. the Hestenes-Stiefel form; see docs/unconstrained-methods.md).
                     Restart with d = -g every ``n_restart`` iterations (default N*m) and whenever d is not a
                     descent direction.
``variable-metric``  BFGS on the inverse reduced Hessian: limited memory (two-loop recursion, ``memory``
                     pairs, Nocedal 1980) or a dense (N*m)^2 matrix for small problems.
``newton``           Newton's method in the control space, truncated (inexact): the Newton system
                     H d = -g is solved by conjugate gradients on reduced-Hessian products to the
                     relative residual eta = min(0.5, |g|_2) (quadratic local convergence, Dembo,
                     Eisenstat and Steihaug 1982); when CG meets a direction of non-positive curvature
                     it stops and returns the last iterate (-g if that happens at once) -- the
                     negative-curvature exit of Nocedal & Wright Algorithm 7.1.

Step size: one strong Wolfe line search for all four (:mod:`olado.solvers.control.line_search`), with the
initial trial a = 1 for variable metric and Newton, and for gradient/CG the minimizer of the
quadratic interpolating J(u_{i-1}), J(u_i) and the slope (N&W eq. (3.60)).

"Fortuna's modification" (gradient, CG and variable-metric methods) and "Picard's modification"
(Newton) of the original OLADO could not be identified from the sources available to us (the
paper only names them; its references, Findeisen et al. 1980 and Wierzbicki 1984, were not
available). What is implemented in their place,
and why, is in docs/unconstrained-methods.md: a step-size rule with a convergence guarantee (the
strong Wolfe line search above, plus restarts for CG and curvature-guarded updates for BFGS) and,
for Newton, the negative-curvature exit of truncated CG.

Stopping: |g|_inf <= tol (times max(1, |g_0|_inf) with ``relative_tol``) is SUCCESS; a step
|u_{i+1} - u_i|_inf <= step_tol (1 + |u|_inf) or a decrease |J_i - J_{i+1}| <= f_tol max(1, |J|)
stops with ACCEPTABLE; max_iter, max_time, a callback returning True, or a failed line search end
with their own status. These methods do not handle bounds or constraints: a problem with finite
control or state bounds or with constraints g >= 0 gets INVALID_PROBLEM (use pdmin or penalty).

The Result: ``kkt_residual`` is |g|_inf (stationarity; the dynamics hold exactly by simulation, so
``max_constraint_violation`` is 0); ``multipliers["dynamics"]`` (N, n) holds the costates
p^{k+1}, the multipliers of x^{k+1} = f^k(x^k, u^k) in IPOPT's sign convention.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...interrupts import Limits
from ...result import Result, Status
from ..common import Stoppable, stop_outcome
from ...options import option
from ..base import Solver, SolverOptions
from .control_space import ReducedProblem, unsupported_features
from .line_search import strong_wolfe

__all__ = ["GradientSolver", "ConjugateGradientSolver", "VariableMetricSolver", "NewtonSolver",
           "unsupported_features"]


@dataclasses.dataclass
class ReducedGradientOptions(SolverOptions):
    """Options shared by the control-space descent methods."""

    max_iter: int = option(5000, "maximum number of iterations", min=0)
    tol: float = option(1e-8, "stop when the max-norm of the reduced gradient dJ/du is <= tol", min=0.0, min_exclusive=True)
    relative_tol: bool = option(False, "measure tol relative to max(1, |dJ/du|_inf at the initial guess)")
    acceptable_tol: float = option(1e-6, "a stalled line search still returns ACCEPTABLE when |dJ/du|_inf <= this "
                                   "(relative like tol)", min=0.0, min_exclusive=True)
    step_tol: float = option(0.0, "stop (ACCEPTABLE) when |u+ - u|_inf <= step_tol (1 + |u|_inf); 0 = off", min=0.0)
    f_tol: float = option(0.0, "stop (ACCEPTABLE) when |J - J+| <= f_tol max(1, |J|); 0 = off", min=0.0)
    wolfe_c1: float = option(1e-4, "sufficient-decrease constant of the strong Wolfe line search",
                             min=0.0, max=0.5, min_exclusive=True)
    wolfe_c2: float = option(0.9, "curvature constant of the strong Wolfe line search (> wolfe_c1, < 1)",
                             min=0.0, max=1.0, min_exclusive=True)
    max_step: float = option(1e10, "largest step length a line search may try", min=0.0, min_exclusive=True)
    max_line_search: int = option(40, "evaluations of J allowed per line search", min=2)


class _Iterate:
    """The current point: controls, states, J, reduced gradient, costates."""

    __slots__ = ("U", "X", "J", "g", "costate")

    def __init__(self, U, X, J, g, costate):
        self.U, self.X, self.J, self.g, self.costate = U, X, J, g, costate


@dataclasses.dataclass
class _Loop(Stoppable):
    """The mutable state of one solve's loop: the iterate, the tolerances, the time limit and
    interrupts, the accepted steps, (J, slope, alpha) of the last step (the next first trial
    step), the stop."""

    cur: _Iterate
    tol: float
    acc_tol: float
    limits: Limits
    it: int = 0
    prev: tuple = (None, None, None)
    status: Status | None = None
    message: str = ""


class ReducedGradientSolver(Solver):
    """Common iteration of the control-space methods: subclasses give the search direction.

    The method's memory (CG's last direction, the BFGS pairs) belongs to one solve: ``_start``
    returns it and the other hooks get it, so one solver instance can run several solves at once."""

    name = "reduced-gradient"
    Options = ReducedGradientOptions
    #: first trial step 1 (Newton-like scaling of the direction) or interpolated (gradient-like)
    unit_step = False

    # -- to implement ---------------------------------------------------------------------
    def _start(self, rp, cur):
        """The method's memory at the initial point (None: the method keeps none)."""
        return None

    def _direction(self, rp, cur, mem):
        """(d, info dict) at the current iterate."""
        raise NotImplementedError

    def _accepted(self, mem, old, new, s, y):
        """Update the method's memory after the step s = u+ - u with y = g+ - g."""

    def _restart(self, mem):
        """Forget the memory (the next direction is -g)."""

    # -- the loop ---------------------------------------------------------------------------
    def _solve(self, problem, X0, U0):
        o = self.options
        t_start = time.perf_counter()
        limits = Limits(o.max_time)
        missing = unsupported_features(problem)
        if missing:
            msg = (f"the {self.name} solver minimizes J(u) without bounds or constraints, but the problem has "
                   f"{', '.join(missing)}; use 'pdmin' (control bounds only) or 'penalty' (constraints) instead")
            return Result(status=Status.INVALID_PROBLEM, message=msg, objective=float("nan"),
                          x=np.asarray(X0, dtype=float), u=np.asarray(U0, dtype=float), info={"unsupported": missing})
        rp = ReducedProblem(problem, limits)
        history = []
        U = np.array(U0, dtype=float)
        try:
            J, g, X, costate = rp.gradient(U)
        except NonFiniteEvaluationError as exc:
            return Result(status=Status.INVALID_PROBLEM, message=f"the initial guess cannot be evaluated: {exc}",
                          objective=float("nan"), x=np.asarray(X0, dtype=float), u=U)
        if not math.isfinite(J):
            return Result(status=Status.INVALID_PROBLEM, message=f"J is not finite at the initial guess ({J})",
                          objective=J, x=X, u=U)
        cur = _Iterate(U, X, J, g, costate)
        gnorm = float(np.max(np.abs(g)))
        scale = max(1.0, gnorm) if o.relative_tol else 1.0
        tol, acc_tol = o.tol * scale, o.acceptable_tol * scale
        mem = self._start(rp, cur)
        rec = self._record(0, cur, rp, alpha=0.0, step_norm=0.0)
        history.append(rec)
        self._log(2, self._log_line(rec, header=True))
        loop = _Loop(cur=cur, tol=tol, acc_tol=acc_tol, limits=limits)
        with limits.catch() as stop:        # a time limit or an interrupt: the last accepted iterate
            while not self._iterate(rp, loop, mem, history):
                pass
        cur, it = loop.cur, loop.it
        status, message = loop.status, loop.message
        if stop.reason:
            status, message = stop_outcome(stop.reason, limits, f"after {it} iterations; |dJ/du|_inf = "
                                                         f"{float(np.max(np.abs(cur.g))):.2e}")
        gnorm = float(np.max(np.abs(cur.g)))
        return Result(
            status=status, message=message, objective=float(cur.J), x=cur.X, u=cur.U,
            multipliers={"dynamics": np.array(cur.costate[1:])},
            max_constraint_violation=0.0, kkt_residual=gnorm, iterations=it,
            evaluations={"objective": rp.n_value, "gradient": rp.n_gradient, "hessian_vector": rp.n_hessvec},
            time_s=time.perf_counter() - t_start, history=history,
            info={"kkt_residual_kind": "max-norm of the reduced gradient dJ/du (the states satisfy the dynamics "
                                       "exactly, by simulation)",
                  "multiplier_convention": "dynamics[k] = costate p^{k+1}, the multiplier of x^{k+1} = f^k(x^k, u^k) "
                                           "(IPOPT's sign convention, as the NLP solvers)",
                  "method": self.method_description()},
        )

    def _iterate(self, rp, loop, mem, history):
        """One iteration: stopping tests, direction, line search, the step; True to stop
        (``loop.status`` set). ``loop.it`` counts the accepted steps only."""
        o, cur = self.options, loop.cur
        gnorm = float(np.max(np.abs(cur.g)))
        if gnorm <= loop.tol:
            return loop.stop(Status.SUCCESS, f"converged in {loop.it} iterations: |dJ/du|_inf = {gnorm:.2e} <= "
                                             f"{loop.tol:.1e}")
        if loop.it >= o.max_iter:
            return loop.stop(Status.MAX_ITERATIONS, f"maximum number of iterations ({o.max_iter}) reached; "
                                                    f"|dJ/du|_inf = {gnorm:.2e}")
        loop.limits.check()
        it = loop.it + 1
        d, dinfo = self._direction(rp, cur, mem)
        slope = float(np.vdot(cur.g, d))
        if not (slope < 0.0 and math.isfinite(slope)):
            self._restart(mem)
            d, dinfo = -cur.g, dict(dinfo, restart=True, steepest=True)
            slope = -float(np.vdot(cur.g, cur.g))
        prev = loop.prev
        alpha0 = self._initial_step(cur, d, slope, *prev, dinfo.get("steepest", False))
        ls, new = self._line_search(rp, cur, d, slope, alpha0)
        if not ls.decrease and not dinfo.get("restart") and not dinfo.get("steepest"):
            # the method's direction failed: one retry along -g with the memory dropped
            self._restart(mem)
            d, dinfo = -cur.g, dict(dinfo, restart=True, steepest=True)
            slope = -float(np.vdot(cur.g, cur.g))
            ls, new = self._line_search(rp, cur, d, slope, self._initial_step(cur, d, slope, *prev, True))
        if not ls.decrease:
            if gnorm <= loop.acc_tol:
                return loop.stop(Status.ACCEPTABLE, (f"no further decrease of J at iteration {it} (rounding level); "
                                                     f"|dJ/du|_inf = {gnorm:.2e} <= acceptable_tol {loop.acc_tol:.1e} "
                                                     f"but > tol {loop.tol:.1e}"))
            return loop.stop(Status.NUMERICAL_ERROR, f"{ls.message} at iteration {it}; |dJ/du|_inf = {gnorm:.2e}")
        s = new.U - cur.U
        y = new.g - cur.g
        self._accepted(mem, cur, new, s, y)
        loop.prev = (cur.J, slope, ls.alpha)
        loop.cur, loop.it = new, it
        step_norm = float(np.max(np.abs(s)))
        rec = self._record(it, new, rp, alpha=ls.alpha, step_norm=step_norm, ls_evaluations=ls.n_value,
                           wolfe=ls.success, **dinfo)
        history.append(rec)
        self._log(2, self._log_line(rec))
        if self.options.callback is not None:
            info = dict(rec, x=new.X, u=new.U, gradient=new.g, solver=self.name)
            if self._call_callback(info):
                return loop.stop(Status.USER_STOP, f"stopped by the callback after iteration {it}")
        if o.step_tol > 0 and step_norm <= o.step_tol * (1.0 + float(np.max(np.abs(new.U)))):
            return loop.stop(Status.ACCEPTABLE, (f"step {step_norm:.2e} below step_tol at iteration {it}; "
                                                 f"|dJ/du|_inf = {rec['grad_norm']:.2e}"))
        if o.f_tol > 0 and abs(cur.J - new.J) <= o.f_tol * max(1.0, abs(new.J)):
            return loop.stop(Status.ACCEPTABLE, (f"decrease of J {cur.J - new.J:.2e} below f_tol at iteration "
                                                 f"{it}; |dJ/du|_inf = {rec['grad_norm']:.2e}"))
        return False

    # -- pieces -----------------------------------------------------------------------------
    def method_description(self) -> str:
        return self.summary()

    def _initial_step(self, cur, d, slope, prev_J, prev_slope, prev_alpha, steepest):
        """First trial step of the line search: 1 for a Newton-like direction; else the minimizer
        of the quadratic through J(u_prev), J(u) and the slope (N&W eq. (3.60)), or, with no
        history, the step of max-norm 1 in the control space."""
        if self.unit_step and not steepest:
            return 1.0
        if prev_J is None:
            return 1.0 / max(float(np.max(np.abs(d))), 1e-300)
        a = 1.01 * 2.0 * (cur.J - prev_J) / slope
        if not (math.isfinite(a) and a > 0) or abs(cur.J - prev_J) <= 1e-10 * (1.0 + abs(cur.J)):
            # J changes at rounding level: keep the first-order change of the last step (N&W eq. (3.59))
            a = prev_alpha * prev_slope / slope
        return a if math.isfinite(a) and a > 0 else 1.0

    def _line_search(self, rp, cur, d, slope, alpha0):
        """Strong Wolfe search along d; returns (LineSearchResult, _Iterate at the step or None)."""
        o = self.options
        trials = {}

        def value(a):
            U = cur.U + a * d
            try:
                J, X = rp.value(U)
            except NonFiniteEvaluationError:
                return math.inf
            trials[a] = [U, X, J, None, None]
            return J

        def derivative(a):
            t = trials[a]
            _, g, _, costate = rp.gradient(t[0], t[1])
            t[3], t[4] = g, costate
            return float(np.vdot(g, d))

        c2 = max(o.wolfe_c2, 2.0 * o.wolfe_c1)
        ls = strong_wolfe(value, derivative, cur.J, slope, alpha0, c1=o.wolfe_c1, c2=min(c2, 0.999),
                          alpha_max=o.max_step, max_evaluations=o.max_line_search)
        if not ls.decrease:
            return ls, None
        U, X, J, g, costate = trials[ls.alpha]
        if g is None:
            _, g, _, costate = rp.gradient(U, X)
        return ls, _Iterate(U, X, J, g, costate)

    @staticmethod
    def _record(it, cur, rp, **extra):
        rec = {"iter": it, "objective": float(cur.J), "grad_norm": float(np.max(np.abs(cur.g))),
               "n_objective": rp.n_value, "n_gradient": rp.n_gradient, "n_hessian_vector": rp.n_hessvec}
        rec.update(extra)
        return rec

    @staticmethod
    def _log_line(rec, header=False):
        line = (f"{rec['iter']:5d}  J={rec['objective']: .10e}  |g|={rec['grad_norm']:.3e}  "
                f"a={rec.get('alpha', 0.0):.3e}  |s|={rec.get('step_norm', 0.0):.3e}")
        if rec.get("restart"):
            line += "  restart"
        if "cg_iterations" in rec:
            line += f"  cg={rec['cg_iterations']}"
        return ("  iter  objective / gradient norm / step\n" + line) if header else line


# ============================================================================== gradient
class GradientSolver(ReducedGradientSolver):
    """Steepest descent in the control space, d = -dJ/du, strong Wolfe line search."""

    name = "gradient"

    def _direction(self, rp, cur, mem):
        return -cur.g, {"steepest": True}


# ============================================================================== conjugate gradients
CG_FORMULAS = ("fletcher-reeves", "polak-ribiere", "sinnot-luenberger")


@dataclasses.dataclass
class ConjugateGradientOptions(ReducedGradientOptions):
    """Options of the conjugate-directions method (``[cg]`` section)."""

    formula: str = option("polak-ribiere", "conjugate-direction coefficient beta", choices=CG_FORMULAS)
    n_restart: int = option(0, "restart with d = -g every n_restart iterations; 0 = every N*m", min=0)
    wolfe_c2: float = option(0.1, "curvature constant of the strong Wolfe line search (< 1/2 keeps "
                             "Fletcher-Reeves directions descent directions)", min=0.0, max=1.0, min_exclusive=True)


class ConjugateGradientSolver(ReducedGradientSolver):
    """Nonlinear conjugate gradients in the control space (Fletcher-Reeves, Polak-Ribiere,
    Sinnot-Luenberger), with restarts."""

    name = "cg"
    Options = ConjugateGradientOptions

    def method_description(self):
        return f"{self.summary()}; beta = {self.options.formula}"

    def _start(self, rp, cur):
        return _CGMemory(n_restart=self.options.n_restart or rp.N * rp.m)

    def _restart(self, mem):
        mem.d = None

    def _direction(self, rp, cur, mem):
        if mem.d is None or mem.beta_next is None or mem.since_restart >= mem.n_restart:
            mem.since_restart = 0
            d = -cur.g
            info = {"restart": True, "steepest": True, "beta": 0.0}
        else:
            beta = mem.beta_next
            d = -cur.g + beta * mem.d
            info = {"restart": False, "beta": float(beta)}
            # a direction that is not a clear descent direction restarts (Powell 1977)
            if float(np.vdot(cur.g, d)) > -1e-12 * float(np.vdot(cur.g, cur.g)):
                mem.since_restart = 0
                d = -cur.g
                info = {"restart": True, "steepest": True, "beta": 0.0}
        mem.d = d
        mem.since_restart += 1
        return d, info

    def _accepted(self, mem, old, new, s, y):
        g, gp = old.g, new.g
        gg = float(np.vdot(g, g))
        f = self.options.formula
        if f == "fletcher-reeves":
            beta = float(np.vdot(gp, gp)) / gg
        elif f == "polak-ribiere":
            beta = max(0.0, float(np.vdot(gp, y)) / gg)
        elif mem.d is None:   # just restarted: no previous direction to be conjugate to
            beta = None
        else:
            dy = float(np.vdot(mem.d, y))
            beta = float(np.vdot(gp, y)) / dy if dy != 0.0 else None
        mem.beta_next = beta if beta is not None and math.isfinite(beta) else None


@dataclasses.dataclass
class _CGMemory:
    """One CG solve's memory: the last direction, iterations since the last restart, the
    restart period, the next beta (None: restart)."""

    n_restart: int
    d: np.ndarray | None = None
    since_restart: int = 0
    beta_next: float | None = None


# ============================================================================== variable metric
@dataclasses.dataclass
class VariableMetricOptions(ReducedGradientOptions):
    """Options of the variable-metric (BFGS) method (``[variable-metric]`` section)."""

    variant: str = option("limited-memory", "limited-memory BFGS (two-loop recursion) or a dense inverse Hessian",
                          choices=("limited-memory", "dense"))
    memory: int = option(10, "number of (s, y) pairs kept by limited-memory BFGS", min=1)
    dense_max_size: int = option(2000, "largest N*m for which the dense variant is allowed", min=1)


class VariableMetricSolver(ReducedGradientSolver):
    """BFGS in the control space: limited memory (default) or dense for small N*m."""

    name = "variable-metric"
    Options = VariableMetricOptions
    unit_step = True

    def method_description(self):
        o = self.options
        return f"{self.summary()}; {o.variant}" + (f", memory {o.memory}" if o.variant == "limited-memory" else "")

    def _solve(self, problem, X0, U0):
        o = self.options
        size = problem.N * problem.m
        if o.variant == "dense" and size > o.dense_max_size:
            return Result(status=Status.FAILED,
                          message=(f"dense BFGS needs an (N*m)^2 matrix and N*m = {size} > dense_max_size = "
                                   f"{o.dense_max_size}; use variant = limited-memory"),
                          objective=float("nan"), x=np.asarray(X0, dtype=float), u=np.asarray(U0, dtype=float))
        return super()._solve(problem, X0, U0)

    def _start(self, rp, cur):
        return _BFGSMemory()

    def _restart(self, mem):
        mem.pairs = []
        mem.H = None
        mem.gamma = None

    def _direction(self, rp, cur, mem):
        g = cur.g.ravel()
        if self.options.variant == "dense":
            if mem.H is None:
                return -cur.g, {"steepest": True}
            return (-(mem.H @ g)).reshape(cur.g.shape), {}
        if not mem.pairs:
            return -cur.g, {"steepest": True}
        q = g.copy()
        alphas = []
        for s, y, rho in reversed(mem.pairs):
            a = rho * float(s @ q)
            alphas.append(a)
            q -= a * y
        r = mem.gamma * q
        for (s, y, rho), a in zip(mem.pairs, reversed(alphas)):
            b = rho * float(y @ r)
            r += (a - b) * s
        return (-r).reshape(cur.g.shape), {}

    def _accepted(self, mem, old, new, s, y):
        s, y = s.ravel(), y.ravel()
        sy = float(s @ y)
        if not (sy > 1e-12 * math.sqrt(float(s @ s) * float(y @ y))):
            mem.skipped += 1            # curvature condition fails: keep the old metric
            return
        rho = 1.0 / sy
        mem.gamma = sy / float(y @ y)
        if self.options.variant == "dense":
            n = s.size
            if mem.H is None:
                mem.H = mem.gamma * np.eye(n)
            Hy = mem.H @ y
            # H+ = (I - rho s y') H (I - rho y s') + rho s s'  (N&W eq. (6.17)) expanded
            mem.H += (rho * rho * float(y @ Hy) + rho) * np.outer(s, s) - rho * (np.outer(Hy, s) + np.outer(s, Hy))
        else:
            mem.pairs.append((s.copy(), y.copy(), rho))
            if len(mem.pairs) > self.options.memory:
                mem.pairs.pop(0)


@dataclasses.dataclass
class _BFGSMemory:
    """One BFGS solve's memory: the (s, y, 1/s.y) pairs, oldest first (limited memory), or the
    dense inverse Hessian; the initial scaling s.y / y.y of the last pair; skipped updates."""

    pairs: list = dataclasses.field(default_factory=list)
    H: np.ndarray | None = None
    gamma: float | None = None
    skipped: int = 0


# ============================================================================== Newton
@dataclasses.dataclass
class NewtonOptions(ReducedGradientOptions):
    """Options of Newton's method in the control space (``[newton]`` section)."""

    max_iter: int = option(200, "maximum number of Newton iterations", min=0)
    max_cg_iter: int = option(0, "CG iterations per Newton step; 0 = N*m", min=0)
    forcing: str = option("quadratic", "CG relative residual eta: 'quadratic' min(0.5, |g|_2), 'superlinear' "
                          "min(0.5, sqrt(|g|_2))", choices=("quadratic", "superlinear"))


class NewtonSolver(ReducedGradientSolver):
    """Truncated Newton in the control space: CG on second-order-adjoint Hessian-vector products
    with the negative-curvature exit, strong Wolfe line search."""

    name = "newton"
    Options = NewtonOptions
    unit_step = True

    def _direction(self, rp, cur, mem):
        g = cur.g
        gn = math.sqrt(float(np.vdot(g, g)))
        eta = min(0.5, gn) if self.options.forcing == "quadratic" else min(0.5, math.sqrt(gn))
        max_cg = self.options.max_cg_iter or rp.N * rp.m
        z = np.zeros_like(g)
        r = g.copy()                 # residual of H z = -g is -(r); r = H z + g
        p = -r
        rr = float(np.vdot(r, r))
        negative = False
        j = 0
        while j < max_cg:
            Hp = rp.hessian_vector(cur.U, p)
            curv = float(np.vdot(p, Hp))
            if curv <= 1e-14 * float(np.vdot(p, p)) * max(1.0, gn):
                negative = True
                break
            a = rr / curv
            z = z + a * p
            r = r + a * Hp
            j += 1
            rr_new = float(np.vdot(r, r))
            if math.sqrt(rr_new) <= eta * gn:
                break
            p = -r + (rr_new / rr) * p
            rr = rr_new
        info = {"cg_iterations": j, "negative_curvature": negative}
        if j == 0:
            return -g, dict(info, steepest=True)
        return z, info
