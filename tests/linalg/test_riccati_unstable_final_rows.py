"""A known inaccuracy of the general (equality-row) Riccati recursion, found through ipm on
alp-rider (docs/interior-point-nlp.md, "What is left"): with unstable dynamics and final equality
rows, the KKT residual of the solution's control rows grows with N (4e-16, 4e-13, 8e-7, 0.33 of the
rows' terms at N = 10, 30, 60, 100 below), while the plain recursion (no equality rows) stays at
rounding level (6e-17).
The data are alp-rider's RK4 dynamics blocks (eigenvalues 1.49 and 0.27 of the coupled pair) held
constant, the least-squares system of ipm's start (Q = 0, Dx = Du = 1) and its four final rows
x_i^N = const. The strict xfail turns into a failure once the recursion is fixed: then drop the
marker."""

import numpy as np
import pytest

from olado.linalg.backend import Solution
from olado.linalg.riccati import RiccatiFactorization

A0 = np.array([[0.333, 0, 0, 0, 0], [0, 0.67, 0, 0, 0], [0, 0, 0.881, 0.611, 0], [0, 0, 0.611, 0.881, 0],
               [0, 0, 0, 0, 1.0]])
B0 = np.array([[0.067, 0.067], [0.165, 0.33], [0.246, 0.063], [0.246, 0.428], [0, 0]])


def control_row_residual(N, final_rows=True):
    """The max-norm of the control rows' KKT residual of the recursion's solution, relative to the
    size of the rows' terms (RiccatiFactorization.kkt_residual)."""
    n, m = B0.shape
    A = np.broadcast_to(A0, (N, n, n)).copy()
    B = np.broadcast_to(B0, (N, n, m)).copy()
    Dx = np.ones((N + 1, n))
    Dx[0] = 0.0
    kw = {"EN": np.eye(n)[:4]} if final_rows else {}
    fac = RiccatiFactorization(np.zeros((N + 1, n, n)), np.zeros((N, n, m)), np.zeros((N, m, m)), A, B, Dx=Dx,
                               Du=np.ones((N, m)), **kw)
    rng = np.random.default_rng(0)
    q, r = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
    eN = np.zeros(4) if final_rows else None
    sol = fac.solve(q, r, np.zeros((N, n)), np.zeros(n), eN=eN)
    rhs = fac.data.rhs_arrays(q, r, np.zeros((N, n)), np.zeros(n), None, eN, None)
    resid, size, _ = fac.kkt_residual(rhs, Solution(sol.X, sol.U, sol.lam, sol.nu))
    return float(np.abs(resid.r).max()) / size


def test_the_plain_recursion_is_accurate_on_the_unstable_dynamics():
    assert control_row_residual(100, final_rows=False) < 1e-12


@pytest.mark.xfail(strict=True, reason="the general recursion loses the control rows on unstable dynamics with "
                                       "final equality rows (docs/interior-point-nlp.md, What is left)")
def test_the_general_recursion_is_accurate_on_the_unstable_dynamics_with_final_rows():
    assert control_row_residual(100) < 1e-10
