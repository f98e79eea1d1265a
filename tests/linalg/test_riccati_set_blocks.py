"""RiccatiFactorization.set_blocks: new cost and dynamics blocks for the next refactor (the
interior-point NLP's Newton matrix of the next iteration, olado.solvers.ipm.newton) -- the
factorization and its solves are bit for bit those of a factorization built afresh on the new
blocks, with and without equality rows and stage inequality terms, and a wrong shape is refused."""

import numpy as np
import pytest

from olado.linalg.riccati import RiccatiFactorization


def _blocks(rng, N, n, m):
    H = rng.standard_normal((N + 1, n + m, n + m))
    H = np.einsum("kij,klj->kil", H, H) / (n + m) + 0.1 * np.eye(n + m)
    Q = np.ascontiguousarray(H[:, :n, :n])
    S = np.ascontiguousarray(H[:N, :n, n:])
    R = np.ascontiguousarray(H[:N, n:, n:])
    return Q, S, R, rng.standard_normal((N, n, n)) * 0.5, rng.standard_normal((N, n, m))


@pytest.mark.parametrize("rows", [False, True])
@pytest.mark.parametrize("n, m", [(3, 2), (30, 4)])      # kernels for the block sizes, and the any-size ones
def test_set_blocks_then_refactor_is_a_fresh_factorization(rows, n, m):
    rng = np.random.default_rng(n + m + rows)
    N = 6
    kw = dict(Dx=rng.uniform(0, 1, (N + 1, n)), Du=rng.uniform(0, 1, (N, m)))
    if rows:
        kw.update(E=rng.standard_normal((N, 1, n)), F=rng.standard_normal((N, 1, m)), EN=rng.standard_normal((1, n)),
                  Ci=rng.standard_normal((N, 2, n + m)), sigma=rng.uniform(0.1, 2.0, (N, 2)))
    old = RiccatiFactorization(*_blocks(rng, N, n, m), **kw)
    new_blocks = _blocks(rng, N, n, m)
    old.set_blocks(*new_blocks).refactor(Dx=kw["Dx"], Du=kw["Du"], sigma=kw.get("sigma"))
    fresh = RiccatiFactorization(*new_blocks, **kw)
    rhs = dict(q=rng.standard_normal((N + 1, n)), r=rng.standard_normal((N, m)), c=rng.standard_normal((N, n)),
               x0=rng.standard_normal(n))
    if rows:
        rhs.update(e=rng.standard_normal((N, 1)), eN=rng.standard_normal(1), ci=rng.standard_normal((N, 2)))
    a, b = old.solve(**rhs), fresh.solve(**rhs)
    for x, y in ((a.X, b.X), (a.U, b.U), (a.lam, b.lam), (a.nu, b.nu)):
        assert np.array_equal(x, y)
    assert old.data.A is new_blocks[3]          # held by reference (C-contiguous float64)


def test_set_blocks_refuses_other_shapes():
    rng = np.random.default_rng(0)
    fac = RiccatiFactorization(*_blocks(rng, 4, 3, 2))
    Q, S, R, A, B = _blocks(rng, 5, 3, 2)
    with pytest.raises(ValueError):
        fac.set_blocks(Q, S, R, A, B)
