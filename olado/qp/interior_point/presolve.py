"""The prepared QP of the interior-point methods (paper 001 sec. 4.2.2, QP (14) in stage form):
fixed variables eliminated, equal bounds turned into equality rows, the inequalities flattened
into boxes lo <= w <= hi with a slack and a multiplier per finite side, the stacked stage arrays
of the compiled kernels, and the work arrays reused from iteration to iteration.
"""

from __future__ import annotations

import numpy as np

from ...linalg.codegen import fixed_size_tags, kernel_set
from ..stageqp import StageQP
from .kernels import (_all_finite, _axpy, _axpy_split, _combined_rhs, _complementarity_residual, _corrector_rhs,
                      _implied_newton_residual, _max_abs, _max_step, _max_step_split, _neighbourhood_step, _newton_rhs,
                      _predictor_rhs, _recover_step, _scaling, _step_into, _symmetric_stage_hessians)
from .kkt_map import _kkt_map
from .bundles import KKTData, PointArrays, Residuals
from .point import _Layout, _Point, _PointForm, _Rhs

_FIX_RTOL = 1e-12

#: the kernels of an interior-point iteration, called through a KernelSet of the prepared QP
#: (olado.linalg.codegen.kernel_set: its arrays are C-contiguous float64, so the argument types
#: depend only on the size tags)
_KERNELS = {"kkt_map": _kkt_map, "scaling": _scaling, "newton_rhs": _newton_rhs, "recover_step": _recover_step,
            "complementarity_residual": _complementarity_residual, "max_abs": _max_abs, "max_step": _max_step,
            "max_step_split": _max_step_split, "neighbourhood_step": _neighbourhood_step,
            "combined_rhs": _combined_rhs, "corrector_rhs": _corrector_rhs, "axpy": _axpy, "axpy_split": _axpy_split,
            "all_finite": _all_finite, "implied_newton_residual": _implied_newton_residual,
            "predictor_rhs": _predictor_rhs, "step_into": _step_into}


def _equal_bounds(lo, hi):
    """Entries with finite lo = hi (to _FIX_RTOL relative): fixed variables and equality rows."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(lo) & np.isfinite(hi) & (hi - lo <= _FIX_RTOL * (1 + np.abs(lo)))


# ============================================================================= internal data
class _Prepared:
    """The QP after elimination of fixed controls, with the inequality boxes flattened over
    w = (x_1..x_N, u, C_k z_k, C_N x_N)."""

    def __init__(self, qp: StageQP):
        N, n, m = qp.N, qp.n, qp.m
        self.N, self.n, self.m = N, n, m
        self.qp = qp
        self.limits = None      # the Limits of the solve (InteriorPointQP._solve), for the KKT back-end
        self.Q = qp.Q.copy(); self.S = qp.S.copy(); self.R = qp.R.copy()
        # (own copies of every array the KKT back-end holds: refill writes the next QP's values into them)
        self.q = qp.q.copy(); self.r = qp.r.copy(); self.A = qp.A.copy(); self.B = qp.B.copy()
        self.c = qp.c.copy(); self.x0 = qp.x0.copy()
        ne0, neN0 = qp.E.shape[1], qp.EN.shape[0]
        self.ne0, self.neN0 = ne0, neN0
        F0, e0 = qp.F.copy(), qp.e.copy()
        C = qp.C.copy(); clo = qp.c_lower.copy(); chi = qp.c_upper.copy()
        nc, ncN = C.shape[1], qp.CN.shape[0]
        self.nc, self.ncN = nc, ncN
        self.CN = qp.CN.copy(); cNlo = qp.cN_lower; cNhi = qp.cN_upper

        # ---- inconsistent boxes
        self.bad_box = None
        for name, lo, hi in (("x", qp.x_lower, qp.x_upper), ("u", qp.u_lower, qp.u_upper),
                             ("C_k z_k", clo, chi), ("C_N x_N", cNlo, cNhi)):
            viol = lo - hi
            if viol.size and np.any(viol > _FIX_RTOL * (1 + np.abs(lo))):
                idx = np.unravel_index(np.argmax(viol), viol.shape)
                self.bad_box = f"lower bound above upper bound for {name} at index {tuple(int(i) for i in idx)}"
        fix = _equal_bounds

        # ---- fixed controls: eliminated (their value moves into c, q, r, e and the row bounds)
        self.ufix = fix(qp.u_lower, qp.u_upper)
        self.any_ufix = bool(self.ufix.any())
        self.uval = np.where(self.ufix, 0.5 * (np.where(self.ufix, qp.u_lower, 0.0) + np.where(self.ufix, qp.u_upper, 0.0)), 0.0)
        if self.ufix.any():
            v = self.uval
            self.c += np.einsum("kij,kj->ki", self.B, v)
            self.q[:-1] += np.einsum("kij,kj->ki", self.S, v)
            self.r += np.einsum("kij,kj->ki", self.R, v)
            e0 = e0 + np.einsum("kij,kj->ki", F0, v)
            if nc:
                Cv = np.einsum("kij,kj->ki", C[:, :, n:], v)
                clo, chi = clo - Cv, chi - Cv
            keep = ~self.ufix
            self.B *= keep[:, None, :]
            self.S *= keep[:, None, :]
            F0 = F0 * keep[:, None, :]
            if nc:
                C[:, :, n:] *= keep[:, None, :]
            self.R = self.R * (keep[:, :, None] & keep[:, None, :])
            kk, ii = np.nonzero(self.ufix)
            self.R[kk, ii, ii] = 1.0
            self.r[self.ufix] = 0.0
        self.C = C

        # ---- fixed states (k >= 1) and equal-bound rows become equality rows
        xfix = fix(qp.x_lower, qp.x_upper)
        xfix[0] = False
        cfix = fix(clo, chi) if nc else np.zeros((N, 0), bool)
        cNfix = fix(cNlo, cNhi) if ncN else np.zeros(0, bool)
        mid = lambda lo, hi, f: np.where(f, 0.5 * (np.where(f, lo, 0.0) + np.where(f, hi, 0.0)), 0.0)  # noqa: E731
        xval = mid(qp.x_lower, qp.x_upper, xfix)
        cval = mid(clo, chi, cfix)
        cNval = mid(cNlo, cNhi, cNfix)
        # rows of stage k < N: the QP's own rows, then fixed x_k, then equal-bound C_k rows
        self.n_eq = (ne0 + xfix[:N].sum(axis=1) + cfix.sum(axis=1)).astype(np.int64)
        ne = int(self.n_eq.max(initial=0))
        self.ne = ne
        E = np.zeros((N, ne, n)); F = np.zeros((N, ne, m)); e = np.zeros((N, ne))
        E[:, :ne0] = qp.E; F[:, :ne0] = F0; e[:, :ne0] = e0
        self.eq_map = []   # (k, row, kind, index) of the appended stage rows
        for k in np.nonzero(xfix[:N].any(axis=1) | cfix.any(axis=1))[0]:   # only stages with fixed entries
            k = int(k)
            row = ne0
            for i in np.nonzero(xfix[k])[0]:
                E[k, row, i] = 1.0; e[k, row] = -xval[k, i]; self.eq_map.append((k, row, "x", int(i))); row += 1
            for i in np.nonzero(cfix[k])[0]:
                E[k, row] = C[k, i, :n]; F[k, row] = C[k, i, n:]; e[k, row] = -cval[k, i]
                self.eq_map.append((k, row, "c", int(i))); row += 1
        rowsN = [qp.EN]; eN = [qp.eN]; self.eqN_map = []
        row = neN0
        for i in np.nonzero(xfix[N])[0]:
            rowsN.append(np.eye(n)[i:i + 1]); eN.append([-xval[N, i]]); self.eqN_map.append((row, "x", int(i))); row += 1
        for i in np.nonzero(cNfix)[0]:
            rowsN.append(self.CN[i:i + 1]); eN.append([-cNval[i]]); self.eqN_map.append((row, "c", int(i))); row += 1
        self.EN = np.vstack(rowsN)
        self.eN = np.concatenate([np.asarray(a, float) for a in eN])
        self.neN = self.EN.shape[0]
        self.E, self.F, self.e = E, F, e
        # nothing eliminated or turned into rows: the next QP of the same shapes can be refilled
        self.simple = not (self.ufix.any() or xfix.any() or cfix.any() or cNfix.any())
        self.eq_mask = np.arange(ne)[None, :] < self.n_eq[:, None]
        self.has_eq = bool(self.n_eq.any()) or self.neN > 0
        self.n_nu = max(ne, self.neN)

        # ---- flat boxes lo <= w <= hi; fixed entries (handled above) have none
        inf = np.inf
        xl = np.where(xfix[1:], -inf, qp.x_lower[1:]); xh = np.where(xfix[1:], inf, qp.x_upper[1:])
        ul = np.where(self.ufix, -inf, qp.u_lower); uh = np.where(self.ufix, inf, qp.u_upper)
        sl = np.where(cfix, -inf, clo); sh = np.where(cfix, inf, chi)
        sNl = np.where(cNfix, -inf, cNlo); sNh = np.where(cNfix, inf, cNhi)
        lo = np.concatenate([xl.ravel(), ul.ravel(), sl.ravel(), sNl])
        hi = np.concatenate([xh.ravel(), uh.ravel(), sh.ravel(), sNh])
        self.fl, self.fu = np.isfinite(lo), np.isfinite(hi)
        self.lo = np.where(self.fl, lo, 0.0); self.hi = np.where(self.fu, hi, 0.0)
        self.n_comp = int(self.fl.sum() + self.fu.sum())
        o = np.cumsum([0, N * n, N * m, N * nc, ncN])
        self.sl_x, self.sl_u, self.sl_s, self.sl_sN = (slice(int(o[i]), int(o[i + 1])) for i in range(4))
        self.nw = int(o[-1])
        self.n_z = N * (n + m) + n
        self._scale_work = None
        self._scales()
        # the flat boxes of every entry as given (x_0's included): refill's work arrays
        self.box_lo, self.box_hi = np.empty(n + self.nw), np.empty(n + self.nw)

        # ---- stacked arrays of the compiled kernels and the per-iteration work arrays
        nz = n + m
        tr = lambda a: np.ascontiguousarray(np.swapaxes(a, -1, -2))  # noqa: E731
        # the symmetric parts (what the objective 1/2 z.H z sees, and what the Riccati kernels use)
        self.H = _symmetric_stage_hessians(np.ascontiguousarray(self.Q), np.ascontiguousarray(self.S),
                                           np.ascontiguousarray(self.R), np.empty((N, nz, nz)))
        self.QN = np.ascontiguousarray(0.5 * (self.Q[N] + self.Q[N].T))
        self.AB = np.ascontiguousarray(np.concatenate([self.A, self.B], axis=2))
        tags = fixed_size_tags(n, m)
        self.sizes = tags or (n, m, n + m)
        self.kernels = kernel_set(_KERNELS, None if tags is None else (n, m))
        self.EF = np.ascontiguousarray(np.concatenate([self.E, self.F], axis=2)); self.EFt = tr(self.EF)
        self.eqm = self.eq_mask.astype(float)
        self.be = self.e * self.eqm
        self.C = np.ascontiguousarray(self.C); self.CN = np.ascontiguousarray(self.CN); self.Ct = tr(self.C)
        self.neg_lo = -self.lo
        nw = self.nw
        self.point_layout = _Layout.of(PointArrays, X=(N + 1, n), U=(N, m), lam=(N + 1, n), nu=(N + 1, self.n_nu),
                                       tl=(nw,), tu=(nw,), zl=(nw,), zu=(nw,))
        self.rhs_layout = _Layout.of(Residuals, rx=(N + 1, n), ru=(N, m), dyn=(N, n), x0r=(n,), rE=(N, ne),
                                     rEN=(self.neN,), rl=(nw,), rup=(nw,))
        pl = self.point_layout
        self.part_slices = (pl.span("X", "U"), pl.span("lam", "nu"), pl.span("zl", "zu"))
        self.qr = np.concatenate([self.q.ravel(), self.r.ravel()])   # the gradient, laid out as (X, U)
        self.point_form = _PointForm.of(pl, self.kernels)
        # the bundles of the residual kernel: the stage data, and the offsets of the iterate's
        # residuals (q, r, c, x0, e, eN; -lo, hi)
        self.kkt_data = tuple(KKTData(H=self.H, QN=self.QN, AB=self.AB, EF=self.EF, EFt=self.EFt, eqm=self.eqm, EN=self.EN,
                                      C=self.C, Ct=self.Ct, CN=self.CN, fl=self.fl, fu=self.fu))
        self.offsets = tuple(Residuals(rx=self.q, ru=self.r, dyn=self.c, x0r=self.x0, rE=self.be, rEN=self.eN,
                                       rl=self.neg_lo, rup=self.hi))
        # work arrays of the Newton right-hand side (what _Rhs.kkt_rhs refers to)
        self.work_q, self.work_r, self.work_ci = np.empty((N + 1, n)), np.empty((N, m)), np.empty((N, nc))
        self.zero_res = _Rhs(self, np.zeros(self.rhs_layout.size))
        self.zero_res._size = 0.0
        self.stats = np.empty(6)
        self.inv_tl, self.inv_tu, self.D = np.empty(self.nw), np.empty(self.nw), np.empty(self.nw)
        # views of D: the stage-row weights and the diagonal terms of the bounds on x_1..x_N, u
        self.Ds = self.D[self.sl_s].reshape(N, nc)
        self.Dxb, self.Dub = self.D[self.sl_x].reshape(N, n), self.D[self.sl_u].reshape(N, m)
        self.newton_res = _Rhs(self, np.empty(self.rhs_layout.size))
        # objects reused from iteration to iteration (their lifetimes: InteriorPointQP.solve and
        # _direction): two residual vectors used in turn (the last one may be pending for the
        # implied Newton residual), the complementarity right-hand sides of one solve, and the
        # directions of the predictor, of the (combined) corrector, of further correctors (the
        # Salahi-Peng-Terlaky and centrality correctors, consumed by ``plus``) and of refinement
        self.res_pool, self.res_turn = None, 0
        self.rho_l, self.rho_u = np.empty(self.nw), np.empty(self.nw)
        self.dir_aff = self.dir_main = self.dir_corr = self.dir_refine = None
        self.iterate_pool = None   # the points of the iterates (iterate_buffer)
        self.work_el, self.work_eu, self.work_w = np.empty(self.nw), np.empty(self.nw), np.empty(self.nw)
        self.Q_final = self.Q.copy() if ncN else self.Q   # Q with C_N^T diag(D) C_N added to Q_N
        self.shift = 0.0   # delta added to the Hessian by the nonconvex = "shift" mode
        self.fact = None   # the KKT back-end's factorization, refactored in every iteration
        self.reg_rung = 0  # index (in reg_rungs) of the last iteration's Newton-system regularization
        self._rungs = None
        self.work_Dx, self.work_Du = np.empty((N + 1, n)), np.empty((N, m))
        self._zero_point = None
        self.kkt_used = None   # (kkt, kkt_options) of the back-end in fact (InteriorPointQP._prepare)

    def refill(self, qp: StageQP) -> bool:
        """Make this prepared QP the preparation of ``qp`` -- the next QP of an SQP solve -- by
        writing its numbers into the arrays already here (layouts, kernels' bundles, work arrays
        and the KKT back-end's factor arrays stay: the back-end holds these arrays and is
        refactored with the new values); the same values, entry for entry, as ``_Prepared(qp)``.
        Only for the same shapes (N, n, m and the numbers of rows) and when neither this QP nor
        ``qp`` eliminates anything (no fixed controls or states, no equal-bound rows: ``simple``)
        and ``qp``'s boxes are consistent; else False (the caller prepares ``qp`` afresh; this one may
        have its box arrays written, which the next refill writes again). The finite sides of the boxes may differ. Per-solve state (Hessian shift,
        regularization rung, iterate counters) starts again."""
        N, n, m = self.N, self.n, self.m
        if (not self.simple or qp.N != N or qp.n != n or qp.m != m or qp.E.shape[1] != self.ne0
                or qp.EN.shape[0] != self.neN0 or qp.C.shape[1] != self.nc or qp.CN.shape[0] != self.ncN):
            return False
        # the boxes of every entry (x_0's included, for the consistency test), flat
        blo, bhi = self.box_lo, self.box_hi
        np.concatenate([qp.x_lower.ravel(), qp.u_lower.ravel(), qp.c_lower.ravel(), qp.cN_lower], out=blo)
        np.concatenate([qp.x_upper.ravel(), qp.u_upper.ravel(), qp.c_upper.ravel(), qp.cN_upper], out=bhi)
        if np.greater(blo, bhi).any():      # (the constructor's test needs lo > hi)
            with np.errstate(invalid="ignore"):
                if np.any(blo - bhi > _FIX_RTOL * (1 + np.abs(blo))):
                    return False     # an inconsistent box: the constructor words the message
        # the finite sides, and the boxes with 0 on the infinite ones (the arrays of this QP: on
        # False they stay partly written, which a later refill overwrites)
        lo, hi, fl, fu = blo[n:], bhi[n:], self.fl, self.fu
        np.isfinite(lo, out=fl); np.isfinite(hi, out=fu)
        np.copyto(self.lo, lo); np.copyto(self.lo, 0.0, where=~fl)
        np.copyto(self.hi, hi); np.copyto(self.hi, 0.0, where=~fu)
        if _equal_bounds(lo, hi).any():
            return False
        self.qp, self.bad_box = qp, None
        Q = self.Q
        np.copyto(Q, qp.Q); np.copyto(self.S, qp.S); np.copyto(self.R, qp.R)
        np.copyto(self.q, qp.q); np.copyto(self.r, qp.r); np.copyto(self.c, qp.c); np.copyto(self.x0, qp.x0)
        np.copyto(self.A, qp.A); np.copyto(self.B, qp.B)
        np.concatenate([self.A, self.B], axis=2, out=self.AB)
        ne0 = self.ne0
        if ne0:         # (rows absent: their arrays are empty)
            self.E[:, :ne0] = qp.E; self.F[:, :ne0] = qp.F; self.e[:, :ne0] = qp.e
            np.concatenate([self.E, self.F], axis=2, out=self.EF)
            np.copyto(self.EFt, np.swapaxes(self.EF, -1, -2))
            np.multiply(self.e, self.eqm, out=self.be)
        if self.neN0:
            np.copyto(self.EN, qp.EN); np.copyto(self.eN, qp.eN)
        if self.nc:
            np.copyto(self.C, qp.C)
            np.copyto(self.Ct, np.swapaxes(self.C, -1, -2))
        if self.ncN:
            np.copyto(self.CN, qp.CN)
            np.copyto(self.Q_final, Q)
        self.n_comp = np.count_nonzero(fl) + np.count_nonzero(fu)
        np.concatenate([self.q.ravel(), self.r.ravel()], out=self.qr)
        self._scales()
        _symmetric_stage_hessians(Q, self.S, self.R, self.H)
        QN = self.QN                # 0.5 (Q_N + Q_N^T)
        np.add(Q[N], Q[N].T, out=QN)
        np.multiply(QN, 0.5, out=QN)
        np.negative(self.lo, out=self.neg_lo)
        self.res_turn = 0
        self.shift = 0.0
        self.reg_rung = 0
        self._rungs = None
        return True

    def _scales(self):
        """The sizes of the data: p_data (primal: c, x0, e, eN and the finite box sides), d_data
        (q, r) and h_scale (max |Q, R, S|): the three groups' absolute values put together in a
        work array, one reduction per group (maxima: exact in any order); if one is NaN, the
        maximum of its parts' maxima, NaN or not, as Python's max of them gives it."""
        w = self._scale_work
        if w is None:
            groups = ((self.c, self.x0, self.e, self.eN, self.lo, self.hi), (self.q, self.r), (self.Q, self.R, self.S))
            sizes = [sum(a.size for a in g) for g in groups]
            w = self._scale_work = (groups, [a for g in groups for a in g], np.empty(sum(sizes)),
                                    np.array([0, sizes[0], sizes[0] + sizes[1]]))
        groups, parts, buf, starts = w
        np.concatenate([a.ravel() for a in parts], out=buf)
        out = np.maximum.reduceat(np.abs(buf, out=buf), starts).tolist()   # (every group has entries: n >= 1)
        for i, v in enumerate(out):
            if v != v:
                out[i] = max(float(np.abs(a).max(initial=0.0)) for a in groups[i])
        self.p_data, self.d_data, self.h_scale = out

    def reg_rungs(self, options):
        """The regularizations a Newton-system factorization may use, in increasing order:
        options.regularization, then max(10 delta, 1e-10 (1 + max|H|)) while at most
        options.max_regularization * max|H| (12 at most)."""
        if self._rungs is None:
            rungs = [options.regularization]
            cap = options.max_regularization * max(self.h_scale, 1e-300)
            while len(rungs) < 12:
                nxt = max(10.0 * rungs[-1], 1e-10 * (1.0 + self.h_scale))
                if nxt > cap:
                    break
                rungs.append(nxt)
            self._rungs = rungs
        return self._rungs

    def point(self, v):
        return _Point(self.point_form, v)

    def iterate_buffer(self, current, best):
        """A point for the next iterate that is neither ``current`` nor ``best`` (the current
        iterate and the best one so far): one of three -- the first iterate (the starting point,
        adopted at the first call) and two made then --, so that the iterations allocate nothing
        (Point.step_into overwrites it) and at most three points are alive, as many as when every
        iterate was a new vector (the memory of N = 10^6)."""
        pool = self.iterate_pool
        if pool is None:
            size = self.point_layout.size
            pool = self.iterate_pool = (current,) + tuple(_Point(self.point_form, np.empty(size)) for _ in range(2))
        for p in pool:
            if p is not current and p is not best:
                return p
        raise AssertionError("no free iterate buffer")   # three points, at most two busy

    def start_point(self):
        """A point to write a starting point into: a new one, or after an earlier solve of this
        prepared QP the first of its iterate points (none of them is in use before the iterations;
        the starting point is then one of the three, as in the first solve)."""
        if self.iterate_pool is None:
            return _Point(self.point_form, np.empty(self.point_layout.size))
        p = self.iterate_pool[0]
        p.max_step = p.max_split = p._finite = None
        return p

    def directions(self):
        """The reused direction objects (predictor, main, corrector, refinement), made on first use."""
        if self.dir_aff is None:
            size = self.point_layout.size
            self.dir_aff, self.dir_main, self.dir_corr, self.dir_refine = (_Point(self.point_form, np.empty(size)) for _ in range(4))

    def residual_buffer(self):
        """A residual object not holding the last one returned (the two are used in turn)."""
        if self.res_pool is None:
            self.res_pool = (_Rhs(self, np.empty(self.rhs_layout.size)), _Rhs(self, np.empty(self.rhs_layout.size)))
        self.res_turn ^= 1
        res = self.res_pool[self.res_turn]
        res._size = None
        return res

    def shift_hessian(self, delta):
        """H <- H + delta I on every stage block and on Q_N (the ``nonconvex = "shift"`` mode)."""
        idx = np.arange(self.n)
        self.Q[:, idx, idx] += delta
        iu = np.arange(self.m)
        self.R[:, iu, iu] += delta
        iz = np.arange(self.n + self.m)
        self.H[:, iz, iz] += delta
        self.QN[idx, idx] += delta
        if self.ncN:
            self.Q_final[...] = self.Q
        self.shift += delta

    def point_from(self, X, U, lam, nu, tl, tu, zl, zu):
        return _Point(self.point_form, np.concatenate([np.asarray(a, dtype=float).ravel() for a in (X, U, lam, nu, tl, tu, zl, zu)]))

    # ------------------------------------------------------------------ linear maps
    def w_of(self, X, U):
        """w = (x_1..x_N, u, C_k z_k, C_N x_N), flat."""
        parts = [X[1:].ravel(), U.ravel()]
        if self.nc:
            parts.append(self.cz(X, U).ravel())
        if self.ncN:
            parts.append(self.CN @ X[-1])
        return np.concatenate(parts)

    def zero_point(self):
        """A point of zeros (made on first use; never written)."""
        if self._zero_point is None:
            self._zero_point = _Point(self.point_form, np.zeros(self.point_layout.size))
        return self._zero_point

    def linear_parts(self, X, U, lam, nu, zl, zu):
        """The linear maps of the infeasibility certificates in one pass of the compiled _kkt_map
        (offsets 0, written into the scratch arrays newton_res and work_w): (max |H z + constraint
        gradient of lam, nu, zu - zl|, max |homogeneous equality residuals A x + B u - x_+, -x_0,
        E z, E_N x_N|, the box values w of z). With z = 0 the first is |constraint gradient| (the
        primal certificate); with zero multipliers it is |H z| (the dual one)."""
        e, z, st = self.newton_res, self.zero_res, self.stats
        # the slacks of the point: zero (the zero residual's box parts)
        point = tuple(PointArrays(X=X, U=U, lam=lam, nu=nu, tl=z.rl, tu=z.rup, zl=zl, zu=zu))
        _kkt_map(self.sizes, self.kkt_data, point, z.arrays, e.arrays, self.work_w, st)
        eqs = max(_max_abs(e.dyn.ravel()), _max_abs(e.x0r), _max_abs(e.rE.ravel()), _max_abs(e.rEN))
        return float(st[1]), eqs, self.work_w

    def cz(self, X, U):
        n = self.n
        return np.einsum("kij,kj->ki", self.C[:, :, :n], X[:-1]) + np.einsum("kij,kj->ki", self.C[:, :, n:], U)

    def hess_z(self, X, U):
        """H z as (N+1, n) and (N, m) parts."""
        hx = np.empty_like(X)
        hx[:-1] = np.einsum("kij,kj->ki", self.Q[:-1], X[:-1]) + np.einsum("kij,kj->ki", self.S, U)
        hx[-1] = self.Q[-1] @ X[-1]
        hu = np.einsum("kji,kj->ki", self.S, X[:-1]) + np.einsum("kij,kj->ki", self.R, U)
        return hx, hu

    def constraint_grad(self, lam, nu, zd):
        """Gradient in (x, u) of the constraint part of the Lagrangian for multipliers lam, nu and
        zd = zu - zl (flat over the boxes)."""
        N, n, m, nc = self.N, self.n, self.m, self.nc
        gx = np.empty((N + 1, n))
        gx[:-1] = np.einsum("kji,kj->ki", self.A, lam[1:]) - lam[:-1]
        gx[-1] = -lam[-1]
        gu = np.einsum("kji,kj->ki", self.B, lam[1:])
        if self.ne:
            nus = nu[:N, :self.ne] * self.eq_mask
            gx[:-1] += np.einsum("kji,kj->ki", self.E, nus)
            gu += np.einsum("kji,kj->ki", self.F, nus)
        if self.neN:
            gx[-1] += self.EN.T @ nu[N, :self.neN]
        gx[1:] += zd[self.sl_x].reshape(N, n)
        gu += zd[self.sl_u].reshape(N, m)
        if nc:
            zs = zd[self.sl_s].reshape(N, nc)
            gx[:-1] += np.einsum("kji,kj->ki", self.C[:, :, :n], zs)
            gu += np.einsum("kji,kj->ki", self.C[:, :, n:], zs)
        if self.ncN:
            gx[-1] += self.CN.T @ zd[self.sl_sN]
        return gx, gu

    def eq_residuals(self, X, U, hom=False):
        """Dynamics (N, n), x_0 (n,), stage (N, ne) and final (neN,) equality residuals; with
        ``hom`` only their linear parts (for recession directions)."""
        dyn = np.einsum("kij,kj->ki", self.A, X[:-1]) + np.einsum("kij,kj->ki", self.B, U) - X[1:]
        x0r = -X[0] if hom else self.x0 - X[0]
        if not hom:
            dyn = dyn + self.c
        rE = np.zeros((self.N, self.ne))
        if self.ne:
            rE = np.einsum("kij,kj->ki", self.E, X[:-1]) + np.einsum("kij,kj->ki", self.F, U)
            if not hom:
                rE = rE + self.e
            rE *= self.eq_mask
        rEN = (self.EN @ X[-1] + (0.0 if hom else self.eN)) if self.neN else np.zeros(0)
        return dyn, x0r, rE, rEN
