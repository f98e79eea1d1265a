"""Checking a returned point independently of the solver that produced it: its constraint
violation and a first-order (KKT) residual with least-squares multipliers.

A solver's own ``kkt_residual`` is measured each solver's way (scaled or not, with its own
multipliers, or a reduced gradient). To compare solvers on one scale, :func:`verify_point` takes
only the point (X, U) and computes, on the NLP view (paper 001 eq. (6), :class:`StructuredNLP`),
with the sign convention grad J + Jc^T lam - z_L + z_U = 0 (lam <= 0 on rows g >= 0):

* the violation: the max norm of the dynamics, stage and final constraints and of the bounds
  (x^0 at its fixed value);
* the KKT residual: multipliers for the equality rows and fixed variables (free sign), and for
  the inequality rows and bounds within ``active_tol`` of their bound ("near": lam <= 0 on a row
  g >= 0, z_L, z_U >= 0), all others zero, that minimize the stationarity residual in the least-
  squares sense (a regularized sparse solve of the augmented system); the near one whose
  multiplier comes out with the most wrong sign is dropped and the solve repeated until every
  sign is right (an active-set loop as in NNLS that only drops: an upper bound on the least
  residual). The KKT residual is the larger of the max norm of the stationarity residual and of
  the complementarity products |multiplier x distance to its bound| -- so a bound counted
  "near" while it is not active shows up there. It is reported absolute and divided by
  max(1, |grad J|_inf).

"Near" is within ``active_tol`` relative to 1 + |bound| (default 1e-4: interior-point solvers
stop with the active bounds a small distance away).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["PointCheck", "verify_point"]


@dataclasses.dataclass(frozen=True)
class PointCheck:
    """The outcome of :func:`verify_point`."""

    objective: float
    violation: float
    kkt_residual: float
    kkt_residual_scaled: float
    active_constraints: int
    active_bounds: int


def _near(values, bound, tol):
    finite = np.isfinite(bound)
    fb = np.where(finite, bound, 0.0)
    gap = np.where(finite, np.abs(values - fb), np.inf)
    return finite & (gap <= tol * (1.0 + np.abs(fb))), gap


def _least_squares(A, g, reg=1e-12):
    """mu minimizing |g + A mu|^2 + reg |mu|^2 from the augmented system (sparse LU)."""
    n, k = A.shape
    if k == 0:
        return np.zeros(0)
    # r = g + A mu and the optimality A^T r + reg mu = 0:  [-I A; A^T reg I] [r; mu] = [-g; 0]
    K = sp.bmat([[-sp.identity(n), A], [A.T, reg * sp.identity(k)]], format="csc")
    rhs = np.concatenate([-g, np.zeros(k)])
    return spla.splu(K).solve(rhs)[n:]


def _signed_least_squares(A, g, sign, max_rounds=2000):
    """Least-squares multipliers with sign[j] in {0 (free), -1 (<= 0), +1 (>= 0)}: the column with
    the most wrong sign is dropped and the solve repeated until every sign is right (see the
    module docstring)."""
    keep = np.ones(A.shape[1], dtype=bool)
    mu = np.zeros(A.shape[1])
    for _ in range(max_rounds):
        idx = np.flatnonzero(keep)
        mu[:] = 0.0
        mu[idx] = _least_squares(A[:, idx], g)
        wrong = np.where(keep, sign * mu, 0.0)
        j = int(np.argmin(wrong))
        if wrong[j] >= 0:
            break
        keep[j] = False
    mu[~keep] = 0.0
    return mu


def verify_point(problem, X, U, *, active_tol=1e-4) -> PointCheck:
    """Objective, violation and least-squares KKT residual of the point (X, U) of ``problem``
    (see the module docstring)."""
    from ..nlp import StructuredNLP

    nlp = StructuredNLP(problem)
    y = nlp.pack(X, U)
    c = nlp.constraints(y)
    g = nlp.gradient(y)
    cl, cu = nlp.constraint_bounds()
    lb, ub = nlp.variable_bounds()
    eq = cl == cu
    lo_act, lo_gap = _near(c, cl, active_tol)
    hi_act, hi_gap = _near(c, cu, active_tol)
    lo_act &= ~eq
    hi_act &= ~eq & ~lo_act
    fixed = lb == ub
    at_lo, gap_lo = _near(y, lb, active_tol)
    at_hi, gap_hi = _near(y, ub, active_tol)
    at_lo &= ~fixed
    at_hi &= ~fixed & ~at_lo
    rows = np.flatnonzero(eq | lo_act | hi_act)
    n = y.size
    eye = sp.identity(n, format="csc")
    blocks = [(nlp.jacobian_matrix(y).T.tocsc()[:, rows], np.where(eq[rows], 0, np.where(lo_act[rows], -1, 1)),
               np.where(lo_act[rows], lo_gap[rows], np.where(hi_act[rows], hi_gap[rows], 0.0))),
              (eye[:, np.flatnonzero(fixed)], np.zeros(int(fixed.sum())), np.zeros(int(fixed.sum()))),
              (-eye[:, np.flatnonzero(at_lo)], np.ones(int(at_lo.sum())), gap_lo[at_lo]),
              (eye[:, np.flatnonzero(at_hi)], np.ones(int(at_hi.sum())), gap_hi[at_hi])]
    A = sp.hstack([b[0] for b in blocks]).tocsc()
    sign = np.concatenate([b[1] for b in blocks])
    gaps = np.concatenate([b[2] for b in blocks])
    mu = _signed_least_squares(A, g, sign)
    r = g + A @ mu
    stat = float(np.max(np.abs(r), initial=0.0))
    compl = float(np.max(np.abs(mu) * gaps, initial=0.0))
    kkt = max(stat, compl)
    return PointCheck(objective=float(nlp.objective(y)), violation=float(nlp.max_violation(y, c)),
                      kkt_residual=kkt, kkt_residual_scaled=kkt / max(1.0, float(np.max(np.abs(g), initial=0.0))),
                      active_constraints=int(np.sum((sign[:rows.size] != 0) & (mu[:rows.size] != 0))),
                      active_bounds=int(np.sum(mu[rows.size + int(fixed.sum()):] != 0)))
