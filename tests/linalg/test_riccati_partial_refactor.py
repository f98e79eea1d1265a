"""RiccatiFactorization.refactor(from_stage=k): after a change of the equality rows at stages
<= k only (rows written into E, F in place, counts into data.ne -- the active-set QP's
working-set changes), factoring the stages <= k again gives the factorization of a fresh object
with the same data, bit for bit."""

import numpy as np
import pytest

from olado.linalg import RiccatiFactorization

FACTORS = ("P", "K", "Quu", "Qux", "Lww", "Qm", "Rm", "perm", "rank", "nc", "Cx", "G", "ng", "Wx", "Dmat", "pg", "Zg")


def lq(seed, N=12, n=3, m=2, cap=4):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((N + 1, n, n)); Q = M @ M.transpose(0, 2, 1) + 0.1 * np.eye(n)
    M2 = rng.standard_normal((N, m, m)); R = M2 @ M2.transpose(0, 2, 1) + 0.1 * np.eye(m)
    d = dict(Q=Q, S=0.05 * rng.standard_normal((N, n, m)), R=R, A=0.8 * rng.standard_normal((N, n, n)),
             B=rng.standard_normal((N, n, m)))
    E, F = np.zeros((N, cap, n)), np.zeros((N, cap, m))
    counts = rng.integers(0, 2, N)
    for k in range(N):
        for i in range(counts[k]):
            E[k, i], F[k, i] = rng.standard_normal(n), rng.standard_normal(m)
    rhs = dict(q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)), c=rng.standard_normal((N, n)),
               x0=rng.standard_normal(n), e=rng.standard_normal((N, cap)))
    return d, E, F, counts, rhs, rng


@pytest.mark.parametrize("seed", range(4))
def test_partial_refactor_equals_a_fresh_factorization(seed):
    d, E, F, counts, rhs, rng = lq(seed)
    N = len(counts)
    fact = RiccatiFactorization(**d, E=E, F=F, n_eq=counts.copy(), EN=np.zeros((1, 3)) + [[1.0, 0.0, 0.0]])
    for _ in range(6):
        k = int(rng.integers(0, N))
        # add a row at stage k (a state row, a control row or a mixed one), or take one away
        if counts[k] < E.shape[1] and rng.random() < 0.7:
            i = counts[k]
            E[k, i] = rng.standard_normal(3) * (rng.random() < 0.8)
            F[k, i] = rng.standard_normal(2) * (rng.random() < 0.5)
            counts[k] += 1
        elif counts[k] > 0:
            counts[k] -= 1
            E[k, counts[k]] = 0.0; F[k, counts[k]] = 0.0
        fact.data.ne[:] = counts
        fact.refactor(from_stage=k)
        fresh = RiccatiFactorization(**d, E=E.copy(), F=F.copy(), n_eq=counts.copy(), EN=fact.data.EN.copy())
        for name in FACTORS:
            assert np.array_equal(getattr(fact, name), getattr(fresh, name)), name
        a, b = fact.solve(**rhs), fresh.solve(**rhs)
        assert np.array_equal(a.X, b.X) and np.array_equal(a.nu, b.nu) and a.x0_residual == b.x0_residual


def test_from_stage_beyond_the_horizon_is_a_full_refactor_and_the_plain_recursion_ignores_it():
    d, E, F, counts, rhs, _ = lq(7)
    fact = RiccatiFactorization(**d, E=E, F=F, n_eq=counts.copy())
    x_full = fact.refactor().solve(**rhs).X.copy()
    assert np.array_equal(fact.refactor(from_stage=10_000).solve(**rhs).X, x_full)
    plain = RiccatiFactorization(**d)
    x = plain.solve(rhs["q"], rhs["r"], rhs["c"], rhs["x0"]).X.copy()
    assert np.array_equal(plain.refactor(from_stage=2).solve(rhs["q"], rhs["r"], rhs["c"], rhs["x0"]).X, x)
