"""Certified success: olado's own check of the first-order optimality conditions at a point that
a solver reports as optimal, independent of the subproblem that produced the point
(docs/certificate.md).

The conditions are those of WORHP's optimality test (seed 000 sec. IV.II): the KKT conditions [1]
checked as [3] (stationarity of the Lagrangian), [4]-[5] (signs of the multipliers of active
inequalities, vanishing multipliers of inactive ones -- here as complementarity |mu_j slack_j|)
and [6] (feasibility), in the scaled form [7]: residuals in relative units of the objective, so
that the test reads "the first-order change of J that the residual allows is small against
max(1, |J|)" instead of depending on the scale of J:

    stationarity     max_i |grad_i L(y, lam, z)| max(1, |y_i|) / max(1, |J|)
    complementarity  max_j |mu_j slack_j| / max(1, |J|)          (rows g >= 0 and variable bounds)
    feasibility      max-norm violation of h = f - x^+, g, g^N and the bounds (absolute, [6])

with L = J + lam . c - z_L . (y - lb) - z_U . (ub - y) in the sign convention of
:mod:`olado.solvers.common` (eq. (28)). WORHP's [7] divides by the step |d| of the current
iteration; a returned point has no step, and max(1, |y_i|) -- the step that would move the
variable by its own size -- takes its place.

The check, in stages, each cheap against a solve (all O(N), stage by stage):

1. values and first derivatives at (X, U) from the problem's own functions (analytic where the
   problem provides them, finite differences otherwise) -- nothing is taken from the solver;
2. the solver's multipliers of the constraints c = (h, g, g^N), projected on their sign
   constraints (inequality rows g >= 0 take multipliers <= 0); the bound multipliers are chosen
   per variable, in closed form: a residual r_i that a bound could cancel takes
   z_i = |r_i| w_i / (w_i + slack_i), which minimises max(|r_i - z_i| w_i, z_i slack_i) (w_i =
   max(1, |y_i|)): the best trade between stationarity and complementarity of that variable;
3. only when 2 fails: olado's least-squares multipliers with sign constraints. With the bound
   multipliers eliminated per variable as in 2 (in the least-squares sense: min over z >= 0 of
   w^2 (r - z)^2 + s^2 z^2), they minimise the convex, piecewise quadratic

       Phi(lam) = sum_i D_i(r_i) r_i^2,   r = grad J + Jc' lam,
       D_i = w_i^2 s_i^2 / (w_i^2 + s_i^2) on the side where a bound at slack s_i can cancel r_i,
             w_i^2 elsewhere,

   over the multipliers of the dynamics and the equality rows (free) and of the rows g >= 0
   (<= 0). A stage row g_j >= 0 pays its complementarity in the same sum: Phi + sum_j (g_j mu_j)^2,
   i.e. a row at slack g_j is a soft equality C_j d = t_j with a slack control weighted 1/g_j^2
   (a row whose multiplier comes out positive is released: mu_j = 0); a final row is an equality
   where its slack is ~0 (active set, released likewise). Semismooth Newton: with
   the weights D of the current residual frozen, the minimiser is the multiplier vector of the
   equality-constrained stage QP  min 1/2 d' D^-1 d + grad J . d  s.t. the linearized dynamics and
   rows (its KKT conditions give d = -D r and J D r = 0, the normal equations), solved in O(N) by
   olado's interior-point QP with the Riccati back-end (where the Riccati recursion's projection
   of the terminal rows breaks down, by the sparse LU of the whole KKT matrix); the weights are
   then recomputed, until
   they repeat (at most LSQ_STEPS) or the figures of step 2 meet the tolerance. At the fixed
   point the gradient of Phi vanishes: the multipliers are its exact minimiser. It starts from
   the solver's multipliers when there are some, else from 0; the step with the best figures
   is kept;
4. a spot check of the derivatives the figures rest on: along ``CHECK_DIRECTIONS`` random
   directions v the five-point central difference of every stage function (stage costs, final
   cost, dynamics, constraints, per stage) is compared with the derivative the problem supplies
   (a second difference scheme, independent of the one olado's finite differences use); a
   difference beyond CHECK_RTOL times the terms' size plus ten times the scheme's own error
   estimate (the difference of its two central differences) means a wrong derivative.

:func:`certify` returns the :class:`olado.result.Certificate`; :func:`certify_result` applies it
to a Result (``Solver.solve`` does this for every solver family: a SUCCESS whose certificate holds
only at the acceptable tolerances becomes ACCEPTABLE, one that fails becomes UNCERTIFIED with a
sentence naming the residual that fails and its value). The SQP calls :func:`certify` before it
stops and iterates on when the certificate fails (olado.solvers.sqp.phases).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import NamedTuple

import numpy as np

from ..errors import OladoError
from ..result import Certificate, Status
from .common import stage_gradient_terms
from .diagnosis import largest_violation_of

#: relative step of the derivative spot check (a variable moves by at most 2 CHECK_STEP max(1, |y_i|))
CHECK_STEP = 1e-3
#: random directions of the spot check
CHECK_DIRECTIONS = 2
#: relative tolerance of the spot check, on top of the difference scheme's own error estimate
CHECK_RTOL = 1e-5
#: the spot check's directions are drawn from this seed (a certificate is reproducible)
CHECK_SEED = 20260418
#: tolerance of the weighted least-squares QPs of step 3 (relative, olado's interior-point QP)
LSQ_TOL = 1e-12
#: smallest weight of a residual in the least squares of step 3, relative to max(1, |y_i|)^2
LSQ_FLOOR = 1e-12
#: semismooth Newton steps of step 3 at most (the weights usually repeat after 2-12)
LSQ_STEPS = 30
#: KKT back-ends of the weighted least-squares QPs of step 3, in the order tried
LSQ_KKT = ("riccati", "superlu-full")

_EPS = np.finfo(float).eps


@dataclasses.dataclass(frozen=True)
class CertificateSettings:
    """Tolerances of a certificate: the scaled stationarity and complementarity must be <= tol
    (acceptable: <= acceptable_tol), the violation <= constr_viol_tol (acceptable_constr_viol_tol)."""

    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    constr_viol_tol: float = 1e-8
    acceptable_constr_viol_tol: float = 1e-6
    gradient_check: bool = True

    @classmethod
    def from_options(cls, o):
        """From a solver's options (olado.solvers.base.SolverOptions): certificate_tol or the
        solver's tol when larger, constr_viol_tol, and the acceptable levels."""
        tol = max(float(o.certificate_tol), float(getattr(o, "tol", 0.0)))
        viol = float(o.constr_viol_tol)
        return cls(tol=tol, acceptable_tol=max(float(o.certificate_acceptable_tol), tol), constr_viol_tol=viol,
                   acceptable_constr_viol_tol=max(float(o.certificate_acceptable_constr_viol_tol), viol))


# ---------------------------------------------------------------------------- the point
class StagePoint:
    """Values and first derivatives of the DOCP at (X, U), from the problem's own functions."""

    def __init__(self, p, X, U):
        self.X, self.U = X, U
        # two calls (olado.problems.docp.DOCP.eval_values, eval_first_derivatives): the stage and
        # final costs, dynamics, constraints, then their derivatives, in that order
        self.J, self.f, self.g, self.gN = p.eval_values(X, U)
        self.h = self.f - X[1:]
        self.lx, self.lu, self.lN, self.A, self.B, self.Cx, self.Cu, self.CN = p.eval_first_derivatives(X, U)


class StageBounds(NamedTuple):
    """Variable bounds of the NLP view per stage (x^0 fixed at x0)."""

    xl: np.ndarray
    xu: np.ndarray
    ul: np.ndarray
    uu: np.ndarray

    @classmethod
    def of(cls, p):
        """The bounds of ``p`` as C-contiguous float arrays (the compiled passes' layout)."""
        xl, xu = np.array(p.x_lower, dtype=float), np.array(p.x_upper, dtype=float)
        xl[0] = p.x0
        xu[0] = p.x0
        return cls(xl, xu, np.ascontiguousarray(p.u_lower, dtype=float), np.ascontiguousarray(p.u_upper, dtype=float))


class KKTFigures(NamedTuple):
    """Residuals at a point with one set of multipliers (unscaled max-norms, scaled values and
    where the largest scaled ones occur)."""

    kind: str
    stationarity: float
    complementarity: float
    stationarity_scaled: float
    complementarity_scaled: float
    stationarity_at: str
    complementarity_at: str
    residual_at: float          # the Lagrangian gradient entry at stationarity_at

    def error(self):
        return max(self.stationarity_scaled, self.complementarity_scaled)


# ---------------------------------------------------------------------------- feasibility [6]
def _violation(p, pt):
    """Max-norm violation and a function of no argument that says where it occurs (a phrase,
    written only for a reason), from the violations every olado diagnosis shares
    (:func:`olado.solvers.diagnosis.violation_arrays`; the largest only:
    :func:`olado.solvers.diagnosis.largest_violation_of`)."""
    best, where = largest_violation_of(p, pt)
    return best, (lambda: "") if where is None else where.where


# ---------------------------------------------------------------------------- stationarity [3]-[5]
def _largest(arrays, best=(-1.0, "", 0, 0)):
    """The largest entry over named (K, k) arrays after ``best``: (value, name, K index, k index)
    -- the first array whose maximum exceeds the best so far (an array with a NaN is skipped),
    its first largest entry."""
    for name, a in arrays:
        if a.size and float(a.max()) > best[0]:
            k, i = divmod(int(a.argmax()), a.shape[1])
            best = (float(a[k, i]), name, k, i)
    return best


def _figures(p, pt, bounds, W, S, lam, Lg, LgN, kind):
    """The residuals with the multipliers (lam, Lg, LgN), inequality multipliers projected on
    their signs, bound multipliers chosen per variable (module docstring step 2), the bound
    choice and its largest figures in one compiled pass (certificate_kernels.bound_figures)."""
    Lg = np.array(Lg, dtype=float)
    LgN = np.array(LgN, dtype=float)
    if p.r:
        ineq = ~p.stage_equality_mask
        Lg[:, ineq] = np.minimum(Lg[:, ineq], 0.0)
    if p.rN:
        ineqN = ~p.final_equality_mask
        LgN[ineqN] = np.minimum(LgN[ineqN], 0.0)
    rx, ru = stage_gradient_terms(p, pt, lam, Lg, LgN)
    res_x, res_u = np.empty(7), np.empty(7)
    kernels, S = _kernels(), float(S)
    kernels.bound_figures(np.ascontiguousarray(rx), pt.X, bounds.xl, bounds.xu, W[0], S, 1, res_x)   # x^0 fixed
    kernels.bound_figures(np.ascontiguousarray(ru), pt.U, bounds.ul, bounds.uu, W[1], S, 0, res_u)
    # per array [max stationarity, max scaled stationarity, its stage, component, max complementarity,
    # its stage, component]: the largest as _largest finds them, x before u
    stat = max(float(res_x[0]), float(res_u[0]))
    best, comp_best = (-1.0, "", 0, 0), (-1.0, "", 0, 0)
    for (name, cname), res in ((("x", "x bounds"), res_x), (("u", "u bounds"), res_u)):
        if res[1] > best[0]:
            best = (float(res[1]), name, int(res[2]), int(res[3]))
        if res[4] > comp_best[0]:
            comp_best = (float(res[4]), cname, int(res[5]), int(res[6]))
    stat_scaled, name, k, i = best
    residual = float((rx if name == "x" else ru)[k, i])
    best = comp_best
    comp_rows = []
    if p.r and ineq.any():
        rows = np.zeros_like(pt.g)
        rows[:, ineq] = np.abs(Lg[:, ineq] * pt.g[:, ineq])
        comp_rows.append(("stage constraint", rows))
    if p.rN and ineqN.any():
        rows = np.zeros((1, p.rN))
        rows[0, ineqN] = np.abs(LgN[ineqN] * pt.gN[ineqN])
        comp_rows.append(("final constraint", rows))
    comp, cname, ck, ci = _largest(comp_rows, best)
    comp_at = f"{cname} {ci}" if cname == "final constraint" else f"{cname}, stage {ck}, component {ci}"
    return KKTFigures(kind, stat, comp, stat_scaled, comp / S, f"{name}^{k}[{i}]", comp_at, residual)


def _kernels():
    """olado.solvers.certificate_kernels (numba), loaded with the first certificate."""
    from . import certificate_kernels   # noqa: PLC0415 - numba is loaded on the first solve, not with olado

    return certificate_kernels


def kkt_figures(problem, X, U, multipliers, kind="solver") -> KKTFigures:
    """The residuals of step 2 (module docstring) at (X, U) with a Result's multipliers dict."""
    X, U = np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(U, dtype=float)
    pt = StagePoint(problem, X, U)
    given = _solver_multipliers(problem, multipliers)
    if given is None:
        raise OladoError("kkt_figures needs the multipliers 'dynamics' (N, n) and, if the problem has them, "
                         "'stage_constraints' (N, r) and 'final_constraints' (rN,)")
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    return _figures(problem, pt, StageBounds.of(problem), W, max(1.0, abs(pt.J)), *given, kind)


def _solver_multipliers(p, multipliers):
    """(lam, Lg, LgN) from a Result's multipliers dict, or None when they are missing or unusable."""
    if not multipliers:
        return None
    try:
        lam = np.asarray(multipliers.get("dynamics"), dtype=float).reshape(p.N, p.n)
        Lg = np.asarray(multipliers.get("stage_constraints", np.zeros((p.N, p.r))), dtype=float).reshape(p.N, p.r)
        LgN = np.asarray(multipliers.get("final_constraints", np.zeros(p.rN)), dtype=float).reshape(p.rN)
    except (TypeError, ValueError):
        return None
    if not (np.isfinite(lam).all() and np.isfinite(Lg).all() and np.isfinite(LgN).all()):
        return None
    return lam, Lg, LgN


# ---------------------------------------------------------------------------- least squares (step 3)
def _diagonal(values):
    """Stacked diagonal matrices (K, k, k) with ``values`` (K, k) on the diagonals."""
    K, k = values.shape
    D = np.zeros((K, k, k))
    D[:, np.arange(k), np.arange(k)] = values
    return D


def _lsq_weights(r, y, lo, hi, w):
    """The weights D_i of Phi (module docstring, step 3) at the residual r: w^2 s^2 / (w^2 + s^2)
    where a bound at slack s can cancel r, w^2 elsewhere, at least LSQ_FLOOR w^2."""
    with np.errstate(invalid="ignore", over="ignore"):
        slack = np.maximum(np.where(r > 0, y - lo, hi - y), 0.0)
        bounded = np.isfinite(slack)
        s2 = np.where(bounded, slack, 0.0) ** 2
        D = np.where(bounded, w ** 2 * s2 / (w ** 2 + s2), w ** 2)
    return np.maximum(D, LSQ_FLOOR * w ** 2)


def weighted_qp(p, pt, Dx, Du, active, activeN, soft=None):
    """The equality-constrained stage QP  min 1/2 d' D^-1 d + grad J . d  s.t. the linearized
    dynamics, the equality rows and the rows g >= 0 flagged active (as equalities), whose
    multipliers minimise |D^(1/2) (grad J + Jc' lam)|_2 (module docstring, step 3).

    With ``soft`` (N, rows g >= 0), the stage rows g >= 0 are instead soft equalities
    C d - t = 0 with a slack control t per row weighted 1/2 soft t^2: their multipliers mu then
    also pay |mu g| in the least squares when soft = 1/g^2, and are held at 0 where soft = 0
    (``active`` is ignored). Every stage row's multiplier is then nu[:N, :r] in the rows' order."""
    from ..qp.stageqp import StageQP

    N, n = p.N, p.n
    eq, eqN = p.stage_equality_mask, p.final_equality_mask
    ineq, ineqN = ~eq, ~eqN
    R, B, r = _diagonal(1.0 / Du), pt.B, pt.lu
    kw = {}
    if p.r and ineq.any() and soft is not None:
        ni = int(ineq.sum())
        T = np.zeros((N, p.r, ni))
        T[:, np.flatnonzero(ineq), np.arange(ni)] = -1.0
        R = _block_diagonal(R, _diagonal(soft))
        B = np.concatenate([B, np.zeros((N, n, ni))], axis=2)
        r = np.hstack([r, np.zeros((N, ni))])
        kw.update(E=pt.Cx, F=np.concatenate([pt.Cu, T], axis=2), e=np.zeros((N, p.r)))
    else:
        if p.r and eq.any():
            kw.update(E=pt.Cx[:, eq, :], F=pt.Cu[:, eq, :], e=np.zeros((N, int(eq.sum()))))
        if p.r and ineq.any():
            free = np.where(active, 0.0, np.inf)
            kw.update(C=np.concatenate([pt.Cx[:, ineq, :], pt.Cu[:, ineq, :]], axis=2), c_lower=-free,
                      c_upper=free)
    if p.rN and eqN.any():
        kw.update(EN=pt.CN[eqN], eN=np.zeros(int(eqN.sum())))
    if p.rN and ineqN.any():
        free = np.where(activeN, 0.0, np.inf)
        kw.update(CN=pt.CN[ineqN], cN_lower=-free, cN_upper=free)
    Dx = Dx.copy()
    Dx[0] = 1.0                                 # x^0 is fixed by the x0 row
    return StageQP(Q=_diagonal(1.0 / Dx), R=R, q=np.vstack([pt.lx, pt.lN[None, :]]), r=r,
                   A=pt.A, B=B, c=np.zeros((N, n)), x0=np.zeros(n), **kw)


def _block_diagonal(P, Q):
    """Stacked block-diagonal matrices diag(P_k, Q_k) from (K, a, a) and (K, b, b)."""
    K, a, _ = P.shape
    b = Q.shape[1]
    out = np.zeros((K, a + b, a + b))
    out[:, :a, :a] = P
    out[:, a:, a:] = Q
    return out


def _row_weights(g, released):
    """Weights soft = 1/g^2 of the slacks of the rows g >= 0 in the least squares (module
    docstring, step 3; at least 1/LSQ_FLOOR), 0 where the row's multiplier is released."""
    with np.errstate(divide="ignore"):
        soft = 1.0 / np.maximum(g ** 2, LSQ_FLOOR)
    return np.where(released, 0.0, soft)


def _solve_weighted(qp):
    """Solve a weighted least-squares QP by olado's interior-point QP with the Riccati back-end,
    or, when that fails (a rank-deficient projection of the terminal rows, say), with the sparse
    LU of the whole KKT matrix. Returns the QP result or a sentence saying why neither solved it."""
    from ..qp import make_qp_solver

    why = ""
    for kkt in LSQ_KKT:
        try:
            res = make_qp_solver("mehrotra", kkt=kkt, tol=LSQ_TOL, max_iter=50).solve(qp)
        except (OladoError, ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
            why = str(exc)
            continue
        if res.success:
            return res
        why = f"weighted QP: {res.message}"
    return f"the least-squares multipliers could not be computed ({why})"


def least_squares_multipliers(p, pt, bounds, W, start=None, target=0.0):
    """olado's sign-constrained least-squares multipliers (module docstring, step 3), from the
    multipliers ``start`` (lam, Lg, LgN) or zero: semismooth Newton steps on Phi, each one
    weighted least-squares problem (:func:`weighted_qp`, O(N)), until the weights repeat, or the
    step's figures (:func:`_figures`) meet ``target``. Returns the multipliers of the step with
    the best figures (lam, Lg, LgN), or a sentence saying why they could not be computed."""
    ineq, ineqN = ~p.stage_equality_mask, ~p.final_equality_mask
    if start is None:
        start = (np.zeros((p.N, p.n)), np.zeros((p.N, p.r)), np.zeros(p.rN))
    lam, Lg, LgN = (np.array(a, dtype=float) for a in start)
    # stage rows g >= 0 are soft (weighted by their slack), released once their least-squares
    # multiplier comes out > 0; final rows start active where their multiplier is negative or
    # their slack ~0
    released = np.zeros((p.N, int(ineq.sum())), dtype=bool)
    activeN = (LgN[ineqN] < 0) | (pt.gN[ineqN] <= LSQ_FLOOR ** 0.5)
    wx, wu = W
    S = max(1.0, abs(pt.J))
    seen, best = [], (np.inf, None)
    for _ in range(LSQ_STEPS):
        rx, ru = stage_gradient_terms(p, pt, lam, Lg, LgN)
        Dx = _lsq_weights(rx, pt.X, bounds.xl, bounds.xu, wx)
        Du = _lsq_weights(ru, pt.U, bounds.ul, bounds.uu, wu)
        key = (Dx.tobytes(), Du.tobytes(), released.tobytes(), activeN.tobytes())
        if key in seen:
            break
        seen.append(key)
        soft = _row_weights(pt.g[:, ineq], released) if p.r else None
        res = _solve_weighted(weighted_qp(p, pt, Dx, Du, None, activeN, soft=soft))
        if isinstance(res, str):
            return res
        lam = res.lam[1:].copy()
        if p.r:
            Lg = res.nu[:p.N, :p.r].copy()
            released |= Lg[:, ineq] > 0         # a row whose multiplier has the wrong sign is released
            Lg[:, ineq] = np.minimum(Lg[:, ineq], 0.0)
        if p.rN:
            LgN = np.zeros(p.rN)
            LgN[~ineqN] = res.nu[p.N, :int((~ineqN).sum())]
            LgN[ineqN] = res.yN_upper - res.yN_lower
            activeN &= ~(LgN[ineqN] > 0)
            LgN[ineqN] = np.minimum(LgN[ineqN], 0.0)
        err = _figures(p, pt, bounds, W, S, lam, Lg, LgN, "least-squares").error()
        if err < best[0]:
            best = (err, (lam, Lg, LgN))
        if err <= target:
            break
    return best[1] if best[1] is not None else (lam, Lg, LgN)


# ---------------------------------------------------------------------------- derivative spot check
class _Check(NamedTuple):
    """Outcome of the spot check: the largest relative error, whether a derivative is wrong, and a
    sentence (the failing derivative, or why the check was skipped)."""

    worst: float | None
    failed: bool
    note: str


def _values(p, X, U):
    """The stage functions at (X, U): stage costs (N,), final cost (1,), dynamics (N, n), stage
    constraints (N, r), final constraints (rN,)."""
    return {"stage_cost": p.eval_stage_costs(X, U), "final_cost": np.array([p.eval_final_cost(X[-1])]),
            "dynamics": p.eval_dynamics(X, U), "stage_constraints": p.eval_stage_constraints(X, U),
            "final_constraints": p.eval_final_constraints(X[-1])}


#: the shifts s of the five-point scheme: the spot check evaluates at y + s h v
_SHIFTS = (1, -1, 2, -2)
_STEPS = np.array(_SHIFTS, dtype=float)
#: the functions the spot check differentiates, in the order of its flat vectors
_NAMES = ("stage_cost", "final_cost", "dynamics", "stage_constraints", "final_constraints")


def _shapes(p):
    """The shapes of the values of :func:`_values`, per function."""
    return {"stage_cost": (p.N,), "final_cost": (1,), "dynamics": (p.N, p.n), "stage_constraints": (p.N, p.r),
            "final_constraints": (p.rN,)}


def _shifted_values(p, pt, directions, h):
    """:func:`_values` at every point y + s h v (v in ``directions``, s in _SHIFTS) as one array
    (directions, shifts, L): each point's values of the functions _NAMES flattened and
    concatenated. The stage functions are separable per stage, so each is called once on all the
    points' stages stacked (stage indices repeated), as olado's finite differences call them
    (:meth:`olado.problems.docp.DOCP._fd_stage_jacobian`); the final ones once per point. The
    counters advance as :func:`_values` point by point would advance them. A stage function that
    fails raises here: the caller then evaluates point by point (:func:`_pointwise_values`), whose
    message names the stage."""
    return _stacked_shifted_values(p, pt, np.array([Vx for Vx, _ in directions]),
                                   np.array([Vu for _, Vu in directions]), h)


def _stacked_shifted_values(p, pt, Vx, Vu, h, points=None):
    """:func:`_shifted_values` of the directions stacked (Vx (D, N+1, n), Vu (D, N, m)); ``points``:
    the shifted points (Xs, Us, ends) of :func:`_spot_points` when they are at hand."""
    P, N, n, r = Vx.shape[0] * len(_SHIFTS), p.N, p.n, p.r
    if points is None:
        # the points y + s h v, directions by shifts (D, S, ...): elementwise as (s h) v + y point by point
        steps = (_STEPS * h)[None, :, None, None]
        Xp = pt.X + steps * Vx[:, None]
        Up = pt.U + steps * Vu[:, None]
        points = Xp[:, :, :-1].reshape(P * N, n), Up.reshape(P * N, p.m), Xp[:, :, -1].reshape(P, n)
    Xs, Us, ends = points
    cost, dyn, g, final = p._stacked_values(np.tile(p._K, P), Xs, Us, ends)
    p.counters["stage_cost"] += P
    p.counters["dynamics"] += P
    if r:
        p.counters["stage_constraints"] += P
    gN = np.array([p.eval_final_constraints(x) for x in ends]).reshape(P, p.rN) if p.rN else np.zeros((P, 0))
    parts = (cost.reshape(P, N), final.reshape(P, 1), dyn.reshape(P, N * n), g.reshape(P, N * r), gN)
    return np.concatenate(parts, axis=1).reshape(Vx.shape[0], len(_SHIFTS), -1)


def _pointwise_values(p, pt, directions, h):
    """:func:`_shifted_values` point by point (:func:`_values`): an error names the stage."""
    rows = []
    for Vx, Vu in directions:
        for s in _SHIFTS:
            vals = _values(p, pt.X + s * h * Vx, pt.U + s * h * Vu)
            rows.append(np.concatenate([np.ravel(vals[name]) for name in _NAMES]))
    return np.array(rows).reshape(len(directions), len(_SHIFTS), -1)


def _directional(pt, Vx, Vu):
    """The derivatives the problem supplies along the directions v = (Vx (D, N+1, n), Vu (D, N,
    m)), and the sums of the absolute terms (the size against which an error is measured): two
    arrays (D, L) in the layout of :func:`_shifted_values`."""
    D = Vx.shape[0]
    ax, au = np.abs(Vx), np.abs(Vu)
    vx, avx = Vx[:, :-1], ax[:, :-1]
    ein = lambda M, V: np.einsum("kij,dkj->dki", M, V).reshape(D, -1)  # noqa: E731
    an = [(pt.lx * vx).sum(axis=2) + (pt.lu * Vu).sum(axis=2), (Vx[:, -1] @ pt.lN)[:, None],
          ein(pt.A, vx) + ein(pt.B, Vu)]
    size = [(np.abs(pt.lx) * avx).sum(axis=2) + (np.abs(pt.lu) * au).sum(axis=2),
            (ax[:, -1] @ np.abs(pt.lN))[:, None], ein(np.abs(pt.A), avx) + ein(np.abs(pt.B), au)]
    if pt.Cx.shape[1] and pt.Cx.shape[0]:       # the parts of a problem with such constraints
        an.append(ein(pt.Cx, vx) + ein(pt.Cu, Vu))
        size.append(ein(np.abs(pt.Cx), avx) + ein(np.abs(pt.Cu), au))
    if pt.CN.shape[0]:
        an.append(Vx[:, -1] @ pt.CN.T)
        size.append(ax[:, -1] @ np.abs(pt.CN).T)
    return np.concatenate(an, axis=1), np.concatenate(size, axis=1)


_DERIVATIVE_NAMES = {"stage_cost": "stage_cost_gradient", "final_cost": "final_cost_gradient",
                     "dynamics": "dynamics_jacobian", "stage_constraints": "stage_constraints_jacobian",
                     "final_constraints": "final_constraints_jacobian"}


def _direction(rng, pt, bounds, W, h):
    """A random direction, scaled by max(1, |y_i|), zero on x^0 and on components that a step of
    2h would take out of their bounds."""
    wx, wu = W
    Vx = rng.uniform(-1.0, 1.0, pt.X.shape) * wx
    Vu = rng.uniform(-1.0, 1.0, pt.U.shape) * wu
    Vx[0] = 0.0
    with np.errstate(invalid="ignore"):
        ax, au = 2 * h * np.abs(Vx), 2 * h * np.abs(Vu)
        Vx[(pt.X - ax < bounds.xl) | (pt.X + ax > bounds.xu)] = 0.0
        Vu[(pt.U - au < bounds.ul) | (pt.U + au > bounds.uu)] = 0.0
    return Vx, Vu


def _directions(draw, pt, bounds, W, h):
    """The directions of :func:`_direction`, stacked (Vx (D, N+1, n), Vu (D, N, m)), from the
    uniform draws (D, (N+1) n + N m) of :func:`_uniform_draws` -- the generator's values in the
    order of the directions drawn one by one, states before controls: the same numbers."""
    return _spot_points(draw, pt, bounds, W, h)[:2]


def _spot_points(draw, pt, bounds, W, h):
    """(Vx, Vu, (Xs, Us, ends)): the directions of :func:`_directions` and the shifted points of
    :func:`_stacked_shifted_values` in one compiled pass (certificate_kernels.spot_points)."""
    D, N, n = draw.shape[0], pt.U.shape[0], pt.X.shape[1]
    P = D * len(_SHIFTS)
    Vx, Vu = np.empty((D,) + pt.X.shape), np.empty((D,) + pt.U.shape)
    points = np.empty((P * N, n)), np.empty((P * N, pt.U.shape[1])), np.empty((P, n))
    _kernels().spot_points(draw, pt.X, pt.U, bounds.xl, bounds.xu, bounds.ul, bounds.uu, W[0], W[1], float(h),
                           _STEPS * h, Vx, Vu, *points)
    return Vx, Vu, points


def _entry_of(shapes, j):
    """(name, index in its array) of entry j of the concatenation of the functions _NAMES' values
    (``shapes``: their shapes)."""
    for name in _NAMES:
        size = int(np.prod(shapes[name]))
        if j < size:
            return name, np.unravel_index(j, shapes[name])
        j -= size
    raise IndexError(j)


#: draws of :func:`_uniform_draws` remembered (read-only), at most this many ...
_DRAWS_KEPT = 8
#: ... and each of at most this many numbers (a larger draw is redrawn at every certificate)
_DRAWS_SIZE = 1 << 18
_DRAWS: dict = {}
_DRAWS_LOCK = threading.Lock()


def _uniform_draws(seed, count, size):
    """``np.random.default_rng(seed).uniform(-1, 1, (count, size))``: the spot check's draws,
    which depend on the seed and the sizes only -- remembered for the sizes last seen (a problem
    solved again and again draws nothing)."""
    key = (seed, count, size)
    draw = _DRAWS.get(key)
    if draw is None:
        draw = np.random.default_rng(seed).uniform(-1.0, 1.0, (count, size))
        draw.setflags(write=False)
        if draw.size <= _DRAWS_SIZE:
            with _DRAWS_LOCK:                   # solves in threads: one insertion at a time
                while len(_DRAWS) >= _DRAWS_KEPT:
                    _DRAWS.pop(next(iter(_DRAWS)))
                _DRAWS[key] = draw
    return draw


def spot_check(p, pt, bounds, W, seed=CHECK_SEED) -> _Check:
    """Step 4 of the module docstring: five-point central differences of every stage function
    along CHECK_DIRECTIONS random directions against the derivatives the problem supplies (every
    function's entries, of every direction, in one array: the formulas are elementwise, and the
    first largest ratio over the concatenation is the one the functions and directions in turn
    would find)."""
    h = CHECK_STEP
    draw = _uniform_draws(seed, CHECK_DIRECTIONS, pt.X.size + pt.U.size)
    Vx, Vu, points = _spot_points(draw, pt, bounds, W, h)
    saved = p.counters.copy()
    try:
        vals = _stacked_shifted_values(p, pt, Vx, Vu, h, points)
    except OladoError:
        p.counters.clear()
        p.counters.update(saved)
        try:
            vals = _pointwise_values(p, pt, list(zip(Vx, Vu)), h)
        except OladoError as exc:
            return _Check(None, False, f"spot check skipped: the problem cannot be evaluated near the point ({exc})")
    an, size = _directional(pt, Vx, Vu)
    # per entry (shifts 1, -1, 2, -2 of vals): d_h = (v1 - m1) / 2h, d_2h = (v2 - m2) / 4h,
    # d5 = (4 d_h - d_2h) / 3, rounding = eps (|v1| + |m1| + |v2| + |m2|) / h,
    # scale = max(size, |d5|), allowed = CHECK_RTOL scale + 10 (|d_h - d_2h| + rounding) + 1e-300,
    # err = |d5 - an|, rel = err / max(scale, 1e-300): worst = the largest rel where err > 10 rounding,
    # failed where err / allowed > 1 (the first largest ratio is reported); one compiled pass
    out = np.empty(6)
    _kernels().spot_verdict(np.ascontiguousarray(vals), an, size, float(h), _EPS, CHECK_RTOL, out)
    worst, j = float(out[0]), int(out[1])
    if not out[2] > 1.0:
        return _Check(worst, False, "")
    name, idx = _entry_of(_shapes(p), j % vals.shape[2])
    d5, an, rel = float(out[3]), float(out[4]), float(out[5])
    where = f" at stage {idx[0]}" if name in ("stage_cost", "dynamics", "stage_constraints") else ""
    if len(idx) == 2 or name == "final_constraints":
        where += f", component {idx[-1]}"
    source = p.derivative_sources().get(_DERIVATIVE_NAMES[name], "")
    return _Check(worst, True, (f"the derivative of {name}{where} ({source}) disagrees with a five-point central "
                                f"difference along a random direction: {an:.6g} vs {d5:.6g} (relative error {rel:.1e})"))


# ---------------------------------------------------------------------------- the verdict
def _verdict(settings, viol, viol_at, fig, check):
    """(level, reason) from the figures (module docstring); the reason names every condition that
    fails (at level acceptable: misses the full tolerance), the worst relative to its tolerance first."""
    if check.failed:
        return "failed", check.note
    s = settings
    if viol <= s.constr_viol_tol and fig.stationarity_scaled <= s.tol and fig.complementarity_scaled <= s.tol:
        return "success", ""                    # (the phrases below are written only for a reason)
    tests = [("constraint violation", viol, s.constr_viol_tol, s.acceptable_constr_viol_tol, f" ({viol_at()})"),
             ("scaled stationarity", fig.stationarity_scaled, s.tol, s.acceptable_tol,
              f" (Lagrangian gradient {fig.residual_at:.2e} at {fig.stationarity_at}, {fig.kind} multipliers)"),
             ("scaled complementarity", fig.complementarity_scaled, s.tol, s.acceptable_tol,
              f" (at {fig.complementarity_at}, {fig.kind} multipliers)")]
    fails = [(name, val, tol, where) for name, val, tol, _, where in tests if not val <= tol]
    level = "acceptable"
    failed = [(name, val, atol, where) for name, val, _, atol, where in tests if not val <= atol]
    if failed:
        level, fails = "failed", failed
    fails.sort(key=lambda t: -(t[1] / t[2]) if t[1] == t[1] else -np.inf)
    return level, "; ".join(f"{name} {val:.2e} exceeds {limit:g}{where}" for name, val, limit, where in fails)


def certify(problem, X, U, multipliers=None, settings=None) -> Certificate:
    """The certificate of the point (X, U) (module docstring). ``multipliers`` is a Result's
    multipliers dict (``dynamics`` (N, n), ``stage_constraints`` (N, r), ``final_constraints``
    (rN,)) or None. The problem's evaluation counters are left as they were; the certificate
    records its own evaluations."""
    settings = settings or CertificateSettings()
    t0 = time.perf_counter()
    saved = problem.counters.copy()
    try:
        cert = _certify(problem, np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(U, dtype=float), multipliers,
                        settings)
        cert.evaluations = int(sum(problem.counters.values()) - sum(saved.values()))
    finally:
        problem.counters.clear()
        problem.counters.update(saved)
    cert.time_s = time.perf_counter() - t0
    return cert


def _certify(p, X, U, multipliers, settings):
    tols = dict(tol=settings.tol, acceptable_tol=settings.acceptable_tol, constr_viol_tol=settings.constr_viol_tol,
                acceptable_constr_viol_tol=settings.acceptable_constr_viol_tol)
    try:
        pt = StagePoint(p, X, U)
    except OladoError as exc:
        return Certificate(level="failed", reason=f"the problem cannot be evaluated at the returned point ({exc})", **tols)
    bounds = StageBounds.of(p)
    viol, viol_at = _violation(p, pt)
    W = (np.maximum(1.0, np.abs(X)), np.maximum(1.0, np.abs(U)))
    S = max(1.0, abs(pt.J))
    given = _solver_multipliers(p, multipliers)
    solver_fig = None if given is None else _figures(p, pt, bounds, W, S, *given, "solver")
    fig, note = solver_fig, ""
    if fig is None or fig.error() > settings.tol:
        ls = least_squares_multipliers(p, pt, bounds, W, given, target=settings.tol)
        if isinstance(ls, str):
            note = ls
        else:
            ls_fig = _figures(p, pt, bounds, W, S, *ls, "least-squares")
            if fig is None or ls_fig.error() < fig.error():
                fig = ls_fig
    if fig is None:
        return Certificate(level="failed", reason=note or "no multipliers", violation=viol, **tols)
    check = spot_check(p, pt, bounds, W) if settings.gradient_check else _Check(None, False, "")
    level, reason = _verdict(settings, viol, viol_at, fig, check)
    if level != "success" and note:
        reason = f"{reason}; {note}"
    return Certificate(level=level, reason=reason, multipliers=fig.kind, violation=viol,
                       stationarity=fig.stationarity, complementarity=fig.complementarity,
                       stationarity_scaled=fig.stationarity_scaled, complementarity_scaled=fig.complementarity_scaled,
                       solver_stationarity_scaled=float("nan") if solver_fig is None else solver_fig.stationarity_scaled,
                       gradient_check=check.worst, gradient_check_note=check.note, **tols)


def verdict_status(cert, status, message):
    """(status, message) of a result that stopped with ``status`` (a success) after ``cert``:
    unchanged at level success; SUCCESS becomes ACCEPTABLE at level acceptable; UNCERTIFIED when
    the certificate fails, the message naming what does not hold."""
    if cert.level == "success":
        return status, message
    if cert.level == "acceptable":
        if status == Status.SUCCESS:
            return Status.ACCEPTABLE, f"{message}; olado's certificate holds at the acceptable level only: {cert.reason}"
        return status, message
    return Status.UNCERTIFIED, f"{message}; but olado's independent optimality check fails: {cert.reason}"


def certify_result(result, problem, options):
    """Certify a Result that reports success (unless ``options.certify`` is off or the solver
    certified it already) and apply the verdict (:func:`verdict_status`)."""
    if not getattr(options, "certify", False) or not result.status.success or result.certificate is not None:
        return result
    cert = certify(problem, result.x, result.u, result.multipliers, CertificateSettings.from_options(options))
    result.certificate = cert
    result.status, result.message = verdict_status(cert, result.status, result.message)
    return result
