"""Block Hessian approximations of the SQP method (paper 001 sec. 4.2.1, eq. (13))."""

import numpy as np

from olado.solvers.sqp.hessian import BlockBFGS, BlockSR1, ExactHessian, PowellBFGS, gerschgorin, levenberg


def _rand(seed, N=4, n=2, m=1):
    rng = np.random.default_rng(seed)
    return rng, N, n, m


def test_block_bfgs_satisfies_the_secant_equation_per_block():
    rng, N, n, m = _rand(0)
    h = BlockBFGS(); h.initial(N, n, m)
    s = rng.standard_normal((N, n + m)); sN = rng.standard_normal(n)
    M = rng.standard_normal((n + m, n + m)); Hs = M @ M.T + np.eye(n + m)
    y = s @ Hs.T; yN = 2.0 * sN
    h.update(s, sN, y, yN)
    B, BN = h.current()
    assert np.allclose(np.einsum("kij,kj->ki", B, s), y) and np.allclose(BN @ sN, yN)
    assert np.all(np.linalg.eigvalsh(B) > 0)


def test_powell_damping_keeps_bfgs_positive_definite_for_negative_curvature():
    rng, N, n, m = _rand(1)
    h = BlockBFGS(); h.initial(N, n, m)
    s = rng.standard_normal((N, n + m)); y = -s          # s.y < 0: undamped BFGS would lose definiteness
    h.update(s, np.ones(n), y, -np.ones(n))
    B, BN = h.current()
    assert np.all(np.linalg.eigvalsh(B) > 0) and np.all(np.linalg.eigvalsh(BN) > 0)
    # damped secant condition: s.B+s = s.r with r = theta y + (1-theta) B s, s.r = 0.2 s.B s
    assert np.allclose(np.einsum("ki,kij,kj->k", s, B, s), 0.2 * np.einsum("ki,ki->k", s, s))


def test_block_bfgs_restarts_an_ill_conditioned_block():
    """A block with curvature ~1e-9 along e_0 (a flat direction) and a step mostly along e_0 whose
    y points elsewhere: the update r r^T / s.r has a tiny s.r and drives the condition number far
    beyond max_condition; that block (only) is restarted as g I, g the geometric mean of its
    eigenvalues after the update."""
    N, n, m = 2, 1, 1
    h = BlockBFGS(max_condition=1e8, initial_scale=1.0); h.initial(N, n, m)
    h.B[0] = np.diag([1e-9, 1.0]); h.BN = np.eye(n)
    s = np.array([[1.0, 1e-3], [1.0, 0.0]]); y = np.array([[1e-9, 1.0], [1.0, 0.0]])
    B0 = h.B.copy()
    raw = BlockBFGS(max_condition=np.inf, initial_scale=1.0); raw.initial(N, n, m); raw.B = B0.copy()
    raw.update(s, np.zeros(n), y, np.zeros(n))
    w = np.linalg.eigvalsh(raw.B[0])
    assert w[-1] / w[0] > 1e8                                           # what the restart is for
    h.update(s, np.zeros(n), y, np.zeros(n))
    assert h.resets == 1
    assert np.allclose(h.B[0], np.exp(np.mean(np.log(w))) * np.eye(2))
    assert np.allclose(h.B[1], raw.B[1])                                # the other block: plain BFGS


def test_sr1_recovers_a_quadratic_and_stays_positive_definite():
    rng, N, n, m = _rand(2, N=2, n=2, m=1)
    M = rng.standard_normal((3, 3)); H = M @ M.T + np.eye(3)   # H - B0 >= 0: every SR1 iterate stays PD
    h = BlockSR1(); h.initial(N, n, m)
    for j in range(3):
        s = np.tile(np.eye(3)[j], (N, 1)); h.update(s, np.zeros(n), s @ H.T, np.zeros(n))
    B, _ = h.current()
    assert np.allclose(B, H, atol=1e-8)
    h2 = BlockSR1(min_eig=1e-3); h2.initial(1, 1, 1)
    h2.update(np.array([[1.0, 0.0]]), np.zeros(1), np.array([[-5.0, 0.0]]), np.zeros(1))
    assert np.linalg.eigvalsh(h2.current()[0])[0, 0] >= 1e-3 - 1e-12


def test_powell_bfgs_with_gangster_operator_keeps_the_block_pattern():
    rng, N, n, m = _rand(3)
    h = PowellBFGS(); h.initial(N, n, m)
    s = rng.standard_normal((N, n + m)); sN = rng.standard_normal(n)
    y = 3.0 * s; yN = 3.0 * sN
    h.update(s, sN, y, yN)
    B, BN = h.current()
    # the whole-matrix update with scalar curvature 3 and B0 = I: B = I - ss^T/|s|^2 + 3 ss^T/|s|^2 restricted to blocks
    ss = float(np.sum(s * s) + sN @ sN)
    expect = np.eye(n + m) + 2.0 * np.einsum("ki,kj->kij", s, s) / ss
    assert np.allclose(B, expect) and np.allclose(BN, np.eye(n) + 2.0 * np.outer(sN, sN) / ss)


def test_gerschgorin_modification_13_and_levenberg_shift():
    H = np.array([[[1.0, 2.0], [2.0, -1.0]]])
    G = gerschgorin(H, 1e-3)
    assert np.allclose(G, [[[2.001, 2.0], [2.0, 2.001]]])
    assert np.all(np.linalg.eigvalsh(G) > 0)
    L = levenberg(H, 1e-3)
    assert np.isclose(np.linalg.eigvalsh(L)[0, 0], 1e-3)
    assert np.allclose(L - H, (L - H)[0, 0, 0] * np.eye(2))
    e = ExactHessian(convexify="gerschgorin", min_eig=1e-3); e.set_exact(H, np.eye(1)); assert np.allclose(e.current()[0], G)
