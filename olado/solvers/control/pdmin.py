"""PDMIN: projected descent minimization for DOCPs with simple bounds on the controls only
(paper 001 sec. 2.2; Schwartz and Polak 1997, extending Bertsekas 1982).

The states are eliminated (:class:`~olado.solvers.control.control_space.ReducedProblem`), which leaves

    min_u J(u)   s.t.   u_L <= u <= u_U      (u = (u^0, ..., u^{N-1}), bounds (N, m), eq. (5))

with P the projection onto the box. One iteration at u with the reduced gradient g:

1. projected gradient and epsilon-active set (Bertsekas 1982, eq. (32)):

       w = |u - P(u - g)|_inf,    eps_k = min(epsilon, w),
       A = {i : u_i <= u_L,i + eps_k, g_i > 0}  U  {i : u_i >= u_U,i - eps_k, g_i < 0},   F = not A;

2. a direction d: on A the (scaled) negative gradient, d_A = -gamma g_A, which the projection
   stops at the bound; on the free set F one of

       steepest-descent   d_F = -g_F
       polak-ribiere      d_F = -g_F + beta d_F^-,  beta = max(0, g_F.(g_F - g_F^-) / |g_F^-|^2)  (PR+)
       lbfgs              d_F = -H_F g_F, the limited-memory BFGS two-loop recursion on the free
                          components (pairs (s_F, y_F) with s_F.y_F > 0 only, H0 = gamma I,
                          gamma = s.y / y.y of the newest pair)

   restarted (steepest descent / empty memory) when the active set changes (option), when d_F
   is not a descent direction, and for CG every ``cg_restart`` iterations;

3. Armijo rule along the projection arc u(alpha) = P(u + alpha d) (Bertsekas' rule):

       J(u(alpha)) <= J(u) + sigma [ alpha g_F.d_F + g_A.(u(alpha) - u)_A ],

   alpha = alpha_0 beta^j with safeguarded quadratic interpolation (alpha_0 = 1 for lbfgs, else
   the previous step scaled by the ratio of the slopes, Nocedal-Wright). Option interpolate_step
   refines an accepted step: for steepest descent by a quadratic model of J (or extrapolation
   when J fell linearly), for CG by secant steps on the directional derivative
   phi'(a) = grad J(u(a)).d until |phi'(alpha)| <= 0.1 |phi'(0)| -- PR+ needs near-exact line
   searches (without them it took 10-50x more iterations on the test problems). When the decrease is at the
   rounding level of J (large N, tight tolerance) the change of J is estimated from the
   gradients at both ends, J(u(alpha)) - J(u) ~ (g + g(alpha)).(u(alpha) - u) / 2 (exact for
   quadratics), so the tolerance can be driven far below sqrt(eps) |J|.

Stop when w <= tol (max-norm of the projected gradient), or on max_iter / max_time / a callback.
The bound multipliers are z_L = max(g, 0), z_U = max(-g, 0) on the epsilon-active bounds (zero
elsewhere), so that grad J - z_L + z_U = 0 at a solution (IPOPT's sign convention); the dynamics
multipliers are the costates p^{k+1} of the adjoint recursion.

All work is on (N, m) arrays (no Python loop over the stages); one iteration costs one gradient
(simulation + adjoint sweep) and usually one extra simulation.

Code: an iteration is the phases ``_measure`` (step 1 and the history record), ``_stop``,
``_direction`` (2), ``_search`` (3) and ``_update`` of :class:`PDMINSolver` over the solve's
:class:`~olado.solvers.control.pdmin_steps.State`; the solver holds only options. The state
types, the arc refinements and the two-loop recursion are in :mod:`olado.solvers.control.pdmin_steps`.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...result import Result, Status
from ...errors import NonFiniteEvaluationError
from .pdmin_steps import Arc, Direction, Evaluations, Point, State, dot, refine, secant, two_loop
from ..common import MULTIPLIER_CONVENTION, stop_outcome
from ...interrupts import Limits
from ...options import option
from ..base import Solver, SolverOptions
from .control_space import ReducedProblem, unsupported_features

DIRECTIONS = ("steepest-descent", "polak-ribiere", "lbfgs")

_EPS = np.finfo(float).eps


@dataclasses.dataclass
class PDMINOptions(SolverOptions):
    """Options of :class:`PDMINSolver` (``[pdmin]`` section of an ini file)."""

    max_iter: int = option(5000, "maximum number of iterations", min=0)
    tol: float = option(1e-6, "stop when the projected gradient |u - P(u - grad J)|_inf <= tol (absolute)",
                        min=0.0, min_exclusive=True)
    direction: str = option("lbfgs", "descent direction on the free variables", choices=DIRECTIONS)
    memory: int = option(8, "lbfgs: number of (s, y) pairs kept", min=1)
    epsilon: float = option(1e-3, "upper bound of Bertsekas' epsilon_k = min(epsilon, |u - P(u - g)|_inf) "
                            "that identifies the active bounds", min=0.0)
    restart_on_active_change: bool = option(True, "restart the direction (CG: steepest descent; lbfgs: empty "
                                            "memory, scaling kept) when the epsilon-active set changes")
    cg_restart: int = option(0, "polak-ribiere: restart with steepest descent every this many iterations "
                             "(0: only by the other rules)", min=0)
    armijo: float = option(1e-4, "sufficient-decrease constant sigma of the Armijo rule", min=0.0, max=0.5,
                           min_exclusive=True)
    backtrack: float = option(0.5, "largest step reduction factor of the Armijo rule (quadratic "
                              "interpolation inside [0.1, backtrack])", min=0.1, max=0.9)
    max_line_search: int = option(40, "trial steps per iteration before the line search fails", min=1)
    initial_step: float = option(1.0, "lbfgs: first trial step; steepest descent / CG: upper bound of the "
                                 "first trial step, which is scaled so that |alpha d|_inf <= initial_step "
                                 "at the first iteration", min=0.0, min_exclusive=True)
    interpolate_step: bool = option(True, "steepest descent: after an accepted first trial, also try the minimizer "
                                    "of the quadratic through J(u), the slope and J(u(alpha)), or extrapolate "
                                    "when J fell linearly; CG: secant steps on the directional derivative until "
                                    "|phi'(alpha)| <= 0.1 |phi'(0)| (conjugacy needs near-exact line searches)")


def _box_project(U, lo, hi, out=None):
    return np.clip(U, lo, hi, out=out)


class PDMINSolver(Solver):
    """Projected descent minimization (PDMIN) for bound-constrained controls (paper 001 sec. 2.2)."""

    name = "pdmin"
    Options = PDMINOptions

    # ---------------------------------------------------------------------------- checks
    @staticmethod
    def unsupported(problem) -> str:
        """Why PDMIN cannot solve ``problem`` ('' when it can)."""
        why = unsupported_features(problem, control_bounds=True)
        if not why:
            return ""
        return ("PDMIN handles simple bounds on the controls only; this problem has " + ", ".join(why)
                + ". Use solver='penalty' (penalty functions on the control-space methods) or "
                  "solver='sqp' / 'ipopt' for state and general constraints.")

    # ---------------------------------------------------------------------------- solve
    def _solve(self, problem, X0, U0):
        p = problem
        t_start = time.perf_counter()
        U = _box_project(np.array(U0, dtype=float), p.u_lower, p.u_upper)
        why = self.unsupported(p)
        if why:     # the guess's states, as they are: the controls clipped need not simulate finitely
            X = np.asarray(X0, dtype=float)
            return self._result(p, Status.INVALID_PROBLEM, why, X, U, None, None, float("nan"), 0, [], None, t_start)
        limits = Limits(self.options.max_time)
        evals = Evaluations(ReducedProblem(p, limits))
        try:
            J, g, X, costate = evals.gradient(U)
        except NonFiniteEvaluationError as exc:
            X = np.full((p.N + 1, p.n), np.nan)
            return self._result(p, Status.INVALID_PROBLEM, f"the problem cannot be evaluated at the initial "
                                f"controls (clipped into their bounds): {exc}", X, U, None, None, float("nan"),
                                0, [], evals.rp, t_start, eval_time=evals.time_s)
        st = State(cur=Point(U, J, g, X, costate), evals=evals, t_start=t_start, limits=limits,
                    message=f"maximum number of PDMIN iterations ({self.options.max_iter}) reached")
        pgn = float("nan")
        with limits.catch() as stop:    # a time limit or an interrupt: the last accepted iterate
            while True:
                active, pgn = self._measure(p, st)
                if self._stop(st, pgn, active):
                    break
                direction = self._direction(st, active)
                trial = self._search(p, st, direction)
                st.n_ls_total += st.n_trials
                if trial is None:
                    st.status, st.message = Status.NUMERICAL_ERROR, (
                        f"line search failed at iteration {st.it}: no sufficient decrease along the projection arc "
                        f"after {st.n_trials} trial steps (projected gradient {pgn:.2e}, tol {self.options.tol:.1e})")
                    if pgn <= math.sqrt(self.options.tol):
                        st.status = Status.ACCEPTABLE
                        st.message += "; the point is kept as acceptable"
                    break
                self._update(st, direction, trial, active)
        if stop.reason:
            st.status, st.message = stop_outcome(stop.reason, limits, f"after {st.it} iterations")
        c = st.cur
        return self._result(p, st.status, st.message, c.X, c.U, c.g, c.costate, pgn, st.it, st.history, evals.rp,
                            t_start, extra={"line_search_trials": st.n_ls_total}, eval_time=evals.time_s)

    # ---------------------------------------------------------------------------- phases
    def _measure(self, p, st):
        """Step 1 at the iterate: projected gradient w, the epsilon-active set; the history record."""
        o, c = self.options, st.cur
        U, g, lo, hi = c.U, c.g, p.u_lower, p.u_upper
        pg = U - _box_project(U - g, lo, hi)
        pgn = float(np.max(np.abs(pg), initial=0.0))
        eps_k = min(o.epsilon, pgn)
        active = ((U <= lo + eps_k) & (g > 0)) | ((U >= hi - eps_k) & (g < 0))
        n_active = int(np.count_nonzero(active))
        n_lower = int(np.count_nonzero(U == lo)); n_upper = int(np.count_nonzero(U == hi))
        rec = {"iter": st.it, "objective": c.J, "pg_norm": pgn, "n_active": n_active,
               "n_at_bound": n_lower + n_upper, "step": st.step, "line_search": st.n_trials,
               "time_s": time.perf_counter() - st.t_start}
        st.history.append(rec)
        if o.verbose >= 2:
            if st.it % 20 == 0:
                print(f"{'iter':>6} {'objective':>20} {'|pg|_inf':>10} {'active':>8} {'step':>10} {'ls':>3}")
            print(f"{st.it:6d} {c.J:20.12e} {pgn:10.3e} {n_active:8d} {st.step:10.3e} {st.n_trials:3d}")
        return active, pgn

    def _stop(self, st, pgn, active):
        """Converged (w <= tol), stopped by the callback, or out of iterations / time."""
        o, c = self.options, st.cur
        if pgn <= o.tol:
            st.status, st.message = Status.SUCCESS, (f"converged in {st.it} iterations: projected gradient "
                                                     f"{pgn:.2e} <= tol {o.tol:.1e}, "
                                                     f"{int(np.count_nonzero(active))} active bounds")
            return True
        if self._call_callback(dict(st.history[-1], x=c.X, u=c.U, gradient=c.g, solver=self.name)):
            st.status, st.message = Status.USER_STOP, f"stopped by the callback after iteration {st.it}"
            return True
        if st.it >= o.max_iter:
            return True
        st.limits.check()       # the time limit, an interrupt: raise (olado.interrupts)
        return False

    def _direction(self, st, active):
        """Step 2: d_A = -gamma g_A on the active set, d_F by the chosen method on the free set
        (restarted as the module docstring says)."""
        o, mem, g = self.options, st.memory, st.cur.g
        sd, cg, lbfgs = (o.direction == d for d in DIRECTIONS)
        free = ~active
        changed = mem.active_prev is None or not np.array_equal(active, mem.active_prev)
        restart = changed and o.restart_on_active_change
        freef = free.astype(float)
        gF = g * freef
        if sd:
            dF = -gF
        elif cg:
            if restart or mem.d_prev is None or (o.cg_restart and mem.since_restart >= o.cg_restart):
                dF, mem.since_restart = -gF, 0
            else:
                gpF = mem.g_prev * freef
                den = dot(gpF, gpF)
                beta = max(0.0, dot(gF, gF - gpF) / den) if den > 0 else 0.0
                dF = -gF + beta * (mem.d_prev * freef)
                if dot(gF, dF) > -1e-12 * dot(gF, gF):   # not a descent direction
                    dF, mem.since_restart = -gF, 0
            mem.since_restart += 1
        else:
            if restart:
                mem.S.clear(); mem.Y.clear()
            dF = -two_loop(gF, freef, mem.S, mem.Y, mem.gamma)
        gA = g - gF
        d = dF - (mem.gamma if lbfgs else 1.0) * gA          # dF is zero on the active set
        return Direction(d=d, gA=gA, slope=dot(gF, dF))    # slope g_F.d_F < 0

    def _first_step(self, st, direction, dmax):
        """alpha_0: 1 for lbfgs (once it has a scaling), else the previous step scaled by the
        ratio of the slopes, at most initial_step / |d|_inf at the first iteration."""
        o, mem, slope = self.options, st.memory, direction.slope
        if o.direction == "lbfgs":
            return 1.0 if mem.have_gamma else min(1.0, o.initial_step / max(dmax, 1e-300))
        if mem.alpha_prev is None or mem.slope_prev is None or slope >= 0:
            return min(1.0, o.initial_step / max(dmax, 1e-300))
        return min(1e10, mem.alpha_prev * mem.slope_prev / slope)

    def _search(self, p, st, direction):
        """Step 3: the Armijo rule along the projection arc (module docstring); the accepted
        Point or None. ``st.n_trials`` counts the trial points."""
        o, c, evals = self.options, st.cur, st.evals
        U, J, g, lo, hi = c.U, c.J, c.g, p.u_lower, p.u_upper
        d, gA, slope = direction
        arc = Arc(U, d, lo, hi)
        interpolate = o.interpolate_step and o.direction == "steepest-descent"
        dmax = float(np.max(np.abs(d), initial=0.0))
        alpha = self._first_step(st, direction, dmax)
        noise = 1e3 * _EPS * (1.0 + abs(J))
        accepted = None
        st.n_trials = n_trials = 0
        while n_trials < o.max_line_search:
            n_trials += 1
            Ut = arc.at(alpha)
            s = Ut - U
            pred = alpha * slope + dot(gA, s)          # <= 0
            try:
                Jt, Xt = evals.value(Ut)
            except NonFiniteEvaluationError:
                Jt, Xt = math.inf, None
            dJ = Jt - J
            if n_trials == 1:
                # end game: the decrease predicted for the first trial is near the rounding
                # level of J; only then may the gradients stand in for the values
                endgame = abs(pred) <= 1e3 * noise
            if math.isfinite(Jt) and dJ <= o.armijo * pred:
                if interpolate and n_trials == 1 and dJ < 0 and not endgame:
                    Ut, Xt, alpha, extra = refine(evals.value, arc, J, Jt, Ut, Xt, alpha, pred / alpha)
                    n_trials += extra
                accepted = Point(Ut, *evals.gradient(Ut, Xt), alpha)
                break
            if endgame and math.isfinite(Jt) and abs(dJ) <= noise:
                # decrease at the rounding level of J: estimate it from the end gradients
                # (trapezoid rule, exact for quadratics)
                trial = Point(Ut, *evals.gradient(Ut, Xt), alpha)
                if 0.5 * dot(g + trial.g, s) <= o.armijo * pred:
                    accepted = trial
                    break
            # safeguarded quadratic interpolation on phi(a) ~ J + a*slope_total
            slope_tot = pred / alpha
            if math.isfinite(Jt) and slope_tot < 0 and not endgame:
                denom = 2.0 * (dJ - slope_tot * alpha)
                a_new = -slope_tot * alpha * alpha / denom if denom > 0 else o.backtrack * alpha
                alpha = min(max(a_new, 0.1 * alpha), o.backtrack * alpha)
            else:
                alpha *= 0.1 if not math.isfinite(Jt) else o.backtrack
            if alpha * dmax <= 1e-15 * (1.0 + float(np.max(np.abs(U), initial=0.0))):
                break
        if accepted is not None and o.direction == "polak-ribiere" and o.interpolate_step:
            accepted, extra = secant(evals.gradient, arc, g, accepted, noise)
            n_trials += extra
        st.n_trials = n_trials
        return accepted

    def _update(self, st, direction, trial, active):
        """Step 4: the new iterate; the lbfgs pair (s, y) when s.y > 0; the CG and step memory."""
        o, mem, c = self.options, st.memory, st.cur
        s = trial.U - c.U
        st.step = float(np.max(np.abs(s), initial=0.0))
        if o.direction == "lbfgs":
            yv = trial.g - c.g
            sy = dot(s, yv)
            yy = dot(yv, yv)
            if sy > 1e-12 * math.sqrt(dot(s, s) * yy) and yy > 0:
                mem.S.append(s); mem.Y.append(yv)
                if len(mem.S) > o.memory:
                    mem.S.pop(0); mem.Y.pop(0)
                mem.gamma, mem.have_gamma = sy / yy, True
        mem.d_prev, mem.g_prev = direction.d, c.g
        mem.alpha_prev, mem.slope_prev = trial.alpha, direction.slope
        mem.active_prev = active
        st.cur = trial
        st.it += 1

    def _result(self, p, status, message, X, U, g, costate, pgn, it, history, rp, t_start, extra=None,
                eval_time=0.0):
        N, n, m = p.N, p.n, p.m
        lo, hi = p.u_lower, p.u_upper
        zl = np.zeros((N, m)); zu = np.zeros((N, m))
        info = {"direction": self.options.direction, "projected_gradient": pgn,
                "multiplier_convention": MULTIPLIER_CONVENTION,
                "kkt_residual_kind": "max-norm of grad J - z_L + z_U (reduced gradient, control bounds) and of "
                                     "the complementarity z_L (u - u_L), z_U (u_U - u)"}
        kkt = None
        if g is not None:
            eps_k = min(self.options.epsilon, pgn)
            at_lo = (U <= lo + eps_k) & (g > 0)
            at_hi = (U >= hi - eps_k) & (g < 0)
            zl[at_lo] = g[at_lo]
            zu[at_hi] = -g[at_hi]
            stat = float(np.max(np.abs(g - zl + zu), initial=0.0))
            with np.errstate(invalid="ignore"):
                compl = float(np.max(np.nan_to_num(np.maximum(zl * (U - lo), zu * (hi - U))), initial=0.0))
            kkt = max(stat, compl)
            info.update(stationarity_residual=stat, complementarity_residual=compl,
                        n_active=int(np.count_nonzero(at_lo | at_hi)), n_at_lower=int(np.count_nonzero(U == lo)),
                        n_at_upper=int(np.count_nonzero(U == hi)))
        if extra:
            info.update(extra)
        solve_time = time.perf_counter() - t_start
        info.update(solve_time_s=solve_time, callback_time_s=eval_time,
                    callback_share=eval_time / solve_time if solve_time > 0 else float("nan"))
        mult = {"dynamics": costate[1:].copy() if costate is not None else np.zeros((N, n)),
                "stage_constraints": np.zeros((N, 0)), "final_constraints": np.zeros(0),
                "bound_lower_x": np.zeros((N + 1, n)), "bound_upper_x": np.zeros((N + 1, n)),
                "bound_lower_u": zl, "bound_upper_u": zu}
        viol = float(max(np.max(lo - U, initial=0.0), np.max(U - hi, initial=0.0), 0.0))
        J = float("nan")
        if history:
            J = history[-1]["objective"]
        elif np.all(np.isfinite(X)):
            J = p.objective(X, U)
        evaluations = {}
        if rp is not None:
            evaluations = {"objective": rp.n_value + rp.n_gradient, "gradient": rp.n_gradient}
        return Result(status=status, message=message, objective=float(J), x=np.asarray(X, dtype=float),
                      u=np.asarray(U, dtype=float), multipliers=mult, max_constraint_violation=viol,
                      kkt_residual=kkt, iterations=it, evaluations=evaluations, history=history, info=info)
