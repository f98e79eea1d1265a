"""Starting points of the interior-point QP (paper 001 sec. 4.2.2: a point with positive slacks
w and multipliers lambda, (18)-(19)): the centred cold start and the warm start from an earlier
result.
"""

from __future__ import annotations

import numpy as np

from ...linalg.backend import RHS, NotPositiveDefiniteError, make_kkt_solver
from ..stageqp import QPResult
from .point import _Point
from .step import _check_rows


#: weights of the cold start's proximal term |w - w_ref|^2 tried in turn (relative to 1 + max|H|
#: after the first, the unit weight): a Hessian that is not positive definite on the null space of
#: the equalities needs a larger one for the starting system to have a minimizer
START_WEIGHTS = (None, 1e-2, 1.0, 1e2)


def initial_point(P, options, mu0=None):
    """Cold start: (X, U) minimizes f + D/2 |w - w_ref|^2 (+ D/2 |z|^2 on unbounded
    components) subject to the equality constraints -- one factorization -- with w_ref the
    middle of two-sided boxes and 0 clipped into one-sided ones; its lam, nu are kept; slacks
    t = max(w - lo, 1) (resp. max(hi - w, 1)) and multipliers z = mu0 / t on every finite side
    (a perfectly centred start, mu = mu0, by default ``initial_mu``). D = 1; when the Hessian of
    a nonconvex QP leaves that system without a minimizer (a reduced Hessian that is not positive
    definite), D grows through :data:`START_WEIGHTS` (the starting point is only a centred
    guess: the iterations regularize their Newton systems themselves). Raises the last
    NotPositiveDefiniteError when none succeeds."""
    for weight in START_WEIGHTS:
        try:
            sol, ref = _start_solve(P, options, start_weight(P, weight))
            break
        except NotPositiveDefiniteError:
            if weight == START_WEIGHTS[-1]:
                raise
    return _centred(P, options, sol, ref, mu0)


def start_weight(P, weight):
    """The diagonal D of the cold-start system for an entry of :data:`START_WEIGHTS`."""
    return 1.0 if weight is None else weight * (1.0 + P.h_scale)


def _start_solve(P, options, D):
    """The equality-constrained least-distance system of the cold start with weight D. With the
    Riccati back-end the system is factored by the prepared QP's own back-end (:func:`_shared_solve`),
    which its iterations then refactor; another back-end is made for it alone."""
    N, n, m, nc = P.N, P.n, P.m, P.nc
    two = P.fl & P.fu
    ref = np.where(two, 0.5 * (P.lo + P.hi),
                   np.clip(np.zeros(P.nw), np.where(P.fl, P.lo, -np.inf), np.where(P.fu, P.hi, np.inf)))
    q = P.q.copy(); r = P.r.copy()
    q[1:] -= D * ref[P.sl_x].reshape(N, n)
    r -= D * ref[P.sl_u].reshape(N, m)
    ci = -D * ref[P.sl_s].reshape(N, nc) if nc else None
    if P.ncN:
        q[-1] -= D * (P.CN.T @ ref[P.sl_sN])
    if options.kkt == "riccati":
        return _shared_solve(P, options, D, q, r, ci), ref
    kw, rhs = dict(Dx=np.full((N + 1, n), D), Du=np.full((N, m), D)), {}
    if nc:
        kw.update(Ci=P.C, sigma=np.full((N, nc), D))
        rhs["ci"] = ci
    Q = P.Q
    if P.ncN:
        Q = P.Q.copy(); Q[-1] = Q[-1] + D * (P.CN.T @ P.CN)
    if P.has_eq:
        kw.update(E=P.E, F=P.F, n_eq=P.n_eq, EN=P.EN)
        rhs.update(e=P.e, eN=P.eN)
    kw.update(options.kkt_options)
    sol = make_kkt_solver(options.kkt, Q, P.S, P.R, P.A, P.B, limits=P.limits, **kw).solve(q, r, P.c, P.x0, **rhs)
    _check_rows(P, float(sol.x0_residual), None, "starting point")
    return sol, ref


def _shared_solve(P, options, D, q, r, ci):
    """The cold-start system solved with the prepared QP's back-end: its diagonal work arrays
    (Dx, Du, the stage-row weights; Q_N + D C_N^T C_N in Q_final) set to the start's terms and
    the back-end made with them (the arguments of the iterations' factorizations, step.py) or
    refactored; the same system and solution as a back-end made for the start alone. The
    solution is written into a new point (its X, U, lam, nu), returned: the start is made in it."""
    P.work_Dx.fill(D)
    P.work_Du.fill(D)
    if P.nc:
        P.Ds.fill(D)
    if P.ncN:
        P.Q_final[-1] = P.Q[-1] + D * (P.CN.T @ P.CN)
    if P.fact is None:
        kw = {}
        if P.nc:
            kw.update(Ci=P.C, sigma=P.Ds)
        if P.has_eq:
            kw.update(E=P.E, F=P.F, n_eq=P.n_eq, EN=P.EN)
        kw.update(options.kkt_options)
        P.fact = make_kkt_solver(options.kkt, P.Q_final if P.ncN else P.Q, P.S, P.R, P.A, P.B,
                                 Dx=P.work_Dx, Du=P.work_Du, limits=P.limits, **kw)
    else:
        P.fact.refactor(Dx=P.work_Dx, Du=P.work_Du, sigma=P.Ds if P.nc else None)
    point = P.start_point()
    defect = P.fact.solve_into(RHS(q=q, r=r, c=P.c, x0=P.x0, e=P.e, eN=P.eN, ci=P.work_ci if ci is None else ci),
                               point.solution)
    _check_rows(P, float(defect), None, "starting point")
    return point


def _centred(P, options, sol, ref, mu0):
    """The centred starting point from the solution ``sol`` of the cold-start system (an
    LQSolution, or the point it was solved into), written into a new point (or that one): (X, U, lam, nu) of ``sol``, t = max(w - lo, 1), max(hi - w, 1) and z = mu0 / t on
    the finite sides, 0 on the others."""
    if isinstance(sol, _Point):      # solved into the point (_shared_solve)
        p = sol
    else:
        p = P.start_point()
        np.copyto(p.X, sol.X); np.copyto(p.U, sol.U); np.copyto(p.lam, sol.lam)
        p.nu.fill(0.0)
        k = min(P.n_nu, sol.nu.shape[1])
        p.nu[:, :k] = sol.nu[:, :k]
    w = P.w_of(p.X, p.U)
    mu0 = options.initial_mu if mu0 is None else mu0
    for t, z, finite, a, b in ((p.tl, p.zl, P.fl, w, P.lo), (p.tu, p.zu, P.fu, P.hi, w)):
        np.subtract(a, b, out=t)
        np.maximum(t, 1.0, out=t)
        infinite = ~finite
        np.copyto(t, 0.0, where=infinite)
        np.divide(mu0, t, out=z, where=finite)
        np.copyto(z, 0.0, where=infinite)
    return p


def warm_point(P, options, ws: QPResult):
    """Warm start from a previous result: X, U, lam, nu and the box multipliers are taken over
    (multipliers of eliminated or equality-row entries mapped as in
    :meth:`InteriorPointQP._finish`); slacks
    t = max(w - lo, theta) and multipliers z = max(z_ws, theta) on finite sides with
    theta = ``warm_start_push`` * (1 + max |z_ws|)."""
    N, n, m = P.N, P.n, P.m
    p = P.start_point()     # the start, written in place
    np.copyto(p.X, np.asarray(ws.X, dtype=float).reshape(N + 1, n))
    np.copyto(p.U, np.asarray(ws.U, dtype=float).reshape(N, m))
    if P.any_ufix:
        p.U[P.ufix] = 0.0   # eliminated controls are 0 in the reduced problem
    np.copyto(p.lam, np.asarray(ws.lam, dtype=float).reshape(N + 1, n))
    nu = p.nu
    nu.fill(0.0)
    wnu = np.asarray(ws.nu, dtype=float)
    if wnu.ndim == 2 and wnu.shape[0] == N + 1:
        a, b = min(P.ne0, wnu.shape[1]), min(P.neN0, wnu.shape[1])
        nu[:N, :a] = wnu[:N, :a]
        nu[N, :b] = wnu[N, :b]
    for k, row, kind, i in P.eq_map:
        nu[k, row] = (ws.zx_upper[k, i] - ws.zx_lower[k, i]) if kind == "x" else (ws.yc_upper[k, i] - ws.yc_lower[k, i])
    for row, kind, i in P.eqN_map:
        nu[N, row] = (ws.zx_upper[N, i] - ws.zx_lower[N, i]) if kind == "x" else (ws.yN_upper[i] - ws.yN_lower[i])
    flat = lambda out, *a: np.concatenate([np.asarray(v, dtype=float).ravel() for v in a], out=out)  # noqa: E731
    zl = flat(p.zl, np.asarray(ws.zx_lower)[1:], ws.zu_lower, ws.yc_lower, ws.yN_lower)
    zu = flat(p.zu, np.asarray(ws.zx_upper)[1:], ws.zu_upper, ws.yc_upper, ws.yN_upper)
    for z in (zl, zu):
        if not np.isfinite(z).all():
            np.nan_to_num(z, copy=False)
    big = max(float(np.max(np.abs(zl), initial=0.0)), float(np.max(np.abs(zu), initial=0.0)))
    theta = options.warm_start_push * (1.0 + big)
    w = P.w_of(p.X, p.U)
    for t, z, finite, a, b in ((p.tl, zl, P.fl, w, P.lo), (p.tu, zu, P.fu, P.hi, w)):
        infinite = ~finite
        np.subtract(a, b, out=t)
        np.maximum(t, theta, out=t)
        np.copyto(t, 0.0, where=infinite)
        np.maximum(z, theta, out=z)
        np.copyto(z, 0.0, where=infinite)
    return p
