"""Compiled passes of olado's certificate (olado.solvers.certificate, docs/certificate.md) and of
the stage-wise KKT quantities every result carries (olado.solvers.sqp.residuals.stage_kkt): the
Lagrangian gradient per stage, the bound choice and the largest residuals of the KKT figures, the
largest violation of the bounds and the dynamics, the spot check's directions, its shifted
points and its five-point formulas.

At small N these are some hundred numpy operations on arrays of a few hundred entries, about
half of the fixed cost of a certified solve (benchmarks/RESULTS.md, "The certificate's and
Solver.solve's fixed cost per solve"). Each kernel computes the numpy expressions it replaces
operation by operation and in the same order (IEEE operations are exactly rounded, and numba
contracts no multiply-add without fastmath), so the certificate's figures are the same bits:

* ``np.maximum(a, b)`` returns a NaN operand, else ``a if a > b else b`` (numpy returns the second
  operand of two equal ones: np.maximum(-0.0, 0.0) is +0.0): :func:`_maximum`;
* ``a.max()`` propagates a NaN, ``a.argmax()`` returns the first NaN, else the first largest entry;
  Python's ``max(x, y)`` returns y only when y > x;
* ``np.einsum("kij,ki->kj", M, v)`` sums each output entry over i from 0 in order when every
  output dimension j is larger than 1 (olado.solvers.common.einsum_sequential); the
  callers take the numpy form otherwise.

tests/solvers/test_certificate_fastpath.py and tests/solvers/test_certificate_kernels.py keep
the numpy forms as the reference, bit for bit. Imported with the certificate (on the first
success), not with olado. The kernels call only functions of this file (numba's cache is per
source file, docs/architecture.md "Caches"); they are few: each compiled function costs the
first solve on a machine a fraction of a second (benchmarks/RESULTS.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_JIT = {"cache": True, "error_model": "numpy"}   # x / 0 is inf or NaN, as in numpy


@nb.njit(**_JIT)
def _maximum(a, b):
    """np.maximum(a, b) of two floats: a NaN operand, else b unless a > b."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a > b else b


# ---------------------------------------------------------------------------- Lagrangian gradient
@nb.njit(**_JIT)
def gradient_terms(lx, lu, lN, A, B, Cx, Cu, lam, Lg, rx, ru):
    """rx, ru of olado.solvers.common.stage_gradient_terms with sigma = 1 and without the final
    rows' term (the caller adds CN^T LgN in numpy): grad J + Jc^T lam per stage, each einsum
    entry summed over i from 0 in order, the terms added in the numpy form's order."""
    N, n = lx.shape
    m = lu.shape[1]
    r = Cx.shape[1]
    for k in range(N):
        for j in range(n):
            s = 0.0
            for i in range(n):
                s += A[k, i, j] * lam[k, i]
            v = lx[k, j] + s
            if k >= 1:
                v = v - lam[k - 1, j]
            if r:
                s = 0.0
                for i in range(r):
                    s += Cx[k, i, j] * Lg[k, i]
                v = v + s
            rx[k, j] = v
        for j in range(m):
            s = 0.0
            for i in range(n):
                s += B[k, i, j] * lam[k, i]
            v = lu[k, j] + s
            if r:
                s = 0.0
                for i in range(r):
                    s += Cu[k, i, j] * Lg[k, i]
                v = v + s
            ru[k, j] = v
    for j in range(n):
        rx[N, j] = lN[j] - lam[N - 1, j]


# ---------------------------------------------------------------------------- KKT figures (step 2)
@nb.njit(**_JIT)
def bound_figures(r, Y, lo, hi, w, S, first, res):
    """The bound choice of the variables of one array (the certificate's module docstring, step 2:
    z = |r| w / (w + s) on the side a bound at finite slack s can cancel r, nothing on a fixed
    variable (lo == hi) and on rows before ``first``) and its largest figures: res = [numpy max
    of the stationarity (initial 0), max of the scaled stationarity, its stage, component, max of
    the complementarity, its stage, component] (first largest; a NaN max is NaN)."""
    st0, smax, cmax = 0.0, -np.inf, -np.inf
    sk = si = ck = ci = 0
    for k in range(r.shape[0]):
        for i in range(r.shape[1]):
            w_ = w[k, i]
            st = cp = 0.0
            if k >= first and lo[k, i] != hi[k, i]:
                y = Y[k, i]
                if r[k, i] > 0:
                    s = _maximum(y - lo[k, i], 0.0)
                else:
                    s = _maximum(hi[k, i] - y, 0.0)
                bounded = np.isfinite(s)
                slack = s if bounded else 0.0
                a = abs(r[k, i])
                z = a * w_ / (w_ + slack) if bounded else 0.0
                st, cp = a - z, z * slack
            if st0 == st0 and (st != st or st > st0):
                st0 = st
            sc = st * w_ / S
            if smax == smax and (sc != sc or sc > smax):
                smax, sk, si = sc, k, i
            if cmax == cmax and (cp != cp or cp > cmax):
                cmax, ck, ci = cp, k, i
    res[0], res[1], res[2], res[3], res[4], res[5], res[6] = st0, smax, sk, si, cmax, ck, ci


# ---------------------------------------------------------------------------- violation [6]
@nb.njit(**_JIT)
def largest_violation(Y, lo, hi, first, res):
    """The largest violation max(max(lo - y, 0), max(y - hi, 0)) of one array (rows before
    ``first``: 0; with lo = hi = 0 it is |y|, bit for bit), NaN counted as inf, at its first
    largest entry, and whether the upper side is the larger there: res = [value (-1 when empty),
    stage, component, upper] (olado.solvers.diagnosis.largest_violation_of)."""
    top, tk, ti, upper = -1.0, 0, 0, 0.0
    for k in range(Y.shape[0]):
        for i in range(Y.shape[1]):
            below, above = lo[k, i] - Y[k, i], Y[k, i] - hi[k, i]
            v = _maximum(_maximum(below, 0.0), _maximum(above, 0.0))
            if k < first:
                v = 0.0
            if v != v:
                v = np.inf
            if v > top:
                top, tk, ti, upper = v, k, i, 1.0 if above > below else 0.0
    res[0], res[1], res[2], res[3] = top, tk, ti, upper


# ---------------------------------------------------------------------------- spot check (step 4)
@nb.njit(**_JIT)
def spot_points(draw, X, U, xl, xu, ul, uu, wx, wu, h, steps, Vx, Vu, Xs, Us, ends):
    """The spot check's directions and shifted points. Directions (Vx (D, N+1, n), Vu (D, N, m))
    from the uniform draws (D, (N+1) n + N m, x before u): the draw times max(1, |y_i|), 0 on x^0
    and where a step of 2h |v_i| leaves the bounds (the certificate's _direction, drawn one by
    one before). Points y + (s h) v for every direction and shift s h (``steps``), their stage
    rows stacked (direction, shift, stage) in Xs (P N, n), Us (P N, m), their final states in
    ends (P, n)."""
    N1, n = X.shape
    N, m = U.shape
    h2 = 2 * h
    for d in range(draw.shape[0]):
        for k in range(N1):
            for i in range(n):
                v = draw[d, k * n + i] * wx[k, i] if k else 0.0
                y, a = X[k, i], h2 * abs(v)
                Vx[d, k, i] = 0.0 if (y - a < xl[k, i]) or (y + a > xu[k, i]) else v
        for k in range(N):
            for i in range(m):
                v = draw[d, N1 * n + k * m + i] * wu[k, i]
                y, a = U[k, i], h2 * abs(v)
                Vu[d, k, i] = 0.0 if (y - a < ul[k, i]) or (y + a > uu[k, i]) else v
        for s in range(steps.shape[0]):
            p = d * steps.shape[0] + s
            t = steps[s]
            for k in range(N):
                for i in range(n):
                    Xs[p * N + k, i] = X[k, i] + t * Vx[d, k, i]
                for i in range(m):
                    Us[p * N + k, i] = U[k, i] + t * Vu[d, k, i]
            for i in range(n):
                ends[p, i] = X[N, i] + t * Vx[d, N, i]


@nb.njit(**_JIT)
def spot_verdict(vals, an, size, h, eps, rtol, out):
    """The spot check's figures from the values at the shifted points (D, 4, L: shifts 1, -1, 2,
    -2) and the supplied derivatives ``an`` and term sizes (D, L), per entry
    d_h = (v1 - m1) / 2h, d_2h = (v2 - m2) / 4h, d5 = (4 d_h - d_2h) / 3,
    rounding = eps (|v1| + |m1| + |v2| + |m2|) / h, scale = max(size, |d5|),
    allowed = rtol scale + 10 (|d_h - d_2h| + rounding) + 1e-300, err = |d5 - an|,
    rel = err / max(scale, 1e-300): out = [worst relative error (Python max(0, the numpy max of rel
    where err > 10 rounding)), flat index j of the largest ratio err / allowed (numpy argmax: the
    first NaN, else the first largest), that ratio, d5, an and rel at j]."""
    D, _, L = vals.shape
    worst, best, jbest = -np.inf, -np.inf, -1
    for d in range(D):
        for j in range(L):
            v1, m1, v2, m2 = vals[d, 0, j], vals[d, 1, j], vals[d, 2, j], vals[d, 3, j]
            d_h = (v1 - m1) / (2 * h)
            d_2h = (v2 - m2) / (4 * h)
            d5 = (4 * d_h - d_2h) / 3
            rounding = eps * (((abs(v1) + abs(m1)) + abs(v2)) + abs(m2)) / h
            scale = _maximum(size[d, j], abs(d5))
            allowed = rtol * scale + 10 * (abs(d_h - d_2h) + rounding) + 1e-300
            err = abs(d5 - an[d, j])
            rel = err / _maximum(scale, 1e-300)
            w = rel if err > 10 * rounding else 0.0
            if worst == worst and (w != w or w > worst):
                worst = w
            ratio = err / allowed
            if jbest < 0 or (best == best and (ratio != ratio or ratio > best)):
                best, jbest = ratio, d * L + j
                out[3], out[4], out[5] = d5, an[d, j], rel
    out[0] = worst if worst > 0.0 else 0.0
    out[1], out[2] = jbest, best


# ---------------------------------------------------------------------------- the Result's KKT quantities
@nb.njit(**_JIT)
def _stationarity_part(r, lo, hi, zl, zu, fl, fu):
    """olado.solvers.sqp.residuals._fill_fixed of one array (a fixed variable, lo == hi, takes
    z_L = max(r, 0), z_U = max(-r, 0)) into fl, fu, and the numpy max of |r - z_L + z_U|
    (initial 0, NaN propagated)."""
    res = 0.0
    for k in range(r.shape[0]):
        for i in range(r.shape[1]):
            a, b = zl[k, i], zu[k, i]
            if lo[k, i] == hi[k, i]:
                a, b = _maximum(r[k, i], 0.0), _maximum(-r[k, i], 0.0)
            fl[k, i], fu[k, i] = a, b
            v = abs(r[k, i] - a + b)
            if res == res and (v != v or v > res):
                res = v
    return res


@nb.njit(**_JIT)
def violation_maxima(lo, y, hi, res):
    """residuals._violation's terms of one array: res = [numpy max of max(lo - y, 0), of
    max(y - hi, 0)] (NaN propagated; -inf when empty). Constraint rows c: lo = 0, y = c, hi = 0
    on equality rows (and the dynamics), +inf on rows c >= 0 (0 - c and c - cu as in numpy)."""
    a, b = -np.inf, -np.inf
    for k in range(y.shape[0]):
        for i in range(y.shape[1]):
            va = _maximum(lo[k, i] - y[k, i], 0.0)
            vb = _maximum(y[k, i] - hi[k, i], 0.0)
            if a == a and (va != va or va > a):
                a = va
            if b == b and (vb != vb or vb > b):
                b = vb
    res[0], res[1] = a, b


@nb.njit(**_JIT)
def stage_kkt(rx, ru, X, U, xl, xu, ul, uu, zl_x, zu_x, zl_u, zu_u, fx_l, fx_u, fu_l, fu_u, out):
    """olado.solvers.sqp.residuals.stage_kkt_reference's stationarity and the bounds' part of its
    violation in one pass: the bound multipliers with the fixed variables filled in (fx_l, fx_u,
    fu_l, fu_u), out[0] = Python's max of the x and u stationarity (:func:`_stationarity_part`),
    out[1:3], out[3:5] the violations of the x and u bounds (:func:`violation_maxima`)."""
    sx = _stationarity_part(rx, xl, xu, zl_x, zu_x, fx_l, fx_u)
    su = _stationarity_part(ru, ul, uu, zl_u, zu_u, fu_l, fu_u)
    out[0] = su if su > sx else sx
    violation_maxima(xl, X, xu, out[1:3])
    violation_maxima(ul, U, uu, out[3:5])
