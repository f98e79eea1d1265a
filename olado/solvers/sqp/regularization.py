"""WORHP's Hessian regularization (seed 000, sec. IV.V) as a safeguard of the exact-Hessian SQP:

    H = H_L + tau (|sigma| + 1) I,                                                  [11]

sigma the Gerschgorin bound of the most negative eigenvalue of H_L, tau in [0, 1], and tau
updated from the agreement of the actual and the predicted reduction of the merit function M:

    rho_1 = M^[k-1] - M^[k]                                   (actual reduction,    [12])
    rho_2 = -dM/dalpha - 1/2 d^T H d                          (predicted reduction, [13])
    rho_3 = |grad L^[k]|_inf / |grad L^[k-1]|_inf             (rate of the Lagrangian gradient, [14])
    rho_1 <= 0.25 rho_2:  tau := min(theta tau, 1);    rho_1 >= 0.75 rho_2:  tau := tau min(1/theta, rho_3).

On the stage QP the shift is taken per stage block, delta_k >= tau (|sigma_k| + max|H|) with
sigma_k the Gerschgorin bound of block k (the Hessian (12) is block diagonal, so the blocks'
bounds bound its spectrum), and max|H| in place of WORHP's 1 (which presumes a scaled problem:
max|H| makes the shift independent of the objective's scale). With tau = 1 every block is
positive definite. Along the step of length alpha the predicted reduction is
-alpha D - alpha^2/2 s.H s.

tau is 0 -- the exact Hessian with the inertia correction (olado.solvers.sqp.step), unchanged --
until the SQP meets a step its quadratic model does not describe at all: a full QP step along
which the merit function grows by more than ``untrusted_growth`` (|phi| + |D|) (no Maratos
effect explains that; vanderpol's second QP step, 2e4 long, took phi from 12 to 3.5e76), or a QP
that fails even after the inertia correction. Then tau starts at ``tau_init`` (or grows by theta
= ``tau_increase``), the QP is solved again at the same point, and from there on tau follows the
rule above; it returns to 0 once it falls below ``tau_min`` (the model agreeing again, near a
solution rho_3 -> 0), so the local rate is the unregularized one.
"""

from __future__ import annotations

import numpy as np

from .step import curvature, shift_scale


def gerschgorin_bounds(Bk, BN):
    """sigma_k = min_i (h_ii - sum_{j != i} |h_ij|) of every stage block and of the final block
    (N + 1 values): a lower bound of the block's eigenvalues."""
    def bound(H):
        d = np.diagonal(H, axis1=-2, axis2=-1)
        off = np.sum(np.abs(H), axis=-1) - np.abs(d)
        return np.min(d - off, axis=-1)
    return np.concatenate([bound(Bk), [float(bound(BN))]])


def tau_shift(tau, Bk, BN, hscale):
    """The shift of eq. [11] per stage block: tau (|sigma_k| + max|H|) (0 when tau = 0)."""
    if tau <= 0.0:
        return np.zeros(len(Bk) + 1)
    return tau * (np.abs(gerschgorin_bounds(Bk, BN)) + shift_scale(hscale))


def raise_tau(tau, options):
    """tau after a step the model does not describe (or a failed QP): tau_init, or theta tau."""
    return min(1.0, max(options.tau_init, options.tau_increase * tau))


def untrusted(phi, phi0, D, options):
    """A trial merit value that no Maratos effect explains: non-finite, or more than
    ``untrusted_growth`` (|phi0| + |D|) above phi0."""
    return not np.isfinite(phi) or phi - phi0 > options.untrusted_growth * (abs(phi0) + abs(D))


def update_tau(tau, options, actual, alpha, D, sHs, kkt_ratio):
    """WORHP's update [12]-[14] after an accepted step of length alpha: ``actual`` = rho_1,
    the predicted reduction rho_2 = -alpha D - alpha^2/2 s.H s, ``kkt_ratio`` = rho_3."""
    if tau <= 0.0:
        return 0.0
    predicted = -alpha * D - 0.5 * alpha * alpha * sHs
    theta = options.tau_increase
    if actual <= 0.25 * predicted:
        tau = min(theta * tau, 1.0)
    elif actual >= 0.75 * predicted:
        tau = tau * min(1.0 / theta, kkt_ratio if np.isfinite(kkt_ratio) else 1.0)
    return tau if tau >= options.tau_min else 0.0


def step_curvature(Bk, BN, delta, dX, dU):
    """s.(H + delta) s of the QP Hessian the step was computed with (delta per stage block)."""
    sHs, _ = curvature(Bk, BN, dX, dU)
    z = np.concatenate([dX[:-1], dU], axis=1)
    return sHs + float(np.sum(delta[:-1] * np.einsum("ki,ki->k", z, z)) + delta[-1] * (dX[-1] @ dX[-1]))
