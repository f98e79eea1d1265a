"""The damped BFGS approximation B of the Lagrangian Hessian, the (1,1) block of FQLNK's KKT
matrix (seed 002 sec. 3.2; Nocedal and Wright 2006, Procedure 18.2).

With s = x^k - x^{k-1} and y = grad_x L(x^k, lam^k) - grad_x L(x^{k-1}, lam^k) (the seed's s^(k),
y^(k): the multipliers held at their new value), the curvature s'y > 0 is not guaranteed in the
constrained case, so y is replaced by

    r = theta y + (1 - theta) B s,
    theta = 1                                   if s'y >= 0.2 s'Bs,
          = 0.8 s'Bs / (s'Bs - s'y)             otherwise,

and B+ = B - B s s' B / (s'Bs) + r r' / (s'r). Then s'r >= 0.2 s'Bs > 0, so B+ is symmetric
positive definite whenever B is, and B+ s = r (the secant equation with the damped r).

The seed fixes 0.2 / 0.8 (Powell's constants, "suggested by [20]"). Two variants the field uses
where the seed is silent, kept as options for measurement (docs/fqlnk.md, "Closing the iteration
gap"): another threshold t (theta = (1 - t) s'Bs / (s'Bs - s'y) below t s'Bs: s'r = t s'Bs), and
skipping the update instead of damping it (Nocedal and Wright sec. 18.3: B+ = B when
s'y < t s'Bs). And the scaling of a Hessian start after the first step, B^(0) <- (s'y / s'B s)
B^(0) when s'y > 0 (the Shanno-Phua / Oren-Luenberger factor: Nocedal and Wright eq. (6.20) is
its case B^(0) = I).

B is dense: the seed's full-space BFGS matrix, whose rank-two updates fill the (1,1) block.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

#: the damping threshold 0.2 and factor 0.8 of the seed's theta (Nocedal and Wright's choice)
DAMP_THRESHOLD = 0.2
DAMP_FACTOR = 0.8


class Update(NamedTuple):
    """One update: the new matrix, theta (1: undamped) and whether it was skipped (s'Bs <= 0:
    a zero step; or, with ``skip``, s'y below the threshold)."""

    B: np.ndarray
    theta: float
    skipped: bool


def damping_theta(sBs: float, sy: float, threshold: float = DAMP_THRESHOLD) -> float:
    """The seed's theta^(k) (sec. 3.2) for threshold 0.2; in general 1 when s'y >= t s'Bs, else
    (1 - t) s'Bs / (s'Bs - s'y), so that s'r = t s'Bs."""
    if sy >= threshold * sBs:
        return 1.0
    return (1.0 - threshold) * sBs / (sBs - sy)


def damped_bfgs_update(B, s, y, threshold: float = DAMP_THRESHOLD, skip: bool = False) -> Update:
    """B+ of the damped BFGS formula (module docstring). ``B`` dense symmetric positive definite;
    ``skip``: B unchanged where the formula would damp (s'y < threshold s'Bs)."""
    Bs = B @ s
    sBs = float(s @ Bs)
    if not sBs > 0.0 or not np.isfinite(sBs):
        return Update(B, 1.0, True)
    theta = damping_theta(sBs, float(s @ y), threshold)
    if skip and theta < 1.0:
        return Update(B, 1.0, True)
    r = theta * y + (1.0 - theta) * Bs
    sr = float(s @ r)
    B_new = B - np.outer(Bs, Bs) / sBs + np.outer(r, r) / sr
    return Update(0.5 * (B_new + B_new.T), theta, False)


def positive_definite_start(H, margin=1e-4):
    """B^(0) from a Hessian H. The seed builds it "by using the AD approach" (sec. 4.6) and says
    no more, but its BFGS needs B^(0) positive definite, and the Earth-to-Mars start's Hessian is
    indefinite. B^(0) = V max(|Lambda|, floor) V' for H = V Lambda V' (the modified Hessian of
    Nocedal and Wright sec. 3.4: negative eigenvalues flipped, the small ones raised to
    floor = margin max(1, max|H_ii|)), which keeps H's scale in every direction (a shift by
    -lambda_min I does not: it took twice the Newton iterations on Earth-to-Mars). Returns
    (B0 dense, the most negative eigenvalue of H or 0)."""
    B = H.toarray() if sp.issparse(H) else np.array(H, dtype=float)
    B = 0.5 * (B + B.T)
    if not B.size:
        return B, 0.0
    floor = margin * max(1.0, float(np.max(np.abs(np.diag(B)), initial=0.0)))
    w, V = np.linalg.eigh(B)
    if w[0] >= floor:
        return B, 0.0
    return (V * np.maximum(np.abs(w), floor)) @ V.T, float(max(0.0, -w[0]))


def scaled_identity_start(nv, s=None, y=None):
    """B^(0) = gamma I without a Hessian: gamma = y'y / s'y after the first step when s'y > 0
    (Nocedal and Wright eq. (6.20)), 1 before it."""
    gamma = 1.0
    if s is not None and y is not None:
        sy = float(s @ y)
        if sy > 0:
            gamma = float(y @ y) / sy
    return gamma * np.eye(nv)


def scaled_start(B0, s, y):
    """B^(0) (s'y / s'B^(0) s) before the first update, when both are positive; B^(0) unchanged
    otherwise (module docstring). Returns (B, the factor applied or 1)."""
    sy, sBs = float(s @ y), float(s @ (B0 @ s))
    if sy > 0.0 and sBs > 0.0 and np.isfinite(sy / sBs):
        gamma = sy / sBs
        return gamma * B0, gamma
    return B0, 1.0
