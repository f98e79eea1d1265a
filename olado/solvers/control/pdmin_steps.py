"""The pieces of a PDMIN iteration (olado.solvers.control.pdmin; paper 001 sec. 2.2, Schwartz
and Polak 1997, Bertsekas 1982) on the controls u (N, m) of the reduced problem min J(u) s.t.
the bounds (5): the solve's state, the projection arc u(a) = P(u + a d), the refinements of an
accepted Armijo step (quadratic model or extrapolation for steepest descent, secant steps on
phi'(a) for conjugate gradients) and the L-BFGS two-loop recursion on the free variables.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, NamedTuple

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...result import Status


def dot(a, b):
    """a.b over all entries (einsum: no BLAS call, whose threads would compete with the problem's)."""
    return float(np.einsum("ij,ij->", a, b))


class Evaluations:
    """J(u) and its gradient on the reduced problem, timed (info["callback_time_s"])."""

    def __init__(self, rp):
        self.rp = rp
        self.time_s = 0.0

    def gradient(self, U, X=None):
        """(J, g, X, costate) at U."""
        t0 = time.perf_counter()
        try:
            return self.rp.gradient(U, X)
        finally:
            self.time_s += time.perf_counter() - t0

    def value(self, U):
        """(J, X) at U."""
        t0 = time.perf_counter()
        try:
            return self.rp.value(U)
        finally:
            self.time_s += time.perf_counter() - t0


class Point(NamedTuple):
    """A point with its gradient: controls, J, reduced gradient, states, costates, and the step
    alpha along the arc that reached it (line-search trials)."""

    U: np.ndarray
    J: float
    g: np.ndarray
    X: np.ndarray
    costate: np.ndarray
    alpha: float = 0.0


class Direction(NamedTuple):
    """The search direction d, the gradient on the active set g_A and the slope g_F.d_F."""

    d: np.ndarray
    gA: np.ndarray
    slope: float


class Arc(NamedTuple):
    """The projection arc u(a) = P(U + a d) onto the box [lo, hi]."""

    U: np.ndarray
    d: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    def at(self, a):
        return np.clip(self.U + a * self.d, self.lo, self.hi)


@dataclasses.dataclass
class Memory:
    """What the directions and the first trial step carry from one iteration to the next."""

    S: list = dataclasses.field(default_factory=list)   # lbfgs pairs (full vectors, masked in the two-loop)
    Y: list = dataclasses.field(default_factory=list)
    gamma: float = 1.0              # lbfgs H0 scaling
    have_gamma: bool = False
    d_prev: np.ndarray | None = None    # CG
    g_prev: np.ndarray | None = None
    since_restart: int = 0
    alpha_prev: float | None = None
    slope_prev: float | None = None
    active_prev: np.ndarray | None = None


@dataclasses.dataclass
class State:
    """One PDMIN solve: the iterate, the direction memory, the evaluations, counters, history."""

    cur: Point
    evals: Evaluations
    t_start: float
    message: str
    limits: Any = None              # the solve's olado.interrupts.Limits
    memory: Memory = dataclasses.field(default_factory=Memory)
    status: Status = Status.MAX_ITERATIONS
    it: int = 0
    step: float = 0.0               # |u_{k+1} - u_k|_inf of the last step
    n_trials: int = 0               # trial points of the last line search
    n_ls_total: int = 0
    history: list = dataclasses.field(default_factory=list)


def refine(value, arc, J, Jt, Ut, Xt, alpha, slope, max_expand=10):
    """After an accepted first trial (Jt, Ut, Xt) at alpha: try the minimizer of the quadratic
    through J(u), the slope along the arc and J(u(alpha)); when J fell almost linearly (the step
    is far too short to feel any curvature) extrapolate alpha by 4 while J keeps falling. The
    lowest point is kept. Returns (u, x, alpha, number of extra values)."""
    count = [0]

    def trial(a):
        count[0] += 1
        Ua = arc.at(a)
        try:
            Ja, Xa = value(Ua)
        except NonFiniteEvaluationError:
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


def secant(gradient, arc, g, t, noise, max_steps=2):
    """CG: make the line search near exact with secant steps on the directional derivative
    phi'(a) = grad J(u(a)).d (over the components not stopped by a bound) while
    |phi'(alpha)| > 0.1 |phi'(0)|, from the accepted point t (a :class:`Point`). Gradients, not
    values: works at the rounding level of J. Each new point is kept only when it is lower (the
    trapezoid estimate of the change when the values cannot tell). Returns (Point, extra
    gradients)."""
    moving = ((t.U > arc.lo) & (t.U < arc.hi)).astype(float)
    dm = arc.d * moving
    s0 = dot(g, dm)
    extra = 0
    if not s0 < 0:
        return t, extra
    for _ in range(max_steps):
        s1 = dot(t.g, dm)
        if abs(s1) <= 0.1 * abs(s0) or s1 <= s0:
            break
        a_s = t.alpha * s0 / (s0 - s1)
        a_s = min(a_s, 10.0 * t.alpha)
        Us = arc.at(a_s)
        try:
            Js, gs, Xs, cs = gradient(Us)
        except NonFiniteEvaluationError:
            break
        extra += 1
        better = Js < t.J - noise or (abs(Js - t.J) <= noise and 0.5 * dot(t.g + gs, Us - t.U) < 0)
        if not better:
            break
        t = Point(Us, Js, gs, Xs, cs, a_s)
    return t, extra


def two_loop(gF, freef, S, Y, gamma):
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
        a = rho * dot(s, q)
        q -= (a * y) * freef
        kept.append((s, y, rho, a, sy / yy))
    if kept:   # H0 scaling from the newest usable pair
        gamma = kept[0][4]
    r = gamma * q
    for s, y, rho, a, _ in reversed(kept):
        b = rho * dot(y, r)
        r += ((a - b) * s) * freef
    return r
