"""The globalization of FQLNK (seed 002 sec. 3.4): the augmented Lagrangian merit function

    M_rho(v, lam) = L(v, lam) + rho/2 c(v)' c(v)                                        (3.3)

on the full space (the multipliers included), its penalty parameter chosen so that the Newton
step dp = (dv, dlam) is a descent direction (Prudencio, Byrd and Cai 2006, the seed's rule 1):

    rho^(k) = max(rho_bar, rho^(k-1)),   rho_bar = -2 grad L' dp / (c' G dv),

and the step length alpha by backtracking until Armijo's condition (3.4) holds,

    M(p + alpha dp) <= M(p) + alpha beta grad M(p)' dp,

with the seed's quadratic line search (Dennis and Schnabel 1996, sec. 6.3.2: the minimizer of
the quadratic through M(0), M'(0), M(alpha), kept in [0.1 alpha, 0.5 alpha]).

With L = J + lam . c, grad M' dp = grad_v L' dv + c' dlam + rho c' G dv. Where rho cannot make
dp a descent direction (c = 0 or c' G dv >= 0, and grad L' dp >= 0: possible with an indefinite
exact or finite-difference Hessian, never with the positive definite BFGS matrix on the null
space of G), the line search falls back to the residual norm 1/2 ||F||^2, for which an inexact
Newton step is a descent direction whenever eta_k < 1 (Eisenstat and Walker 1994):
d/dalpha 1/2 ||F(p + alpha dp)||^2 at 0 is F' K dp = -||F||^2 + F'(F + K dp) <= (eta - 1) ||F||^2.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple


class Slope(NamedTuple):
    """The merit's penalty parameter and directional derivative along dp, and which merit:
    "augmented-lagrangian" (3.3) or "residual" (the fallback)."""

    rho: float
    derivative: float
    kind: str


def penalty_and_slope(gradL, c, Gdv, dp, rho_prev, F=None, Kdp=None) -> Slope:
    """rho^(k) of the seed's rule 1 and grad M_rho' dp; the residual fallback (module docstring)
    when that is not negative."""
    gL_dp = float(gradL @ dp)
    cGdv = float(c @ Gdv)
    rho = rho_prev
    if cGdv < 0.0:
        rho_bar = -2.0 * gL_dp / cGdv
        rho = max(rho_bar, rho_prev)
    slope = gL_dp + rho * cGdv
    if slope < 0.0 and math.isfinite(slope):
        return Slope(rho, slope, "augmented-lagrangian")
    if F is not None and Kdp is not None:
        return Slope(rho, float(F @ Kdp), "residual")
    return Slope(rho, slope, "augmented-lagrangian")


def quadratic_step(alpha, m0, slope, m_alpha):
    """The next trial of the quadratic line search, in [0.1 alpha, 0.5 alpha]."""
    denom = 2.0 * (m_alpha - m0 - slope * alpha)
    new = -slope * alpha * alpha / denom if denom > 0 and math.isfinite(denom) else 0.5 * alpha
    return min(max(new, 0.1 * alpha), 0.5 * alpha)


class SearchResult(NamedTuple):
    """The accepted step length (None: alpha fell below alpha_min) and the trials taken."""

    alpha: float | None
    trials: int
    value: float


def armijo_backtracking(merit: Callable[[float], float], m0, slope, beta, alpha_min, check=None) -> SearchResult:
    """Backtrack from alpha = 1 until merit(alpha) <= m0 + alpha beta slope (3.4); merit(alpha)
    is inf where the functions are not finite. ``check`` is called before each trial (the
    solve's time limit and interrupts)."""
    alpha, trials = 1.0, 0
    while alpha >= alpha_min:
        if check is not None:
            check()
        trials += 1
        m = merit(alpha)
        if m <= m0 + alpha * beta * slope:
            return SearchResult(alpha, trials, m)
        alpha = quadratic_step(alpha, m0, slope, m) if math.isfinite(m) else 0.1 * alpha
    return SearchResult(None, trials, math.nan)


def augmented_lagrangian(J, lam, c, rho):
    """M_rho (3.3) with olado's L = J + lam . c."""
    return float(J + lam @ c + 0.5 * rho * (c @ c))


def residual_merit(F):
    return 0.5 * float(F @ F)


__all__ = ["Slope", "SearchResult", "penalty_and_slope", "armijo_backtracking", "augmented_lagrangian",
           "residual_merit", "quadratic_step"]
