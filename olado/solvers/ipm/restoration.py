"""The least-squares multiplier estimate of the start (Waechter and Biegler 2006, sec. 3.6,
eq. (36)) and the feasibility restoration phase (sec. 3.3), both as LQ-DOCPs on the Riccati
back-end (:class:`~olado.solvers.ipm.newton.KKTMatrix`).

Restoration: olado's phase is not IPOPT's l1 restoration NLP (eq. (30)) but a sequence of
minimum-distance Gauss-Newton steps towards the linearized constraints,

    min 1/2 d^T (Sigma + zeta I) d   s.t.  J d = -c,        zeta = sqrt(mu)

(the proximity term of (30) with D_R = I, the barrier's Sigma keeping the bounds at a distance;
c every constraint residual, slacks included), with the fraction-to-boundary rule and
backtracking on theta -- one Riccati factorization per step, always positive definite. It
returns to the filter method once theta has fallen to kappa_resto = 0.9 of its value at the
start of the phase and the point is acceptable to the filter (sec. 3.3); the multipliers are
then estimated afresh (least squares), the bound multipliers kept. The theory of sec. 2 allows
any restoration procedure that reduces theta; a phase that cannot (no step inside the bounds
reduces the violation) reports the problem as locally infeasible.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...result import Status
from .newton import KKTMatrix, Residuals

KAPPA_RESTO = 0.9


class Restoration(NamedTuple):
    """The solver's functions the phase uses (evaluate, theta, barrier_value, residuals)."""

    evaluate: Callable
    theta: Callable
    barrier_value: Callable
    residuals: Callable
    lagrangian_gradient: Callable


def _diagonal_system(setup, pt, sig):
    """The KKT matrix with a zero Hessian and the diagonal ``sig`` (flat, like v) at pt's Jacobians."""
    from .solver import constraint_blocks    # noqa: PLC0415 - the solver module imports this one

    p, L = setup.problem, setup.layout
    N, n, m = p.N, p.n, p.m
    Sx, Su, Ss, SsN = L.split(sig, np.zeros(n))
    return KKTMatrix(np.zeros((N + 1, n, n)), np.zeros((N, n, m)), np.zeros((N, m, m)), pt.A, pt.B, Sx, Su,
                     constraint_blocks(setup, pt, Ss, SsN))


def least_squares_multipliers(setup, pt, zl, zu, s_obj):
    """The constraint multipliers minimizing the 2-norm of the Lagrangian's gradient (eq. (36)):
    the LQ-DOCP with identity Hessian and zero constraint offsets, one Riccati recursion.
    Returns (lam (N+1, n), nu, nuN, yd, ydN)."""
    p, L = setup.problem, setup.layout
    N, n = p.N, p.n
    kkt = _diagonal_system(setup, pt, np.ones(L.size))
    kkt.try_factor(0.0)
    dz = zu - zl
    bx, bu, vs, vsN = L.split(dz, np.zeros(n))
    q = np.empty((N + 1, n)); q[:-1] = pt.lx; q[-1] = pt.lN
    zero = Residuals(np.zeros((N, n)), np.zeros((N, L.ne)), np.zeros(L.neN), np.zeros((N, L.ni)), np.zeros(L.niN))
    step = kkt.solve(s_obj * q + bx, s_obj * pt.lu + bu, zero, vs, vsN)     # gs = -v_L: vs = zu - zl = -zl
    return step.lam, step.nu, step.nuN, step.yd, step.ydN


def restore(setup, st, fns: Restoration):
    """The restoration phase at the current iterate (the filter already augmented by it). On
    success the iterate and the multipliers are updated in ``st`` and None is returned; otherwise
    a function of the reason the line search gave up that returns (Status, message)."""
    p, b, o, L = setup.problem, setup.bounds, setup.options, setup.layout
    th0 = fns.theta(setup, st.pt, st.v)
    if th0 <= 0.1 * o.constr_viol_tol:
        return lambda why: (Status.NUMERICAL_ERROR,
                            f"{why} at a feasible point (constraint violation {th0:.2e}) after {st.it} iterations: "
                            f"no acceptable step along the Newton direction (scaled optimality error "
                            f"{st.errors[0]:.2e}, mu = {st.mu:.1e})")
    v, pt, th = st.v, st.pt, th0
    zeta = np.sqrt(st.mu)
    N, n, m = p.N, p.n, p.m
    for _ in range(o.max_restoration_iter):
        setup.limits.check()
        kkt = _diagonal_system(setup, pt, b.sigma(v, st.zl, st.zu) + zeta)
        if not np.all(np.isfinite(kkt.Sx)) or not kkt.try_factor(0.0):
            break       # no step: equality rows the recursion cannot satisfy with this diagonal
        step = kkt.solve(np.zeros((N + 1, n)), np.zeros((N, m)), fns.residuals(setup, pt, v))
        dv = L.pack(step.dX, step.dU, step.ds, step.dsN)
        alpha = b.max_step(v, dv, st.tau)
        while alpha > 1e-12:
            try:
                trial = fns.evaluate(setup, v + alpha * dv, st.clock)
            except NonFiniteEvaluationError:
                alpha *= 0.5
                continue
            if fns.theta(setup, trial, v + alpha * dv) <= (1.0 - 1e-4 * alpha) * th:
                break
            alpha *= 0.5
        else:
            break
        v = v + alpha * dv
        b.move_tiny(v)
        pt, th = trial, fns.theta(setup, trial, v)
        pt.add_derivatives(p)
        phi = fns.barrier_value(setup, pt, v, st.mu, st.s_obj)[0]
        if th <= KAPPA_RESTO * th0 and st.filt.acceptable(th, phi):
            st.v, st.pt = v, pt
            b.move_tiny(v)
            st.zl, st.zu = b.safeguard(v, st.zl, st.zu, st.mu)
            mult = least_squares_multipliers(setup, pt, st.zl, st.zu, st.s_obj)
            if max(float(np.abs(a).max(initial=0.0)) for a in mult) > o.constr_mult_init_max:
                mult = tuple(np.zeros_like(a) for a in mult)
            st.lam, st.nu, st.nuN, st.yd, st.ydN = mult
            return None
    stat = infeasibility_stationarity(setup, fns, pt, v)
    failed = (f"the feasibility restoration could not reduce the constraint violation {th0:.3e} (1-norm) to "
              f"{KAPPA_RESTO} of it inside the bounds (reached {th:.3e})")
    if stat <= INFEASIBLE_TOL:
        return lambda why: (Status.INFEASIBLE,
                            f"{why} after {st.it} iterations, {failed}, and the point is a stationary point of the "
                            f"violation (projected gradient of |c|^2/2 {stat:.1e} relative): the problem is "
                            "locally infeasible")
    return lambda why: (Status.FAILED,
                        f"{why} after {st.it} iterations and {failed}; the point is no stationary point of the "
                        f"violation (projected gradient {stat:.1e} relative), so infeasibility is not shown: "
                        "olado's restoration is not IPOPT's l1 restoration NLP (docs/interior-point-nlp.md)")


#: the relative projected gradient of |c|^2 / 2 below which a failed restoration reports INFEASIBLE
INFEASIBLE_TOL = 1e-4


def infeasibility_stationarity(setup, fns, pt, v):
    """The max-norm of the gradient J^T c of |c|^2 / 2 (c every constraint residual, slacks
    included) projected on the bounds (components pushing out of an active bound dropped),
    relative to max(1, |c|_inf max|J|) -- 0 at a local minimizer of the violation."""
    from types import SimpleNamespace    # noqa: PLC0415

    res = fns.residuals(setup, pt, v)
    lam = np.zeros((pt.X.shape[0], pt.X.shape[1]))
    lam[1:] = res.h
    fake = SimpleNamespace(pt=pt, lam=lam, nu=res.e, nuN=res.eN, yd=res.d, ydN=res.dN, s_obj=0.0)
    g = fns.lagrangian_gradient(setup, fake)
    b = setup.bounds
    sl, su = b.slacks(v)
    act_lo = b.has_lo & (sl <= 1e-6 * np.maximum(1.0, np.abs(v)))
    act_hi = b.has_hi & (su <= 1e-6 * np.maximum(1.0, np.abs(v)))
    g = np.where(act_lo, np.minimum(g, 0.0), g)
    g = np.where(act_hi, np.maximum(g, 0.0), g)
    jmax = max(float(np.abs(a).max(initial=0.0)) for a in (pt.A, pt.B, pt.Cx, pt.Cu, pt.CN))
    return float(np.abs(g).max(initial=0.0)) / max(1.0, res.max() * max(1.0, jmax))


def restore_l1(setup, st, fns: Restoration):
    """IPOPT's restoration phase (sec. 3.3): the l1 restoration problem of
    :mod:`olado.solvers.ipm.elastic` solved by this interior-point method from the current point,
    until an iterate (with the slacks of the inequalities max(g, mu)) is acceptable to the
    original filter with theta at most kappa_resto times its start. Returns None (``st``
    updated) or a function of the reason the line search gave up that returns (Status, message);
    the restoration problem's own line-search failures fall back to the Gauss-Newton phase."""
    from .elastic import ElasticDOCP          # noqa: PLC0415
    from .solver import Setup, initial_state, iterate   # noqa: PLC0415 - the solver module imports this one

    p, o, L = setup.problem, setup.options, setup.layout
    th0 = fns.theta(setup, st.pt, st.v)
    if th0 <= 0.1 * o.constr_viol_tol:
        return restore(setup, st, fns)
    X, U = st.pt.X.copy(), st.pt.U.copy()
    mu = max(st.mu, fns.residuals(setup, st.pt, st.v).max())
    ep = ElasticDOCP(p, X, U, mu)
    opts = dataclasses.replace(o, mu_init=mu, obj_scaling="none", max_iter=o.max_restoration_iter)
    inner = Setup(opts, ep, setup.limits, lambda info: False)
    inner.l1_restoration = False
    ist = initial_state(inner, X, ep.start_controls(X, U, mu), st.clock)
    done, th = False, th0
    while not done:
        if np.sqrt(ist.mu) < ep.zeta:       # the proximity weight follows the restoration's mu (IPOPT)
            ep.zeta = float(np.sqrt(ist.mu))
            ist.pt.J = ep.objective(ist.pt.X, ist.pt.U)
            ist.pt.lx, ist.pt.lu = ep.eval_stage_cost_gradients(ist.pt.X, ist.pt.U)
            ist.pt.lN = ep.eval_final_cost_gradient(ist.pt.X[-1])
        done = iterate(inner, ist)
        Xi, Ui = ist.pt.X, ep.split(ist.pt.U)[0]
        try:
            pt = fns.evaluate(setup, L.pack(Xi, Ui, np.zeros((L.N, L.ni)), np.zeros(L.niN)), st.clock)
        except NonFiniteEvaluationError:
            continue
        v = L.pack(Xi, Ui, np.maximum(pt.g[:, L.ineq], st.mu), np.maximum(pt.gN[L.ineqN], st.mu))
        th = fns.theta(setup, pt, v)
        phi = fns.barrier_value(setup, pt, v, st.mu, st.s_obj)[0]
        if np.isfinite(phi) and th <= KAPPA_RESTO * th0 and st.filt.acceptable(th, phi):
            _return_to_filter_method(setup, st, v, pt)
            return None
    elastic = ep.elastic_sum(ist.pt.U)
    pt.add_derivatives(p)
    stat = infeasibility_stationarity(setup, fns, pt, v) if ist.status.success else np.inf
    if ist.status.success and elastic > 10 * o.constr_viol_tol and stat <= INFEASIBLE_TOL:
        _return_to_filter_method(setup, st, v, pt)
        return lambda why: (Status.INFEASIBLE,
                            f"{why} after {st.it} iterations; the restoration phase converged to a local minimizer "
                            f"of the l1 constraint violation ({elastic:.3e} in the elastic variables, theta "
                            f"{th:.3e}) where the projected gradient of |c|^2/2 is {stat:.1e} (relative): the "
                            "problem is locally infeasible")
    return lambda why: (Status.FAILED,
                        f"{why} after {st.it} iterations and the restoration phase ended without a point "
                        f"acceptable to the filter ({ist.status.value}: {ist.message}; theta {th0:.3e} -> {th:.3e}; "
                        f"projected gradient of |c|^2/2 {stat:.1e}, so infeasibility is not shown)")


def _return_to_filter_method(setup, st, v, pt):
    """Back from the restoration: the new iterate, the bound multipliers kept (safeguarded), the
    constraint multipliers estimated afresh (least squares, 0 when too large)."""
    b, o = setup.bounds, setup.options
    pt.add_derivatives(setup.problem)
    st.v, st.pt = v, pt
    b.move_tiny(v)
    sl, su = b.slacks(v)
    zl = np.where(b.has_lo & (st.zl <= 0), st.mu / sl, st.zl)
    st.zl, st.zu = b.safeguard(v, zl, st.zu, st.mu)
    mult = least_squares_multipliers(setup, pt, st.zl, st.zu, st.s_obj)
    if max(float(np.abs(a).max(initial=0.0)) for a in mult) > o.constr_mult_init_max:
        mult = tuple(np.zeros_like(a) for a in mult)
    st.lam, st.nu, st.nuN, st.yd, st.ydN = mult
