"""General sparse back-ends for the KKT systems of the LQ-DOCP (paper 001 sec. 4.2.3, (24)-(25)).

The same linear systems the block Riccati recursion (:mod:`olado.linalg.riccati`) solves, here
assembled as one sparse matrix and handed to a general solver, for comparison and as a fallback.
One factory picks the back-end by name::

    solver = make_kkt_solver("superlu-reduced", Q, S, R, A, B, Dx=Dx, Du=Du, Ci=Ci, sigma=sigma)
    sol = solver.solve(q, r, c, x0, ci=ci)        # -> LQSolution, as RiccatiFactorization.solve

``make_kkt_solver`` (:mod:`olado.linalg.backend`, the table of back-ends ``KKT_BACKENDS``) takes
the keyword arguments of :class:`~olado.linalg.backend.StageData` (E, F, n_eq, EN, Dx, Du, Ci,
sigma, n_ineq, regularization) plus the options of the chosen back-end. Every back-end
implements :class:`~olado.linalg.backend.KKTBackend`: it factors (or preconditions) in the
constructor and again in ``refactor`` (new diagonal terms: the matrix is assembled again);
``solve`` may be called for any number of right-hand sides and returns the same multipliers as
the Riccati solver.

Variables, Lagrangian and multiplier signs (as in :mod:`olado.linalg.riccati`):

    L = J + sum_k lam_{k+1}.(A_k x_k + B_k u_k + c_k - x_{k+1}) + lam_0.(xbar_0 - x_0)
          + sum_k nu_k.(E_k x_k + F_k u_k + e_k) + nu_N.(E_N x_N + e_N),

    J = sum_k 1/2 z_k^T H_k z_k + q_k.x_k + r_k.u_k + 1/2 x_N^T (Q_N + Dx_N) x_N + q_N.x_N
        + sum_k 1/2 (C_k z_k + ci_k)^T diag(sigma_k) (C_k z_k + ci_k),
    H_k = [Q_k + diag(Dx_k), S_k; S_k^T, R_k + diag(Du_k) + regularization I],  z_k = (x_k, u_k).

With all equality rows written C y + d = 0 and multipliers mu = (lam, nu), the KKT system is

    [ H   C^T ] [ y  ]   [ -g ]
    [ C    0  ] [ mu ] = [ -d ].                                     (reduced system (25))

"superlu-full" keeps the interior-point rows of (24) instead of folding them: for every stage
inequality row with sigma != 0 a multiplier w = sigma (C z + ci) and the row C z - w / sigma = -ci;
for every simple-bound term with Dx (or Du) != 0 a multiplier v = Dx x and the row x - v / Dx = 0
(``bounds_as_rows=False`` folds the bound terms into H instead). Rows whose weight is 0 would be
"w = 0" and are dropped. The primal solution and (lam, nu) are the same as in (25).

Unknowns are ordered stage by stage, (lam_k, x_k, u_k, nu_k [, w_k, v_k]) for k = 0..N (the
dynamics row that defines x_k is placed just before x_k), so the matrix is banded with a band
width of a few stage sizes; SuperLU in this natural order is a banded LU, O(N) in time and memory.

Back-ends:

- ``"riccati"``: :class:`~olado.linalg.riccati.RiccatiFactorization` (the reference).
- ``"superlu-reduced"``: (25) factored once with ``scipy.sparse.linalg.splu``.
- ``"superlu-full"``: (24) factored once with ``splu``.
- ``"minres"``: MINRES on (25). MINRES needs a symmetric positive definite preconditioner, so an
  ILU (not symmetric) cannot be used; it uses the block-diagonal preconditioner
  diag(|H|, C |H|^{-1} C^T) (Murphy, Golub, Wathen 2000), where |H| is the stage block of H with
  its eigenvalues replaced by their absolute values (floored at ``1e-8 * max``) and the Schur
  complement is factored exactly by splu (it is banded). When H is positive definite the
  preconditioned matrix has three distinct eigenvalues and MINRES stops after a few iterations.
  ``preconditioner="none"`` runs it unpreconditioned.
- ``"gmres"``: restarted GMRES on (25) with the incomplete LU factor of ``spilu`` (``drop_tol``,
  ``fill_factor``) as preconditioner.

Iterative back-ends take ``rtol`` (relative residual, default 1e-10) and ``maxiter``; when they
stop without meeting ``rtol`` in the true residual ||K y - b|| / ||b||, :class:`KKTSolveError`
names the back-end, the iteration count and the residual. They check the back-end's ``limits``
(the solve's time limit and interrupts, :class:`~olado.linalg.backend.KKTBackend`) at every
Krylov iteration: ``maxiter`` defaults to 10 times the system's size, and one solve at that
bound can take longer than the whole time limit.

A singular matrix whose cause is dependent equality rows (which the Riccati recursion drops,
reporting their consistency defect) is factored again with the dual block regularized,
-delta_c I (``DUAL_REGULARIZATION``, relative to the rows' entries), and SuperLU's solution is
refined on the unregularized system; the residual of the rows (``x0_residual``) then measures
their consistency as Riccati's does. GMRES's complete-LU preconditioner and the Schur complement
of MINRES's preconditioner are regularized likewise. A matrix singular in its primal block as
well still raises :class:`KKTSolveError`. Unlike the Riccati recursion, the
sparse back-ends do not check the inertia (a reduced Hessian that is not positive definite on
the null space of the constraints goes unnoticed unless the matrix is singular).

``LQSolution.x0_residual`` of a sparse back-end is the largest residual of the equality rows
C y + d of the computed solution (for Riccati it is the residual of the rows reaching x_0 and
the consistency defect of the dependent rows the recursion dropped).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import ConfigError, OladoError
from .backend import KKT_SOLVERS, RHS, LQSolution, Solution, StageData, make_kkt_solver

__all__ = ["KKT_SOLVERS", "KKTSolveError", "make_kkt_solver", "SuperLUReducedKKT", "SuperLUFullKKT",
           "MinresKKT", "GmresKKT"]


class KKTSolveError(OladoError, np.linalg.LinAlgError):
    """A KKT back-end failed: singular matrix, or an iterative method that did not converge."""

    def __init__(self, backend, message, iterations=None, residual=None):
        self.backend, self.iterations, self.residual = backend, iterations, residual
        text = f"KKT solver '{backend}': {message}"
        if iterations is not None:
            text += f" after {iterations} iterations"
        if residual is not None:
            text += f", relative residual {residual:.3e}"
        super().__init__(text)


#: the dual regularization of a singular KKT matrix, relative to the largest entry of its equality
#: rows: their diagonal block -delta_c I (Waechter & Biegler 2006, sec. 3.1: IPOPT's delta_c =
#: 1e-8 mu^(1/4) for a rank-deficient constraint Jacobian); the residual of the unregularized
#: system is refined away (_REFINE_STEPS) where the rows are consistent, and measured
#: (x0_residual) where they are not
DUAL_REGULARIZATION = 1e-8
_REFINE_STEPS = 10


def _regularized_lu(K, dual_mask, permc_spec, sign=-1.0, **opts):
    """SuperLU of K + sign delta_c diag(dual_mask) (a KKT matrix whose equality rows are
    dependent, so that K itself is singular: sign -1; the preconditioner's Schur complement
    C |H|^-1 C^T, positive semidefinite: sign +1), and delta_c; RuntimeError if that is singular
    too. delta_c is relative to the rows' entries, not to max|K|: the interior-point diagonal
    terms reach 1e14."""
    rows = K[np.flatnonzero(dual_mask)]
    delta_c = DUAL_REGULARIZATION * max(float(abs(rows).max()) if rows.nnz else 0.0, 1.0)
    Kr = (K + sp.diags(np.where(dual_mask, sign * delta_c, 0.0))).tocsc()
    return spla.splu(Kr, permc_spec=permc_spec, **opts), delta_c


def _block_entries(rows, cols, vals):
    """COO triplets of dense blocks: rows (K, a), cols (K, b), vals (K, a, b)."""
    rr = np.broadcast_to(rows[:, :, None], vals.shape)
    cc = np.broadcast_to(cols[:, None, :], vals.shape)
    return rr.ravel(), cc.ravel(), vals.ravel()


class _SparseKKT:
    """Sparse assembly of the KKT matrix in the stage-interleaved order (see the module docstring)."""

    name = "sparse"
    full = False            # True: system (24), inequality and bound rows kept
    limits = None           # KKTBackend.limits: checked at every Krylov iteration (_IterativeKKT)

    def __init__(self, Q, S, R, A, B, *, bounds_as_rows=True, **stage_kw):
        self.data = StageData(Q, S, R, A, B, **stage_kw)
        self.bounds_as_rows = bool(bounds_as_rows) and self.full
        self._assemble()

    def refactor(self, Dx=None, Du=None, sigma=None, regularization=None):
        """New diagonal terms (arguments as :meth:`~olado.linalg.backend.StageData.set_diagonal`):
        the matrix is assembled again from the stage arrays (its layout depends on which
        diagonal terms are zero; arrays the caller updated in place are seen) and factored."""
        self.data.set_diagonal(Dx=Dx, Du=Du, sigma=sigma, regularization=regularization)
        self._assemble()
        return self

    def _assemble(self):
        """The sparse KKT matrix of the stage arrays ``data`` (layout, K), then its factorization."""
        d = self.data
        N, n, m, ne, ni, neN = d.N, d.n, d.m, d.ne_max, d.ni_max, d.neN
        nz = n + m
        # ---- padded layout: stage block (lam n | x n | u m | nu ne | w ni | vx n | vu m)
        nw = ni if self.full else 0
        nb = nz if self.bounds_as_rows else 0
        s = 2 * n + m + ne + nw + nb
        self.stride = s
        o_lam, o_x, o_u, o_nu, o_w, o_vx, o_vu = 0, n, 2 * n, 2 * n + m, 2 * n + m + ne, 2 * n + m + ne + nw, 3 * n + m + ne + nw
        base = (np.arange(N) * s)[:, None]
        self.i_lam = np.vstack([base + o_lam + np.arange(n), [N * s + np.arange(n)]])       # (N+1, n)
        self.i_x = np.vstack([base + o_x + np.arange(n), [N * s + n + np.arange(n)]])        # (N+1, n)
        self.i_u = base + o_u + np.arange(m)                                                   # (N, m)
        self.i_nu = base + o_nu + np.arange(ne)                                                # (N, ne)
        self.i_nuN = N * s + 2 * n + np.arange(neN)                                            # (neN,)
        self.i_w = base + o_w + np.arange(nw)                                                  # (N, nw)
        self.i_vx = np.vstack([base + o_vx + np.arange(nb and n), [N * s + 2 * n + neN + np.arange(nb and n)]])
        self.i_vu = base + o_vu + np.arange(nb and m)
        npad = N * s + 2 * n + neN + (n if nb else 0)
        keep = np.ones(npad, dtype=bool)
        keep[self.i_nu[~d.eq_mask]] = False
        if self.full:
            keep[self.i_w[d.ineq_w == 0.0]] = False
        if self.bounds_as_rows:
            keep[self.i_vx[d.Dx == 0.0]] = False
            keep[self.i_vu[d.Du == 0.0]] = False
        self.npad, self.keep = npad, keep
        self.newidx = np.cumsum(keep) - 1
        self.size = int(keep.sum())
        dual = np.zeros(npad, dtype=bool)       # rows of equality constraints (lam, nu)
        dual[self.i_lam.ravel()] = True
        dual[self.i_nu.ravel()] = True
        dual[self.i_nuN] = True
        self.dual_mask = dual[keep]

        # ---- Hessian stage blocks
        iz = np.hstack([self.i_x[:N], self.i_u])                                              # (N, nz)
        self.i_z = iz
        Hk = np.empty((N, nz, nz))
        Hk[:, :n, :n] = d.Q[:N]
        Hk[:, :n, n:] = d.S
        Hk[:, n:, :n] = d.S.transpose(0, 2, 1)
        Hk[:, n:, n:] = d.R
        ar_n, ar_m = np.arange(n), np.arange(m)
        Hk[:, n + ar_m, n + ar_m] += d.regularization
        HN = d.Q[N].copy()
        if not self.bounds_as_rows:
            Hk[:, ar_n, ar_n] += d.Dx[:N]
            Hk[:, n + ar_m, n + ar_m] += d.Du
            HN[ar_n, ar_n] += d.Dx[N]
        if not self.full and ni:
            Hk += np.einsum("kci,kc,kcj->kij", d.Ci, d.ineq_w, d.Ci, optimize=True)
        Hk = 0.5 * (Hk + Hk.transpose(0, 2, 1))      # exactly symmetric matrix (rounding of the einsum)
        HN = 0.5 * (HN + HN.T)
        self.Hk, self.HN = Hk, HN
        trip = [_block_entries(iz, iz, Hk), _block_entries(self.i_x[N:], self.i_x[N:], HN[None])]
        # ---- equality rows (C part; the transpose is added below)
        eye_n = np.broadcast_to(np.eye(n), (N, n, n))
        ctrip = [_block_entries(self.i_lam[:1], self.i_x[:1], -np.eye(n)[None]),     # -x_0 + xbar_0 = 0
                 _block_entries(self.i_lam[1:], self.i_x[:N], d.A),                   # A x + B u + c - x+ = 0
                 _block_entries(self.i_lam[1:], self.i_u, d.B),
                 _block_entries(self.i_lam[1:], self.i_x[1:], -eye_n)]
        if ne:
            ctrip.append(_block_entries(self.i_nu, self.i_x[:N], d.E))
            ctrip.append(_block_entries(self.i_nu, self.i_u, d.F))
        if neN:
            ctrip.append(_block_entries(self.i_nuN[None], self.i_x[N:], d.EN[None]))
        diag_r, diag_v = [], []
        if self.full and ni:
            ctrip.append(_block_entries(self.i_w, iz, d.Ci))
            with np.errstate(divide="ignore"):
                diag_r.append(self.i_w.ravel()); diag_v.append(-1.0 / d.ineq_w.ravel())
        if self.bounds_as_rows:
            ctrip.append((self.i_vx.ravel(), self.i_x.ravel(), np.ones((N + 1) * n)))
            ctrip.append((self.i_vu.ravel(), self.i_u.ravel(), np.ones(N * m)))
            with np.errstate(divide="ignore"):
                diag_r += [self.i_vx.ravel(), self.i_vu.ravel()]
                diag_v += [-1.0 / d.Dx.ravel(), -1.0 / d.Du.ravel()]
        rows = [t[0] for t in trip] + [t[0] for t in ctrip] + [t[1] for t in ctrip] + diag_r
        cols = [t[1] for t in trip] + [t[1] for t in ctrip] + [t[0] for t in ctrip] + diag_r
        vals = [t[2] for t in trip] + [t[2] for t in ctrip] * 2 + diag_v
        rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
        ok = vals != 0.0
        if not keep.all():
            ok &= keep[rows] & keep[cols]
            rows, cols, vals = self.newidx[rows[ok]], self.newidx[cols[ok]], vals[ok]
        else:
            rows, cols, vals = rows[ok], cols[ok], vals[ok]
        self.K = sp.csc_matrix((vals, (rows, cols)), shape=(self.size, self.size))
        self.K.sum_duplicates()
        self._factorize()

    # ------------------------------------------------------------------ right-hand side / solution
    def _rhs(self, q, r, c, x0, e, eN, ci):
        d = self.data
        b = np.zeros(self.npad)
        b[self.i_x] = -q
        b[self.i_u] = -r
        b[self.i_lam[0]] = -x0
        b[self.i_lam[1:]] = -c
        if d.ne_max:
            b[self.i_nu] = -e
        b[self.i_nuN] = -eN
        if d.ni_max:
            if self.full:
                b[self.i_w] = -ci
            else:
                g = np.einsum("kci,kc->ki", d.Ci, d.ineq_w * ci)
                b[self.i_z] -= g
        return b[self.keep]

    def _solution(self, y, b):
        d = self.data
        N = d.N
        ypad = np.zeros(self.npad)
        ypad[self.keep] = y
        nu = np.zeros((N + 1, max(d.ne_max, d.neN)))
        nu[:N, :d.ne_max] = ypad[self.i_nu]
        nu[N, :d.neN] = ypad[self.i_nuN]
        res = self.K @ y - b
        eq_res = float(np.abs(res[self.dual_mask]).max()) if self.dual_mask.any() else 0.0
        return LQSolution(ypad[self.i_x], ypad[self.i_u], ypad[self.i_lam], nu, eq_res)

    def solve(self, q, r, c, x0, e=None, eN=None, ci=None) -> LQSolution:
        """Solve for one right-hand side; arguments as in :meth:`RiccatiFactorization.solve`."""
        b = self._rhs(*self.data.rhs_arrays(q, r, c, x0, e, eN, ci))
        y = self._solve_vector(b)
        return self._solution(y, b)

    def solve_into(self, rhs: RHS, out: Solution) -> float:
        """:meth:`solve`, the solution copied into ``out`` (the KKTBackend fast path: no faster
        here); returns ``LQSolution.x0_residual``."""
        sol = self.solve(*rhs)
        out = Solution._make(out)       # a Solution or a plain tuple of its fields
        out.X[...] = sol.X
        out.U[...] = sol.U
        out.lam[...] = sol.lam
        k = min(out.nu.shape[1], sol.nu.shape[1])
        out.nu[:, :k] = sol.nu[:, :k]
        out.nu[:, k:] = 0.0
        return sol.x0_residual

    def _factorize(self):
        raise NotImplementedError

    def _solve_vector(self, b):
        raise NotImplementedError


class SuperLUReducedKKT(_SparseKKT):
    """The reduced system (25), factored once by SuperLU (``scipy.sparse.linalg.splu``).

    ``permc_spec`` is SuperLU's column ordering ("NATURAL", "COLAMD", "MMD_AT_PLUS_A", "MMD_ATA").
    The default "NATURAL" keeps the stage-interleaved order: a banded LU whose fill is bounded by
    the band, O(N) whatever the row pivoting does. (COLAMD is about as fast; the minimum degree
    orderings of A^T + A ignore the zero diagonal of the multiplier rows and, once partial pivoting
    leaves the diagonal, filled in 200x more at N=1000 with bound terms spread over 1e-4..1e4.)
    ``diag_pivot_thresh`` is SuperLU's partial-pivoting threshold (default 1.0)."""

    name = "superlu-reduced"

    def __init__(self, Q, S, R, A, B, *, permc_spec="NATURAL", diag_pivot_thresh=None, **kw):
        self.permc_spec, self.diag_pivot_thresh = permc_spec, diag_pivot_thresh
        super().__init__(Q, S, R, A, B, **kw)

    def _factorize(self):
        opts = {} if self.diag_pivot_thresh is None else {"diag_pivot_thresh": self.diag_pivot_thresh}
        self.dual_regularization = 0.0
        try:
            self.lu = spla.splu(self.K, permc_spec=self.permc_spec, **opts)
        except RuntimeError:   # "Factor is exactly singular": dependent equality rows (the Riccati
            # recursion drops them and reports their consistency defect; here the dual block is
            # regularized and the defect measured by _solution's x0_residual)
            try:
                self.lu, self.dual_regularization = _regularized_lu(self.K, self.dual_mask, self.permc_spec, **opts)
            except RuntimeError as exc:
                raise KKTSolveError(self.name, f"SuperLU factorization failed ({exc}), also with the dual "
                                    f"regularization {DUAL_REGULARIZATION:g} max|K|; the KKT matrix is singular") from None
        self.nnz_factor = self.lu.L.nnz + self.lu.U.nnz

    def _solve_vector(self, b):
        y = self.lu.solve(b)
        if self.dual_regularization:
            y = self._refine(y, b)
        if not np.all(np.isfinite(y)):
            raise KKTSolveError(self.name, "non-finite solution (singular or badly scaled KKT matrix)")
        return y


    def _refine(self, y, b):
        """Iterative refinement with the regularized factors towards a solution of K y = b, while
        it halves the residual (with consistent rows it converges; inconsistent rows leave a
        residual that no refinement removes, and the solution is kept where it was smallest)."""
        res = b - self.K @ y
        rn, bn = np.linalg.norm(res), np.linalg.norm(b)
        for _ in range(_REFINE_STEPS):
            if not rn > 1e-14 * bn:
                break
            y_new = y + self.lu.solve(res)
            res_new = b - self.K @ y_new
            rn_new = np.linalg.norm(res_new)
            if not rn_new < 0.5 * rn:
                break
            y, res, rn = y_new, res_new, rn_new
        return y


class SuperLUFullKKT(SuperLUReducedKKT):
    """The unreduced symmetric system (24): stage inequality rows (and, with ``bounds_as_rows``,
    the simple-bound terms) keep their own rows with diagonal -1/sigma (-1/Dx, -1/Du); rows with
    weight 0 are dropped. Factored once by SuperLU."""

    name = "superlu-full"
    full = True


class _IterativeKKT(_SparseKKT):
    def __init__(self, Q, S, R, A, B, *, rtol=1e-10, maxiter=None, max_restarts=5, **kw):
        if not rtol > 0:
            raise ValueError(f"rtol must be positive, got {rtol}")
        self.rtol = float(rtol)
        self.max_restarts = int(max_restarts)
        self.iterations = 0          # Krylov iterations of the last solve
        self.residual = 0.0          # its relative residual ||K y - b|| / ||b||
        self._maxiter = maxiter
        super().__init__(Q, S, R, A, B, **kw)

    def _assemble(self):
        super()._assemble()
        self.maxiter = int(self._maxiter) if self._maxiter is not None else max(10 * self.size, 100)

    def _solve_vector(self, b):
        """Run the Krylov method, then refine: while the true relative residual ||K y - b|| / ||b||
        exceeds rtol (scipy's MINRES stops on an estimate relative to ||K|| ||y||, which can be
        larger), solve again for the correction from the residual, at most ``max_restarts`` times
        and ``maxiter`` iterations in total."""
        bn = np.linalg.norm(b)
        y = np.zeros_like(b)
        self.iterations, self.residual = 0, 0.0
        if bn == 0.0:
            return y
        res, total, info, rel = b, 0, 0, 1.0
        for _restart in range(self.max_restarts + 1):
            dy, info, its = self._krylov(res, self.maxiter - total)
            total += its
            y += dy
            res = b - self.K @ y
            rel = float(np.linalg.norm(res) / bn)
            if info < 0 or not np.isfinite(rel) or rel <= self.rtol or total >= self.maxiter:
                break
        self.iterations, self.residual = total, rel
        if info < 0 or not np.isfinite(rel) or rel > self.rtol:
            why = f"breakdown (info={info})" if info < 0 else "did not converge"
            raise KKTSolveError(self.name, f"{why} (rtol={self.rtol:g}, maxiter={self.maxiter})", total, rel)
        return y

    def _krylov(self, b, maxiter):
        """One run of the method from zero; returns (y, info, iterations)."""
        raise NotImplementedError

    def _check_limits(self):
        """Per Krylov iteration (the methods' callbacks): the solve's time limit and interrupts
        (``limits.check()`` raises StopRequested inside the solve's loop)."""
        if self.limits is not None:
            self.limits.check()


class MinresKKT(_IterativeKKT):
    """MINRES on the reduced system (25) with the SPD block-diagonal preconditioner
    diag(|H|, C |H|^{-1} C^T) (``preconditioner="block"``, default) or none (``"none"``)."""

    name = "minres"

    def __init__(self, Q, S, R, A, B, *, preconditioner="block", **kw):
        if preconditioner not in ("block", "none"):
            raise ConfigError(f"minres preconditioner {preconditioner!r}", key="preconditioner", allowed="block, none")
        self.preconditioner = preconditioner
        super().__init__(Q, S, R, A, B, **kw)

    @staticmethod
    def _abs_inverse(H):
        """|H|^{-1} of a stack of symmetric blocks: eigenvalues replaced by max(|l|, 1e-8 max|l|)."""
        w, V = np.linalg.eigh(H)
        aw = np.abs(w)
        aw = np.maximum(aw, 1e-8 * max(aw.max(initial=0.0), 1e-300))
        return np.einsum("kij,kj,klj->kil", V, 1.0 / aw, V)

    def _factorize(self):
        self.M = None
        if self.preconditioner == "none":
            return
        d = self.data
        N, n = d.N, d.n
        primal = ~self.dual_mask
        # |H|^{-1}, block diagonal over stages (x_k, u_k) and x_N
        Hinv_k = self._abs_inverse(self.Hk)
        Hinv_N = self._abs_inverse(self.HN[None])
        trip = [_block_entries(self.i_z, self.i_z, Hinv_k), _block_entries(self.i_x[N:], self.i_x[N:], Hinv_N)]
        rows = self.newidx[np.concatenate([t[0] for t in trip])]
        cols = self.newidx[np.concatenate([t[1] for t in trip])]
        Hinv = sp.csc_matrix((np.concatenate([t[2] for t in trip]), (rows, cols)), shape=(self.size, self.size))
        pidx, didx = np.flatnonzero(primal), np.flatnonzero(self.dual_mask)
        Hinv = Hinv[pidx][:, pidx]
        C = self.K[didx][:, pidx]
        schur = (C @ Hinv @ C.T).tocsc()
        try:
            lu = spla.splu(schur, permc_spec="NATURAL")
        except RuntimeError:        # dependent equality rows: the Schur complement regularized
            try:
                lu, _ = _regularized_lu(schur, np.ones(schur.shape[0], dtype=bool), "NATURAL", sign=1.0)
            except RuntimeError as exc:
                raise KKTSolveError(self.name, f"Schur complement of the preconditioner is singular ({exc}), also "
                                    f"with the regularization {DUAL_REGULARIZATION:g} max|S|; the equality rows "
                                    "are dependent") from None

        def apply(v):
            out = np.empty_like(v)
            out[pidx] = Hinv @ v[pidx]
            out[didx] = lu.solve(v[didx])
            return out

        self.M = spla.LinearOperator(self.K.shape, matvec=apply, dtype=np.float64)

    def _krylov(self, b, maxiter):
        count = [0]

        def cb(_x):
            count[0] += 1
            self._check_limits()

        try:
            y, info = spla.minres(self.K, b, M=self.M, rtol=self.rtol, maxiter=maxiter, callback=cb)
        except ValueError as exc:       # scipy: "indefinite preconditioner" (rounding in |H|^-1, S)
            raise KKTSolveError(self.name, f"MINRES stopped: {exc}", count[0]) from None
        return y, info, count[0]


class GmresKKT(_IterativeKKT):
    """Restarted GMRES on the reduced system (25), preconditioned by SuperLU's incomplete LU
    (``spilu`` with ``drop_tol``, ``fill_factor``); ``restart`` is the Krylov dimension."""

    name = "gmres"

    def __init__(self, Q, S, R, A, B, *, restart=50, drop_tol=1e-5, fill_factor=10.0, **kw):
        self.restart, self.drop_tol, self.fill_factor = int(restart), float(drop_tol), float(fill_factor)
        super().__init__(Q, S, R, A, B, **kw)

    def _factorize(self):
        # the stage ordering keeps the factor banded; when dropping leaves a zero pivot (the zero
        # dual block of (25) and the interior-point diagonal terms: "Factor is exactly singular"
        # on 5 of 65 factorizations of the SQP on zambezi12 N = 36, 3 of the first 8 QPs at
        # N = 120), a fill-reducing column ordering with 100 times less dropping, and last the
        # complete LU (cheap for a banded matrix; GMRES then converges at once)
        self.ilu_fallback = 0
        for perm, drop in (("NATURAL", self.drop_tol), ("COLAMD", 0.01 * self.drop_tol)):
            try:
                self.ilu = spla.spilu(self.K, drop_tol=drop, fill_factor=self.fill_factor, permc_spec=perm)
                break
            except RuntimeError:
                self.ilu_fallback += 1
        else:
            try:
                self.ilu = spla.splu(self.K, permc_spec="COLAMD")
            except RuntimeError:        # dependent equality rows: the dual block regularized
                try:
                    self.ilu, _ = _regularized_lu(self.K, self.dual_mask, "COLAMD")
                except RuntimeError as exc:
                    raise KKTSolveError(self.name, f"the matrix is singular: its incomplete and complete LU "
                                        f"factorizations failed, the latter also with the dual regularization "
                                        f"{DUAL_REGULARIZATION:g} max|K| ({exc})") from None
        self.M = spla.LinearOperator(self.K.shape, matvec=self.ilu.solve, dtype=np.float64)

    def _krylov(self, b, maxiter):
        count = [0]

        def cb(_r):
            count[0] += 1
            self._check_limits()

        # scipy's gmres counts maxiter in restart cycles
        cycles = max(1, -(-maxiter // self.restart))
        y, info = spla.gmres(self.K, b, M=self.M, rtol=self.rtol, atol=0.0, restart=self.restart,
                             maxiter=cycles, callback=cb, callback_type="pr_norm")
        return y, info, count[0]
