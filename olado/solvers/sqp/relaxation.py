"""The relaxed QP of the SQP method for inconsistent linearizations (WORHP, seed 000 sec. IV.III
and step A-6.1 of its algorithm, sec. IV.VII), on the stage QP: when the QP (8)-(10) at the
iterate is found infeasible, its elastic form (olado.qp.elastic: a nonnegative slack per row and
side, charged at the penalty eta) is solved instead. It is always feasible, and its solution is
the QP's whenever eta exceeds that QP's multipliers, so a feasible problem is never declared
infeasible from one linearization.

Penalty update (A-6.1: "if delta >= min(1, delta_max) increase eta_r = rho_r eta_r and solve the
QP again"): with one slack per row the relaxation is measured by

    delta = (l1 violation of the linearized constraints at the step) / (l1 violation at s = 0)

(the dynamics counted, exact at the step), delta = 1 meaning that the step does not reduce the
linearized violation at all. eta starts from ``elastic_penalty`` (1 + |grad J|), the last eta
used, and never below the current merit weights: then Powell's update gives weights rho <= eta,
rho = eta on every row with a positive slack, and the step is a descent direction of the L1 merit
function whose directional derivative counts the linearized violation left at the step,

    D = grad J . s - sum rho v(c) + sum rho v(c + J s)      (v: the violation of a row)

(Fletcher's Sl1QP; for a consistent QP the last sum is zero and D is (18.29) of Nocedal & Wright).
eta grows tenfold while the step removes less than ``elastic_progress`` of the linearized
violation -- or, when that is more than any step can remove, of what the feasibility QP (no
gradient, the largest penalty ``elastic_penalty_max`` (1 + |grad J|)) removes: the steering rule
of Byrd, Nocedal & Waltz (2008) in the place of delta_max. When not even the feasibility QP
reduces the linearized violation at a point whose dynamics hold, the iterate is a stationary point
of the l1 violation of the other constraints as a function of the controls, and the SQP ends
INFEASIBLE (olado.solvers.sqp.restoration.infeasible, which also asks for a positive violation).
With a dynamics residual this proves nothing (the step must remove that residual whatever it costs
the other rows): the SQP simulates the states from the controls, or starts the restoration phase
(olado.solvers.sqp.phases.qp_phase).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import step as qp_step


class Relaxed(NamedTuple):
    """The relaxed QP's solve (a :class:`~olado.solvers.sqp.step.QPSolve` with slacks; its
    result may have failed), its penalty eta, the l1 violation of the linearized constraints at
    s = 0, the reduction the step achieves, and the largest reduction any step achieves (the
    feasibility QP's; nan when it was not needed)."""

    solve: qp_step.QPSolve
    eta: float
    violation0: float
    progress: float
    best: float = float("nan")

    dynamics_residual: float = 0.0

    @property
    def irreducible(self) -> bool:
        """No step with exact linearized dynamics reduces the linearized violation."""
        return self.best == self.best and self.best <= STATIONARY_RTOL * self.violation0

    @property
    def stationary(self) -> bool:
        """No step reduces the linearized violation, at a point whose dynamics hold (to
        STATIONARY_RTOL of the violation): a stationary point of the l1 violation of the path,
        final and bound constraints along the simulated states (the states are functions of the
        controls there, and the relaxed QP's linearization is that function's). With a dynamics
        residual, irreducibility proves nothing (the restoration phase decides)."""
        return self.irreducible and self.dynamics_residual <= STATIONARY_RTOL * self.violation0


#: the linearized l1 violation counts as irreducible when the best step removes at most this
#: fraction of it
STATIONARY_RTOL = 1e-9


def gradient_norm(pt):
    """max |grad J| at pt."""
    return max(float(np.max(np.abs(a), initial=0.0)) for a in (pt.lx, pt.lu, pt.lN))


def linearized_violation0(violations):
    """The l1 violation at s = 0 of the constraints the relaxed QP linearizes: all of them (the
    merit's violation arrays); its dynamics rows and control bounds are exact, so the reduction
    a step achieves is this minus the sum of its slacks."""
    return float(sum(np.sum(v) for v in violations))


def start_penalty(setup, st):
    """eta of the first relaxed QP at this iterate: elastic_penalty (1 + |grad J|), the last eta
    used, and at least what the merit function's weights ask for (the largest exact-penalty
    weight; the largest multiplier estimate of the augmented Lagrangian: Merit.elastic_floor)."""
    o = setup.options
    return max(o.elastic_penalty * (1.0 + gradient_norm(st.pt)), st.eta, setup.merit.elastic_floor(st.rho))


def largest_penalty(setup, st):
    return max(start_penalty(setup, st), setup.options.elastic_penalty_max * (1.0 + gradient_norm(st.pt)))


def feasibility_qp(setup, st, Bk, BN, delta, eta=None, inertia=None, u_box=None, relax_dynamics=False):
    """The feasibility QP: the relaxed QP without the objective's gradient, min eta sum(slacks) +
    1/2 s.H s; at the largest penalty (default) the step that removes the most linearized
    violation (the shortest such step in the Hessian's norm). With ``relax_dynamics`` the dynamics
    rows are relaxed too: its slacks are then the l1 model of *every* constraint's violation, so
    "no step reduces it" is a first-order stationary point of the l1 violation theta (with exact
    dynamics rows and a dynamics residual at the point, the best step may make the model worse
    than s = 0, which proves nothing)."""
    return qp_step.solve_qp(setup, st, st.pt, Bk, BN, delta, inertia=setup.inertia if inertia is None else inertia,
                            eta=largest_penalty(setup, st) if eta is None else eta, zero_gradient=True,
                            u_box=u_box, relax_dynamics=relax_dynamics)


def solve_relaxed(setup, st, Bk, BN, delta, u_box=None):
    """The relaxed QP at the iterate with the penalty update of the module docstring (WORHP
    A-6.1 with the steering rule of Byrd, Nocedal & Waltz 2008: eta grows until the step removes
    ``elastic_progress`` of the linearized violation, or of what the feasibility QP removes when
    that is less); returns a :class:`Relaxed`. ``u_box``: the control steps' trust region
    (olado.solvers.sqp.trust; the l1 model is convex, so "no step in the box reduces it" is
    still its stationarity)."""
    o = setup.options
    v0 = linearized_violation0(setup.merit.violations(st.pt))
    eta, eta_max = start_penalty(setup, st), largest_penalty(setup, st)
    target, best, iterations = o.elastic_progress * v0, float("nan"), 0
    while True:
        qs = qp_step.solve_qp(setup, st, st.pt, Bk, BN, delta, inertia=setup.inertia, eta=eta, u_box=u_box)
        iterations += qs.iterations
        if not qs.result.success:
            return Relaxed(qs._replace(iterations=iterations), eta, v0, 0.0, best)
        progress = v0 - qs.slacks.total()
        if progress >= target or eta >= eta_max or qs.slacks.largest() <= o.constr_viol_tol:
            return Relaxed(qs._replace(iterations=iterations), eta, v0, progress, best)
        if best != best:   # too little progress: what is possible at all?
            fs = feasibility_qp(setup, st, Bk, BN, qs.delta, u_box=u_box)
            iterations += fs.iterations
            if not fs.result.success:
                return Relaxed(fs._replace(iterations=iterations), eta_max, v0, 0.0, best)
            best = v0 - fs.slacks.total()
            if best <= STATIONARY_RTOL * v0:
                return Relaxed(fs._replace(iterations=iterations), eta_max, v0, best, best,
                               float(np.sum(np.abs(st.pt.h))))
            target = min(target, o.elastic_progress * best)
            if progress >= target:
                return Relaxed(qs._replace(iterations=iterations), eta, v0, progress, best)
        eta = min(10.0 * eta, eta_max)
        delta = qs.delta
