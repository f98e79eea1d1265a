"""The structured large-scale NLP view of a DOCP (paper 001 sec. 4.1, eq. (6)).

    y = (x^0, u^0, x^1, u^1, ..., x^{N-1}, u^{N-1}, x^N),     m_y = N(n+m) + n
    h(y) = [f^k(x^k, u^k) - x^{k+1}]_{k=0..N-1} = 0,         m_h = N n
    g(y) = [g^0(x^0,u^0); ...; g^{N-1}; g^N(x^N)] >= 0       (flagged components = 0)

External NLP solvers see only this view. The constraint vector is c(y) = [h(y); g(y)] with
bounds cl <= c(y) <= cu; x^0 is fixed through its variable bounds. The Jacobian has a fixed
sparsity pattern (stage blocks A^k, B^k, -I, C_x^k, C_u^k, C^N), and the Lagrangian Hessian is
block diagonal with one (n+m) block per stage and an n block for x^N (eq. (12)); both are
returned as value arrays in the order of their ``*_structure()`` index arrays (the Hessian as its
lower triangle). No dense matrices of NLP size are formed anywhere on this path.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import ProblemDefinitionError


class StructuredNLP:
    """Sparse NLP view (6) of a :class:`~olado.problems.docp.DOCP`."""

    def __init__(self, problem):
        self.problem = p = problem
        n, m, N, r, rN = p.n, p.m, p.N, p.r, p.rN
        self.n, self.m, self.N, self.r, self.rN = n, m, N, r, rN
        self.nz = nz = n + m
        self.n_vars = N * nz + n
        self.n_dyn = N * n
        self.n_cons = N * n + N * r + rN
        k = np.arange(N)
        self._xidx = (k[:, None] * nz + np.arange(n)[None, :])          # (N, n)
        self._uidx = (k[:, None] * nz + n + np.arange(m)[None, :])      # (N, m)
        self._xN = N * nz + np.arange(n)
        self._build_jacobian_structure()
        self._build_hessian_structure()
        # stage parts of y as strided views: x^k starts at k (n+m), x^N at N (n+m), u^k at k (n+m) + n
        self._x_geometry = ((N + 1, n), (nz * 8, 8), 0)
        self._u_geometry = ((N, m), (nz * 8, 8), n * 8)

    def _view(self, y, geometry):
        """A strided (no copy) view of the states or controls inside the contiguous vector y."""
        shape, strides, offset = geometry
        return np.ndarray(shape, dtype=np.float64, buffer=y, offset=offset, strides=strides)

    def _vector(self, y):
        """y as a contiguous float vector of the right length (no copy when it already is one)."""
        y = np.asarray(y, dtype=float)
        if y.shape != (self.n_vars,):
            raise ProblemDefinitionError(f"expected a vector of length {self.n_vars}, got shape {y.shape}", array="y")
        if not y.flags.c_contiguous:
            y = np.ascontiguousarray(y)
        return y

    def _trajectories(self, y):
        """(X (N+1, n), U (N, m)) from y, fresh contiguous arrays (what unpack returns)."""
        y = self._vector(y)
        return self._view(y, self._x_geometry).copy(), self._view(y, self._u_geometry).copy()

    # ------------------------------------------------------------------ packing
    def pack(self, X, U):
        """y from X (N+1, n) and U (N, m)."""
        p = self.problem
        X = p.check_array(X, (self.N + 1, self.n), "pack", "X")
        U = p.check_array(U, (self.N, self.m), "pack", "U")
        return self._pack_raw(X, U)

    def unpack(self, y):
        """(X (N+1, n), U (N, m)) from y (copies)."""
        return self._trajectories(y)

    # ------------------------------------------------------------------ bounds
    def variable_bounds(self):
        """(lb, ub) on y: the simple bounds (4)-(5), with x^0 fixed (lb = ub = x0)."""
        p = self.problem
        xl = p.x_lower.copy(); xu = p.x_upper.copy()
        xl[0] = p.x0; xu[0] = p.x0
        return self._pack_raw(xl, p.u_lower), self._pack_raw(xu, p.u_upper)

    def _pack_raw(self, X, U):
        y = np.empty(self.n_vars)
        self._view(y, self._x_geometry)[...] = X
        self._view(y, self._u_geometry)[...] = U
        return y

    def constraint_bounds(self):
        """(cl, cu): h = 0; g >= 0 (0 <= g <= inf), or g = 0 for flagged equality components."""
        p = self.problem
        cl = np.zeros(self.n_cons)
        cu = np.zeros(self.n_cons)
        s = self.n_dyn
        if self.r:
            cu_stage = np.where(p.stage_equality_mask, 0.0, np.inf)
            cu[s: s + self.N * self.r] = np.tile(cu_stage, self.N)
        s += self.N * self.r
        if self.rN:
            cu[s:] = np.where(p.final_equality_mask, 0.0, np.inf)
        return cl, cu

    # ------------------------------------------------------------------ values
    def objective(self, y):
        X, U = self._trajectories(y)
        return self.problem.objective(X, U)

    def gradient(self, y):
        X, U = self._trajectories(y)
        p = self.problem
        lx, lu = p.eval_stage_cost_gradients(X, U)
        gN = p.eval_final_cost_gradient(X[-1])
        out = np.empty(self.n_vars)
        gx = self._view(out, self._x_geometry)
        gx[:-1] = lx
        gx[-1] = gN
        self._view(out, self._u_geometry)[...] = lu
        return out

    def constraints(self, y):
        X, U = self._trajectories(y)
        p = self.problem
        out = np.empty(self.n_cons)
        np.subtract(p.eval_dynamics(X, U), X[1:], out=out[: self.n_dyn].reshape(self.N, self.n))
        s = self.n_dyn
        if self.r:
            out[s: s + self.N * self.r] = p.eval_stage_constraints(X, U).reshape(-1)
        s += self.N * self.r
        if self.rN:
            out[s:] = p.eval_final_constraints(X[-1])
        return out

    def max_violation(self, y, c=None):
        """Max-norm violation of c(y) in [cl, cu] and of the variable bounds."""
        c = self.constraints(y) if c is None else c
        cl, cu = self.constraint_bounds()
        lb, ub = self.variable_bounds()
        v = 0.0
        if c.size:
            v = max(v, float(np.max(np.maximum(cl - c, 0.0))), float(np.max(np.maximum(c - cu, 0.0))))
        v = max(v, float(np.max(np.maximum(lb - y, 0.0))), float(np.max(np.maximum(y - ub, 0.0))))
        return v

    # ------------------------------------------------------------------ Jacobian
    def _build_jacobian_structure(self):
        n, m, N, r, rN = self.n, self.m, self.N, self.r, self.rN
        rows, cols = [], []
        dyn_rows = np.arange(N)[:, None] * n + np.arange(n)[None, :]            # (N, n)
        # A^k: d h^k / d x^k
        rows.append(np.broadcast_to(dyn_rows[:, :, None], (N, n, n)).ravel())
        cols.append(np.broadcast_to(self._xidx[:, None, :], (N, n, n)).ravel())
        # B^k: d h^k / d u^k
        rows.append(np.broadcast_to(dyn_rows[:, :, None], (N, n, m)).ravel())
        cols.append(np.broadcast_to(self._uidx[:, None, :], (N, n, m)).ravel())
        # -I: d h^k / d x^{k+1}
        nxt = np.vstack([self._xidx[1:], self._xN[None, :]]) if N > 1 else self._xN[None, :]
        rows.append(dyn_rows.ravel())
        cols.append(nxt.ravel())
        if r:
            g_rows = self.n_dyn + np.arange(N)[:, None] * r + np.arange(r)[None, :]   # (N, r)
            rows.append(np.broadcast_to(g_rows[:, :, None], (N, r, n)).ravel())
            cols.append(np.broadcast_to(self._xidx[:, None, :], (N, r, n)).ravel())
            rows.append(np.broadcast_to(g_rows[:, :, None], (N, r, m)).ravel())
            cols.append(np.broadcast_to(self._uidx[:, None, :], (N, r, m)).ravel())
        if rN:
            gN_rows = self.n_dyn + N * r + np.arange(rN)
            rows.append(np.repeat(gN_rows, n))
            cols.append(np.tile(self._xN, rN))
        self._jac_rows = np.concatenate(rows).astype(np.int64)
        self._jac_cols = np.concatenate(cols).astype(np.int64)

    def jacobian_structure(self):
        """(rows, cols) of the nonzeros of dc/dy, fixed for the whole solve."""
        return self._jac_rows, self._jac_cols

    def jacobian(self, y):
        """Values of dc/dy in the order of :meth:`jacobian_structure`."""
        X, U = self._trajectories(y)
        p = self.problem
        out = np.empty(self._jac_rows.size)

        def put(s, block):
            out[s: s + block.size].reshape(block.shape)[...] = block
            return s + block.size

        A, B = p.eval_dynamics_jacobians(X, U)
        s = put(put(0, A), B)
        out[s: s + self.n_dyn] = -1.0
        s += self.n_dyn
        if self.r:
            Cx, Cu = p.eval_stage_constraint_jacobians(X, U)
            s = put(put(s, Cx), Cu)
        if self.rN:
            out[s:] = p.eval_final_constraint_jacobian(X[-1]).reshape(-1)
        return out

    def jacobian_matrix(self, y):
        """dc/dy as a scipy.sparse CSR matrix."""
        return sp.csr_matrix((self.jacobian(y), (self._jac_rows, self._jac_cols)), shape=(self.n_cons, self.n_vars))

    # ------------------------------------------------------------------ Hessian
    def _build_hessian_structure(self):
        nz, n, N = self.nz, self.n, self.N
        a, b = np.tril_indices(nz)
        self._tril_stage = (a, b)
        base = np.arange(N)[:, None] * nz
        rows = [(base + a[None, :]).ravel()]
        cols = [(base + b[None, :]).ravel()]
        af, bf = np.tril_indices(n)
        self._tril_final = (af, bf)
        rows.append(N * nz + af)
        cols.append(N * nz + bf)
        self._hess_rows = np.concatenate(rows).astype(np.int64)
        self._hess_cols = np.concatenate(cols).astype(np.int64)

    def hessian_structure(self):
        """(rows, cols) of the lower triangle of the block-diagonal Lagrangian Hessian (12)."""
        return self._hess_rows, self._hess_cols

    def stage_blocks(self, y, lagrange, obj_factor=1.0):
        """The Hessian blocks: (Hxx (N,n,n), Hxu (N,n,m), Huu (N,m,m), HN (n,n)) of
        obj_factor*J + lagrange.c."""
        X, U = self._trajectories(y)
        p = self.problem
        mult = self.multipliers_to_stages(lagrange)
        Hxx, Hxu, Huu = p.eval_stage_hessians(X, U, obj_factor, mult["dynamics"], mult["stage_constraints"])
        HN = p.eval_final_hessian(X[-1], obj_factor, mult["final_constraints"])
        return Hxx, Hxu, Huu, HN

    def hessian(self, y, lagrange, obj_factor=1.0):
        """Values (lower triangle, order of :meth:`hessian_structure`) of the Hessian of
        obj_factor*J(y) + lagrange . c(y)."""
        Hxx, Hxu, Huu, HN = self.stage_blocks(y, lagrange, obj_factor)
        out = np.empty(self._hess_rows.size)
        from . import _kernels   # noqa: PLC0415 - numba loads on first use

        c = np.ascontiguousarray
        _kernels.gather_hessian_values(c(Hxx, dtype=np.float64), c(Hxu, dtype=np.float64),
                               c(Huu, dtype=np.float64), c(HN, dtype=np.float64), out)
        return out

    def hessian_matrix(self, y, lagrange, obj_factor=1.0):
        """The full symmetric Lagrangian Hessian as a scipy.sparse CSR matrix."""
        vals = self.hessian(y, lagrange, obj_factor)
        r, c = self._hess_rows, self._hess_cols
        off = r != c
        H = sp.coo_matrix((np.concatenate([vals, vals[off]]), (np.concatenate([r, c[off]]), np.concatenate([c, r[off]]))),
                          shape=(self.n_vars, self.n_vars))
        return H.tocsr()

    # ------------------------------------------------------------------ multipliers and counts
    def multipliers_to_stages(self, lagrange):
        """Split constraint multipliers into dynamics (N, n), stage (N, r) and final (rN,)."""
        lam = np.asarray(lagrange, dtype=float)
        if lam.shape != (self.n_cons,):
            raise ProblemDefinitionError(f"expected {self.n_cons} multipliers, got shape {lam.shape}", array="lagrange")
        s = self.n_dyn
        return {
            "dynamics": lam[:s].reshape(self.N, self.n),
            "stage_constraints": lam[s: s + self.N * self.r].reshape(self.N, self.r),
            "final_constraints": lam[s + self.N * self.r:],
        }

    def counts(self) -> dict:
        """Problem size counted as in paper 001 Table 1 (:func:`nlp_counts`)."""
        return nlp_counts(self.problem)


def nlp_counts(p) -> dict:
    """Size of the NLP view (6) of the DOCP ``p``, counted as in paper 001 Table 1.

    variables    m_y = N(n+m) + n
    equalities   the N n state equations, the n fixed initial states, and the equality
                 components of g^k and g^N
    inequalities every finite simple bound of eqs. (4)-(5) -- for k = 0..N on states, as eq.
                 (4) is written, and k = 0..N-1 on controls -- plus the inequality components
                 of g^k and g^N.
    """
    N, n_dyn, n_vars = p.N, p.N * p.n, p.N * (p.n + p.m) + p.n
    n_bx = int(np.isfinite(p.x_lower).sum() + np.isfinite(p.x_upper).sum())
    n_bu = int(np.isfinite(p.u_lower).sum() + np.isfinite(p.u_upper).sum())
    eq_stage = int(p.stage_equality_mask.sum()) * N
    eq_final = int(p.final_equality_mask.sum())
    ineq_stage = (p.r - int(p.stage_equality_mask.sum())) * N
    ineq_final = p.rN - eq_final
    return {
        "N": N,
        "variables": n_vars,
        "equalities": n_dyn + p.n + eq_stage + eq_final,
        "inequalities": n_bx + n_bu + ineq_stage + ineq_final,
        "breakdown": {
            "state_equations": n_dyn, "fixed_initial_states": p.n,
            "equality_constraints": eq_stage + eq_final,
            "state_bounds": n_bx, "control_bounds": n_bu,
            "inequality_constraints": ineq_stage + ineq_final,
        },
    }
