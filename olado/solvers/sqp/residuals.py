"""KKT quantities of the SQP, computed stage by stage from the stage data of a
:class:`~olado.solvers.sqp.state.Point` (cost gradients, dynamics and constraint Jacobians) and
the multipliers per stage -- the NLP (6) of paper 001 is never assembled.

Stationarity of the Lagrangian (eq. (28) of :mod:`olado.solvers.common`, IPOPT's signs)

    grad J + Jc^T lam - z_L + z_U = 0,     c = (h, g, gN),  h^k = f^k(x^k, u^k) - x^{k+1},

reads per stage, with lam^{k+1} the multiplier of h^k (``Multipliers.lam[k+1]``):

    x^k (0 < k < N):  l_x^k + A_k^T lam^{k+1} + C_x^k^T Lg^k - lam^k - z_L + z_U
    x^0:              l_x^0 + A_0^T lam^1 + C_x^0^T Lg^0 - z_L + z_U      (x^0 fixed)
    u^k:              l_u^k + B_k^T lam^{k+1} + C_u^k^T Lg^k - z_L + z_U
    x^N:              F_x + C^N^T LgN - lam^N - z_L + z_U

:func:`kkt_residual` is the SQP's convergence measure (x^1..x^N and u, x^0 left out);
:func:`stage_kkt` gives the Result's residuals, which agree with
:func:`olado.solvers.common.build_result` on the NLP view to rounding (tests/solvers/sqp).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ...problems.nlp import nlp_counts
from ...result import Result
from ..common import (EVALUATION_KINDS, MULTIPLIER_CONVENTION, bound_complementarity, einsum_sequential,
                      stage_gradient_terms)
from .state import BoundMultipliers


def kkt_residual(p, pt, mult, bounds):
    """Max-norm of the NLP stationarity over x^1..x^N and u (x^0 is fixed), and the gradient
    scale max|grad J|, at pt with the multipliers ``mult`` and bound multipliers ``bounds``.
    One compiled pass (olado.solvers.sqp.kernels.kkt_residual, the same arithmetic) where numpy's
    einsum sums in the kernel's order; the numpy form otherwise."""
    from . import kernels

    if einsum_sequential(p.n, p.m):     # (the Point's arrays are float64: olado.problems.docp)
        gN0 = pt.lN + pt.CN.T @ mult.LgN if p.rN else pt.lN
        return kernels.kkt_residual(pt.lx, pt.lu, gN0, pt.A, pt.B, pt.Cx, pt.Cu, mult.lam, mult.Lg, *bounds, pt.lN)
    return kkt_residual_reference(p, pt, mult, bounds)


def kkt_residual_reference(p, pt, mult, bounds):
    """:func:`kkt_residual` in numpy (the reference of the compiled pass)."""
    lam = mult.lam
    gz, gN = pt.lagrangian_gradients(mult)
    n = p.n
    gx = gz[:, :n].copy(); gu = gz[:, n:]
    gx[1:] -= lam[1:-1]                      # the -lam_{k}.x_k term of the previous dynamics row
    gN = gN - lam[-1]
    zl_x, zu_x, zl_u, zu_u = bounds
    gx = gx - zl_x[:-1] + zu_x[:-1]
    gN = gN - zl_x[-1] + zu_x[-1]
    gu = gu - zl_u + zu_u
    res = max(float(np.abs(gx[1:]).max(initial=0.0)), float(np.abs(gu).max(initial=0.0)),
              float(np.abs(gN).max(initial=0.0)))
    scale = max(float(np.abs(pt.lx).max(initial=0.0)), float(np.abs(pt.lu).max(initial=0.0)),
                float(np.abs(pt.lN).max(initial=0.0)))
    return res, scale


class StageKKT(NamedTuple):
    """KKT quantities at a point: max-norms of stationarity and complementarity, the constraint
    violation (constraints and bounds, x^0 against its fixed value), and the bound multipliers
    with those of the fixed variables (lb == ub, x^0 among them) filled in."""

    stationarity: float
    complementarity: float
    violation: float
    bounds: BoundMultipliers


def _bounds(p):
    """Per-stage variable bounds of the NLP view: x^0 fixed at x0."""
    xl = p.x_lower.copy(); xu = p.x_upper.copy()
    xl[0] = p.x0; xu[0] = p.x0
    return xl, xu, p.u_lower, p.u_upper


def _gradient_terms(p, pt, mult):
    """grad J + Jc^T lam per stage, without the bound multipliers: (rx (N+1, n), ru (N, m))."""
    return stage_gradient_terms(p, pt, mult.lam[1:], mult.Lg, mult.LgN)


def _fill_fixed(r, lo, hi, zl, zu):
    """Fixed variables (lo == hi) get z_L = max(r, 0), z_U = max(-r, 0) (their multiplier is
    free in sign), so that their stationarity residual vanishes."""
    fixed = lo == hi
    return np.where(fixed, np.maximum(r, 0.0), zl), np.where(fixed, np.maximum(-r, 0.0), zu)


def _violation(c_parts, y_parts):
    """Max-norm violation of cl <= c <= cu (``c_parts``: (c, cu) pairs, cl = 0) and of the
    variable bounds (``y_parts``: (y, lb, ub))."""
    v = 0.0
    for c, cu in c_parts:
        if c.size:
            v = max(v, float(np.max(np.maximum(0.0 - c, 0.0))), float(np.max(np.maximum(c - cu, 0.0))))
    for y, lo, hi in y_parts:
        v = max(v, float(np.max(np.maximum(lo - y, 0.0), initial=0.0)), float(np.max(np.maximum(y - hi, 0.0), initial=0.0)))
    return v


def stage_complementarity(p, pt, mult, bounds):
    """Max-norm of the complementarity and multiplier-sign errors at pt (WORHP's conditions [4]-[5],
    seed 000 sec. IV.II): |z_L (y - lb)|, |z_U (ub - y)| and negative parts of z on the free
    variables, |Lg g| and positive parts of Lg on the rows g >= 0 (their multipliers are <= 0).
    One compiled pass (olado.solvers.sqp.kernels.complementarity: maxima, exact in any order)."""
    from . import kernels

    ineq, ineqN = ~p.stage_equality_mask, ~p.final_equality_mask
    return kernels.complementarity(pt.X, p.x_lower, p.x_upper, pt.U, p.u_lower, p.u_upper, *bounds, mult.Lg,
                                   pt.g, ineq, mult.LgN, pt.gN, ineqN)


def stage_complementarity_reference(p, pt, mult, bounds):
    """:func:`stage_complementarity` in numpy (the reference of the compiled pass)."""
    xl, xu, ul, uu = _bounds(p)
    parts = [0.0]
    parts += bound_complementarity(pt.X, xl, xu, bounds.zl_x, bounds.zu_x) + bound_complementarity(pt.U, ul, uu, bounds.zl_u, bounds.zu_u)
    ineq, ineqN = ~p.stage_equality_mask, ~p.final_equality_mask
    for lam, g in ((mult.Lg[:, ineq], pt.g[:, ineq]), (mult.LgN[ineqN], pt.gN[ineqN])):
        if lam.size:      # rows g >= 0: |lam g| and the positive part of lam (it must be <= 0)
            parts += [float(np.max(np.abs(lam * g))), float(np.max(np.maximum(lam, 0.0)))]
    return max(parts)


def stage_kkt(p, pt, mult, bounds) -> StageKKT:
    """The Result's KKT quantities at pt (values and derivatives evaluated) with the stage
    multipliers ``mult`` and bound multipliers ``bounds`` (see the module docstring): the
    numbers of :func:`stage_kkt_reference`, the fixed variables' multipliers, the stationarity
    and the violation in one compiled pass (olado.solvers.certificate_kernels.stage_kkt)."""
    c = np.ascontiguousarray
    xl, xu, ul, uu = (c(a, dtype=float) for a in _bounds(p))
    rx, ru = _gradient_terms(p, pt, mult)
    X, U, h, g, gN = (c(a, dtype=float) for a in (pt.X, pt.U, pt.h, pt.g, pt.gN))
    z = tuple(c(a, dtype=float) for a in bounds)
    if not (xl.shape == X.shape == z[0].shape == z[1].shape and ul.shape == U.shape == z[2].shape == z[3].shape
            and h.ndim == 2 and g.ndim == 2 and gN.ndim == 1):
        return stage_kkt_reference(p, pt, mult, bounds)
    filled = BoundMultipliers(*(np.empty_like(a) for a in (X, X, U, U)))
    out, rows = np.empty(5), np.empty(2)
    kernels = _certificate_kernels()
    kernels.stage_kkt(c(rx), c(ru), X, U, xl, xu, ul, uu, *z, *filled, out)
    viol = 0.0                  # Python's max over the arrays' maxima (NaN ones add nothing), in _violation's order
    for values, eq in ((h, None), (g, p.stage_equality_mask), (gN[None, :], p.final_equality_mask)):
        if values.size:         # max(0 - c, 0) and max(c - cu, 0): cu = 0 (dynamics, equality rows) or inf
            upper = np.zeros(values.shape) if eq is None else np.ascontiguousarray(
                np.broadcast_to(np.where(eq, 0.0, np.inf), values.shape))
            kernels.violation_maxima(np.zeros(values.shape), values, upper, rows)
            viol = max(viol, float(rows[0]), float(rows[1]))
    viol = max(viol, *(float(v) for v in out[1:]))
    return StageKKT(float(out[0]), stage_complementarity(p, pt, mult, filled), viol, filled)


def _certificate_kernels():
    from .. import certificate_kernels   # noqa: PLC0415 - numba is loaded on the first solve

    return certificate_kernels


def stage_kkt_reference(p, pt, mult, bounds) -> StageKKT:
    """:func:`stage_kkt` in numpy (the reference of the compiled pass)."""
    xl, xu, ul, uu = _bounds(p)
    rx, ru = _gradient_terms(p, pt, mult)
    zl_x, zu_x = _fill_fixed(rx, xl, xu, bounds.zl_x, bounds.zu_x)
    zl_u, zu_u = _fill_fixed(ru, ul, uu, bounds.zl_u, bounds.zu_u)
    stat = max(float(np.max(np.abs(rx - zl_x + zu_x), initial=0.0)), float(np.max(np.abs(ru - zl_u + zu_u), initial=0.0)))
    filled = BoundMultipliers(zl_x, zu_x, zl_u, zu_u)
    compl = stage_complementarity(p, pt, mult, filled)
    upper = (np.zeros_like(pt.h), np.where(p.stage_equality_mask, 0.0, np.inf), np.where(p.final_equality_mask, 0.0, np.inf))
    viol = _violation(zip((pt.h, pt.g, pt.gN), upper), ((pt.X, xl, xu), (pt.U, ul, uu)))
    return StageKKT(stat, compl, viol, filled)


def finish(setup, st, info) -> Result:
    """The Result at the last iterate with the multipliers of the last QP: KKT quantities stage
    by stage (:func:`stage_kkt`), the SQP's own KKT residual as ``kkt_residual``."""
    p = setup.problem
    solve_time = time.perf_counter() - setup.t_start
    kkt = stage_kkt(p, st.pt, st.mult, st.bounds)
    clock = st.clock
    info = dict(info)
    info.update(
        callback_time_s=clock.time_s,
        solve_time_s=solve_time,
        callback_share=(clock.time_s / solve_time) if solve_time > 0 else float("nan"),
        kkt_residual_kind="max-norm NLP stationarity at the final point with the QP multipliers (olado SQP)",
        stationarity_residual=kkt.stationarity,
        complementarity_residual=kkt.complementarity,
        multiplier_convention=MULTIPLIER_CONVENTION,
        nlp=nlp_counts(p),
    )
    z = kkt.bounds
    multipliers = {"dynamics": st.mult.lam[1:].copy(), "stage_constraints": st.mult.Lg.copy(),
                   "final_constraints": st.mult.LgN.copy(), "bound_lower_x": z.zl_x, "bound_lower_u": z.zl_u,
                   "bound_upper_x": z.zu_x, "bound_upper_u": z.zu_u}
    res = Result(status=st.status, message=st.message, objective=float(st.pt.J), x=st.pt.X.copy(),
                 u=st.pt.U.copy(), multipliers=multipliers, max_constraint_violation=kkt.violation,
                 kkt_residual=float(st.kkt_res), iterations=int(st.it),
                 evaluations={k: int(clock.counts[k]) for k in EVALUATION_KINDS}, history=list(st.history),
                 info=info, certificate=st.certificate)
    res.qp_iterations = st.qp_iters
    return res
