"""The primal-dual Newton step of the barrier problem on the Riccati back-end, with IPOPT's
inertia correction (Waechter and Biegler 2006, sec. 2.2 and 3.1).

The primal-dual system (11) of the barrier problem, with the bound multipliers eliminated
(eq. (13)), reads for the DOCP of paper 001 (variables y = (x^1..x^N, u^0..u^{N-1}), x^0 fixed,
constraints the dynamics h^k = f^k(x^k, u^k) - x^{k+1} = 0):

    [W + Sigma + delta_w I   J^T] [dy      ]     [grad phi_mu]
    [J                       0  ] [lam + dl] = - [h          ]

with W the Hessian of the Lagrangian, Sigma = Z_L / S_L + Z_U / S_U (eq. (12)) and grad phi_mu
the gradient of the barrier function. This is the KKT system of an LQ-DOCP -- the stage blocks
of W as Q, S, R, Sigma (+ delta_w) as the diagonal terms Dx, Du, grad phi_mu as q, r, h as the
dynamics offsets c -- so one block Riccati factorization (olado.linalg, ``make_kkt_solver``)
replaces IPOPT's sparse LDL^T. The factorization succeeds exactly when the reduced Hessian on
the null space of the linearized dynamics is positive definite, i.e. when the KKT matrix has
IPOPT's desired inertia (n, N n, 0): its ``NotPositiveDefiniteError`` is the inertia test.
The solution's multipliers are lam + d_lam directly (the LQ-DOCP's multiplier convention is the
one of olado.solvers.common).

Inertia correction: Algorithm IC of sec. 3.1 (delta_w only; the dynamics Jacobian always has
full row rank -- the -I of x^{k+1} -- so delta_c is never needed for it).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ...linalg.backend import NotPositiveDefiniteError, make_kkt_solver
from .barrier import NO_POINT, _kernels


@dataclasses.dataclass(frozen=True)
class InertiaConstants:
    """Algorithm IC's constants (IPOPT's defaults: first_hessian_perturbation, min/max_hessian_perturbation,
    perturb_inc_fact_first, perturb_inc_fact, perturb_dec_fact)."""

    delta_0: float = 1e-4
    delta_min: float = 1e-20
    delta_max: float = 1e20
    kappa_plus_first: float = 100.0
    kappa_plus: float = 8.0
    kappa_minus: float = 1.0 / 3.0


@dataclasses.dataclass
class Constraints:
    """The linearized stage and final constraints of an iteration: equality rows (E, F) of the
    stage equalities and EN of the final ones (the Riccati recursion's equality rows), the
    inequality rows (Ci = [C_x C_u] (N, ni, n+m), CNi (niN, n)) with the slack Sigma Ss (N, ni),
    SsN (niN,) (v_L / s, eq. (12) for the slacks)."""

    E: np.ndarray
    F: np.ndarray
    EN: np.ndarray
    Ci: np.ndarray
    CNi: np.ndarray
    Ss: np.ndarray
    SsN: np.ndarray

    @classmethod
    def none(cls, N, n, m):
        return cls(np.zeros((N, 0, n)), np.zeros((N, 0, m)), np.zeros((0, n)), np.zeros((N, 0, n + m)),
                   np.zeros((0, n)), np.zeros((N, 0)), np.zeros(0))


class Direction(NamedTuple):
    """The Newton system's right-hand side in y (q, r) and s (gs, gsN), and grad phi flat."""

    q: np.ndarray
    r: np.ndarray
    gs: np.ndarray
    gsN: np.ndarray
    grad: np.ndarray


class Residuals(NamedTuple):
    """The constraint residuals of the Newton system's right-hand side: dynamics h (N, n),
    stage equalities e (N, ne), final equalities eN (neN,), and the inequality rows d - s
    (N, ni) and d_N - s_N (niN,)."""

    h: np.ndarray
    e: np.ndarray
    eN: np.ndarray
    d: np.ndarray
    dN: np.ndarray

    def combine(self, alpha, other):
        """alpha * self + other (the accumulated offsets of the second-order correction (27))."""
        return Residuals(*(alpha * a + b for a, b in zip(self, other)))

    def l1(self):
        """sum(np.abs(a).sum() for a in self), compiled (kernels.residual_norms: the same sums)."""
        return self.norms()[0]

    def max(self):
        """max(np.abs(a).max() for the non-empty a, default 0), compiled (kernels.residual_norms)."""
        return self.norms()[1]

    def norms(self):
        """(l1, max) in one compiled pass (kernels.residual_norms in kernels.point_terms, here
        without a point)."""
        l1, mx, _, _ = _kernels().point_terms(*NO_POINT, *self)
        return float(l1), float(mx)


class Step(NamedTuple):
    """A solution of the Newton system: the primal steps dX (N+1, n) (dX[0] = 0), dU, ds (N, ni),
    dsN (niN,) and the new multipliers lam (N+1, n) (dynamics), nu (N, ne), nuN (neN,) of the
    equalities and yd (N, ni), ydN (niN,) of the inequality rows d - s = 0."""

    dX: np.ndarray
    dU: np.ndarray
    ds: np.ndarray
    dsN: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    nuN: np.ndarray
    yd: np.ndarray
    ydN: np.ndarray


@dataclasses.dataclass
class KKTMatrix:
    """One iteration's LQ-DOCP matrix: Hessian blocks Q (N+1, n, n), S (N, n, m), R (N, m, m),
    dynamics A, B, the barrier diagonal Sigma as Sx (N+1, n) (row 0 unused: x^0 is fixed),
    Su (N, m), and the constraints (:class:`Constraints`; their slacks eliminated, below).
    ``factor`` factors it with the inertia correction; ``solve`` solves for a right-hand side.

    Slacks (Waechter and Biegler sec. 3.4; the rows d(y) - s = 0 of the inequalities g >= 0):
    with Ss' = Ss + delta_w the slack rows eliminate to yd^+ = Ss' ds + grad_s phi and
    ds = J_d dy + (d - s), which leaves J_d^T Ss' J_d in the Hessian and the gradient term
    J_d^T (Ss' (d - s) + grad_s phi): the Riccati recursion's stage inequality term
    1/2 sigma |C z + ci|^2 with sigma = Ss', ci = (d - s) + grad_s phi / Ss'; the final rows are
    added to Q_N and q_N. The equality rows are the recursion's equality rows E z + e = 0."""

    Q: np.ndarray
    S: np.ndarray
    R: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Sx: np.ndarray
    Su: np.ndarray
    cons: Constraints = None
    backend: str = "riccati"
    kkt: object = None
    delta: float = 0.0
    factorizations: int = 0
    #: the previous iteration's matrix, whose factorization (back-end object and work arrays)
    #: this one takes over instead of building its own (:meth:`_take_over`)
    reuse: "KKTMatrix" = None
    #: whether :meth:`release_blocks` let the blocks go
    released: bool = False

    def __post_init__(self):
        N, n, m = self.B.shape
        if self.cons is None:
            self.cons = Constraints.none(N, n, m)
        c = self.cons
        #: Q[N] without the final rows' slack weights (:meth:`_final_block`; without final rows Q[N] stays)
        self.QN = self.Q[N].copy() if c.CNi.shape[0] else None
        #: the dynamics alone (no equality, inequality or final rows) on the Riccati back-end: the
        #: factorization's and the solve's short paths (:meth:`try_factor`, :meth:`_solve_dynamics_only`)
        self.plain = self.backend == "riccati" and not (c.E.shape[1] or c.EN.shape[0] or c.Ci.shape[1] or
                                                        c.CNi.shape[0])

    def _final_block(self, delta):
        """Q[N] = QN + CNi' (SsN + delta) CNi: the final inequality rows' slack weights."""
        c = self.cons
        N = self.B.shape[0]
        if c.CNi.shape[0]:
            self.Q[N] = self.QN + c.CNi.T @ ((c.SsN + delta)[:, None] * c.CNi)

    def _diagonals(self, delta):
        Dx = self.Sx + delta
        Dx[0] = 0.0
        self._final_block(delta)
        return Dx, self.Su + delta, self.cons.Ss + delta

    def _take_over(self):
        """Take over the back-end of ``reuse`` (same shapes): the back-end gets this matrix's
        blocks (Riccati: ``set_blocks``, by reference; their rows copied into its arrays), so the
        next factorization is a ``refactor`` -- no new back-end object, validation or factor arrays
        per iteration. ``reuse`` can no longer solve afterwards (its back-end is gone)."""
        old, self.reuse = self.reuse, None
        kkt = old.kkt if old is not None else None
        c, oc = self.cons, old.cons if old is not None else None
        if kkt is None or self.backend != "riccati" or old.backend != self.backend or \
                old.Q.shape != self.Q.shape or oc.Ci.shape != c.Ci.shape or oc.E.shape != c.E.shape or \
                oc.EN.shape != c.EN.shape:
            return None
        d = kkt.set_blocks(self.Q, self.S, self.R, self.A, self.B).data
        self.Q = d.Q        # the same array unless it had to be made contiguous (_diagonals writes Q[N])
        if c.E.shape[1] or c.EN.shape[0]:
            for name, held in (("E", d.E), ("F", d.F), ("EN", d.EN)):
                np.copyto(held, getattr(c, name))
        if c.Ci.shape[1]:
            np.copyto(d.Ci, c.Ci)
        old.kkt = None
        return kkt

    def release_blocks(self, sigma=True):
        """Let this matrix's blocks go (Q, S, R and the Jacobians A, B, here and in its Riccati
        back-end; with ``sigma`` the barrier diagonals Sx, Su too) once its iteration has taken its
        step, before the new point's derivatives are evaluated: the next matrix takes the back-end
        over (:meth:`_take_over`, which needs only their shapes), so one generation of blocks less
        is alive at the peak. This matrix can no longer factor or solve. A second call does nothing."""
        if self.released:
            return
        self.released = True
        if sigma:
            from ...linalg.riccati import _placeholder  # noqa: PLC0415 - only where one is made (not per
                                                        # iteration at small N: the back-end's are reused)
            self.Sx, self.Su = _placeholder(self.Sx.shape), _placeholder(self.Su.shape)
        if self.kkt is not None and self.backend == "riccati":
            d = self.kkt.release_blocks().data
            if d.Q.shape == self.Q.shape:   # the back-end held these blocks: its placeholders are theirs
                self.Q, self.S, self.R, self.A, self.B = d.Q, d.S, d.R, d.A, d.B
                return
        from ...linalg.riccati import _placeholder  # noqa: PLC0415

        self.Q, self.S, self.R, self.A, self.B = (_placeholder(a.shape)
                                                  for a in (self.Q, self.S, self.R, self.A, self.B))

    def release_costs(self):
        """After a successful factorization whose solves read no cost blocks -- the Riccati
        back-end's plain recursion of small blocks (RiccatiFactorization.release_costs) -- let Q,
        S, R go here and in the back-end (a third of the matrix's memory, not needed through the
        line search); True when they went. The matrix solves as before; it factors again only
        after :meth:`_take_over` gave its back-end new blocks."""
        if not self.plain or self.kkt is None or not self.kkt.release_costs():
            return False
        d = self.kkt.data
        self.Q, self.S, self.R = d.Q, d.S, d.R
        return True

    def _diagonals_into(self, delta, Dx, Du):
        """:meth:`_diagonals` written into the back-end's arrays Dx, Du (the same values; no new
        arrays for the back-end to validate); returns the slack rows' weights (None without)."""
        _kernels().shifted_diagonals(self.Sx, self.Su, float(delta), Dx, Du)   # np.add's sums, Dx[0] = 0
        self._final_block(delta)
        c = self.cons
        return c.Ss + delta if c.Ci.shape[1] else None

    def try_factor(self, delta) -> bool:
        """Factor with delta_w = delta; False when the inertia is wrong (reduced Hessian not
        positive definite)."""
        c = self.cons
        self.factorizations += 1
        try:
            if self.kkt is None and self.reuse is not None:
                self.kkt = self._take_over()
            if self.plain and self.kkt is not None:
                # :meth:`_diagonals_into` and the back-end's refactor without rows: the shifted
                # diagonals written into the back-end's Dx, Du (Q[N] is QN: no final rows), factored
                d = self.kkt.data
                _kernels().shifted_diagonals(self.Sx, self.Su, float(delta), d.Dx, d.Du)
                self.kkt.refactor_in_place()
                self.delta = delta
                return True
            if self.kkt is not None and self.backend == "riccati":
                d = self.kkt.data
                self.kkt.refactor(Dx=d.Dx, Du=d.Du, sigma=self._diagonals_into(delta, d.Dx, d.Du))
                self.delta = delta
                return True
            Dx, Du, sig = self._diagonals(delta)
            if self.kkt is None:
                kw = {}
                if c.E.shape[1] or c.EN.shape[0]:
                    kw.update(E=c.E, F=c.F, EN=c.EN)
                if c.Ci.shape[1]:
                    kw.update(Ci=c.Ci, sigma=sig)
                self.kkt = make_kkt_solver(self.backend, self.Q, self.S, self.R, self.A, self.B, Dx=Dx, Du=Du, **kw)
            else:
                self.kkt.refactor(Dx=Dx, Du=Du, sigma=sig if c.Ci.shape[1] else None)
        except NotPositiveDefiniteError:
            return False
        self.delta = delta
        return True

    def factor(self, delta_last, const=InertiaConstants()):
        """Algorithm IC (Waechter and Biegler 2006, sec. 3.1): delta_w = 0 first; then from
        delta_0 (the first time) or kappa_minus delta_last, raised by kappa_plus_first (first
        time) or kappa_plus until the inertia is right. Returns delta_w, or None when it would
        exceed delta_max (the caller starts the restoration phase)."""
        if self.try_factor(0.0):
            return 0.0
        delta = const.delta_0 if delta_last == 0.0 else max(const.delta_min, const.kappa_minus * delta_last)
        while delta <= const.delta_max:
            if self.try_factor(delta):
                return delta
            delta *= const.kappa_plus_first if delta_last == 0.0 else const.kappa_plus
        return None

    def solve(self, q, r, res: Residuals, gs=None, gsN=None, out=None) -> Step:
        """Solve for the gradient rows q (N+1, n), r (N, m) of the barrier function in y, its
        gradient gs (N, ni), gsN (niN,) in the slacks, and the constraint residuals ``res``,
        with dx^0 = 0. ``out``: C-contiguous float64 arrays (dX (N+1, n), dU (N, m), lam (N+1, n))
        the step is written into (Riccati back-end; new arrays otherwise)."""
        if self.plain:
            return self._solve_dynamics_only(q, r, res, out)
        c, d = self.cons, self.delta
        N, n, m = self.B.shape
        gs = np.zeros(c.Ss.shape) if gs is None else gs
        gsN = np.zeros(c.SsN.shape) if gsN is None else gsN
        ss, ssN = c.Ss + d, c.SsN + d
        q = q.copy()
        if c.CNi.shape[0]:
            q[N] += c.CNi.T @ (ssN * res.dN + gsN)
        kw = {}
        if c.E.shape[1] or c.EN.shape[0]:
            kw.update(e=res.e, eN=res.eN)
        if c.Ci.shape[1]:
            kw.update(ci=res.d + gs / ss)
        if self.backend == "riccati":
            # the back-end's solve without its argument checks (the arrays are C-contiguous float64
            # of the system's shapes: the Newton right-hand side's, made here or by the solver)
            data = self.kkt.data
            rhs = (q, np.ascontiguousarray(r, dtype=float), np.ascontiguousarray(res.h, dtype=float), np.zeros(n),
                   np.ascontiguousarray(kw["e"], dtype=float) if "e" in kw else np.zeros((N, data.ne_max)),
                   np.ascontiguousarray(kw["eN"], dtype=float) if "eN" in kw else np.zeros(data.neN),
                   np.ascontiguousarray(kw["ci"], dtype=float) if "ci" in kw else np.zeros(data.sig.shape))
            X, U, lam = (np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n))) if out is None else out
            nu = np.empty((N + 1, max(data.ne_max, data.neN)))
            self.kkt.solve_into(rhs, (X, U, lam, nu))
        else:
            sol = self.kkt.solve(q, r, res.h, np.zeros(n), **kw)
            X, U, lam, nu = sol.X, sol.U, sol.lam, sol.nu
        ne, neN = c.E.shape[1], c.EN.shape[0]
        if c.Ci.shape[1]:
            dz = np.concatenate([X[:N], U], axis=1)
            ds = np.einsum("kij,kj->ki", c.Ci, dz) + res.d
        else:
            ds = np.zeros((N, 0))
        dsN = c.CNi @ X[N] + res.dN if c.CNi.shape[0] else np.zeros(0)
        return Step(X, U, ds, dsN, lam, nu[:N, :ne].copy(), nu[N, :neN].copy(), ss * ds + gs, ssN * dsN + gsN)


    def _solve_dynamics_only(self, q, r, res, out=None):
        """:meth:`solve` without constraint rows (the dynamics alone): the back-end's solve_into
        on the right-hand side (q, r, h), the empty row parts of the Step as they would be."""
        N, n, m = self.B.shape
        X, U, lam = (np.empty((N + 1, n)), np.empty((N, m)), np.empty((N + 1, n))) if out is None else out
        none, noneN, x0, nu = _empty_parts(N, n)
        # q as it is: the plain recursion's solve reads the right-hand side only
        self.kkt.solve_into((np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(r, dtype=float),
                             np.ascontiguousarray(res.h, dtype=float), x0, none, noneN, none), (X, U, lam, nu))
        return Step(X, U, none, noneN, lam, none, noneN, none, noneN)


_EMPTY_PARTS = {}


def _empty_parts(N, n):
    """The row parts of a solve without constraint rows -- (N, 0), (0,) and the (N+1, 0) nu, empty
    arrays nothing writes into -- and the zero initial step dx^0 (n,), which the solve only reads:
    made once per (N, n), shared by every such solve."""
    parts = _EMPTY_PARTS.get((N, n))
    if parts is None:
        parts = _EMPTY_PARTS[(N, n)] = (np.zeros((N, 0)), np.zeros(0), np.zeros(n), np.empty((N + 1, 0)))
    return parts


def stage_blocks(Hxx, Hxu, Huu, HN, Q=None):
    """Q (N+1, n, n) with the final block (into ``Q`` if given), S, R from the stage Hessian blocks."""
    N, n = Hxx.shape[0], Hxx.shape[1]
    if Q is None:
        Q = np.empty((N + 1, n, n))
    Q[:N] = Hxx
    Q[N] = HN
    return Q, np.ascontiguousarray(Hxu), np.ascontiguousarray(Huu)
