"""A QP method for stage QPs (14) (paper 001 sec. 4.2.2) whose only inequalities are simple bounds
on states and controls -- the QP of the "special version of Powell's SQP method optimized for
constrained problems with only simple bounds on state and control" and of the "version of
Schittkowski's SQP method tailored for problems with only simple bounds constraints" (sec. 2.2).

The method is the primal-dual active-set iteration for bound constraints (Bergounioux, Ito and
Kunisch 1999; Hintermueller, Ito and Kunisch 2002, who show that it is a semismooth Newton method
and converges locally superlinearly; in the family of Bertsekas' (1982) projected Newton methods:
the variables at a bound are fixed and a Newton step is taken in the others). With v the
bound multiplier (zu - zl) and w the bounded quantities (olado.qp.bounds.eqp):

1. fix the working set's variables at their bounds and solve the EQP exactly (one Riccati
   factorization, O(N): fixed controls leave the recursion, fixed states are equality rows);
2. the next working set: a fixed variable stays fixed while its multiplier has the right sign
   (v >= -tol at an upper bound, v <= tol at a lower one), a free variable is fixed at the
   bound it violates by more than tol (1 + |b|);
3. stop when the working set repeats: the point is then a KKT point of the QP (feasible free
   variables, multipliers of the right sign, complementarity exact).

Unlike Goldfarb and Idnani's method (olado.qp.active_set), which changes one constraint per
factorization, the iteration changes every wrong bound at once: the number of factorizations
does not grow with the number of active bounds (typically 2-6 from a cold start, 1-2 from the
previous SQP iteration's working set). It has no global convergence guarantee for general
(non-M-matrix) Hessians and can cycle; a QP it gives up on -- a repeated working set, no fixed
point within ``pdas_max_iter``, a working set whose fixed states cannot all hold -- is solved by
the interior-point method ``fallback`` (Mehrotra's by default), whose status (infeasibility
certificates) is then the result's. A QP with general rows (E, C rows) or, by default, with state
bounds goes to the fallback directly. A working set whose reduced Hessian is not positive
definite ends the solve with NUMERICAL_ERROR (``nonconvex = 'fail'``, the SQP's inertia
correction then shifts the Hessian) or goes to the fallback (``'fallback'``).
"""

from __future__ import annotations

import time

import numpy as np

from ...linalg.backend import NotPositiveDefiniteError
from ...linalg.riccati import RiccatiStatusError
from ...options import make_options
from ...result import Status
from ..stageqp import QPResult, StageQP, qp_kkt_residuals
from .eqp import Boxes, solve_eqp
from .options import BoundsQPOptions


def general_rows(qp: StageQP) -> str:
    """'' when the only inequalities of ``qp`` are simple bounds and it has no equality rows
    besides the dynamics and x_0; else what it has (a phrase)."""
    parts = [f"{k} {what}" for k, what in ((qp.E.shape[1], "stage equality rows E_k"),
                                           (qp.EN.shape[0], "final equality rows E_N"),
                                           (qp.C.shape[1], "stage inequality rows C_k"),
                                           (qp.CN.shape[0], "final inequality rows C_N")) if k]
    return ", ".join(parts)


class _GiveUp(Exception):
    """The active-set iteration gives the QP to the fallback method (the message says why)."""


class _NotConvex(Exception):
    """A working set's reduced Hessian is not positive definite (nonconvex = 'fail')."""


class _Inconsistent(_GiveUp):
    """The fixed states of a working set cannot all hold (x_0 fixed, the dynamics, the fixed
    controls and states leave no point): another working set may be tried."""


_INCONSISTENT = "the fixed states of the working set cannot all hold"


class PrimalDualActiveSetQP:
    """The primal-dual active-set method on the bounds (module docstring). ``solve(qp,
    warm_start=None, limits=None)`` returns a :class:`~olado.qp.stageqp.QPResult` (multipliers in
    its convention, ``kkt`` = :func:`~olado.qp.stageqp.qp_kkt_residuals`, ``active_set`` the final
    working set, ``iterations`` the factorizations -- plus the fallback's iterations --, one
    history entry per active-set iteration and a ``fallback`` entry when the fallback solved it)."""

    name = "bounds"
    Options = BoundsQPOptions

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)

    def solve(self, qp: StageQP, warm_start: QPResult | None = None, limits=None) -> QPResult:
        """Solve ``qp``; ``warm_start`` a previous result for a QP of the same shape: its working
        set (``active_set``, or the bounds whose multiplier exceeds their slack) is the first one.
        ``limits`` (olado.interrupts.Limits) is checked at every iteration."""
        t0 = time.perf_counter()
        run = _Run(self.options, qp, limits)
        try:
            res = run.iterate(warm_start)
        except _GiveUp as why:
            res = self._fallback(qp, warm_start, limits, str(why), run)
        except _NotConvex as why:
            res = run.failed(str(why))
        res.time_s = time.perf_counter() - t0
        if self.options.verbose >= 1:
            print(f"{self.name}: {res.status.value} after {res.iterations} iterations, objective "
                  f"{res.objective:.10g}, {res.time_s:.3f} s ({res.solver})")
        return res

    def _fallback(self, qp, warm_start, limits, why, run):
        from ..interior_point import FrankeQP, GondzioQP, MehrotraQP, WeightedCorrectorQP

        o = self.options
        cls = {"mehrotra": MehrotraQP, "gondzio": GondzioQP, "weighted": WeightedCorrectorQP, "franke": FrankeQP}[o.fallback]
        ip = cls(tol=o.tol, max_iter=o.max_iter, kkt=o.kkt, warm_start_push=o.warm_start_push)
        res = ip.solve(qp, warm_start=warm_start, limits=limits)
        res.message = f"{res.message} [solved by {o.fallback}: {why}]"
        res.iterations += run.it
        res.history = run.history + [{"fallback": o.fallback, "reason": why}] + list(res.history)
        res.solver = f"{self.name}+{o.fallback}"
        return res


class _Run:
    """One solve's active-set iteration: the boxes, the working set (``side`` over w), counts."""

    def __init__(self, options, qp, limits):
        self.o, self.qp, self.limits = options, qp, limits
        self.it, self.history = 0, []

    def iterate(self, warm):
        qp, o = self.qp, self.o
        rows = general_rows(qp)
        if rows:
            raise _GiveUp(f"the QP has {rows}, not simple bounds only")
        B = self.boxes = Boxes(qp)
        if B.bad is not None:
            raise _GiveUp(B.bad)
        if o.state_bounds == "interior-point" and np.any(B.has_lo[:B.nx] | B.has_hi[:B.nx] | B.fixed[:B.nx]):
            raise _GiveUp("the QP bounds states (state_bounds = 'interior-point')")
        if np.any(np.isfinite(qp.x_lower[0]) | np.isfinite(qp.x_upper[0])):
            v0 = max(float(np.max(qp.x_lower[0] - qp.x0)), float(np.max(qp.x0 - qp.x_upper[0])))
            if v0 > o.tol * (1 + float(np.max(np.abs(qp.x0), initial=0.0))):
                raise _GiveUp(f"x0 violates the bounds of x_0 by {v0:.3g}")
        self.dtol = o.tol * (1.0 + max(float(np.max(np.abs(qp.q), initial=0.0)), float(np.max(np.abs(qp.r), initial=0.0))))
        self.pdata = self._pdata()
        side = self.initial_side(warm)
        seen = set()
        pt = self.eqp(side, first=True)
        side = self.side
        while True:
            new, added, dropped = self.next_side(side, pt)
            self.history.append({"iter": self.it, "active": int(np.count_nonzero(side)), "added": added,
                                 "dropped": dropped})
            if o.verbose >= 2:
                print(f"bounds {self.it:4d}  |A| {np.count_nonzero(side):6d}  +{added} -{dropped}")
            if not (added or dropped):
                return self.result(side, pt)
            key = new.tobytes()
            if key in seen:
                raise _GiveUp(f"the working set repeated after {self.it} iterations (a cycle)")
            seen.add(key)
            if self.it >= o.pdas_max_iter:
                raise _GiveUp(f"no fixed point within pdas_max_iter = {o.pdas_max_iter} iterations")
            pt = self.eqp_of(new, side)
            side = self.side

    # ------------------------------------------------------------------ working sets
    def initial_side(self, warm):
        """The first working set: the warm start's, else Bertsekas' epsilon-active set at the
        zero step; fixed variables always."""
        B = self.boxes
        side = np.zeros(B.lo.size, dtype=np.int8)
        ids = None if warm is None else _warm_sides(warm, B)
        if ids is not None:
            side[ids[0] & B.has_lo] = -1
            side[ids[1] & B.has_hi & (side == 0)] = 1
        else:
            eps = self.o.init_eps
            with np.errstate(invalid="ignore"):
                side[B.has_lo & (np.abs(B.lo) <= eps)] = -1
                side[B.has_hi & (np.abs(B.hi) <= eps) & (side == 0)] = 1
        side[B.fixed] = 2
        return side

    def eqp_of(self, new, side):
        """The EQP of the next working set ``new`` (from ``side``); when the fixed states of
        ``new`` cannot all hold, ``new`` without the state bounds it adds, then without any bound
        it adds (the step's drops only) -- a free state the controls can reach is fixed in a
        later iteration. Sets ``self.side`` to the working set solved."""
        added = (side == 0) & (new != 0)
        is_x = np.arange(new.size) < self.boxes.nx
        tries = [new, np.where(added & is_x, 0, new).astype(np.int8), np.where(added, 0, new).astype(np.int8)]
        tries = [t for i, t in enumerate(tries) if i == 0 or (np.any(t != tries[i - 1]) and np.any(t != side))]
        for i, t in enumerate(tries):
            try:
                return self.eqp(t)
            except _Inconsistent:
                if i == len(tries) - 1:
                    raise _GiveUp("the fixed states of every candidate working set cannot all hold") from None
        raise AssertionError("unreachable")

    def eqp(self, side, first=False):
        """The EQP of ``side`` (one factorization); the first working set falls back to the
        fixed variables alone when its EQP fails. Stores the working set solved in ``side``."""
        if self.limits is not None:
            self.limits.check()
        self.it += 1
        try:
            pt = solve_eqp(self.qp, self.boxes, side)
            ok = np.isfinite(pt.defect) and pt.defect <= 1e3 * self.o.tol * (1.0 + self.pdata)
            why = f"{_INCONSISTENT} (defect {pt.defect:.3g})"
        except NotPositiveDefiniteError as exc:
            ok, why = False, (f"the reduced Hessian of the working set is not positive definite at stage "
                              f"k={exc.stage}")
            if self.o.nonconvex == "fail":
                raise _NotConvex(f"iteration {self.it}: {why}; the QP is not strictly convex on its working set") from None
        except (RiccatiStatusError, np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
            ok, why = False, f"{type(exc).__name__}: {exc}"
        if ok and not (np.all(np.isfinite(pt.X)) and np.all(np.isfinite(pt.U))):
            ok, why = False, "the working set's EQP has a non-finite solution"
        if not ok:
            base = np.where(self.boxes.fixed, 2, 0).astype(np.int8)
            if first and np.any(side != base):
                return self.eqp(base)
            raise (_Inconsistent if why.startswith(_INCONSISTENT) else _GiveUp)(why)
        self.side, self.pt = side, pt
        return pt

    def _pdata(self):
        """The largest |value| of the data the rows hold (offsets c, x0, finite bounds)."""
        qp = self.qp
        b = np.concatenate([self.boxes.lo, self.boxes.hi])
        return max(float(np.max(np.abs(qp.c), initial=0.0)), float(np.max(np.abs(qp.x0), initial=0.0)),
                   float(np.max(np.abs(b[np.isfinite(b)]), initial=0.0)))

    def next_side(self, side, pt):
        """Step 2: (the next working set, bounds added, bounds dropped)."""
        B, tol, dtol = self.boxes, self.o.tol, self.dtol
        w = B.values(pt.X, pt.U)
        free = side == 0
        with np.errstate(invalid="ignore"):
            add_lo = free & B.has_lo & (w < B.lo - tol * B.scale_lo)
            add_hi = free & B.has_hi & (w > B.hi + tol * B.scale_hi)
        drop = ((side == -1) & (pt.v > dtol)) | ((side == 1) & (pt.v < -dtol))
        new = side.copy()
        new[drop] = 0
        new[add_lo] = -1
        new[add_hi] = 1
        return new, int(np.count_nonzero(add_lo | add_hi)), int(np.count_nonzero(drop))

    # ------------------------------------------------------------------ result
    def failed(self, why):
        """The NUMERICAL_ERROR result of a nonconvex working set (nonconvex = 'fail'): the last
        EQP point, if any, and no multipliers (the SQP shifts its Hessian and solves again)."""
        qp = self.qp
        N, n, m = qp.N, qp.n, qp.m
        pt = getattr(self, "pt", None)
        X, U = (pt.X, pt.U) if pt is not None else (np.full((N + 1, n), np.nan), np.full((N, m), np.nan))
        z = np.zeros
        return QPResult(Status.NUMERICAL_ERROR, f"{Status.NUMERICAL_ERROR.sentence} ({why})", X, U, z((N + 1, n)),
                        z((N + 1, 0)), z((N + 1, n)), z((N + 1, n)), z((N, m)), z((N, m)), z((N, 0)), z((N, 0)),
                        z(0), z(0), iterations=self.it, history=self.history, solver="bounds")

    def result(self, side, pt):
        qp, B = self.qp, self.boxes
        N, n, m, nx = qp.N, qp.n, qp.m, B.nx
        v = pt.v
        zu = np.where((side == 1) | (side == 2), np.maximum(v, 0.0), 0.0)
        zl = np.where((side == -1) | (side == 2), np.maximum(-v, 0.0), 0.0)
        zxl, zxu = np.zeros((N + 1, n)), np.zeros((N + 1, n))
        zxl[1:], zxu[1:] = zl[:nx].reshape(N, n), zu[:nx].reshape(N, n)
        res = QPResult(Status.SUCCESS, "", pt.X, pt.U, pt.lam, np.zeros((N + 1, 0)), zxl, zxu,
                       zl[nx:].reshape(N, m), zu[nx:].reshape(N, m), np.zeros((N, 0)), np.zeros((N, 0)),
                       np.zeros(0), np.zeros(0), objective=qp.objective(pt.X, pt.U), iterations=self.it,
                       history=self.history, solver="bounds")
        lo_x, hi_x = np.zeros((N + 1, n), bool), np.zeros((N + 1, n), bool)
        lo_x[1:] = ((side == -1) | (side == 2))[:nx].reshape(N, n)
        hi_x[1:] = (side == 1)[:nx].reshape(N, n)
        res.active_set = {"x": (lo_x, hi_x),
                          "u": (((side == -1) | (side == 2))[nx:].reshape(N, m), (side == 1)[nx:].reshape(N, m)),
                          "c": (np.zeros((N, 0), bool), np.zeros((N, 0), bool)), "cN": (np.zeros(0, bool), np.zeros(0, bool))}
        res.kkt = qp_kkt_residuals(qp, res)
        if not res.kkt["stationarity"] <= 1e-6 * (1.0 + self.dtol / self.o.tol):
            raise _GiveUp(f"the fixed point's stationarity residual {res.kkt['stationarity']:.3g} shows a "
                          f"numerically unreliable EQP solve")
        res.message = (f"{Status.SUCCESS.sentence} The working set repeated after {self.it} Riccati factorizations "
                       f"({int(np.count_nonzero(side))} variables at a bound).")
        return res


def _warm_sides(warm, boxes):
    """(lower, upper) masks over w of a warm start's working set: its ``active_set``, else the
    bounds whose multiplier exceeds their slack at its point; None if it does not fit."""
    try:
        act = getattr(warm, "active_set", None)
        if act is not None:
            lo = np.concatenate([np.asarray(act["x"][0])[1:].ravel(), np.asarray(act["u"][0]).ravel()]).astype(bool)
            hi = np.concatenate([np.asarray(act["x"][1])[1:].ravel(), np.asarray(act["u"][1]).ravel()]).astype(bool)
        else:
            w = boxes.values(np.asarray(warm.X, float), np.asarray(warm.U, float))
            zl = np.concatenate([np.asarray(warm.zx_lower)[1:].ravel(), np.asarray(warm.zu_lower).ravel()])
            zu = np.concatenate([np.asarray(warm.zx_upper)[1:].ravel(), np.asarray(warm.zu_upper).ravel()])
            with np.errstate(invalid="ignore"):
                lo = zl > np.abs(w - boxes.lo)
                hi = zu > np.abs(boxes.hi - w)
    except (KeyError, ValueError, TypeError, IndexError, AttributeError):
        return None
    if lo.size != boxes.lo.size or hi.size != boxes.lo.size:
        return None
    return lo, hi
