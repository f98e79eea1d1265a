"""The filter line search of the interior-point solver (:mod:`olado.solvers.ipm.solver`;
Waechter and Biegler 2006, Math. Program. 106, 25-57, sec. 2.3-2.4, Algorithm A steps A-5 to A-8;
docs/interior-point-nlp.md): the Newton direction at an iterate and its line-search quantities,
the trial points, backtracking with second-order corrections (eqs. (26)-(27)), and IPOPT's watchdog.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from ...errors import NonFiniteEvaluationError
from ..sqp.state import Point
from .barrier import _kernels, dot
from .evaluation import _residual_entry, barrier_value, residuals, theta
from .newton import Direction, KKTMatrix, Residuals

#: IPOPT's tiny step: max |dv| / (1 + |v|) below this (10 eps) takes the step without a line search
TINY_STEP = 10 * np.finfo(float).eps


def _trial(setup, st, dv, alpha):
    """The trial point v + alpha dv of the iterate: (v_t, point, theta, phi); (v_t, None, inf, inf)
    when a function is not finite there. v_t and its (X, U) (the workspace's trial arrays) are
    made in one compiled pass (kernels.trial_point), the point evaluated as :func:`.evaluation.evaluate` does,
    its theta, max-norm (cached with its residuals) and phi in another (barrier.Bounds.point_terms)."""
    L = setup.layout
    v_t, X, U, slacks = setup.ws.trial_arrays(st.v)
    setup.bounds.forget(v_t)
    _kernels().trial_point(st.v, dv, alpha, L.x0, v_t, X, U)
    try:
        pt = Point(setup.problem, X, U, derivatives=False, clock=st.clock)
    except NonFiniteEvaluationError:
        return v_t, None, math.inf, math.inf
    entry = _residual_entry(setup, pt, v_t)
    l1, mx, barrier = setup.bounds.point_terms(v_t, entry[2], st.mu, slacks)
    entry[3] = (l1, mx)
    return v_t, pt, l1, st.s_obj * pt.J + barrier


def step_vector(setup, step):
    return setup.layout.pack(step.dX, step.dU, step.ds, step.dsN)


class Search(NamedTuple):
    """A Newton direction at an iterate and the quantities its line search compares against:
    the system and right-hand side (for second-order corrections), the residuals, the step, dv,
    grad phi . dv, theta, phi and the largest step by the fraction-to-boundary rule."""

    kkt: KKTMatrix
    g: Direction
    res: Residuals
    step: object
    dv: np.ndarray
    gphi: float
    theta: float
    phi: float
    alpha_max: float
    tiny: float = math.inf


@dataclasses.dataclass
class Watchdog:
    """IPOPT's watchdog (watchdog_shortened_iter_trigger, watchdog_trial_iter_max): the iterate
    and search where it started and the trial steps taken since."""

    state: dict
    search: Search
    trials: int = 1


WATCHED = ("v", "pt", "lam", "nu", "nuN", "yd", "ydN", "zl", "zu", "mu", "tau")


def direction(setup, st, kkt, g) -> Search:
    """The Newton direction at the iterate and its line-search quantities."""
    res = residuals(setup, st.pt, st.v)
    out, dv = setup.ws.step()
    step = kkt.solve(g.q, g.r, res, g.gs, g.gsN, out=out)
    # step_vector, Bounds.max_step and the tiny-step measure in one compiled pass
    dv, alpha_max, tiny = setup.bounds.step_terms(st.v, step, st.tau, dv)
    phi = barrier_value(setup, st.pt, st.v, st.mu, st.s_obj)[0]
    return Search(kkt, g, res, step, dv, dot(g.grad, dv), theta(setup, st.pt, st.v), phi, alpha_max, tiny)


def line_search(setup, st, kkt, g):
    """The filter line search with second-order corrections (sec. 2.3-2.4, Algorithm A steps
    A-5 to A-8) and IPOPT's watchdog. Returns the accepted step (v_new, pt_new, dv, newton step,
    alpha, soc) or None (alpha fell below alpha_min: restoration)."""
    o = setup.options
    d = direction(setup, st, kkt, g)
    if d.tiny < TINY_STEP:     # IPOPT's tiny-step rule: no line search for a step below rounding
        v_t, pt_t, _, _ = _trial(setup, st, d.dv, d.alpha_max)
        if pt_t is not None:
            return v_t, pt_t, d.dv, d.step, d.alpha_max, 0
    if st.watch is None and o.watchdog_shortened_iter_trigger and st.shortened >= o.watchdog_shortened_iter_trigger:
        st.watch = Watchdog({k: getattr(st, k) for k in WATCHED}, d)
        setup.ws.detach()           # the watchdog keeps the search's arrays
        st.shortened = 0
        step = _watchdog_step(setup, st, d)
        if step is not None:
            return step
        st.watch = None
    elif st.watch is not None:
        step = _watched_trial(setup, st, d)
        if step is not None:
            return step
        d = st.watch.search           # the watchdog gives up: back to where it started
        for k, val in st.watch.state.items():
            setattr(st, k, val)
        st.watch = None
    return backtrack(setup, st, d)


def _watchdog_step(setup, st, d):
    """A full step taken without the acceptance test (IPOPT's "w" iteration); None when the
    functions are not finite there."""
    v_t, pt_t, _, _ = _trial(setup, st, d.dv, d.alpha_max)
    return None if pt_t is None else (v_t, pt_t, d.dv, d.step, d.alpha_max, 0)


def _watched_trial(setup, st, d):
    """In the watchdog: the full step, accepted (and the watchdog ended) when the filter accepts it
    against the watchdog's starting point; else another "w" step while watchdog_trial_iter_max
    allows; None: the watchdog fails and the line search starts again from its starting point."""
    ref = st.watch.search
    v_t, pt_t, th_t, phi_t = _trial(setup, st, d.dv, d.alpha_max)
    # the tests use the watched point's values and step to the boundary (IPOPT's watchdog_alpha_primal_test)
    ok, f_type = st.filt.accept(ref.alpha_max, ref.theta, ref.phi, ref.gphi, th_t, phi_t)
    if ok:
        if not f_type:
            st.filt.add(ref.theta, ref.phi)
        st.watch = None
        return v_t, pt_t, d.dv, d.step, d.alpha_max, 0
    if pt_t is not None and st.watch.trials < setup.options.watchdog_trial_iter_max:
        st.watch.trials += 1
        return v_t, pt_t, d.dv, d.step, d.alpha_max, 0
    return None


def backtrack(setup, st, d: Search):
    """Backtracking from alpha_max by halves to alpha_min (23), with second-order corrections
    after a rejected first trial that increased theta."""
    o = setup.options
    th, phi, gphi = d.theta, d.phi, d.gphi
    alpha_min = st.filt.alpha_min(th, gphi)
    alpha, trials = d.alpha_max, 0
    while alpha > alpha_min or trials == 0:     # the first trial always (IPOPT)
        setup.limits.check()
        trials += 1
        v_t, pt_t, th_t, phi_t = _trial(setup, st, d.dv, alpha)
        ok, f_type = st.filt.accept(alpha, th, phi, gphi, th_t, phi_t)
        if ok:
            if not f_type:
                st.filt.add(th, phi)
            st.shortened = st.shortened + 1 if trials > 1 else 0
            return v_t, pt_t, d.dv, d.step, alpha, 0
        if trials == 1 and pt_t is not None and th_t >= th and o.max_soc:
            soc = second_order_correction(setup, st, d.kkt, d.g, d.res, alpha, (th, phi, gphi), pt_t, v_t, th_t)
            if soc is not None:
                st.shortened = 0
                return soc
        alpha *= 0.5
    return None


def second_order_correction(setup, st, kkt, g, res, alpha_max, current, pt_t, v_t, th_t):
    """Second-order corrections (sec. 2.4): the system solved again with the constraint offsets
    c_soc = alpha c(y) + c(y_trial) (accumulated, eq. (27)), at most max_soc times while each
    reduces theta by kappa_soc."""
    o, b = setup.options, setup.bounds
    th, phi, gphi = current
    c_soc = res.combine(alpha_max, residuals(setup, pt_t, v_t))
    th_old = th_t
    for k in range(o.max_soc):
        step = kkt.solve(g.q, g.r, c_soc, g.gs, g.gsN)
        dv = step_vector(setup, step)
        a_soc = b.max_step(st.v, dv, st.tau)
        v_s, pt_s, th_s, phi_s = _trial(setup, st, dv, a_soc)
        if pt_s is None:
            return None
        ok, f_type = st.filt.accept(alpha_max, th, phi, gphi, th_s, phi_s)
        if ok:
            if not f_type:
                st.filt.add(th, phi)
            return v_s, pt_s, dv, step, a_soc, k + 1
        if th_s > o.kappa_soc * th_old:
            return None
        th_old = th_s
        c_soc = c_soc.combine(a_soc, residuals(setup, pt_s, v_s))
    return None
