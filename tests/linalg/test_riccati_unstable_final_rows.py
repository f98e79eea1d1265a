"""Accuracy of the Riccati recursion on unstable dynamics, found through ipm on alp-rider
(docs/interior-point-nlp.md): alp-rider's RK4 dynamics blocks (eigenvalues 1.49 and 0.27 of the
coupled pair, a fifth clock-like state the controls do not reach) held constant, the
least-squares system of ipm's start (Q = 0, Dx = Du = 1) and its four final rows x_i^N = const.

The general recursion used to recover the dynamics multipliers lam_k by the x-stationarity rows'
backward recursion, which multiplies its rounding by (A^T)^(N-k): the control rows' relative KKT
residual was 4e-16, 4e-13, 8e-7, 0.33 at N = 10, 30, 60, 100 while X, U and nu were accurate.
The kernels now take lam_k = P_k x_k + p_k - G_k^T eta_k (olado.linalg.riccati_kernels._solve);
the checks below are the KKT residual and a dense solve of the same KKT system (assembled here
from the Lagrangian of olado.linalg.riccati's module docstring)."""

import numpy as np
import pytest

from olado.linalg.backend import Solution
from olado.linalg.riccati import RiccatiFactorization

A0 = np.array([[0.333, 0, 0, 0, 0], [0, 0.67, 0, 0, 0], [0, 0, 0.881, 0.611, 0], [0, 0, 0.611, 0.881, 0],
               [0, 0, 0, 0, 1.0]])
B0 = np.array([[0.067, 0.067], [0.165, 0.33], [0.246, 0.063], [0.246, 0.428], [0, 0]])


def problem(N, final_rows=True, copies=1):
    """The factorization and a random right-hand side (q, r; c = 0, x0 = 0, eN = 0); ``copies``
    > 1 repeats the blocks block-diagonally (n = 5 copies, m = 2 copies)."""
    A1, B1 = np.kron(np.eye(copies), A0), np.kron(np.eye(copies), B0)
    n, m = B1.shape
    A = np.broadcast_to(A1, (N, n, n)).copy()
    B = np.broadcast_to(B1, (N, n, m)).copy()
    Dx = np.ones((N + 1, n))
    Dx[0] = 0.0
    kw = {"EN": np.eye(n)[:4]} if final_rows else {}
    fac = RiccatiFactorization(np.zeros((N + 1, n, n)), np.zeros((N, n, m)), np.zeros((N, m, m)), A, B, Dx=Dx,
                               Du=np.ones((N, m)), **kw)
    rng = np.random.default_rng(0)
    q, r = rng.standard_normal((N + 1, n)), rng.standard_normal((N, m))
    return fac, q, r, (np.zeros(4) if final_rows else None)


def control_row_residual(N, final_rows=True, copies=1):
    """The max-norm of the control rows' KKT residual of the recursion's solution, relative to the
    size of the rows' terms (RiccatiFactorization.kkt_residual)."""
    fac, q, r, eN = problem(N, final_rows, copies)
    n = fac.n
    sol = fac.solve(q, r, np.zeros((N, n)), np.zeros(n), eN=eN)
    rhs = fac.data.rhs_arrays(q, r, np.zeros((N, n)), np.zeros(n), None, eN, None)
    resid, size, _ = fac.kkt_residual(rhs, Solution(sol.X, sol.U, sol.lam, sol.nu))
    return float(np.abs(resid.r).max()) / size


def dense_solution(N, q, r):
    """X, U, lam, nu_N of the KKT system with the final rows, by a dense solve: unknowns
    x_1..x_N, u_0..u_{N-1}, lam_0..lam_N, nu_N; rows: stationarity in x_k (q_k + Dx_k x_k - lam_k
    + A^T lam_{k+1}, at N: q_N + x_N - lam_N + E_N^T nu_N), in u_k (r_k + u_k + B^T lam_{k+1}),
    the dynamics A x_k + B u_k - x_{k+1} and the final rows E_N x_N (x_0 = 0, Dx_0 = 0)."""
    n, m = B0.shape
    ix = lambda k: (k - 1) * n                       # noqa: E731  x_k, k >= 1
    iu = lambda k: N * n + k * m                     # noqa: E731
    il = lambda k: N * n + N * m + k * n             # noqa: E731
    inu = N * n + N * m + (N + 1) * n
    nz = inu + 4
    K, rhs = np.zeros((nz, nz)), np.zeros(nz)
    row = 0
    I, EN = np.eye(n), np.eye(n)[:4]
    for k in range(N + 1):                           # x-stationarity
        blk = slice(row, row + n)
        if k >= 1:
            K[blk, ix(k):ix(k) + n] = I
        K[blk, il(k):il(k) + n] = -I
        if k < N:
            K[blk, il(k + 1):il(k + 1) + n] = A0.T
        else:
            K[blk, inu:inu + 4] = EN.T
        rhs[blk] = -q[k]
        row += n
    for k in range(N):                               # u-stationarity
        blk = slice(row, row + m)
        K[blk, iu(k):iu(k) + m] = np.eye(m)
        K[blk, il(k + 1):il(k + 1) + n] = B0.T
        rhs[blk] = -r[k]
        row += m
    for k in range(N):                               # dynamics
        blk = slice(row, row + n)
        if k >= 1:
            K[blk, ix(k):ix(k) + n] = A0
        K[blk, iu(k):iu(k) + m] = B0
        K[blk, ix(k + 1):ix(k + 1) + n] = -I
        row += n
    K[row:row + 4, ix(N):ix(N) + n] = EN             # final rows
    z = np.linalg.solve(K, rhs)
    X = np.vstack([np.zeros(n), z[:N * n].reshape(N, n)])
    return X, z[N * n:N * n + N * m].reshape(N, m), z[il(0):inu].reshape(N + 1, n), z[inu:]


def test_the_plain_recursion_is_accurate_on_the_unstable_dynamics():
    assert control_row_residual(100, final_rows=False) < 1e-12


def test_the_general_recursion_is_accurate_on_the_unstable_dynamics_with_final_rows():
    assert control_row_residual(100) < 1e-10


def test_the_generic_plain_kernel_is_accurate_on_the_unstable_dynamics():
    # n = 25 > codegen.FIXED_SIZE_MAX: the plain kernels for any block size, not the fixed ones
    assert control_row_residual(100, final_rows=False, copies=5) < 1e-12


@pytest.mark.parametrize("N", [30, 60, 100])
def test_the_general_recursion_matches_a_dense_solve(N):
    fac, q, r, eN = problem(N)
    n = fac.n
    sol = fac.solve(q, r, np.zeros((N, n)), np.zeros(n), eN=eN)
    X, U, lam, nuN = dense_solution(N, q, r)
    for got, ref in ((sol.X, X), (sol.U, U), (sol.lam, lam), (sol.nu[N, :4], nuN)):
        assert np.abs(got - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max())
