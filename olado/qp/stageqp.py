"""Stage-wise data of the QP subproblem (paper 001 eqs. (8)-(10), written as (14)).

    min  sum_{k<N} 1/2 z_k^T [Q_k S_k; S_k^T R_k] z_k + q_k.x_k + r_k.u_k + 1/2 x_N^T Q_N x_N + q_N.x_N
    s.t. x_{k+1} = A_k x_k + B_k u_k + c_k            (k < N),  x_0 = x0
         E_k x_k + F_k u_k + e_k = 0                   (k < N),  E_N x_N + e_N = 0
         c_lower_k <= C_k z_k <= c_upper_k             (k < N),  cN_lower <= C_N x_N <= cN_upper
         x_lower_k <= x_k <= x_upper_k (k <= N),       u_lower_k <= u_k <= u_upper_k (k < N)

with z_k = (x_k, u_k). Inequalities are two-sided (+-inf where absent; equal bounds fix a
variable). Stage data lives in stacked arrays (docs/architecture.md, "The linalg and qp layers"); the
variable order of the sparse form is the NLP view's y = (x_0, u_0, ..., x_{N-1}, u_{N-1}, x_N).
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import scipy.sparse as sp


@dataclasses.dataclass
class StageQP:
    """QP (14) in stage form; see the module docstring. Only Q, R, q, r, A, B, c, x0 are required."""

    Q: np.ndarray                 # (N+1, n, n)
    R: np.ndarray                 # (N, m, m)
    q: np.ndarray                 # (N+1, n)
    r: np.ndarray                 # (N, m)
    A: np.ndarray                 # (N, n, n)
    B: np.ndarray                 # (N, n, m)
    c: np.ndarray                 # (N, n)
    x0: np.ndarray                # (n,)
    S: np.ndarray | None = None   # (N, n, m)
    E: np.ndarray | None = None   # (N, ne, n)
    F: np.ndarray | None = None   # (N, ne, m)
    e: np.ndarray | None = None   # (N, ne)
    EN: np.ndarray | None = None  # (neN, n)
    eN: np.ndarray | None = None  # (neN,)
    C: np.ndarray | None = None   # (N, nc, n+m)
    c_lower: np.ndarray | None = None   # (N, nc)
    c_upper: np.ndarray | None = None   # (N, nc)
    CN: np.ndarray | None = None        # (ncN, n)
    cN_lower: np.ndarray | None = None  # (ncN,)
    cN_upper: np.ndarray | None = None  # (ncN,)
    x_lower: np.ndarray | None = None   # (N+1, n)
    x_upper: np.ndarray | None = None   # (N+1, n)
    u_lower: np.ndarray | None = None   # (N, m)
    u_upper: np.ndarray | None = None   # (N, m)

    def __post_init__(self):
        f = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731
        self.A = f(self.A)
        N, n = self.A.shape[0], self.A.shape[1]
        self.B = f(self.B)
        m = self.B.shape[2]
        self.N, self.n, self.m = N, n, m
        self.Q, self.R, self.q, self.r, self.c, self.x0 = f(self.Q), f(self.R), f(self.q), f(self.r), f(self.c), f(self.x0)
        self.S = np.zeros((N, n, m)) if self.S is None else f(self.S)
        self._complete_rows()
        self.x_lower = np.full((N + 1, n), -np.inf) if self.x_lower is None else f(self.x_lower)
        self.x_upper = np.full((N + 1, n), np.inf) if self.x_upper is None else f(self.x_upper)
        self.u_lower = np.full((N, m), -np.inf) if self.u_lower is None else f(self.u_lower)
        self.u_upper = np.full((N, m), np.inf) if self.u_upper is None else f(self.u_upper)
        self._check_shapes()

    def _complete_rows(self):
        """The equality and inequality rows as contiguous float arrays, absent ones as empty
        arrays (and infinite sides for missing inequality bounds)."""
        f = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731
        N, n, m = self.N, self.n, self.m
        if self.E is None:
            self.E, self.F, self.e = np.zeros((N, 0, n)), np.zeros((N, 0, m)), np.zeros((N, 0))
        else:
            self.E, self.F = f(self.E), f(self.F)
            self.e = np.zeros(self.E.shape[:2]) if self.e is None else f(self.e)
        if self.EN is None:
            self.EN, self.eN = np.zeros((0, n)), np.zeros(0)
        else:
            self.EN = f(np.atleast_2d(self.EN))
            self.eN = np.zeros(self.EN.shape[0]) if self.eN is None else f(self.eN)
        if self.C is None:
            self.C, self.c_lower, self.c_upper = np.zeros((N, 0, n + m)), np.zeros((N, 0)), np.zeros((N, 0))
        else:
            self.C = f(self.C)
            shp = self.C.shape[:2]
            self.c_lower = np.full(shp, -np.inf) if self.c_lower is None else f(self.c_lower)
            self.c_upper = np.full(shp, np.inf) if self.c_upper is None else f(self.c_upper)
        if self.CN is None:
            self.CN, self.cN_lower, self.cN_upper = np.zeros((0, n)), np.zeros(0), np.zeros(0)
        else:
            self.CN = f(np.atleast_2d(self.CN))
            k = self.CN.shape[0]
            self.cN_lower = np.full(k, -np.inf) if self.cN_lower is None else f(self.cN_lower)
            self.cN_upper = np.full(k, np.inf) if self.cN_upper is None else f(self.cN_upper)

    @classmethod
    def assembled(cls, *, Q, R, S, q, r, A, B, c, x0, x_lower, x_upper, u_lower, u_upper, **rows) -> StageQP:
        """A StageQP from arrays that are already C-contiguous float64 of the right shapes (the
        SQP's compiled QP assembly, olado.solvers.sqp.kernels): the dataclass's conversions and
        shape checks of these are skipped; the optional rows (``E``, ``C``, ...) in ``rows`` are
        completed and checked as by the constructor. The same object the constructor would make."""
        qp = cls.__new__(cls)
        d = qp.__dict__
        d.update(Q=Q, R=R, q=q, r=r, A=A, B=B, c=c, x0=x0, S=S, E=None, F=None, e=None, EN=None, eN=None, C=None,
                 c_lower=None, c_upper=None, CN=None, cN_lower=None, cN_upper=None, x_lower=x_lower,
                 x_upper=x_upper, u_lower=u_lower, u_upper=u_upper)
        d.update(rows)
        qp.N, qp.n, qp.m = A.shape[0], A.shape[1], B.shape[2]
        qp._complete_rows()
        if rows:
            qp._check_shapes()
        return qp

    def _check_shapes(self):
        N, n, m = self.N, self.n, self.m
        expected = {"Q": (N + 1, n, n), "R": (N, m, m), "q": (N + 1, n), "r": (N, m), "A": (N, n, n),
                    "B": (N, n, m), "c": (N, n), "x0": (n,), "S": (N, n, m), "x_lower": (N + 1, n),
                    "x_upper": (N + 1, n), "u_lower": (N, m), "u_upper": (N, m)}
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"StageQP.{name}: expected shape {shape}, got {getattr(self, name).shape}")
        ne = self.E.shape[1]
        for name, shape in {"E": (N, ne, n), "F": (N, ne, m), "e": (N, ne)}.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"StageQP.{name}: expected shape {shape}, got {getattr(self, name).shape}")
        nc = self.C.shape[1]
        for name, shape in {"C": (N, nc, n + m), "c_lower": (N, nc), "c_upper": (N, nc)}.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"StageQP.{name}: expected shape {shape}, got {getattr(self, name).shape}")

    # ------------------------------------------------------------------ sizes
    @property
    def n_vars(self) -> int:
        return self.N * (self.n + self.m) + self.n

    def pack(self, X, U):
        """y = (x_0, u_0, ..., x_N) from X (N+1, n), U (N, m)."""
        nz = self.n + self.m
        y = np.empty(self.n_vars)
        st = y[: self.N * nz].reshape(self.N, nz)
        st[:, : self.n] = X[:-1]
        st[:, self.n:] = U
        y[self.N * nz:] = X[-1]
        return y

    def unpack(self, y):
        nz = self.n + self.m
        st = y[: self.N * nz].reshape(self.N, nz)
        X = np.vstack([st[:, : self.n], y[self.N * nz:][None, :]])
        return X, st[:, self.n:].copy()

    def objective(self, X, U) -> float:
        """Value of the quadratic objective."""
        Xs = X[:-1]
        val = 0.5 * np.einsum("ki,kij,kj->", Xs, self.Q[:-1], Xs) + np.einsum("ki,kij,kj->", Xs, self.S, U)
        val += 0.5 * np.einsum("ki,kij,kj->", U, self.R, U) + np.sum(self.q[:-1] * Xs) + np.sum(self.r * U)
        val += 0.5 * X[-1] @ self.Q[-1] @ X[-1] + self.q[-1] @ X[-1]
        return float(val)

    # ------------------------------------------------------------------ sparse form
    def to_sparse(self):
        """The QP as sparse matrices over y: a dict with P (upper+lower, CSC), q, A_eq, b_eq
        (A_eq y = b_eq: x_0 fixing, dynamics, stage and final equalities), G, h_lower, h_upper
        (h_lower <= G y <= h_upper: the general inequalities) and lb, ub (variable bounds)."""
        N, n, m = self.N, self.n, self.m
        nz = n + m
        nv = self.n_vars
        xi = lambda k: (k * nz if k < N else N * nz) + np.arange(n)  # noqa: E731
        # Hessian
        blocks = np.empty((N, nz, nz))
        blocks[:, :n, :n] = self.Q[:-1]
        blocks[:, :n, n:] = self.S
        blocks[:, n:, :n] = np.transpose(self.S, (0, 2, 1))
        blocks[:, n:, n:] = self.R
        P = sp.block_diag(list(blocks) + [self.Q[-1]], format="csc")
        P = 0.5 * (P + P.T)
        qv = self.pack(self.q, self.r)
        # equalities
        rows, cols, vals, rhs = [], [], [], []
        row = 0
        rows.append(np.arange(n)); cols.append(xi(0)); vals.append(np.ones(n)); rhs.append(self.x0); row += n
        k = np.arange(N)
        dyn_rows = row + k[:, None] * n + np.arange(n)[None, :]
        rows += [np.repeat(dyn_rows, n, axis=1).ravel(), np.repeat(dyn_rows, m, axis=1).ravel(), dyn_rows.ravel()]
        cols += [np.tile((k[:, None] * nz + np.arange(n)[None, :])[:, None, :], (1, n, 1)).ravel(),
                 np.tile((k[:, None] * nz + n + np.arange(m)[None, :])[:, None, :], (1, n, 1)).ravel(),
                 np.concatenate([xi(j + 1) for j in range(N)])]
        vals += [self.A.ravel(), self.B.ravel(), -np.ones(N * n)]
        rhs.append(-self.c.ravel()); row += N * n
        ne = self.E.shape[1]
        if ne:
            er = row + k[:, None] * ne + np.arange(ne)[None, :]
            rows += [np.repeat(er, n, axis=1).ravel(), np.repeat(er, m, axis=1).ravel()]
            cols += [np.tile((k[:, None] * nz + np.arange(n)[None, :])[:, None, :], (1, ne, 1)).ravel(),
                     np.tile((k[:, None] * nz + n + np.arange(m)[None, :])[:, None, :], (1, ne, 1)).ravel()]
            vals += [self.E.ravel(), self.F.ravel()]
            rhs.append(-self.e.ravel()); row += N * ne
        neN = self.EN.shape[0]
        if neN:
            rows.append(np.repeat(row + np.arange(neN), n)); cols.append(np.tile(xi(N), neN)); vals.append(self.EN.ravel())
            rhs.append(-self.eN); row += neN
        A_eq = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row, nv))
        b_eq = np.concatenate(rhs)
        # general inequalities
        nc = self.C.shape[1]
        grows, gcols, gvals, lo, hi = [], [], [], [], []
        grow = 0
        if nc:
            cr = k[:, None] * nc + np.arange(nc)[None, :]
            grows.append(np.repeat(cr, nz, axis=1).ravel())
            gcols.append(np.tile((k[:, None] * nz + np.arange(nz)[None, :])[:, None, :], (1, nc, 1)).ravel())
            gvals.append(self.C.ravel()); lo.append(self.c_lower.ravel()); hi.append(self.c_upper.ravel()); grow += N * nc
        ncN = self.CN.shape[0]
        if ncN:
            grows.append(np.repeat(grow + np.arange(ncN), n)); gcols.append(np.tile(xi(N), ncN)); gvals.append(self.CN.ravel())
            lo.append(self.cN_lower); hi.append(self.cN_upper); grow += ncN
        if grow:
            G = sp.csc_matrix((np.concatenate(gvals), (np.concatenate(grows), np.concatenate(gcols))), shape=(grow, nv))
            h_lower, h_upper = np.concatenate(lo), np.concatenate(hi)
        else:
            G, h_lower, h_upper = sp.csc_matrix((0, nv)), np.zeros(0), np.zeros(0)
        lb = self.pack(self.x_lower, self.u_lower)
        ub = self.pack(self.x_upper, self.u_upper)
        return {"P": P.tocsc(), "q": qv, "A_eq": A_eq, "b_eq": b_eq, "G": G, "h_lower": h_lower,
                "h_upper": h_upper, "lb": lb, "ub": ub}


# ============================================================================= QP results
@dataclasses.dataclass
class QPResult:
    """Solution of a :class:`StageQP` by any QP method (interior point, OSQP, Clarabel ...).

    Multiplier convention (all inequality multipliers >= 0), with z_k = (x_k, u_k):

        L = objective + sum_k lam_{k+1}.(A_k x_k + B_k u_k + c_k - x_{k+1}) + lam_0.(x0 - x_0)
            + sum_k nu_k.(E_k x_k + F_k u_k + e_k) + nu_N.(E_N x_N + e_N)
            - zx_lower.(x - x_lower) + zx_upper.(x - x_upper) - zu_lower.(u - u_lower) + zu_upper.(u - u_upper)
            - yc_lower.(C z - c_lower) + yc_upper.(C z - c_upper) - yN_lower.(C_N x_N - cN_lower) + yN_upper.(C_N x_N - cN_upper)

    ``status`` is an :class:`olado.result.Status`; ``kkt`` holds the residuals measured by
    :func:`qp_kkt_residuals` (stationarity, primal infeasibility, complementarity), so results of
    different solvers can be compared at the same accuracy.
    """

    status: object
    message: str
    X: np.ndarray
    U: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    zx_lower: np.ndarray
    zx_upper: np.ndarray
    zu_lower: np.ndarray
    zu_upper: np.ndarray
    yc_lower: np.ndarray
    yc_upper: np.ndarray
    yN_lower: np.ndarray
    yN_upper: np.ndarray
    objective: float = float("nan")
    iterations: int = 0
    time_s: float = 0.0
    kkt: dict = dataclasses.field(default_factory=dict)
    history: list = dataclasses.field(default_factory=list)
    solver: str = ""
    #: largest primal regularization delta (delta*I added to the Hessian of the Newton systems)
    #: the solve needed -- for a failed solve the value at which the factorization last failed;
    #: a caller with a nonconvex Hessian (the SQP's inertia correction) can shift by at least this
    regularization: float = 0.0
    #: the active-set method's final working set: for each kind of BOX_FIELDS ("x", "u", "c",
    #: "cN") the boolean masks (lower side, upper side) of the inequality sides held at their
    #: bounds, in the shapes of the boxes; its warm start begins there. None from other methods
    active_set: dict | None = None

    @property
    def success(self) -> bool:
        return getattr(self.status, "success", False)

    def defer_measures(self, qp: StageQP):
        """``kkt`` and ``objective`` measured on first access (:func:`qp_kkt_residuals` and
        ``qp.objective`` of this result's X, U, as they are then): a caller that never reads them
        (the SQP) saves their ~50 array operations, about half a millisecond a QP at N = 24."""
        self.__dict__["_kkt_of"] = self.__dict__["_objective_of"] = qp

    def replaced(self, **changes) -> QPResult:
        """A copy with ``changes`` (as dataclasses.replace, which would measure deferred values
        first); a deferred ``kkt`` or ``objective`` stays deferred, measured on the copy's own
        values when read."""
        out = copy.copy(self)
        for name, value in changes.items():
            setattr(out, name, value)
        return out


def _deferred(name, measure):
    """The property ``name`` of a QPResult: its value, or -- after :meth:`QPResult.defer_measures`
    -- ``measure(qp, result)`` on first access. (The pending entry holds the QP only: a reference
    to the result itself would make a cycle, tests/qp/test_no_reference_cycles.py.)"""
    slot, pending = "_" + name, "_" + name + "_of"

    def get(res):
        d = res.__dict__
        qp = d.get(pending)
        if qp is not None:
            d[slot] = measure(qp, res)
            d[pending] = None
        return d[slot]

    def put(res, value):
        res.__dict__[pending] = None
        res.__dict__[slot] = value

    return property(get, put)


QPResult.kkt = _deferred("kkt", lambda qp, res: qp_kkt_residuals(qp, res))
QPResult.objective = _deferred("objective", lambda qp, res: qp.objective(res.X, res.U))


#: the boxes of a StageQP and the multipliers of their sides in a QPResult:
#: (kind, lower bound, upper bound, lower-side multiplier, upper-side multiplier) field names
BOX_FIELDS = (("x", "x_lower", "x_upper", "zx_lower", "zx_upper"), ("u", "u_lower", "u_upper", "zu_lower", "zu_upper"),
              ("c", "c_lower", "c_upper", "yc_lower", "yc_upper"), ("cN", "cN_lower", "cN_upper", "yN_lower", "yN_upper"))


def box_values(qp: StageQP, X, U) -> dict:
    """The boxed quantities of ``qp`` at (X, U), by the kinds of :data:`BOX_FIELDS`: x, u, the
    stage rows C_k z_k (z_k = (x_k, u_k)) and the final rows C_N x_N."""
    Z = np.concatenate([X[:-1], U], axis=1)
    return {"x": X, "u": U, "c": np.einsum("kij,kj->ki", qp.C, Z), "cN": qp.CN @ X[-1]}


def qp_kkt_residuals(qp: StageQP, res: QPResult) -> dict:
    """Max-norm KKT residuals of ``res`` for ``qp`` under the :class:`QPResult` convention:
    ``stationarity`` (gradient of L w.r.t. x and u), ``primal`` (equality residuals and bound /
    inequality violations), ``complementarity`` (max |multiplier * slack| over finite sides) and
    ``dual_sign`` (most negative inequality multiplier, as a positive number)."""
    N, n, m = qp.N, qp.n, qp.m
    X, U = res.X, res.U
    ne, ncs, neN, ncN = qp.E.shape[1], qp.C.shape[1], qp.EN.shape[0], qp.CN.shape[0]
    nu = res.nu
    # gradient of the objective
    gx = np.einsum("kij,kj->ki", qp.Q[:-1], X[:-1]) + np.einsum("kij,kj->ki", qp.S, U) + qp.q[:-1]
    gu = np.einsum("kji,kj->ki", qp.S, X[:-1]) + np.einsum("kij,kj->ki", qp.R, U) + qp.r
    gN = qp.Q[-1] @ X[-1] + qp.q[-1]
    lam = res.lam
    gx = gx + np.einsum("kji,kj->ki", qp.A, lam[1:]) - lam[:-1]
    gu = gu + np.einsum("kji,kj->ki", qp.B, lam[1:])
    gN = gN - lam[-1]
    if ne:
        gx = gx + np.einsum("kji,kj->ki", qp.E, nu[:N, :ne]); gu = gu + np.einsum("kji,kj->ki", qp.F, nu[:N, :ne])
    if neN:
        gN = gN + qp.EN.T @ nu[N, :neN]
    gx = gx - res.zx_lower[:-1] + res.zx_upper[:-1]
    gN = gN - res.zx_lower[-1] + res.zx_upper[-1]
    gu = gu - res.zu_lower + res.zu_upper
    if ncs:
        gz = np.einsum("kji,kj->ki", qp.C, res.yc_upper - res.yc_lower)
        gx = gx + gz[:, :n]; gu = gu + gz[:, n:]
    if ncN:
        gN = gN + qp.CN.T @ (res.yN_upper - res.yN_lower)
    stat = max(np.abs(gx).max(initial=0.0), np.abs(gu).max(initial=0.0), np.abs(gN).max(initial=0.0))
    # primal
    dyn = np.einsum("kij,kj->ki", qp.A, X[:-1]) + np.einsum("kij,kj->ki", qp.B, U) + qp.c - X[1:]
    prim = max(np.abs(dyn).max(initial=0.0), np.abs(X[0] - qp.x0).max(initial=0.0))
    if ne:
        prim = max(prim, np.abs(np.einsum("kij,kj->ki", qp.E, X[:-1]) + np.einsum("kij,kj->ki", qp.F, U) + qp.e).max())
    if neN:
        prim = max(prim, np.abs(qp.EN @ X[-1] + qp.eN).max())
    # every box side in one flat vector (the maxima are exact whatever the grouping)
    vals = box_values(qp, X, U)
    kinds = [f for f in BOX_FIELDS if vals[f[0]].size]
    flat = lambda arrays: np.concatenate([np.ravel(a) for a in arrays])  # noqa: E731
    val = flat([vals[f[0]] for f in kinds])
    lo, hi = flat([getattr(qp, f[1]) for f in kinds]), flat([getattr(qp, f[2]) for f in kinds])
    zl, zu = flat([getattr(res, f[3]) for f in kinds]), flat([getattr(res, f[4]) for f in kinds])
    fl, fu = np.isfinite(lo), np.isfinite(hi)
    sl = np.where(fl, val - lo, 0.0)
    su = np.where(fu, hi - val, 0.0)
    prim = max(prim, float(np.maximum(-sl, 0.0).max(initial=0.0)), float(np.maximum(-su, 0.0).max(initial=0.0)))
    comp = max(float(np.abs(np.where(fl, zl * sl, 0.0)).max(initial=0.0)),
               float(np.abs(np.where(fu, zu * su, 0.0)).max(initial=0.0)))
    sign = max(float(np.maximum(-zl, 0.0).max(initial=0.0)), float(np.maximum(-zu, 0.0).max(initial=0.0)))
    return {"stationarity": float(stat), "primal": float(prim), "complementarity": comp, "dual_sign": sign}
