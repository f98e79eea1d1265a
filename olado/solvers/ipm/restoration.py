"""The least-squares multiplier estimate of the start (Waechter and Biegler 2006, sec. 3.6,
eq. (36)) and the feasibility restoration phases (sec. 3.3), on the Riccati back-end
(:class:`~olado.solvers.ipm.newton.KKTMatrix`).

``restore_l1`` (the default, ``restoration = l1``) is IPOPT's phase: the l1 restoration problem
(30) of :mod:`olado.solvers.ipm.elastic`, solved by this interior-point method, with IPOPT's
start, its convergence test on the original point and its return (bound-multiplier step of the
whole phase, constraint multipliers 0); a converged restoration problem at a positive violation
is a stationary point of the l1 violation: INFEASIBLE (docs/interior-point-nlp.md).

``restore`` (``restoration = gauss-newton``; also the restoration problem's own phase) is
olado's earlier phase, minimum-distance Gauss-Newton steps towards the linearized constraints,

    min 1/2 d^T (Sigma + zeta I) d   s.t.  J d = -c,        zeta = sqrt(mu)

(the proximity term of (30) with D_R = I, the barrier's Sigma keeping the bounds at a distance;
c every constraint residual, slacks included), with the fraction-to-boundary rule and
backtracking on theta -- one Riccati factorization per step, always positive definite. It
returns to the filter method once theta has fallen to kappa_resto = 0.9 of its value at the
start of the phase and the point is acceptable to the filter; the multipliers are then estimated
afresh (least squares), the bound multipliers kept. It reports INFEASIBLE only at a stationary
point of |c|^2 / 2 on the bounds.
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


def least_squares_multipliers(setup, pt, zl, zu, s_obj, hand_over=False):
    """The constraint multipliers minimizing the 2-norm of the Lagrangian's gradient (eq. (36)):
    the LQ-DOCP with identity Hessian and zero constraint offsets, one Riccati recursion.
    Returns (lam (N+1, n), nu, nuN, yd, ydN). With ``hand_over`` (the start of a solve) the
    factored matrix becomes ``setup.last_kkt``: the first Newton matrix takes its back-end over
    (newton.KKTMatrix's ``reuse``; it sets every block and factors afresh), as the later ones take
    their predecessor's, instead of building one of its own."""
    p, L = setup.problem, setup.layout
    N, n = p.N, p.n
    kkt = _diagonal_system(setup, pt, np.ones(L.size))
    kkt.try_factor(0.0)
    dz = zu - zl
    bx, bu, vs, vsN = L.split(dz, np.zeros(n))
    q = np.empty((N + 1, n)); q[:-1] = pt.lx; q[-1] = pt.lN
    zero = Residuals(np.zeros((N, n)), np.zeros((N, L.ne)), np.zeros(L.neN), np.zeros((N, L.ni)), np.zeros(L.niN))
    step = kkt.solve(s_obj * q + bx, s_obj * pt.lu + bu, zero, vs, vsN)     # gs = -v_L: vs = zu - zl = -zl
    if hand_over:
        setup.last_kkt = kkt
    return step.lam, step.nu, step.nuN, step.yd, step.ydN


def largest_multiplier(mult):
    """max((float(np.abs(a).max(initial=0.0)) for a in mult), default=0.0), the same float (the
    test against constr_mult_init_max): Python's max (the first value, then each larger one), an
    empty array's value 0.0 without a reduction (for another, max |a| is its max(initial=0.0))."""
    largest = 0.0
    for i, a in enumerate(mult):
        x = float(np.abs(a).max()) if a.size else 0.0
        if i == 0 or x > largest:
            largest = x
    return largest


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
            if largest_multiplier(mult) > o.constr_mult_init_max:
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


#: IPOPT's bound_mult_reset_threshold: bound multipliers above it after the restoration phase are reset to 1
BOUND_MULT_RESET = 1e3
#: IPOPT's theta_max_fact of the restoration problem (resto.theta_max_fact)
RESTO_THETA_MAX_FACT = 1e8


@dataclasses.dataclass
class L1Phase:
    """One l1 restoration phase: the restoration problem ``ep``, its solver set-up and state, and
    the original iterate's values the phase is judged against (theta, phi, max-norm violation)."""

    ep: object
    inner: object
    ist: object
    theta0: float
    phi0: float
    inf_pr0: float


def restore_l1(setup, st, fns: Restoration):
    """IPOPT's restoration phase (sec. 3.3; IPOPT's MinC_1NrmRestorationPhase and
    RestoConvergenceCheck): the l1 restoration problem of :mod:`olado.solvers.ipm.elastic`,
    solved by this interior-point method from the current point. At every iterate of the
    restoration problem but its start, the original problem's point (x, u and the slacks s of
    the restoration problem) ends the phase when its max-norm violation is at most max(kappa_resto
    times the one where the phase started, min(tol, constr_viol_tol)) and it is acceptable to the
    original filter and to the original iterate (sufficient decrease of theta or phi, eq. (18));
    the bound multipliers then take the Newton step of the whole phase, the constraint multipliers
    start at 0. If instead the restoration problem converges (its own optimality test, eq. (5)),
    the point is a stationary point of the l1 violation: INFEASIBLE when the violation there
    exceeds 100 tol (after the restoration's tolerance was once tightened by 100), otherwise a
    FAILED restoration (a feasible point the filter does not accept). Returns None (``st``
    updated) or a function of the reason the line search gave up that returns (Status, message).
    The restoration's iterations count as iterations (IPOPT's count)."""
    o = setup.options
    res0 = fns.residuals(setup, st.pt, st.v)
    if res0.l1() <= 0.1 * o.constr_viol_tol:
        return restore(setup, st, fns)
    phase = _start_l1_phase(setup, st, fns, res0)
    try:
        return _run_l1_phase(setup, st, fns, phase)
    finally:
        st.it += phase.ist.it


def _start_l1_phase(setup, st, fns, res0) -> L1Phase:
    """The restoration problem at the current point and its starting iterate (IPOPT's
    RestoIterateInitializer): mu = max(mu, |c|_inf, |d - s|_inf); x, u and the slacks as they are;
    the elastic variables of eq. (33); the bound multipliers min(rho, z) on the original
    variables and mu / p, mu / n on the elastic ones; the constraint multipliers 0."""
    from .elastic import RHO, ElasticDOCP   # noqa: PLC0415
    from .filter import Filter              # noqa: PLC0415
    from .solver import IPMState, Setup     # noqa: PLC0415 - the solver module imports this one

    p, o, L = setup.problem, setup.options, setup.layout
    X, U, s, sN = L.split(st.v)
    mu = max(st.mu, res0.max())
    ep = ElasticDOCP(p, st.pt.X, st.pt.U, mu)
    Xe, Ue = ep.start(st.pt.X, st.pt.U, res0, mu)
    opts = dataclasses.replace(o, mu_init=mu, obj_scaling="none", max_iter=max(o.max_iter - st.it, 0),
                               restoration="gauss-newton")
    inner = Setup(opts, ep, setup.limits, lambda info: False)
    _share_bounds(setup, inner)
    v = inner.layout.pack(Xe, Ue, s, sN)
    pt = fns.evaluate(inner, v, st.clock, derivatives=True)
    zl = _start_bound_multipliers(setup, inner, st.zl, Ue, mu, RHO)
    zu = _start_bound_multipliers(setup, inner, st.zu, None, mu, RHO)
    N, Li = p.N, inner.layout
    ist = IPMState(v=v, pt=pt, lam=np.zeros((N + 1, ep.n)), zl=zl, zu=zu, mu=mu, tau=max(o.tau_min, 1.0 - mu),
                   filt=Filter.start(fns.theta(inner, pt, v), theta_max_fact=RESTO_THETA_MAX_FACT), s_obj=1.0,
                   clock=st.clock, nu=np.zeros((N, Li.ne)), nuN=np.zeros(Li.neN), yd=np.zeros((N, Li.ni)),
                   ydN=np.zeros(Li.niN))
    inner.on_mu_change = lambda: _follow_mu(ep, ist)
    phi0 = fns.barrier_value(setup, st.pt, st.v, st.mu, st.s_obj)[0]
    return L1Phase(ep, inner, ist, res0.l1(), phi0, res0.max())


def _share_bounds(setup, inner):
    """The restoration problem's bounds on x, u and the slacks are the original problem's as they
    are now (relaxed, and moved by slack_move, barrier.Bounds.move_tiny), so that the current point
    is inside them."""
    L, Li, n0, m0 = setup.layout, inner.layout, setup.layout.n, setup.layout.m
    for side in ("lo", "hi"):
        X, U, s, sN = L.split(getattr(setup.bounds, side), np.zeros(n0))
        Xe, Ue, _, _ = Li.split(getattr(inner.bounds, side), np.zeros(Li.n))
        Xe[:, :n0], Ue[:, :m0] = X, U
        setattr(inner.bounds, side, Li.pack(Xe, Ue, s, sN))


def _start_bound_multipliers(setup, inner, z, Ue, mu, rho):
    """The restoration problem's bound multipliers of one side: min(rho, z) on the original
    variables and slacks, mu / value on the elastic controls (lower side, ``Ue`` given), 0 where
    the side is infinite."""
    L, Li = setup.layout, inner.layout
    n0, m0 = L.n, L.m
    Xz, Uz, sz, szN = L.split(np.minimum(z, rho), np.zeros(n0))
    Xe = np.zeros((L.N + 1, Li.n)); Xe[:, :n0] = Xz
    Uel = np.zeros((L.N, Li.m)); Uel[:, :m0] = Uz
    if Ue is not None:
        Uel[:, m0:] = mu / Ue[:, m0:]
    has = inner.bounds.has_lo if Ue is not None else inner.bounds.has_hi
    return np.where(has, Li.pack(Xe, Uel, sz, szN), 0.0)


def _follow_mu(ep, ist):
    """The proximity weight zeta = sqrt(mu) follows the restoration's barrier parameter (IPOPT's
    RestoIpoptNLP): the objective and its gradient at the current point again."""
    ep.zeta = float(np.sqrt(ist.mu))
    pt = ist.pt
    pt.J = ep.objective(pt.X, pt.U)
    if pt.derivs:
        pt.lx, pt.lu = ep.eval_stage_cost_gradients(pt.X, pt.U)
        pt.lN = ep.eval_final_cost_gradient(pt.X[-1])


def _original_point(setup, fns, phase, clock):
    """The original problem's (v, point, residuals) at the restoration's iterate: its x, u and the
    slacks s; None where a function is not finite."""
    L = setup.layout
    Xe, Ue, s, sN = phase.inner.layout.split(phase.ist.v)
    v = L.pack(Xe[:, :L.n], Ue[:, :L.m], s, sN)
    try:
        pt = fns.evaluate(setup, v, clock)
    except NonFiniteEvaluationError:
        return None
    return v, pt, fns.residuals(setup, pt, v)


def _acceptable(setup, st, fns, phase, point):
    """IPOPT's RestoConvergenceCheck: the max-norm violation reduced to max(kappa_resto times its
    start, min(tol, constr_viol_tol)), then acceptable to the original filter and to the original
    iterate (RestoFilterConvergenceCheck::TestOrigProgress)."""
    o = setup.options
    v, pt, res = point
    if res.max() > max(KAPPA_RESTO * phase.inf_pr0, min(o.tol, o.constr_viol_tol)):
        return False
    th, phi = res.l1(), fns.barrier_value(setup, pt, v, st.mu, st.s_obj)[0]
    return bool(np.isfinite(phi) and st.filt.acceptable(th, phi)
                and st.filt.acceptable_to_iterate(phase.theta0, phase.phi0, th, phi))


def _run_l1_phase(setup, st, fns, phase):
    """The restoration problem's iterations with the convergence test of :func:`restore_l1`."""
    from .solver import iterate              # noqa: PLC0415

    o, ist, inner = setup.options, phase.ist, phase.inner
    first = True
    while True:
        point = None if first else _original_point(setup, fns, phase, st.clock)
        if not first:
            _record(st, phase, point)
        if point is not None and _acceptable(setup, st, fns, phase, point):
            _return_to_filter_method(setup, st, *point[:2])
            return None
        first = False
        if not iterate(inner, ist):
            continue
        point = _original_point(setup, fns, phase, st.clock)
        if not ist.status.success or point is None:
            break
        inf_pr = point[2].max()
        if inf_pr <= 1e2 * inner.options.tol and inner.options.tol > 0.1 * o.tol:
            # once: the restoration problem solved more tightly when the violation is small (IPOPT)
            inner.options = dataclasses.replace(inner.options, tol=1e-2 * inner.options.tol)
            ist.status, ist.acceptable = Status.MAX_ITERATIONS, 0
            continue
        return _converged_outcome(setup, st, phase, point)
    return _failed_outcome(setup, st, fns, phase, point)


def _record(st, phase, point):
    """The history entry of an iteration of the restoration problem (IPOPT's "r" lines): its step,
    mu and shift, with the original problem's objective and max-norm violation at the new point."""
    ist = phase.ist
    entry = dict(ist.history[-1], iter=st.it + ist.it, restoration=True, watchdog=False)
    if point is not None:
        entry.update(objective=float(point[1].J), inf_pr=point[2].max())
    st.history.append(entry)


def _converged_outcome(setup, st, phase, point):
    """The restoration problem converged without a point the filter method accepts: INFEASIBLE at
    a violation above 100 tol (a stationary point of the l1 violation: the restoration's
    optimality error (5) is the l1 problem's stationarity, its multipliers bounded by rho), else
    FAILED (IPOPT's RESTORATION_CONVERGED_TO_FEASIBLE_POINT)."""
    ist, inner = phase.ist, phase.inner
    v, pt, res = point
    inf_pr, l1 = res.max(), res.l1()
    e0 = ist.errors[0]
    _adopt_restoration_point(setup, st, phase, v, pt)
    st.infeasibility_certificate = {
        "restoration_optimality_error": float(e0), "restoration_tol": float(inner.options.tol),
        "restoration_status": ist.status.value, "max_violation": float(inf_pr), "l1_violation": float(l1),
        "elastic_sum": phase.ep.elastic_sum(ist.pt.X, ist.pt.U)}
    if inf_pr <= 1e2 * inner.options.tol:
        return lambda why: (Status.FAILED,
                            f"{why} after {st.it} iterations; the restoration phase converged to a point of "
                            f"small violation ({inf_pr:.2e}, max-norm) that the filter does not accept")
    level = (f"<= tol = {inner.options.tol:g}" if ist.status is Status.SUCCESS else
             f"<= acceptable_tol = {inner.options.acceptable_tol:g}, IPOPT's acceptable level")
    return lambda why: (Status.INFEASIBLE,
                        f"{why} after {st.it} iterations; the restoration phase converged (scaled optimality "
                        f"error of the l1 restoration problem {e0:.1e} {level}) to a stationary "
                        f"point of the l1 constraint violation where it is {l1:.3e} (largest residual "
                        f"{inf_pr:.3e}): the problem is locally infeasible")


def _failed_outcome(setup, st, fns, phase, point):
    """The restoration problem stopped without converging: MAX_ITERATIONS at its iteration limit,
    otherwise FAILED, the sentence naming its status."""
    ist = phase.ist
    if point is not None:
        _adopt_restoration_point(setup, st, phase, *point[:2])
    th = fns.theta(setup, st.pt, st.v)
    status = Status.MAX_ITERATIONS if ist.status is Status.MAX_ITERATIONS else Status.FAILED
    return lambda why: (status,
                        f"{why} after {st.it} iterations and the restoration phase ended without a point "
                        f"acceptable to the filter ({ist.status.value}: {ist.message}; constraint violation "
                        f"{phase.theta0:.3e} -> {th:.3e}, 1-norm), so infeasibility is not shown")


def _adopt_restoration_point(setup, st, phase, v, pt):
    """The restoration's last point becomes the iterate the solve returns (IPOPT copies it), with
    the restoration problem's multipliers: the constraint multipliers y of the l1 problem (|y| <=
    rho, y = rho sign(c) on a violated equality row) and its bound multipliers, multiplied by s_f
    so that the Result (which divides by s_f) holds them as they are."""
    L, Li, ist = setup.layout, phase.inner.layout, phase.ist
    pt.add_derivatives(setup.problem)
    st.v, st.pt = v, pt
    f = st.s_obj
    st.lam = f * ist.lam[:, :L.n]
    st.nu, st.nuN, st.yd, st.ydN = f * ist.nu, f * ist.nuN, f * ist.yd, f * ist.ydN
    zl, zu = [], []
    for z in (ist.zl, ist.zu):
        Xz, Uz, sz, szN = Li.split(z, np.zeros(Li.n))
        (zl if z is ist.zl else zu).append(f * L.pack(Xz[:, :L.n], Uz[:, :L.m], sz, szN))
    st.zl, st.zu = zl[0], zu[0]


def _return_to_filter_method(setup, st, v, pt):
    """Back from the restoration (IPOPT's MinC_1NrmRestorationPhase): the new iterate; the bound
    multipliers as if the whole phase were one primal-dual Newton step (eq. (13) with dv the
    phase's change of v, the fraction-to-boundary rule (15)), all reset to 1 when one exceeds
    bound_mult_reset_threshold = 1e3; the constraint multipliers 0 (constr_mult_reset_threshold
    = 0)."""
    b = setup.bounds
    pt.add_derivatives(setup.problem)
    dzl, dzu = b.dual_step(st.v, v - st.v, st.zl, st.zu, st.mu)
    alpha = min(b.max_dual_step(st.zl, dzl, st.tau), b.max_dual_step(st.zu, dzu, st.tau))
    zl, zu = st.zl + alpha * dzl, st.zu + alpha * dzu
    if max(float(np.abs(zl).max(initial=0.0)), float(np.abs(zu).max(initial=0.0))) > BOUND_MULT_RESET:
        zl, zu = b.has_lo.astype(float), b.has_hi.astype(float)
    st.v, st.pt, st.zl, st.zu = v, pt, zl, zu
    b.move_tiny(v)
    st.lam, st.nu, st.nuN, st.yd, st.ydN = (np.zeros_like(a) for a in (st.lam, st.nu, st.nuN, st.yd, st.ydN))
