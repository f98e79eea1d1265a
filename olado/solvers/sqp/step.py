"""The QP step of the SQP method (paper 001 sec. 4.2.1): the QP (8)-(10) in stage form at the
iterate, its solution s with delta*I (+ the proximal term) added to the block-diagonal Hessian
(12), the inertia correction of delta, and the QP's multipliers as the new estimates.

Inertia correction (Waechter & Biegler 2006, Alg. IC, applied to the QP): a QP that fails (its
Riccati factorizations find a reduced Hessian that is not positive definite and the interior
point stalls) is solved again with delta = max(shift_increase delta, shift_init max|H|,
shift_curvature (-s.H s / |s|^2)), s its last iterate; with shift_mode = "stage" only on the
blocks without positive curvature along s, s_k.(H_k + delta_k I) s_k <= 0 (H block diagonal,
so s.H s is the sum of these terms). A QP step that is no descent direction of the merit
function gets the same treatment (olado.solvers.sqp.phases).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ...qp.elastic import ElasticQP
from ...qp.stageqp import StageQP
from ..certificate import weighted_qp
from ...result import Status
from .state import BoundMultipliers, Multipliers


class QPSolve(NamedTuple):
    """A solved QP subproblem: the QP result, the shift delta (per stage block) it was solved
    with, the interior-point iterations of all its attempts, and for the elastic QP
    (olado.qp.elastic) its slacks, the linearized violations at the step (None otherwise)."""

    result: Any
    delta: np.ndarray
    iterations: int
    slacks: Any = None


def proximal_factor(options, local, local_scale=1.0):
    """The proximal factor: in the local phase ``local_proximal`` (unless None) times
    ``local_scale`` (< 1 after local steps the proximal term dominated, see
    olado.solvers.sqp.phases.crawling); else the ``proximal`` option, by default 1e-4 with
    the exact Hessian and 0 with the quasi-Newton ones (their blocks keep the initial scale in
    directions no step has explored, so max|H| overstates the curvature;
    docs/structure-exploiting-sqp.md)."""
    if local and options.local_proximal is not None:
        return options.local_proximal * local_scale
    if options.proximal is not None:
        return options.proximal
    return 1e-4 if options.hessian == "exact" else 0.0


def hessian_scale(Bk, BN):
    """max|H| of the block-diagonal Hessian (at least 1e-300); numpy's max (a NaN propagates)
    over each of Bk and BN, compiled (olado.solvers.sqp.kernels) for float arrays."""
    if Bk.dtype == np.float64 and BN.dtype == np.float64:
        from . import kernels
        return max(1e-300, kernels.npmax_abs(Bk, 0.0), kernels.npmax_abs(BN, 0.0))
    return max(1e-300, float(np.max(np.abs(Bk), initial=0.0)), float(np.max(np.abs(BN), initial=0.0)))


def current_hessian_scale(st, Bk, BN):
    """hessian_scale(Bk, BN), taken from the iteration's Hessian phase when Bk, BN are the blocks
    it measured (``st.hscale_of``; olado.solvers.sqp.phases.hessian_phase)."""
    known = st.hscale_of
    if known is not None and known[0] is Bk and known[1] is BN:
        return known[2]
    return hessian_scale(Bk, BN)


def shift_scale(scale):
    """The scale of the inertia correction's shifts after a failed QP: max|H|, or 1 when H = 0 (a
    linear objective with zero multipliers, e.g. at the start of a free-time or Mayer problem):
    shifts of shift_init * 1e-300 * 10^k could never bound such a QP -- orbit-raising's first QP
    stayed unbounded through all 30 of them (IPOPT's first inertia correction is likewise an
    absolute 1e-4, Waechter & Biegler 2006 sec. 3.1)."""
    return scale if scale > 1e-300 else 1.0


def curvature(Bk, BN, dX, dU):
    """(s.H s, s.s) for s = (dX, dU) and the block-diagonal H of the stage blocks Bk and BN."""
    z = np.concatenate([dX[:-1], dU], axis=1)
    sHs = float(np.einsum("ki,kij,kj->", z, Bk, z) + dX[-1] @ BN @ dX[-1])
    return sHs, float(np.sum(z * z) + dX[-1] @ dX[-1])


class ShiftRule:
    """The inertia correction's shift delta (one value per stage block, N + 1 values)."""

    def __init__(self, options):
        self.options = options

    def start(self, shift, hscale):
        """The shift an iteration starts from: ``shift_decrease`` times the last one, 0 below
        shift_min * max|H|."""
        o = self.options
        delta0 = shift * o.shift_decrease
        delta0[delta0 < o.shift_min * hscale] = 0.0
        return delta0

    def raise_(self, delta, hscale, stages=None, floor=0.0):
        """The next shift: max(shift_increase * delta_k, shift_init * max|H|, floor) on the
        stage blocks in ``stages`` (a boolean mask over the N + 1 blocks; all if None)."""
        o = self.options
        new = np.maximum(o.shift_increase * delta, max(o.shift_init * shift_scale(hscale), floor))
        return new if stages is None else np.where(stages, new, delta)

    def raise_along(self, delta, hscale, Bk, BN, dX, dU, local):
        """The next shift after a rejected QP step, or a failed QP's last iterate, s = (dX, dU):
        raised on the blocks without positive curvature along s (shift_mode = 'stage'; all
        otherwise) to at least the curvature floor of s."""
        return self.raise_(delta, hscale, self.flat_stages(Bk, BN, delta, hscale, dX, dU, local),
                           floor=self.curvature_floor(Bk, BN, dX, dU))

    def curvature_floor(self, Bk, BN, dX, dU):
        """shift_curvature times the negative curvature -s.H s / |s|^2 of the unshifted Hessian
        along s (0 if none): s comes from a QP whose reduced Hessian had about that much negative
        curvature, so a shift well below it cannot restore descent."""
        sHs, ss = curvature(Bk, BN, dX, dU)
        if not ss > 0.0:
            return 0.0
        return self.options.shift_curvature * max(0.0, -sHs / ss)

    def flat_stages(self, Bk, BN, delta, hscale, dX, dU, local=False):
        """With shift_mode = 'stage': the blocks without positive curvature along the rejected
        step s (s_k.(H_k + (delta_k + proximal max|H|) I) s_k <= 0), or None (all blocks) when
        there is none or shift_mode = 'global'."""
        if self.options.shift_mode != "stage":
            return None
        prox = proximal_factor(self.options, local) * hscale
        z = np.concatenate([dX[:-1], dU], axis=1)
        curv = np.empty(len(delta))
        curv[:-1] = np.einsum("ki,kij,kj->k", z, Bk, z) + (delta[:-1] + prox) * np.einsum("ki,ki->k", z, z)
        curv[-1] = dX[-1] @ BN @ dX[-1] + (delta[-1] + prox) * (dX[-1] @ dX[-1])
        flat = curv <= 0.0
        return flat if flat.any() else None


def qp_tolerance(options, kkt_res, grad_scale):
    """Tolerance of the next interior-point QP: ``qp_tol``, or with ``qp_adaptive_tol`` the
    inexact-SQP rule clip(qp_forcing * KKT residual / (1 + |grad J|), qp_tol, qp_tol_max)."""
    o = options
    if not o.qp_adaptive_tol or not math.isfinite(kkt_res):
        return o.qp_tol if not o.qp_adaptive_tol else max(o.qp_tol, o.qp_tol_max)
    return min(max(o.qp_tol, o.qp_forcing * kkt_res / (1.0 + grad_scale)), max(o.qp_tol, o.qp_tol_max))


def build_qp(p, pt, Bk, BN, masks, offsets=None):
    """The QP (8)-(10) in the step (dx, du) at the point pt, in stage form. ``offsets`` =
    (h, g, gN) replaces the constraint values of the linearization (second-order correction)."""
    eq, ineq, eqN, ineqN = masks
    N, n = p.N, p.n
    X, U = pt.X, pt.U
    h, g, gN = (pt.h, pt.g, pt.gN) if offsets is None else offsets
    Q = np.empty((N + 1, n, n))
    Q[:-1] = Bk[:, :n, :n]; Q[-1] = BN
    kw = _constraint_rows(p, pt, masks, g, gN)
    xl = p.x_lower - X; xu = p.x_upper - X
    xl[0] = -np.inf; xu[0] = np.inf      # x0 is fixed by the x0 row; its bounds are not the QP's business
    drop_fixed_bounds(pt.A, pt.B, h, p.x0 - X[0], xl, xu, kw.get("EN"), kw.get("eN"),
                      slack=FIXED_BOUND_RTOL * (1.0 + np.abs(X)))
    return StageQP(Q=Q, R=Bk[:, n:, n:], S=Bk[:, :n, n:], q=np.vstack([pt.lx, pt.lN[None, :]]), r=pt.lu,
                   A=pt.A, B=pt.B, c=h, x0=p.x0 - X[0], x_lower=xl, x_upper=xu,
                   u_lower=p.u_lower - U, u_upper=p.u_upper - U, **kw)


def _constraint_rows(p, pt, masks, g, gN):
    """The stage and final constraint rows of the QP at pt (keyword arguments of StageQP)."""
    eq, ineq, eqN, ineqN = masks
    N = p.N
    kw = {}
    if p.r and eq.any():
        kw.update(E=pt.Cx[:, eq, :], F=pt.Cu[:, eq, :], e=g[:, eq])
    if p.r and ineq.any():
        C = np.concatenate([pt.Cx[:, ineq, :], pt.Cu[:, ineq, :]], axis=2)
        kw.update(C=C, c_lower=-g[:, ineq], c_upper=np.full((N, int(ineq.sum())), np.inf))
    if p.rN and eqN.any():
        kw.update(EN=pt.CN[eqN], eN=gN[eqN])
    if p.rN and ineqN.any():
        kw.update(CN=pt.CN[ineqN], cN_lower=-gN[ineqN], cN_upper=np.full(int(ineqN.sum()), np.inf))
    return kw


def assemble_qp(p, pt, Bk, BN, shift, masks, offsets=None):
    """:func:`build_qp` with the Hessian blocks Bk + shift_k I, BN + shift_N I (``shift``: N + 1
    values, or None for the blocks unshifted), in compiled passes (olado.solvers.sqp.kernels: the
    blocks, the step's vectors and boxes, the fixed-state bound rule) -- the same QP, entry for
    entry, as ``build_qp`` of the shifted blocks."""
    from . import kernels

    n = p.n
    X, U = pt.X, pt.U
    h, g, gN = (pt.h, pt.g, pt.gN) if offsets is None else offsets
    f = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731   (as StageQP does)
    Bk = f(Bk); BN = f(BN)
    if shift is None:
        Q, S, R = kernels.plain_blocks(Bk, BN, n)
    else:
        Q, S, R = kernels.shifted_blocks(Bk, BN, f(shift), n)
    A, B, c = f(pt.A), f(pt.B), f(h)
    q, x0, xl, xu, ul, uu = kernels.step_vectors(f(pt.lx), f(pt.lN), f(X), f(U), f(p.x0), f(p.x_lower),
                                                 f(p.x_upper), f(p.u_lower), f(p.u_upper))
    kw = _constraint_rows(p, pt, masks, g, gN) if (p.r or p.rN) else {}
    EN, eN = kw.get("EN"), kw.get("eN")
    EN = np.zeros((0, n)) if EN is None else f(EN)
    eN = np.zeros(0) if eN is None else f(eN)
    kernels.drop_fixed_bounds(A, B, c, x0, xl, xu, EN, eN, f(X), FIXED_BOUND_RTOL)
    return StageQP.assembled(Q=Q, R=R, S=S, q=q, r=f(pt.lu), A=A, B=B, c=c, x0=x0, x_lower=xl, x_upper=xu,
                             u_lower=ul, u_upper=uu, **kw)


def fixed_states(A, B, c, x0, EN=None, eN=None, wanted=None):
    """The state steps that the QP's equality rows fix whatever the controls, as (mask, values),
    both (N+1, n): dx_0 = x0 (the x0 row); then, while any component is fixed, the components
    of dx_{k+1} = A_k dx_k + B_k du_k + c_k whose row of B_k is zero and whose row of A_k touches
    fixed components only (e.g. the states a parameter stage copies, olado.problems.continuous,
    or an explicit Euler position x_1 = x_0 + h v_0); and the components of x_N that a final
    equality row with a single nonzero entry fixes (a singleton row, as in LP presolve).
    ``wanted`` (N+1, n), if given, marks the components whose values matter (finite bounds): a
    chain that stays fixed over every later stage (a clock) is not followed stage by stage when
    it has none of them (its later entries get the mask and no value) or when its value and the
    offsets c_k of its rows are 0 from there on (a feasible iterate: its values stay 0), so a
    long horizon costs one vectorized test instead of a Python loop (~0.1 ms per stage)."""
    N, n = A.shape[0], A.shape[1]
    fixed = np.zeros((N + 1, n), dtype=bool)
    value = np.zeros((N + 1, n))
    fixed[0], value[0] = True, x0
    tail_tested = False
    for k in range(N):
        rows = ~np.any(B[k] != 0.0, axis=1) & ~np.any((A[k] != 0.0) & ~fixed[k][None, :], axis=1)
        if not rows.any():
            break           # nothing fixed at stage k + 1, so nothing later through the dynamics
        fixed[k + 1] = rows
        value[k + 1] = np.where(rows, A[k] @ np.where(fixed[k], value[k], 0.0) + c[k], 0.0)
        if wanted is not None and not tail_tested and k + 2 <= N and np.array_equal(rows, fixed[k]):
            tail_tested = True
            if _fixed_from_here(A, B, k + 1, rows) and (not wanted[k + 2:, rows].any() or (
                    not np.any(value[k + 1, rows]) and not np.any(c[k + 1:, rows]))):
                fixed[k + 2:, rows] = True      # (values 0: from 0 through rows without offsets)
                break
    if EN is not None and EN.size:
        for row in np.nonzero(np.count_nonzero(EN, axis=1) == 1)[0]:
            i = int(np.flatnonzero(EN[row])[0])
            if not fixed[N, i]:
                fixed[N, i], value[N, i] = True, -eN[row] / EN[row, i]
    return fixed, value


def _fixed_from_here(A, B, k, rows):
    """Whether the components ``rows`` stay fixed through the dynamics of stages k..N-1: zero rows
    of B_j, rows of A_j that touch those components only."""
    return not (np.any(B[k:, rows, :] != 0.0) or np.any(A[k:][:, rows][:, :, ~rows] != 0.0))


#: a fixed state step within this times (1 + |x|) of its bound counts as satisfying it (the
#: dynamics residual c_k of a feasible iterate is a rounding error, not a violation)
FIXED_BOUND_RTOL = 1e-12


def drop_fixed_bounds(A, B, c, x0, xl, xu, EN=None, eN=None, slack=0.0):
    """Remove (in place) the bounds xl <= dx <= xu of the state steps that the equality rows fix
    (:func:`fixed_states`; x_0's are dropped by the caller) when the fixed value satisfies them
    to within ``slack``. Such a bound at its limit is active at every feasible point: the QP has no
    strictly feasible point, and an interior-point method's multipliers z = mu / slack on it grow
    without bound with those of the rows that fix it (goddard: its final mass row m(T) = 0.6 on
    the bound m >= 0.6, and the states at x0's bounds that its parameter stage copies -- QP
    multipliers 1.27e6, IPOPT's largest 4.8; IPOPT relaxes such bounds, bound_relax_factor,
    Waechter & Biegler 2006 sec. 3.5). The QP's feasible set is unchanged (to ``slack``), and so
    is its solution; the dropped bounds' multipliers are 0, their share carried by the rows that
    fix the state. A violated bound is kept (the QP is then infeasible, and says so)."""
    fixed, value = fixed_states(A, B, c, x0, EN, eN, wanted=np.isfinite(xl) | np.isfinite(xu))
    fixed[0] = False
    ok = fixed & (value >= xl - slack) & (value <= xu + slack)
    xl[ok] = -np.inf
    xu[ok] = np.inf


def _qp_shift(qp_solver, qres):
    """The shift an interior-point QP in nonconvex = "shift" mode added to its Hessian (0 otherwise)."""
    opts = getattr(qp_solver, "options", None)
    if getattr(opts, "nonconvex", "regularize") != "shift":
        return 0.0
    reg = float(getattr(qres, "regularization", 0.0) or 0.0)
    return reg if reg > 10.0 * opts.regularization else 0.0


_FAILED = (Status.NUMERICAL_ERROR, Status.UNBOUNDED, Status.MAX_ITERATIONS, Status.FAILED)

#: the relaxed QP's slacks get this times max|H| as curvature (olado.qp.elastic.ElasticQP), so that
#: the QP methods that need a strictly convex QP (the active-set method, quadprog) take it too
ELASTIC_CURVATURE = 1e-6


def solve_qp(setup, st, pt, Bk, BN, delta, *, inertia, warm=None, zero_gradient=False, offsets=None, eta=None,
             u_box=None, relax_dynamics=False):
    """Solve the QP subproblem at pt with delta*I (+ the proximal term) added to the Hessian.
    With ``inertia`` a QP whose KKT factorization fails -- a reduced Hessian that is not positive
    definite -- is solved again with a larger delta (:class:`ShiftRule`); with ``curvature_tol``
    so is a QP step along which the Hessian has almost no positive curvature (inertia-free test,
    Chiang & Zavala 2016). ``warm`` is a QPResult to start the QP from. With ``eta`` the elastic
    form of the QP (olado.qp.elastic, penalty eta) is solved instead, cold; ``u_box`` bounds the
    control steps, |du| <= u_box (a trust region); ``relax_dynamics`` relaxes the dynamics rows of the
    elastic QP too (olado.qp.elastic). Reads the local-phase flag and the relative KKT
    residual of ``st``; returns a :class:`QPSolve`."""
    o, p, qp_solver = setup.options, setup.problem, setup.qp_solver
    rule = ShiftRule(o)
    iterations = 0
    scale = current_hessian_scale(st, Bk, BN)
    # Levenberg-Marquardt-like: delta shrinks with the relative KKT residual of the last
    # iterate (kept superlinear), but never exceeds proximal * max|H|
    prox_factor = proximal_factor(o, st.qp_local, st.local_proximal_scale)
    # (relative to shift_scale: with H = 0, e.g. a linear objective at zero multipliers, a term
    # relative to max|H| = 1e-300 would make a QP whose Hessian is 1e-304 I -- "positive
    # definite" to a Cholesky factorization, and the active-set QP's points then reach 1e307)
    ref = shift_scale(scale)
    prox = min(prox_factor, st.kkt_rel) * ref if o.adaptive_proximal else prox_factor * ref
    n, m = p.n, p.m
    # the compiled assembly unless the shifted blocks themselves are needed (the curvature test)
    compiled = not (inertia and o.curvature_tol > 0)
    for _ in range(30):
        shifted = delta + prox
        if compiled:
            qp = assemble_qp(p, pt, Bk, BN, shifted if np.any(shifted > 0) else None, setup.masks, offsets)
        else:
            if np.any(shifted > 0):
                Bd = Bk + (delta[:-1] + prox)[:, None, None] * np.eye(n + m)
                BNd = BN + (delta[-1] + prox) * np.eye(n)
            else:
                Bd, BNd = Bk, BN
            qp = build_qp(p, pt, Bd, BNd, setup.masks, offsets)
        if zero_gradient:     # new arrays: the QP's r may be the point's own lu, which must stay
            qp.q = np.zeros_like(qp.q)
            qp.r = np.zeros_like(qp.r)
        if u_box is not None:
            qp.u_lower = np.maximum(qp.u_lower, -u_box)
            qp.u_upper = np.minimum(qp.u_upper, u_box)
        slacks = None
        if eta is None:
            qres = qp_solver.solve(qp, warm_start=warm, limits=setup.limits)
        else:
            elastic = ElasticQP(qp, eta, curvature=ELASTIC_CURVATURE * ref, relax_dynamics=relax_dynamics)
            qres, slacks = elastic.restore(qp_solver.solve(elastic.relaxed, limits=setup.limits))
        iterations += int(qres.iterations)
        if inertia and o.curvature_tol > 0 and qres.success:
            sHs, ss = curvature(Bd, BNd, qres.X, qres.U)
            if not sHs >= o.curvature_tol * scale * ss:
                delta = rule.raise_(delta, scale)
                continue
        qshift = _qp_shift(qp_solver, qres)
        if not inertia or qres.success or qres.status not in _FAILED:
            return QPSolve(qres, delta + qshift, iterations, slacks)
        # a failed QP: raise the shift (with shift_mode = 'stage' on the blocks without positive
        # curvature along its last iterate, when it has one)
        if qres.X is not None and np.all(np.isfinite(qres.X)) and np.all(np.isfinite(qres.U)):
            delta = rule.raise_along(delta, shift_scale(scale), Bk, BN, qres.X, qres.U, st.qp_local)
        else:
            delta = rule.raise_(delta, shift_scale(scale))
    return QPSolve(qres, delta, iterations, slacks)


def least_squares_multipliers(setup, pt):
    """IPOPT's initial multiplier estimate (Waechter & Biegler 2006, sec. 3.6, eq. (36)) on the
    stage structure: the multipliers of the equality constraints (dynamics, equality rows of g and
    gN) that minimize |grad J + J_eq^T y| -- the multipliers of the QP min 1/2 |s|^2 + grad J.s
    subject to the homogeneous linearized equalities, one Riccati solve; inequalities and bounds
    get 0. Returns (Multipliers, max |y|, QP iterations), or None when that QP fails."""
    p = setup.problem
    eq, _, eqN, _ = setup.masks
    N = p.N
    # the certificate's weighted least-squares QP with unit weights and no inequality row active
    qp = weighted_qp(p, pt, np.ones((N + 1, p.n)), np.ones((N, p.m)), np.zeros((N, int((~eq).sum())), dtype=bool),
                     np.zeros(int((~eqN).sum()), dtype=bool))
    qres = setup.qp_solver.solve(qp)    # before the solve's interrupt guard: no limits (one Newton step)
    if not qres.success:
        return None
    mult, _ = qp_multipliers(qres, setup.masks, N, p.r, p.rN)
    mult.Lg[:, ~eq] = 0.0                 # the rows g >= 0 were free in that QP
    mult.LgN[~eqN] = 0.0
    mult.lam[0] = 0.0
    return mult, mult.largest(), int(qres.iterations)


def bounded_estimate(setup, pt):
    """The least-squares estimate at pt (:func:`least_squares_multipliers`) when its largest
    multiplier is at most ``multiplier_init_max`` (IPOPT's constr_mult_init_max), else None; with
    the QP iterations it cost."""
    est = least_squares_multipliers(setup, pt)
    if est is None:
        return None, 0
    return (est[0] if est[1] <= setup.options.multiplier_init_max else None), est[2]


def qp_multipliers(qres, masks, N, r, rN):
    """The QP's multipliers as the new NLP estimates: (Multipliers, BoundMultipliers)."""
    eq, ineq, eqN, ineqN = masks
    Lg = np.zeros((N, r))
    if r:
        Lg[:, eq] = qres.nu[:N, : int(eq.sum())]
        Lg[:, ineq] = -(qres.yc_lower - qres.yc_upper)
    LgN = np.zeros(rN)
    if rN:
        LgN[eqN] = qres.nu[N, : int(eqN.sum())]
        LgN[ineqN] = -(qres.yN_lower - qres.yN_upper)
    bounds = BoundMultipliers(qres.zx_lower, qres.zx_upper, qres.zu_lower, qres.zu_upper)
    return Multipliers(qres.lam.copy(), Lg, LgN), bounds


def soc_offsets(p, pt, cand, dX, dU):
    """Constraint values for the second-order correction QP: c(pt + s) - J(pt) s for the
    dynamics (h = f - x_+), the stage and the final constraints (the bounds are linear)."""
    h = cand.h - (np.einsum("kij,kj->ki", pt.A, dX[:-1]) + np.einsum("kij,kj->ki", pt.B, dU) - dX[1:])
    g = cand.g - (np.einsum("kij,kj->ki", pt.Cx, dX[:-1]) + np.einsum("kij,kj->ki", pt.Cu, dU)) if p.r else cand.g
    gN = cand.gN - pt.CN @ dX[-1] if p.rN else cand.gN
    return h, g, gN
