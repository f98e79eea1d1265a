"""Explicit one-step integrators of a continuous-time model over all stages at once, and the
exact derivatives of their step maps.

A continuous-time problem  x' = f(x, u),  running cost L(x, u)  is discretized with piecewise-
constant controls on steps of length h by explicit Euler or by the classical Runge-Kutta method
(RK4). The running cost is integrated by the same scheme as a quadrature state c' = L, so one
step maps z = (x, u) to (x+, c) -- the next state and the stage cost f_0 of paper 001 eq. (1).

The model is given as one function of all stages' rows, ``rhs(X, U) -> F (K, n+1)`` with
F[:, :n] = f and F[:, n] = L, and for derivatives ``rhs_derivatives(X, U, order) -> (F, J, H)``
with J = dF/dz (K, n+1, n+m) and, for order 2, H = d2F/dz2 (K, n+1, n+m, n+m). The built-in ODE
problems (:mod:`olado.problems.testproblems`) and the literature problems
(:mod:`olado.problems.continuous`) share these functions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rk_step", "rk_step_derivatives"]

#: RK4 stage coefficients a_i (y_{i+1} = x + a_i h k_i) and weights b_i (times h/6)
_RK4_NODES = (0.5, 0.5, 1.0)
_RK4_WEIGHTS = (1.0, 2.0, 2.0, 1.0)


def rk_step(rhs, X, U, h, rk4=True):
    """One Euler or RK4 step from every row of X (K, n) under U (K, m): the next states (K, n)
    and the stage costs (K,), the quadrature of L over the step."""
    X = np.asarray(X, dtype=float)
    n = X.shape[1]
    k1 = rhs(X, U)
    if not rk4:
        return X + h * k1[:, :n], h * k1[:, n]
    k2 = rhs(X + 0.5 * h * k1[:, :n], U)
    k3 = rhs(X + 0.5 * h * k2[:, :n], U)
    k4 = rhs(X + h * k3[:, :n], U)
    inc = (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return X + inc[:, :n], inc[:, n]


def rk_step_derivatives(rhs_derivatives, X, U, h, rk4=True, order=1):
    """Derivatives of the step map z = (x, u) -> (x+, c) (K, n+1 outputs) by forward
    propagation through the Euler / RK4 stages: (D (K, n+1, n+m), D2 (K, n+1, n+m, n+m) or
    None). For RK4 with stage points w_i = (y_i, u), y_1 = x, y_{i+1} = x + a_i h k_i[:n],

        dk_i = F_z(w_i) W_i,   d2k_i = W_i' F_zz(w_i) W_i + F_z[:, :n](w_i) d2y_i,

    with W_i = dw_i/dz, and the step is (x, 0) + h/6 (k_1 + 2 k_2 + 2 k_3 + k_4)."""
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float)
    K, n, m = X.shape[0], X.shape[1], U.shape[1]
    nz = n + m
    E = np.zeros((n + 1, nz))
    E[np.arange(n), np.arange(n)] = 1.0
    if not rk4:
        _, J, H = rhs_derivatives(X, U, order)
        D = E + h * J
        return D, (h * H if order >= 2 else None)
    D = np.broadcast_to(E, (K, n + 1, nz)).copy()
    D2 = np.zeros((K, n + 1, nz, nz)) if order >= 2 else None
    Y = X
    W = np.zeros((K, nz, nz))          # dw/dz, w = (y, u)
    W[:, n:, n:] = np.eye(m)
    W[:, :n, :n] = np.eye(n)
    Y2 = None                          # d2y/dz2 (K, n, nz, nz); zero at the first stage
    for i in range(4):
        F, J, H = rhs_derivatives(Y, U, order)
        dk = np.matmul(J, W)                                  # (K, n+1, nz)
        if order >= 2:
            HW = np.matmul(H, W[:, None])                     # (K, n+1, nz, nz): F_zz W
            d2k = np.matmul(np.swapaxes(W, 1, 2)[:, None], HW)  # W' F_zz W
            if Y2 is not None:
                d2k += np.einsum("kab,kbij->kaij", J[:, :, :n], Y2)
        w = _RK4_WEIGHTS[i] * h / 6.0
        D += w * dk
        if order >= 2:
            D2 += w * d2k
        if i < 3:
            a = _RK4_NODES[i] * h
            Y = X + a * F[:, :n]
            W = W.copy()
            W[:, :n, :] = E[:n] + a * dk[:, :n]
            if order >= 2:
                Y2 = a * d2k[:, :n]
    return D, D2
