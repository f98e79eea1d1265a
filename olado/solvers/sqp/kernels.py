"""Compiled passes of the SQP's own per-iteration work (numba): the KKT residual of
:func:`olado.solvers.sqp.residuals.kkt_residual`, the L1 merit function's violations and
weighted sums (:mod:`olado.solvers.sqp.merit`), and the assembly of the QP (8)-(10) in stage form
with the fixed-state bound rule of :func:`olado.solvers.sqp.step.drop_fixed_bounds`.

At small N the SQP's cost outside the QP solver is Python around small arrays (benchmarks/RESULTS.md,
"Small-N overhead outside the kernels"): each of these passes replaces some ten to thirty numpy
operations, a temporary each. The arithmetic is the numpy expressions' own, operation by operation
and in the same order (IEEE operations are exactly rounded, and numba contracts no multiply-add
without fastmath):

* ``np.einsum("kij,ki->kj", M, v)`` accumulates each output entry over i from 0 in order when
  the output dimension j has more than one entry (numpy's contiguous sum-of-products loop runs
  over j); with one entry numpy reduces over i with unrolled partial sums, so the callers use
  olado.solvers.common.einsum_sequential to take these kernels only where the order is the sequential one;
* ``(w * v).sum()`` of a C-contiguous array is numpy's pairwise summation over the flattened
  array (olado.linalg.numpy_sums.pairwise_sum is numpy's algorithm);
* maxima are exact in any order; Python's ``max`` of floats keeps the first of a NaN and a
  number, numpy's ``max`` propagates a NaN: both rules are kept.

Where numpy calls BLAS (a matrix-vector product in the fixed-state rule) the kernel's sequential
sum may differ from it in the last bit; those values are only compared with bounds widened by
``FIXED_BOUND_RTOL`` (1 + |x|). tests/solvers/sqp/test_sqp_kernels.py keeps the numpy forms as the
reference (bit for bit where the order is numpy's). Imported on the first solve, so that
importing olado does not load numba.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...linalg.numpy_sums import pairwise_sum

_JIT = {"cache": True, "error_model": "numpy"}   # x / 0 is inf or NaN, as in numpy


# ---------------------------------------------------------------------------- reductions
@nb.njit(**_JIT)
def npmax_abs(a, res):
    """max(res, max|a|) with numpy's NaN propagation (res is the running value, NaN stays)."""
    for x in a.flat:
        v = abs(x)
        if v != v:
            return v
        if v > res:
            res = v
    return res


@nb.njit(inline="always")
def _pymax(a, b):
    """Python's max(a, b) of two floats: b only when b > a (a NaN a stays, a NaN b is dropped)."""
    return b if b > a else a


@nb.njit(inline="always")
def _maximum0(x):
    """np.maximum(x, 0.0) with its NaN rule (a NaN x is returned); +0.0 for x = 0."""
    if x != x:
        return x
    return x if x > 0.0 else 0.0


@nb.njit(**_JIT)
def _weighted(w, v, tmp):
    """float((w * v).sum()) of two C-contiguous arrays of one shape (tmp: a work vector)."""
    wf = w.ravel()
    vf = v.ravel()
    n = wf.size
    for i in range(n):
        tmp[i] = wf[i] * vf[i]
    return pairwise_sum(tmp, 0, n, False)


@nb.njit(**_JIT)
def gradient_sums(lx, dXs, lu, dU):
    """np.sum(lx * dXs) + np.sum(lu * dU) (C-contiguous arrays), each numpy's pairwise sum."""
    tmp = np.empty(max(lx.size, lu.size))
    return _weighted(lx, dXs, tmp) + _weighted(lu, dU, tmp)


@nb.njit(**_JIT)
def penalty(w0, v0, w1, v1, w2, v2, w3, v3, w4, v4, tmp):
    """sum(float((w * v).sum()) for w, v in zip(weights, violations)) -- Python's sum from the
    integer 0, in order -- for the five parts of the L1 merit function."""
    total = _weighted(w0, v0, tmp)
    total += _weighted(w1, v1, tmp)
    total += _weighted(w2, v2, tmp)
    total += _weighted(w3, v3, tmp)
    total += _weighted(w4, v4, tmp)
    return total


# ---------------------------------------------------------------------------- merit violations
@nb.njit(**_JIT)
def violations(h, g, gN, X, U, eq, eqN, x_lower, x_upper, u_lower, u_upper):
    """(|h|, vg, vgN, vbx, vbu) of Merit._violations: vg = |g| on equality rows, max(-g, 0) on
    the others; the bound violations max(lo - y, 0) + max(y - hi, 0), x^0's zero; and the largest
    entry of each (max with initial 0, numpy's NaN rule) combined by Python's max in order."""
    vh = np.empty_like(h)
    for i in range(h.shape[0]):
        for j in range(h.shape[1]):
            vh[i, j] = abs(h[i, j])
    vg = np.empty_like(g)
    for i in range(g.shape[0]):
        for j in range(g.shape[1]):
            vg[i, j] = abs(g[i, j]) if eq[j] else _maximum0(-g[i, j])
    vgN = np.empty_like(gN)
    for j in range(gN.shape[0]):
        vgN[j] = abs(gN[j]) if eqN[j] else _maximum0(-gN[j])
    vbx = np.empty_like(X)
    for i in range(X.shape[0]):
        for j in range(X.shape[1]):
            vbx[i, j] = 0.0 if i == 0 else (_maximum0(x_lower[i, j] - X[i, j]) + _maximum0(X[i, j] - x_upper[i, j]))
    vbu = np.empty_like(U)
    for i in range(U.shape[0]):
        for j in range(U.shape[1]):
            vbu[i, j] = _maximum0(u_lower[i, j] - U[i, j]) + _maximum0(U[i, j] - u_upper[i, j])
    worst = npmax_abs(vh, 0.0)
    worst = _pymax(worst, npmax_abs(vg, 0.0))
    worst = _pymax(worst, npmax_abs(vgN, 0.0))
    worst = _pymax(worst, npmax_abs(vbx, 0.0))
    worst = _pymax(worst, npmax_abs(vbu, 0.0))
    return vh, vg, vgN, vbx, vbu, worst


# ---------------------------------------------------------------------------- KKT residual
@nb.njit(inline="always")
def _contract(M, v, off, k, j):
    """np.einsum("kij,ki->kj", M, v[off:])[k, j] summed over i in order from 0."""
    s = 0.0
    for i in range(M.shape[1]):
        s += M[k, i, j] * v[k + off, i]
    return s


@nb.njit(**_JIT)
def kkt_residual(lx, lu, gN0, A, B, Cx, Cu, lam, Lg, zl_x, zu_x, zl_u, zu_u, lN):
    """(res, scale) of residuals.kkt_residual: gN0 = lN + CN^T LgN (numpy's, from the caller)."""
    N, n = lx.shape
    m = lu.shape[1]
    res_x = 0.0
    for k in range(N):
        for j in range(n):
            gx = lx[k, j] + _contract(A, lam, 1, k, j)
            gx = gx + _contract(Cx, Lg, 0, k, j)
            if k >= 1:
                gx -= lam[k, j]
                gx = gx - zl_x[k, j]
                gx = gx + zu_x[k, j]
                res_x = _nanmax(res_x, abs(gx))
    res_u = 0.0
    for k in range(N):
        for j in range(m):
            gu = lu[k, j] + _contract(B, lam, 1, k, j)
            gu = gu + _contract(Cu, Lg, 0, k, j)
            gu = gu - zl_u[k, j]
            gu = gu + zu_u[k, j]
            res_u = _nanmax(res_u, abs(gu))
    res_N = 0.0
    for j in range(n):
        gn = gN0[j] - lam[N, j]
        gn = gn - zl_x[N, j]
        gn = gn + zu_x[N, j]
        res_N = _nanmax(res_N, abs(gn))
    res = _pymax(_pymax(res_x, res_u), res_N)
    scale = _pymax(_pymax(npmax_abs(lx, 0.0), npmax_abs(lu, 0.0)), npmax_abs(lN, 0.0))
    return res, scale


# ---------------------------------------------------------------------------- QP assembly
@nb.njit(**_JIT)
def shifted_blocks(Bk, BN, d, n):
    """Q (N+1, n, n), S (N, n, m), R (N, m, m) of Bk + d_k I (and BN + d_N I), each entry
    Bk_ij + d_k * I_ij as numpy's ``Bk + d[:, None, None] * np.eye(n + m)``."""
    N, nz = Bk.shape[0], Bk.shape[1]
    m = nz - n
    Q = np.empty((N + 1, n, n))
    S = np.empty((N, n, m))
    R = np.empty((N, m, m))
    for k in range(N):
        dk = d[k]
        for i in range(nz):
            for j in range(nz):
                v = Bk[k, i, j] + dk * (1.0 if i == j else 0.0)
                if i < n:
                    if j < n:
                        Q[k, i, j] = v
                    else:
                        S[k, i, j - n] = v
                elif j >= n:
                    R[k, i - n, j - n] = v
    dN = d[N]
    for i in range(n):
        for j in range(n):
            Q[N, i, j] = BN[i, j] + dN * (1.0 if i == j else 0.0)
    return Q, S, R


@nb.njit(**_JIT)
def plain_blocks(Bk, BN, n):
    """Q, S, R of the unshifted blocks (copies of Bk's parts and BN)."""
    N, nz = Bk.shape[0], Bk.shape[1]
    m = nz - n
    Q = np.empty((N + 1, n, n))
    S = np.empty((N, n, m))
    R = np.empty((N, m, m))
    for k in range(N):
        for i in range(n):
            for j in range(n):
                Q[k, i, j] = Bk[k, i, j]
            for j in range(m):
                S[k, i, j] = Bk[k, i, n + j]
        for i in range(m):
            for j in range(m):
                R[k, i, j] = Bk[k, n + i, n + j]
    for i in range(n):
        for j in range(n):
            Q[N, i, j] = BN[i, j]
    return Q, S, R


@nb.njit(**_JIT)
def step_vectors(lx, lN, X, U, x0, x_lower, x_upper, u_lower, u_upper):
    """q = [lx; lN], x0 - X_0, the state boxes x_lower - X, x_upper - X (x^0's free) and the
    control boxes u_lower - U, u_upper - U of the QP in the step."""
    N, n = lx.shape
    m = U.shape[1]
    q = np.empty((N + 1, n))
    for k in range(N):
        for j in range(n):
            q[k, j] = lx[k, j]
    for j in range(n):
        q[N, j] = lN[j]
    dx0 = np.empty(n)
    for j in range(n):
        dx0[j] = x0[j] - X[0, j]
    xl = np.empty((N + 1, n))
    xu = np.empty((N + 1, n))
    for k in range(N + 1):
        for j in range(n):
            xl[k, j] = x_lower[k, j] - X[k, j]
            xu[k, j] = x_upper[k, j] - X[k, j]
    for j in range(n):
        xl[0, j] = -np.inf
        xu[0, j] = np.inf
    ul = np.empty((N, m))
    uu = np.empty((N, m))
    for k in range(N):
        for j in range(m):
            ul[k, j] = u_lower[k, j] - U[k, j]
            uu[k, j] = u_upper[k, j] - U[k, j]
    return q, dx0, xl, xu, ul, uu


@nb.njit(**_JIT)
def _fixed_from_here(A, B, k, rows):
    """step._fixed_from_here: rows of B_j zero and rows of A_j touching ``rows`` only, j >= k."""
    N, n, m = B.shape
    for j in range(k, N):
        for i in range(n):
            if not rows[i]:
                continue
            for c in range(m):
                if B[j, i, c] != 0.0:
                    return False
            for c in range(n):
                if not rows[c] and A[j, i, c] != 0.0:
                    return False
    return True


@nb.njit(**_JIT)
def drop_fixed_bounds(A, B, c, x0, xl, xu, EN, eN, X, rtol):
    """step.drop_fixed_bounds with step.fixed_states, in place on xl, xu (x^0's bounds already
    dropped by the caller), slack rtol * (1 + |X|)."""
    N, n, m = B.shape
    fixed = np.zeros((N + 1, n), dtype=np.bool_)
    value = np.zeros((N + 1, n))
    for j in range(n):
        fixed[0, j] = True
        value[0, j] = x0[j]
    tail_tested = False
    rows = np.zeros(n, dtype=np.bool_)
    for k in range(N):
        anyrow = False
        for i in range(n):
            ok = True
            for col in range(m):
                if B[k, i, col] != 0.0:
                    ok = False
                    break
            if ok:
                for col in range(n):
                    if A[k, i, col] != 0.0 and not fixed[k, col]:
                        ok = False
                        break
            rows[i] = ok
            anyrow = anyrow or ok
        if not anyrow:
            break
        for i in range(n):
            fixed[k + 1, i] = rows[i]
            if rows[i]:
                s = 0.0
                for col in range(n):
                    s += A[k, i, col] * (value[k, col] if fixed[k, col] else 0.0)
                value[k + 1, i] = s + c[k, i]
            else:
                value[k + 1, i] = 0.0
        if not tail_tested and k + 2 <= N:
            same = True
            for i in range(n):
                if rows[i] != fixed[k, i]:
                    same = False
            if same:
                tail_tested = True
                if _fixed_from_here(A, B, k + 1, rows):
                    wanted = False
                    for kk in range(k + 2, N + 1):
                        for i in range(n):
                            if rows[i] and (np.isfinite(xl[kk, i]) or np.isfinite(xu[kk, i])):
                                wanted = True
                    stays_zero = True
                    for i in range(n):
                        if rows[i] and value[k + 1, i] != 0.0:
                            stays_zero = False
                    for kk in range(k + 1, N):
                        for i in range(n):
                            if rows[i] and c[kk, i] != 0.0:
                                stays_zero = False
                    if not wanted or stays_zero:
                        for kk in range(k + 2, N + 1):
                            for i in range(n):
                                if rows[i]:
                                    fixed[kk, i] = True
                        break
    for row in range(EN.shape[0]):
        nz = 0
        col = -1
        for i in range(n):
            if EN[row, i] != 0.0:
                nz += 1
                if col < 0:
                    col = i
        if nz == 1 and not fixed[N, col]:
            fixed[N, col] = True
            value[N, col] = -eN[row] / EN[row, col]
    for k in range(1, N + 1):
        for i in range(n):
            if fixed[k, i]:
                slack = rtol * (1.0 + abs(X[k, i]))
                if value[k, i] >= xl[k, i] - slack and value[k, i] <= xu[k, i] + slack:
                    xl[k, i] = -np.inf
                    xu[k, i] = np.inf


# ---------------------------------------------------------------------------- complementarity
@nb.njit(inline="always")
def _nanmax(res, v):
    """The running max of numpy's np.max: a NaN stays."""
    if res != res:
        return res
    if v != v:
        return v
    return v if v > res else res


@nb.njit(**_JIT)
def _bound_parts(y, lb, ub, zl, zu, first, total):
    """common.bound_complementarity's parts (rows from ``first`` on; x^0's bounds are its fixed
    value, no condition) combined into ``total`` by Python's max: |z_L (y - lb)|, the negative
    part of z_L, |z_U (ub - y)|, the negative part of z_U, each over the free variables (lb < ub)
    and for the products with a finite gap only; a part with a NaN is numpy's NaN, which
    Python's max passes over."""
    comp_l = 0.0; sign_l = 0.0; comp_u = 0.0; sign_u = 0.0
    for k in range(first, y.shape[0]):
        for j in range(y.shape[1]):
            if not lb[k, j] < ub[k, j]:
                continue
            gl = y[k, j] - lb[k, j]
            if np.isfinite(gl):
                comp_l = _nanmax(comp_l, abs(zl[k, j] * gl))
            sign_l = _nanmax(sign_l, _maximum0(-zl[k, j]))
            gu = ub[k, j] - y[k, j]
            if np.isfinite(gu):
                comp_u = _nanmax(comp_u, abs(zu[k, j] * gu))
            sign_u = _nanmax(sign_u, _maximum0(-zu[k, j]))
    total = _pymax(total, comp_l)
    total = _pymax(total, sign_l)
    total = _pymax(total, comp_u)
    total = _pymax(total, sign_u)
    return total


@nb.njit(**_JIT)
def _row_parts(lam, g, ineq, total):
    """|lam g| and the positive part of lam over the rows g >= 0 (``ineq``), into ``total``."""
    comp = 0.0
    sign = 0.0
    for k in range(lam.shape[0]):
        for j in range(lam.shape[1]):
            if ineq[j]:
                comp = _nanmax(comp, abs(lam[k, j] * g[k, j]))
                sign = _nanmax(sign, _maximum0(lam[k, j]))
    total = _pymax(total, comp)
    return _pymax(total, sign)


@nb.njit(**_JIT)
def complementarity(X, x_lower, x_upper, U, u_lower, u_upper, zl_x, zu_x, zl_u, zu_u, Lg, g, ineq, LgN, gN, ineqN):
    """residuals.stage_complementarity: the max of the bound parts of X (x^0 fixed) and U and
    the inequality rows' parts of g and g^N."""
    total = _bound_parts(X, x_lower, x_upper, zl_x, zu_x, 1, 0.0)
    total = _bound_parts(U, u_lower, u_upper, zl_u, zu_u, 0, total)
    total = _row_parts(Lg, g, ineq, total)
    comp = 0.0
    sign = 0.0
    for j in range(LgN.shape[0]):
        if ineqN[j]:
            comp = _nanmax(comp, abs(LgN[j] * gN[j]))
            sign = _nanmax(sign, _maximum0(LgN[j]))
    total = _pymax(total, comp)
    return _pymax(total, sign)
