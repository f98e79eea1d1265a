"""The least-squares multiplier estimate of the start (Waechter and Biegler 2006, sec. 3.6,
eq. (36)) and the feasibility restoration phase (sec. 3.3), both as LQ-DOCPs on the Riccati
back-end.

Restoration: olado's phase is not IPOPT's l1 restoration NLP (eq. (30)) but a sequence of
minimum-distance Gauss-Newton steps towards the linearized dynamics,

    min 1/2 d^T (Sigma + zeta I) d   s.t.  J_h d = -h,        zeta = sqrt(mu)

(the proximity term of (30) with D_R = I and the barrier's Sigma keeping the bounds at a
distance), with the fraction-to-boundary rule and backtracking on theta -- one Riccati
factorization per step, always positive definite. It returns to the filter method once theta has
fallen to kappa_resto = 0.9 of its value at the start of the phase and the point is acceptable to
the filter (sec. 3.3); the multipliers are then estimated afresh (least squares), the bound
multipliers kept. The theory of sec. 2 allows any restoration procedure that reduces theta; a
phase that cannot (a point where J_h d = -h has no step inside the bounds) reports the problem as
locally infeasible.
"""

from __future__ import annotations

import numpy as np

from ...errors import NonFiniteEvaluationError
from ...linalg.backend import make_kkt_solver
from ...result import Status
from .barrier import pack, unpack

KAPPA_RESTO = 0.9


def least_squares_multipliers(p, pt, zl, zu, s_obj):
    """The dynamics multipliers minimizing |grad (s_f J) + J_h^T lam - z_L + z_U|_2 (eq. (36)): the
    LQ-DOCP with Q = I, R = I and zero offsets, solved by one Riccati recursion."""
    N, n, m = p.N, p.n, p.m
    dz = zu - zl
    bx, bu = unpack(dz, np.zeros(n), N, n, m)
    q = np.empty((N + 1, n)); q[:-1] = pt.lx; q[-1] = pt.lN
    q = s_obj * q + bx
    r = s_obj * pt.lu + bu
    kkt = make_kkt_solver("riccati", np.zeros((N + 1, n, n)), None, np.zeros((N, m, m)), pt.A, pt.B,
                          Dx=np.ones((N + 1, n)), Du=np.ones((N, m)))
    return kkt.solve(q, r, np.zeros((N, n)), np.zeros(n)).lam


def restore(setup, st, evaluate, theta, barrier_value):
    """The restoration phase at the current iterate (the filter already augmented by it). On
    success the iterate, lam and the bound multipliers are updated in ``st`` and None is
    returned; otherwise a function of the reason the line search gave up that returns
    (Status, message)."""
    p, b, o = setup.problem, setup.bounds, setup.options
    N, n, m = p.N, p.n, p.m
    th0 = theta(st.pt)
    if th0 <= 0.1 * o.constr_viol_tol:
        return lambda why: (Status.NUMERICAL_ERROR,
                            f"{why} at a feasible point (constraint violation {th0:.2e}) after {st.it} iterations: "
                            f"no acceptable step along the Newton direction (scaled optimality error "
                            f"{st.errors[0]:.2e}, mu = {st.mu:.1e})")
    v, pt, th = st.v, st.pt, th0
    zeta = np.sqrt(st.mu)
    for k in range(o.max_restoration_iter):
        setup.limits.check()
        sig = b.sigma(v, st.zl, st.zu) + zeta
        Sx, Su = unpack(sig, np.zeros(n), N, n, m)
        Sx[0] = 0.0
        kkt = make_kkt_solver("riccati", np.zeros((N + 1, n, n)), None, np.zeros((N, m, m)), pt.A, pt.B, Dx=Sx, Du=Su)
        sol = kkt.solve(np.zeros((N + 1, n)), np.zeros((N, m)), pt.h, np.zeros(n))
        dv = pack(sol.X, sol.U)
        alpha = b.max_step(v, dv, st.tau)
        while alpha > 1e-12:
            try:
                trial = evaluate(setup, v + alpha * dv, st.clock)
            except NonFiniteEvaluationError:
                alpha *= 0.5
                continue
            if theta(trial) <= (1.0 - 1e-4 * alpha) * th:
                break
            alpha *= 0.5
        else:
            break
        v, pt, th = v + alpha * dv, trial, theta(trial)
        pt.add_derivatives(p)
        phi = barrier_value(setup, pt, v, st.mu, st.s_obj)[0]
        if th <= KAPPA_RESTO * th0 and st.filt.acceptable(th, phi):
            st.v, st.pt = v, pt
            st.zl, st.zu = b.safeguard(v, st.zl, st.zu, st.mu)
            lam = least_squares_multipliers(p, pt, st.zl, st.zu, st.s_obj)
            st.lam = lam if float(np.abs(lam).max(initial=0.0)) <= o.constr_mult_init_max else np.zeros_like(lam)
            return None
    return lambda why: (Status.INFEASIBLE,
                        f"{why} after {st.it} iterations and the feasibility restoration could not reduce the "
                        f"dynamics violation {th0:.3e} (1-norm) to {KAPPA_RESTO} of it while staying inside the "
                        f"bounds (reached {th:.3e}): the problem looks locally infeasible")
