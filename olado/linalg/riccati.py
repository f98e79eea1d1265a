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

import numpy as np

from ..errors import OladoError
from .backend import RHS, LQSolution, NotPositiveDefiniteError, Solution, StageData, _f64
from .codegen import fixed_size_tags, kernel_set
from .riccati_fixed import (_STRAIGHT_N_MAX, _factor_unconstrained_fixed, _factor_unconstrained_fixed_loops,
                            _solve_unconstrained_fixed)
from .riccati_kernels import (Costs, Dynamics, EqualityRows, GeneralFactors, IPTerms, PlainFactors, _factor,
                              _factor_unconstrained, _solve, _solve_unconstrained)
from .riccati_residual import _kkt_residual

#: the kernels of the recursion, called through a KernelSet (codegen.kernel_set: the stage arrays
#: are C-contiguous float64, so the argument types depend only on the size tags)
_KERNELS = {"factor": _factor, "solve": _solve, "factor_plain": _factor_unconstrained,
            "solve_plain": _solve_unconstrained, "residual": _kkt_residual, "factor_fixed": _factor_unconstrained_fixed,
            "factor_fixed_loops": _factor_unconstrained_fixed_loops, "solve_fixed": _solve_unconstrained_fixed}

_NU = Solution._fields.index("nu")

#: static pivots (module docstring): a combined row whose u-part is below PIVOT_TOL times the row's
#: norm is not used as a pivot -- its elimination would put gains up to 1/PIVOT_TOL into K_k and
#: their square into P_k, whose rounding then swamps the cost-to-go -- but passed back with the
#: dependent rows; its left-out u-coupling is put back by iterative refinement
PIVOT_TOL = 1e-6
#: refinement steps at most, the relative residual at which they stop, and the largest relative
#: residual accepted before the exact pivots are used instead
REFINE_STEPS = 10
REFINE_TOL = 1e-14
REFINE_ACCEPT = 1e-9

__all__ = ["RiccatiFactorization", "solve_lq_docp", "LQSolution", "StageData", "NotPositiveDefiniteError",
           "RiccatiStatusError"]


class RiccatiStatusError(OladoError):
    """Equality rows exceeding the recursion's row buffers. Since the passed-back state rows are
    compressed to an independent set (at most n rows) this is not expected to happen; dependent
    rows are handled, inconsistent ones reported through ``LQSolution.x0_residual``."""


class RiccatiFactorization:
    """Factorization of the LQ-DOCP KKT matrix by the block Riccati recursion (a
    :class:`~olado.linalg.backend.KKTBackend`); :meth:`solve` applies it to right-hand sides.

    The constructor takes the arguments of :class:`~olado.linalg.backend.StageData` (held as
    ``data``) and ``rank_tol``, the relative rank tolerance of the pivoted QRs of the general
    recursion. Without equality rows (``unconstrained``) the plain recursion is used, compiled for
    the block sizes when they are small."""

    limits = None       # KKTBackend.limits: not read (a factorization and a solve are O(N) sweeps)
    _released = None    # the placeholders release_blocks puts in the blocks' place (one tuple per object)

    def __init__(self, Q, S, R, A, B, *, E=None, F=None, n_eq=None, EN=None, Dx=None, Du=None,
                 Ci=None, sigma=None, n_ineq=None, regularization=0.0, rank_tol=1e-10, pivot_tol=PIVOT_TOL):
        d = self.data = StageData(Q, S, R, A, B, E=E, F=F, n_eq=n_eq, EN=EN, Dx=Dx, Du=Du, Ci=Ci, sigma=sigma,
                                  n_ineq=n_ineq, regularization=regularization)
        N, n, m = self.N, self.n, self.m = d.N, d.n, d.m
        self.rank_tol = float(rank_tol)
        self.pivot_tol = max(float(pivot_tol), self.rank_tol)
        #: whether the last factorization left out a u-coupling (static pivots, see _refine)
        self.perturbed = False
        # the stage arrays as the kernels take them (plain tuples, codegen.as_bundle), by role
        self._costs = tuple(Costs(Q=d.Q, S=d.S, R=d.R))
        self._dyn = tuple(Dynamics(A=d.A, B=d.B))
        self._eq = tuple(EqualityRows(E=d.E, F=d.F, ne=d.ne, EN=d.EN))
        self._ipt = None
        # fast path: no equality rows anywhere -> plain Riccati recursion, none of the constraint
        # workspaces (QR factors, propagated rows) are allocated
        self.unconstrained = not d.has_equality_rows
        if self.unconstrained:
            self.ncmax = 0
            self.P = np.empty((N + 1, n, n)); self.K = np.empty((N, m, n)); self.Lww = np.empty((N, m, m))
            self._factors = tuple(PlainFactors(P=self.P, K=self.K, L=self.Lww))
            # small blocks: the kernels compiled for these sizes (olado.linalg.codegen.FIXED_SIZE_MAX)
            self._size_tags = fixed_size_tags(n, m)
        else:
            ncmax = max(d.ne_max + n + d.neN, 1)
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
            self.dropped = np.zeros(N)
            self._factors = tuple(GeneralFactors(P=self.P, K=self.K, Quu=self.Quu, Qux=self.Qux, Lww=self.Lww, Qm=self.Qm,
                                                 Rm=self.Rm, perm=self.perm, rank=self.rank, nc=self.nc, Cx=self.Cx, G=self.G,
                                                 ng=self.ng, Wx=self.Wx, Dmat=self.Dmat, pg=self.pg, Zg=self.Zg,
                                                 dropped=self.dropped))
            self._size_tags = None
        self._kernels = kernel_set(_KERNELS, None if self._size_tags is None else (n, m))
        self._factorize()

    def refactor(self, Dx=None, Du=None, sigma=None, regularization=None, from_stage=None):
        """Factorize again after a change of the diagonal terms only -- the interior-point
        Newton matrix of the next iteration (arguments as
        :meth:`~olado.linalg.backend.StageData.set_diagonal`); Q, S, R, A, B and the equality
        rows stay.  The factors are overwritten in place (no new allocation: on large N the first
        touch of fresh factor arrays costs as much as the kernel).  Raises
        NotPositiveDefiniteError like the constructor (the object must then be refactored before
        the next solve).

        ``from_stage`` k (general recursion only; the plain one always factors every stage):
        only the stages <= k are factored again, for a caller that changed the stage data of
        those stages only -- in place, e.g. equality rows written into E, F and their counts into
        ``data.ne`` (the active-set QP's working-set changes) -- and whose last factorization
        of this object succeeded; the backward sweep's factors of the later stages are kept."""
        self.data.set_diagonal(Dx=Dx, Du=Du, sigma=sigma, regularization=regularization)
        self._factorize(self.N - 1 if from_stage is None else max(-1, min(int(from_stage), self.N - 1)))
        return self

    def refactor_in_place(self):
        """:meth:`refactor` after the caller wrote the new diagonal terms into ``data.Dx``,
        ``data.Du`` in place (no stage-row weights, no regularization change: the same
        factorization, without set_diagonal's checks)."""
        self._factorize(self.N - 1)
        return self

    def set_blocks(self, Q, S, R, A, B):
        """New cost and dynamics blocks of the same shapes -- the Newton matrix of an
        interior-point NLP's next iteration -- held by reference (copied only if not C-contiguous
        float64); the equality rows, the stage inequality rows and the factor arrays stay.
        Factor with :meth:`refactor` before the next solve."""
        d = self.data
        d.Q, d.S, d.R = _held(Q, d.Q, "Q"), _held(S, d.S, "S"), _held(R, d.R, "R")
        d.A, d.B = _held(A, d.A, "A"), _held(B, d.B, "B")
        self._costs = (d.Q, d.S, d.R)       # tuple(Costs(...)): the kernels' plain tuples, in field order
        self._dyn = (d.A, d.B)              # tuple(Dynamics(...))
        return self

    def release_blocks(self):
        """Drop the references to the cost and dynamics blocks (placeholders of their shapes take
        their place, for :meth:`set_blocks`' shape test): an interior-point NLP's previous Newton
        matrix lets its iteration's blocks go before the next ones are evaluated. Neither
        factor nor solve before the next :meth:`set_blocks`."""
        d = self.data
        held = self._released
        if held is None or held[0].shape != d.Q.shape or held[3].shape != d.A.shape:
            # the placeholders of this object's shapes, looked up once (the same object is
            # released once per interior-point iteration)
            held = self._released = tuple(_placeholder(a.shape) for a in (d.Q, d.S, d.R, d.A, d.B))
        d.Q, d.S, d.R, d.A, d.B = held
        self._costs = self._dyn = None
        return self

    def release_costs(self):
        """Drop the references to the cost blocks Q, S, R (placeholders of their shapes take their
        place) when the solves of this factorization do not read them -- the plain recursion of
        small blocks (:meth:`fixed_solve_operands`; its compiled solve takes the dynamics, the
        interior-point terms and the factors only); False otherwise (nothing changed). Solves work
        as before; no factorization before the next :meth:`set_blocks`."""
        if self.fixed_solve_operands() is None:
            return False
        d = self.data
        d.Q, d.S, d.R = _placeholder(d.Q.shape), _placeholder(d.S.shape), _placeholder(d.R.shape)
        self._costs = None
        return True

    def _ip_terms(self):
        """The kernels' IPTerms bundle of ``data`` (a plain tuple: codegen.as_bundle), rebuilt
        only when a refactor replaced one of its arrays; the other roles (Costs, Dynamics,
        EqualityRows) are built once, in the constructor."""
        d, ipt = self.data, self._ipt
        if (ipt is None or ipt[0] is not d.Dx or ipt[1] is not d.Du or ipt[2] is not d.Ci or ipt[3] is not d.sig
                or ipt[4] is not d.ni):
            ipt = self._ipt = tuple(IPTerms(Dx=d.Dx, Du=d.Du, Ci=d.Ci, sig=d.sig, ni=d.ni))
        return ipt

    def _factorize(self, k_start=None):
        # the interior-point terms as the kernels take them, for the factorization and its
        # solves (a refactor may have replaced their arrays); the general recursion factors the
        # stages <= k_start (default: all)
        ipt = self._ip_terms()
        reg, costs, dyn, k = self.data.regularization, self._costs, self._dyn, self._kernels
        if self.unconstrained:
            if self._size_tags is None:
                code = k.factor_plain(costs, dyn, ipt, reg, self._factors)
            elif self.n <= _STRAIGHT_N_MAX:
                code = k.factor_fixed(self._size_tags, costs, dyn, ipt, reg, self._factors)
            else:
                code = k.factor_fixed_loops(self._size_tags, costs, dyn, ipt, reg, self._factors)
            if code >= 0:
                raise NotPositiveDefiniteError(code)
            return
        k_start = self.N - 1 if k_start is None else k_start
        for w in (self.Lww, self.Rm, self.perm, self.rank, self.nc, self.Cx, self.G, self.ng, self.Wx, self.Dmat,
                  self.pg, self.Zg, self.dropped):
            w[:k_start + 1].fill(0)   # the general kernel expects zeroed padding (a refactor reuses the arrays)
        code = k.factor(costs, dyn, self._eq, ipt, reg, self.rank_tol, self.pivot_tol, self._factors, k_start)
        self.perturbed = code < 0 and bool(self.dropped.any())
        if code >= 0 and self.pivot_tol > self.rank_tol and self.dropped.any():
            # a failure after a static pivot: the exact pivots (old behaviour) decide
            code = self._exact_pivots()
        if code >= 0:
            raise NotPositiveDefiniteError(code)
        if code <= -1000:
            raise RiccatiStatusError(f"more than {self.ncmax} equality rows reach stage k={-code - 1000} "
                                     "(more than the row buffers hold)")

    def _exact_pivots(self):
        """Factor the whole sweep again with every pivot above rank_tol used (no static pivots);
        returns the kernel's code."""
        ipt, k = self._ip_terms(), self._kernels
        for w in (self.Lww, self.Rm, self.perm, self.rank, self.nc, self.Cx, self.G, self.ng, self.Wx, self.Dmat,
                  self.pg, self.Zg, self.dropped):
            w.fill(0)
        code = k.factor(self._costs, self._dyn, self._eq, ipt, self.data.regularization, self.rank_tol, self.rank_tol,
                        self._factors, self.N - 1)
        self.perturbed = False
        return code

    def solve(self, q, r, c, x0, e=None, eN=None, ci=None, out=None) -> LQSolution:
        """Solve for one right-hand side: linear cost terms q (N+1, n), r (N, m); dynamics
        offsets c (N, n); initial state x0 (n,); equality offsets e (N, ne), eN (neN,); for the
        stage inequality terms, ci (N, nineq) is the constant in C_k z_k + ci_k (the Hessian term
        sigma * C^T C adds sigma * C^T ci to the gradient).  ``out`` = (X, U, lam): C-contiguous
        float arrays of shapes (N+1, n), (N, m), (N+1, n) to write the solution into (the
        returned LQSolution holds them)."""
        N, n, m = self.N, self.n, self.m
        rhs = self.data.rhs_arrays(q, r, c, x0, e, eN, ci)
        if out is None:
            X = np.empty((N + 1, n)); U = np.empty((N, m)); lam = np.empty((N + 1, n))
        else:
            X, U, lam = out
            for a, shape, name in ((X, (N + 1, n), "X"), (U, (N, m), "U"), (lam, (N + 1, n), "lam")):
                if a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous:
                    raise ValueError(f"out: {name} must be a C-contiguous float64 array of shape {shape}")
        nu = np.zeros((N + 1, max(self.data.ne_max, self.data.neN)))
        res = self.solve_into(rhs, Solution(X, U, lam, nu))
        return LQSolution(X, U, lam, nu, res)

    def fixed_factor_operands(self):
        """(size tags, interior-point terms, regularization, factors) of the plain recursion of
        small blocks straight-line kernels (n <= riccati_fixed._STRAIGHT_N_MAX), for a kernel that
        factors and solves itself with its own cost and dynamics blocks (the interior-point NLP's
        compiled iteration, olado.solvers.ipm.iteration_kernels): it writes the diagonal terms
        into the first two arrays of the interior-point terms (``data.Dx``, ``data.Du``); None for
        the other recursions."""
        if not self.unconstrained or self._size_tags is None or self.n > _STRAIGHT_N_MAX:
            return None
        return self._size_tags, self._ip_terms(), self.data.regularization, self._factors

    def fixed_solve_operands(self):
        """The operands of the plain Riccati recursion of small blocks (size tags, dynamics,
        interior-point terms, factors) in the order its compiled solve takes them, for a kernel that
        calls that solve itself (the interior-point QP's fused Newton solve); None for the other
        recursions (equality rows, blocks above the fixed-size limit)."""
        if not self.unconstrained or self._size_tags is None:
            return None
        return self._size_tags, self._dyn, self._ipt, self._factors

    def solve_into(self, rhs: RHS, out: Solution) -> float:
        """:meth:`solve` without argument checks or result object, for callers whose arrays are
        already C-contiguous float64 of the right shapes (the interior-point QP's work arrays,
        validated once when the QP is prepared): writes the solution into ``out`` (nu zero where
        no row counts) and returns ``LQSolution.x0_residual``."""
        out[_NU].fill(0.0)
        rhs, out = tuple(rhs), tuple(out)       # the kernels take plain tuples (codegen.as_bundle)
        k = self._kernels
        if not self.unconstrained:
            res = float(k.solve(self._costs, self._dyn, self._eq, self._ipt, self._factors, rhs, out))
            if self.perturbed:
                res = self._refine(rhs, out)
            return res
        if self._size_tags is None:
            k.solve_plain(self._costs, self._dyn, self._ipt, self._factors, rhs, out)
        else:
            k.solve_fixed(self._size_tags, self._dyn, self._ipt, self._factors, rhs, out)
        return 0.0

    def _refine(self, rhs, out):
        """Iterative refinement of a solution of the factorization with static pivots (the
        module docstring; Li and Demmel 1998): the KKT residual (:meth:`kkt_residual`) of the
        exact system is solved for with the same factors and the correction added, until the
        residual is at rounding level (relative to the size of the KKT rows' terms) or stops
        decreasing.  If it stays above REFINE_ACCEPT, the static pivots made the factored matrix
        too far from the exact one (a row the earlier stages cannot reach): the whole sweep is
        factored again with the exact pivots and the right-hand side solved with those.
        Returns the equality-row infeasibility (``LQSolution.x0_residual``)."""
        X, U, lam, nu = out
        corr = Solution(np.empty_like(X), np.empty_like(U), np.empty_like(lam), np.empty_like(nu))
        k = self._kernels
        best = None
        for _ in range(REFINE_STEPS + 1):
            resid, size, infeas = self.kkt_residual(rhs, out)
            err = max(float(np.abs(a).max(initial=0.0)) for a in resid) / size
            if best is not None and err >= 0.5 * best:
                break
            best = err
            if err <= REFINE_TOL:
                break
            corr[_NU].fill(0.0)
            k.solve(self._costs, self._dyn, self._eq, self._ipt, self._factors, tuple(resid), tuple(corr))
            for a, b in zip(out, corr):
                a += b
        if best <= REFINE_ACCEPT:
            return infeas
        # the static pivots are too coarse for this system: exact pivots (a fresh solve); if
        # those fail, the static ones again and the refined solution stands
        code = self._exact_pivots()
        if code >= 0:
            self._factorize()
            return infeas
        out[_NU].fill(0.0)
        return float(k.solve(self._costs, self._dyn, self._eq, self._ipt, self._factors, tuple(rhs), tuple(out)))

    def kkt_residual(self, rhs, sol):
        """The residual of the KKT rows of the factored system (with its regularization) at
        ``sol`` = (X, U, lam, nu), as a right-hand side (RHS: the stationarity rows in q, r, the
        dynamics rows in c, the equality rows in e, eN; x0 and ci zero -- X[0] = x0 holds
        exactly), with the size of the rows' terms and the max-norm of the equality rows
        (:func:`~olado.linalg.riccati_residual._kkt_residual`)."""
        resid = RHS(*(np.empty_like(a) for a in rhs))
        size, infeas = self._kernels.residual(self._costs, self._dyn, self._eq, self._ip_terms(),
                                              self.data.regularization, tuple(rhs), tuple(sol), tuple(resid))
        return resid, float(size), float(infeas)

_PLACEHOLDERS: dict = {}


def _placeholder(shape):
    """A read-only zero array of ``shape`` on one float (zero strides), one per shape: built once
    (as_strided costs ~10 us, ten per interior-point iteration), then shared."""
    a = _PLACEHOLDERS.get(shape)
    if a is None:
        if len(_PLACEHOLDERS) > 256:
            _PLACEHOLDERS.clear()
        a = _PLACEHOLDERS[shape] = np.lib.stride_tricks.as_strided(np.zeros(1), shape, (0,) * len(shape),
                                                                    writeable=False)
    return a


def _held(a, held, name):
    """``a`` in place of the held array ``held``: ``a`` itself when it is a C-contiguous float64
    ndarray of held's shape (what _f64 would return), else _f64's copy or error."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.shape == held.shape and a.flags.c_contiguous:
        return a
    return _f64(a, held.shape, name)


def solve_lq_docp(Q, S, R, q, r, A, B, c, x0, **kw) -> LQSolution:
    """Factorize and solve in one call (see :class:`RiccatiFactorization`)."""
    rhs = {k: kw.pop(k) for k in ("e", "eN", "ci") if k in kw}
    return RiccatiFactorization(Q, S, R, A, B, **kw).solve(q, r, c, x0, **rhs)
