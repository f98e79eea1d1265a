"""External QP solvers (OSQP, Clarabel, PIQP, ... through qpsolvers) for the QP subproblem (14).

The stage QP of :class:`olado.qp.stageqp.StageQP` is handed to a qpsolvers backend in its
sparse form (``StageQP.to_sparse``) as

    min 1/2 y^T P y + q.y   s.t.  A y = b,  G y <= h,  lb <= y <= ub,

with the bookkeeping (per row: which original constraint, which side) needed to map the
backend's multipliers back to the :class:`olado.qp.stageqp.QPResult` convention:

* equality rows: x_0 fixing (lam_0 = -y), dynamics (lam_{k+1} = y), stage / final equalities
  (nu = y); two-sided inequalities with equal finite sides, and variables with equal finite
  bounds, also become equality rows, whose multiplier w splits by sign into the upper (w > 0)
  and lower (w < 0) multiplier -- an interior-point backend has no strictly feasible interior
  for a "<= and >=" pair;
* general inequalities h_lower <= G y <= h_upper: one row G y <= h_upper per finite upper side
  (multiplier -> y_upper) and one row -G y <= -h_lower per finite lower side (-> y_lower);
  infinite sides produce no row;
* dense-only backends (quadprog, qpsolvers' ``dense_solvers`` that are not in its
  ``sparse_solvers``) get the matrices as dense arrays (stage QPs of a few thousand variables
  at most are sensible for them);
* variable bounds: passed as qpsolvers' lb/ub to backends that accept +-inf there (OSQP,
  PIQP), whose box multiplier z_box (< 0 at an active lower bound) splits by sign into
  zx/zu lower and upper; for every other backend the finite bounds become rows of G (with
  +-I) so that no infinite number ever reaches the backend.

qpsolvers' Lagrangian is 1/2 y^T P y + q.y + y_eq.(A y - b) + z.(G y - h) + z_box.y, so with the
rows above all signs follow directly; :func:`olado.qp.stageqp.qp_kkt_residuals` checks them.

The backend status is mapped to :class:`olado.result.Status` (solved -> SUCCESS, solved
inaccurate / almost solved -> ACCEPTABLE, iteration limit -> MAX_ITERATIONS, time limit ->
MAX_TIME, primal infeasible -> INFEASIBLE, dual infeasible -> UNBOUNDED, numerical error ->
NUMERICAL_ERROR, anything else -> FAILED); the message names the backend and its own status.
The iteration count is the backend's own (OSQP's ``info.iter``; Clarabel's ``iterations``, for
which Clarabel is called directly with qpsolvers' cones -- qpsolvers' Solution drops it), so the
SQP's cumulative QP iterations and ``olado bench``'s ``qp_iterations`` count external QPs too.
Non-convergence is a status, never an exception; a missing backend is a
:class:`olado.errors.SolverNotAvailableError`.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
import warnings

import numpy as np
import scipy.sparse as sp

from ..errors import SolverNotAvailableError
from .stageqp import QPResult, StageQP, qp_kkt_residuals
from ..result import Status
from ..options import make_options, option

__all__ = ["ExternalQP", "ExternalQPOptions", "available_qp_backends"]

INSTALL_HINT = "pip install qpsolvers osqp clarabel (dependencies of olado)"

# backends whose qpsolvers interface accepts +-inf in lb/ub (others get finite bounds as rows)
_NATIVE_INF_BOX = frozenset({"osqp", "piqp"})
# backends whose qpsolvers interface uses a primal warm start (``initvals``)
_WARM_START = frozenset({"osqp", "proxqp", "qpalm", "qpoases", "cvxopt", "scs"})


def available_qp_backends() -> list[str]:
    """Names of the qpsolvers backends installed here (empty if qpsolvers itself is missing)."""
    try:
        import qpsolvers
    except ImportError:
        return []
    return sorted(qpsolvers.available_solvers)


@dataclasses.dataclass
class ExternalQPOptions:
    """Options of :class:`ExternalQP`. Each tolerance is passed only to the backends that know it."""

    backend: str = option("osqp", "qpsolvers backend: osqp, clarabel, piqp, proxqp, ... (see available_qp_backends())")
    max_iter: int = option(0, "iteration limit (OSQP, Clarabel, PIQP, ProxQP, QPALM); 0 keeps the backend's "
                              "own default", min=0)
    max_time: float = option(math.inf, "wall-time limit of one QP solve in seconds (OSQP, Clarabel)",
                             min=0.0, min_exclusive=True)
    eps_abs: float = option(1e-7, "absolute tolerance (OSQP, PIQP, ProxQP)", min=0.0, min_exclusive=True)
    eps_rel: float = option(1e-7, "relative tolerance (OSQP, PIQP, ProxQP)", min=0.0)
    polish: bool = option(True, "OSQP: polish the ADMM solution by an active-set solve (accurate multipliers)")
    tol_gap_abs: float = option(1e-8, "Clarabel: absolute duality-gap tolerance", min=0.0, min_exclusive=True)
    tol_gap_rel: float = option(1e-8, "Clarabel: relative duality-gap tolerance", min=0.0, min_exclusive=True)
    tol_feas: float = option(1e-8, "Clarabel: primal/dual feasibility tolerance", min=0.0, min_exclusive=True)
    warm_start: bool = option(True, "pass the primal of a warm-start QPResult to backends that use one "
                                    "(OSQP, ProxQP, QPALM ...; Clarabel and PIQP ignore it)")
    verbose: bool = option(False, "print the backend's own output")
    convexify: str = option("none", "'augmented': a QP whose Hessian P is not positive definite is passed with "
                            "P + rho A_eq^T A_eq (and q - rho A_eq^T b_eq), the smallest rho of a tenfold ladder that "
                            "makes it positive semidefinite -- the same solution and multipliers, since the added "
                            "term vanishes where A_eq y = b_eq (Debreu's lemma: such a rho exists if P is positive "
                            "definite on the null space of A_eq); a QP for which none does is reported as a failed "
                            "(nonconvex) QP. 'none': P as it is", choices=("none", "augmented"))
    backend_options: dict = option({}, "further keyword arguments passed unchanged to the backend")


def _backend_kwargs(backend: str, o: ExternalQPOptions) -> dict:
    """The options of ``o`` under the names ``backend`` understands, plus ``backend_options``."""
    kw: dict = {}
    if backend == "osqp":
        kw.update(eps_abs=o.eps_abs, eps_rel=o.eps_rel)
        polish_key = _osqp_polish_key()
        kw[polish_key] = bool(o.polish)
        if polish_key == "polishing":
            kw["raise_error"] = False     # OSQP 1.x: a status, not an exception (and no warning about it)
        if math.isfinite(o.max_time):
            kw["time_limit"] = float(o.max_time)
    elif backend == "clarabel":
        kw.update(tol_gap_abs=o.tol_gap_abs, tol_gap_rel=o.tol_gap_rel, tol_feas=o.tol_feas)
        if math.isfinite(o.max_time):
            kw["time_limit"] = float(o.max_time)
    elif backend in ("piqp", "proxqp"):
        kw.update(eps_abs=o.eps_abs, eps_rel=o.eps_rel)
    if o.max_iter and backend in ("osqp", "clarabel", "piqp", "proxqp", "qpalm"):
        kw["max_iter"] = int(o.max_iter)
    kw.update(o.backend_options)
    return kw


def _osqp_polish_key() -> str:
    """OSQP 1.x renamed the setting ``polish`` to ``polishing``."""
    try:
        import osqp

        major = int(str(getattr(osqp, "__version__", "1")).split(".")[0])
    except (ImportError, ValueError):
        major = 1
    return "polishing" if major >= 1 else "polish"


# ============================================================================= status mapping
def _status_text(sol) -> str | None:
    """The backend's own status string, from ``solution.extras`` (``status`` or ``info.status``)."""
    ex = getattr(sol, "extras", None) or {}
    st = ex.get("status")
    info = ex.get("info")
    if st is None and info is not None:
        st = info.get("status") if isinstance(info, dict) else getattr(info, "status", None)
    if st is None:
        return None
    text = str(st)
    return text.split(".")[-1] if text.startswith(("Status.", "SolverStatus.", "QPSolverOutput.")) else text


def _iterations(sol) -> int:
    ex = getattr(sol, "extras", None) or {}
    for key in ("iter", "iterations", "iter_count"):
        if key in ex:
            try:
                return int(ex[key])
            except (TypeError, ValueError):
                pass
    info = ex.get("info")
    if info is not None:
        for key in ("iter", "iterations", "iter_count"):
            val = info.get(key) if isinstance(info, dict) else getattr(info, key, None)
            if val is not None:
                try:
                    return int(val)
                except (TypeError, ValueError):
                    pass
    return 0


def map_backend_status(text: str | None, found: bool | None) -> Status:
    """olado Status of a backend status string (OSQP, Clarabel, PIQP, ProxQP spellings)."""
    if text is None:
        return Status.SUCCESS if found else Status.FAILED
    s = re.sub(r"[^a-z]", "", text.lower())
    for prefix in ("osqp", "piqp", "proxqp", "qpalm"):
        if s.startswith(prefix):
            s = s[len(prefix):]
    if "unsolved" in s or "nonconvex" in s or "noncvx" in s:
        return Status.FAILED
    if "primalinfeasible" in s or s in ("infeasible", "primalinfeas"):
        return Status.INFEASIBLE
    if "dualinfeasible" in s or "unbounded" in s:
        return Status.UNBOUNDED
    if "iter" in s:
        return Status.MAX_ITERATIONS
    if "time" in s:
        return Status.MAX_TIME
    if "numerical" in s:
        return Status.NUMERICAL_ERROR
    if s in ("solved", "optimal", "success"):
        return Status.SUCCESS
    if ("solved" in s or "optimal" in s) and ("inaccurate" in s or "almost" in s or "reduced" in s):
        return Status.ACCEPTABLE
    return Status.FAILED


# ============================================================================= QP conversion
@dataclasses.dataclass
class _Rows:
    """The qpsolvers problem of one StageQP and the row bookkeeping to map multipliers back."""

    problem: object
    n_eq0: int                   # rows of to_sparse()'s A_eq (x_0, dynamics, E, E_N)
    eq_g: np.ndarray             # G rows with equal finite sides, as equality rows
    eq_fix: np.ndarray           # variables with equal finite bounds, as equality rows
    g_up: np.ndarray             # G rows with a finite upper side: G y <= h_upper
    g_lo: np.ndarray             # G rows with a finite lower side: -G y <= -h_lower
    b_up: np.ndarray             # variables with a finite upper bound as rows (non-native box)
    b_lo: np.ndarray             # variables with a finite lower bound as rows (non-native box)
    native_box: bool             # lb/ub passed to the backend
    n_g: int                     # rows of to_sparse()'s G
    rho: float = 0.0             # convexify = "augmented": the rho of P + rho A_eq^T A_eq
    A_eq: object = None          # ... and the rows A_eq y = b_eq it was taken over
    b_eq: object = None


def _positive_semidefinite(M, floor) -> bool:
    """Whether the symmetric sparse M + floor I is positive definite (M positive semidefinite up
    to floor): a banded Cholesky factorization (a stage QP in stage order is banded, bandwidth
    about 2n + m)."""
    import scipy.linalg as sla

    M = sp.csr_matrix(M)
    coo = M.tocoo()
    bw = int(np.max(np.abs(coo.row - coo.col), initial=0))
    nv = M.shape[0]
    ab = np.zeros((bw + 1, nv))
    for k in range(bw + 1):
        ab[bw - k, k:] = M.diagonal(k)
    ab[bw] += floor
    try:
        sla.cholesky_banded(ab, lower=False, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return False
    return True


#: the rho ladder of convexify = "augmented": rho_0 times 10^0..10^_AUGMENT_STEPS
_AUGMENT_STEPS = 12


def augmented_hessian(d):
    """(P, q, rho) with P + rho A^T A positive semidefinite (to 1e-10 max|P_ii|) and q - rho A^T b,
    rho the smallest of the ladder (0 first), for the sparse form ``d`` of a stage QP; None when
    no rho works (P is not positive semidefinite on the null space of the equality rows A y = b)."""
    P, A, b = d["P"], d["A_eq"], d["b_eq"]
    scale = max(float(np.max(np.abs(P.diagonal()), initial=0.0)), 1e-300)
    floor = 1e-10 * scale
    if _positive_semidefinite(P, floor):
        return P, d["q"], 0.0
    AtA = (A.T @ A).tocsc()
    rho0 = scale / max(float(np.max(np.abs(AtA.diagonal()), initial=0.0)), 1e-300)
    for j in range(_AUGMENT_STEPS + 1):
        rho = rho0 * 10.0 ** j
        Pa = (P + rho * AtA).tocsc()
        if _positive_semidefinite(Pa, floor):
            return Pa, d["q"] - rho * (A.T @ b), rho
    return None


def _build_rows(qp: StageQP, backend: str, convexify: str = "none") -> _Rows | None:
    import qpsolvers

    d = qp.to_sparse()
    rho = 0.0
    if convexify == "augmented":
        aug = augmented_hessian(d)
        if aug is None:
            return None
        d["P"], d["q"], rho = aug
    nv = qp.n_vars
    G, hl, hu = d["G"].tocsr(), d["h_lower"], d["h_upper"]
    lb, ub = d["lb"], d["ub"]
    fl, fu = np.isfinite(hl), np.isfinite(hu)
    geq = fl & fu & (hl == hu)
    eq_g = np.flatnonzero(geq)
    g_up = np.flatnonzero(fu & ~geq)
    g_lo = np.flatnonzero(fl & ~geq)
    native = backend in _NATIVE_INF_BOX
    bl, bu = np.isfinite(lb), np.isfinite(ub)
    if native:
        eq_fix = np.zeros(0, dtype=int)
        b_up = b_lo = np.zeros(0, dtype=int)
    else:
        fix = bl & bu & (lb == ub)
        eq_fix = np.flatnonzero(fix)
        b_up = np.flatnonzero(bu & ~fix)
        b_lo = np.flatnonzero(bl & ~fix)
    eye = sp.identity(nv, format="csr")
    A_blocks = [d["A_eq"].tocsr(), G[eq_g], eye[eq_fix]]
    A = sp.vstack(A_blocks, format="csc")
    b = np.concatenate([d["b_eq"], hl[eq_g], lb[eq_fix]])
    G_blocks = [G[g_up], -G[g_lo], eye[b_up], -eye[b_lo]]
    n_ineq = sum(blk.shape[0] for blk in G_blocks)
    if n_ineq:
        Gq = sp.vstack(G_blocks, format="csc")
        h = np.concatenate([hu[g_up], -hl[g_lo], ub[b_up], -lb[b_lo]])
    else:
        Gq, h = None, None
    if native and (bl.any() or bu.any()):
        lbq, ubq = lb.copy(), ub.copy()
    else:
        lbq = ubq = None
    if backend not in qpsolvers.sparse_solvers:
        # dense-only backends (quadprog, ...) refuse sparse matrices ("problem has sparse matrices")
        P, A = d["P"].toarray(), A.toarray()
        Gq = None if Gq is None else Gq.toarray()
    else:
        P = d["P"]
    problem = qpsolvers.Problem(P, d["q"], Gq, h, A, b, lbq, ubq)
    return _Rows(problem, d["A_eq"].shape[0], eq_g, eq_fix, g_up, g_lo, b_up, b_lo,
                 lbq is not None, G.shape[0], rho, d["A_eq"], d["b_eq"])


def _split_signed(w):
    """(lower, upper) nonnegative parts of a signed multiplier w = upper - lower."""
    return np.maximum(-w, 0.0), np.maximum(w, 0.0)


def _map_back(qp: StageQP, rows: _Rows, x, y, z, z_box):
    """QPResult arrays (X, U, lam, nu, zx_l, zx_u, zu_l, zu_u, yc_l, yc_u, yN_l, yN_u)."""
    N, n, m = qp.N, qp.n, qp.m
    nv = qp.n_vars
    ne, neN, nc, ncN = qp.E.shape[1], qp.EN.shape[0], qp.C.shape[1], qp.CN.shape[0]
    y = np.zeros(rows.problem.A.shape[0]) if y is None or len(y) == 0 else np.asarray(y, dtype=float)
    z = np.zeros(0) if z is None else np.asarray(z, dtype=float)
    X, U = qp.unpack(np.asarray(x, dtype=float))
    # equality rows
    y0 = y[: rows.n_eq0]
    lam = np.empty((N + 1, n))
    lam[0] = -y0[:n]
    lam[1:] = y0[n: n + N * n].reshape(N, n)
    nu = np.zeros((N + 1, max(ne, neN)))
    s = n + N * n
    if ne:
        nu[:N, :ne] = y0[s: s + N * ne].reshape(N, ne)
        s += N * ne
    if neN:
        nu[N, :neN] = y0[s: s + neN]
    s = rows.n_eq0
    w_g = y[s: s + len(rows.eq_g)]
    s += len(rows.eq_g)
    w_fix = y[s: s + len(rows.eq_fix)]
    # general inequalities
    gl, gu = np.zeros(rows.n_g), np.zeros(rows.n_g)
    gl[rows.eq_g], gu[rows.eq_g] = _split_signed(w_g)
    s = 0
    gu[rows.g_up] = z[s: s + len(rows.g_up)]; s += len(rows.g_up)
    gl[rows.g_lo] = z[s: s + len(rows.g_lo)]; s += len(rows.g_lo)
    # bounds
    bl, bu = np.zeros(nv), np.zeros(nv)
    bl[rows.eq_fix], bu[rows.eq_fix] = _split_signed(w_fix)
    bu[rows.b_up] = z[s: s + len(rows.b_up)]; s += len(rows.b_up)
    bl[rows.b_lo] = z[s: s + len(rows.b_lo)]; s += len(rows.b_lo)
    if rows.native_box and z_box is not None and len(z_box):
        zl, zu = _split_signed(np.asarray(z_box, dtype=float))
        bl += zl; bu += zu
    zx_l, zu_l = qp.unpack(bl)
    zx_u, zu_u = qp.unpack(bu)
    yc_l, yc_u = gl[: N * nc].reshape(N, nc), gu[: N * nc].reshape(N, nc)
    yN_l, yN_u = gl[N * nc: N * nc + ncN], gu[N * nc: N * nc + ncN]
    return X, U, lam, nu, zx_l, zx_u, zu_l, zu_u, yc_l, yc_u, yN_l, yN_u


def _backend_duals(qp: StageQP, rows: _Rows, res: QPResult):
    """Inverse of :func:`_map_back`: (y_eq, z, z_box) in the backend's row order from a QPResult
    (for dual warm starts)."""
    N, n = qp.N, qp.n
    ne, neN = qp.E.shape[1], qp.EN.shape[0]
    yc = np.concatenate([(res.yc_upper - res.yc_lower).ravel(), res.yN_upper - res.yN_lower])
    ycl = np.concatenate([res.yc_lower.ravel(), res.yN_lower])
    ycu = np.concatenate([res.yc_upper.ravel(), res.yN_upper])
    zb = qp.pack(res.zx_upper - res.zx_lower, res.zu_upper - res.zu_lower)
    zbl = qp.pack(res.zx_lower, res.zu_lower)
    zbu = qp.pack(res.zx_upper, res.zu_upper)
    y_eq = np.concatenate([-res.lam[0], res.lam[1:].ravel(), res.nu[:N, :ne].ravel(), res.nu[N, :neN],
                           yc[rows.eq_g], zb[rows.eq_fix]])
    z = np.concatenate([ycu[rows.g_up], ycl[rows.g_lo], zbu[rows.b_up], zbl[rows.b_lo]])
    z_box = zb if rows.native_box else np.zeros(0)
    return y_eq, z, z_box


def _solve_osqp(problem, x0, duals, verbose, kwargs):
    """OSQP on the qpsolvers problem, with a primal *and dual* warm start (qpsolvers passes the
    primal only, which does not shorten OSQP's ADMM: its iterate is driven by the duals)."""
    import osqp
    import qpsolvers

    P, q, G, h, A, b, lb, ub = problem.unpack()
    nv = q.shape[0]
    mats, lo, hi = [], [], []
    if G is not None:
        mats.append(sp.csc_matrix(G)); lo.append(np.full(h.shape, -np.inf)); hi.append(h)
    mats.append(sp.csc_matrix(A)); lo.append(b); hi.append(b)
    if lb is not None:
        mats.append(sp.identity(nv, format="csc")); lo.append(lb); hi.append(ub)
    solver = osqp.OSQP()
    kw = dict(kwargs)
    solve_kw = {"raise_error": kw.pop("raise_error")} if "raise_error" in kw else {}
    solver.setup(P=sp.csc_matrix(P), q=q, A=sp.vstack(mats, format="csc"), l=np.concatenate(lo),
                 u=np.concatenate(hi), verbose=verbose, **kw)
    if x0 is not None:
        y0 = None if duals is None else np.concatenate([duals[1], duals[0], duals[2]])
        solver.warm_start(x=x0, y=y0)
    out = solver.solve(**solve_kw)
    sol = qpsolvers.Solution(problem)
    sol.extras = {"info": out.info}
    sol.found = out.info.status_val == osqp.SolverStatus.OSQP_SOLVED
    sol.x = out.x
    mg = 0 if G is None else G.shape[0]
    sol.z, sol.y, sol.z_box = out.y[:mg], out.y[mg: mg + A.shape[0]], out.y[mg + A.shape[0]:]
    return sol


def _solve_clarabel(problem, verbose, kwargs):
    """Clarabel on the qpsolvers problem, called directly with the same cones as qpsolvers' own
    interface (a zero cone for A y = b, a nonnegative cone for G y <= h) but keeping the
    solver's iteration count, which qpsolvers' Solution drops (``extras`` holds only s, status
    and solve time). Variable bounds never reach here: Clarabel gets them as rows of G."""
    import clarabel
    import qpsolvers

    P, q, G, h, A, b, lb, ub = problem.unpack()
    if lb is not None or ub is not None or (A is None and G is None):   # not a stage QP's form
        return qpsolvers.solve_problem(problem, solver="clarabel", verbose=verbose, **kwargs)
    mats, rhs, cones = [], [], []
    if A is not None:
        mats.append(sp.csc_matrix(A)); rhs.append(b); cones.append(clarabel.ZeroConeT(b.shape[0]))
    if G is not None:
        mats.append(sp.csc_matrix(G)); rhs.append(h); cones.append(clarabel.NonnegativeConeT(h.shape[0]))
    settings = clarabel.DefaultSettings()
    settings.verbose = verbose
    for key, value in kwargs.items():
        setattr(settings, key, value)
    try:
        solver = clarabel.DefaultSolver(sp.csc_matrix(P), q, sp.vstack(mats, format="csc"), np.concatenate(rhs),
                                        cones, settings)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:   # noqa: BLE001 - Clarabel's Rust panic (pyo3 PanicException) at set-up
        raise qpsolvers.ProblemError(f"Clarabel failed to build the problem ({type(exc).__name__}: {exc})") from exc
    out = solver.solve()
    sol = qpsolvers.Solution(problem)
    sol.extras = {"status": out.status, "iterations": int(out.iterations), "solve_time": out.solve_time, "s": out.s}
    sol.found = out.status == clarabel.SolverStatus.Solved
    sol.obj = out.obj_val
    sol.x = np.array(out.x)
    z = np.asarray(out.z, dtype=float)
    meq = 0 if A is None else A.shape[0]
    sol.y, sol.z, sol.z_box = z[:meq], z[meq:], np.zeros(0)
    return sol


def _nan_result(qp: StageQP, status, message, backend, time_s, iterations=0) -> QPResult:
    N, n, m = qp.N, qp.n, qp.m
    ne, neN, nc, ncN = qp.E.shape[1], qp.EN.shape[0], qp.C.shape[1], qp.CN.shape[0]
    f = lambda *shape: np.full(shape, np.nan)  # noqa: E731
    return QPResult(status, message, f(N + 1, n), f(N, m), f(N + 1, n), f(N + 1, max(ne, neN)),
                    f(N + 1, n), f(N + 1, n), f(N, m), f(N, m), f(N, nc), f(N, nc), f(ncN), f(ncN),
                    iterations=iterations, time_s=time_s, solver=backend,
                    kkt={k: math.nan for k in ("stationarity", "primal", "complementarity", "dual_sign")})


# ============================================================================= the QP method
class ExternalQP:
    """Solve :class:`StageQP` subproblems with an installed qpsolvers backend.

    ``ExternalQP("clarabel", tol_feas=1e-9)`` or ``ExternalQP(options=ExternalQPOptions(...))``;
    keyword overrides are validated like every olado option (:func:`olado.options.option`).
    """

    Options = ExternalQPOptions

    def __init__(self, backend: str | None = None, options=None, **overrides):
        if backend is not None:
            overrides["backend"] = backend
        self.options = make_options(ExternalQPOptions, options, **overrides)
        self.backend = self.options.backend
        _require_backend(self.backend)
        self.name = self.backend

    def __repr__(self):
        return f"ExternalQP(backend={self.backend!r})"

    def solve(self, qp: StageQP, warm_start: QPResult | None = None, limits=None) -> QPResult:
        """Solve ``qp``; ``warm_start`` (a previous QPResult of the same size) seeds the primal
        iterate of backends that accept one, and for OSQP also the multipliers. Returns a :class:`QPResult` (never raises on
        non-convergence: the backend's failure is the status and message). ``limits``
        (:class:`olado.interrupts.Limits`) is checked before the backend starts: a backend runs
        in compiled code that cannot be stopped midway."""
        import qpsolvers

        if limits is not None:
            limits.check()

        o = self.options
        backend = self.backend
        t0 = time.perf_counter()
        rows = _build_rows(qp, backend, o.convexify)
        if rows is None:
            return _nan_result(qp, Status.NUMERICAL_ERROR, (f"{backend}: not solved, the QP is nonconvex (its Hessian "
                                                            "is not positive definite on the null space of its "
                                                            "equality rows)"), backend, time.perf_counter() - t0)
        initvals = duals = None
        if (warm_start is not None and o.warm_start and backend in _WARM_START
                and warm_start.X.shape == (qp.N + 1, qp.n) and warm_start.U.shape == (qp.N, qp.m)
                and np.all(np.isfinite(warm_start.X)) and np.all(np.isfinite(warm_start.U))):
            initvals = qp.pack(warm_start.X, warm_start.U)
            if backend == "osqp":
                try:
                    duals = _backend_duals(qp, rows, warm_start)
                    if not all(np.all(np.isfinite(v)) for v in duals):
                        duals = None
                except (ValueError, IndexError):   # multipliers of another QP shape: primal only
                    duals = None
        kwargs = _backend_kwargs(backend, o)
        try:
            with warnings.catch_warnings():
                # the backend's status is reported in the result, not as a warning
                warnings.filterwarnings("ignore", module=r"qpsolvers(\..*)?")
                warnings.simplefilter("ignore", RuntimeWarning)
                if backend == "osqp" and _osqp_polish_key() == "polishing":
                    sol = _solve_osqp(rows.problem, initvals, duals, bool(o.verbose), kwargs)
                elif backend == "clarabel":
                    sol = _solve_clarabel(rows.problem, bool(o.verbose), kwargs)
                else:
                    sol = qpsolvers.solve_problem(rows.problem, solver=backend, initvals=initvals,
                                                  verbose=bool(o.verbose), **kwargs)
        except (qpsolvers.QPError, ValueError, ArithmeticError) as exc:
            return _nan_result(qp, Status.FAILED, f"{backend} raised {type(exc).__name__}: {exc}", backend,
                               time.perf_counter() - t0)
        except Exception as exc:   # noqa: BLE001 - a backend's own exception type (OSQPException ...)
            if type(exc).__module__.split(".")[0] not in (backend, "qpsolvers"):
                raise
            # OSQP raises at setup when its KKT factorization fails: "the problem seems to be non-convex"
            return _nan_result(qp, Status.NUMERICAL_ERROR, f"{backend} raised {type(exc).__name__} {exc} (a "
                               "failed factorization: the QP is nonconvex or singular)", backend,
                               time.perf_counter() - t0)
        elapsed = time.perf_counter() - t0
        raw = _status_text(sol)
        status = map_backend_status(raw, sol.found)
        iters = _iterations(sol)
        message = f"{backend}: status '{raw if raw is not None else ('found' if sol.found else 'not found')}'"
        if backend == "osqp":
            info = (sol.extras or {}).get("info")
            pol = getattr(info, "status_polish", 0)
            if o.polish and pol not in (None, 1):
                message += " (polishing " + ("unsuccessful" if pol == -1 else "not performed") + ")"
        x = sol.x
        if x is None or np.shape(x) != (qp.n_vars,) or not np.all(np.isfinite(x)):
            res = _nan_result(qp, status, message, backend, elapsed, iters)
            if status.success:   # a "solved" status without a usable primal is not a success
                res.status = Status.NUMERICAL_ERROR
                res.message = message + "; no finite primal solution returned"
            return res
        y_eq = sol.y
        if rows.rho and y_eq is not None and len(y_eq):
            # multipliers of the QP itself: lambda + rho (A_eq y - b_eq) (the augmented term's gradient)
            y_eq = np.array(y_eq, dtype=float)
            y_eq[: rows.n_eq0] += rows.rho * (rows.A_eq @ x - rows.b_eq)
        arrays = _map_back(qp, rows, x, y_eq, sol.z, sol.z_box)
        res = QPResult(status, message, *arrays, iterations=iters, time_s=elapsed, solver=backend)
        res.objective = qp.objective(res.X, res.U)
        res.kkt = qp_kkt_residuals(qp, res)
        return res


def _require_backend(backend: str) -> None:
    """Raise :class:`SolverNotAvailableError` unless ``backend`` is an installed qpsolvers backend."""
    try:
        import qpsolvers
    except ImportError as exc:
        raise SolverNotAvailableError(
            f"external QP backend {backend!r} needs the qpsolvers package, which is not installed; "
            f"install it with: {INSTALL_HINT}") from exc
    installed = sorted(qpsolvers.available_solvers)
    if backend not in installed:
        raise SolverNotAvailableError(
            f"QP backend {backend!r} is not installed (installed qpsolvers backends: "
            f"{', '.join(installed) if installed else 'none'}); OSQP and Clarabel: {INSTALL_HINT}; "
            f"another backend: its own package (e.g. pip install {backend})")
