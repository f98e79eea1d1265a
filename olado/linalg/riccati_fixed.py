"""The plain Riccati kernels (no equality rows) compiled for small blocks (paper 001 sec. 4.2.3).

For n + m <= FIXED_SIZE_MAX (:mod:`olado.linalg.codegen`) the factorization and the solve are
compiled once per (n, m) with the sizes as compile-time constants (size tags) and their stage
workspaces on the stack: about 3x faster than the any-size kernels of
:mod:`olado.linalg.riccati_kernels` at n = 6, m = 7. They are cached on disk per (n, m); a new
(n, m) costs one compilation (~2 s each). Multiply-adds may be contracted to FMAs.

The matrix part of a factorization stage is one intrinsic (:func:`_eliminate_stage`) that
unrolls the stage at compile time into straight-line SIMD code on row pieces of 4, 2 and 1
doubles held in registers (about 2x faster than scalar loops at n = 6, m = 7; 1.1-2x at other
sizes up to n = 12; slower beyond, where the scalar-loop kernel
:func:`_factor_unconstrained_fixed_loops` is kept). The solve kernel's sweeps are written the
same way (:func:`_solve_back_sweep`, :func:`_solve_forward_sweep`: one loop each, the vector
carried from stage to stage in registers; the stage intrinsics take the whole arrays and k,
since slicing a stage out costs reference counting per stage): 1.4-1.5x faster than scalar
loops at n = 6, m = 7, about 2x at n + m >= 16, 1.1x at n + m <= 5, so there is no scalar
fallback.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir as llir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .backend import RHS, Solution
from .codegen import (CONTRACT, F64, I32, I64, REASSOC, ContractRowCode, RowCode, SizeTags, as_bundle, as_i64, c_arrays,
                      carry_slots, pieces, stack_matrix, stack_vector, stage_pointers)
from .riccati_kernels import Costs, Dynamics, IPTerms, PlainFactors

_STRAIGHT_N_MAX = 12     # larger n: _factor_unconstrained_fixed_loops


@intrinsic
def _eliminate_stage(typingctx, tags, Hs, Pn, Ak, Bk, Pk, Kk, Lk):
    """One stage of _factor_unconstrained_fixed as straight-line SIMD code, for the sizes of
    tags = size_tags(n, m); all arguments are C-contiguous 2-d float64 arrays: Hs
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
        g = RowCode(builder)
        hs, pn, ak, bk, pk, kk, lk = (context.make_array(t)(context, builder, v).data
                                      for t, v in zip(signature.args[1:], args[1:]))
        upieces, xpieces = pieces(0, m), pieces(m, n)
        zero, one, mzero = (llir.Constant(F64, v) for v in (0.0, 1.0, -0.0))
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
        sqrt = builder.module.declare_intrinsic("llvm.sqrt", [F64])
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


@nb.njit(cache=True, fastmath=CONTRACT)
def _factor_unconstrained_fixed(tags, costs, dyn, ipt, reg, fac):
    """_factor_unconstrained compiled for the sizes of tags = size_tags(n, m).

    Stage k assembles the upper triangle of its Hessian in [u; x] order,
        H = [R + diag(Du) + reg I, S^T; S, Q + diag(Dx)] + [B A]^T P_{k+1} [B A] (+ C^T diag(sig) C)
    (of the symmetric parts of Q and R, which is Q and R themselves when they are symmetric),
    and eliminates the u block by a partial Cholesky factorization: H_uu = L L^T (L -> L[k]),
    L_xu = H_xu L^{-T}; then K_k = -L^{-T} L_xu^T and P_k = H_xx - L_xu L_xu^T (the Schur
    complement, symmetric by construction); see _eliminate_stage. Returns -1 on success, else
    the stage whose Q_uu is not positive definite."""
    costs = as_bundle(costs, Costs)
    Q, S, R = costs.Q, costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    ipt = as_bundle(ipt, IPTerms)
    Dx, Du, Ci, sig, ni = ipt.Dx, ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    fac = as_bundle(fac, PlainFactors)
    P, K, L = fac.P, fac.K, fac.L
    tags = as_bundle(tags, SizeTags)
    nt, mt, zt = tags.n, tags.m, tags.nz
    n, m = len(nt), len(mt)
    N = A.shape[0]
    Hs = stack_matrix(zt, zt)      # upper triangle of the stage Hessian without the P term
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


@nb.njit(cache=True, fastmath=CONTRACT)
def _factor_unconstrained_fixed_loops(tags, costs, dyn, ipt, reg, fac):
    """_factor_unconstrained_fixed in scalar loops, for n > _STRAIGHT_N_MAX (where the
    straight-line code of _eliminate_stage runs out of registers and is slower).

    Stage k works on the lower triangle of its Hessian in [u; x] order,
        H = [R + diag(Du) + reg I, S^T; S, Q + diag(Dx)] + [B A]^T P_{k+1} [B A] (+ C^T diag(sig) C)
    (of the symmetric parts of Q and R, which is Q and R themselves when they are symmetric),
    and eliminates the u block by a partial Cholesky factorization: H_uu = L L^T (L -> L[k]),
    L_xu = H_xu L^{-T}; then K_k = -L^{-T} L_xu^T and P_k = H_xx - L_xu L_xu^T (the Schur
    complement, symmetric by construction). Returns -1 on success, else the stage whose Q_uu
    is not positive definite."""
    costs = as_bundle(costs, Costs)
    Q, S, R = costs.Q, costs.S, costs.R
    dyn = as_bundle(dyn, Dynamics)
    A, B = dyn.A, dyn.B
    ipt = as_bundle(ipt, IPTerms)
    Dx, Du, Ci, sig, ni = ipt.Dx, ipt.Du, ipt.Ci, ipt.sig, ipt.ni
    fac = as_bundle(fac, PlainFactors)
    P, K, L = fac.P, fac.K, fac.L
    tags = as_bundle(tags, SizeTags)
    nt, mt, zt = tags.n, tags.m, tags.nz
    n, m, nz = len(nt), len(mt), len(zt)
    N = A.shape[0]
    Pn = stack_matrix(nt, nt)      # P_{k+1}
    G = stack_matrix(nt, zt)       # [B_k A_k]
    W = stack_matrix(nt, zt)       # P_{k+1} G
    H = stack_matrix(zt, zt)       # stage Hessian, then its partial Cholesky factor
    dinv = stack_vector(mt)        # 1 / diag(L)
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


class _SolveRowCode(ContractRowCode):
    """ContractRowCode with what _solve_back_sweep / _solve_forward_sweep need besides: zero
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
            return self.b.insert_element(llir.Constant(self.vtype(W), [0.0] * W), v, llir.Constant(I32, 0))
        z = llir.Constant(self.vtype(w), [0.0] * w)
        return self.widen(self.b.shuffle_vector(v, z, llir.Constant(llir.VectorType(I32, 2 * w),
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


def _back_stage(g, d, n, m, pn, gk):
    """Code of one stage of the backward sweep (see _solve_back_sweep) on the stage pointers d,
    p_{k+1} given (pieces); stores p_k and k_k, returns p_k (pieces)."""
    b = g.b
    xp, up = pieces(0, n), pieces(0, m)
    rows = lambda name, cnt, pieces, ncols: [g.row(b.gep(d[name], [llir.Constant(I64, l * ncols)]), pieces)  # noqa: E731
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
        qu = g.addrows(qu, g.row(b.gep(gk, [llir.Constant(I64, n)]), up))
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
                dg = b.insert_element(dg, Lk(c0 + j, c0 + j), llir.Constant(I32, j))
        dv = b.fdiv(llir.Constant(g.vtype(w), 1.0 if w == 1 else [1.0] * w), dg)
        dinv += [dv] if w == 1 else [b.extract_element(dv, llir.Constant(I32, j)) for j in range(w)]
    # L y = -q_u, L^T z = y (scalar substitutions, the newest unknown last)
    y = [None] * m
    for i in range(m):
        s = b.fsub(llir.Constant(F64, -0.0), qus[i])
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
    xp, up = pieces(0, n), pieces(0, m)
    W = max(w for _, w in xp + up)
    rowp = lambda name, l, ncols: b.gep(d[name], [llir.Constant(I64, l * ncols)])  # noqa: E731
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


@intrinsic
def _solve_back_sweep(typingctx, tags, k_lo, k_hi, P, p, c, A, B, K, L, q, r, gk, U):
    """Stages k = k_hi - 1, ..., k_lo of the backward sweep of _solve_unconstrained_fixed as
    straight-line SIMD code in one loop, p_k carried in registers from stage to stage; for the
    sizes of tags = size_tags(n, m), C-contiguous float64 arrays of the kernel's shapes,
    P_k symmetric (as the factorizations store it), p (the kernel's lam) holding p_{k_hi} on
    entry; gk None or the stage-row gradient terms C^T sig ci (n + m values, [x; u]) added to
    every stage of the range. Stage k writes p_k -> p[k] and k_k -> U[k]:
        t = P_{k+1} c_k + p_{k+1}  (sum of rows of P_{k+1}), q_x = q_k + A^T t, q_u = r_k + B^T t
        (+ gk), p_k = q_x + K^T q_u (axpys over rows), k_k = -L^{-T} L^{-1} q_u (scalar
        substitutions, multiplied by the reciprocals of diag(L), computed by pieces)."""
    if not (c_arrays(P, p, c, A, B, K, L, q, r, U, ndim=(3, 2, 2, 3, 3, 3, 3, 2, 2, 2))
            and (gk == types.none or c_arrays(gk, ndim=(1,)))
            and isinstance(k_lo, types.Integer) and isinstance(k_hi, types.Integer)):
        return None
    n, m = len(tags[0]), len(tags[1])

    def codegen(context, builder, signature, args):
        g = _SolveRowCode(builder)
        names = ("P", "p", "c", "A", "B", "K", "L", "q", "r", "gk", "U")
        data = {name: context.make_array(t)(context, builder, v).data
                for name, t, v in zip(names, signature.args[3:], args[3:]) if t != types.none}
        k_lo, k_hi = as_i64(builder, args[1]), as_i64(builder, args[2])
        where = {"Pn": (data["P"], 1, n * n), "c": (data["c"], 0, n), "A": (data["A"], 0, n * n),
                 "B": (data["B"], 0, n * m), "K": (data["K"], 0, m * n), "L": (data["L"], 0, m * m),
                 "q": (data["q"], 0, n), "r": (data["r"], 0, m), "p": (data["p"], 0, n), "U": (data["U"], 0, m)}
        xp = pieces(0, n)
        slots = carry_slots(builder, xp)
        p0 = g.row(builder.gep(data["p"], [builder.mul(k_hi, llir.Constant(I64, n))]), xp)
        for (_, _, v), (_, _, s) in zip(p0, slots):
            builder.store(v, s)
        with cgutils.for_range(builder, builder.sub(k_hi, k_lo)) as loop:
            k = builder.sub(builder.sub(k_hi, llir.Constant(I64, 1)), loop.index)
            pn = [(c0, w, builder.load(s)) for c0, w, s in slots]
            p = _back_stage(g, stage_pointers(builder, k, data, where), n, m, pn, data.get("gk"))
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
    if not c_arrays(X, K, U, P, lam, A, B, c, ndim=(2, 3, 2, 3, 2, 3, 3, 2)):
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
        xp = pieces(0, n)
        slots = carry_slots(builder, xp)
        for (_, _, v), (_, _, s) in zip(g.row(data["X"], xp), slots):
            builder.store(v, s)
        with cgutils.for_range(builder, N) as loop:
            x = [(c0, w, builder.load(s)) for c0, w, s in slots]
            xn = _forward_stage(g, stage_pointers(builder, as_i64(builder, loop.index), data, where), n, m, x)
            for (_, _, v), (_, _, s) in zip(xn, slots):
                builder.store(v, s)
        return context.get_dummy_value()
    return types.none(tags, X, K, U, P, lam, A, B, c), codegen


@nb.njit(cache=True, fastmath=REASSOC)
def _solve_unconstrained_fixed(tags, dyn, ipt, fac, rhs, sol):
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
    tags = as_bundle(tags, SizeTags)
    nt, mt, zt = tags.n, tags.m, tags.nz
    n, m = len(nt), len(mt)
    N = A.shape[0]
    gc = stack_vector(zt)
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
