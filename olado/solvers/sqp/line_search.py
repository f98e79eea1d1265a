"""The step length alpha of eq. (11) (paper 001 sec. 4.2.1): Armijo backtracking on the L1
merit function (olado.solvers.sqp.merit), with the watchdog technique of Chamberlain, Powell,
Lemarechal and Pedersen (1982) and the second-order correction (Fletcher 1982; Nocedal & Wright
2006 sec. 18.3).
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple

import numpy as np

from ...errors import NonFiniteEvaluationError
from .state import Point


class SearchResult(NamedTuple):
    """alpha, the accepted point (None when no acceptable step was found), the trial points
    evaluated, and how the step was accepted: "full", "backtrack", "soc", "relaxed",
    "watchdog" or "failed"."""

    alpha: float
    point: Point | None
    trials: int
    mode: str


class Direction(NamedTuple):
    """A step s = (dX, dU) from pt with the merit's value phi0 there and directional derivative D."""

    pt: Point
    dX: np.ndarray
    dU: np.ndarray
    phi0: float
    D: float


def line_search(options, problem, direction, merit: Callable[[Point, float], float], watch, *, relaxed_ok=True,
                soc: Callable[[Point], Any] | None = None, d_tol=0.0, backtrack_uphill=True,
                complete: Callable[[Point], None] | None = None,
                untrusted: Callable[[float], bool] | None = None, stop_untrusted=False) -> SearchResult:
    """Armijo backtracking on the merit function ``merit(point, alpha)`` along ``direction`` (alpha:
    the step length that reached the point; the augmented Lagrangian's multipliers move with it). With the
    watchdog enabled, no watch active and ``relaxed_ok``, a full step that fails the Armijo test
    is still taken ("relaxed"); while a watch is active (and not expired) so is the full step
    ("watchdog"). Along a direction that is no descent direction (D >= 0) only the full step is
    tried unless ``backtrack_uphill`` (quasi-Newton Hessians, where D >= 0 only comes from an
    inexact QP solution and no Hessian shift is available). ``soc(trial point)`` -> corrected
    step (dX, dU) or None: when the full step along a descent direction fails the Armijo test,
    the second-order correction is tried once, and accepted if it meets the Armijo test of the
    full step (mode "soc").

    Safeguards (docs/structure-exploiting-sqp.md): a trial point where the problem returns
    non-finite values (NonFiniteEvaluationError) counts as a failed trial, and so does a point
    that would be accepted but whose derivatives are non-finite (``complete(point)`` evaluates
    them, and the Hessian, before the point is returned); a full step whose merit value
    ``untrusted(phi)`` calls untrustworthy is never taken as a relaxed or watchdog step -- with
    ``stop_untrusted`` the search ends there (mode "untrusted", no point: the caller solves the
    QP again with a regularized Hessian), else it backtracks."""
    o = options
    pt, dX, dU, phi0, D = direction
    alpha, trials = 1.0, 0
    # merit changes below the rounding level of phi (or d_tol, what the optimality tolerance
    # resolves along the step) are not distinguished
    noise = max(10.0 * np.finfo(float).eps * max(1.0, abs(phi0)), d_tol)

    def done(cand, mode):
        """``cand`` completed (derivatives) as the accepted point, or None when they are non-finite."""
        if complete is None:
            return SearchResult(alpha, cand, trials, mode)
        try:
            complete(cand)
        except NonFiniteEvaluationError:
            return None
        return SearchResult(alpha, cand, trials, mode)

    while alpha >= o.min_step:
        trials += 1
        X = pt.X + alpha * dX
        U = pt.U + alpha * dU
        try:
            cand = Point(problem, X, U, derivatives=False, clock=pt.clock)
            phi = merit(cand, alpha)
        except NonFiniteEvaluationError:  # non-finite values at the trial point: shorten the step
            phi = math.inf
            cand = None
        if cand is not None and phi <= phi0 + o.armijo * alpha * D + noise:
            found = done(cand, "full" if alpha == 1.0 else "backtrack")
            if found is not None:
                return found
            cand = None
        if alpha == 1.0 and cand is not None and soc is not None and D < -noise:
            corr = soc(cand)
            if corr is not None:
                trials += 1
                try:
                    ccand = Point(problem, pt.X + corr[0], pt.U + corr[1], derivatives=False, clock=pt.clock)
                    if merit(ccand, 1.0) <= phi0 + o.armijo * D + noise:
                        found = done(ccand, "soc")
                        if found is not None:
                            return found
                except NonFiniteEvaluationError:  # non-finite values at the corrected point
                    pass
        trusted = cand is not None and math.isfinite(phi) and (untrusted is None or not untrusted(phi))
        if alpha == 1.0 and cand is not None and not trusted and stop_untrusted:
            return SearchResult(alpha, None, trials, "untrusted")
        if alpha == 1.0 and trusted and o.watchdog and watch is None and relaxed_ok:
            found = done(cand, "relaxed")
            if found is not None:
                return found
        if watch is not None and alpha == 1.0 and trusted and not watch.expired:
            found = done(cand, "watchdog")
            if found is not None:
                return found
        if D >= -noise and not backtrack_uphill:
            break
        alpha *= o.backtrack
    return SearchResult(alpha, None, trials, "failed")
