"""The elastic (relaxed) stage QP: QP (14) with every constraint but the dynamics relaxed by
nonnegative slack variables charged at a penalty eta in the objective,

    min  objective(z) + eta * sum(slacks)
    s.t. x_{k+1} = A_k x_k + B_k u_k + c_k,  x_0 = x0                 (not relaxed)
         E_k z_k + e_k + p_k - n_k = 0,                               p_k, n_k >= 0
         c_lower_k <= C_k z_k + s_k - t_k <= c_upper_k,               s_k, t_k >= 0
         x_lower_k <= x_k + s_k - t_k <= x_upper_k      (k >= 1),     s_k, t_k >= 0
         the final rows (E_N, C_N, bounds of x_N) likewise,
         u_lower <= u <= u_upper                                      (not relaxed)

the stage-wise l1 form of the relaxed QP of WORHP (seed 000, sec. IV.III, the relaxed form of
[8]: there one scalar delta scales every constraint value, G(1 - delta) + grad G d, with the
penalty eta_r; here one slack per row and side, so that one inconsistent stage does not relax
the others, as in Fletcher's Sl1QP). It is always feasible (the slacks absorb any violation; the
dynamics with x_0 fixed and the control bounds alone are always consistent), and for eta above
the largest multiplier of a consistent QP its solution is that QP's solution (the exact-penalty
property), so it may replace the QP whenever the QP is found inconsistent.

The stage structure is kept: the slacks of stage k are extra *controls* of stage k (the stage's
equality rows gain the columns [I, -I], so they also have full row rank), the bounds of x_k
become rows of stage k, and the final rows (E_N x_N, C_N x_N, the bounds of x_N) are written at
stage N-1 through the (unrelaxed) dynamics x_N = A_{N-1} x_{N-1} + B_{N-1} u_{N-1} + c_{N-1}.
The relaxed QP is again a :class:`~olado.qp.stageqp.StageQP`, solved by any QP method (its KKT
systems are LQ-DOCPs with m + (number of slacks) controls, solved by the Riccati recursion).
:meth:`ElasticQP.restore` maps its solution back to a :class:`QPResult` of the original QP
(multipliers of the moved rows, lam_N corrected by their terms) and the slack values, the
linearized violation of each row at the step.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from .stageqp import QPResult, StageQP


class Slacks(NamedTuple):
    """Linearized constraint violations at the step (the slack values, >= 0), by the rows of the
    original QP: stage equality rows ``e`` (N, ne), stage inequality rows ``c`` (N, nc), state
    bounds ``x`` (N+1, n), final equality rows ``eN`` (neN,), final inequality rows ``cN``
    (ncN,)."""

    e: np.ndarray
    c: np.ndarray
    x: np.ndarray
    eN: np.ndarray
    cN: np.ndarray
    h: np.ndarray = np.zeros((0, 0))    # dynamics rows (N, n), with relax_dynamics only

    def total(self) -> float:
        """The l1 norm of the linearized violation."""
        return float(sum(np.sum(a) for a in self))

    def largest(self) -> float:
        return float(max(np.max(a, initial=0.0) for a in self))


def _sides(lo, hi):
    """(lower side finite at some stage, upper side finite at some stage) per row, over axis 0."""
    return np.isfinite(lo).any(axis=0), np.isfinite(hi).any(axis=0)


@dataclasses.dataclass
class ElasticQP:
    """The relaxed form of ``qp`` (module docstring) with penalty ``eta``; ``relaxed`` is the
    StageQP to solve, :meth:`restore` maps its result back. ``curvature`` > 0 adds
    curvature/2 |slacks|^2 to the objective: a strictly convex QP in the slacks, which dual
    active-set methods (Goldfarb-Idnani) and quadprog need (the l1 penalty alone has none).
    ``relax_dynamics`` relaxes the dynamics rows too, x_{k+1} = A_k x_k + B_k u_k + c_k + p_k - n_k
    (p_k, n_k >= 0 more controls of stage k, charged at eta): the QP then minimizes the l1 model of
    the violation of *every* constraint, which the feasibility restoration's step and its
    stationarity test need (with exact dynamics rows the step must remove the dynamics residual
    at any cost to the other rows, so it need not reduce the l1 model at all)."""

    qp: StageQP
    eta: float
    curvature: float = 0.0
    relax_dynamics: bool = False
    relaxed: StageQP = dataclasses.field(init=False)

    def __post_init__(self):
        qp = self.qp
        N, n, m = qp.N, qp.n, qp.m
        ne, nc, neN, ncN = qp.E.shape[1], qp.C.shape[1], qp.EN.shape[0], qp.CN.shape[0]
        # ---- the inequality rows of stage k: C rows, then bounds of x_k (k >= 1), then (stage
        # N-1 only) the final inequality rows and the bounds of x_N through the dynamics
        xl, xu = qp.x_lower.copy(), qp.x_upper.copy()
        xl[0], xu[0] = -np.inf, np.inf                      # x_0 is fixed by its own row
        xcols = np.nonzero(np.isfinite(xl[:N]).any(axis=0) | np.isfinite(xu[:N]).any(axis=0))[0]
        xNcols = np.nonzero(np.isfinite(xl[N]) | np.isfinite(xu[N]))[0]
        AB = np.concatenate([qp.A[-1], qp.B[-1]], axis=1)   # x_N = AB z_{N-1} + c_{N-1}
        rows, lo, hi = [qp.C], [qp.c_lower], [qp.c_upper]
        moved = []      # (first row, G) of the final rows moved to stage N-1: x_N enters through G
        nxb = len(xcols)
        if nxb:
            Cx = np.zeros((N, nxb, n + m))
            Cx[:, np.arange(nxb), xcols] = 1.0
            rows.append(Cx); lo.append(xl[:N][:, xcols]); hi.append(xu[:N][:, xcols])
        for G, glo, ghi in ((qp.CN, qp.cN_lower, qp.cN_upper), (np.eye(n)[xNcols], xl[N, xNcols], xu[N, xNcols])):
            if G.shape[0] == 0:
                continue
            moved.append((sum(a.shape[1] for a in rows), G))
            rN = np.zeros((N, G.shape[0], n + m))
            rN[-1] = G @ AB
            off = G @ qp.c[-1]
            l = np.full((N, G.shape[0]), -np.inf); h = np.full((N, G.shape[0]), np.inf)
            l[-1] = glo - off; h[-1] = ghi - off
            rows.append(rN); lo.append(l); hi.append(h)
        C = np.concatenate(rows, axis=1)
        clo = np.concatenate(lo, axis=1); chi = np.concatenate(hi, axis=1)
        ncr = C.shape[1]
        # ---- the equality rows of stage k: E rows, then (stage N-1) the final equality rows
        E, F, e = qp.E, qp.F, qp.e
        if neN:
            EN = np.zeros((N, neN, n)); FN = np.zeros((N, neN, m)); eNr = np.zeros((N, neN))
            EN[-1] = qp.EN @ qp.A[-1]; FN[-1] = qp.EN @ qp.B[-1]; eNr[-1] = qp.EN @ qp.c[-1] + qp.eN
            E = np.concatenate([E, EN], axis=1); F = np.concatenate([F, FN], axis=1); e = np.concatenate([e, eNr], axis=1)
        ner = E.shape[1]
        # ---- slack columns: p, n per equality row; s (lower), t (upper) per inequality row side
        lo_side, hi_side = _sides(clo, chi)
        s_rows, t_rows = np.nonzero(lo_side)[0], np.nonzero(hi_side)[0]
        ns, nt = len(s_rows), len(t_rows)
        msl = 2 * ner + ns + nt
        nd = 2 * n if self.relax_dynamics else 0     # dynamics slacks p, n: the last columns
        ma = m + msl + nd
        Fa = np.zeros((N, ner, ma)); Fa[:, :, :m] = F
        Fa[:, np.arange(ner), m + np.arange(ner)] = 1.0
        Fa[:, np.arange(ner), m + ner + np.arange(ner)] = -1.0
        Ca = np.zeros((N, ncr, n + ma)); Ca[:, :, :n + m] = C
        Ca[:, s_rows, n + m + 2 * ner + np.arange(ns)] = 1.0
        Ca[:, t_rows, n + m + 2 * ner + ns + np.arange(nt)] = -1.0
        dcol = m + msl                               # first dynamics slack column (controls)
        if nd:   # the final rows moved to stage N-1 see x_N's dynamics slacks
            for row, G in moved:
                Ca[-1, row: row + G.shape[0], n + dcol: n + dcol + n] = G
                Ca[-1, row: row + G.shape[0], n + dcol + n: n + dcol + nd] = -G
            if neN:
                Fa[-1, ne:ner, dcol: dcol + n] = qp.EN
                Fa[-1, ne:ner, dcol + n: dcol + nd] = -qp.EN
        # slack bounds: >= 0; a side that is infinite at a stage has its slack fixed at 0
        sl_hi = np.full((N, msl + nd), np.inf)
        sl_hi[:, 2 * ner: 2 * ner + ns] = np.where(np.isfinite(clo[:, s_rows]), np.inf, 0.0)
        sl_hi[:, 2 * ner + ns: msl] = np.where(np.isfinite(chi[:, t_rows]), np.inf, 0.0)
        if neN:   # the final rows' slacks exist at stage N-1 only
            sl_hi[:-1, ne:ner] = 0.0
            sl_hi[:-1, ner + ne: 2 * ner] = 0.0
        R = np.zeros((N, ma, ma)); R[:, :m, :m] = qp.R
        R[:, np.arange(m, ma), np.arange(m, ma)] = float(self.curvature)
        S = np.zeros((N, n, ma)); S[:, :, :m] = qp.S
        r = np.concatenate([qp.r, np.full((N, msl + nd), float(self.eta))], axis=1)
        B = np.zeros((N, n, ma)); B[:, :, :m] = qp.B
        if nd:
            B[:, np.arange(n), dcol + np.arange(n)] = 1.0
            B[:, np.arange(n), dcol + n + np.arange(n)] = -1.0
        xl_a, xu_a = qp.x_lower.copy(), qp.x_upper.copy()
        xl_a[:, :] = -np.inf; xu_a[:, :] = np.inf
        xl_a[0], xu_a[0] = qp.x_lower[0], qp.x_upper[0]
        self._layout = (ne, nc, neN, ncN, ner, ncr, nxb, xcols, xNcols, s_rows, t_rows, ns, nt)
        self.relaxed = StageQP(
            Q=qp.Q, R=R, S=S, q=qp.q, r=r, A=qp.A, B=B, c=qp.c, x0=qp.x0,
            E=E if ner else None, F=Fa if ner else None, e=e if ner else None,
            C=Ca if ncr else None, c_lower=clo if ncr else None, c_upper=chi if ncr else None,
            x_lower=xl_a, x_upper=xu_a,
            u_lower=np.concatenate([qp.u_lower, np.zeros((N, msl + nd))], axis=1),
            u_upper=np.concatenate([qp.u_upper, sl_hi], axis=1))

    @property
    def n_slacks(self) -> int:
        """Slack controls per stage."""
        return self.relaxed.m - self.qp.m

    def restore(self, res: QPResult) -> tuple[QPResult, Slacks]:
        """The relaxed QP's result as a result of the original QP (same status and message) and
        the slack values by the original rows (module docstring)."""
        qp = self.qp
        N, n, m = qp.N, qp.n, qp.m
        ne, nc, neN, ncN, ner, ncr, nxb, xcols, xNcols, s_rows, t_rows, ns, nt = self._layout
        X = res.X
        Ua = res.U
        U = Ua[:, :m].copy()
        sl = Ua[:, m:]
        p_, n_ = sl[:, :ner], sl[:, ner: 2 * ner]
        s_ = np.zeros((N, ncr)); t_ = np.zeros((N, ncr))
        s_[:, s_rows] = sl[:, 2 * ner: 2 * ner + ns]
        t_[:, t_rows] = sl[:, 2 * ner + ns: 2 * ner + ns + nt]
        viol_rows = np.maximum(s_, 0.0) + np.maximum(t_, 0.0)
        nu_rows = res.nu[:N, :ner] if res.nu.shape[1] >= ner else np.zeros((N, ner))
        ycl, ycu = res.yc_lower, res.yc_upper
        if ycl.shape != (N, ncr):
            ycl = ycu = np.zeros((N, ncr))
        # the original rows' multipliers
        nu = np.zeros((N + 1, max(ne, neN)))
        nu[:N, :ne] = nu_rows[:, :ne]
        nu[N, :neN] = nu_rows[-1, ne:ner]
        zxl = res.zx_lower.copy(); zxu = res.zx_upper.copy()
        zxl[1:] = 0.0; zxu[1:] = 0.0
        col = nc
        zxl[:N, xcols] = ycl[:, col: col + nxb]; zxu[:N, xcols] = ycu[:, col: col + nxb]
        zxl[0], zxu[0] = res.zx_lower[0], res.zx_upper[0]
        col += nxb
        yNl, yNu = ycl[-1, col: col + ncN].copy(), ycu[-1, col: col + ncN].copy()
        col += ncN
        zxl[N, xNcols] = ycl[-1, col:]; zxu[N, xNcols] = ycu[-1, col:]
        # lam_N of the original QP: the moved rows' terms at x_N
        lam = res.lam.copy()
        lam[N] += qp.EN.T @ nu[N, :neN] + qp.CN.T @ (yNu - yNl) + (zxu[N] - zxl[N])
        slacks = Slacks(e=np.abs(p_[:, :ne]) + np.abs(n_[:, :ne]), c=viol_rows[:, :nc],
                        x=np.zeros((N + 1, n)), eN=np.abs(p_[-1, ne:ner]) + np.abs(n_[-1, ne:ner]),
                        cN=viol_rows[-1, nc + nxb: nc + nxb + ncN])
        if self.relax_dynamics:
            dyn = sl[:, sl.shape[1] - 2 * n:]
            slacks = slacks._replace(h=np.abs(dyn[:, :n]) + np.abs(dyn[:, n:]))
        slacks.x[:N, xcols] = viol_rows[:, nc: nc + nxb]
        slacks.x[N, xNcols] = viol_rows[-1, nc + nxb + ncN:]
        out = dataclasses.replace(res, X=X, U=U, lam=lam, nu=nu, zx_lower=zxl, zx_upper=zxu,
                                  zu_lower=res.zu_lower[:, :m].copy(), zu_upper=res.zu_upper[:, :m].copy(),
                                  yc_lower=ycl[:, :nc].copy(), yc_upper=ycu[:, :nc].copy(),
                                  yN_lower=yNl, yN_upper=yNu,
                                  objective=qp.objective(X, U) if np.all(np.isfinite(X)) else float("nan"))
        return out, slacks
