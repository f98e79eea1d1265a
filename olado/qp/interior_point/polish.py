"""Solution polishing of the interior-point QP (docs/qp-interior-point.md, "Polishing"): an
ACCEPTABLE result's active set held at its bounds and the equality-constrained QP (14) solved
exactly, as OSQP polishes (Stellato et al. 2020), in interior-point form.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...linalg.riccati import RiccatiStatusError
from ...result import Status
from ..stageqp import BOX_FIELDS, box_values, qp_kkt_residuals
from .presolve import _equal_bounds


def polish(solver, qp, res, limits=None):
    """Polish an ACCEPTABLE result of ``solver`` (see the ``polish`` option): every side of a box on which
    the multiplier exceeds the slack at ``res`` is taken as active; the QP with the active
    sides as equal bounds (fixed controls are eliminated, fixed states and rows become
    equality rows) and the inactive sides dropped is an equality-constrained QP, solved in
    one Newton step. Sides that its solution violates are added and it is solved again (at
    most ``polish_rounds`` solves). The result, with the multipliers of the equal bounds put
    back on the active sides, replaces ``res`` if it meets ``tol`` (stationarity, primal,
    complementarity) with multipliers of the right sign; else None (``res`` stays)."""
    opts = solver.options
    tol = opts.tol
    inf = np.inf
    vals = box_values(qp, res.X, res.U)
    fixed, act = {}, {}
    for key, lo_name, hi_name, zl_name, zu_name in BOX_FIELDS:
        lo, hi, val = getattr(qp, lo_name), getattr(qp, hi_name), vals[key]
        fixed[key] = _equal_bounds(lo, hi)
        aL = np.isfinite(lo) & ~fixed[key] & (getattr(res, zl_name) > val - lo)
        aU = np.isfinite(hi) & ~fixed[key] & (getattr(res, zu_name) > hi - val) & ~aL
        if key == "x":
            aL[0] = aU[0] = False          # x_0 is fixed by its own row
        act[key] = [aL, aU]
    inner = type(solver)(solver.options, polish=False, max_iter=5, stall_restart_mu=1.0)
    r2, extra = None, 0
    for _ in range(opts.polish_rounds):
        kw = {}
        for key, lo_name, hi_name, _, _ in BOX_FIELDS:
            lo, hi = getattr(qp, lo_name), getattr(qp, hi_name)
            aL, aU = act[key]
            kw[lo_name] = np.where(fixed[key] | aL, lo, np.where(aU, hi, -inf))
            kw[hi_name] = np.where(fixed[key] | aU, hi, np.where(aL, lo, inf))
            if key == "x":
                kw[lo_name][0], kw[hi_name][0] = lo[0], hi[0]
        try:
            r2 = inner.solve(dataclasses.replace(qp, **kw), limits=limits)
        except (np.linalg.LinAlgError, FloatingPointError, ValueError, ArithmeticError, RiccatiStatusError):
            return None
        if not r2.success:
            return None
        extra += r2.iterations
        vals = box_values(qp, r2.X, r2.U)
        violated = False
        for key, lo_name, hi_name, _, _ in BOX_FIELDS:
            v = vals[key]
            slack = tol * (1.0 + np.abs(v))
            vL, vU = v < getattr(qp, lo_name) - slack, v > getattr(qp, hi_name) + slack
            if key == "x":
                vL[0] = vU[0] = False
            if vL.any() or vU.any():
                violated = True
                act[key][0] |= vL
                act[key][1] |= vU & ~act[key][0]
        if not violated:
            break
    else:
        return None
    # the multipliers of the equal bounds (net lower minus upper) back on the active sides
    mult = {}
    for key, _, _, zl_name, zu_name in BOX_FIELDS:
        zl2, zu2 = getattr(r2, zl_name), getattr(r2, zu_name)
        aL, aU = act[key]
        net = zl2 - zu2
        mult[zl_name] = np.where(fixed[key], zl2, np.where(aL, net, 0.0))
        mult[zu_name] = np.where(fixed[key], zu2, np.where(aU, -net, 0.0))
    pol = dataclasses.replace(r2, **mult, history=res.history, iterations=res.iterations + extra,
                              solver=res.solver, regularization=res.regularization)
    kkt = qp_kkt_residuals(qp, pol)
    d_scale = 1.0 + max(float(np.max(np.abs(qp.q), initial=0.0)), float(np.max(np.abs(qp.r), initial=0.0)))
    p_scale = 1.0 + max(float(np.max(np.abs(qp.c), initial=0.0)), float(np.max(np.abs(qp.x0), initial=0.0)),
                        float(np.max(np.abs(pol.X), initial=0.0)), float(np.max(np.abs(pol.U), initial=0.0)))
    if not (kkt["stationarity"] <= tol * d_scale and kkt["dual_sign"] <= tol * d_scale
            and kkt["primal"] <= tol * p_scale and kkt["complementarity"] <= tol * (1.0 + abs(pol.objective))):
        return None
    pol.kkt = kkt
    pol.status = Status.SUCCESS
    pol.message = (f"{Status.SUCCESS.sentence} Polished ({extra} Newton steps on the active set of the best "
                   f"iterate, counted in the iterations) after: {res.message}")
    return pol
