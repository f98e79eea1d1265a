"""The step-size rule shared by the control-space descent methods: a strong Wolfe line search.

Given phi(a) = J(u + a d) with phi'(0) < 0, find a step a > 0 with

    sufficient decrease   phi(a) <= phi(0) + c1 a phi'(0)                              (W1)
    curvature (strong)    |phi'(a)| <= c2 |phi'(0)|,       0 < c1 < c2 < 1.            (W2)

Algorithm: bracketing phase then zoom phase of Nocedal & Wright, *Numerical Optimization*
(2nd ed. 2006), Algorithms 3.5 and 3.6. Trial steps inside the bracket are the minimizer of the
cubic through both ends when both slopes are known (N&W eq. (3.59)), else of the quadratic
through (lo, phi(lo), phi'(lo)) and (hi, phi(hi)); they are safeguarded to the middle 80% of the
bracket (bisection otherwise). A trial point where J is not finite, or where the problem raises a
"non-finite" evaluation error, counts as "too long" (it becomes the upper end of the bracket).

Near a minimizer phi(a) - phi(0) is at the level of rounding and (W1) can fail for every a
although the step is good. As in Hager & Zhang (SIAM J. Optim. 16, 2005, sec. 4, "approximate
Wolfe conditions"), (W1) is then replaced by

    phi(a) <= phi(0) + eps_f   and   phi'(a) <= (2 c1 - 1) phi'(0),    eps_f = 1e-12 (1 + |phi(0)|),

which is (W1) for a quadratic and is decidable in floating point. Derivatives phi'(a) are only
asked for where they are needed (a trial that fails (W1) on its value costs one J evaluation).

The theory (N&W Theorem 3.2, Zoutendijk): with (W1)-(W2) and descent directions whose angle with
-grad J stays away from 90 degrees, grad J -> 0. The Fletcher-Reeves method with (W1)-(W2) and
c2 < 1/2 produces descent directions and converges (Al-Baali, IMA J. Numer. Anal. 5, 1985);
BFGS needs (W2) for s.y > 0.
"""

from __future__ import annotations

import dataclasses
import math

_EPS = 2.220446049250313e-16


@dataclasses.dataclass
class LineSearchResult:
    """The step taken. ``success``: (W1)-(W2) hold; ``decrease``: at least (W1) holds, so the step
    may still be taken; ``n_value``/``n_derivative``: evaluations spent."""

    alpha: float
    value: float
    derivative: float | None
    success: bool
    decrease: bool
    message: str
    n_value: int = 0
    n_derivative: int = 0


def _cubic_min(a, fa, da, b, fb, db):
    """Minimizer of the cubic interpolating (a, fa, da), (b, fb, db); None if it has none."""
    d1 = da + db - 3.0 * (fa - fb) / (a - b)
    disc = d1 * d1 - da * db
    if not math.isfinite(disc) or disc < 0.0:
        return None
    d2 = math.copysign(math.sqrt(disc), b - a)
    den = db - da + 2.0 * d2
    if den == 0.0:
        return None
    t = b - (b - a) * (db + d2 - d1) / den
    return t if math.isfinite(t) else None


def _quadratic_min(a, fa, da, b, fb):
    """Minimizer of the quadratic through (a, fa) with slope da and (b, fb); None if not convex."""
    h = b - a
    curv = fb - fa - da * h
    if not math.isfinite(curv) or curv <= 0.0:
        return None
    t = a - da * h * h / (2.0 * curv)
    return t if math.isfinite(t) else None


def strong_wolfe(value, derivative, f0, d0, alpha_init, *, c1=1e-4, c2=0.9, alpha_max=1e10,
                 max_evaluations=40) -> LineSearchResult:
    """Strong Wolfe line search (module docstring).

    ``value(a)`` returns phi(a) (may be inf/nan for a failed evaluation); ``derivative(a)`` returns
    phi'(a) for an ``a`` whose value was computed before. ``f0 = phi(0)``, ``d0 = phi'(0) < 0``."""
    if not (d0 < 0.0 and math.isfinite(d0)):
        return LineSearchResult(0.0, f0, d0, False, False, f"not a descent direction (phi'(0) = {d0:.3e})")
    if not (0.0 < c1 < c2 < 1.0):
        raise ValueError(f"need 0 < c1 < c2 < 1, got c1={c1}, c2={c2}")
    eps_f = 1e-12 * (1.0 + abs(f0))
    counts = {"v": 0, "d": 0}
    known_d = {}

    def phi(a):
        counts["v"] += 1
        f = value(a)
        return f if (f is not None and math.isfinite(f)) else math.inf

    def dphi(a):
        if a not in known_d:
            counts["d"] += 1
            known_d[a] = float(derivative(a))
        return known_d[a]

    def flat(f):
        """phi(a) equals phi(0) to within rounding: compare slopes, not values."""
        return abs(f - f0) <= eps_f

    def decrease(a, f):
        """(W1), or its approximate form near the minimizer (module docstring)."""
        if f <= f0 + c1 * a * d0:
            return True
        if flat(f):
            return dphi(a) <= (2.0 * c1 - 1.0) * d0
        return False

    def curvature(a):
        return abs(dphi(a)) <= -c2 * d0

    def done(a, f, ok, msg):
        return LineSearchResult(a, f, known_d.get(a), ok, True, msg, counts["v"], counts["d"])

    def zoom(lo, flo, dlo, hi, fhi, dhi):
        """N&W Algorithm 3.6: lo satisfies (W1) and has the lowest value so far; the bracket
        [lo, hi] (either order) contains steps satisfying (W1)-(W2). Where the values are flat
        (rounding level) the bracket is updated by the sign of phi' and the trial step is the
        secant zero of phi'."""
        while counts["v"] < max_evaluations:
            width = abs(hi - lo)
            if width <= 4 * _EPS * max(abs(lo), abs(hi)):
                break
            t = None
            if math.isfinite(fhi):
                if flat(flo) and flat(fhi):
                    if dhi is not None and dhi != dlo:
                        t = lo - dlo * (hi - lo) / (dhi - dlo)
                else:
                    if dhi is not None:
                        t = _cubic_min(lo, flo, dlo, hi, fhi, dhi)
                    if t is None:
                        t = _quadratic_min(lo, flo, dlo, hi, fhi)
            left, right = min(lo, hi), max(lo, hi)
            if t is None or not (left + 0.1 * width <= t <= right - 0.1 * width):
                t = 0.5 * (lo + hi)
            f = phi(t)
            if flat(f) and math.isfinite(f):
                dt = dphi(t)
                if decrease(t, f) and curvature(t):
                    return done(t, f, True, "strong Wolfe conditions met (approximate, at rounding level)")
                if dt * (hi - lo) >= 0.0:
                    hi, fhi, dhi = t, f, dt
                else:
                    lo, flo, dlo = t, f, dt
            elif not decrease(t, f) or f >= flo:
                hi, fhi, dhi = t, f, known_d.get(t)
            else:
                if curvature(t):
                    return done(t, f, True, "strong Wolfe conditions met")
                dt = dphi(t)
                if dt * (hi - lo) >= 0.0:
                    hi, fhi, dhi = lo, flo, dlo
                lo, flo, dlo = t, f, dt
        if lo > 0.0 and (flo < f0 or decrease(lo, flo)):
            return done(lo, flo, False, "line search: sufficient decrease only (bracket exhausted)")
        return LineSearchResult(0.0, f0, d0, False, False,
                                f"line search failed: no decrease after {counts['v']} evaluations "
                                f"(bracket width {abs(hi - lo):.2e})", counts["v"], counts["d"])

    a_prev, f_prev, d_prev = 0.0, f0, d0
    a = min(max(alpha_init, 0.0), alpha_max) if math.isfinite(alpha_init) and alpha_init > 0 else min(1.0, alpha_max)
    first = True
    while counts["v"] < max_evaluations:
        f = phi(a)
        if not decrease(a, f) or (not first and f >= f_prev and not (flat(f) and flat(f_prev))):
            return zoom(a_prev, f_prev, d_prev, a, f, known_d.get(a))
        if curvature(a):
            return done(a, f, True, "strong Wolfe conditions met")
        da = dphi(a)
        if da >= 0.0:
            return zoom(a, f, da, a_prev, f_prev, d_prev)
        if a >= alpha_max:
            return done(a, f, False, f"line search: step reached alpha_max = {alpha_max:g} (unbounded below?)")
        a_prev, f_prev, d_prev = a, f, da
        a = min(4.0 * a, alpha_max)
        first = False
    if a_prev > 0.0:
        return done(a_prev, f_prev, False, "line search: sufficient decrease only (evaluation limit)")
    return LineSearchResult(0.0, f0, d0, False, False, f"line search failed after {counts['v']} evaluations",
                            counts["v"], counts["d"])
