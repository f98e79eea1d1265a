"""The rows of the stage QP (14) (paper 001 sec. 4.2.2) as the active-set method sees them.

Every inequality of a :class:`~olado.qp.stageqp.StageQP` is a box ``lo <= w <= hi`` on the flat
vector w = (x_1..x_N, u_0..u_{N-1}, C_k z_k, C_N x_N) (the interior-point method's ordering,
docs/qp-interior-point.md); the general rows C_k, C_N are normalized to unit 2-norm (their
bounds divided by the same norm), so violations and multipliers of different rows compare. Each
finite side of a box is one constraint of the dual method in Goldfarb and Idnani's form
``n^T z - b >= 0``: the lower side of w_j has the id j (n = +row, b = lo_j), the upper side
the id nw + j (n = -row, b = -hi_j). x_0 is fixed by the QP (its bounds are only checked).

A constraint in the working set is an equality row of the LQ-DOCP KKT system that the Riccati
recursion solves (olado.linalg: E_k x_k + F_k u_k + e_k = 0 at its stage k, E_N x_N + e_N = 0
for x_N and C_N rows), with e = -b. The equalities of the QP that are always in it -- its own
rows E, F, E_N, the fixed entries (lo = hi: fixed states, fixed controls, equal-bound rows) --
are the *base rows*; their ids: a fixed entry keeps the id j of its lower side (with a free
multiplier), the QP's own stage rows come after the sides (2 nw + k ne + i), then its own final
rows.
"""

from __future__ import annotations

import numpy as np

_FIX_RTOL = 1e-12


def _equal_bounds(lo, hi):
    """Entries with finite lo = hi (to _FIX_RTOL relative): fixed variables and equality rows."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(lo) & np.isfinite(hi) & (hi - lo <= _FIX_RTOL * (1 + np.abs(lo)))


class Constraints:
    """The sides and base rows of ``qp`` (module docstring): ids, rows, offsets, values."""

    def __init__(self, qp):
        N, n, m = qp.N, qp.n, qp.m
        self.qp, self.N, self.n, self.m = qp, N, n, m
        nc, ncN = qp.C.shape[1], qp.CN.shape[0]
        self.nc, self.ncN = nc, ncN
        self.ne0, self.neN0 = qp.E.shape[1], qp.EN.shape[0]
        # normalized general rows (a zero row keeps norm 1 and is checked below)
        cn = np.linalg.norm(qp.C, axis=2) if nc else np.ones((N, 0))
        cNn = np.linalg.norm(qp.CN, axis=1) if ncN else np.ones(0)
        self.bad_box = None
        zero_c, zero_cN = cn == 0.0, cNn == 0.0
        cn = np.where(zero_c, 1.0, cn)
        cNn = np.where(zero_cN, 1.0, cNn)
        self.Cn = qp.C / cn[:, :, None] if nc else qp.C
        self.CNn = qp.CN / cNn[:, None] if ncN else qp.CN
        self.norms = np.concatenate([np.ones(N * (n + m)), cn.ravel(), cNn])
        lo = np.concatenate([qp.x_lower[1:].ravel(), qp.u_lower.ravel(), (qp.c_lower / cn).ravel(), qp.cN_lower / cNn])
        hi = np.concatenate([qp.x_upper[1:].ravel(), qp.u_upper.ravel(), (qp.c_upper / cn).ravel(), qp.cN_upper / cNn])
        o = np.cumsum([0, N * n, N * m, N * nc, ncN])
        self.offsets = o
        self.nw = nw = int(o[-1])
        # inconsistent boxes (lower above upper), and zero rows whose box excludes 0
        for name, a, b in (("x", qp.x_lower, qp.x_upper), ("u", qp.u_lower, qp.u_upper),
                           ("C_k z_k", qp.c_lower, qp.c_upper), ("C_N x_N", qp.cN_lower, qp.cN_upper)):
            viol = a - b
            if viol.size and np.any(viol > _FIX_RTOL * (1 + np.abs(a))):
                idx = np.unravel_index(np.argmax(viol), viol.shape)
                self.bad_box = f"lower bound above upper bound for {name} at index {tuple(int(i) for i in idx)}"
        zero = np.concatenate([np.zeros(N * (n + m), bool), zero_c.ravel(), zero_cN])
        if np.any(zero & ((lo > 0) | (hi < 0))) and self.bad_box is None:
            j = int(np.nonzero(zero & ((lo > 0) | (hi < 0)))[0][0])
            self.bad_box = f"the zero row {self.describe(j)} has a box that excludes 0"
        lo = np.where(zero, -np.inf, lo)
        hi = np.where(zero, np.inf, hi)
        self.fixed = _equal_bounds(lo, hi)
        self.lo = np.where(self.fixed, 0.5 * (np.where(self.fixed, lo, 0.0) + np.where(self.fixed, hi, 0.0)), lo)
        self.hi = np.where(self.fixed, self.lo, hi)
        # the inequality sides: finite and not fixed
        self.has_lo = np.isfinite(self.lo) & ~self.fixed
        self.has_hi = np.isfinite(self.hi) & ~self.fixed
        # ids of the QP's own rows, and the offsets of every id's row (+ a trailing 0: index -1)
        self.own_base = 2 * nw
        self.own_final = 2 * nw + N * self.ne0
        self.n_ids = self.own_final + self.neN0
        off = np.zeros(self.n_ids + 1)
        off[:nw] = np.where(self.has_lo | self.fixed, -np.where(np.isfinite(self.lo), self.lo, 0.0), 0.0)
        off[nw:2 * nw] = np.where(self.has_hi, np.where(np.isfinite(self.hi), self.hi, 0.0), 0.0)
        off[self.own_base:self.own_final] = qp.e.ravel()
        off[self.own_final:self.n_ids] = qp.eN
        self.off = off
        self.scale = 1.0 + np.abs(np.concatenate([np.where(np.isfinite(self.lo), self.lo, 0.0),
                                                  np.where(np.isfinite(self.hi), self.hi, 0.0)]))
        self.p_data = max(float(np.max(np.abs(a), initial=0.0)) for a in
                          (qp.c, qp.x0, qp.e, qp.eN, np.where(np.isfinite(self.lo), self.lo, 0.0),
                           np.where(np.isfinite(self.hi), self.hi, 0.0)))

    # ------------------------------------------------------------------ ids
    def kind(self, j):
        """(kind, stage, index) of the box entry w_j: kind 'x' (stage 1..N), 'u', 'c' or 'cN' (stage N)."""
        o, n, m, nc = self.offsets, self.n, self.m, self.nc
        if j < o[1]:
            return "x", j // n + 1, j % n
        if j < o[2]:
            j -= o[1]
            return "u", j // m, j % m
        if j < o[3]:
            j -= o[2]
            return "c", j // nc, j % nc
        return "cN", self.N, j - o[3]

    def describe(self, cid):
        """A human name of the constraint ``cid`` ('the lower bound of u[3, 1]', ...)."""
        side, j = divmod(cid, self.nw) if cid < 2 * self.nw else (None, None)
        if side is None:
            return "an equality row of the QP"
        kind, k, i = self.kind(j)
        what = {"x": f"x[{k}, {i}]", "u": f"u[{k}, {i}]", "c": f"row {i} of C_{k} z_{k}", "cN": f"row {i} of C_N x_N"}[kind]
        return f"the {'lower' if side == 0 else 'upper'} bound of {what}"

    def row(self, cid):
        """(stage, E row (n,), F row (m,)) of the constraint ``cid`` as an equality row n^T z - b = 0
        (stage N: a final row on x_N, F row empty)."""
        n, m, N = self.n, self.m, self.N
        if cid >= self.own_base:
            if cid < self.own_final:
                k, i = divmod(cid - self.own_base, self.ne0)
                return k, self.qp.E[k, i], self.qp.F[k, i]
            return N, self.qp.EN[cid - self.own_final], np.zeros(0)
        side, j = divmod(cid, self.nw)
        sign = 1.0 if side == 0 else -1.0
        kind, k, i = self.kind(j)
        e, f = np.zeros(n), np.zeros(m if k < N else 0)
        if kind == "x":
            e[i] = sign
        elif kind == "u":
            f[i] = sign
        elif kind == "c":
            e[:] = sign * self.Cn[k, i, :n]; f[:] = sign * self.Cn[k, i, n:]
        else:
            e[:] = sign * self.CNn[i]
        return k, e, f

    def rows(self, ids):
        """:meth:`row` of many inequality sides at once: (stages (len,), E rows (len, n), F rows
        (len, m))."""
        n, m, N, nw, o = self.n, self.m, self.N, self.nw, self.offsets
        side, j = np.divmod(np.asarray(ids, dtype=np.int64), nw)
        sign = 1.0 - 2.0 * side
        k = np.empty(j.size, dtype=np.int64)
        E, F = np.zeros((j.size, n)), np.zeros((j.size, m))
        r = np.arange(j.size)
        x, u, c, cN = j < o[1], (j >= o[1]) & (j < o[2]), (j >= o[2]) & (j < o[3]), j >= o[3]
        k[x] = j[x] // n + 1
        E[r[x], j[x] % n] = sign[x]
        ju = j[u] - o[1]
        k[u] = ju // m
        F[r[u], ju % m] = sign[u]
        if self.nc:
            kc, ic = np.divmod(j[c] - o[2], self.nc)
            k[c] = kc
            E[c] = sign[c, None] * self.Cn[kc, ic, :n]
            F[c] = sign[c, None] * self.Cn[kc, ic, n:]
        k[cN] = N
        if self.ncN:
            E[cN] = sign[cN, None] * self.CNn[j[cN] - o[3]]
        return k, E, F

    def stage(self, cid):
        """The stage of the constraint ``cid`` (N: a row on x_N)."""
        if cid >= self.own_base:
            return (cid - self.own_base) // self.ne0 if cid < self.own_final else self.N
        return self.kind(cid % self.nw)[1]

    def base_ids(self):
        """The ids of the base rows (always in the working set): the QP's own stage and final rows,
        then the fixed entries (lower-side ids)."""
        own = list(range(self.own_base, self.n_ids))
        return own + [int(j) for j in np.nonzero(self.fixed)[0]]

    # ------------------------------------------------------------------ values
    def values(self, X, U):
        """w at (X, U) (normalized general rows)."""
        parts = [X[1:].ravel(), U.ravel()]
        if self.nc:
            parts.append(np.einsum("kij,kj->ki", self.Cn, np.concatenate([X[:-1], U], axis=1)).ravel())
        if self.ncN:
            parts.append(self.CNn @ X[-1])
        return np.concatenate(parts)

    def slacks(self, w):
        """The slacks n^T z - b of every side, lower sides then upper sides (+inf where absent)."""
        with np.errstate(invalid="ignore"):
            return np.concatenate([np.where(self.has_lo, w - self.lo, np.inf), np.where(self.has_hi, self.hi - w, np.inf)])

    def gradient_term(self, cid, weight, q, r):
        """Add weight * n_cid to the gradient (q, r) in place (the objective of the EQP along
        Goldfarb and Idnani's path: gradient g - u_p n_p)."""
        k, e, f = self.row(cid)
        q[k] += weight * e
        if k < self.N:
            r[k] += weight * f
