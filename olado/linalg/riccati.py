"""Block Riccati solver for the equality-constrained LQ-DOCP (paper 001 sec. 4.2.3).

Solves the KKT system of the linear-quadratic DOCP

    min  sum_k 1/2 [x_k; u_k]^T [Q_k S_k; S_k^T R_k] [x_k; u_k] + q_k.x_k + r_k.u_k
         + 1/2 x_N^T Q_N x_N + q_N.x_N
    s.t. x_{k+1} = A_k x_k + B_k u_k + c_k,   x_0 = xbar_0,
         E_k x_k + F_k u_k + e_k = 0  (k < N),   E_N x_N + e_N = 0,

i.e. the equality part of QP (14) after the interior-point method has folded its inequalities
into the Hessian (system (25)): the diagonal terms ``Dx`` (N+1, n), ``Du`` (N, m) of simple
bounds and the terms C_k^T diag(sigma_k) C_k of linear stage inequalities are accepted directly.

The recursion (Arnold's block elimination in the constraint-propagating form, and the plain
Riccati recursion when there are no equality rows) is compiled: :mod:`olado.linalg.riccati_kernels`
(any block size) and :mod:`olado.linalg.riccati_fixed` (small blocks, compiled for their sizes).
The factorization depends only on the matrices; :meth:`RiccatiFactorization.solve` takes any
number of right-hand sides (q, r, c, e, xbar_0), each in O(N (n+m)^2).

Multipliers: with the Lagrangian
    L = J + sum_k lam_{k+1}.(A_k x_k + B_k u_k + c_k - x_{k+1}) + lam_0.(xbar_0 - x_0)
          + sum_k nu_k.(E_k x_k + F_k u_k + e_k) + nu_N.(E_N x_N + e_N),
``solve`` returns lam (N+1, n) and nu (N+1, ne). (The paper's p in (16) is -lam.)
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import OladoError
from .codegen import fixed_size_tags
from .riccati_fixed import (_STRAIGHT_N_MAX, _factor_unconstrained_fixed, _factor_unconstrained_fixed_loops,
                            _solve_unconstrained_fixed)
from .riccati_kernels import _factor, _factor_unconstrained, _solve, _solve_unconstrained


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
            # small blocks: the kernels compiled for these sizes (olado.linalg.codegen.FIXED_SIZE_MAX)
            self._size_tags = fixed_size_tags(n, m)
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
