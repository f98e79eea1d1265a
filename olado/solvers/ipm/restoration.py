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
