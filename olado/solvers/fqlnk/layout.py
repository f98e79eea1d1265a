"""The full-space unknown of FQLNK (seed 002 sec. 2.3 and 3.1) and the pieces of its KKT system.

Variables ``v = (y, s)``: y stage by stage, ``(u^0, x^1, u^1, x^2, ..., u^{N-1}, x^N)`` (x^0 is
fixed), then the slacks s of the inequalities when they are treated by the seed's squared slacks
(eq. (4.6)). Constraints ``c(v) = 0``, in this order:

    h^k = f^k(x^k, u^k) - x^{k+1}              k = 0..N-1   (the dynamics, seed's R_j)
    g^k_E(x^k, u^k)                             stage equality rows
    g^N_E(x^N)                                  final equality rows
    g^k_I(x^k, u^k) - s^2,  g^N_I(x^N) - s^2    inequality rows g >= 0 (squared slacks, eq. (4.6))
    +-(y_i - b_i) - s^2                         finite bounds y_i >= lb_i, y_i <= ub_i (the same)

The Lagrangian is olado's ``L = J + lam . c`` (olado.solvers.common, eq. (28)); the seed writes
``J - p_lambda . c``, which only flips the multipliers' sign. With it the seed's F (eq. (3.1))
is ``F(v, lam) = (grad_v L, c)`` and its KKT matrix ``K = [[H, G^T], [G, 0]]``
(Algorithm 1, step 3), G the sparse Jacobian of c assembled here from the problem's stage
Jacobians, H the Lagrangian Hessian assembled from its stage Hessians
(:meth:`olado.problems.docp.DOCP.eval_stage_hessians`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ..common import stage_gradient_terms

#: smallest initial slack value s0^2 of a row that is violated or active at the start (a slack at
#: 0 has a zero Jacobian column, eq. (4.6): the KKT matrix would start singular)
SLACK_FLOOR = 1e-2


class BoundRows(NamedTuple):
    """The finite bounds of y as rows sign (y[col] - value) - s^2 = 0 (sign +1: lower, -1: upper)."""

    col: np.ndarray
    sign: np.ndarray
    value: np.ndarray


class Layout:
    """Index maps of v and c for one problem (module docstring)."""

    def __init__(self, problem, slacks: bool):
        p = self.problem = problem
        self.N, self.n, self.m = N, n, m = p.N, p.n, p.m
        self.eq, self.ineq = p.stage_equality_mask, ~p.stage_equality_mask
        self.eqN, self.ineqN = p.final_equality_mask, ~p.final_equality_mask
        self.ne, self.neN = int(self.eq.sum()), int(self.eqN.sum())
        self.ny = N * (n + m)
        blocks = np.arange(N * (n + m)).reshape(N, n + m)
        self.ucol = blocks[:, :m]                      # (N, m): column of u^k_j
        xcol = np.full((N + 1, n), -1)
        xcol[1:] = blocks[:, m:]
        self.xcol = xcol                               # (N+1, n): column of x^k_j (row 0: fixed, -1)
        self.bounds = self._bound_rows() if slacks else BoundRows(*(np.zeros(0, dtype=t) for t in (int, float, float)))
        self.ni = int(self.ineq.sum()) if slacks else 0
        self.niN = int(self.ineqN.sum()) if slacks else 0
        self.nb = self.bounds.col.size
        self.ns = N * self.ni + self.niN + self.nb
        self.nv = self.ny + self.ns
        self.nc = N * n + N * self.ne + self.neN + self.ns
        self.slack_rows = np.arange(self.nc - self.ns, self.nc)
        self.slack_cols = np.arange(self.ny, self.nv)

    def _bound_rows(self) -> BoundRows:
        p = self.problem
        cols, signs, vals = [], [], []
        for lo, hi, col in ((p.x_lower[1:], p.x_upper[1:], self.xcol[1:]), (p.u_lower, p.u_upper, self.ucol)):
            for bound, sign in ((lo, 1.0), (hi, -1.0)):
                fin = np.isfinite(bound)
                cols.append(col[fin]); vals.append(bound[fin]); signs.append(np.full(int(fin.sum()), sign))
        return BoundRows(np.concatenate(cols).astype(int), np.concatenate(signs), np.concatenate(vals))

    # ------------------------------------------------------------------ packing
    def pack(self, X, U, s=None):
        v = np.empty(self.nv)
        blocks = v[:self.ny].reshape(self.N, self.n + self.m)
        blocks[:, :self.m] = U
        blocks[:, self.m:] = X[1:]
        v[self.ny:] = 0.0 if s is None else s
        return v

    def unpack(self, v):
        """(X (N+1, n) with x^0, U (N, m), s (ns,))."""
        blocks = v[:self.ny].reshape(self.N, self.n + self.m)
        X = np.empty((self.N + 1, self.n))
        X[0] = self.problem.x0
        X[1:] = blocks[:, self.m:]
        return X, blocks[:, :self.m].copy(), v[self.ny:].copy()

    def slack_row_values(self, pt, v):
        """The inequality rows' values before the slacks: g_I (N, ni), g^N_I, the bound gaps."""
        b = self.bounds
        gi = pt.g[:, self.ineq] if self.ni else np.zeros((self.N, 0))
        giN = pt.gN[self.ineqN] if self.niN else np.zeros(0)
        return np.concatenate([gi.ravel(), giN, b.sign * (v[b.col] - b.value)])

    def initial_slacks(self, pt, v):
        """s0 = sqrt(max(row value, SLACK_FLOOR)): the rows hold where they hold strictly."""
        return np.sqrt(np.maximum(self.slack_row_values(pt, v), SLACK_FLOOR))

    # ------------------------------------------------------------------ multipliers
    def split_multipliers(self, lam):
        """(dynamics (N, n), Lg (N, r) in the problem's row order, LgN (rN,), bound rows (nb,))."""
        N, n = self.N, self.n
        p = self.problem
        a = N * n
        dyn = lam[:a].reshape(N, n)
        Lg = np.zeros((N, p.r))
        LgN = np.zeros(p.rN)
        Lg[:, self.eq] = lam[a:a + N * self.ne].reshape(N, self.ne)
        a += N * self.ne
        LgN[self.eqN] = lam[a:a + self.neN]
        a += self.neN
        if self.ni:
            Lg[:, self.ineq] = lam[a:a + N * self.ni].reshape(N, self.ni)
        a += N * self.ni
        if self.niN:
            LgN[self.ineqN] = lam[a:a + self.niN]
        a += self.niN
        return dyn, Lg, LgN, lam[a:]

    # ------------------------------------------------------------------ c, grad L, G, H
    def constraints(self, pt, v):
        """c(v) in the module docstring's order."""
        parts = [pt.h.ravel(), pt.g[:, self.eq].ravel(), pt.gN[self.eqN]]
        if self.ns:
            s = v[self.ny:]
            parts.append(self.slack_row_values(pt, v) - s * s)
        return np.concatenate(parts)

    def lagrangian_gradient(self, pt, v, lam):
        """grad_v L = grad J + G^T lam (seed's F, first block), from the stage derivatives."""
        dyn, Lg, LgN, mb = self.split_multipliers(lam)
        rx, ru = stage_gradient_terms(self.problem, pt, dyn, Lg, LgN)
        X_dummy = np.empty((self.N + 1, self.n))
        X_dummy[1:] = rx[1:]
        grad = self.pack(X_dummy, ru)
        if self.ns:
            np.add.at(grad, self.bounds.col, self.bounds.sign * mb)
            grad[self.ny:] = -2.0 * v[self.ny:] * lam[self.slack_rows]
        return grad

    def jacobian(self, pt, v):
        """G = dc/dv, sparse (nc, nv), from A^k, B^k, C_x^k, C_u^k, C^N."""
        N, n = self.N, self.n
        rows, cols, vals = [], [], []

        def add(r, c, x):
            r, c, x = np.broadcast_arrays(r, c, x)
            keep = c >= 0          # x^0 is not a variable
            rows.append(r[keep]); cols.append(c[keep]); vals.append(x[keep])

        rdyn = np.arange(N * n).reshape(N, n)
        add(rdyn[:, :, None], self.xcol[:-1, None, :], pt.A)
        add(rdyn[:, :, None], self.ucol[:, None, :], pt.B)
        add(rdyn, self.xcol[1:], -1.0)
        r0 = N * n
        for mask, count in ((self.eq, self.ne), (self.ineq, self.ni)):
            if count:
                rr = (r0 + np.arange(N * count)).reshape(N, count)
                add(rr[:, :, None], self.xcol[:-1, None, :], pt.Cx[:, mask])
                add(rr[:, :, None], self.ucol[:, None, :], pt.Cu[:, mask])
            r0 += N * count
            if mask is self.eq:
                if self.neN:
                    add((r0 + np.arange(self.neN))[:, None], self.xcol[-1][None, :], pt.CN[self.eqN])
                r0 += self.neN
        if self.niN:
            add((r0 + np.arange(self.niN))[:, None], self.xcol[-1][None, :], pt.CN[self.ineqN])
            r0 += self.niN
        if self.nb:
            add(r0 + np.arange(self.nb), self.bounds.col, self.bounds.sign)
        if self.ns:
            add(self.slack_rows, self.slack_cols, -2.0 * v[self.ny:])
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(self.nc, self.nv))

    def hessian(self, pt, v, lam, source=None):
        """H = grad_vv L, sparse (nv, nv): the stage blocks of the problem's Lagrangian Hessian
        (``source`` None: the problem's own second derivatives, "fd": second central differences
        of the Lagrangian's values, seed eq. (3.2)) and -2 lam on the slacks' diagonal."""
        p = self.problem
        dyn, Lg, LgN, _ = self.split_multipliers(lam)
        Hxx, Hxu, Huu = p.eval_stage_hessians(pt.X, pt.U, 1.0, dyn, Lg, source=source)
        HN = p.eval_final_hessian(pt.X[-1], 1.0, LgN, source=source)
        cols = np.concatenate([self.xcol[:-1], self.ucol], axis=1)          # (N, n+m) per stage
        blocks = np.empty((self.N, self.n + self.m, self.n + self.m))
        blocks[:, :self.n, :self.n] = Hxx
        blocks[:, :self.n, self.n:] = Hxu
        blocks[:, self.n:, :self.n] = np.transpose(Hxu, (0, 2, 1))
        blocks[:, self.n:, self.n:] = Huu
        r, c = np.broadcast_arrays(cols[:, :, None], cols[:, None, :])
        keep = (r >= 0) & (c >= 0)
        rows, cc, vals = [r[keep]], [c[keep]], [blocks[keep]]
        xN = self.xcol[-1]
        rows.append(np.repeat(xN, self.n)); cc.append(np.tile(xN, self.n)); vals.append(HN.ravel())
        if self.ns:
            rows.append(self.slack_cols); cc.append(self.slack_cols); vals.append(-2.0 * lam[self.slack_rows])
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cc))),
                             shape=(self.nv, self.nv))
