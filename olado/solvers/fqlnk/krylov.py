"""The Newton step of FQLNK (seed 002 sec. 3.3, Algorithm 1 step 4): K dp = -F solved inexactly,

    || F + K dp || <= eta_k || F ||,

by restarted GMRES (scipy.sparse.linalg.gmres) preconditioned by an incomplete LU
factorization with threshold and pivoting of K itself (ILUTP, Saad 2003 sec. 10.4: SuperLU's
ILU through scipy.sparse.linalg.spilu: drop tolerance tau, fill factor, column ordering,
threshold partial pivoting). The seed: tau = 1e-6, eta_k = 1e-6.

A breakdown -- the ILU finding a zero pivot, GMRES not reaching eta_k -- is reported in the
returned :class:`KKTSolve`, never raised: the solver turns it into a status.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


class KKTSolve(NamedTuple):
    """A step dp (None when the preconditioner failed), the GMRES iterations, the achieved
    relative residual ||F + K dp|| / ||F||, whether eta_k was met, a sentence on a failure,
    and the time of the assembly + ILU and of GMRES."""

    dp: np.ndarray | None
    iterations: int
    relative_residual: float
    converged: bool
    message: str
    ilu_time: float
    gmres_time: float


def kkt_matrix(H, G):
    """K = [[H, G^T], [G, 0]] (seed's Algorithm 1, step 3), CSC."""
    H = sp.csr_matrix(H) if not sp.issparse(H) else H
    return sp.bmat([[H, G.T], [G, None]], format="csc")


def incomplete_lu(K, o):
    """SuperLU's ILUTP of K; a factorization that fails ("Factor is exactly singular": a pivot
    dropped to zero, typically where the fill limit cut a column short -- the dense BFGS block
    at large N) is tried again with the fill factor tripled, ``ilu_retries`` times. A sentence
    when every try fails."""
    fill = o.ilu_fill_factor
    for attempt in range(o.ilu_retries + 1):
        try:
            return spla.spilu(K, drop_tol=o.ilu_drop_tol, fill_factor=fill, permc_spec=o.ilu_permc_spec,
                              diag_pivot_thresh=o.ilu_pivot_threshold)
        except RuntimeError as exc:        # SuperLU: "Factor is exactly singular" and the like
            error = exc
            fill *= 3.0
    return (f"the ILUTP factorization of the KKT matrix failed ({error}; fill factor up to "
            f"{fill / 3.0:g}, drop tolerance {o.ilu_drop_tol:g})")


def solve_kkt(K, F, options) -> KKTSolve:
    """dp with || F + K dp || <= eta || F || (module docstring); ``options``: the solver's
    (forcing, ilu_drop_tol, ilu_fill_factor, ilu_permc_spec, ilu_pivot_threshold, gmres_restart,
    gmres_max_iter)."""
    o = options
    t0 = time.perf_counter()
    ilu = incomplete_lu(K, o)
    if isinstance(ilu, str):
        return KKTSolve(None, 0, np.inf, False, ilu, time.perf_counter() - t0, 0.0)
    t1 = time.perf_counter()
    M = spla.LinearOperator(K.shape, matvec=ilu.solve, dtype=float)
    count = [0]

    def tick(_):
        count[0] += 1

    rhs = -F
    norm = float(np.linalg.norm(F))
    with np.errstate(all="ignore"):
        dp, info = spla.gmres(K, rhs, rtol=o.forcing, atol=0.0, restart=o.gmres_restart, maxiter=o.gmres_max_iter,
                              M=M, callback=tick, callback_type="pr_norm")
    t2 = time.perf_counter()
    if not np.all(np.isfinite(dp)):
        return KKTSolve(None, count[0], np.inf, False, "GMRES broke down: the step is not finite", t1 - t0, t2 - t1)
    rel = float(np.linalg.norm(F + K @ dp)) / norm if norm > 0 else 0.0
    ok = info == 0 or rel <= o.forcing
    msg = "" if ok else (f"GMRES stopped after {count[0]} iterations at relative residual {rel:.2e} > forcing term "
                         f"eta = {o.forcing:g} (info {info})")
    return KKTSolve(dp, count[0], rel, ok, msg, t1 - t0, t2 - t1)
