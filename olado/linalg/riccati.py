"""Block Riccati solver for the equality-constrained LQ-DOCP (paper 001 sec. 4.2.3).

Solves the KKT system of the linear-quadratic DOCP

    min  sum_k 1/2 [x_k; u_k]^T [Q_k S_k; S_k^T R_k] [x_k; u_k] + q_k.x_k + r_k.u_k
         + 1/2 x_N^T Q_N x_N + q_N.x_N
    s.t. x_{k+1} = A_k x_k + B_k u_k + c_k,   x_0 = xbar_0,
         E_k x_k + F_k u_k + e_k = 0  (k < N),   E_N x_N + e_N = 0,

i.e. the equality part of QP (14) after the interior-point method has folded its inequalities
into the Hessian (system (25)): the diagonal terms ``Dx`` (N+1, n), ``Du`` (N, m) of simple
bounds and the terms C_k^T diag(sigma_k) C_k of linear stage inequalities are accepted directly.

Algorithm (Arnold's block elimination, an extension of the Riccati recursion to equality
constraints; written here in the constraint-propagating form): going backwards, the cost-to-go
on x_{k+1} is 1/2 x^T P x + p.x restricted to the affine set G_{k+1} x + g_{k+1} = 0. At stage k
the stage equalities and the propagated ones, [F_k; G_{k+1} B_k] u = -([E_k; G_{k+1} A_k] x + d),
are split by a pivoted Householder QR of their u-part: the rank part fixes u in the range of
Q_1, the rest is a pure state constraint G_k x + g_k = 0 passed to stage k-1, and u moves freely
in the null space Q_2 where the reduced Hessian Q_2^T Quu Q_2 must be positive definite (its
Cholesky factor is where a non-positive-definite problem is detected, with the stage index).
The passed-back state rows are compressed before they go on: a state-only row set on x_k has at
most n independent rows, and dependent ones (e.g. every x_k fixed by a row while the dynamics
carry the fixed x_{k+1} back onto x_k as well -- the interior-point QP's fixed states) are
dropped by a rank-revealing (column-pivoted) QR of G_k^T with the same relative rank_tol; the
dropped rows are combinations of the kept ones, so they only impose a consistency condition on
the constants, whose violation (an inconsistent, i.e. infeasible, constraint set) is reported with
the residual of the rows reaching x_0, and they get zero multipliers (their multipliers are not
unique). So at most ne_max + max(n, neN) rows ever reach a stage.
The factorization depends only on the matrices; :meth:`RiccatiFactorization.solve` takes any
number of right-hand sides (q, r, c, e, xbar_0), each in O(N (n+m)^2).

Without any equality rows (the usual interior-point case: only bounds and inequalities, folded
into Dx, Du, C^T diag(sigma) C) a separate plain-Riccati kernel is used: no QR, no propagated
rows, and only P_k, K_k and the Cholesky factor of Q_uu are stored; for small blocks
(n + m <= _FIXED_SIZE_MAX) it is compiled per (n, m) with the sizes as compile-time constants.

Everything is compiled with numba; the stage loops run on preallocated arrays (no allocation
inside the loops). Cost: O(N (n+m)^3) for the factorization.

Multipliers: with the Lagrangian
    L = J + sum_k lam_{k+1}.(A_k x_k + B_k u_k + c_k - x_{k+1}) + lam_0.(xbar_0 - x_0)
          + sum_k nu_k.(E_k x_k + F_k u_k + e_k) + nu_N.(E_N x_N + e_N),
``solve`` returns lam (N+1, n) and nu (N+1, ne). (The paper's p in (16) is -lam.)
"""

from __future__ import annotations

import dataclasses

import numba as nb
import numpy as np
from llvmlite import ir as llir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..errors import OladoError


class NotPositiveDefiniteError(OladoError, np.linalg.LinAlgError):
    """The reduced Hessian of a stage is not positive definite; ``stage`` says where."""

    def __init__(self, stage, message=None):
        self.stage = int(stage)
        super().__init__(message or f"reduced Hessian Q_uu (projected on the null space of the stage "
                                    f"equality constraints) is not positive definite at stage k={stage}")


class RiccatiStatusError(OladoError):
    """Equality rows exceeding the recursion's row buffers. Since the passed-back state rows are
    compressed to an independent set (at most n rows) this is not expected to happen; dependent
    rows are handled, inconsistent ones reported through ``LQSolution.x0_residual``."""


# ============================================================================= numba kernels
@nb.njit(cache=True)
def _chol_inplace(a, d):
    """Cholesky of the leading d x d block of a (lower, in place). Returns False if not PD."""
    for j in range(d):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        if not (s > 0.0):
            return False
        ljj = np.sqrt(s)
        a[j, j] = ljj
        for i in range(j + 1, d):
            t = a[i, j]
            for k in range(j):
                t -= a[i, k] * a[j, k]
            a[i, j] = t / ljj
        for i in range(j):
            a[i, j] = 0.0
    return True


@nb.njit(cache=True)
def _chol_solve_vec(L, d, b):
    """Solve (L L^T) x = b in place on the first d entries of b."""
    for i in range(d):
        t = b[i]
        for k in range(i):
            t -= L[i, k] * b[k]
        b[i] = t / L[i, i]
    for i in range(d - 1, -1, -1):
        t = b[i]
        for k in range(i + 1, d):
            t -= L[k, i] * b[k]
        b[i] = t / L[i, i]


@nb.njit(cache=True)
def _chol_solve_mat(L, d, B, ncol):
    """Solve (L L^T) X = B in place on B[:d, :ncol]."""
    for c in range(ncol):
        for i in range(d):
            t = B[i, c]
            for k in range(i):
                t -= L[i, k] * B[k, c]
            B[i, c] = t / L[i, i]
        for i in range(d - 1, -1, -1):
            t = B[i, c]
            for k in range(i + 1, d):
                t -= L[k, i] * B[k, c]
            B[i, c] = t / L[i, i]


@nb.njit(cache=True)
def _qr_pivot(M, rows, cols, Qacc, perm, vtmp, norms, rank_tol, scale, accumulate, weights):
    """Householder QR with column pivoting of M[:rows, :cols] in place (M <- R), accumulating
    the orthogonal factor in Qacc[:rows, :rows] (unless ``accumulate`` is False: Qacc is then not
    touched) and the column permutation in perm. Returns the numerical rank: the elimination stops
    at the first pivot column whose remaining norm is <= rank_tol * max(r00, scale), r00 the norm
    of the first pivot (the largest column) and ``scale`` an optional reference magnitude of the
    data the columns were computed from (so that columns that are only rounding noise count as
    zero even when all columns are).

    ``weights`` (empty, or one entry per column, indexed by the original column): pivot choice and
    rank test use the weighted remaining norms weights[c] * |M[j:, c]|, i.e. this is the pivoted
    QR of M diag(weights) -- the same reflections and permutation, since scaling a column does
    not change its direction -- with R left unscaled (R = R_w diag(weights)^{-1})."""
    if accumulate:
        for i in range(rows):
            for j in range(rows):
                Qacc[i, j] = 1.0 if i == j else 0.0
    for j in range(cols):
        perm[j] = j
    kmax = min(rows, cols)
    r00 = 0.0
    rank = 0
    for j in range(kmax):
        # pivot: largest remaining column norm
        best, p = -1.0, j
        bestw = -1.0
        for c in range(j, cols):
            s = 0.0
            for i in range(j, rows):
                s += M[i, c] * M[i, c]
            norms[c] = s
            sw = s
            if weights.shape[0] > 0:
                sw = s * weights[perm[c]] * weights[perm[c]]
            if sw > bestw:
                best, bestw, p = s, sw, c
        if p != j:
            for i in range(rows):
                t = M[i, j]; M[i, j] = M[i, p]; M[i, p] = t
            t2 = perm[j]; perm[j] = perm[p]; perm[p] = t2
        nrm = np.sqrt(best)
        nrmw = np.sqrt(bestw)
        if j == 0:
            r00 = nrmw
        if nrmw <= rank_tol * max(r00, scale, 1e-300) or nrm == 0.0:
            break
        rank += 1
        # Householder vector v for M[j:rows, j]
        alpha = -nrm if M[j, j] >= 0.0 else nrm
        for i in range(j, rows):
            vtmp[i] = M[i, j]
        vtmp[j] -= alpha
        vn = 0.0
        for i in range(j, rows):
            vn += vtmp[i] * vtmp[i]
        if vn > 0.0:
            # apply H = I - 2 v v^T / (v.v) to M[j:, j:] and accumulate Q = Q H
            for c in range(j, cols):
                s = 0.0
                for i in range(j, rows):
                    s += vtmp[i] * M[i, c]
                s = 2.0 * s / vn
                for i in range(j, rows):
                    M[i, c] -= s * vtmp[i]
            if accumulate:
                for i in range(rows):
                    s = 0.0
                    for l in range(j, rows):
                        s += Qacc[i, l] * vtmp[l]
                    s = 2.0 * s / vn
                    for l in range(j, rows):
                        Qacc[i, l] -= s * vtmp[l]
        for i in range(j + 1, rows):
            M[i, j] = 0.0
    return rank


@nb.njit(cache=True)
def _closed_loop(A, B, c, K, kff, X, U):
    """Forward sweep u_k = K_k x_k + k_k, x_{k+1} = A_k x_k + B_k u_k + c_k (X[0] given)."""
    N, n, m = B.shape
    for k in range(N):
        for i in range(m):
            s = kff[k, i]
            for l in range(n):
                s += K[k, i, l] * X[k, l]
            U[k, i] = s
        for i in range(n):
            s = c[k, i]
            for l in range(n):
                s += A[k, i, l] * X[k, l]
            for l in range(m):
                s += B[k, i, l] * U[k, l]
            X[k + 1, i] = s


@nb.njit(cache=True)
def _factor(Q, S, R, A, B, E, F, ne, EN, neN, Dx, Du, Ci, sig, ni, reg, rank_tol,
            P, K, Quu_s, Qux_s, Lww, Qm, Rm, perm, rank, nc, Cx_s, G, ng, Wx, Dmat, pg, Zg):
    """Backward factorization sweep (paper 001 sec. 4.2.3, Arnold's elimination in the
    constraint-propagating form). Returns -1 on success, the stage index of a failure
    (non-positive-definite reduced Hessian), or -(1000 + k) when more rows than the buffers hold
    (ncmax) reach stage k -- which the compression of the passed-back rows rules out: at most
    ne_max + max(n, neN) rows reach any stage.

    Stage k: the combined rows [E_k; G_{k+1} A_k] x + [F_k; G_{k+1} B_k] u + d = 0 (nc[k] rows,
    stored in Cx_s) are split by the pivoted QR of their u-part, F^T Pi = Q [R11 R12] (Qm, Rm, perm,
    rank rk; pivots and rank test on the u-parts relative to the norm of their whole row, so a
    u-part that is rounding noise of its row counts as zero); the nc[k] - rk rows the controls cannot satisfy leave as state rows
    Graw x + graw = 0 with Graw = R12^T Wx - Pi_2^T Cx, Wx = R11^{-T} Pi_1^T Cx. Dependent rows
    among them are dropped: a pivoted QR (Graw^T diag(s)^{-1}) Pi_g = Q_g [S11 S12], each row
    scaled by the norm s of the combined row [Cx Cu] it came from (rank rg <= n, same relative
    rank_tol, measured against max(1, largest scaled row) so that rows that cancelled to rounding
    noise count as zero) keeps the rg independent rows G_k = (Pi_g^T Graw)[:rg] (ng[k] = rg, the
    permutation in pg[k]); the dropped rows are (Pi_g^T Graw)[rg:] = Zg^T G_k with
    Zg = D1^{-1} S11^{-1} S12 D2 (D1, D2 the scalings of the kept / dropped rows; stored in Zg[k],
    rg x (nc[k] - rk - rg)), so for the constants they only impose the consistency
    (Pi_g^T graw)[rg:] = Zg^T g_k, checked by :func:`_solve`. The row sets G_N = E_N and G_k are
    stored in G (rows on x_k only)."""
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    ncmax = Cx_s.shape[1]
    # workspaces
    PA = np.empty((n, n)); PB = np.empty((n, m))
    M = np.empty((m, ncmax)); vt = np.empty(max(m, 1)); nr = np.empty(max(ncmax, 1))
    T = np.empty((m, n)); Y = np.empty((m, n)); Qww = np.empty((m, m)); Qwx = np.empty((m, n)); tmp = np.empty((m, m))
    Cu = np.empty((ncmax, m)); Cx = np.empty((ncmax, n))
    Graw = np.empty((ncmax, n)); Mg = np.empty((n, ncmax)); vg = np.empty(max(n, 1)); Qg = np.empty((1, 1))
    sg = np.empty(max(ncmax, 1)); wu = np.empty(max(ncmax, 1)); nowt = np.empty(0)
    # terminal stage
    for i in range(n):
        for j in range(n):
            P[N, i, j] = Q[N, i, j]
        P[N, i, i] += Dx[N, i]
    ng[N] = neN
    for i in range(neN):
        for j in range(n):
            G[N, i, j] = EN[i, j]
    for k in range(N - 1, -1, -1):
        # PA = P_{k+1} A_k, PB = P_{k+1} B_k
        for i in range(n):
            for j in range(n):
                s = 0.0
                for l in range(n):
                    s += P[k + 1, i, l] * A[k, l, j]
                PA[i, j] = s
            for j in range(m):
                s = 0.0
                for l in range(n):
                    s += P[k + 1, i, l] * B[k, l, j]
                PB[i, j] = s
        # Qxx -> P[k] (temporarily), Quu, Qux
        for i in range(n):
            for j in range(n):
                s = Q[k, i, j]
                for l in range(n):
                    s += A[k, l, i] * PA[l, j]
                P[k, i, j] = s
            P[k, i, i] += Dx[k, i]
        for i in range(m):
            for j in range(m):
                s = R[k, i, j]
                for l in range(n):
                    s += B[k, l, i] * PB[l, j]
                Quu_s[k, i, j] = s
            Quu_s[k, i, i] += Du[k, i] + reg
            for j in range(n):
                s = S[k, j, i]
                for l in range(n):
                    s += B[k, l, i] * PA[l, j]
                Qux_s[k, i, j] = s
        # stage inequality terms C^T diag(sig) C
        for c in range(ni[k]):
            w = sig[k, c]
            if w != 0.0:
                for i in range(n):
                    ci = Ci[k, c, i] * w
                    if ci != 0.0:
                        for j in range(n):
                            P[k, i, j] += ci * Ci[k, c, j]
                        for j in range(m):
                            Qux_s[k, j, i] += ci * Ci[k, c, n + j]
                for i in range(m):
                    ci = Ci[k, c, n + i] * w
                    if ci != 0.0:
                        for j in range(m):
                            Quu_s[k, i, j] += ci * Ci[k, c, n + j]
        # combined equality rows: [E_k; G_{k+1} A_k] x + [F_k; G_{k+1} B_k] u + d = 0
        nck = ne[k] + ng[k + 1]
        if nck > ncmax:
            return -(1000 + k)
        nc[k] = nck
        for i in range(ne[k]):
            for j in range(n):
                Cx[i, j] = E[k, i, j]
            for j in range(m):
                Cu[i, j] = F[k, i, j]
        for i in range(ng[k + 1]):
            for j in range(n):
                s = 0.0
                for l in range(n):
                    s += G[k + 1, i, l] * A[k, l, j]
                Cx[ne[k] + i, j] = s
            for j in range(m):
                s = 0.0
                for l in range(n):
                    s += G[k + 1, i, l] * B[k, l, j]
                Cu[ne[k] + i, j] = s
        for i in range(nck):
            for j in range(n):
                Cx_s[k, i, j] = Cx[i, j]
        rk = 0
        if nck > 0:
            for i in range(m):
                for j in range(nck):
                    M[i, j] = Cu[j, i]
            # rank test per row: a row's u-part counts as zero when it is <= rank_tol times the
            # norm of the whole row [Cx Cu] (weights 1/s; with scale 1 the test is relative to the
            # row itself), so u-parts that cancelled to rounding noise (G_{k+1} B_k of a state
            # constraint the control reaches only after several steps) are not used as pivots
            for c in range(nck):
                s = 0.0
                for j in range(n):
                    s += Cx[c, j] * Cx[c, j]
                for j in range(m):
                    s += Cu[c, j] * Cu[c, j]
                wu[c] = 1.0 / np.sqrt(s) if s > 0.0 else 1.0
            rk = _qr_pivot(M, m, nck, Qm[k], perm[k], vt, nr, rank_tol, 1.0, True, wu[:nck])
            for i in range(m):
                for j in range(nck):
                    Rm[k, i, j] = M[i, j]
        else:
            for i in range(m):
                for j in range(m):
                    Qm[k, i, j] = 1.0 if i == j else 0.0
        rank[k] = rk
        # Wx = R11^{-T} Pi_1^T Cx  (rk x n): forward substitution with R11^T (lower)
        for i in range(rk):
            for j in range(n):
                s = Cx[perm[k, i], j]
                for l in range(i):
                    s -= Rm[k, l, i] * Wx[k, l, j]
                Wx[k, i, j] = s / Rm[k, i, i]
        # Dmat = -R11^{-1} R12  (rk x (nck - rk)), back substitution
        for c in range(nck - rk):
            for i in range(rk - 1, -1, -1):
                s = -Rm[k, i, rk + c]
                for l in range(i + 1, rk):
                    s -= Rm[k, i, l] * Dmat[k, l, c]
                Dmat[k, i, c] = s / Rm[k, i, i]
        # passed-back state rows before compression: Graw = R12^T Wx - Pi_2^T Cx
        ngr = nck - rk
        for c in range(ngr):
            for j in range(n):
                s = -Cx[perm[k, rk + c], j]
                for l in range(rk):
                    s += Rm[k, l, rk + c] * Wx[k, l, j]
                Graw[c, j] = s
        # compression: pivoted QR of Graw^T (n x ngr), each row divided by the norm s_c of the
        # combined row [Cx Cu] it came from (a row that cancelled to rounding noise is then of
        # the order of eps whatever the scale of the other rows) -> rank rg <= n; G_k = the rg
        # pivoted independent rows; Zg = diag(s) S11^{-1} S12 diag(s)^{-1} (of the scaled QR)
        # expresses the dropped rows through the kept ones
        rg = 0
        if ngr > 0:
            for c in range(ngr):
                p = perm[k, rk + c]
                s = 0.0
                for j in range(n):
                    s += Cx[p, j] * Cx[p, j]
                for j in range(m):
                    s += Cu[p, j] * Cu[p, j]
                sg[c] = np.sqrt(s) if s > 0.0 else 1.0
            for j in range(n):
                for c in range(ngr):
                    Mg[j, c] = Graw[c, j] / sg[c]
            rg = _qr_pivot(Mg, n, ngr, Qg, pg[k], vg, nr, rank_tol, 1.0, False, nowt)
            for c in range(ngr - rg):
                for i in range(rg - 1, -1, -1):
                    s = Mg[i, rg + c]
                    for l in range(i + 1, rg):
                        s -= Mg[i, l] * Zg[k, l, c]
                    Zg[k, i, c] = s / Mg[i, i]
                for i in range(rg):
                    Zg[k, i, c] *= sg[pg[k, rg + c]] / sg[pg[k, i]]
        ng[k] = rg
        for i in range(rg):
            for j in range(n):
                G[k, i, j] = Graw[pg[k, i], j]
        # u = T x + Q2 w with T = -Q1 Wx
        for i in range(m):
            for j in range(n):
                s = 0.0
                for l in range(rk):
                    s -= Qm[k, i, l] * Wx[k, l, j]
                T[i, j] = s
        dw = m - rk
        # Qww = Q2^T Quu Q2 ; Qwx = Q2^T (Quu T + Qux)
        for i in range(m):
            for j in range(dw):
                s = 0.0
                for l in range(m):
                    s += Quu_s[k, i, l] * Qm[k, l, rk + j]
                tmp[i, j] = s
        for i in range(dw):
            for j in range(dw):
                s = 0.0
                for l in range(m):
                    s += Qm[k, l, rk + i] * tmp[l, j]
                Qww[i, j] = s
        for i in range(m):
            for j in range(n):
                s = Qux_s[k, i, j]
                for l in range(m):
                    s += Quu_s[k, i, l] * T[l, j]
                Y[i, j] = s
        for i in range(dw):
            for j in range(n):
                s = 0.0
                for l in range(m):
                    s += Qm[k, l, rk + i] * Y[l, j]
                Qwx[i, j] = s
        for i in range(dw):
            for j in range(dw):
                Lww[k, i, j] = 0.5 * (Qww[i, j] + Qww[j, i])
        if not _chol_inplace(Lww[k], dw):
            return k
        # Qwx <- Qww^{-1} Qwx
        _chol_solve_mat(Lww[k], dw, Qwx, n)
        # K = T - Q2 Qww^{-1} Qwx
        for i in range(m):
            for j in range(n):
                s = T[i, j]
                for l in range(dw):
                    s -= Qm[k, i, rk + l] * Qwx[l, j]
                K[k, i, j] = s
        # P_k = Qxx + Qux^T K + K^T Qux + K^T Quu K
        for i in range(m):
            for j in range(n):
                s = 0.0
                for l in range(m):
                    s += Quu_s[k, i, l] * K[k, l, j]
                T[i, j] = s + Qux_s[k, i, j]  # Quu K + Qux
        for i in range(n):
            for j in range(n):
                s = P[k, i, j]
                for l in range(m):
                    s += Qux_s[k, l, i] * K[k, l, j] + K[k, l, i] * T[l, j]
                PA[i, j] = s
        for i in range(n):
            for j in range(n):
                P[k, i, j] = 0.5 * (PA[i, j] + PA[j, i])
    return -1


@nb.njit(cache=True)
def _solve(A, B, c, q, r, e, eN, x0, Dx, Du, S, Q, R, E, F, ne, EN, neN, Ci, sig, ni, ci_rhs,
           P, K, Quu_s, Qux_s, Lww, Qm, Rm, perm, rank, nc, Cx_s, G, ng, Wx, Dmat, pg, Zg,
           X, U, lam, nu, kff, pvec, gvec, dvec):
    """One right-hand side (paper 001 sec. 4.2.3): backward vector sweep, forward simulation,
    multiplier sweeps, with the factors of :func:`_factor`.

    The backward sweep forms the constants of the passed-back rows as the factorization formed
    the rows: graw = R12^T v1 - Pi_2^T d, then g_k = (Pi_g^T graw)[:rg] for the kept rows and the
    consistency defect (Pi_g^T graw)[rg:] - Zg^T g_k of the dropped (dependent) ones. In the
    forward multiplier sweep the multipliers eta_k of the kept rows G_k are those of the rows
    (Pi_g^T Graw)[:rg], the dropped rows get zero (their multipliers are not unique;
    Graw^T eta_raw = G_k^T eta_k, so the stationarity rows hold), and eta_raw is mapped through
    perm / Dmat into the multipliers of the stage's combined rows as before.

    Returns the infeasibility of the equality rows (max norm): the largest of the residual
    G_0 x0 + g_0 of the rows reaching x_0 and the consistency defects of the dependent rows
    dropped at every stage (zero up to rounding for a consistent constraint set)."""
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    ncmax = Cx_s.shape[1]
    t1 = np.empty(n); qx = np.empty(n); qu = np.empty(m); m0 = np.empty(m); w = np.empty(max(m, 1))
    v1 = np.empty(max(ncmax, 1)); bu = np.empty(m); mu = np.empty(max(ncmax, 1)); mup = np.empty(max(ncmax, 1))
    eta = np.empty(max(ncmax, 1)); a_next = np.empty(n); a_cur = np.empty(n)
    graw = np.empty(max(ncmax, 1)); etar = np.empty(max(ncmax, 1))
    res = 0.0
    # terminal
    for i in range(n):
        pvec[N, i] = q[N, i]
    for i in range(neN):
        gvec[N, i] = eN[i]
    for k in range(N - 1, -1, -1):
        # t1 = P_{k+1} c_k + p_{k+1}
        for i in range(n):
            s = pvec[k + 1, i]
            for l in range(n):
                s += P[k + 1, i, l] * c[k, l]
            t1[i] = s
        for i in range(n):
            s = q[k, i]
            for l in range(n):
                s += A[k, l, i] * t1[l]
            qx[i] = s
        for i in range(m):
            s = r[k, i]
            for l in range(n):
                s += B[k, l, i] * t1[l]
            qu[i] = s
        # linear terms of the stage inequality terms: C^T diag(sig) ci_rhs
        for cc in range(ni[k]):
            wgt = sig[k, cc] * ci_rhs[k, cc]
            if wgt != 0.0:
                for i in range(n):
                    qx[i] += Ci[k, cc, i] * wgt
                for i in range(m):
                    qu[i] += Ci[k, cc, n + i] * wgt
        # d = [e_k; G_{k+1} c_k + g_{k+1}]
        nck = nc[k]
        rk = rank[k]
        for i in range(ne[k]):
            dvec[k, i] = e[k, i]
        for i in range(ng[k + 1]):
            s = gvec[k + 1, i]
            for l in range(n):
                s += G[k + 1, i, l] * c[k, l]
            dvec[k, ne[k] + i] = s
        # v1 = R11^{-T} Pi_1^T d ; m0 = -Q1 v1
        for i in range(rk):
            s = dvec[k, perm[k, i]]
            for l in range(i):
                s -= Rm[k, l, i] * v1[l]
            v1[i] = s / Rm[k, i, i]
        for i in range(m):
            s = 0.0
            for l in range(rk):
                s -= Qm[k, i, l] * v1[l]
            m0[i] = s
        # graw = R12^T v1 - Pi_2^T d; g_k = the kept rows; defect of the dropped ones
        ngr = nck - rk
        for cc in range(ngr):
            s = -dvec[k, perm[k, rk + cc]]
            for l in range(rk):
                s += Rm[k, l, rk + cc] * v1[l]
            graw[cc] = s
        rg = ng[k]
        for i in range(rg):
            gvec[k, i] = graw[pg[k, i]]
        for cc in range(ngr - rg):
            s = graw[pg[k, rg + cc]]
            for l in range(rg):
                s -= Zg[k, l, cc] * gvec[k, l]
            res = max(res, abs(s))
        # w0 = -Qww^{-1} Q2^T (Quu m0 + qu)
        dw = m - rk
        for i in range(m):
            s = qu[i]
            for l in range(m):
                s += Quu_s[k, i, l] * m0[l]
            bu[i] = s
        for i in range(dw):
            s = 0.0
            for l in range(m):
                s += Qm[k, l, rk + i] * bu[l]
            w[i] = -s
        _chol_solve_vec(Lww[k], dw, w)
        for i in range(m):
            s = m0[i]
            for l in range(dw):
                s += Qm[k, i, rk + l] * w[l]
            kff[k, i] = s
        # p_k = qx + Qux^T kff + K^T (qu + Quu kff)
        for i in range(m):
            s = qu[i]
            for l in range(m):
                s += Quu_s[k, i, l] * kff[k, l]
            bu[i] = s
        for i in range(n):
            s = qx[i]
            for l in range(m):
                s += Qux_s[k, l, i] * kff[k, l] + K[k, l, i] * bu[l]
            pvec[k, i] = s
    # forward simulation
    for i in range(n):
        X[0, i] = x0[i]
    for cc in range(ng[0]):
        s = gvec[0, cc]
        for l in range(n):
            s += G[0, cc, l] * x0[l]
        res = max(res, abs(s))
    _closed_loop(A, B, c, K, kff, X, U)
    # multipliers, backward part: a_k (stored in lam), c-part of mu (stored in mup via nu scratch)
    for i in range(n):
        s = q[N, i] + Dx[N, i] * X[N, i]
        for l in range(n):
            s += Q[N, i, l] * X[N, l]
        lam[N, i] = s
    for k in range(N - 1, -1, -1):
        for i in range(n):
            a_next[i] = lam[k + 1, i]
        # b_u = (R + Du) u + S^T x + r + B^T a_{k+1}  (+ inequality terms)
        for i in range(m):
            s = r[k, i] + Du[k, i] * U[k, i]
            for l in range(m):
                s += R[k, i, l] * U[k, l]
            for l in range(n):
                s += S[k, l, i] * X[k, l] + B[k, l, i] * a_next[l]
            bu[i] = s
        for i in range(n):
            s = q[k, i] + Dx[k, i] * X[k, i]
            for l in range(n):
                s += Q[k, i, l] * X[k, l] + A[k, l, i] * a_next[l]
            for l in range(m):
                s += S[k, i, l] * U[k, l]
            a_cur[i] = s
        for cc in range(ni[k]):
            wgt = ci_rhs[k, cc]
            for l in range(n):
                wgt += Ci[k, cc, l] * X[k, l]
            for l in range(m):
                wgt += Ci[k, cc, n + l] * U[k, l]
            wgt *= sig[k, cc]
            for i in range(n):
                a_cur[i] += Ci[k, cc, i] * wgt
            for i in range(m):
                bu[i] += Ci[k, cc, n + i] * wgt
        rk = rank[k]
        nck = nc[k]
        # c_k = -R11^{-1} (Q^T b_u)_{1:rk}  -> stored in Wx-free scratch: use dvec row as storage
        for i in range(rk):
            s = 0.0
            for l in range(m):
                s += Qm[k, l, i] * bu[l]
            v1[i] = -s
        for i in range(rk - 1, -1, -1):
            s = v1[i]
            for l in range(i + 1, rk):
                s -= Rm[k, i, l] * v1[l]
            v1[i] = s / Rm[k, i, i]
        # keep c_k in dvec[k, :rk] (d is no longer needed)
        for i in range(rk):
            dvec[k, i] = v1[i]
        # a_k += Cx^T Pi [c_k; 0]
        for i in range(rk):
            row = perm[k, i]
            for j in range(n):
                a_cur[j] += Cx_s[k, row, j] * v1[i]
        for i in range(n):
            lam[k, i] = a_cur[i]
    # forward multiplier sweep: eta_0 = 0; mu' = [c_k + D eta_k; eta_k]; nu_k = mu[:ne]; eta_{k+1} = -mu[ne:]
    ng0 = ng[0]
    for i in range(ng0):
        eta[i] = 0.0
    for k in range(N):
        rk = rank[k]
        nck = nc[k]
        ngk = ng[k]
        # lam_k = a_k - G_k^T eta_k
        for j in range(n):
            s = lam[k, j]
            for cc in range(ngk):
                s -= G[k, cc, j] * eta[cc]
            lam[k, j] = s
        # multipliers of the uncompressed passed rows: eta on the kept ones, 0 on the dropped
        ngr = nck - rk
        for cc in range(ngr):
            etar[cc] = 0.0
        for i in range(ngk):
            etar[pg[k, i]] = eta[i]
        for i in range(rk):
            s = dvec[k, i]
            for cc in range(ngr):
                s += Dmat[k, i, cc] * etar[cc]
            mup[i] = s
        for cc in range(ngr):
            mup[rk + cc] = etar[cc]
        for i in range(nck):
            mu[perm[k, i]] = mup[i]
        for i in range(ne[k]):
            nu[k, i] = mu[i]
        for i in range(ng[k + 1]):
            eta[i] = -mu[ne[k] + i]
    # terminal: lam_N = a_N - G_N^T eta_N, nu_N = -eta_N (G_N = E_N)
    for j in range(n):
        s = lam[N, j]
        for cc in range(ng[N]):
            s -= G[N, cc, j] * eta[cc]
        lam[N, j] = s
    for i in range(neN):
        nu[N, i] = -eta[i]
    return res


# ------------------------------------------------------------------ fast path: no equality rows
# Without stage or final equality rows the recursion is the plain Riccati recursion: no QR, no
# propagated state rows, and only P, K and the Cholesky factor of Q_uu need to be stored. This is
# the case of every interior-point iteration of a problem with only inequalities and bounds, so it
# gets its own kernels (about 2x fewer flops, 4x less memory than the general path).

@nb.njit(cache=True)
def _factor_unconstrained(Q, S, R, A, B, Dx, Du, Ci, sig, ni, reg, P, K, L):
    """Backward Riccati sweep without equality rows. With Q_uu = L L^T and V = L^{-1} Q_ux:
    K_k = -L^{-T} V, P_k = Q_xx - V^T V. Returns -1 on success, else the failing stage index."""
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    PA = np.empty((n, n)); PB = np.empty((n, m)); Qux = np.empty((m, n)); V = np.empty((m, n))
    Pk = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            P[N, i, j] = Q[N, i, j]
        P[N, i, i] += Dx[N, i]
    for k in range(N - 1, -1, -1):
        # PA = P_{k+1} A_k, PB = P_{k+1} B_k (row-wise axpy form: contiguous inner loops)
        for i in range(n):
            for j in range(n):
                PA[i, j] = 0.0
            for j in range(m):
                PB[i, j] = 0.0
            for l in range(n):
                p = P[k + 1, i, l]
                for j in range(n):
                    PA[i, j] += p * A[k, l, j]
                for j in range(m):
                    PB[i, j] += p * B[k, l, j]
        # Q_xx = Q + diag(Dx) + A^T PA (into Pk)
        for i in range(n):
            for j in range(n):
                Pk[i, j] = Q[k, i, j]
            Pk[i, i] += Dx[k, i]
        for l in range(n):
            for i in range(n):
                a = A[k, l, i]
                for j in range(n):
                    Pk[i, j] += a * PA[l, j]
        # Q_uu = R + diag(Du) + reg I + B^T PB (into L[k]),  Q_ux = S^T + B^T PA
        for i in range(m):
            for j in range(m):
                L[k, i, j] = R[k, i, j]
            L[k, i, i] += Du[k, i] + reg
            for j in range(n):
                Qux[i, j] = S[k, j, i]
        for l in range(n):
            for i in range(m):
                b = B[k, l, i]
                for j in range(m):
                    L[k, i, j] += b * PB[l, j]
                for j in range(n):
                    Qux[i, j] += b * PA[l, j]
        # stage inequality terms C^T diag(sig) C
        for c in range(ni[k]):
            w = sig[k, c]
            if w != 0.0:
                for i in range(n):
                    cw = Ci[k, c, i] * w
                    if cw != 0.0:
                        for j in range(n):
                            Pk[i, j] += cw * Ci[k, c, j]
                        for j in range(m):
                            Qux[j, i] += cw * Ci[k, c, n + j]
                for i in range(m):
                    cw = Ci[k, c, n + i] * w
                    if cw != 0.0:
                        for j in range(m):
                            L[k, i, j] += cw * Ci[k, c, n + j]
        if not _chol_inplace(L[k], m):
            return k
        # V = L^{-1} Q_ux (forward substitution, row-wise)
        for i in range(m):
            for j in range(n):
                V[i, j] = Qux[i, j]
            for l in range(i):
                a = L[k, i, l]
                for j in range(n):
                    V[i, j] -= a * V[l, j]
            inv = 1.0 / L[k, i, i]
            for j in range(n):
                V[i, j] *= inv
        # K = -L^{-T} V (back substitution, row-wise)
        for i in range(m - 1, -1, -1):
            for j in range(n):
                K[k, i, j] = -V[i, j]
            for l in range(i + 1, m):
                a = L[k, l, i]
                for j in range(n):
                    K[k, i, j] -= a * K[k, l, j]
            inv = 1.0 / L[k, i, i]
            for j in range(n):
                K[k, i, j] *= inv
        # P_k = Q_xx - V^T V, symmetrized
        for l in range(m):
            for i in range(n):
                v = V[l, i]
                for j in range(n):
                    Pk[i, j] -= v * V[l, j]
        for i in range(n):
            for j in range(n):
                P[k, i, j] = 0.5 * (Pk[i, j] + Pk[j, i])
    return -1


@nb.njit(cache=True)
def _solve_unconstrained(Q, S, A, B, Dx, Ci, sig, ni, P, K, L, q, r, c, x0, ci, X, U, lam, kff, pvec):
    """One right-hand side without equality rows: backward vector sweep (kff_k = -Q_uu^{-1} q_u,
    p_k = q_x + K_k^T q_u), forward simulation, and lam_k from the x-stationarity rows."""
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    t1 = np.empty(n); qu = np.empty(m); a_cur = np.empty(n)
    for i in range(n):
        pvec[N, i] = q[N, i]
    for k in range(N - 1, -1, -1):
        # t1 = P_{k+1} c_k + p_{k+1}
        for i in range(n):
            s = pvec[k + 1, i]
            for l in range(n):
                s += P[k + 1, i, l] * c[k, l]
            t1[i] = s
        # q_x = q + A^T t1 (into pvec[k]), q_u = r + B^T t1
        for i in range(n):
            pvec[k, i] = q[k, i]
        for i in range(m):
            qu[i] = r[k, i]
        for l in range(n):
            t = t1[l]
            for i in range(n):
                pvec[k, i] += A[k, l, i] * t
            for i in range(m):
                qu[i] += B[k, l, i] * t
        for cc in range(ni[k]):
            wgt = sig[k, cc] * ci[k, cc]
            if wgt != 0.0:
                for i in range(n):
                    pvec[k, i] += Ci[k, cc, i] * wgt
                for i in range(m):
                    qu[i] += Ci[k, cc, n + i] * wgt
        # kff = -Q_uu^{-1} q_u ;  p_k = q_x + K^T q_u
        for i in range(m):
            kff[k, i] = -qu[i]
        _chol_solve_vec(L[k], m, kff[k])
        for l in range(m):
            t = qu[l]
            for i in range(n):
                pvec[k, i] += K[k, l, i] * t
    # forward simulation
    for i in range(n):
        X[0, i] = x0[i]
    _closed_loop(A, B, c, K, kff, X, U)
    # multipliers from the x-stationarity rows:
    # lam_N = (Q_N + Dx_N) x_N + q_N,  lam_k = (Q + Dx) x + S u + q + A^T lam_{k+1} + C_x^T sig (C z + ci)
    for i in range(n):
        s = q[N, i] + Dx[N, i] * X[N, i]
        for l in range(n):
            s += Q[N, i, l] * X[N, l]
        lam[N, i] = s
    for k in range(N - 1, -1, -1):
        for i in range(n):
            s = q[k, i] + Dx[k, i] * X[k, i]
            for l in range(n):
                s += Q[k, i, l] * X[k, l]
            for l in range(m):
                s += S[k, i, l] * U[k, l]
            a_cur[i] = s
        for l in range(n):
            t = lam[k + 1, l]
            for i in range(n):
                a_cur[i] += A[k, l, i] * t
        for cc in range(ni[k]):
            wgt = ci[k, cc]
            for l in range(n):
                wgt += Ci[k, cc, l] * X[k, l]
            for l in range(m):
                wgt += Ci[k, cc, n + l] * U[k, l]
            wgt *= sig[k, cc]
            if wgt != 0.0:
                for i in range(n):
                    a_cur[i] += Ci[k, cc, i] * wgt
        for i in range(n):
            lam[k, i] = a_cur[i]


# ------------------------------------------------------------------ fast path, small blocks
# The stage blocks are tiny (n, m ~ 5..10), so what the compiler knows about the sizes matters
# more than the flop count: for n + m <= _FIXED_SIZE_MAX the *_fixed kernels are compiled once per
# (n, m) with the sizes as compile-time constants (passed as "size tags", tuples whose lengths are
# the sizes: numba specializes on the tuple type and len() of a tuple is a constant), and their
# stage workspaces live on the stack (_stack_matrix), where LLVM knows they alias nothing and keeps
# them in registers; about 3x faster than the any-size kernels at n = 6, m = 7. They are cached on
# disk (cache=True) per (n, m); a new (n, m) costs one compilation (~2 s each). Larger blocks use
# the any-size kernels (row-wise loops, which vectorize with run-time sizes; faster there).
# Multiply-adds may be contracted to FMAs (no other fast-math: NaN and inf still propagate).
#
# The matrix part of a factorization stage is one intrinsic (_eliminate_stage) that writes
# straight-line SIMD code: numba runs LLVM without its SLP vectorizer, and LLVM's loop vectorizer
# never sees loops of a few constant trips (they are unrolled first), so loops over the rows stay
# scalar however they are ordered. The intrinsic unrolls the stage at compile time into
# operations on row pieces of 4, 2 and 1 doubles held in registers (about 2x faster than the
# scalar loops at n = 6, m = 7; 1.1-2x at other sizes up to n = 12; slower beyond, where the
# scalar-loop kernel _factor_unconstrained_fixed_loops is kept).
# The solve kernel's sweeps are written the same way (_solve_back_sweep, _solve_forward_sweep:
# one loop each, the vector carried from stage to stage in registers; the stage intrinsics take
# the whole arrays and k, since slicing a stage out costs reference counting per stage): 1.4-1.5x
# faster than scalar loops at n = 6, m = 7, about 2x at n + m >= 16, 1.1x at n + m <= 5, so
# there is no scalar fallback.
_CONTRACT = {"contract"}
_REASSOC = {"reassoc", "contract", "nsz"}
_FIXED_SIZE_MAX = 24
_STRAIGHT_N_MAX = 12     # larger n: _factor_unconstrained_fixed_loops


@intrinsic
def _stack_buffer(typingctx, tags):
    """Pointer to a float64 buffer on the stack of the calling kernel, of size the product of
    the lengths of the size tags (known at compile time)."""
    size = 1
    for tag in tags:
        size *= len(tag)

    def codegen(context, builder, signature, args):
        return cgutils.alloca_once(builder, context.get_value_type(types.float64),
                                   size=context.get_constant(types.intp, size))
    return types.CPointer(types.float64)(tags), codegen


@nb.njit(inline="always")
def _stack_matrix(rows, cols):
    """A (len(rows), len(cols)) workspace on the stack (contents undefined)."""
    return nb.carray(_stack_buffer((rows, cols)), (len(rows), len(cols)))


@nb.njit(inline="always")
def _stack_vector(rows):
    """A (len(rows),) workspace on the stack (contents undefined)."""
    return nb.carray(_stack_buffer((rows,)), (len(rows),))


def _size_tags(*sizes):
    """The size tags of the fixed-size kernels: one tuple of zeros of each length."""
    return tuple((0,) * s for s in sizes)


_F64 = llir.DoubleType()
_I32 = llir.IntType(32)
_I64 = llir.IntType(64)


def _pieces(first, count):
    """(first column, width) of the pieces of 4, 2 and 1 doubles covering count columns."""
    out, c, end = [], first, first + count
    while end - c >= 4:
        out.append((c, 4))
        c += 4
    if end - c >= 2:
        out.append((c, 2))
        c += 2
    if end - c == 1:
        out.append((c, 1))
    return out


class _RowCode:
    """Code generation helpers of _eliminate_stage (and of qp_ip's _kkt_stage / _kkt_boxes). A
    row is a list of pieces (first column, width, LLVM value: a double or a vector of 2 or 4
    doubles), data pointers point to C-ordered float64 matrices of ncols columns.

    Numba's on-disk cache of a kernel is invalidated only by changes to the kernel's own source
    file: after editing these helpers, delete the cached kernels of qp_ip.py as well
    (olado/solvers/__pycache__/qp_ip.*.nbi, *.nbc), or they keep the old generated code."""

    def __init__(self, builder):
        self.b = builder

    def _ptr(self, data, ncols, i, j, w):
        p = self.b.gep(data, [llir.Constant(llir.IntType(64), i * ncols + j)])
        return p if w == 1 else self.b.bitcast(p, llir.VectorType(_F64, w).as_pointer())

    def load(self, data, ncols, i, j, w=1):
        return self.b.load(self._ptr(data, ncols, i, j, w), align=8)

    def store(self, v, data, ncols, i, j, w=1):
        self.b.store(v, self._ptr(data, ncols, i, j, w), align=8)

    def splat(self, x, w):
        if w == 1:
            return x
        v = self.b.insert_element(llir.Constant(llir.VectorType(_F64, w), llir.Undefined), x,
                                  llir.Constant(_I32, 0))
        return self.b.shuffle_vector(v, v, llir.Constant(llir.VectorType(_I32, w), [0] * w))

    def entry(self, row, col):
        for c0, w, v in row:
            if c0 <= col < c0 + w:
                return v if w == 1 else self.b.extract_element(v, llir.Constant(_I32, col - c0))
        raise IndexError(col)

    def axpy(self, row, a, x):
        """row + a x, on the pieces of row (x has those pieces, maybe more)."""
        xv = {c0: v for c0, w, v in x}
        return [(c0, w, self.b.fadd(v, self.b.fmul(self.splat(a, w), xv[c0]))) for c0, w, v in row]

    def scale(self, row, a):
        return [(c0, w, self.b.fmul(self.splat(a, w), v)) for c0, w, v in row]


@intrinsic
def _eliminate_stage(typingctx, tags, Hs, Pn, Ak, Bk, Pk, Kk, Lk):
    """One stage of _factor_unconstrained_fixed as straight-line SIMD code, for the sizes of
    tags = _size_tags(n, m, n + m); all arguments are C-contiguous 2-d float64 arrays: Hs
    (n+m, n+m) the upper triangle of the stage Hessian in [u; x] order (R + diag(Du) + reg I,
    S^T; Q + diag(Dx), plus the C terms), Pn = P_{k+1} (n, n), Ak (n, n), Bk (n, m); writes
    P_k -> Pk, K_k -> Kk, L_k -> Lk. Returns False if a pivot of Q_uu is not positive (or NaN).

    H = Hs + [B A]^T (P_{k+1} [B A]) (upper triangle, rows in pieces of 4, 2, 1 columns: the u
    columns and the x columns separately, so that rows of B, A, K, P are whole pieces), then the
    u block is eliminated on unscaled rows (LDL^T form: row i -= (H_ji / s_j) row j for the
    pivot s_j = H_jj, so that only one division and no square root lies on the dependency chain
    of the pivots); U = D^{-1/2} H_u is the Cholesky factor (L = U_uu^T), K = -U_uu^{-1} U_ux
    (i.e. K_i = -(H_ix + sum_{l>i} H_il K_l) / s_i), and the x rows left are P_k (the Schur
    complement, stored symmetric from its upper triangle). Everything is evaluated whatever the
    pivots: a failed stage leaves garbage (NaN) in its outputs."""
    if not all(isinstance(a, types.Array) and a.ndim == 2 and a.dtype == types.float64 and a.layout == "C"
               for a in (Hs, Pn, Ak, Bk, Pk, Kk, Lk)):
        return None
    n, m = len(tags[0]), len(tags[1])
    nz = n + m

    def codegen(context, builder, signature, args):
        g = _RowCode(builder)
        hs, pn, ak, bk, pk, kk, lk = (context.make_array(t)(context, builder, v).data
                                      for t, v in zip(signature.args[1:], args[1:]))
        upieces, xpieces = _pieces(0, m), _pieces(m, n)
        zero, one, mzero = (llir.Constant(_F64, v) for v in (0.0, 1.0, -0.0))
        # G = [B A] by rows, W = P_{k+1} G
        G = [[(c0, w, g.load(bk, m, l, c0, w)) for c0, w in upieces]
             + [(c0, w, g.load(ak, n, l, c0 - m, w)) for c0, w in xpieces] for l in range(n)]
        W = []
        for i in range(n):
            row = g.scale(G[0], g.load(pn, n, i, 0))
            for l in range(1, n):
                row = g.axpy(row, g.load(pn, n, i, l), G[l])
            W.append(row)
        # H = Hs + G^T W: of row i, the pieces holding columns >= i
        H = []
        for i in range(nz):
            row = [(c0, w, g.load(hs, nz, i, c0, w)) for c0, w in upieces + xpieces if c0 + w > i]
            for l in range(n):
                row = g.axpy(row, g.load(bk, m, l, i) if i < m else g.load(ak, n, l, i - m), W[l])
            H.append(row)
        # eliminate the u block on unscaled rows
        ok = llir.Constant(llir.IntType(1), 1)
        s = []
        for j in range(m):
            s.append(g.entry(H[j], j))
            ok = builder.and_(ok, builder.fcmp_ordered(">", s[j], zero))
            sinv = builder.fdiv(one, s[j])
            for i in range(j + 1, nz):
                H[i] = g.axpy(H[i], builder.fsub(mzero, builder.fmul(g.entry(H[j], i), sinv)), H[j])
        # L_k = U_uu^T, U = D^{-1/2} H_u
        sqrt = builder.module.declare_intrinsic("llvm.sqrt", [_F64])
        for j in range(m):
            d = builder.call(sqrt, [s[j]])
            dinv = builder.fdiv(one, d)
            g.store(d, lk, m, j, j)
            for i in range(j + 1, m):
                g.store(builder.fmul(g.entry(H[j], i), dinv), lk, m, i, j)
                g.store(zero, lk, m, j, i)
        # K_k, back substitution by rows
        K = [None] * m
        for i in range(m - 1, -1, -1):
            row = [piece for piece in H[i] if piece[0] >= m]
            for l in range(i + 1, m):
                row = g.axpy(row, g.entry(H[i], l), K[l])
            K[i] = g.scale(row, builder.fsub(mzero, builder.fdiv(one, s[i])))
            for c0, w, v in K[i]:
                g.store(v, kk, n, i, c0 - m, w)
        # P_k from the upper triangle of the x rows
        for i in range(n):
            for j in range(i, n):
                v = g.entry(H[m + i], m + j)
                g.store(v, pk, n, i, j)
                if j != i:
                    g.store(v, pk, n, j, i)
        return ok
    return types.boolean(tags, Hs, Pn, Ak, Bk, Pk, Kk, Lk), codegen


@nb.njit(cache=True, fastmath=_CONTRACT)
def _factor_unconstrained_fixed(tags, Q, S, R, A, B, Dx, Du, Ci, sig, ni, reg, P, K, L):
    """_factor_unconstrained compiled for the sizes of tags = _size_tags(n, m, n + m).

    Stage k assembles the upper triangle of its Hessian in [u; x] order,
        H = [R + diag(Du) + reg I, S^T; S, Q + diag(Dx)] + [B A]^T P_{k+1} [B A] (+ C^T diag(sig) C)
    (of the symmetric parts of Q and R, which is Q and R themselves when they are symmetric),
    and eliminates the u block by a partial Cholesky factorization: H_uu = L L^T (L -> L[k]),
    L_xu = H_xu L^{-T}; then K_k = -L^{-T} L_xu^T and P_k = H_xx - L_xu L_xu^T (the Schur
    complement, symmetric by construction); see _eliminate_stage. Returns -1 on success, else
    the stage whose Q_uu is not positive definite."""
    nt, mt, zt = tags
    n, m = len(nt), len(mt)
    N = A.shape[0]
    Hs = _stack_matrix(zt, zt)      # upper triangle of the stage Hessian without the P term
    for i in range(n):
        for j in range(n):
            P[N, i, j] = 0.5 * (Q[N, i, j] + Q[N, j, i])
        P[N, i, i] += Dx[N, i]
    for k in range(N - 1, -1, -1):
        for i in range(m):
            for j in range(i, m):
                Hs[i, j] = 0.5 * (R[k, i, j] + R[k, j, i])
            Hs[i, i] += Du[k, i] + reg
            for j in range(n):
                Hs[i, m + j] = S[k, j, i]
        for i in range(n):
            for j in range(i, n):
                Hs[m + i, m + j] = 0.5 * (Q[k, i, j] + Q[k, j, i])
            Hs[m + i, m + i] += Dx[k, i]
        # stage inequality terms C^T diag(sig) C (C rows are in [x; u] order)
        for c in range(ni[k]):
            w = sig[k, c]
            if w != 0.0:
                for i in range(m):
                    cw = w * Ci[k, c, n + i]
                    for j in range(i, m):
                        Hs[i, j] += cw * Ci[k, c, n + j]
                    for j in range(n):
                        Hs[i, m + j] += cw * Ci[k, c, j]
                for i in range(n):
                    cw = w * Ci[k, c, i]
                    for j in range(i, n):
                        Hs[m + i, m + j] += cw * Ci[k, c, j]
        if not _eliminate_stage(tags, Hs, P[k + 1], A[k], B[k], P[k], K[k], L[k]):
            return k
    return -1


@nb.njit(cache=True, fastmath=_CONTRACT)
def _factor_unconstrained_fixed_loops(tags, Q, S, R, A, B, Dx, Du, Ci, sig, ni, reg, P, K, L):
    """_factor_unconstrained_fixed in scalar loops, for n > _STRAIGHT_N_MAX (where the
    straight-line code of _eliminate_stage runs out of registers and is slower).

    Stage k works on the lower triangle of its Hessian in [u; x] order,
        H = [R + diag(Du) + reg I, S^T; S, Q + diag(Dx)] + [B A]^T P_{k+1} [B A] (+ C^T diag(sig) C)
    (of the symmetric parts of Q and R, which is Q and R themselves when they are symmetric),
    and eliminates the u block by a partial Cholesky factorization: H_uu = L L^T (L -> L[k]),
    L_xu = H_xu L^{-T}; then K_k = -L^{-T} L_xu^T and P_k = H_xx - L_xu L_xu^T (the Schur
    complement, symmetric by construction). Returns -1 on success, else the stage whose Q_uu
    is not positive definite."""
    nt, mt, zt = tags
    n, m, nz = len(nt), len(mt), len(zt)
    N = A.shape[0]
    Pn = _stack_matrix(nt, nt)      # P_{k+1}
    G = _stack_matrix(nt, zt)       # [B_k A_k]
    W = _stack_matrix(nt, zt)       # P_{k+1} G
    H = _stack_matrix(zt, zt)       # stage Hessian, then its partial Cholesky factor
    dinv = _stack_vector(mt)        # 1 / diag(L)
    for i in range(n):
        for j in range(n):
            Pn[i, j] = 0.5 * (Q[N, i, j] + Q[N, j, i])
        Pn[i, i] += Dx[N, i]
        for j in range(n):
            P[N, i, j] = Pn[i, j]
    for k in range(N - 1, -1, -1):
        # G = [B_k A_k], W = P_{k+1} G
        for i in range(n):
            for j in range(m):
                G[i, j] = B[k, i, j]
            for j in range(n):
                G[i, m + j] = A[k, i, j]
        for i in range(n):
            for j in range(nz):
                s = 0.0
                for l in range(n):
                    s += Pn[i, l] * G[l, j]
                W[i, j] = s
        # H (lower triangle) = stage Hessian + G^T W
        for i in range(m):
            for j in range(i + 1):
                H[i, j] = 0.5 * (R[k, i, j] + R[k, j, i])
            H[i, i] += Du[k, i] + reg
        for i in range(n):
            for j in range(m):
                H[m + i, j] = S[k, i, j]
            for j in range(i + 1):
                H[m + i, m + j] = 0.5 * (Q[k, i, j] + Q[k, j, i])
            H[m + i, m + i] += Dx[k, i]
        for i in range(nz):
            for j in range(i + 1):
                s = H[i, j]
                for l in range(n):
                    s += G[l, i] * W[l, j]
                H[i, j] = s
        # stage inequality terms C^T diag(sig) C (C rows are in [x; u] order)
        for c in range(ni[k]):
            w = sig[k, c]
            if w != 0.0:
                for i in range(nz):
                    cw = w * Ci[k, c, i - m if i >= m else n + i]
                    for j in range(i + 1):
                        H[i, j] += cw * Ci[k, c, j - m if j >= m else n + j]
        # partial Cholesky: the first m columns (left-looking); a non-positive pivot (or NaN)
        # means Q_uu is not positive definite
        for j in range(m):
            s = H[j, j]
            for l in range(j):
                s -= H[j, l] * H[j, l]
            if not (s > 0.0):
                return k
            d = np.sqrt(s)
            H[j, j] = d
            inv = 1.0 / d
            dinv[j] = inv
            for i in range(j + 1, nz):
                t = H[i, j]
                for l in range(j):
                    t -= H[i, l] * H[j, l]
                H[i, j] = t * inv
        for i in range(m):
            for j in range(m):
                L[k, i, j] = H[i, j] if j <= i else 0.0
        # K = -L^{-T} L_xu^T (back substitution, one column of K per state)
        for j in range(n):
            for i in range(m - 1, -1, -1):
                t = -H[m + j, i]
                for l in range(i + 1, m):
                    t -= H[l, i] * K[k, l, j]
                K[k, i, j] = t * dinv[i]
        # P_k = H_xx - L_xu L_xu^T (lower triangle, mirrored)
        for i in range(n):
            for j in range(i + 1):
                s = H[m + i, m + j]
                for l in range(m):
                    s -= H[m + i, l] * H[m + j, l]
                Pn[i, j] = s
                Pn[j, i] = s
        for i in range(n):
            for j in range(n):
                P[k, i, j] = Pn[i, j]
    return -1


class _ContractRowCode(_RowCode):
    """_RowCode with contracted arithmetic (LLVM may fuse a multiply and an add), lane extraction
    and the transposing row reduction: what the solve sweeps here and qp_ip's _kkt_stage share."""

    def vtype(self, w):
        return _F64 if w == 1 else llir.VectorType(_F64, w)

    def add(self, a, b):
        return self.b.fadd(a, b, flags=("contract",))

    def sub(self, a, b):
        return self.b.fsub(a, b, flags=("contract",))

    def mul(self, a, b):
        return self.b.fmul(a, b, flags=("contract",))

    def axpy(self, row, a, x):
        xv = {c0: v for c0, w, v in x}
        return [(c0, w, self.add(v, self.mul(self.splat(a, w), xv[c0]))) for c0, w, v in row]

    def lanes(self, v, first, w):
        """Lanes first..first+w-1 of the vector v."""
        if w == 1:
            return self.b.extract_element(v, llir.Constant(_I32, first))
        return self.b.shuffle_vector(v, v, llir.Constant(llir.VectorType(_I32, w), list(range(first, first + w))))

    def row_sums(self, rows, W):
        """Lane i = the sum of the lanes of rows[i] (len(rows) <= W vectors of W lanes; the other
        lanes undefined): pairwise shuffles and adds, a transposing reduction."""
        if W == 1:
            return rows[0]
        L = list(rows) + [llir.Constant(self.vtype(W), llir.Undefined)] * (W - len(rows))
        b = 1
        while len(L) > 1:
            # lane order: P's block 2j, Q's block 2j, ... (ev) and the odd blocks (od)
            ev = [x for j in range(W // (2 * b)) for x in
                  [2 * j * b + t for t in range(b)] + [W + 2 * j * b + t for t in range(b)]]
            od = [x for j in range(W // (2 * b)) for x in
                  [(2 * j + 1) * b + t for t in range(b)] + [W + (2 * j + 1) * b + t for t in range(b)]]
            ev, od = (llir.Constant(llir.VectorType(_I32, W), idx) for idx in (ev, od))
            L = [self.add(self.b.shuffle_vector(L[i], L[i + 1], ev), self.b.shuffle_vector(L[i], L[i + 1], od))
                 for i in range(0, len(L), 2)]
            b *= 2
        return L[0]


class _SolveRowCode(_ContractRowCode):
    """_ContractRowCode with what _solve_back_sweep / _solve_forward_sweep need besides: zero
    extension of pieces, sums of scaled rows in interleaved partial sums, and matrix-vector
    products by rows (products summed over the pieces of a row, then the rows summed by
    row_sums)."""

    def scale(self, row, a):
        return [(c0, w, self.mul(self.splat(a, w), v)) for c0, w, v in row]

    def addrows(self, a, b):
        bv = {c0: v for c0, w, v in b}
        return [(c0, w, self.add(v, bv[c0])) for c0, w, v in a]

    def row(self, data, pieces):
        """The pieces of a row at data."""
        return [(c0, w, self.load(data, 0, 0, c0, w)) for c0, w in pieces]

    def store_row(self, row, data):
        for c0, w, v in row:
            self.store(v, data, 0, 0, c0, w)

    def widen(self, v, w, W):
        """v (width w) in the low lanes of a width-W vector, zeros above."""
        if w == W:
            return v
        if w == 1:
            return self.b.insert_element(llir.Constant(self.vtype(W), [0.0] * W), v, llir.Constant(_I32, 0))
        z = llir.Constant(self.vtype(w), [0.0] * w)
        return self.widen(self.b.shuffle_vector(v, z, llir.Constant(llir.VectorType(_I32, 2 * w),
                                                                     list(range(2 * w)))), 2 * w, W)

    def row_dot(self, pairs):
        """The products of the (row piece, vector piece, width) pairs summed over pieces of the
        same width, the narrower sums added into the low lanes of the widest: one vector (or a
        double) whose lanes sum to the dot product, and its width."""
        by_w = {}
        for a, x, w in pairs:
            by_w[w] = self.mul(a, x) if w not in by_w else self.add(by_w[w], self.mul(a, x))
        ws = sorted(by_w)
        s, sw = by_w[ws[0]], ws[0]
        for w in ws[1:]:
            s, sw = self.add(by_w[w], self.widen(s, sw, w)), w
        return s, sw

    def matvec(self, dots, W, out_pieces):
        """The row results of dots (row_dot vectors, all of width W >= the widths of
        out_pieces) in out_pieces."""
        out = []
        for r0, w in out_pieces:
            v = self.row_sums(dots[r0:r0 + w], W)
            out.append((r0, w, v if w == W else self.lanes(v, 0, w)))
        return out

    def accumulate(self, init, coefs, rows, nacc=2):
        """init + sum_l coefs[l] rows[l] (init None: 0) in nacc interleaved partial sums (shorter
        dependency chains)."""
        accs = []
        for l, (a, row) in enumerate(zip(coefs, rows)):
            if l < nacc:
                accs.append(self.scale(row, a) if l or init is None else self.axpy(init, a, row))
            else:
                accs[l % nacc] = self.axpy(accs[l % nacc], a, row)
        if not accs:
            return init
        out = accs[0]
        for acc in accs[1:]:
            out = self.addrows(out, acc)
        return out


def _c_arrays(*arrs, ndim):
    return all(isinstance(a, types.Array) and a.ndim == nd and a.dtype == types.float64 and a.layout == "C"
               for a, nd in zip(arrs, ndim))


def _stage_pointers(builder, k, data, where):
    """{name: pointer to stage k (+ offset) of an array} for where = {name: (array data pointer,
    stage offset, elements per stage)}."""
    out = {}
    for name, (ptr, off, size) in where.items():
        i = builder.mul(builder.add(k, llir.Constant(_I64, off)), llir.Constant(_I64, size))
        out[name] = builder.gep(ptr, [i])
    return out


def _back_stage(g, d, n, m, pn, gk):
    """Code of one stage of the backward sweep (see _solve_back_sweep) on the stage pointers d,
    p_{k+1} given (pieces); stores p_k and k_k, returns p_k (pieces)."""
    b = g.b
    xp, up = _pieces(0, n), _pieces(0, m)
    rows = lambda name, cnt, pieces, ncols: [g.row(b.gep(d[name], [llir.Constant(_I64, l * ncols)]), pieces)  # noqa: E731
                                             for l in range(cnt)]
    cs = [g.load(d["c"], 0, 0, l) for l in range(n)]
    # t = P_{k+1} c_k + p_{k+1} (p_{k+1} last: it is on the dependency chain of the sweep)
    Pc = g.accumulate(None, cs, rows("Pn", n, xp, n))
    t = g.addrows(Pc, pn)
    ts = [g.entry(t, l) for l in range(n)]
    qx = g.row(d["q"], xp)
    qu = g.row(d["r"], up)
    if gk is not None:
        qx = g.addrows(qx, g.row(gk, xp))
        qu = g.addrows(qu, g.row(b.gep(gk, [llir.Constant(_I64, n)]), up))
    qx = g.accumulate(qx, ts, rows("A", n, xp, n))
    qu = g.accumulate(qu, ts, rows("B", n, up, m))
    qus = [g.entry(qu, l) for l in range(m)]
    p = g.accumulate(qx, qus, rows("K", m, xp, n))
    # reciprocals of diag(L) by pieces
    Lk = lambda i, l: g.load(d["L"], m, i, l)  # noqa: E731
    dinv = []
    for c0, w in up:
        if w == 1:
            dg = Lk(c0, c0)
        else:
            dg = llir.Constant(g.vtype(w), llir.Undefined)
            for j in range(w):
                dg = b.insert_element(dg, Lk(c0 + j, c0 + j), llir.Constant(_I32, j))
        dv = b.fdiv(llir.Constant(g.vtype(w), 1.0 if w == 1 else [1.0] * w), dg)
        dinv += [dv] if w == 1 else [b.extract_element(dv, llir.Constant(_I32, j)) for j in range(w)]
    # L y = -q_u, L^T z = y (scalar substitutions, the newest unknown last)
    y = [None] * m
    for i in range(m):
        s = b.fsub(llir.Constant(_F64, -0.0), qus[i])
        for l in range(i):
            s = g.sub(s, g.mul(Lk(i, l), y[l]))
        y[i] = g.mul(s, dinv[i])
    for i in range(m - 1, -1, -1):
        s = y[i]
        for l in range(m - 1, i, -1):
            s = g.sub(s, g.mul(Lk(l, i), y[l]))
        y[i] = g.mul(s, dinv[i])
    g.store_row(p, d["p"])
    for i in range(m):
        g.store(y[i], d["U"], 0, 0, i)
    return p


def _forward_stage(g, d, n, m, x):
    """Code of one stage of the forward sweep (see _solve_forward_sweep) on the stage pointers
    d, x_k given (pieces); stores u_k, lam_k, x_{k+1} and returns x_{k+1} (pieces)."""
    b = g.b
    xp, up = _pieces(0, n), _pieces(0, m)
    W = max(w for _, w in xp + up)
    rowp = lambda name, l, ncols: b.gep(d[name], [llir.Constant(_I64, l * ncols)])  # noqa: E731
    xs = [g.entry(x, l) for l in range(n)]

    def dots(pairs_list):
        out = []
        for pairs in pairs_list:
            v, w = g.row_dot(pairs)
            out.append(g.widen(v, w, W))
        return out
    Kd = dots([[(a, xv, w) for (_, w, a), (_, _, xv) in zip(g.row(rowp("K", i, n), xp), x)] for i in range(m)])
    u = g.addrows(g.matvec(Kd, W, up), g.row(d["U"], up))
    lam = g.addrows(g.accumulate(None, xs, [g.row(rowp("P", l, n), xp) for l in range(n)]), g.row(d["lam"], xp))
    ABd = dots([[(a, xv, w) for (_, w, a), (_, _, xv) in zip(g.row(rowp("A", i, n), xp), x)]
                + [(bb, uv, w) for (_, w, bb), (_, _, uv) in zip(g.row(rowp("B", i, m), up), u)]
                for i in range(n)])
    xn = g.addrows(g.matvec(ABd, W, xp), g.row(d["c"], xp))
    g.store_row(u, d["U"])
    g.store_row(lam, d["lam"])
    g.store_row(xn, d["X1"])
    return xn


def _carry(builder, pieces):
    """Stack slots for values carried from one iteration of a sweep to the next (promoted to
    registers by LLVM)."""
    return [(c0, w, cgutils.alloca_once(builder, _F64 if w == 1 else llir.VectorType(_F64, w)))
            for c0, w in pieces]


def _as_i64(builder, v):
    return builder.sext(v, _I64) if v.type.width < 64 else v


@intrinsic
def _solve_back_sweep(typingctx, tags, k_lo, k_hi, P, p, c, A, B, K, L, q, r, gk, U):
    """Stages k = k_hi - 1, ..., k_lo of the backward sweep of _solve_unconstrained_fixed as
    straight-line SIMD code in one loop, p_k carried in registers from stage to stage; for the
    sizes of tags = _size_tags(n, m, n + m), C-contiguous float64 arrays of the kernel's shapes,
    P_k symmetric (as the factorizations store it), p (the kernel's lam) holding p_{k_hi} on
    entry; gk None or the stage-row gradient terms C^T sig ci (n + m values, [x; u]) added to
    every stage of the range. Stage k writes p_k -> p[k] and k_k -> U[k]:
        t = P_{k+1} c_k + p_{k+1}  (sum of rows of P_{k+1}), q_x = q_k + A^T t, q_u = r_k + B^T t
        (+ gk), p_k = q_x + K^T q_u (axpys over rows), k_k = -L^{-T} L^{-1} q_u (scalar
        substitutions, multiplied by the reciprocals of diag(L), computed by pieces)."""
    if not (_c_arrays(P, p, c, A, B, K, L, q, r, U, ndim=(3, 2, 2, 3, 3, 3, 3, 2, 2, 2))
            and (gk == types.none or _c_arrays(gk, ndim=(1,)))
            and isinstance(k_lo, types.Integer) and isinstance(k_hi, types.Integer)):
        return None
    n, m = len(tags[0]), len(tags[1])

    def codegen(context, builder, signature, args):
        g = _SolveRowCode(builder)
        names = ("P", "p", "c", "A", "B", "K", "L", "q", "r", "gk", "U")
        data = {name: context.make_array(t)(context, builder, v).data
                for name, t, v in zip(names, signature.args[3:], args[3:]) if t != types.none}
        k_lo, k_hi = _as_i64(builder, args[1]), _as_i64(builder, args[2])
        where = {"Pn": (data["P"], 1, n * n), "c": (data["c"], 0, n), "A": (data["A"], 0, n * n),
                 "B": (data["B"], 0, n * m), "K": (data["K"], 0, m * n), "L": (data["L"], 0, m * m),
                 "q": (data["q"], 0, n), "r": (data["r"], 0, m), "p": (data["p"], 0, n), "U": (data["U"], 0, m)}
        xp = _pieces(0, n)
        slots = _carry(builder, xp)
        p0 = g.row(builder.gep(data["p"], [builder.mul(k_hi, llir.Constant(_I64, n))]), xp)
        for (_, _, v), (_, _, s) in zip(p0, slots):
            builder.store(v, s)
        with cgutils.for_range(builder, builder.sub(k_hi, k_lo)) as loop:
            k = builder.sub(builder.sub(k_hi, llir.Constant(_I64, 1)), loop.index)
            pn = [(c0, w, builder.load(s)) for c0, w, s in slots]
            p = _back_stage(g, _stage_pointers(builder, k, data, where), n, m, pn, data.get("gk"))
            for (_, _, v), (_, _, s) in zip(p, slots):
                builder.store(v, s)
        return context.get_dummy_value()
    return types.none(tags, k_lo, k_hi, P, p, c, A, B, K, L, q, r, gk, U), codegen


@intrinsic
def _solve_forward_sweep(typingctx, tags, X, K, U, P, lam, A, B, c):
    """The forward sweep of _solve_unconstrained_fixed as straight-line SIMD code in one loop
    over the stages, x_k carried in registers (arguments as _solve_back_sweep): from x_0 in
    X[0], k_k in U[k] and p_k in lam[k], stage k writes u_k = K_k x_k + k_k -> U[k],
    lam_k = P_k x_k + p_k -> lam[k] (sum of rows of the symmetric P_k) and
    x_{k+1} = A_k x_k + B_k u_k + c_k -> X[k + 1] (row products summed by a transposing
    reduction)."""
    if not _c_arrays(X, K, U, P, lam, A, B, c, ndim=(2, 3, 2, 3, 2, 3, 3, 2)):
        return None
    n, m = len(tags[0]), len(tags[1])

    def codegen(context, builder, signature, args):
        g = _SolveRowCode(builder)
        names = ("X", "K", "U", "P", "lam", "A", "B", "c")
        aryX = context.make_array(signature.args[1])(context, builder, args[1])
        data = {name: context.make_array(t)(context, builder, v).data
                for name, t, v in zip(names, signature.args[1:], args[1:])}
        N = builder.extract_value(aryX.shape, 0)
        N = builder.sub(N, llir.Constant(N.type, 1))
        where = {"X1": (data["X"], 1, n), "K": (data["K"], 0, m * n), "U": (data["U"], 0, m),
                 "P": (data["P"], 0, n * n), "lam": (data["lam"], 0, n), "A": (data["A"], 0, n * n),
                 "B": (data["B"], 0, n * m), "c": (data["c"], 0, n)}
        xp = _pieces(0, n)
        slots = _carry(builder, xp)
        for (_, _, v), (_, _, s) in zip(g.row(data["X"], xp), slots):
            builder.store(v, s)
        with cgutils.for_range(builder, N) as loop:
            x = [(c0, w, builder.load(s)) for c0, w, s in slots]
            xn = _forward_stage(g, _stage_pointers(builder, _as_i64(builder, loop.index), data, where), n, m, x)
            for (_, _, v), (_, _, s) in zip(xn, slots):
                builder.store(v, s)
        return context.get_dummy_value()
    return types.none(tags, X, K, U, P, lam, A, B, c), codegen


@nb.njit(cache=True, fastmath=_REASSOC)
def _solve_unconstrained_fixed(tags, A, B, Ci, sig, ni, P, K, L, q, r, c, x0, ci, X, U, lam):
    """One right-hand side without equality rows, compiled for the sizes of tags (as
    _factor_unconstrained_fixed).

    Backward: t = P_{k+1} c_k + p_{k+1}, q_x = q_k + A^T t, q_u = r_k + B^T t (+ C^T sig ci),
    p_k = q_x + K_k^T q_u, k_k = -Q_uu^{-1} q_u. Forward: u_k = K_k x_k + k_k,
    x_{k+1} = A_k x_k + B_k u_k + c_k, and the multipliers lam_k = P_k x_k + p_k (the gradient
    of the cost-to-go; the same as the x-stationarity rows lam_k = Q_xx x_k + Q_xu u_k + q_x,
    exactly so in exact arithmetic, with Dx, the C terms and the regularization included).
    lam holds p and U holds k_k between the sweeps. The sweeps are straight-line SIMD code
    (_solve_back_sweep over runs of stages without stage rows, one stage at a time with them;
    _solve_forward_sweep); P_k must be symmetric (as the factorizations store it)."""
    nt, mt, zt = tags
    n, m = len(nt), len(mt)
    N = A.shape[0]
    gc = _stack_vector(zt)
    for i in range(n):
        lam[N, i] = q[N, i]
    k = N - 1
    while k >= 0:
        if ni[k] > 0:
            # stage-row terms C^T sig ci ([x; u] order, as the rows of C)
            for i in range(n + m):
                gc[i] = 0.0
            for cc in range(ni[k]):
                wgt = sig[k, cc] * ci[k, cc]
                if wgt != 0.0:
                    for i in range(n + m):
                        gc[i] += Ci[k, cc, i] * wgt
            _solve_back_sweep(tags, k, k + 1, P, lam, c, A, B, K, L, q, r, gc, U)
            k -= 1
        else:
            j = k - 1
            while j >= 0 and ni[j] == 0:
                j -= 1
            _solve_back_sweep(tags, j + 1, k + 1, P, lam, c, A, B, K, L, q, r, None, U)
            k = j
    for i in range(n):
        X[0, i] = x0[i]
    _solve_forward_sweep(tags, X, K, U, P, lam, A, B, c)
    for i in range(n):
        s = lam[N, i]
        for l in range(n):
            s += P[N, i, l] * X[N, l]
        lam[N, i] = s


# ============================================================================= Python API
@dataclasses.dataclass
class LQSolution:
    """Solution of one right-hand side: states X (N+1, n), controls U (N, m), dynamics
    multipliers lam (N+1, n) (lam[0] belongs to x_0 = xbar_0), equality multipliers nu
    (N+1, ne) (nu[N] for E_N), and ``x0_residual``, the infeasibility of the equality rows
    (max norm): for the Riccati recursion the residual of the rows reaching the fixed x_0 and the
    consistency defects of the dependent rows it dropped (0 up to rounding when the constraint
    set is consistent; with an inconsistent set the other rows are still satisfied)."""

    X: np.ndarray
    U: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    x0_residual: float


def _f64(a, shape, name):
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {arr.shape}")
    return arr


class StageData:
    """Validated stage arrays of an LQ-DOCP KKT system (the constructor arguments of
    :class:`RiccatiFactorization` and of the sparse back-ends in :mod:`olado.linalg.kkt`):
    defaults for the optional parts, per-stage counts n_eq / n_ineq."""

    def __init__(self, Q, S, R, A, B, E=None, F=None, n_eq=None, EN=None, Dx=None, Du=None, Ci=None,
                 sigma=None, n_ineq=None, regularization=0.0):
        A = np.ascontiguousarray(A, dtype=np.float64)
        if A.ndim != 3 or A.shape[1] != A.shape[2]:
            raise ValueError(f"A: expected shape (N, n, n), got {A.shape}")
        N, n = A.shape[0], A.shape[1]
        B = np.ascontiguousarray(B, dtype=np.float64)
        if B.ndim != 3 or B.shape[:2] != (N, n):
            raise ValueError(f"B: expected shape ({N}, {n}, m), got {B.shape}")
        m = B.shape[2]
        self.N, self.n, self.m = N, n, m
        self.A, self.B = A, B
        self.Q = _f64(Q, (N + 1, n, n), "Q")
        self.S = np.zeros((N, n, m)) if S is None else _f64(S, (N, n, m), "S")
        self.R = _f64(R, (N, m, m), "R")
        if E is None:
            self.ne_max = 0
            self.E, self.F = np.zeros((N, 0, n)), np.zeros((N, 0, m))
            self.ne = np.zeros(N, dtype=np.int64)
        else:
            E = np.asarray(E, dtype=np.float64)
            self.ne_max = E.shape[1]
            self.E = _f64(E, (N, self.ne_max, n), "E")
            self.F = _f64(F, (N, self.ne_max, m), "F")
            self.ne = (np.full(N, self.ne_max, dtype=np.int64) if n_eq is None
                       else _f64(n_eq, (N,), "n_eq").astype(np.int64))
        self.EN = np.zeros((0, n)) if EN is None else np.ascontiguousarray(np.atleast_2d(EN), dtype=np.float64)
        if self.EN.shape[1] != n:
            raise ValueError(f"EN: expected shape (neN, {n}), got {self.EN.shape}")
        self.neN = self.EN.shape[0]
        self.Dx = np.zeros((N + 1, n)) if Dx is None else _f64(Dx, (N + 1, n), "Dx")
        self.Du = np.zeros((N, m)) if Du is None else _f64(Du, (N, m), "Du")
        if Ci is None:
            self.Ci, self.sig = np.zeros((N, 0, n + m)), np.zeros((N, 0))
            self.ni = np.zeros(N, dtype=np.int64)
        else:
            self.Ci = np.ascontiguousarray(Ci, dtype=np.float64)
            if self.Ci.ndim != 3 or self.Ci.shape[0] != N or self.Ci.shape[2] != n + m:
                raise ValueError(f"Ci: expected shape ({N}, nineq, {n + m}), got {self.Ci.shape}")
            self.sig = _f64(sigma, self.Ci.shape[:2], "sigma")
            self.ni = (np.full(N, self.Ci.shape[1], dtype=np.int64) if n_ineq is None
                       else _f64(n_ineq, (N,), "n_ineq").astype(np.int64))
        self.ni_max = self.Ci.shape[1]
        self.regularization = float(regularization)
        # active masks of the padded row slots
        self.eq_mask = np.arange(self.ne_max)[None, :] < self.ne[:, None]                      # (N, ne_max)
        self.ineq_active = np.arange(self.ni_max)[None, :] < self.ni[:, None]                  # (N, ni_max)
        self.ineq_w = np.where(self.ineq_active, self.sig, 0.0)                                 # (N, ni_max)

    def rhs_arrays(self, q, r, c, x0, e, eN, ci):
        N, n, m = self.N, self.n, self.m
        q = _f64(q, (N + 1, n), "q"); r = _f64(r, (N, m), "r"); c = _f64(c, (N, n), "c"); x0 = _f64(x0, (n,), "x0")
        e = np.zeros((N, self.ne_max)) if e is None else _f64(e, (N, self.ne_max), "e")
        eN = np.zeros(self.neN) if eN is None else _f64(eN, (self.neN,), "eN")
        ci = np.zeros(self.sig.shape) if ci is None else _f64(ci, self.sig.shape, "ci")
        return q, r, c, x0, e, eN, ci



class RiccatiFactorization(StageData):
    """Factorization of the LQ-DOCP KKT matrix; :meth:`solve` applies it to right-hand sides."""

    def __init__(self, Q, S, R, A, B, *, E=None, F=None, n_eq=None, EN=None, Dx=None, Du=None,
                 Ci=None, sigma=None, n_ineq=None, regularization=0.0, rank_tol=1e-10):
        StageData.__init__(self, Q, S, R, A, B, E=E, F=F, n_eq=n_eq, EN=EN, Dx=Dx, Du=Du, Ci=Ci, sigma=sigma,
                           n_ineq=n_ineq, regularization=regularization)
        N, n, m = self.N, self.n, self.m
        self.rank_tol = float(rank_tol)
        # fast path: no equality rows anywhere -> plain Riccati recursion, none of the constraint
        # workspaces (QR factors, propagated rows) are allocated
        self.unconstrained = self.neN == 0 and (self.ne_max == 0 or not self.ne.any())
        if self.unconstrained:
            self.ncmax = 0
            self.P = np.empty((N + 1, n, n)); self.K = np.empty((N, m, n)); self.Lww = np.empty((N, m, m))
            # small blocks: the kernel compiled for these sizes (see _FIXED_SIZE_MAX)
            self._size_tags = _size_tags(n, m, n + m) if 0 < n and 0 < m and n + m <= _FIXED_SIZE_MAX else None
        else:
            ncmax = max(self.ne_max + n + self.neN, 1)
            self.ncmax = ncmax
            self.P = np.empty((N + 1, n, n)); self.K = np.empty((N, m, n))
            self.Quu = np.empty((N, m, m)); self.Qux = np.empty((N, m, n)); self.Lww = np.zeros((N, m, m))
            self.Qm = np.empty((N, m, m)); self.Rm = np.zeros((N, m, ncmax))
            self.perm = np.zeros((N, ncmax), dtype=np.int64)
            self.rank = np.zeros(N, dtype=np.int64); self.nc = np.zeros(N, dtype=np.int64)
            self.Cx = np.zeros((N, ncmax, n)); self.G = np.zeros((N + 1, ncmax, n))
            self.ng = np.zeros(N + 1, dtype=np.int64)
            self.Wx = np.zeros((N, ncmax, n)); self.Dmat = np.zeros((N, ncmax, ncmax))
            # compression of the passed-back rows: row permutation, dropped rows in terms of the kept
            self.pg = np.zeros((N, ncmax), dtype=np.int64); self.Zg = np.zeros((N, max(n, 1), ncmax))
        self._factorize()

    def refactor(self, Dx=None, Du=None, sigma=None, regularization=None):
        """Factorize again after a change of the diagonal terms only -- the interior-point
        Newton matrix of the next iteration: new Dx (N+1, n), Du (N, m), stage-row weights sigma
        and/or regularization; Q, S, R, A, B and the equality rows stay.  The factors are
        overwritten in place (no new allocation: on large N the first touch of fresh factor
        arrays costs as much as the kernel).  Raises NotPositiveDefiniteError like the
        constructor (the object must then be refactored before the next solve).  Arrays that are
        the ones already held (updated in place by the caller) are not validated again."""
        N, n, m = self.N, self.n, self.m
        if Dx is not None and Dx is not self.Dx:
            self.Dx = _f64(Dx, (N + 1, n), "Dx")
        if Du is not None and Du is not self.Du:
            self.Du = _f64(Du, (N, m), "Du")
        if sigma is not None:
            if sigma is not self.sig:
                self.sig = _f64(sigma, self.Ci.shape[:2], "sigma")
                self.ineq_w = np.where(self.ineq_active, self.sig, 0.0)
            else:
                np.copyto(self.ineq_w, self.sig, where=self.ineq_active)
        if regularization is not None:
            self.regularization = float(regularization)
        self._factorize()
        return self

    def _factorize(self):
        if self.unconstrained:
            args = (self.Q, self.S, self.R, self.A, self.B, self.Dx, self.Du, self.Ci, self.sig, self.ni,
                    self.regularization, self.P, self.K, self.Lww)
            if self._size_tags is None:
                code = _factor_unconstrained(*args)
            elif self.n <= _STRAIGHT_N_MAX:
                code = _factor_unconstrained_fixed(self._size_tags, *args)
            else:
                code = _factor_unconstrained_fixed_loops(self._size_tags, *args)
            if code >= 0:
                raise NotPositiveDefiniteError(code)
            return
        ncmax = self.ncmax
        for w in (self.Lww, self.Rm, self.perm, self.rank, self.nc, self.Cx, self.G, self.ng, self.Wx, self.Dmat,
                  self.pg, self.Zg):
            w.fill(0)   # the general kernel expects zeroed padding (a refactor reuses the arrays)
        code = _factor(self.Q, self.S, self.R, self.A, self.B, self.E, self.F, self.ne, self.EN, self.neN,
                       self.Dx, self.Du, self.Ci, self.sig, self.ni, self.regularization, self.rank_tol,
                       self.P, self.K, self.Quu, self.Qux, self.Lww, self.Qm, self.Rm, self.perm, self.rank,
                       self.nc, self.Cx, self.G, self.ng, self.Wx, self.Dmat, self.pg, self.Zg)
        if code >= 0:
            raise NotPositiveDefiniteError(code)
        if code <= -1000:
            raise RiccatiStatusError(f"more than {ncmax} equality rows reach stage k={-code - 1000} "
                                     "(more than the row buffers hold)")

    def solve(self, q, r, c, x0, e=None, eN=None, ci=None, out=None) -> LQSolution:
        """Solve for one right-hand side: linear cost terms q (N+1, n), r (N, m); dynamics
        offsets c (N, n); initial state x0 (n,); equality offsets e (N, ne), eN (neN,); for the
        stage inequality terms, ci (N, nineq) is the constant in C_k z_k + ci_k (the Hessian term
        sigma * C^T C adds sigma * C^T ci to the gradient).  ``out`` = (X, U, lam): C-contiguous
        float arrays of shapes (N+1, n), (N, m), (N+1, n) to write the solution into (the
        returned LQSolution holds them)."""
        N, n, m = self.N, self.n, self.m
        q, r, c, x0, e, eN, ci = self.rhs_arrays(q, r, c, x0, e, eN, ci)
        if out is None:
            X = np.empty((N + 1, n)); U = np.empty((N, m)); lam = np.empty((N + 1, n))
        else:
            X, U, lam = out
            for a, shape, name in ((X, (N + 1, n), "X"), (U, (N, m), "U"), (lam, (N + 1, n), "lam")):
                if a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous:
                    raise ValueError(f"out: {name} must be a C-contiguous float64 array of shape {shape}")
        nu = np.zeros((N + 1, max(self.ne_max, self.neN)))
        if self.unconstrained:
            self.solve_trusted(q, r, c, x0, ci, X, U, lam)
            return LQSolution(X, U, lam, nu, 0.0)
        kff = np.empty((N, m)); pvec = np.empty((N + 1, n))
        gvec = np.zeros((N + 1, self.ncmax)); dvec = np.zeros((N, self.ncmax))
        res = _solve(self.A, self.B, c, q, r, e, eN, x0, self.Dx, self.Du, self.S, self.Q, self.R, self.E, self.F,
                     self.ne, self.EN, self.neN, self.Ci, self.sig, self.ni, ci,
                     self.P, self.K, self.Quu, self.Qux, self.Lww, self.Qm, self.Rm, self.perm, self.rank, self.nc,
                     self.Cx, self.G, self.ng, self.Wx, self.Dmat, self.pg, self.Zg, X, U, lam, nu, kff, pvec, gvec,
                     dvec)
        return LQSolution(X, U, lam, nu, float(res))


    def solve_trusted(self, q, r, c, x0, ci, X, U, lam):
        """:meth:`solve` without argument checks or result object, for callers whose arrays are
        already C-contiguous float64 of the right shapes (the interior-point QP's work arrays,
        validated once when the QP is prepared): writes the solution into X, U, lam.  Only for
        factorizations without equality rows (``unconstrained``); ``ci`` (N, nineq) is required
        (zero columns when there are no stage rows)."""
        if self._size_tags is None:
            _solve_unconstrained(self.Q, self.S, self.A, self.B, self.Dx, self.Ci, self.sig, self.ni,
                                 self.P, self.K, self.Lww, q, r, c, x0, ci, X, U, lam,
                                 np.empty((self.N, self.m)), np.empty((self.N + 1, self.n)))
        else:
            _solve_unconstrained_fixed(self._size_tags, self.A, self.B, self.Ci, self.sig, self.ni,
                                       self.P, self.K, self.Lww, q, r, c, x0, ci, X, U, lam)


def solve_lq_docp(Q, S, R, q, r, A, B, c, x0, **kw) -> LQSolution:
    """Factorize and solve in one call (see :class:`RiccatiFactorization`)."""
    rhs = {k: kw.pop(k) for k in ("e", "eN", "ci") if k in kw}
    return RiccatiFactorization(Q, S, R, A, B, **kw).solve(q, r, c, x0, **rhs)
