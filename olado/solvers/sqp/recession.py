"""Unboundedness of the SQP iterates: UNBOUNDED as a status of its own.

The QP's own certificate (olado/qp/interior_point/certificates.py: a direction d of the QP's
feasible cone along which the objective falls, g.d < 0, while |H d| vanishes) rarely reaches the
SQP: the proximal term and the inertia correction make every QP Hessian positive definite, so
the QP is bounded and its step just grows along the recession direction (a linear cost on a
control that nothing else sees took the steps 5e4 long, iteration after iteration, to
MAX_ITERATIONS). The SQP therefore tests the same certificate on the model of the *unshifted*
QP at the iterate, along its normalized step d = s / |s|_inf:

    g.d < 0   and   max(|H d|, |A d_x + B d_u - d_x+|, |E d|, |d_x0|, (C d)^-, bound violations of d)
                    <= ``recession_tol`` * |g.d|,  and with the exact Hessian also
                    <= |g.d| / (REACH (1 + |y|_inf))

(H the Lagrangian Hessian blocks without shift or proximal term, E the equality rows, C the
inequality rows g >= 0, a bound violated when d points out of a finite bound: the recession cone
of the linearized feasible set). The second bound is the scale-aware one: with |H d| ~ d'Hd the
model's minimizer along d lies at a distance |g.d| / d'Hd >= REACH (1 + |y|_inf), far beyond the
iterate's own size. The relative test alone called the badly scaled lq-box at N = 200 (unstable
dynamics, J ~ 1e19 at the start, |y| ~ 1.6e9, |g.d| ~ 3e10 against |H d| ~ 10: the model's
minimum two iterate sizes away) UNBOUNDED although it is a convex QP bounded below; a truly
unbounded problem has |H d| at rounding level (1e-12 at |y| ~ 1e6 in tests/fixtures'
UnboundedBelow), which a bound relative to |y| with recession_tol itself (1e-6 / |y|) would
reject. A quasi-Newton Hessian's curvature along a direction the iterates have only just explored
is no evidence either way (block SR1 on UnboundedBelow: |H d| ~ 1e-8 at |y| ~ 1e8, so the model's
minimum sits one iterate size away at every step), so the second bound needs the exact Hessian.
When it holds at ``unbounded_steps`` consecutive accepted steps
from feasible iterates (violation <= constr_viol_tol (1 + |y|_inf): the iterates grow, and the
QP's accuracy with them), each of which decreased the objective, the SQP ends with status UNBOUNDED
and a sentence; so does a QP that reports UNBOUNDED itself at a feasible iterate after a step that
decreased the objective.
"""

from __future__ import annotations

import numpy as np

#: the QP model's minimizer along a direction of recession lies at least this many times the
#: iterate's size (1 + |y|_inf) away (module docstring)
REACH = 100.0


def certificate(p, pt, Bk, BN, masks, dX, dU):
    """(slope g.d, worst residual) of the normalized step d = (dX, dU) / |(dX, dU)|_inf as a
    direction of recession of the unshifted QP model at pt (module docstring); None when the
    step is zero."""
    nrm = max(float(np.max(np.abs(dX))), float(np.max(np.abs(dU))))
    if not nrm > 0.0:
        return None
    dx, du = dX / nrm, dU / nrm
    slope = float(np.sum(pt.lx * dx[:-1]) + np.sum(pt.lu * du) + pt.lN @ dx[-1])
    z = np.concatenate([dx[:-1], du], axis=1)
    worst = max(float(np.max(np.abs(np.einsum("kij,kj->ki", Bk, z)))), float(np.max(np.abs(BN @ dx[-1]))),
                float(np.max(np.abs(np.einsum("kij,kj->ki", pt.A, dx[:-1]) + np.einsum("kij,kj->ki", pt.B, du)
                                    - dx[1:]))), float(np.max(np.abs(dx[0]))))
    eq, ineq, eqN, ineqN = masks
    if p.r:
        Cd = np.einsum("kij,kj->ki", pt.Cx, dx[:-1]) + np.einsum("kij,kj->ki", pt.Cu, du)
        worst = max(worst, float(np.max(np.abs(Cd[:, eq]), initial=0.0)),
                    float(np.max(np.maximum(-Cd[:, ineq], 0.0), initial=0.0)))
    if p.rN:
        CNd = pt.CN @ dx[-1]
        worst = max(worst, float(np.max(np.abs(CNd[eqN]), initial=0.0)),
                    float(np.max(np.maximum(-CNd[ineqN], 0.0), initial=0.0)))
    for d, lo, hi in ((dx[1:], p.x_lower[1:], p.x_upper[1:]), (du, p.u_lower, p.u_upper)):
        out = np.where(np.isfinite(lo), np.maximum(-d, 0.0), 0.0) + np.where(np.isfinite(hi), np.maximum(d, 0.0), 0.0)
        worst = max(worst, float(np.max(out, initial=0.0)))
    return slope, worst


def size(pt):
    """|y|_inf of the iterate."""
    return max(float(np.max(np.abs(pt.X))), float(np.max(np.abs(pt.U))))


def feasible(setup, pt, viol):
    """Feasible for this test: violation <= constr_viol_tol (1 + |y|_inf) (the iterates grow)."""
    return viol <= setup.options.constr_viol_tol * (1.0 + size(pt))


def count(setup, st, step, J_new):
    """Update the count of consecutive accepted steps along directions of recession (module
    docstring); returns the sentence of an UNBOUNDED end, or None."""
    o, p = setup.options, setup.problem
    holds = False
    if feasible(setup, st.pt, step.viol) and J_new < st.pt.J:
        cert = certificate(p, st.pt, st.Bk, st.BN, setup.masks, step.dX, step.dU)
        holds = cert is not None and cert[0] < 0.0 and cert[1] <= o.recession_tol * -cert[0]
        if holds and st.hess.needs_exact:
            holds = cert[1] * REACH * (1.0 + size(st.pt)) <= -cert[0]
    st.recession_steps = st.recession_steps + 1 if holds else 0
    if holds and st.recession_steps >= o.unbounded_steps:
        slope, worst = cert
        return (f"the problem appears unbounded below: the last {st.recession_steps} accepted steps from feasible "
                f"iterates decreased the objective to {J_new:.6g}, each along a direction of recession d of the QP "
                f"model at its iterate (slope g.d = {slope:.3g}, while |H d|, the linearized constraint residuals "
                f"and the bound violations along d are at most {worst:.3g})")
    return None
