"""Goldfarb and Idnani's dual active-set method for the stage QP (14) (paper 001 sec. 4.2.2:
"the active-set strategy of Goldfarb and Idnani (Goldfarb and Idnani, 1983; Powell, 1985) with
Fletcher's or Bertsekas's methods of active set initialization"), whose equality-constrained
subproblems are LQ-DOCPs solved by the block Riccati recursion (sec. 4.2.3) -- one O(N)
factorization per working-set change. docs/qp-active-set.md describes the method.

The dual method, in the constraint form n_j^T z >= b_j of :mod:`.constraints` (the equalities of
the QP -- dynamics, x_0 = x0, E rows, fixed entries -- always in the working set A):

1. start from the minimizer of the EQP of a working set A whose multipliers u_A are >= 0 (the
   equalities only, or an initial working set with its negative-multiplier members dropped);
2. pick the most violated constraint p (n_p^T z < b_p beyond ``tol``); none: optimal;
3. step direction: z = H^{-1} n_p projected on the null space of A and r = the change of the
   multipliers of A, i.e. H z - n_p + N_A r = 0, N_A^T z = 0 (Goldfarb & Idnani's z = J_2 J_2^T n_p,
   r = R^{-1} J_1^T n_p): one solve with A's factorization and the gradient -n_p;
4. step t = min(t1, t2): t2 = -s_p / n_p^T z (full step: p becomes active), t1 = min u_j / r_j
   over r_j > 0 (partial step: the blocking constraint k leaves A); z += t z, u_A -= t r,
   u_p += t (and the dynamics and equality multipliers along the same direction);
5. a full step factors A + {p}, the working set's next EQP. If that factorization drops a row
   (p is linearly dependent on A: z = 0 in exact arithmetic) the step is a partial one in the
   dual space only (t = t1); with no r_j > 0 the QP is infeasible;
6. the point is updated along the steps (Goldfarb and Idnani's updates) and recomputed exactly
   from the working set's factorization every ``_REFRESH`` changes and before the optimality test
   (the minimizer of the EQP of A with the gradient g - u_p n_p while p is being added).

Goldfarb and Idnani need a strictly convex QP; here each working set's reduced Hessian must be
positive definite (the Riccati recursion checks it at every factorization). A factorization that
finds it is not ends the solve with NUMERICAL_ERROR naming the stage (``regularization`` 0: no
shift was tried), the status after which the SQP's inertia correction shifts the Hessian and
solves again.
"""

from __future__ import annotations

import time

import numpy as np

from ...linalg.backend import RHS, NotPositiveDefiniteError, Solution
from ...linalg.riccati import RiccatiStatusError
from ...options import make_options
from ...result import Status
from ..stageqp import BOX_FIELDS, QPResult, StageQP, qp_kkt_residuals
from .constraints import Constraints
from .options import ActiveSetQPOptions
from .working_set import WorkingSet

#: r_j counts as positive (a blocking candidate) above this times max |r|
_R_TOL = 1e-13
#: the point (updated along the steps) is recomputed from the factorization every this many changes
_REFRESH = 16


class _Point:
    """A primal-dual point on Goldfarb and Idnani's path: X, U, the dynamics multipliers lam, the
    multipliers of the QP's own equality rows (nu_stage (N, ne), nu_final (neN,)), the
    multipliers per constraint id (Riccati sign: u = -mult for a side) and the consistency defect
    of the rows (of the last exact solve). ``exact``: computed by a solve, not updated since."""

    __slots__ = ("X", "U", "lam", "nu_stage", "nu_final", "mult", "defect", "exact")

    def __init__(self, sol, mult, ne0, neN0, defect):
        self.X, self.U, self.lam, self.mult = sol.X, sol.U, sol.lam, mult
        self.nu_stage = sol.nu[:-1, :ne0].copy()
        self.nu_final = sol.nu[-1, :neN0].copy()
        self.defect = float(defect)
        self.exact = True

    def step(self, t, d):
        """The point + t d (d a direction: a _Point of the solve with gradient -n_p)."""
        self.X += t * d.X
        self.U += t * d.U
        self.lam += t * d.lam
        self.nu_stage += t * d.nu_stage
        self.nu_final += t * d.nu_final
        self.mult += t * d.mult
        self.exact = False


class _Infeasible(Exception):
    """The dual step is unbounded: the QP is infeasible (message names the constraint)."""


class GoldfarbIdnaniQP:
    """Goldfarb and Idnani's dual active-set method on Riccati-solved EQPs (module docstring).
    ``solve(qp, warm_start=None)`` returns a :class:`~olado.qp.stageqp.QPResult` (multipliers in
    its convention, ``kkt`` = :func:`~olado.qp.stageqp.qp_kkt_residuals`, ``active_set`` the final
    working set, ``iterations`` the working-set changes, one history entry per change)."""

    name = "active-set"
    Options = ActiveSetQPOptions

    def __init__(self, options=None, **overrides):
        self.options = make_options(self.Options, options, **overrides)

    def solve(self, qp: StageQP, warm_start: QPResult | None = None) -> QPResult:
        """Solve ``qp``; ``warm_start`` is a previous result for a QP of the same shape: its working
        set (``active_set``, or the sides with multipliers larger than their slacks) is the
        initial working set."""
        return _Solve(self, qp).run(warm_start)


class _Solve:
    """One solve: the constraints, the working set and its factorizations, the point, counts."""

    def __init__(self, solver, qp):
        self.t0 = time.perf_counter()
        self.solver, self.options, self.qp = solver, solver.options, qp
        self.cons = Constraints(qp)
        self.history = []
        self.changes = 0
        self.pt = None
        N, n, m = qp.N, qp.n, qp.m
        self._zq, self._zr = np.zeros((N + 1, n)), np.zeros((N, m))
        self._zc, self._zx0 = np.zeros((N, n)), np.zeros(n)
        self._zoff = np.zeros(self.cons.n_ids + 1)
        self.sizes = (N, n, m)
        self._e0, self._eN0, self._ci0 = np.zeros((N, 0)), np.zeros(0), np.zeros((N, 0))

    # ------------------------------------------------------------------ entry
    def run(self, warm):
        qp, cons, opts = self.qp, self.cons, self.options
        if cons.bad_box is not None:
            return self.result(Status.INFEASIBLE, f"{Status.INFEASIBLE.sentence} ({cons.bad_box})")
        x0tol = opts.tol * (1 + float(np.max(np.abs(qp.x0), initial=0.0)))
        v0 = max(float(np.max(qp.x_lower[0] - qp.x0, initial=-np.inf)), float(np.max(qp.x0 - qp.x_upper[0], initial=-np.inf)))
        if v0 > x0tol:
            return self.result(Status.INFEASIBLE, f"{Status.INFEASIBLE.sentence} (the fixed initial state x0 violates "
                                                  f"the bounds of x_0 by {v0:.3g})")
        self.ws = WorkingSet(qp, cons)
        try:
            self.start(self.initial_candidates(warm))
            status, message = self.iterate()
        except NotPositiveDefiniteError as exc:
            status = Status.NUMERICAL_ERROR
            message = (f"{status.sentence} (working-set change {self.changes}: the QP is not strictly convex on the "
                       f"working set -- the reduced Hessian is not positive definite at stage k={exc.stage}; "
                       f"Goldfarb-Idnani needs a positive definite reduced Hessian: {exc})")
        except _Infeasible as exc:
            status, message = Status.INFEASIBLE, f"{Status.INFEASIBLE.sentence} ({exc})"
        except (np.linalg.LinAlgError, FloatingPointError, ValueError, ZeroDivisionError, RiccatiStatusError) as exc:
            status = Status.NUMERICAL_ERROR
            message = f"{status.sentence} (working-set change {self.changes}: {type(exc).__name__}: {exc})"
        return self.result(status, message)

    # ------------------------------------------------------------------ EQP solves
    def _solve(self, f, q, r, c, x0, off):
        """Solve the EQP of the factorization f for the gradient (q, r), dynamics offsets c, x0
        and the row offsets ``off`` (per id): a _Point. (The arrays are C-contiguous float64 of
        the right shapes by construction: the back-end's unchecked ``solve_into``.)"""
        cons, fact, (N, n, m) = self.cons, f.fact, self.sizes
        if fact.unconstrained:
            e, eN = self._e0, self._eN0
        else:
            e, eN = f.offsets(off)
        sol = Solution(np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n)),
                       np.empty((N + 1, max(fact.data.ne_max, fact.data.neN))))
        defect = fact.solve_into(RHS(q, r, c, x0, e, eN, self._ci0), sol)
        mult = np.zeros(cons.n_ids) if fact.unconstrained else f.multipliers(sol.nu, cons.n_ids)
        return _Point(sol, mult, cons.ne0, cons.neN0, defect)

    def eqp(self, f, p=None, u_p=0.0):
        """The minimizer of the EQP of the factorization f (gradient g - u_p n_p)."""
        qp = self.qp
        q, r = qp.q, qp.r
        if p is not None and u_p != 0.0:
            q, r = q.copy(), r.copy()
            self.cons.gradient_term(p, -u_p, q, r)
        return self._solve(f, q, r, qp.c, qp.x0, self.cons.off)

    def direction(self, f, p):
        """Step 3: (z, r) -- the solve of A's EQP with the gradient -n_p and no offsets, as a
        _Point (z in X, U; r in the multipliers) -- and theta = n_p^T z."""
        q, r = self._zq.copy(), self._zr.copy()
        self.cons.gradient_term(p, -1.0, q, r)
        d = self._solve(f, q, r, self._zc, self._zx0, self._zoff)
        k, e, fr = self.cons.row(p)
        theta = float(e @ d.X[k] + (fr @ d.U[k] if k < self.qp.N else 0.0))
        return d, theta

    # ------------------------------------------------------------------ initialization
    def initial_candidates(self, warm):
        """Initial working sets to try, in order: the warm start's (or Bertsekas' epsilon-active
        sides), the same restricted to control bounds (always linearly independent of each
        other), none (Goldfarb and Idnani's own start)."""
        cons, opts = self.cons, self.options
        if warm is not None:
            ids = self.warm_ids(warm)
        elif opts.init == "bertsekas":
            eps = opts.init_eps
            with np.errstate(invalid="ignore"):
                lo = np.nonzero(cons.has_lo & (np.abs(cons.lo) <= eps))[0]
                hi = np.nonzero(cons.has_hi & (np.abs(cons.hi) <= eps))[0] + cons.nw
            ids = np.concatenate([lo, hi])
        else:
            ids = np.zeros(0, dtype=np.int64)
        cands = [ids]
        if ids.size:
            o1, o2 = cons.offsets[1], cons.offsets[2]
            j = ids % cons.nw
            ctrl = ids[(j >= o1) & (j < o2)]
            if 0 < ctrl.size < ids.size:
                cands.append(ctrl)
            cands.append(np.zeros(0, dtype=np.int64))
        return cands

    def warm_ids(self, ws):
        """The working set of a previous result: its ``active_set``, else the sides whose
        multiplier exceeds their slack at its point."""
        cons, nw = self.cons, self.cons.nw
        try:
            act = getattr(ws, "active_set", None)
            if act is not None:
                lo_mask = self.flat([act[kind][0] for kind, *_ in BOX_FIELDS]).astype(bool)
                hi_mask = self.flat([act[kind][1] for kind, *_ in BOX_FIELDS]).astype(bool)
            else:
                w = cons.values(np.asarray(ws.X, float), np.asarray(ws.U, float))
                zl = self.flat([getattr(ws, f[3]) for f in BOX_FIELDS]) * cons.norms
                zu = self.flat([getattr(ws, f[4]) for f in BOX_FIELDS]) * cons.norms
                with np.errstate(invalid="ignore"):
                    lo_mask = zl > np.abs(w - cons.lo)
                    hi_mask = zu > np.abs(cons.hi - w)
        except (KeyError, ValueError, TypeError, IndexError, AttributeError):   # another shape: cold start
            return np.zeros(0, dtype=np.int64)
        lo_mask &= cons.has_lo
        hi_mask &= cons.has_hi & ~lo_mask
        return np.concatenate([np.nonzero(lo_mask)[0], np.nonzero(hi_mask)[0] + nw])

    def flat(self, parts):
        """Arrays of the kinds x (N+1, n), u, c, cN (BOX_FIELDS order) flattened into w's order
        (x_0 left out); a ValueError if their sizes do not fit."""
        n = self.qp.n
        out = np.concatenate([np.asarray(parts[0]).ravel()[n:]] + [np.asarray(a).ravel() for a in parts[1:]])
        if out.size != self.cons.nw:
            raise ValueError("the warm start does not fit the QP")
        return out

    def start(self, candidates):
        """Step 1: the first candidate working set whose factorization succeeds without
        dependent rows, then its members with negative multipliers dropped (all at once,
        repeated until none is negative)."""
        ws, deftol = self.ws, 1e-6 * (1.0 + self.cons.p_data)
        base_drops, f, pt = None, None, None
        for i, ids in enumerate(candidates):
            last = i == len(candidates) - 1
            ids = ws.add_many(ids)
            try:
                f = ws.factorize()
            except NotPositiveDefiniteError:
                if last:
                    raise
                f = None
            if f is not None and ids.size and f.drops > 0:
                if base_drops is None:          # rows the QP's own equalities drop: not the candidates' fault
                    ws.reset()
                    base_drops = ws.factorize().drops
                    ws.add_many(ids)
                    f = ws.factorize()
                if f.drops > base_drops:
                    f = None
            if f is not None:
                pt = self.eqp(f)
                if last or pt.defect <= deftol:
                    break
            ws.reset()
        if pt.defect > deftol:
            raise _Infeasible(f"the equality constraints (dynamics, equality rows, fixed entries and x_0) are "
                              f"inconsistent: a combination of them is violated by {pt.defect:.3g} at every point")
        while True:
            act = ws.inequalities()
            neg = act[pt.mult[act] > 0.0]          # u = -mult < 0
            if neg.size == 0:
                break
            for c in neg:
                ws.remove(int(c))
            self.changes += int(neg.size)
            f = ws.factorize()
            pt = self.eqp(f)
        self.cur, self.pt = f, pt
        self.n_initial = ws.size()

    # ------------------------------------------------------------------ the dual steps
    def refresh(self, p, u_p):
        """Recompute the point exactly from the current factorization (step 6)."""
        self.pt = self.eqp(self.cur, p, u_p)

    def most_violated(self):
        """Step 2: (p, slack) of the most violated constraint (scaled by 1 + |b|), or (None, 0)."""
        cons, ws = self.cons, self.ws
        sl = cons.slacks(cons.values(self.pt.X, self.pt.U))
        viol = -sl / cons.scale
        viol[ws.inequalities()] = -np.inf
        p = int(np.argmax(viol))
        return (p, float(sl[p])) if viol[p] > self.options.tol else (None, 0.0)

    def blocking(self, d):
        """(t1, k) of step 4: the largest dual step before a multiplier of A reaches 0."""
        act = self.ws.inequalities()
        if not act.size:
            return np.inf, None
        rj = d.mult[act]           # r (Riccati sign): u_j(t) = u_j - t r_j
        pos = rj > _R_TOL * max(1.0, float(np.max(np.abs(rj))))
        if not pos.any():
            return np.inf, None
        u = np.maximum(-self.pt.mult[act[pos]], 0.0)
        ratio = u / rj[pos]
        i = int(np.argmin(ratio))
        return float(ratio[i]), int(act[pos][i])

    def iterate(self):
        """Steps 2-6 until no constraint is violated: (status, message)."""
        cons, opts, ws = self.cons, self.options, self.ws
        p, u_p, since = None, 0.0, 0
        while True:
            if p is None:
                p, s_p = self.most_violated()
                if p is None and not self.pt.exact:
                    self.refresh(None, 0.0)
                    since = 0
                    p, s_p = self.most_violated()
                if p is None:
                    return Status.SUCCESS, (f"{Status.SUCCESS.sentence} No constraint violated by more than tol "
                                            f"after {self.changes} working-set changes ({self.n_initial} constraints "
                                            f"in the initial working set, {ws.size()} at the end).")
                u_p = 0.0
            else:
                s_p = float(cons.slacks(cons.values(self.pt.X, self.pt.U))[p])
            if self.changes >= opts.max_iter:
                return Status.MAX_ITERATIONS, (f"{Status.MAX_ITERATIONS.sentence} ({self.changes} working-set changes; "
                                               f"{cons.describe(p)} is still violated by {-s_p:.3g})")
            d, theta = self.direction(self.cur, p)
            t1, k = self.blocking(d)
            t2 = -s_p / theta if theta > 0.0 else np.inf
            dependent = False
            if t2 <= t1 or t1 == np.inf:
                ws.add(p)
                f = ws.factorize()
                dependent = f.drops > self.cur.drops
                if not dependent and t2 < np.inf:                          # full step: p joins A
                    self.pt.step(t2, d)
                    self.pt.mult[p] -= t2 + u_p
                    self.cur, entry, p = f, ("add", p, t2), None
                else:
                    ws.remove(p)
                    if t1 == np.inf:
                        if dependent:
                            raise _Infeasible(f"{cons.describe(p)} (violated by {-s_p:.3g}) is linearly dependent "
                                              f"on the constraints of the working set and no multiplier of the "
                                              f"working set can decrease (Goldfarb-Idnani: the dual is unbounded)")
                        raise FloatingPointError(f"the step direction of {cons.describe(p)} has no positive "
                                                 f"curvature (n_p^T z = {theta:.3g}) although it is independent of "
                                                 f"the working set")
            if p is not None and (t1 < t2 or dependent):                   # partial step: k leaves A
                self.pt.step(t1, d)
                u_p += t1
                ws.remove(k)
                self.pt.mult[k] = 0.0
                self.cur, entry = ws.factorize(), ("drop", k, t1)
            self.changes += 1
            since += 1
            if since >= _REFRESH:
                self.refresh(p, u_p)
                since = 0
            if not np.all(np.isfinite(self.pt.X)):
                raise FloatingPointError("non-finite point")
            self.history.append({"iter": self.changes, "change": entry[0], "constraint": entry[1], "step": entry[2],
                                 "active": ws.size(), "dependent": dependent})
            if opts.verbose >= 2:
                print(f"{self.solver.name} {self.changes:5d}  {entry[0]:4s} {cons.describe(entry[1])}  t {entry[2]:.3e}"
                      f"  |A| {ws.size()}")

    # ------------------------------------------------------------------ result
    def result(self, status, message):
        qp, cons = self.qp, self.cons
        N, n, m = qp.N, qp.n, qp.m
        nc, ncN, nw = cons.nc, cons.ncN, cons.nw
        pt = self.pt
        ne_out = max(cons.ne0, cons.neN0)
        zl_w, zu_w = np.zeros(nw), np.zeros(nw)
        act_lo, act_hi = np.zeros(nw, bool), np.zeros(nw, bool)
        nu = np.zeros((N + 1, ne_out))
        if pt is None:
            X, U, lam = np.full((N + 1, n), np.nan), np.full((N, m), np.nan), np.zeros((N + 1, n))
        else:
            X, U, lam = pt.X.copy(), pt.U.copy(), pt.lam.copy()
            nu[:N, :cons.ne0] = pt.nu_stage
            nu[N, :cons.neN0] = pt.nu_final
            ids = self.ws.inequalities()
            u = np.maximum(-pt.mult[ids], 0.0)
            lo_ids, hi_ids = ids[ids < nw], ids[ids >= nw]
            zl_w[lo_ids] = u[ids < nw] / cons.norms[lo_ids]
            zu_w[hi_ids - nw] = u[ids >= nw] / cons.norms[hi_ids - nw]
            act_lo[lo_ids] = True
            act_hi[hi_ids - nw] = True
            fixed = np.nonzero(cons.fixed)[0]
            v = pt.mult[fixed] / cons.norms[fixed]
            zu_w[fixed], zl_w[fixed] = np.maximum(v, 0.0), np.maximum(-v, 0.0)
        o = cons.offsets

        def split(flat):
            x = np.zeros((N + 1, n), dtype=flat.dtype); x[1:] = flat[o[0]:o[1]].reshape(N, n)
            return (x, flat[o[1]:o[2]].reshape(N, m).copy(), flat[o[2]:o[3]].reshape(N, nc).copy(),
                    flat[o[3]:o[4]].copy())

        zxl, zul, ycl, yNl = split(zl_w)
        zxu, zuu, ycu, yNu = split(zu_w)
        res = QPResult(status, message, X, U, lam, nu, zxl, zxu, zul, zuu, ycl, ycu, yNl, yNu,
                       objective=qp.objective(X, U) if pt is not None else float("nan"), iterations=self.changes,
                       history=self.history, solver=self.solver.name)
        al, ah = split(act_lo), split(act_hi)
        res.active_set = {kind: (al[i], ah[i]) for i, (kind, *_rest) in enumerate(BOX_FIELDS)}
        if pt is not None:
            res.kkt = qp_kkt_residuals(qp, res)
        res.time_s = time.perf_counter() - self.t0
        if self.options.verbose >= 1:
            kkt = ", ".join(f"{key} {val:.1e}" for key, val in res.kkt.items())
            print(f"{self.solver.name}: {status.value} after {self.changes} working-set changes "
                  f"({getattr(getattr(self, 'ws', None), 'factorizations', 0)} factorizations), objective "
                  f"{res.objective:.10g}, {kkt}, {res.time_s:.3f} s")
        return res
