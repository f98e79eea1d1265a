"""Infeasibility certificates of the interior-point QP (docs/qp-interior-point.md,
"Infeasibility"): a Farkas certificate from the multipliers of (16)-(20) for a primal infeasible
QP (14), a recession direction for an unbounded one; strict thresholds at suspicious iterates,
loose ones after a stall.
"""

from __future__ import annotations

import math

from ...result import Status
from .kernels import _cone_violation, _dot, _farkas_kappa, _max_abs

#: the word of a message that marks a stalled solve (InteriorPointQP.solve restarts such a cold start)
STALLED = "stalled"


def certificates(P, it, d, options, loose=False):
    """(status, message) if a certificate of primal or dual infeasibility holds (strict or,
    after a stall, loose thresholds; docs/qp-interior-point.md), else None."""
    eps = 1e-3 if loose else options.infeasibility_tol
    min_quality = 10.0 if loose else 1.0 / options.infeasibility_tol
    xu, lamnu, zlzu = P.part_slices       # (X, U), (lam, nu), (zl, zu): contiguous parts of a point
    z = P.zero_point()
    size_xu = _max_abs(it.v[xu])
    # primal infeasibility: y.constraints(z) = G.z + kappa <= 0 on the feasible set
    if _max_abs(it.v[lamnu]) > 0 or _max_abs(it.v[zlzu]) > 0:
        kappa = _farkas_kappa(it.lam, P.c, P.x0, it.zl, P.lo, it.zu, P.hi, it.nu, P.be, P.eN)
        G = math.inf
        if kappa > 0:   # the constraint gradient only when the certificate can hold
            G = P.linear_parts(z.X, z.U, it.lam, it.nu, it.zl, it.zu)[0]
        scale = 1.0 + size_xu + P.p_data
        if kappa > 0 and kappa >= min_quality * scale * P.n_z * G:
            bound = kappa / (P.n_z * G) if G > 0 else math.inf
            return Status.INFEASIBLE, (
                f"{Status.INFEASIBLE.sentence} Farkas certificate from the multipliers: every point satisfying the "
                f"constraints would have |z|_inf >= {bound:.3g}, {bound / scale:.3g} times the size of the iterate "
                f"and the data{' (loose test after the iterates stalled)' if loose else ''}.")
    # dual infeasibility: a recession direction along which the objective decreases
    cands = []
    if d is not None:
        cands.append(("step", d))
    if size_xu > 1e10 * (1.0 + P.p_data + P.d_data):
        cands.append(("iterate", it))
    for what, p in cands:
        nrm = _max_abs(p.v[xu])
        if not nrm > 0:
            continue
        # the measures of the normalized direction (X, U) / nrm
        gd = _dot(P.qr, p.v[xu]) / nrm
        if gd >= 0:
            continue
        hd, eqs, dw = P.linear_parts(p.X, p.U, z.lam, z.nu, z.zl, z.zu)
        worst = max(hd, eqs, _cone_violation(dw, P.fl, P.fu)) / nrm
        if worst <= eps * -gd:
            return Status.UNBOUNDED, (
                f"{Status.UNBOUNDED.sentence} Certificate: along the normalized {what} direction d the objective "
                f"decreases (g.d = {gd:.3g}) while |H d|, the equality residuals and the bound violations of d "
                f"are at most {worst:.3g}{' (loose test after the iterates stalled)' if loose else ''}.")
    return None

def stall_status(pr, du, gap):
    # Without a certificate a stall is not evidence of infeasibility (a tight tol, a nearly
    # singular or nonconvex Hessian stall too): report it as a numerical difficulty.
    return Status.NUMERICAL_ERROR, (f"{Status.NUMERICAL_ERROR.sentence} The iterates {STALLED} (scaled primal "
                                    f"{pr:.3g}, dual {du:.3g}, gap {gap:.3g}); no infeasibility certificate was found.")
