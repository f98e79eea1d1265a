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
  output dimension j is larger than 1 (olado.solvers.sqp.kernels.einsum_sequential); the
  callers take the numpy form otherwise.

tests/solvers/test_certificate_fastpath.py and tests/solvers/test_certificate_kernels.py keep
the numpy forms as the reference, bit for bit. Imported with the certificate (on the first
success), not with olado. The kernels call only kernels of this file and numpy's pairwise
summation (olado.linalg.numpy_sums, whose algorithm is fixed: numba's cache is per source file,
docs/architecture.md "Caches", so a change there must clear this file's cache).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..linalg.numpy_sums import pairwise_sum

_JIT = {"cache": True, "error_model": "numpy"}   # x / 0 is inf or NaN, as in numpy


@nb.njit(inline="always")
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
@nb.njit(inline="always")
def _choice(r, y, lo, hi, w):
    """(stationarity, complementarity) of one variable after the bound choice (the certificate's
    module docstring, step 2; _BoundSides.choice of before): z = |r| w / (w + s) on the side a
    bound at finite slack s can cancel r, 0 on a fixed variable."""
    if lo == hi:
        return 0.0, 0.0
    gl = _maximum(y - lo, 0.0)
    gu = _maximum(hi - y, 0.0)
    if r > 0:
        bounded = np.isfinite(gl)
        slack = gl if bounded else 0.0
    else:
        bounded = np.isfinite(gu)
        slack = gu if bounded else 0.0
    a = abs(r)
    z = a * w / (w + slack) if bounded else 0.0
    return a - z, z * slack


@nb.njit(**_JIT)
def bound_figures(rx, ru, X, U, xl, xu, ul, uu, wx, wu, S, out, at):
    """The bound choice of every variable (x^0 fixed: 0) and the largest figures:
    out = [stationarity (Python max of the x and u parts' numpy max with initial 0), largest
    scaled stationarity, largest complementarity of the bounds], at = [array of the scaled one
    (0 x, 1 u, -1 none), stage, component, array of the complementarity (0 x bounds, 1 u bounds,
    -1 none), stage, component]; largest as the certificate's _largest: the first array whose
    maximum (NaN: skipped) exceeds the best so far (from -1), its first largest entry."""
    N1, n = rx.shape
    m = ru.shape[1]
    best_s, best_c = -1.0, -1.0
    at[0] = -1
    at[1] = 0
    at[2] = 0
    at[3] = -1
    at[4] = 0
    at[5] = 0
    stat = 0.0
    for part in range(2):
        K, k_ = (N1, n) if part == 0 else (ru.shape[0], m)
        smax, cmax, st0 = -np.inf, -np.inf, 0.0
        snan, cnan = False, False
        sk, si, ck, ci = 0, 0, 0, 0
        for k in range(K):
            for i in range(k_):
                if part == 0:
                    if k == 0:
                        st, cp, w = 0.0, 0.0, wx[0, i]
                    else:
                        st, cp = _choice(rx[k, i], X[k, i], xl[k, i], xu[k, i], wx[k, i])
                        w = wx[k, i]
                else:
                    st, cp = _choice(ru[k, i], U[k, i], ul[k, i], uu[k, i], wu[k, i])
                    w = wu[k, i]
                sc = st * w / S
                # numpy max with NaN propagation (stationarity), first largest (argmax)
                if st0 == st0 and (st != st or st > st0):
                    st0 = st
                if sc != sc:
                    snan = True
                elif sc > smax:
                    smax, sk, si = sc, k, i
                if cp != cp:
                    cnan = True
                elif cp > cmax:
                    cmax, ck, ci = cp, k, i
        if K * k_:
            if not snan and smax > best_s:
                best_s = smax
                at[0], at[1], at[2] = part, sk, si
            if not cnan and cmax > best_c:
                best_c = cmax
                at[3], at[4], at[5] = part, ck, ci
        if part == 0:
            stat = st0
        elif st0 > stat:                # Python's max(x part, u part)
            stat = st0
    out[0] = stat
    out[1] = best_s
    out[2] = best_c


# ---------------------------------------------------------------------------- violation [6]
@nb.njit(inline="always")
def _take(v, k, i, top, tk, ti):
    """Running max / argmax of a violation array with NaN counted as infinite (the first largest
    entry)."""
    if v != v:
        v = np.inf
    if v > top:
        return v, k, i, True
    return top, tk, ti, False


@nb.njit(**_JIT)
def largest_violations(h, X, x0, xl, xu, U, ul, uu, out, at):
    """The largest entry (value, stage, component; for the bounds whether the upper side is the
    larger) of |h|, |x^0 - x0|, the x bounds' violations (x^0's row 0) and the u bounds',
    each as olado.solvers.diagnosis.largest_violation_of reads them: out[a] the array's max
    (NaN as inf; -1 when empty), at[a] = (k, i, upper)."""
    for a in range(4):
        top, tk, ti, upper = -1.0, 0, 0, 0
        if a == 0:
            for k in range(h.shape[0]):
                for i in range(h.shape[1]):
                    top, tk, ti, new = _take(abs(h[k, i]), k, i, top, tk, ti)
        elif a == 1:
            for i in range(X.shape[1]):
                top, tk, ti, new = _take(abs(X[0, i] - x0[i]), 0, i, top, tk, ti)
        else:
            Y, lo, hi = (X, xl, xu) if a == 2 else (U, ul, uu)
            for k in range(Y.shape[0]):
                for i in range(Y.shape[1]):
                    below, above = lo[k, i] - Y[k, i], Y[k, i] - hi[k, i]
                    v = _maximum(_maximum(below, 0.0), _maximum(above, 0.0))
                    if a == 2 and k == 0:
                        v = 0.0
                    top, tk, ti, new = _take(v, k, i, top, tk, ti)
                    if new:
                        upper = 1 if above > below else 0
        out[a] = top
        at[a, 0], at[a, 1], at[a, 2] = tk, ti, upper


# ---------------------------------------------------------------------------- spot check (step 4)
@nb.njit(**_JIT)
def directions(draw, X, U, xl, xu, ul, uu, wx, wu, h, Vx, Vu):
    """The spot check's directions from the uniform draws (D, (N+1) n + N m), x before u: the
    draw times max(1, |y_i|), 0 on x^0 and where a step of 2h |v_i| leaves the bounds
    (the certificate's _directions of before, one pass)."""
    D = draw.shape[0]
    N1, n = X.shape
    N, m = U.shape
    h2 = 2 * h
    for d in range(D):
        for k in range(N1):
            for i in range(n):
                v = draw[d, k * n + i] * wx[k, i]
                if k == 0:
                    v = 0.0
                y, a = X[k, i], h2 * abs(v)
                Vx[d, k, i] = 0.0 if (y - a < xl[k, i]) or (y + a > xu[k, i]) else v
        off = N1 * n
        for k in range(N):
            for i in range(m):
                v = draw[d, off + k * m + i] * wu[k, i]
                y, a = U[k, i], h2 * abs(v)
                Vu[d, k, i] = 0.0 if (y - a < ul[k, i]) or (y + a > uu[k, i]) else v


@nb.njit(**_JIT)
def shifted_points(X, U, Vx, Vu, steps, Xs, Us, ends):
    """The points y + (s h) v of every direction and shift s h (``steps``), their stage rows
    stacked (direction, shift, stage) in Xs (P N, n), Us (P N, m) and their final states in
    ends (P, n)."""
    D = Vx.shape[0]
    N1, n = X.shape
    N, m = U.shape
    S = steps.shape[0]
    for d in range(D):
        for s in range(S):
            p = d * S + s
            t = steps[s]
            for k in range(N):
                for i in range(n):
                    Xs[p * N + k, i] = X[k, i] + t * Vx[d, k, i]
                for i in range(m):
                    Us[p * N + k, i] = U[k, i] + t * Vu[d, k, i]
            for i in range(n):
                ends[p, i] = X[N, i] + t * Vx[d, N, i]


@nb.njit(inline="always")
def _spot_terms(vals, an, size, d, j, h, eps, rtol):
    """The five-point formulas of one entry: (d5, err, rel, allowed, rounding)."""
    v1, m1, v2, m2 = vals[d, 0, j], vals[d, 1, j], vals[d, 2, j], vals[d, 3, j]
    d_h = (v1 - m1) / (2 * h)
    d_2h = (v2 - m2) / (4 * h)
    d5 = (4 * d_h - d_2h) / 3
    rounding = eps * (((abs(v1) + abs(m1)) + abs(v2)) + abs(m2)) / h
    scale = _maximum(size[d, j], abs(d5))
    allowed = rtol * scale + 10 * (abs(d_h - d_2h) + rounding) + 1e-300
    err = abs(d5 - an[d, j])
    rel = err / _maximum(scale, 1e-300)
    return d5, err, rel, allowed, rounding


@nb.njit(**_JIT)
def spot_verdict(vals, an, size, h, eps, rtol, out):
    """The spot check's figures from the values at the shifted points (D, 4, L: shifts 1, -1, 2,
    -2) and the supplied derivatives ``an`` and term sizes (D, L): out = [worst relative error
    (Python max(0, the numpy max of rel where err > 10 rounding)), flat index j of the largest
    ratio err / allowed (numpy argmax), that ratio, d5, an and rel at j]."""
    D, _, L = vals.shape
    worst, wnan = -np.inf, False
    best, jbest, rnan = -np.inf, -1, False
    for d in range(D):
        for j in range(L):
            d5, err, rel, allowed, rounding = _spot_terms(vals, an, size, d, j, h, eps, rtol)
            w = rel if err > 10 * rounding else 0.0
            if w != w:
                wnan = True
            elif w > worst:
                worst = w
            ratio = err / allowed
            if not rnan:
                if ratio != ratio:
                    rnan, best, jbest = True, ratio, d * L + j
                elif jbest < 0 or ratio > best:
                    best, jbest = ratio, d * L + j
    out[0] = worst if (not wnan and worst > 0.0) else 0.0
    out[1] = jbest
    out[2] = best
    d5, err, rel, allowed, rounding = _spot_terms(vals, an, size, jbest // L, jbest % L, h, eps, rtol)
    out[3] = d5
    out[4] = an[jbest // L, jbest % L]
    out[5] = rel


# ---------------------------------------------------------------------------- the Result's KKT quantities
@nb.njit(inline="always")
def _pymax(a, b):
    """Python's max(a, b) of two floats: b only when b > a."""
    return b if b > a else a


@nb.njit(inline="always")
def _fill(r, lo, hi, zl, zu):
    """olado.solvers.sqp.residuals._fill_fixed of one variable: a fixed one (lo == hi) takes
    z_L = max(r, 0), z_U = max(-r, 0)."""
    if lo == hi:
        return _maximum(r, 0.0), _maximum(-r, 0.0)
    return zl, zu


@nb.njit(inline="always")
def _row_max(c, shift, res, nan):
    """Running numpy max of np.maximum(c - shift, 0.0) (NaN propagated: ``nan``)."""
    v = _maximum(c - shift, 0.0)
    if v != v:
        return res, True
    return (v if v > res else res), nan


@nb.njit(**_JIT)
def stage_kkt(rx, ru, X, U, xl, xu, ul, uu, zl_x, zu_x, zl_u, zu_u, h, g, eq, gN, eqN, fx_l, fx_u, fu_l, fu_u, out):
    """olado.solvers.sqp.residuals.stage_kkt_reference's stationarity and violation in one pass:
    the bound multipliers with the fixed variables filled in (fx_l, fx_u, fu_l, fu_u), out[0] =
    the stationarity max(numpy max |r - z_L + z_U| of x, of u; initial 0), out[1] = the
    violation: Python's max over the arrays h, g, gN (numpy max of max(0 - c, 0) and of
    max(c - cu, 0), cu = 0 on h and the equality rows, inf elsewhere; an array with a NaN adds
    nothing) and the bounds (lo - y, y - hi likewise, initial 0)."""
    stat = 0.0
    for part in range(2):
        r, Y, lo, hi, zl, zu, ol, ou = ((rx, X, xl, xu, zl_x, zu_x, fx_l, fx_u) if part == 0
                                        else (ru, U, ul, uu, zl_u, zu_u, fu_l, fu_u))
        res = 0.0
        for k in range(r.shape[0]):
            for i in range(r.shape[1]):
                a, b = _fill(r[k, i], lo[k, i], hi[k, i], zl[k, i], zu[k, i])
                ol[k, i], ou[k, i] = a, b
                v = abs(r[k, i] - a + b)
                if res == res and (v != v or v > res):
                    res = v
        stat = res if part == 0 else _pymax(stat, res)
    out[0] = stat
    viol = 0.0
    for arr in range(3):
        lo_max, hi_max, lo_nan, hi_nan = -np.inf, -np.inf, False, False
        size = h.size if arr == 0 else (g.size if arr == 1 else gN.size)
        if arr == 0:
            for k in range(h.shape[0]):
                for i in range(h.shape[1]):
                    lo_max, lo_nan = _row_max(0.0 - h[k, i], 0.0, lo_max, lo_nan)
                    hi_max, hi_nan = _row_max(h[k, i], 0.0, hi_max, hi_nan)
        elif arr == 1:
            for k in range(g.shape[0]):
                for i in range(g.shape[1]):
                    lo_max, lo_nan = _row_max(0.0 - g[k, i], 0.0, lo_max, lo_nan)
                    hi_max, hi_nan = _row_max(g[k, i], 0.0 if eq[i] else np.inf, hi_max, hi_nan)
        else:
            for i in range(gN.shape[0]):
                lo_max, lo_nan = _row_max(0.0 - gN[i], 0.0, lo_max, lo_nan)
                hi_max, hi_nan = _row_max(gN[i], 0.0 if eqN[i] else np.inf, hi_max, hi_nan)
        if size:
            if not lo_nan:
                viol = _pymax(viol, lo_max)
            if not hi_nan:
                viol = _pymax(viol, hi_max)
    for part in range(2):
        Y, lo, hi = (X, xl, xu) if part == 0 else (U, ul, uu)
        lo_max, hi_max, lo_nan, hi_nan = 0.0, 0.0, False, False
        for k in range(Y.shape[0]):
            for i in range(Y.shape[1]):
                lo_max, lo_nan = _row_max(lo[k, i], Y[k, i], lo_max, lo_nan)
                hi_max, hi_nan = _row_max(Y[k, i], hi[k, i], hi_max, hi_nan)
        if not lo_nan:
            viol = _pymax(viol, lo_max)
        if not hi_nan:
            viol = _pymax(viol, hi_max)
    out[1] = viol


@nb.njit(**_JIT)
def stage_cost_directional(lx, lu, Vx, Vu, an, size):
    """The stage costs' part of the certificate's _directional: an[d, k] = (lx * vx).sum(axis=2) +
    (lu * vu).sum(axis=2) and size[d, k] the same of the absolute values (vx = Vx[:, :-1]), each
    sum numpy's pairwise summation of the products (olado.linalg.numpy_sums)."""
    D = Vx.shape[0]
    N, n = lx.shape
    m = lu.shape[1]
    tx, tu = np.empty(n), np.empty(m)
    ax, au = np.empty(n), np.empty(m)
    for d in range(D):
        for k in range(N):
            for j in range(n):
                tx[j] = lx[k, j] * Vx[d, k, j]
                ax[j] = abs(lx[k, j]) * abs(Vx[d, k, j])
            for j in range(m):
                tu[j] = lu[k, j] * Vu[d, k, j]
                au[j] = abs(lu[k, j]) * abs(Vu[d, k, j])
            an[d, k] = pairwise_sum(tx, 0, n, False) + pairwise_sum(tu, 0, m, False)
            size[d, k] = pairwise_sum(ax, 0, n, False) + pairwise_sum(au, 0, m, False)
