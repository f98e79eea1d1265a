"""The equality-constrained QP of a working set of bounds (paper 001 sec. 4.2.3: an LQ-DOCP
solved by the block Riccati recursion), for a :class:`~olado.qp.stageqp.StageQP` whose only
inequalities are simple bounds.

The bounded quantities are w = (x_1..x_N, u_0..u_{N-1}) (x_0 is fixed by x0), the ordering of
the active-set and interior-point QPs. A working set fixes some entries of w at one of their
bounds (``side``: 0 free, -1 lower, +1 upper, 2 a fixed variable, lo = hi).

* A fixed control u_k,i = b leaves the recursion: its column of S_k, B_k and its row and column
  of R_k are moved into the linear terms (q_k += S_k[:, i] b, r_k += R_k[:, i] b, c_k += B_k[:, i] b)
  and replaced by the decoupled equation d u_k,i = d b. With fixed controls only, the EQP is
  solved by the plain Riccati recursion (no equality rows) on these modified blocks.
* A fixed state x_k,i = b is an equality row e_i^T x_k - b = 0 at stage k (E_N on x_N), passed
  back through the dynamics by Arnold's elimination of the general recursion: a state is not a
  free variable of the recursion (x_{k+1} follows from x_k, u_k), so it cannot simply be dropped.

Every bound's multiplier is read off the stationarity residual of the unconstrained Lagrangian
(no bound terms) with the original blocks: for a free entry it is 0 (up to rounding), for a
fixed one it is minus the bound's multiplier; so no multiplier of the recursion's rows is
needed and its sign convention does not enter.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...linalg.riccati import RiccatiFactorization

_FIX_RTOL = 1e-12


class Boxes:
    """The bounds of ``qp`` on w (module docstring): lo, hi, the fixed entries (finite lo = hi), the
    finite sides of the others, ``scale`` = 1 + |bound| per side, and ``bad``, a sentence naming
    a box whose lower bound lies above its upper one (None if none)."""

    def __init__(self, qp):
        N, n = qp.N, qp.n
        self.N, self.n, self.m, self.nx = N, n, qp.m, N * n
        lo = np.concatenate([qp.x_lower[1:].ravel(), qp.u_lower.ravel()])
        hi = np.concatenate([qp.x_upper[1:].ravel(), qp.u_upper.ravel()])
        with np.errstate(invalid="ignore"):
            gap = hi - lo
            self.fixed = np.isfinite(lo) & np.isfinite(hi) & (gap <= _FIX_RTOL * (1 + np.abs(lo)))
            bad = np.nonzero(gap < -_FIX_RTOL * (1 + np.abs(lo)))[0]
        self.bad = None if not bad.size else f"lower bound above upper bound for {self.name(int(bad[0]))}"
        self.lo, self.hi = lo, np.where(self.fixed, lo, hi)
        self.has_lo = np.isfinite(lo) & ~self.fixed
        self.has_hi = np.isfinite(hi) & ~self.fixed
        self.scale_lo = 1.0 + np.abs(np.where(np.isfinite(lo), lo, 0.0))
        self.scale_hi = 1.0 + np.abs(np.where(np.isfinite(hi), hi, 0.0))

    def name(self, j):
        """'x[k, i]' or 'u[k, i]' of the entry w_j."""
        if j < self.nx:
            return f"x[{j // self.n + 1}, {j % self.n}]"
        j -= self.nx
        return f"u[{j // self.m}, {j % self.m}]"

    def values(self, X, U):
        """w at (X, U)."""
        return np.concatenate([X[1:].ravel(), U.ravel()])


class EQPPoint(NamedTuple):
    """The minimizer of a working set's EQP: X, U, the dynamics multipliers lam (QPResult
    convention), v = -(stationarity residual without bound terms) on w (the bound multiplier:
    zu - zl), and the consistency defect of the fixed states' rows (0 when consistent)."""

    X: np.ndarray
    U: np.ndarray
    lam: np.ndarray
    v: np.ndarray
    defect: float


def _eliminate_controls(qp, au, bu):
    """(q, r, c, R, S, B) with the fixed controls (mask au, values bu) moved out of the blocks
    (module docstring)."""
    q, r, c = qp.q.copy(), qp.r.copy(), qp.c.copy()
    if not au.any():
        return q, r, c, qp.R, qp.S, qp.B
    b = np.where(au, bu, 0.0)
    q[:-1] += np.einsum("kij,kj->ki", qp.S, b)
    r += np.einsum("kij,kj->ki", qp.R, b)
    c += np.einsum("kij,kj->ki", qp.B, b)
    keep = (~au).astype(float)
    R = qp.R * keep[:, :, None] * keep[:, None, :]
    S = qp.S * keep[:, None, :]
    B = qp.B * keep[:, None, :]
    k, i = np.nonzero(au)
    d = np.maximum(1.0, np.abs(qp.R[k, i, i]))
    R[k, i, i] = d
    r[k, i] = -d * bu[k, i]
    return q, r, c, np.ascontiguousarray(R), np.ascontiguousarray(S), np.ascontiguousarray(B)


def _state_rows(N, n, m, ax, bx):
    """The fixed states (mask ax (N, n) over x_1..x_N, values bx) as equality rows: keyword
    arguments of the Riccati factorization (E, F, n_eq, EN) and of its solve (e, eN)."""
    fact_kw, rhs_kw = {}, {}
    ks, iS = np.nonzero(ax[:-1])
    if ks.size:
        counts = np.bincount(ks + 1, minlength=N)
        cap = int(counts.max())
        slot = np.arange(ks.size) - np.searchsorted(ks, ks, side="left")
        E, F, e = np.zeros((N, cap, n)), np.zeros((N, cap, m)), np.zeros((N, cap))
        E[ks + 1, slot, iS] = 1.0
        e[ks + 1, slot] = -bx[ks, iS]
        fact_kw.update(E=E, F=F, n_eq=counts)
        rhs_kw["e"] = e
    iN = np.nonzero(ax[-1])[0]
    if iN.size:
        fact_kw["EN"] = np.eye(n)[iN]
        rhs_kw["eN"] = -bx[-1, iN]
    return fact_kw, rhs_kw


def solve_eqp(qp, boxes, side) -> EQPPoint:
    """The EQP of ``qp`` with the entries of w whose ``side`` is not 0 fixed at their bound (the
    lower one for -1 and 2, the upper one for +1). Raises NotPositiveDefiniteError when the
    reduced Hessian of the working set is not positive definite at some stage."""
    N, n, m, nx = qp.N, qp.n, qp.m, boxes.nx
    act = side != 0
    val = np.where(side == 1, boxes.hi, boxes.lo)
    ax, bx = act[:nx].reshape(N, n), val[:nx].reshape(N, n)
    au, bu = act[nx:].reshape(N, m), val[nx:].reshape(N, m)
    q, r, c, R, S, B = _eliminate_controls(qp, au, bu)
    fact_kw, rhs_kw = _state_rows(N, n, m, ax, bx)
    sol = RiccatiFactorization(qp.Q, S, R, qp.A, B, **fact_kw).solve(q, r, c, qp.x0, **rhs_kw)
    X, U, lam = sol.X, sol.U, sol.lam
    U[au] = bu[au]
    return EQPPoint(X, U, lam, -stationarity(qp, X, U, lam), float(sol.x0_residual))


def stationarity(qp, X, U, lam):
    """The gradient of the QP's Lagrangian without bound terms (dynamics and x_0 rows only) with
    respect to w = (x_1..x_N, u), at (X, U, lam)."""
    gx = (np.einsum("kij,kj->ki", qp.Q[1:-1], X[1:-1]) + np.einsum("kij,kj->ki", qp.S[1:], U[1:]) + qp.q[1:-1]
          + np.einsum("kji,kj->ki", qp.A[1:], lam[2:]) - lam[1:-1])
    gN = qp.Q[-1] @ X[-1] + qp.q[-1] - lam[-1]
    gu = (np.einsum("kji,kj->ki", qp.S, X[:-1]) + np.einsum("kij,kj->ki", qp.R, U) + qp.r
          + np.einsum("kji,kj->ki", qp.B, lam[1:]))
    return np.concatenate([gx.ravel(), gN, gu.ravel()])
