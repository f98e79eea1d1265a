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
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ...result import Result, Status
from ..common import MULTIPLIER_CONVENTION, is_nonfinite_error
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


def _dot(a, b):
    """a.b over all entries (einsum: no BLAS call, whose threads would compete with the problem's)."""
    return float(np.einsum("ij,ij->", a, b))


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
        o = self.options
        p = problem
        t_start = time.perf_counter()
        lo, hi = p.u_lower, p.u_upper
        U = _box_project(np.array(U0, dtype=float), lo, hi)
        why = self.unsupported(p)
        if why:
            X = p.simulate(U)
            return self._result(p, Status.INVALID_PROBLEM, why, X, U, None, None, float("nan"), 0, [], None, t_start)

        rp = ReducedProblem(p)
        self._eval_time = 0.0

        def gradient(U, X=None):
            t0 = time.perf_counter()
            try:
                return rp.gradient(U, X)
            finally:
                self._eval_time += time.perf_counter() - t0

        def value(U):
            t0 = time.perf_counter()
            try:
                return rp.value(U)
            finally:
                self._eval_time += time.perf_counter() - t0

        try:
            J, g, X, costate = gradient(U)
        except Exception as exc:
            if not is_nonfinite_error(exc):
                raise
            X = np.full((p.N + 1, p.n), np.nan)
            return self._result(p, Status.INVALID_PROBLEM, f"the problem cannot be evaluated at the initial "
                                f"controls (clipped into their bounds): {exc}", X, U, None, None, float("nan"),
                                0, [], rp, t_start)

        sd, cg, lbfgs = (o.direction == d for d in DIRECTIONS)
        refine = o.interpolate_step and sd
        S, Y = [], []               # lbfgs pairs (full vectors, masked in the two-loop)
        gamma = 1.0                 # lbfgs H0 scaling
        have_gamma = False
        d_prev = g_prev = None      # CG
        alpha_prev = slope_prev = None
        active_prev = None
        since_restart = 0
        history = []
        status, message = Status.MAX_ITERATIONS, f"maximum number of PDMIN iterations ({o.max_iter}) reached"
        it = 0
        n_ls_total = 0
        step = 0.0
        n_trials = 0
        while True:
            pg = U - _box_project(U - g, lo, hi)
            pgn = float(np.max(np.abs(pg), initial=0.0))
            eps_k = min(o.epsilon, pgn)
            active = ((U <= lo + eps_k) & (g > 0)) | ((U >= hi - eps_k) & (g < 0))
            n_active = int(np.count_nonzero(active))
            n_lower = int(np.count_nonzero(U == lo)); n_upper = int(np.count_nonzero(U == hi))
            rec = {"iter": it, "objective": J, "pg_norm": pgn, "n_active": n_active,
                   "n_at_bound": n_lower + n_upper, "step": step, "line_search": n_trials,
                   "time_s": time.perf_counter() - t_start}
            history.append(rec)
            if o.verbose >= 2:
                if it % 20 == 0:
                    print(f"{'iter':>6} {'objective':>20} {'|pg|_inf':>10} {'active':>8} {'step':>10} {'ls':>3}")
                print(f"{it:6d} {J:20.12e} {pgn:10.3e} {n_active:8d} {step:10.3e} {n_trials:3d}")
            if pgn <= o.tol:
                status, message = Status.SUCCESS, (f"converged in {it} iterations: projected gradient "
                                                   f"{pgn:.2e} <= tol {o.tol:.1e}, {n_active} active bounds")
                break
            if self._call_callback(dict(rec, x=X, u=U, gradient=g, solver=self.name)):
                status, message = Status.USER_STOP, f"stopped by the callback after iteration {it}"
                break
            if it >= o.max_iter:
                break
            if time.perf_counter() - t_start > o.max_time:
                status, message = Status.MAX_TIME, f"time limit of {o.max_time:g} s reached after {it} iterations"
                break

            # ---------------------------------------------------------------- direction
            free = ~active
            changed = active_prev is None or not np.array_equal(active, active_prev)
            restart = changed and o.restart_on_active_change
            freef = free.astype(float)
            gF = g * freef
            if sd:
                dF = -gF
            elif cg:
                if (restart or d_prev is None or (o.cg_restart and since_restart >= o.cg_restart)):
                    dF, since_restart = -gF, 0
                else:
                    gpF = g_prev * freef
                    den = _dot(gpF, gpF)
                    beta = max(0.0, _dot(gF, gF - gpF) / den) if den > 0 else 0.0
                    dF = -gF + beta * (d_prev * freef)
                    if _dot(gF, dF) > -1e-12 * _dot(gF, gF):   # not a descent direction
                        dF, since_restart = -gF, 0
                since_restart += 1
            else:
                if restart:
                    S.clear(); Y.clear()
                dF = -self._two_loop(gF, freef, S, Y, gamma)
            gA = g - gF
            d = dF - (gamma if lbfgs else 1.0) * gA          # dF is zero on the active set
            slope = _dot(gF, dF)       # g_F.d_F < 0

            # ---------------------------------------------------------------- Armijo along the arc
            dmax = float(np.max(np.abs(d), initial=0.0))
            if lbfgs:
                alpha = 1.0 if have_gamma else min(1.0, o.initial_step / max(dmax, 1e-300))
            elif alpha_prev is None or slope_prev is None or slope >= 0:
                alpha = min(1.0, o.initial_step / max(dmax, 1e-300))
            else:
                alpha = min(1e10, alpha_prev * slope_prev / slope)
            noise = 1e3 * _EPS * (1.0 + abs(J))
            accepted = False
            n_trials = 0
            while n_trials < o.max_line_search:
                n_trials += 1
                Ut = _box_project(U + alpha * d, lo, hi)
                s = Ut - U
                pred = alpha * slope + _dot(gA, s)          # <= 0
                try:
                    Jt, Xt = value(Ut)
                except Exception as exc:
                    if not is_nonfinite_error(exc):
                        raise
                    Jt, Xt = math.inf, None
                dJ = Jt - J
                if n_trials == 1:
                    # end game: the decrease predicted for the first trial is near the rounding
                    # level of J; only then may the gradients stand in for the values
                    endgame = abs(pred) <= 1e3 * noise
                if math.isfinite(Jt) and dJ <= o.armijo * pred:
                    if refine and n_trials == 1 and dJ < 0 and not endgame:
                        Ut, Xt, alpha, extra = self._refine(value, U, d, lo, hi, J, Jt, Ut, Xt, alpha, pred / alpha)
                        n_trials += extra
                    J_new, g_new, X_new, c_new = gradient(Ut, Xt)
                    accepted = True
                    break
                if endgame and math.isfinite(Jt) and abs(dJ) <= noise:
                    # decrease at the rounding level of J: estimate it from the end gradients
                    # (trapezoid rule, exact for quadratics)
                    J_new, g_new, X_new, c_new = gradient(Ut, Xt)
                    if 0.5 * _dot(g + g_new, s) <= o.armijo * pred:
                        accepted = True
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
            if accepted and cg and o.interpolate_step:
                Ut, J_new, g_new, X_new, c_new, alpha, extra = self._secant(
                    gradient, U, d, lo, hi, J, g, Ut, J_new, g_new, X_new, c_new, alpha, noise)
                n_trials += extra
            n_ls_total += n_trials
            if not accepted:
                status, message = Status.NUMERICAL_ERROR, (
                    f"line search failed at iteration {it}: no sufficient decrease along the projection arc "
                    f"after {n_trials} trial steps (projected gradient {pgn:.2e}, tol {o.tol:.1e})")
                if pgn <= math.sqrt(o.tol):
                    status = Status.ACCEPTABLE
                    message += "; the point is kept as acceptable"
                break

            # ---------------------------------------------------------------- update
            s = Ut - U
            step = float(np.max(np.abs(s), initial=0.0))
            if lbfgs:
                yv = g_new - g
                sy = _dot(s, yv)
                yy = _dot(yv, yv)
                if sy > 1e-12 * math.sqrt(_dot(s, s) * yy) and yy > 0:
                    S.append(s); Y.append(yv)
                    if len(S) > o.memory:
                        S.pop(0); Y.pop(0)
                    gamma, have_gamma = sy / yy, True
            d_prev, g_prev = d, g
            alpha_prev, slope_prev = alpha, slope
            active_prev = active
            U, J, g, X, costate = Ut, J_new, g_new, X_new, c_new
            it += 1

        return self._result(p, status, message, X, U, g, costate, pgn, it, history, rp, t_start,
                            extra={"line_search_trials": n_ls_total})

    # ---------------------------------------------------------------------------- pieces
    @staticmethod
    def _refine(value, U, d, lo, hi, J, Jt, Ut, Xt, alpha, slope, max_expand=10):
        """After an accepted first trial: try the minimizer of the quadratic through J(u), the
        slope along the arc and J(u(alpha)); when J fell almost linearly (the step is far too
        short to feel any curvature) extrapolate alpha by 4 while J keeps falling. The lowest
        point is kept. Returns (u, x, alpha, number of extra values)."""
        count = [0]

        def trial(a):
            count[0] += 1
            Ua = np.clip(U + a * d, lo, hi)
            try:
                Ja, Xa = value(Ua)
            except Exception as exc:
                if not is_nonfinite_error(exc):
                    raise
                return math.inf, None, None
            return Ja, Ua, Xa

        curv = (Jt - J - slope * alpha) / (alpha * alpha)
        if curv > 0 and (Jt - J) > 0.9 * slope * alpha:     # curvature felt: quadratic model
            a_q = -slope / (2.0 * curv)
            if 0.8 * alpha <= a_q <= 1.25 * alpha:
                return Ut, Xt, alpha, 0
            Jq, Uq, Xq = trial(min(a_q, 100.0 * alpha))
            if Jq < Jt:
                return Uq, Xq, min(a_q, 100.0 * alpha), 1
            return Ut, Xt, alpha, 1
        best = (Jt, Ut, Xt, alpha)        # nearly linear decrease: extrapolate
        pts = [(0.0, J), (alpha, Jt)]
        a = alpha
        for _ in range(max_expand):
            a *= 4.0
            Ja, Ua, Xa = trial(a)
            pts.append((a, Ja))
            if not Ja < best[0]:
                break
            best = (Ja, Ua, Xa, a)
        (a0, J0), (a1, J1), (a2, J2) = pts[-3:]
        if math.isfinite(J2) and J2 >= J1 <= J0:
            # minimizer of the parabola through the last three points (a bracket)
            num = (a1 - a0) ** 2 * (J1 - J2) - (a1 - a2) ** 2 * (J1 - J0)
            den = (a1 - a0) * (J1 - J2) - (a1 - a2) * (J1 - J0)
            if den != 0:
                a_p = a1 - 0.5 * num / den
                if a0 < a_p < a2 and abs(a_p - a1) > 0.1 * a1:
                    Jp, Up, Xp = trial(a_p)
                    if Jp < best[0]:
                        best = (Jp, Up, Xp, a_p)
        return best[1], best[2], best[3], count[0]

    @staticmethod
    def _secant(gradient, U, d, lo, hi, J, g, Ut, Jt, gt, Xt, ct, alpha, noise, max_steps=2):
        """CG: make the line search near exact with secant steps on the directional derivative
        phi'(a) = grad J(u(a)).d (over the components not stopped by a bound) while
        |phi'(alpha)| > 0.1 |phi'(0)|. Gradients, not values: works at the rounding level of J.
        Each new point is kept only when it is lower (the trapezoid estimate of the change when
        the values cannot tell)."""
        moving = ((Ut > lo) & (Ut < hi)).astype(float)
        dm = d * moving
        s0 = _dot(g, dm)
        extra = 0
        if not s0 < 0:
            return Ut, Jt, gt, Xt, ct, alpha, extra
        for _ in range(max_steps):
            s1 = _dot(gt, dm)
            if abs(s1) <= 0.1 * abs(s0) or s1 <= s0:
                break
            a_s = alpha * s0 / (s0 - s1)
            a_s = min(a_s, 10.0 * alpha)
            Us = np.clip(U + a_s * d, lo, hi)
            try:
                Js, gs, Xs, cs = gradient(Us)
            except Exception as exc:
                if not is_nonfinite_error(exc):
                    raise
                break
            extra += 1
            better = Js < Jt - noise or (abs(Js - Jt) <= noise and 0.5 * _dot(gt + gs, Us - Ut) < 0)
            if not better:
                break
            Ut, Jt, gt, Xt, ct, alpha = Us, Js, gs, Xs, cs, a_s
        return Ut, Jt, gt, Xt, ct, alpha, extra

    @staticmethod
    def _two_loop(gF, freef, S, Y, gamma):
        """H_F g_F by the L-BFGS two-loop recursion on the free components: the pairs are masked
        to F (``freef`` is the 0/1 float mask; q and r stay zero on the active set, so only the
        updates need the mask), pairs without positive curvature on F are skipped."""
        q = gF.copy()
        kept = []
        for s, y in zip(reversed(S), reversed(Y)):
            sy = float(np.einsum("ij,ij,ij->", s, y, freef))
            ss = float(np.einsum("ij,ij,ij->", s, s, freef))
            yy = float(np.einsum("ij,ij,ij->", y, y, freef))
            if sy <= 1e-12 * math.sqrt(ss * yy) or sy <= 0:
                continue
            rho = 1.0 / sy
            a = rho * _dot(s, q)
            q -= (a * y) * freef
            kept.append((s, y, rho, a, sy / yy))
        if kept:   # H0 scaling from the newest usable pair
            gamma = kept[0][4]
        r = gamma * q
        for s, y, rho, a, _ in reversed(kept):
            b = rho * _dot(y, r)
            r += ((a - b) * s) * freef
        return r

    def _result(self, p, status, message, X, U, g, costate, pgn, it, history, rp, t_start, extra=None):
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
        ev_time = getattr(self, "_eval_time", 0.0)
        info.update(solve_time_s=solve_time, callback_time_s=ev_time,
                    callback_share=ev_time / solve_time if solve_time > 0 else float("nan"))
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
