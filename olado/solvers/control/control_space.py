"""The DOCP as a function of the controls only (paper 001 sec. 2.2, "reduced gradient").

The states are eliminated by simulation, x^{k+1} = f^k(x^k, u^k) from the fixed x^0, which leaves
the unconstrained problem  min_u J(u) = sum_k f_0^k(x^k(u), u^k) + F^N(x^N(u)).

* :meth:`ReducedProblem.gradient` -- the reduced gradient by the backward adjoint (costate)
  recursion (Findeisen et al. 1980; Bryson 1998):

      p^N = F_x(x^N),   p^k = f0_x^k + (f_x^k)^T p^{k+1},   dJ/du^k = f0_u^k + (f_u^k)^T p^{k+1}

* :meth:`ReducedProblem.hessian_vector` -- the product of the reduced Hessian with a direction
  v by the second-order adjoint: a forward sweep of the state perturbation and a backward sweep
  of the costate perturbation, with the stage Hessians of H^k = f0^k + p^{k+1}.f^k:

      dx^0 = 0,   dx^{k+1} = f_x dx^k + f_u v^k
      dp^N = F_xx dx^N,   dp^k = H_xx dx^k + H_xu v^k + f_x^T dp^{k+1}
      (Hv)^k = H_ux dx^k + H_uu v^k + f_u^T dp^{k+1}

Both cost O(N) (stage derivatives for all stages at once, one compiled sweep). The methods of the
control-space family (gradient, conjugate gradients, variable metric, Newton-CG, PDMIN) and the
penalty method are built on this class. It only uses the problem's public eval_* methods.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def _adjoint(lx, lu, A, B, pN, p, g):
    """Backward costate sweep: p (N+1, n) and the reduced gradient g (N, m)."""
    N, n = lx.shape
    m = lu.shape[1]
    for i in range(n):
        p[N, i] = pN[i]
    for k in range(N - 1, -1, -1):
        for j in range(n):
            s = lx[k, j]
            for i in range(n):
                s += A[k, i, j] * p[k + 1, i]
            p[k, j] = s
        for j in range(m):
            s = lu[k, j]
            for i in range(n):
                s += B[k, i, j] * p[k + 1, i]
            g[k, j] = s


@nb.njit(cache=True)
def _second_order_adjoint(A, B, Hxx, Hxu, Huu, HN, V, dx, dp, out):
    """Forward perturbation sweep then backward costate-perturbation sweep (module docstring)."""
    N, n = A.shape[0], A.shape[1]
    m = B.shape[2]
    for i in range(n):
        dx[0, i] = 0.0
    for k in range(N):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += A[k, i, j] * dx[k, j]
            for j in range(m):
                s += B[k, i, j] * V[k, j]
            dx[k + 1, i] = s
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += HN[i, j] * dx[N, j]
        dp[N, i] = s
    for k in range(N - 1, -1, -1):
        for j in range(n):
            s = 0.0
            for i in range(n):
                s += Hxx[k, j, i] * dx[k, i] + A[k, i, j] * dp[k + 1, i]
            for i in range(m):
                s += Hxu[k, j, i] * V[k, i]
            dp[k, j] = s
        for j in range(m):
            s = 0.0
            for i in range(n):
                s += Hxu[k, i, j] * dx[k, i] + B[k, i, j] * dp[k + 1, i]
            for i in range(m):
                s += Huu[k, j, i] * V[k, i]
            out[k, j] = s


def unsupported_features(problem, control_bounds=False) -> list:
    """What ``problem`` has beyond an unconstrained control-space problem (empty: nothing);
    ``control_bounds=True`` for methods that handle simple control bounds (PDMIN)."""
    out = []
    if problem.r:
        out.append(f"{problem.r} stage constraints g^k")
    if problem.rN:
        out.append(f"{problem.rN} final constraints g^N")
    if not control_bounds and (np.isfinite(problem.u_lower).any() or np.isfinite(problem.u_upper).any()):
        out.append("bounds on the controls")
    if np.isfinite(problem.x_lower[1:]).any() or np.isfinite(problem.x_upper[1:]).any():
        out.append("bounds on the states")
    return out


class ReducedProblem:
    """J(u) of a DOCP with the states eliminated; caches the last point's derivatives. With
    ``limits`` (:class:`olado.interrupts.Limits`) every evaluation is followed by its check: the
    solve stops within one evaluation of its time limit or an interrupt (line searches and the
    Newton-CG products included)."""

    def __init__(self, problem, limits=None):
        self.problem = problem
        self.limits = limits
        self.N, self.n, self.m = problem.N, problem.n, problem.m
        self._key = None
        self.n_value = self.n_gradient = self.n_hessvec = 0

    # ------------------------------------------------------------------ values
    def states(self, U):
        return self.problem.simulate(U)

    def value(self, U):
        """J(u) and the simulated states."""
        X = self.problem.simulate(U)
        self.n_value += 1
        J = self.problem.objective(X, U)
        self._check()
        return J, X

    def _check(self):
        if self.limits is not None:
            self.limits.check()

    # ------------------------------------------------------------------ first order
    def gradient(self, U, X=None):
        """(J, dJ/du (N, m), X (N+1, n), costates p (N+1, n)) by the adjoint recursion."""
        p = self.problem
        U = np.ascontiguousarray(U, dtype=float)
        if X is None:
            X = p.simulate(U)
        J = p.objective(X, U)
        lx, lu = p.eval_stage_cost_gradients(X, U)
        A, B = p.eval_dynamics_jacobians(X, U)
        pN = p.eval_final_cost_gradient(X[-1])
        costate = np.empty((self.N + 1, self.n))
        g = np.empty((self.N, self.m))
        _adjoint(np.ascontiguousarray(lx), np.ascontiguousarray(lu), np.ascontiguousarray(A), np.ascontiguousarray(B),
                 np.ascontiguousarray(pN), costate, g)
        self.n_gradient += 1
        self._key = (U.tobytes(), X, A, B, costate)
        self._hess = None
        self._check()
        return J, g, X, costate

    # ------------------------------------------------------------------ second order
    def _hessian_blocks(self, U, X, costate):
        if self._hess is None:
            Hxx, Hxu, Huu = self.problem.eval_stage_hessians(X, U, 1.0, costate[1:])
            HN = self.problem.eval_final_hessian(X[-1], 1.0)
            self._hess = tuple(np.ascontiguousarray(a) for a in (Hxx, Hxu, Huu, HN))
        return self._hess

    def hessian_vector(self, U, V):
        """Reduced Hessian times V (N, m) at U, by the second-order adjoint. Uses the
        derivatives of the last :meth:`gradient` call when U is the same point."""
        U = np.ascontiguousarray(U, dtype=float)
        if self._key is None or self._key[0] != U.tobytes():
            self.gradient(U)
        _, X, A, B, costate = self._key
        Hxx, Hxu, Huu, HN = self._hessian_blocks(U, X, costate)
        dx = np.empty((self.N + 1, self.n)); dp = np.empty((self.N + 1, self.n)); out = np.empty((self.N, self.m))
        _second_order_adjoint(np.ascontiguousarray(A), np.ascontiguousarray(B), Hxx, Hxu, Huu, HN,
                              np.ascontiguousarray(V, dtype=float), dx, dp, out)
        self.n_hessvec += 1
        self._check()
        return out

    def stage_derivatives(self, U):
        """(X, A, B, costate, Hxx, Hxu, Huu, HN) at U -- for the dynamic-programming methods."""
        U = np.ascontiguousarray(U, dtype=float)
        if self._key is None or self._key[0] != U.tobytes():
            self.gradient(U)
        _, X, A, B, costate = self._key
        return (X, A, B, costate) + self._hessian_blocks(U, X, costate)
