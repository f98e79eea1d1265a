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

import numpy as np

from ...linalg.backend import NotPositiveDefiniteError, make_kkt_solver


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
class KKTMatrix:
    """One iteration's LQ-DOCP matrix: Hessian blocks Q (N+1, n, n), S (N, n, m), R (N, m, m),
    dynamics A, B, and the barrier diagonal Sigma as Sx (N+1, n) (row 0 unused: x^0 is fixed),
    Su (N, m). ``factor`` factors it with the inertia correction; ``solve`` solves for a
    right-hand side with the factors."""

    Q: np.ndarray
    S: np.ndarray
    R: np.ndarray
    A: np.ndarray
    B: np.ndarray
    Sx: np.ndarray
    Su: np.ndarray
    backend: str = "riccati"
    kkt: object = None
    delta: float = 0.0
    factorizations: int = 0

    def _diagonals(self, delta):
        Dx = self.Sx + delta
        Dx[0] = 0.0
        return Dx, self.Su + delta

    def try_factor(self, delta) -> bool:
        """Factor with delta_w = delta; False when the inertia is wrong (reduced Hessian not
        positive definite)."""
        Dx, Du = self._diagonals(delta)
        self.factorizations += 1
        try:
            if self.kkt is None:
                self.kkt = make_kkt_solver(self.backend, self.Q, self.S, self.R, self.A, self.B, Dx=Dx, Du=Du)
            else:
                self.kkt.refactor(Dx=Dx, Du=Du)
        except NotPositiveDefiniteError:
            self.kkt = None if self.kkt is None else self.kkt
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

    def solve(self, q, r, c):
        """Solve for the gradient rows (q (N+1, n), r (N, m)) and the dynamics offsets c (N, n)
        with dx^0 = 0: (dX (N+1, n), dU (N, m), lam (N+1, n)), lam[k+1] the new multiplier of
        the dynamics of stage k."""
        sol = self.kkt.solve(q, r, c, np.zeros(self.Q.shape[1]))
        return sol.X, sol.U, sol.lam


def stage_blocks(Hxx, Hxu, Huu, HN):
    """Q (N+1, n, n) with the final block, S, R from the stage Hessian blocks."""
    N, n = Hxx.shape[0], Hxx.shape[1]
    Q = np.empty((N + 1, n, n))
    Q[:N] = Hxx
    Q[N] = HN
    return Q, np.ascontiguousarray(Hxu), np.ascontiguousarray(Huu)
