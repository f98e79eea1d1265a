"""The compiled kernels of the block Riccati recursion (paper 001 sec. 4.2.3): the general
kernels with equality rows and the plain (no equality rows) kernels for any block size.

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
unique). So at most ne_max + max(n, neN) rows ever reach a stage. The solve takes the dynamics
multipliers from the cost-to-go, lam_k = P_k x_k + p_k - G_k^T eta_k, not from the x-stationarity
rows' backward recursion, whose rounding grows like (A^T)^(N-k) on unstable dynamics (:func:`_solve`).

Without any equality rows (the usual interior-point case: only bounds and inequalities, folded
into Dx, Du, C^T diag(sigma) C) the plain Riccati recursion applies: no QR, no propagated rows,
and only P_k, K_k and the Cholesky factor of Q_uu are stored (:func:`_factor_unconstrained`,
:func:`_solve_unconstrained`; for small blocks :mod:`olado.linalg.riccati_fixed`).

The stage loops run on preallocated arrays (no allocation inside the loops). Cost:
O(N (n+m)^3) for the factorization, O(N (n+m)^2) per right-hand side.
"""

from __future__ import annotations

import collections

import numba as nb
import numpy as np

from .backend import RHS, Solution
from .codegen import as_bundle

# ---------------------------------------------------------------- the kernels' argument bundles
# (the kernels take them as plain tuples and read them by name through codegen.as_bundle)
#: the stage arrays of an LQ-DOCP KKT system, by role (a kernel takes the roles it reads):
#: the cost blocks Q (N+1, n, n), S (N, n, m), R (N, m, m) ...
Costs = collections.namedtuple("Costs", "Q S R")
#: ... the dynamics A (N, n, n), B (N, n, m) ...
Dynamics = collections.namedtuple("Dynamics", "A B")
#: ... the stage equality rows E (N, ne_max, n), F (N, ne_max, m), of which the first ne[k] count
#: at stage k, and the final rows EN (neN, n) ...
EqualityRows = collections.namedtuple("EqualityRows", "E F ne EN")
#: ... and the interior-point terms: the diagonal terms Dx (N+1, n), Du (N, m) and the stage
#: inequality terms C_k^T diag(sig_k) C_k, Ci (N, ni_max, n+m) and sig (N, ni_max), of which the
#: first ni[k] count
IPTerms = collections.namedtuple("IPTerms", "Dx Du Ci sig ni")
#: the factors of the general recursion (see _factor)
#: (``dropped`` (N,): per stage the largest relative u-part of a combined row that was not used as
#: a pivot although it exceeds rank_tol -- the static pivots of :func:`_factor`)
GeneralFactors = collections.namedtuple("GeneralFactors",
                                        "P K Quu Qux Lww Qm Rm perm rank nc Cx G ng Wx Dmat pg Zg dropped")
#: the factors of the plain recursion: P_k (N+1, n, n), K_k (N, m, n) and the Cholesky factor L_k
#: (N, m, m) of Q_uu
PlainFactors = collections.namedtuple("PlainFactors", "P K L")
# (the right-hand side and the solution arrays: olado.linalg.backend.RHS, .Solution)


@nb.njit(cache=True)
def chol_inplace(a, d):
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
def chol_solve_vec(L, d, b):
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
def chol_solve_mat(L, d, B, ncol):
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
def _cost_to_go_gradient(P, pvec, X, lam):
    """lam_k = P_k x_k + p_k for every stage: the gradient of the cost-to-go, the dynamics
    multipliers taken forward from the factors (the x-stationarity rows' backward recursion
    through A_k^T multiplies its rounding by (A^T)^(N-k) on unstable dynamics)."""
    n = X.shape[1]
    for k in range(X.shape[0]):
        for i in range(n):
            s = pvec[k, i]
            for l in range(n):
                s += P[k, i, l] * X[k, l]
            lam[k, i] = s


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
def _factor(costs, dyn, eq, ipt, reg, rank_tol, pivot_tol, fac, k_start):
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
    stored in G (rows on x_k only).

    ``k_start`` < N - 1 factors only the stages k <= k_start again: the factors of the later
    stages and of the terminal stage (P, G, ng) are those of the last factorization into ``fac``
    (the caller changed nothing there); k_start = N - 1 is the whole sweep."""
    costs = as_bundle(costs, Costs)
    Q, S, R = costs.Q, costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    eq = as_bundle(eq, EqualityRows)
    E, F, ne, EN = eq.E, eq.F, eq.ne, eq.EN
    ipt = as_bundle(ipt, IPTerms)
    Dx, Du, Ci, sig, ni = ipt.Dx, ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    neN = EN.shape[0]
    fac = as_bundle(fac, GeneralFactors)
    P, K, Quu_s, Qux_s, Lww, Qm, Rm = fac.P, fac.K, fac.Quu, fac.Qux, fac.Lww, fac.Qm, fac.Rm
    perm, rank, nc, Cx_s, G, ng = fac.perm, fac.rank, fac.nc, fac.Cx, fac.G, fac.ng
    Wx, Dmat, pg, Zg, dropped = fac.Wx, fac.Dmat, fac.pg, fac.Zg, fac.dropped
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
    if k_start >= N - 1:
        for i in range(n):
            for j in range(n):
                P[N, i, j] = Q[N, i, j]
            P[N, i, i] += Dx[N, i]
        ng[N] = neN
        for i in range(neN):
            for j in range(n):
                G[N, i, j] = EN[i, j]
    for k in range(min(k_start, N - 1), -1, -1):
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
            rk = _qr_pivot(M, m, nck, Qm[k], perm[k], vt, nr, pivot_tol, 1.0, True, wu[:nck])
            for i in range(m):
                for j in range(nck):
                    Rm[k, i, j] = M[i, j]
            # static pivots: the largest relative u-part left in the rows passed back (R22);
            # above rank_tol it is a coupling the factorization leaves out (pivot_tol > rank_tol)
            big = 0.0
            for c in range(rk, nck):
                s = 0.0
                for i in range(rk, m):
                    s += M[i, c] * M[i, c]
                big = max(big, np.sqrt(s) * wu[perm[k, c]])
            dropped[k] = big if big > rank_tol else 0.0
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
        if not chol_inplace(Lww[k], dw):
            return k
        # Qwx <- Qww^{-1} Qwx
        chol_solve_mat(Lww[k], dw, Qwx, n)
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
def _solve(costs, dyn, eq, ipt, fac, rhs, sol):
    """One right-hand side (paper 001 sec. 4.2.3): backward vector sweep, forward simulation,
    multiplier sweeps, with the factors of :func:`_factor`.

    The backward sweep forms the constants of the passed-back rows as the factorization formed
    the rows: graw = R12^T v1 - Pi_2^T d, then g_k = (Pi_g^T graw)[:rg] for the kept rows and the
    consistency defect (Pi_g^T graw)[rg:] - Zg^T g_k of the dropped (dependent) ones. In the
    forward multiplier sweep the multipliers eta_k of the kept rows G_k are those of the rows
    (Pi_g^T Graw)[:rg], the dropped rows get zero (their multipliers are not unique;
    Graw^T eta_raw = G_k^T eta_k, so the stationarity rows hold), and eta_raw is mapped through
    perm / Dmat into the multipliers of the stage's combined rows as before.

    The multipliers of the dynamics are lam_k = a_k - G_k^T eta_k with a_k = P_k x_k + p_k, the
    gradient of the cost-to-go: the x-stationarity rows give the same a_k in exact arithmetic,
    a_k = Q_xx x_k + Q_xu u_k + q_x + A_k^T a_{k+1} + Cx^T Pi_1 c_k (since K_k^T b_u = Cx^T Pi_1 c_k
    and Q_2^T b_u = 0), but as a backward recursion through A_k^T that multiplies its rounding by
    (A^T)^(N-k) -- on unstable dynamics (alp-rider's, eigenvalue 1.49) the control rows' residual
    reached 0.3 at N = 100 (tests/linalg/test_riccati_unstable_final_rows.py); P_k x_k + p_k has
    the accuracy of the stable closed-loop forward sweep.

    Returns the infeasibility of the equality rows (max norm): the largest of the residual
    G_0 x0 + g_0 of the rows reaching x_0 and the consistency defects of the dependent rows
    dropped at every stage (zero up to rounding for a consistent constraint set)."""
    costs = as_bundle(costs, Costs)
    S, R = costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    eq = as_bundle(eq, EqualityRows)
    ne, EN = eq.ne, eq.EN
    ipt = as_bundle(ipt, IPTerms)
    Du, Ci, sig, ni = ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    neN = EN.shape[0]
    fac = as_bundle(fac, GeneralFactors)
    P, K, Quu_s, Qux_s, Lww, Qm, Rm = fac.P, fac.K, fac.Quu, fac.Qux, fac.Lww, fac.Qm, fac.Rm
    perm, rank, nc, Cx_s, G, ng = fac.perm, fac.rank, fac.nc, fac.Cx, fac.G, fac.ng
    Dmat, pg, Zg = fac.Dmat, fac.pg, fac.Zg
    rhs = as_bundle(rhs, RHS)
    q, r, c, x0, e, eN, ci_rhs = rhs.q, rhs.r, rhs.c, rhs.x0, rhs.e, rhs.eN, rhs.ci
    sol = as_bundle(sol, Solution)
    X, U, lam, nu = sol.X, sol.U, sol.lam, sol.nu
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    ncmax = Cx_s.shape[1]
    t1 = np.empty(n); qx = np.empty(n); qu = np.empty(m); m0 = np.empty(m); w = np.empty(max(m, 1))
    v1 = np.empty(max(ncmax, 1)); bu = np.empty(m); mu = np.empty(max(ncmax, 1)); mup = np.empty(max(ncmax, 1))
    eta = np.empty(max(ncmax, 1)); a_next = np.empty(n)
    graw = np.empty(max(ncmax, 1)); etar = np.empty(max(ncmax, 1))
    kff = np.empty((N, m)); pvec = np.empty((N + 1, n)); gvec = np.zeros((N + 1, ncmax)); dvec = np.zeros((N, ncmax))
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
        chol_solve_vec(Lww[k], dw, w)
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
    # multipliers, backward part: a_k = P_k x_k + p_k (stored in lam) -- the gradient of the
    # cost-to-go, equal in exact arithmetic to the x-stationarity rows' recursion
    # a_k = Q_xx x_k + Q_xu u_k + q_x + A_k^T a_{k+1} + Cx^T Pi [c_k; 0] (as K_k^T b_u = Cx^T Pi_1 c_k
    # and Q_2^T b_u = 0), which is unstable backwards on unstable dynamics (errors grow like
    # (A^T)^(N-k)); and the c-part c_k of the combined rows' multipliers from the u-rows
    _cost_to_go_gradient(P, pvec, X, lam)
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
        for cc in range(ni[k]):
            wgt = ci_rhs[k, cc]
            for l in range(n):
                wgt += Ci[k, cc, l] * X[k, l]
            for l in range(m):
                wgt += Ci[k, cc, n + l] * U[k, l]
            wgt *= sig[k, cc]
            for i in range(m):
                bu[i] += Ci[k, cc, n + i] * wgt
        rk = rank[k]
        # c_k = -R11^{-1} (Q^T b_u)_{1:rk}, kept in dvec[k, :rk] (d is no longer needed)
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
        for i in range(rk):
            dvec[k, i] = v1[i]
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
def _factor_unconstrained(costs, dyn, ipt, reg, fac):
    """Backward Riccati sweep without equality rows. With Q_uu = L L^T and V = L^{-1} Q_ux:
    K_k = -L^{-T} V, P_k = Q_xx - V^T V. Returns -1 on success, else the failing stage index."""
    costs = as_bundle(costs, Costs)
    Q, S, R = costs.Q, costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    ipt = as_bundle(ipt, IPTerms)
    Dx, Du, Ci, sig, ni = ipt.Dx, ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    fac = as_bundle(fac, PlainFactors)
    P, K, L = fac.P, fac.K, fac.L
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
        if not chol_inplace(L[k], m):
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
def _solve_unconstrained(costs, dyn, ipt, fac, rhs, sol):
    """One right-hand side without equality rows: backward vector sweep (kff_k = -Q_uu^{-1} q_u,
    p_k = q_x + K_k^T q_u), forward simulation, and lam_k = P_k x_k + p_k (``costs`` is not read:
    the cost blocks are in the factors)."""
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    ipt = as_bundle(ipt, IPTerms)
    Ci, sig, ni = ipt.Ci, ipt.sig, ipt.ni
    fac = as_bundle(fac, PlainFactors)
    P, K, L = fac.P, fac.K, fac.L
    rhs = as_bundle(rhs, RHS)
    q, r, c, x0, ci = rhs.q, rhs.r, rhs.c, rhs.x0, rhs.ci
    sol = as_bundle(sol, Solution)
    X, U, lam = sol.X, sol.U, sol.lam
    N = A.shape[0]
    n = A.shape[1]
    m = B.shape[2]
    t1 = np.empty(n); qu = np.empty(m)
    kff = np.empty((N, m)); pvec = np.empty((N + 1, n))
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
        chol_solve_vec(L[k], m, kff[k])
        for l in range(m):
            t = qu[l]
            for i in range(n):
                pvec[k, i] += K[k, l, i] * t
    # forward simulation
    for i in range(n):
        X[0, i] = x0[i]
    _closed_loop(A, B, c, K, kff, X, U)
    # multipliers: lam_k = P_k x_k + p_k, the gradient of the cost-to-go (as the kernels of
    # olado.linalg.riccati_fixed) -- equal in exact arithmetic to the x-stationarity rows'
    # recursion lam_k = (Q + Dx) x + S u + q + A^T lam_{k+1} + C_x^T sig (C z + ci), which is
    # unstable backwards on unstable dynamics (errors grow like (A^T)^(N-k))
    _cost_to_go_gradient(P, pvec, X, lam)
